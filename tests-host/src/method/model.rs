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
//! | `branch` | `û = clamp(u − k_f·F, 0, input_max)` | no PI: the second paper's branch polynomials (eqs. 6–7) from the last turning point, with a memory of turning points ([`crate::method::branch`]) |

use std::fmt;
use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use piezo_sim::file::{CouplingSection, CreepSection, PiSection};
use piezo_sim::model::{Coupling, Creep, DeadZone, Ldpi, Model, Output, MAX_CREEP};
use piezo_sim::play::{Pi, Values, MAX_OPERATORS};

use crate::data::fem::FemMaps;
use crate::data::toml_file::{self, TomlFile};
use crate::method::branch::{self, BranchSection};

/// The model-file format string.
pub const FORMAT: &str = "piezo-fpi-model/1";

/// Largest model file read, bytes (1 MiB; a model file is about 2 kB).
pub const MAX_FILE_BYTES: u64 = 1 << 20;

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
    /// Branch-polynomial hysteresis (the second paper, eqs. 6–7).
    Branch,
}

impl Kind {
    /// Every kind, in the order reports list them.
    pub const ALL: [Kind; 6] = [
        Kind::Pi,
        Kind::Ldpi,
        Kind::Fpi,
        Kind::Efpi,
        Kind::Gpi,
        Kind::Branch,
    ];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Pi => "pi",
            Kind::Ldpi => "ldpi",
            Kind::Fpi => "fpi",
            Kind::Efpi => "efpi",
            Kind::Gpi => "gpi",
            Kind::Branch => "branch",
        }
    }

    /// A kind by name.
    pub fn parse(s: &str) -> Result<Kind> {
        Kind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .with_context(|| {
                format!("unknown model kind {s:?}: expected pi, ldpi, fpi, efpi, gpi or branch")
            })
    }

    /// Whether the model needs the preload.
    pub fn uses_force(self) -> bool {
        matches!(self, Kind::Ldpi | Kind::Fpi | Kind::Efpi | Kind::Branch)
    }

    /// The name the paper's method gets with this model (PI-FEM, FPI-FFEM, …).
    pub fn method(self) -> &'static str {
        match self {
            Kind::Pi => "PI-FEM",
            Kind::Ldpi => "LDPI-FEM",
            Kind::Fpi => "FPI-FFEM",
            Kind::Efpi => "EFPI-FFEM",
            Kind::Gpi => "GPI-FEM",
            Kind::Branch => "BPH-FFEM",
        }
    }
}

/// Refuses a non-finite value of key `key`.
fn finite(key: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        bail!("{key} = {v}: not finite")
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
    /// What looked suspicious in the data (each names the file, the column and the
    /// value); empty when nothing did.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// A calibrated model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostModel {
    /// Always [`FORMAT`].
    pub format: String,
    /// Which model.
    pub kind: Kind,
    /// The PI part (none in a branch model, whose file leaves it out).
    #[serde(default = "branch::no_pi", skip_serializing_if = "branch::is_no_pi")]
    pub pi: PiSection,
    /// The branch polynomials (branch models only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch: Option<BranchSection>,
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
    /// A correction of the stage's FEM tables estimated from measured runs of the
    /// built stage (`fpi refine`); every command that pairs this model with FEM
    /// tables applies it ([`HostModel::stage_maps`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fem_correction: Option<FemCorrection>,
}

/// The range the gain of `f_K` and the scale of `f_F` may take in a
/// [`FemCorrection`]: a built stage differs from its FEM by a few percent, not by
/// a factor of two.
pub const CORRECTION_RANGE: (f64, f64) = (0.5, 2.0);

/// How the built stage differs from its FEM tables (`[fem_correction]` of a model
/// file, written by `fpi refine`): stage output `stage_gain·f_K(x_pea) +
/// stage_offset_um`, preload `preload_scale·f_F(x_pea)`. The actuator's
/// parameters are not touched.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FemCorrection {
    /// Gain of the stage output `f_K` (within [`CORRECTION_RANGE`]).
    pub stage_gain: f64,
    /// Offset added to the stage output, µm.
    pub stage_offset_um: f64,
    /// Scale of the preload `f_F` (within [`CORRECTION_RANGE`]).
    pub preload_scale: f64,
    /// The FEM file the correction was estimated against (provenance; a model is
    /// meant to be used with the same FEM tables).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub fem: String,
    /// The measured runs it was estimated from.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refined_on: Vec<String>,
    /// RMSE of the stage output on those runs with the FEM tables as they are, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_before_um: Option<f64>,
    /// The same with the correction, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_after_um: Option<f64>,
}

impl FemCorrection {
    /// No correction: the FEM tables as they are.
    pub fn identity() -> Self {
        Self {
            stage_gain: 1.0,
            stage_offset_um: 0.0,
            preload_scale: 1.0,
            fem: String::new(),
            refined_on: Vec::new(),
            rmse_before_um: None,
            rmse_after_um: None,
        }
    }

    /// The FEM maps corrected: new points `x_fhps·gain + offset` and
    /// `preload·scale`, checked as an FEM file's are.
    pub fn apply(&self, fem: &FemMaps) -> Result<FemMaps> {
        fem.corrected(self.stage_gain, self.stage_offset_um, self.preload_scale)
            .map_err(|e| {
                anyhow::anyhow!(
                    "[fem_correction] (stage_gain {}, stage_offset_um {}, preload_scale {}) \
                     applied to {}: {e}",
                    self.stage_gain,
                    self.stage_offset_um,
                    self.preload_scale,
                    fem.source
                )
            })
    }

    /// Checks the section; names the key that is wrong.
    pub fn validate(&self) -> Result<()> {
        let (lo, hi) = CORRECTION_RANGE;
        for (key, v) in [
            ("fem_correction.stage_gain", self.stage_gain),
            ("fem_correction.preload_scale", self.preload_scale),
        ] {
            finite(key, v)?;
            if !(lo..=hi).contains(&v) {
                bail!(
                    "{key} = {v}: outside {lo}..{hi} (a built stage differs from its FEM by a \
                     few percent; is this the right stage or FEM?)"
                );
            }
        }
        finite("fem_correction.stage_offset_um", self.stage_offset_um)?;
        if self.stage_offset_um.abs() > piezo_fpi::q::SIGNAL_ABS_MAX {
            bail!(
                "fem_correction.stage_offset_um = {}: outside ±{} µm",
                self.stage_offset_um,
                piezo_fpi::q::SIGNAL_ABS_MAX
            );
        }
        for (key, v) in [
            ("fem_correction.rmse_before_um", self.rmse_before_um),
            ("fem_correction.rmse_after_um", self.rmse_after_um),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v >= 0.0) {
                    bail!("{key} = {v}: must be a finite number ≥ 0 µm");
                }
            }
        }
        Ok(())
    }
}

impl HostModel {
    /// A new model of `kind` with the given PI part and everything else off.
    pub fn new(kind: Kind, pi: PiSection) -> Self {
        Self {
            format: FORMAT.into(),
            kind,
            pi,
            branch: None,
            ldpi: None,
            coupling: CouplingSection::default(),
            dead_zone_softness_v: 0.0,
            output: OutputMap::Identity,
            offset_um: 0.0,
            creep: Vec::new(),
            calibration: Calibration::default(),
            fem_correction: None,
        }
    }

    /// The stage maps this model runs with: the FEM tables `fem`, corrected by the
    /// model's `[fem_correction]` when it has one. The one place a correction is
    /// applied: every command that pairs a model with FEM tables (predict, compare,
    /// invert, export, `board load`) goes through here.
    pub fn stage_maps(&self, fem: &FemMaps) -> Result<FemMaps> {
        match &self.fem_correction {
            None => Ok(fem.clone()),
            Some(c) => c.apply(fem),
        }
    }

    /// Reads a model file (at most [`MAX_FILE_BYTES`]); errors name the file and
    /// the key.
    pub fn read(path: &Path) -> Result<Self> {
        toml_file::read(path)
    }

    /// A model from the text of a model file named `name` (for messages).
    pub fn parse(text: &str, name: &str) -> Result<Self> {
        toml_file::parse(text, name)
    }

    /// Writes the model file atomically ([`crate::output::write_atomic`]), after
    /// [`validate`](Self::validate): a model that reading would refuse is never
    /// written.
    pub fn write(&self, path: &Path) -> Result<()> {
        toml_file::write(self, path)
    }

    /// Checks the parameters; names the key that is wrong. This is the one
    /// validator of host model files: every reader and [`write`](Self::write) run
    /// it, and the commands that use a model (predict, invert, export) run it again.
    pub fn validate(&self) -> Result<()> {
        if self.format != FORMAT {
            bail!("format = {:?}: expected {FORMAT:?}", self.format);
        }
        if self.kind == Kind::Branch {
            self.validate_branch()?;
            return match &self.fem_correction {
                Some(c) => c.validate(),
                None => Ok(()),
            };
        }
        if self.branch.is_some() {
            bail!(
                "branch: a {} model has no [branch] section (only kind = \"branch\")",
                self.kind
            );
        }
        if branch::is_no_pi(&self.pi) {
            bail!("pi: missing: a {} model needs its [pi] section", self.kind);
        }
        self.validate_sizes()?;
        self.validate_pi()?;
        self.validate_motion()?;
        self.validate_coupling()?;
        self.validate_maps()?;
        self.validate_ldpi()?;
        for (j, c) in self.creep.iter().enumerate() {
            if !(c.tau_s.is_finite() && c.tau_s > 0.0 && c.gain_um_per_v.is_finite()) {
                bail!("creep[{j}]: tau_s must be > 0 and gain_um_per_v finite");
            }
        }
        if let Some(c) = &self.fem_correction {
            c.validate()?;
        }
        Ok(())
    }

    /// A branch model: its `[branch]` section, `k_f` ≥ 0 and the rest offset, and
    /// none of the other kinds' parts.
    fn validate_branch(&self) -> Result<()> {
        let Some(b) = &self.branch else {
            bail!("kind = \"branch\" needs a [branch] section");
        };
        b.validate()?;
        if !branch::is_no_pi(&self.pi) {
            bail!("pi: a branch model has no PI part (leave the [pi] section out)");
        }
        let c = &self.coupling;
        let k_f = c.k_f_v_per_n;
        if !(k_f.is_finite() && k_f >= 0.0) {
            bail!("coupling.k_f_v_per_n = {k_f}: must be a finite value ≥ 0 V/N");
        }
        for (key, v) in [
            ("coupling.offset_v", c.offset_v),
            ("coupling.k_q_v_per_n2", c.k_q_v_per_n2),
            ("coupling.force_q_n", c.force_q_n),
            ("coupling.compliance_um_per_n", c.compliance_um_per_n),
            ("dead_zone_softness_v", self.dead_zone_softness_v),
        ] {
            if v != 0.0 {
                bail!("{key} = {v}: a branch model uses only coupling.k_f_v_per_n (must be 0)");
            }
        }
        finite("offset_um", self.offset_um)?;
        if self.output != OutputMap::Identity {
            bail!("output: a branch model has no output map");
        }
        if self.ldpi.is_some() || !self.creep.is_empty() {
            bail!("ldpi, creep: a branch model has neither section");
        }
        Ok(())
    }

    /// The top of the model's input range, V (`pi.input_max_v`, or
    /// `branch.input_max_v` for a branch model).
    pub fn input_max_v(&self) -> f64 {
        match &self.branch {
            Some(b) if self.kind == Kind::Branch => b.input_max_v,
            _ => self.pi.input_max_v,
        }
    }

    /// Counts: one weight per threshold, at most [`MAX_OPERATORS`] and [`MAX_CREEP`].
    fn validate_sizes(&self) -> Result<()> {
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
        Ok(())
    }

    /// The PI part: finite numbers, a positive input range, thresholds sorted in
    /// `[0, input_max_v]`.
    fn validate_pi(&self) -> Result<()> {
        let p = &self.pi;
        finite("pi.w0_um_per_v", p.w0_um_per_v)?;
        finite("pi.input_max_v", p.input_max_v)?;
        if p.input_max_v <= 0.0 {
            bail!("pi.input_max_v = {}: must be > 0", p.input_max_v);
        }
        let mut prev = 0.0;
        for (i, (&r, &w)) in p.thresholds_v.iter().zip(&p.weights_um_per_v).enumerate() {
            finite(&format!("pi.thresholds_v[{i}]"), r)?;
            finite(&format!("pi.weights_um_per_v[{i}]"), w)?;
            if r < 0.0 {
                bail!("pi.thresholds_v[{i}] = {r}: thresholds are voltages ≥ 0 V");
            }
            if r < prev {
                bail!("pi.thresholds_v[{i}] = {r}: thresholds must be sorted");
            }
            if r > p.input_max_v {
                bail!(
                    "pi.thresholds_v[{i}] = {r}: above pi.input_max_v = {} (the operator never moves)",
                    p.input_max_v
                );
            }
            prev = r;
        }
        Ok(())
    }

    /// The model can produce motion and, but for ldpi (whose weights depend on the
    /// force), has an inverse: `w0 > 0` and every partial sum
    /// `S_j = w0 + w_1 + … + w_j > 0` (its output rises with the voltage).
    fn validate_motion(&self) -> Result<()> {
        let p = &self.pi;
        let slopes = self.ldpi.as_ref();
        let all_zero = p.w0_um_per_v == 0.0
            && p.weights_um_per_v.iter().all(|&w| w == 0.0)
            && slopes
                .is_none_or(|l| l.w0_per_n == 0.0 && l.weights_per_n.iter().all(|&w| w == 0.0));
        if all_zero {
            bail!(
                "pi.w0_um_per_v and pi.weights_um_per_v are all 0: the model cannot produce \
                 motion (was it calibrated on data without motion, e.g. a few rows or a \
                 constant voltage?)"
            );
        }
        if self.kind == Kind::Ldpi {
            return Ok(());
        }
        if p.w0_um_per_v <= 0.0 {
            bail!(
                "pi.w0_um_per_v = {}: must be > 0 µm/V (the model's slope at rest; without it \
                 the model has no inverse)",
                p.w0_um_per_v
            );
        }
        let mut sum = p.w0_um_per_v;
        for (j, &w) in p.weights_um_per_v.iter().enumerate() {
            sum += w;
            if sum <= 0.0 {
                let terms = if j == 0 {
                    "w0 + w_1".to_string()
                } else {
                    format!("w0 + w_1 + … + w_{}", j + 1)
                };
                bail!(
                    "pi.weights_um_per_v[{j}] = {w}: the slope {terms} = {sum} µm/V is not \
                     positive (the output would fall as the voltage rises; no inverse)"
                );
            }
        }
        Ok(())
    }

    /// The coupling: finite, and a stack compliance that is not negative.
    fn validate_coupling(&self) -> Result<()> {
        let c = &self.coupling;
        finite("coupling.offset_v", c.offset_v)?;
        finite("coupling.k_f_v_per_n", c.k_f_v_per_n)?;
        finite("coupling.k_q_v_per_n2", c.k_q_v_per_n2)?;
        finite("coupling.force_q_n", c.force_q_n)?;
        finite("coupling.compliance_um_per_n", c.compliance_um_per_n)?;
        if let Some(f) = c.force_ref_n {
            finite("coupling.force_ref_n", f)?;
        }
        if c.compliance_um_per_n < 0.0 {
            bail!(
                "coupling.compliance_um_per_n = {}: must be ≥ 0 µm/N (a stack yields under load)",
                c.compliance_um_per_n
            );
        }
        Ok(())
    }

    /// The dead zone's softness (≥ 0; 0 is hard), the output offset and map.
    fn validate_maps(&self) -> Result<()> {
        let s = self.dead_zone_softness_v;
        finite("dead_zone_softness_v", s)?;
        if s < 0.0 {
            bail!("dead_zone_softness_v = {s}: must be ≥ 0 V (0: the hard dead zone)");
        }
        finite("offset_um", self.offset_um)?;
        match self.output {
            OutputMap::Identity => Ok(()),
            OutputMap::Saturation { beta_per_um: b } => {
                finite("output.beta_per_um", b)?;
                let top = self.model().pi.output_max();
                if 1.0 + 4.0 * b * top <= 0.0 {
                    bail!(
                        "output.beta_per_um = {b}: the saturation folds over below the model's \
                         largest output {top} µm"
                    );
                }
                Ok(())
            }
            OutputMap::Quadratic { gamma_per_um: g } => finite("output.gamma_per_um", g),
        }
    }

    /// The ldpi section: one finite slope per threshold; present for an ldpi model.
    fn validate_ldpi(&self) -> Result<()> {
        let Some(l) = &self.ldpi else {
            if self.kind == Kind::Ldpi {
                bail!("kind = \"ldpi\" needs an [ldpi] section");
            }
            return Ok(());
        };
        if l.weights_per_n.len() != self.pi.thresholds_v.len() {
            bail!(
                "ldpi.weights_per_n has {} values for {} thresholds",
                l.weights_per_n.len(),
                self.pi.thresholds_v.len()
            );
        }
        finite("ldpi.w0_per_n", l.w0_per_n)?;
        for (i, &b) in l.weights_per_n.iter().enumerate() {
            finite(&format!("ldpi.weights_per_n[{i}]"), b)?;
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

impl TomlFile for HostModel {
    const WHAT: &'static str = "model file";
    const MAX_BYTES: u64 = MAX_FILE_BYTES;
    fn check(&self) -> Result<()> {
        self.validate()
    }
    fn header(&self) -> String {
        let refined = if self.fem_correction.is_some() {
            ", its stage's FEM tables refined on measured runs (`fpi refine`)"
        } else {
            ""
        };
        format!(
            "# A calibrated {} model (`fpi calibrate`){refined}. Units are in the key names.\n\n",
            self.kind
        )
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

    #[test]
    fn fem_corrections_round_trip_and_name_their_key() {
        let mut m = efpi();
        m.fem_correction = Some(FemCorrection {
            stage_gain: 0.98,
            stage_offset_um: -0.02,
            preload_scale: 0.97,
            fem: "data/stage-a/fem.csv.gz".into(),
            refined_on: vec!["data/stage-a/sine_05Hz.csv.gz".into()],
            rmse_before_um: Some(0.158),
            rmse_after_um: Some(0.024),
        });
        let text = toml::to_string(&m).unwrap();
        assert!(text.contains("[fem_correction]"), "{text}");
        assert_eq!(HostModel::parse(&text, "m.toml").unwrap(), m);
        // Without the section: as before.
        assert!(!toml::to_string(&efpi()).unwrap().contains("fem_correction"));
        // The three numbers alone are a section.
        let plain = toml::to_string(&efpi()).unwrap()
            + "\n[fem_correction]\nstage_gain = 1.01\nstage_offset_um = 0.0\npreload_scale = 0.99\n";
        let c = HostModel::parse(&plain, "m.toml")
            .unwrap()
            .fem_correction
            .unwrap();
        assert_eq!((c.stage_gain, c.preload_scale), (1.01, 0.99));
        for (key, bad) in [
            ("stage_gain", "stage_gain = 1.01", "stage_gain = 3.0"),
            (
                "preload_scale",
                "preload_scale = 0.99",
                "preload_scale = nan",
            ),
            (
                "stage_offset_um",
                "stage_offset_um = 0.0",
                "stage_offset_um = inf",
            ),
        ]
        .map(|(k, from, to)| (k, plain.replace(from, to)))
        {
            let e = format!("{:#}", HostModel::parse(&bad, "m.toml").unwrap_err());
            assert!(
                e.contains(&format!("fem_correction.{key}")) && e.contains("m.toml"),
                "{e}"
            );
        }
        let unknown = plain.clone() + "stage_slope = 1.0\n";
        let e = format!("{:#}", HostModel::parse(&unknown, "m.toml").unwrap_err());
        assert!(e.contains("stage_slope"), "{e}");
    }
}
