//! How far the fixed-point core is from its f64 reference on the recorded data.
//!
//! The contract (checked by `tests/fixed_vs_f64.rs`, printed by the demo):
//!
//! * stack extension (forward FPI, virtual sensor): within [`BOUND_X_UM`] = 1 nm;
//! * effective voltage the setpoint produces, `û = g(u - U_p(F))` (what drives the
//!   stack): within [`BOUND_U_V`] = one LSB of a 16-bit DAC over 0–150 V (2.29 mV);
//! * the amplifier setpoint itself: within the same LSB wherever the stack responds
//!   (`g' >= 0.5`, i.e. outside the foot of a soft dead zone). In the foot the stack
//!   hardly moves per volt (du/dx reaches ~225 V/µm), so rounding the input
//!   extension to its 15 pm LSB alone shifts the required voltage by millivolts
//!   that move the stack by picometres; there the effective-voltage bound is the
//!   meaningful one. With the hard dead zone (the paper's model) `g' = 1`.
//!
//! Both implementations get the recorded samples (the fixed-point one after
//! quantising them to `I16F16`) and the embedded firmware model (the f64 one with
//! its unquantised engineering values), so the difference is what fixed point costs.

use std::path::{Path, PathBuf};

use fpi_firmware::board::factory_model::{self, CREEP_TERMS, OPERATORS};
use piezo_fpi::control::{ControllerConfig, ControllerParts, ForceChannel, Interval, Supervision};
use piezo_fpi::fpi::CreepMemory;
use piezo_fpi::play::PlayBank;
use piezo_fpi::q::{Micrometres, Newtons, Volts};

use piezo_sim::control::Controller;
use piezo_sim::model::DeadZone;

use crate::data::{self, DataError};
use crate::model_file::FirmwareModel;

/// Largest tolerated stack-extension difference, µm (1 nm).
pub const BOUND_X_UM: f64 = 1e-3;
/// Largest tolerated setpoint difference, V: one LSB of 16 bits over 150 V.
pub const BOUND_U_V: f64 = 150.0 / 65535.0;

/// Worst differences found in one file.
#[derive(Debug, Clone, PartialEq)]
pub struct FileAccuracy {
    /// The recording.
    pub path: PathBuf,
    /// Samples compared.
    pub samples: usize,
    /// Largest |Δ stack extension| (forward FPI / virtual sensor), µm.
    pub max_dx_um: f64,
    /// Largest |Δ setpoint| where the stack responds (`g' >= 0.5`), V.
    pub max_du_v: f64,
    /// Largest |Δ effective voltage| (what the setpoints drive the stack with), V.
    pub max_duh_v: f64,
    /// Samples in the foot of the soft dead zone (`g' < 0.5`).
    pub foot_samples: usize,
    /// Steps the output limiter acted in (realigning the inverse memory).
    pub limited_steps: usize,
}

/// The embedded model, parsed for the f64 side (once).
pub fn embedded_model() -> &'static FirmwareModel {
    static MODEL: std::sync::OnceLock<FirmwareModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| {
        match FirmwareModel::parse(factory_model::MODEL_TOML, factory_model::MODEL_FILE) {
            Ok(m) => m,
            Err(e) => panic!("the embedded model was validated by build.rs: {e}"),
        }
    })
}

/// The embedded controller with its supervision widened — the reference range to
/// the whole `f_K⁻¹` grid, the force tolerance and dynamic limit to 1000 N — so the recordings
/// (which include a 3 kHz chirp where the stage's dynamics pull the force far
/// from the static FEM map) exercise the arithmetic rather than the safe state;
/// and its f64 twin with the same settings.
pub fn controllers() -> (factory_model::Controller, Controller<'static, f64>) {
    let c = &factory_model::CONTROLLER;
    let reference = Interval {
        lo: Micrometres::from_raw(c.f_k_inv().x_min()),
        hi: Micrometres::from_raw(c.f_k_inv().x_max()),
    };
    let fixed = ControllerConfig::new(ControllerParts {
        fpi: *c.fpi(),
        f_f: *c.f_f(),
        f_k: *c.f_k(),
        f_k_inv: *c.f_k_inv(),
        limits: *c.limits(),
        supervision: Supervision {
            reference,
            force_tolerance: Newtons::from_num(1000),
            channel: ForceChannel {
                dynamic_limit: Newtons::from_num(1000),
                ..c.supervision().channel
            },
            ..c.supervision()
        },
    })
    .unwrap_or_else(|e| panic!("widening the reference range: {e}"));
    let Some(mut f64c) = embedded_model().controller() else {
        panic!("the embedded model was validated by build.rs")
    };
    f64c.reference = (reference.lo.to_num(), reference.hi.to_num());
    f64c.force_tolerance = 1000.0;
    f64c.dynamic_limit = 1000.0;
    (fixed, f64c)
}

fn q(v: f64) -> piezo_fpi::q::Volts {
    Volts::from_num(v)
}

/// Worst differences of two setpoints at one sample.
#[derive(Default)]
struct SetpointError {
    du: f64,
    duh: f64,
    foot: usize,
}

impl SetpointError {
    /// Compares the fixed-point setpoint with the f64 one at force `f`.
    fn add(&mut self, c: &Controller<'_, f64>, u_fixed: f64, u_ref: f64, f: f64) {
        let up = c.model.preload_offset(f).0;
        let g = |u: f64| c.model.dead_zone.apply(u - up).0;
        self.duh = self.duh.max((g(u_fixed) - g(u_ref)).abs());
        let h = 1e-3;
        let slope = (g(u_ref + h) - g(u_ref - h)) / (2.0 * h);
        if slope >= 0.5 || matches!(c.model.dead_zone, DeadZone::Hard) {
            self.du = self.du.max((u_fixed - u_ref).abs());
        } else {
            self.foot += 1;
        }
    }
}

/// Forward and inverse FPI on a preload-rig file: stack extension from (u, F),
/// and voltage for the measured extension at the measured force. The forward and
/// inverse sides each keep their own memories (operators and creep): each is
/// driven by its own history, the measured voltage or the voltage it asks for.
pub fn rig_file(path: &Path) -> Result<FileAccuracy, DataError> {
    let rig = data::read_rig(path)?;
    let (fixed, f64c) = controllers();
    let fpi = fixed.fpi();
    let (m, f_ref) = (&f64c.model, f64c.force_ref);
    let (mut fb, mut ib) = (PlayBank::<OPERATORS>::new(), PlayBank::<OPERATORS>::new());
    let (mut cf, mut ci) = (
        CreepMemory::<CREEP_TERMS>::new(),
        CreepMemory::<CREEP_TERMS>::new(),
    );
    // The f64 side: the forward model's state, and the inverse side's (whose
    // forward steps advance its creep memory).
    let (mut fst, mut ist) = (m.state(f64c.dt), m.state(f64c.dt));
    let inv = m.inverse_pi(&ist);
    let mut ib64 = inv.at_rest();
    // Scratch forward bank that advances the inverse side's creep memory.
    let mut sb = PlayBank::<OPERATORS>::new();
    let mut dx = 0.0f64;
    let mut err = SetpointError::default();
    for k in 0..rig.t.len() {
        let (u, f, x) = (rig.u[k], rig.f[k], rig.x[k]);
        let terms = fpi.force_terms(Newtons::from_num(f));
        let xf = fpi.forward(&mut fb, &mut cf, q(u), &terms).to_num::<f64>();
        let x64 = m.step(&mut fst, u, f, f_ref);
        dx = dx.max((xf - x64).abs());
        let uf = fpi.inverse(&mut ib, &ci, Micrometres::from_num(x), &terms);
        let (u64_, _) = m.inverse(&inv, &mut ib64, &ist, x, f, f_ref);
        err.add(&f64c, uf.to_num::<f64>(), u64_, f);
        fpi.forward(&mut sb, &mut ci, uf, &terms);
        m.step(&mut ist, u64_, f, f_ref);
    }
    Ok(FileAccuracy {
        path: path.to_path_buf(),
        samples: rig.t.len(),
        max_dx_um: dx,
        max_du_v: err.du,
        max_duh_v: err.duh,
        foot_samples: err.foot,
        limited_steps: 0,
    })
}

/// The whole control step on a stage file: reference = recorded stage position
/// (held inside the reachable range), force = recorded force, through the force
/// channel's split on both sides.
pub fn stage_file(path: &Path) -> Result<FileAccuracy, DataError> {
    let run = data::read_stage(path)?;
    let (fixed, f64c) = controllers();
    let mut st = fixed.initial_state();
    let mut st64 = f64c.initial_state();
    let (lo, hi) = f64c.reference;
    let (mut dx, mut limited) = (0.0f64, 0usize);
    let mut err = SetpointError::default();
    for k in 0..run.t.len() {
        let x_ref = run.x[k].clamp(lo, hi);
        let f = run.f[k];
        let o = fixed.step(&mut st, Micrometres::from_num(x_ref), Newtons::from_num(f));
        let o64 = f64c.step(&mut st64, x_ref, f);
        if o.fault.is_some() || o64.fault.is_some() {
            return Err(DataError::file(
                path,
                format!(
                    "sample {k}: a controller faulted ({:?} / {:?})",
                    o.fault, o64.fault
                ),
            ));
        }
        // The effective voltage under the force the models used (the force
        // channel's feedforward).
        err.add(&f64c, o.voltage.to_num::<f64>(), o64.voltage, o64.force);
        dx = dx.max((o.x_pea_est.to_num::<f64>() - o64.x_pea_est).abs());
        limited += o.limited as usize;
    }
    Ok(FileAccuracy {
        path: path.to_path_buf(),
        samples: run.t.len(),
        max_dx_um: dx,
        max_du_v: err.du,
        max_duh_v: err.duh,
        foot_samples: err.foot,
        limited_steps: limited,
    })
}

/// Every `pea-rig/` and `stage-a/` recording the project carries.
pub fn all_files() -> Result<Vec<FileAccuracy>, DataError> {
    let mut out = Vec::new();
    for p in data::datasets_in("pea-rig") {
        out.push(rig_file(&p)?);
    }
    for p in data::datasets_in("stage-a") {
        if p.to_string_lossy().contains("fem.csv") {
            continue;
        }
        out.push(stage_file(&p)?);
    }
    Ok(out)
}
