//! A virtual stage of several axes (`piezo_sim::axes`: each axis its stack,
//! mode and sensors, the flexure's couplings between them) behind one virtual
//! I/O link per axis: what each link's sensors read at rest, and one sample
//! of the stage after each control tick with the amplifiers' outputs.
//!
//! The firmware's multi-axis tests and the host's closed-loop XY measurements
//! drive the control loop's axes through it.

use piezo_fpi::decoupling::{Decoupling, Matrix, Preload};
use piezo_sim::axes::{Axes, AxisSample, Coupling, MAX_AXES};

use crate::emulation::virtual_io::SimLink;

/// Leaves the stage's readings at rest on `links` (axis `i` on `links[i]`).
pub fn prime<const N: usize>(stage: &mut Axes<'_, N>, links: &[&SimLink; N]) {
    for (i, link) in links.iter().enumerate() {
        let rest = stage.stages()[i].rest_force();
        link.set_force(stage.sense_force(i, rest));
        link.set_position(stage.sense_position(i));
    }
}

/// One sample of the stage with each link's amplifier output (0 V where its
/// amplifier is off); each link's sensors then read it. Each axis's sample.
pub fn step<const N: usize>(stage: &mut Axes<'_, N>, links: &[&SimLink; N]) -> [AxisSample; N] {
    let u = links.map(|l| match l.output() {
        (v, true) => v,
        (_, false) => 0.0,
    });
    let s = stage.step(u);
    for (i, link) in links.iter().enumerate() {
        link.set_force(stage.sense_force(i, s[i].stack.force_n));
        link.set_position(stage.sense_position(i));
    }
    s
}

/// A stage's true couplings as the board takes them (`Order::Decoupling`):
/// the input matrix undoing its sensors' cross-talk among its first `n`
/// axes, the output matrix undoing its cross gains, its stacks' preload
/// coupling. What a measurement of the coupling would find; `None` where the
/// board would refuse an entry.
pub fn true_decoupling(c: &Coupling, n: usize) -> Option<Decoupling<MAX_AXES>> {
    let as64 = |m: [[f32; MAX_AXES]; MAX_AXES]| m.map(|r| r.map(f64::from));
    let t = f64::from(c.sensor_crosstalk);
    let talk = core::array::from_fn(|i| {
        core::array::from_fn(|j| if i != j && i < n && j < n { t } else { 0.0 })
    });
    Some(Decoupling {
        input: Matrix::undoing(talk).ok()?,
        output: Matrix::undoing(as64(c.cross_um_per_um)).ok()?,
        preload: Preload::from_f64(as64(c.preload_n_per_um)).ok()?,
    })
}
