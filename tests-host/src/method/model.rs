//! Calibrated models of the actuator: their kinds and their file format
//! (`piezo-fpi-model/1`). A model is evaluated as a [`piezo_sim::model::Model`]
//! ([`HostModel::model`]): the project's one float model, of which every kind is a
//! configuration:
//!
//! | kind | input | parts |
//! |---|---|---|
//! | `pi` | `u` | PI with one-sided play operators (the conventional baseline) |
//! | `ldpi` | `u` | PI whose weights are affine in the preload, `w_i(F) = a_i + b_i·F` (the paper's LDPI baseline, as we implement it: its source is not available) |
//! | `fpi` | `û = max(u − k_f·F, 0)` | the paper's FPI (eqs. 5–7) |
//! | `efpi` | `û = g(u − U_p(F))` | extended FPI: `U_p = k0 + k_f·F + k_q·(F − F_q)²`, soft dead zone `g`, creep lags, output saturation, stack compliance |
//! | `gpi` | `u` | PI followed by a monotone quadratic output map and an offset (for recordings without force) |

use std::fmt;
use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use piezo_sim::file::{CouplingSection, CreepSection, PiSection};
use piezo_sim::model::{Coupling, Creep, DeadZone, Ldpi, Model, Output, MAX_CREEP};
use piezo_sim::play::{Pi, Values, MAX_OPERATORS};

/// The model-file format string.
pub const FORMAT: &str = "piezo-fpi-model/1";

/// Which model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Classical PI on the voltage.
    Pi,
    /// Load-dependent PI: weights affine in the preload.
    Ldpi,
    /// The paper's force-dependent PI.
    Fpi,
    /// Extended FPI: curved preload offset, soft dead zone, creep, saturation, compliance.
    Efpi,
    /// PI with a monotone quadratic output map and an offset (no force).
    Gpi,
}

impl Kind {
    /// Every kind, in the order reports list them.
    pub const ALL: [Kind; 5] = [Kind::Pi, Kind::Ldpi, Kind::Fpi, Kind::Efpi, Kind::Gpi];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Pi => "pi",
            Kind::Ldpi => "ldpi",
            Kind::Fpi => "fpi",
            Kind::Efpi => "efpi",
            Kind::Gpi => "gpi",
        }
    }

    /// A kind by name.
    pub fn parse(s: &str) -> Result<Kind> {
        Kind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .with_context(|| {
                format!("unknown model kind {s:?}: expected pi, ldpi, fpi, efpi or gpi")
            })
    }

    /// Whether the model needs the preload.
    pub fn uses_force(self) -> bool {
        matches!(self, Kind::Ldpi | Kind::Fpi | Kind::Efpi)
    }

    /// The name the paper's method gets with this model (PI-FEM, FPI-FFEM, …).
    pub fn method(self) -> &'static str {
        match self {
            Kind::Pi => "PI-FEM",
            Kind::Ldpi => "LDPI-FEM",
            Kind::Fpi => "FPI-FFEM",
            Kind::Efpi => "EFPI-FFEM",
            Kind::Gpi => "GPI-FEM",
        }
    }
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// LDPI: the slopes of the weights in the preload, `w_i(F) = w_i + b_i·F`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct LdpiParams {
    /// Slope of `w0`, µm/V/N.
    pub w0_per_n: f64,
    /// Slopes of the operator weights, µm/V/N.
    pub weights_per_n: Vec<f64>,
}

/// The map after the PI (analytic), as the model file stores it.
pub type OutputMap = piezo_sim::maps::OutputMap<f64>;

/// Fit of one calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileFit {
    /// The recording.
    pub file: String,
    /// Samples scored.
    pub samples: usize,
    /// Root-mean-square error, µm.
    pub rmse_um: f64,
    /// Largest absolute error (MTE), µm.
    pub mte_um: f64,
}

/// Where a model came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Tool and version.
    pub created_by: String,
    /// Recordings it was fitted on.
    pub files: Vec<String>,
    /// Rows fitted (1-based, inclusive), when only part of one recording was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<[usize; 2]>,
    /// RMSE over all fitted samples, µm.
    pub rmse_um: f64,
    /// Largest error over all fitted samples, µm.
    pub mte_um: f64,
    /// Per recording.
    pub per_file: Vec<FileFit>,
    /// How it was fitted.
    pub method: String,
}

/// A calibrated model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostModel {
    /// Always [`FORMAT`].
    pub format: String,
    /// Which model.
    pub kind: Kind,
    /// The PI part.
    pub pi: PiSection,
    /// LDPI weight slopes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ldpi: Option<LdpiParams>,
    /// Force coupling (FPI kinds).
    #[serde(default)]
    pub coupling: CouplingSection,
    /// Softness `s` of the dead zone `g(e) = s·ln(1 + e^{e/s})`, V (0: hard).
    #[serde(default)]
    pub dead_zone_softness_v: f64,
    /// The map after the PI.
    #[serde(default)]
    pub output: OutputMap,
    /// Constant added to the PI output `Y` before the output map, µm (recordings not
    /// zeroed at rest).
    #[serde(default)]
    pub offset_um: f64,
    /// Creep lags.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub creep: Vec<CreepSection>,
    /// Provenance and fit metrics.
    pub calibration: Calibration,
}

impl HostModel {
    /// A new model of `kind` with the given PI part and everything else off.
    pub fn new(kind: Kind, pi: PiSection) -> Self {
        Self {
            format: FORMAT.into(),
            kind,
            pi,
            ldpi: None,
            coupling: CouplingSection::default(),
            dead_zone_softness_v: 0.0,
            output: OutputMap::Identity,
            offset_um: 0.0,
            creep: Vec::new(),
            calibration: Calibration::default(),
        }
    }

    /// Reads a model file; errors name the file and the key.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// A model from the text of a model file named `name` (for messages).
    pub fn parse(text: &str, name: &str) -> Result<Self> {
        let m: HostModel =
            toml::from_str(text).with_context(|| format!("{name}: not a model file"))?;
        m.validate().with_context(|| name.to_string())?;
        Ok(m)
    }

    /// Writes the model file.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = toml::to_string(self)?;
        let header = format!(
            "# A calibrated {} model (`fpi calibrate`). Units are in the key names.\n\n",
            self.kind
        );
        std::fs::write(path, header + &text).with_context(|| format!("writing {}", path.display()))
    }

    /// Checks the parameters; names the key that is wrong.
    pub fn validate(&self) -> Result<()> {
        if self.format != FORMAT {
            bail!("format = {:?}: expected {FORMAT:?}", self.format);
        }
        let p = &self.pi;
        if p.thresholds_v.len() != p.weights_um_per_v.len() {
            bail!(
                "pi.weights_um_per_v has {} values for {} thresholds",
                p.weights_um_per_v.len(),
                p.thresholds_v.len()
            );
        }
        if p.thresholds_v.len() > MAX_OPERATORS {
            bail!(
                "pi.thresholds_v has {} values: at most {MAX_OPERATORS} operators",
                p.thresholds_v.len()
            );
        }
        if self.creep.len() > MAX_CREEP {
            bail!("creep has {} terms: at most {MAX_CREEP}", self.creep.len());
        }
        let finite = |k: &str, v: f64| -> Result<()> {
            if v.is_finite() {
                Ok(())
            } else {
                bail!("{k} = {v}: not finite")
            }
        };
        finite("pi.w0_um_per_v", p.w0_um_per_v)?;
        finite("pi.input_max_v", p.input_max_v)?;
        if p.input_max_v <= 0.0 {
            bail!("pi.input_max_v = {}: must be > 0", p.input_max_v);
        }
        let mut prev = 0.0;
        for (i, (&r, &w)) in p.thresholds_v.iter().zip(&p.weights_um_per_v).enumerate() {
            finite(&format!("pi.thresholds_v[{i}]"), r)?;
            finite(&format!("pi.weights_um_per_v[{i}]"), w)?;
            if r < prev {
                bail!("pi.thresholds_v[{i}] = {r}: thresholds must be sorted");
            }
            prev = r;
        }
        if let Some(l) = &self.ldpi {
            if l.weights_per_n.len() != p.thresholds_v.len() {
                bail!(
                    "ldpi.weights_per_n has {} values for {} thresholds",
                    l.weights_per_n.len(),
                    p.thresholds_v.len()
                );
            }
        } else if self.kind == Kind::Ldpi {
            bail!("kind = \"ldpi\" needs an [ldpi] section");
        }
        for (j, c) in self.creep.iter().enumerate() {
            if !(c.tau_s.is_finite() && c.tau_s > 0.0 && c.gain_um_per_v.is_finite()) {
                bail!("creep[{j}]: tau_s must be > 0 and gain_um_per_v finite");
            }
        }
        Ok(())
    }

    /// Operators of the PI part.
    pub fn operators(&self) -> usize {
        self.pi.thresholds_v.len()
    }

    /// The model as the project's float model evaluates it.
    pub fn model(&self) -> Model<'static, f64> {
        let p = &self.pi;
        let uses_coupling = matches!(self.kind, Kind::Fpi | Kind::Efpi);
        let c = &self.coupling;
        let mut creep = heapless::Vec::new();
        for cr in &self.creep {
            // At most MAX_CREEP: `validate` refuses more.
            let _ = creep.push(Creep {
                tau_s: cr.tau_s,
                gain: cr.gain_um_per_v,
            });
        }
        Model {
            pi: Pi {
                w0: p.w0_um_per_v,
                r: Values::from_slice(&p.thresholds_v).unwrap_or_default(),
                w: Values::from_slice(&p.weights_um_per_v).unwrap_or_default(),
                input_max: p.input_max_v,
            },
            ldpi: self.ldpi.as_ref().map(|l| Ldpi {
                w0_per_n: l.w0_per_n,
                w_per_n: Values::from_slice(&l.weights_per_n).unwrap_or_default(),
            }),
            coupling: uses_coupling.then_some(Coupling {
                offset: c.offset_v,
                k_f: c.k_f_v_per_n,
                k_q: c.k_q_v_per_n2,
                force_q: c.force_q_n,
                compliance: c.compliance_um_per_n,
            }),
            dead_zone: if uses_coupling && self.dead_zone_softness_v > 0.0 {
                DeadZone::Soft(self.dead_zone_softness_v)
            } else {
                DeadZone::Hard
            },
            output: Output::Map(self.output),
            offset: self.offset_um,
            creep,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn efpi() -> HostModel {
        let mut m = HostModel::new(
            Kind::Efpi,
            PiSection {
                w0_um_per_v: 0.06,
                thresholds_v: vec![10.0, 30.0, 60.0],
                weights_um_per_v: vec![0.01, 0.008, 0.004],
                input_max_v: 150.0,
            },
        );
        m.coupling = CouplingSection {
            offset_v: -0.4,
            k_f_v_per_n: 0.106,
            k_q_v_per_n2: 1.6e-4,
            force_q_n: 75.0,
            compliance_um_per_n: 0.02,
            force_ref_n: None,
        };
        m.dead_zone_softness_v = 1.8;
        m.output = OutputMap::Saturation {
            beta_per_um: 0.0037,
        };
        m.creep = vec![CreepSection {
            tau_s: 0.01,
            gain_um_per_v: 0.003,
        }];
        m
    }

    #[test]
    fn model_files_round_trip() {
        let m = efpi();
        let dir = std::env::temp_dir().join(format!("hmodel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.toml");
        m.write(&p).unwrap();
        assert_eq!(HostModel::read(&p).unwrap(), m);
    }
}
