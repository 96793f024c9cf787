//! A calibrated model of the actuator: its kind and its file (`piezo-fpi-model/1`).
//!
//! A model file names its kind (`kind = "efpi"`) and holds the sections that kind
//! uses ([`crate::method::sections`]). What a kind is and does — its calibration,
//! its checks, its prediction, inversion and export — is one implementation of
//! [`ModelKind`], in its own file under `method/kinds/` (the kinds and their
//! models are listed there); [`Kind`] is the handle a model holds. The kinds
//! built on play operators are evaluated as the project's one float model,
//! [`piezo_sim::model::Model`] ([`HostModel::model`]), of which each is a
//! configuration.

use std::fmt;
use std::path::Path;

use anyhow::Result;
use serde::{Deserialize, Serialize, Serializer};

use piezo_sim::model::{Coupling, Creep, DeadZone, Ldpi, Model, Output};
use piezo_sim::play::{Pi, Values};

use crate::data::fem::FemMaps;
use crate::data::toml_file::{self, TomlFile};
use crate::method::limits::AMPLIFIER_MAX_V;
use crate::method::series::{CalibData, Inversion, Prediction};
use crate::model_file::{CouplingSection, CreepSection, PiSection};

pub use crate::method::sections::{
    is_no_pi, no_pi, BranchSection, Calibration, FemCorrection, FileFit, LdpiParams, Memory,
    OutputMap, CORRECTION_RANGE, PAPER_DEGREES,
};

/// The model-file format string.
pub const FORMAT: &str = "piezo-fpi-model/1";

/// Largest model file read, bytes (1 MiB; a model file is about 2 kB).
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// What a model kind is and does: one implementation per kind, in its own file
/// under `method/kinds/`, listed once in [`crate::method::kinds::ALL`]. The kinds
/// built on play operators implement it through
/// [`Recipe`](crate::method::kinds::play::Recipe), which supplies what they share.
pub trait ModelKind: Sync {
    /// The name on the command line and in model files (`efpi`).
    fn name(&self) -> &'static str;
    /// The name the paper's method gets with this model (PI-FEM, FPI-FFEM, …).
    fn method(&self) -> &'static str;
    /// Whether calibration identifies a part of it from the preload, and so needs
    /// recordings whose force varies.
    fn uses_force(&self) -> bool;
    /// What the preload identifies, as a message that it cannot says it.
    fn force_part(&self) -> String {
        format!("k_f, the force coupling of the {} model,", self.name())
    }
    /// Whether its effective voltage runs through the model's `[coupling]` and dead
    /// zone (in the float model and in the firmware).
    fn coupled(&self) -> bool;
    /// Whether the paper identifies it at one preload (calibration warns about
    /// recordings at several).
    fn one_preload(&self) -> bool {
        false
    }
    /// Whether it takes a stack compliance (`fpi calibrate --compliance`).
    fn takes_compliance(&self) -> bool {
        false
    }
    /// Its calibration defaults.
    fn options(&self) -> Options;
    /// Calibrates it on checked recordings (`warnings`: what the checks found).
    fn calibrate(
        &self,
        data: &[CalibData],
        opt: &Options,
        warnings: Vec<String>,
    ) -> Result<HostModel>;
    /// Checks a model of this kind: the sections it uses present and valid, none it
    /// does not use; names the key that is wrong.
    fn validate(&self, m: &HostModel) -> Result<()>;
    /// The stack extension over a recording driven by its voltage and measured
    /// force, µm.
    fn simulate(&self, m: &HostModel, d: &CalibData) -> Vec<f64>;
    /// The stage for a drive `u(t)` (Part III): the coupled equation solved at every
    /// sample.
    fn predict(&self, m: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction>;
    /// The voltages within `[0, u_max]` that make the stage follow `target` (µm at
    /// times `t`), or why this kind cannot be inverted.
    fn invert(
        &self,
        m: &HostModel,
        fem: &FemMaps,
        t: &[f64],
        target: &[f64],
        u_max: f64,
    ) -> Result<Inversion>;
    /// Whether the firmware can run it (`fpi export`), or why not.
    fn export(&self, m: &HostModel) -> Result<()>;
    /// Its structure in a few words (`10 operators`).
    fn structure(&self, m: &HostModel) -> String;
    /// Its identified nonlinear parameters on one line, if it has any.
    fn parameters(&self, m: &HostModel) -> Option<String>;
}

/// A model kind: the handle a model holds (`Kind::Efpi`), reaching what the kind
/// does through [`ModelKind`]. Each kind's file names its constant; a name is
/// parsed ([`Kind::parse`], and in model files) against the one list of kinds,
/// [`crate::method::kinds::ALL`]. Two handles are equal when their names are.
#[derive(Clone, Copy)]
pub struct Kind(&'static dyn ModelKind);

impl Kind {
    /// The handle of a kind.
    pub const fn of(kind: &'static dyn ModelKind) -> Self {
        Self(kind)
    }
}

impl std::ops::Deref for Kind {
    type Target = dyn ModelKind;
    fn deref(&self) -> &Self::Target {
        self.0
    }
}

impl PartialEq for Kind {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Kind {}

impl std::hash::Hash for Kind {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name().hash(state);
    }
}

impl fmt::Debug for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Kind({})", self.name())
    }
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for Kind {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// What to calibrate and how.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The model kind.
    pub kind: Kind,
    /// Play operators including the `r = 0` one (`w0`).
    pub operators: usize,
    /// Stack compliance, µm/N (the kinds that take one).
    pub compliance: f64,
    /// Creep time constants, s (the kinds with creep).
    pub creep_taus: Vec<f64>,
    /// Fit a constant offset (recordings not zeroed at rest).
    pub offset: bool,
    /// Input domain of the model, V.
    pub input_max: f64,
    /// Branch model: degrees of the ascending and descending polynomials.
    pub branch_degrees: (usize, usize),
    /// Branch model: how turning points are remembered.
    pub branch_memory: Memory,
}

impl Options {
    /// The defaults for a kind ([`ModelKind::options`]).
    pub fn for_kind(kind: Kind) -> Self {
        kind.options()
    }

    /// What every kind's defaults start from: 10 operators, no compliance, no
    /// creep, no offset, the amplifier's span as the input domain, the paper's
    /// branch degrees with a stack of turning points.
    pub fn common(kind: Kind) -> Self {
        Self {
            kind,
            operators: 10,
            compliance: 0.0,
            creep_taus: Vec::new(),
            offset: false,
            input_max: AMPLIFIER_MAX_V,
            branch_degrees: PAPER_DEGREES,
            branch_memory: Memory::Stack,
        }
    }

    /// The same options with another operator count.
    pub fn with_operators(mut self, n: usize) -> Self {
        self.operators = n;
        self
    }
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
    #[serde(default = "no_pi", skip_serializing_if = "is_no_pi")]
    pub pi: PiSection,
    /// The branch polynomials (branch models only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch: Option<BranchSection>,
    /// LDPI weight slopes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ldpi: Option<LdpiParams>,
    /// Force coupling (the kinds whose effective voltage runs through it,
    /// [`ModelKind::coupled`]; branch: `k_f` alone).
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
    /// The kind checks its sections ([`ModelKind::validate`]).
    pub fn validate(&self) -> Result<()> {
        self.check_format()?;
        self.kind.validate(self)?;
        match &self.fem_correction {
            Some(c) => c.validate(),
            None => Ok(()),
        }
    }

    /// The top of the model's input range, V (`pi.input_max_v`, or
    /// `branch.input_max_v` for a model of branch polynomials).
    pub fn input_max_v(&self) -> f64 {
        match &self.branch {
            Some(b) => b.input_max_v,
            None => self.pi.input_max_v,
        }
    }

    /// Operators of the PI part.
    pub fn operators(&self) -> usize {
        self.pi.thresholds_v.len()
    }

    /// The model as the project's float model evaluates it.
    pub fn model(&self) -> Model<'static, f64> {
        let p = &self.pi;
        let uses_coupling = self.kind.coupled();
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
    const FORMAT: &'static str = FORMAT;
    fn format(&self) -> &str {
        &self.format
    }
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
