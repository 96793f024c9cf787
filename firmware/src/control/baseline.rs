//! The uncompensated mode's straight-line drive, derived from the running model.
//!
//! A fair baseline for the hysteresis compensation: the line through the
//! controller's own voltages at 5 % and 95 % of the stroke on the loading curve,
//! so it is right at the ends and shows the hysteresis in between, as an amplifier
//! driven without a hysteresis model would (the paper's comparison). Computed once
//! per model, in the link task (about 4 000 control steps).

use piezo_fpi::control::{ControllerConfig, ForceSource, LinearDrive};
use piezo_fpi::error::{Field, Invalid, ModelError};
use piezo_fpi::fpi::Shape;
use piezo_fpi::q::{Micrometres, Newtons};

/// Steps of the walk up the loading curve (slow enough that the slew limit never bites).
const STEPS: i64 = 4000;

/// The straight line through the compensated voltages at 5 % and 95 % of the
/// model's stroke, walked up slowly from rest with the FEM-predicted force.
pub fn drive<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
    cfg: &ControllerConfig<'a, N, C, G, H>,
) -> Result<LinearDrive, Invalid> {
    let predicted = cfg.with_force_source(ForceSource::Predicted);
    let mut st = predicted.initial_state();
    let r = cfg.reference();
    let span = r.hi.to_bits() as i64 - r.lo.to_bits() as i64;
    let (lo, hi) = (
        r.lo.to_bits() as i64 + span / 20,
        r.lo.to_bits() as i64 + span * 19 / 20,
    );
    let (mut u_lo, mut u_hi) = (0.0, 0.0);
    for k in 0..=STEPS {
        let x = Micrometres::from_bits((lo + (hi - lo) * k / STEPS) as i32);
        let out = predicted.step(&mut st, x, Newtons::ZERO);
        if k == 0 {
            u_lo = out.voltage.to_num::<f64>();
        }
        u_hi = out.voltage.to_num::<f64>();
    }
    let um = |bits: i64| Micrometres::from_bits(bits as i32).to_num::<f64>();
    LinearDrive::through(um(lo), u_lo, um(hi), u_hi)
        .ok_or(Invalid::at(Field::Model, ModelError::NotRepresentable))
}
