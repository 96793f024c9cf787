//! Offline feedforward compensation: the voltage sequence that makes the stage
//! follow a target trajectory, from a calibrated model and the stage's FEM maps.
//!
//! For every target sample: `x_pea = f_K⁻¹(x_fhps)`, the preload the FEM predicts
//! there, `F = f_F(x_pea)`, and the model's inverse at that force — in closed form
//! where the kind has one (the closed-form inverse PI, the inverse output map, the
//! inverse soft dead zone), by search where its weights depend on the force
//! (ldpi); [`invert`] asks the model's kind ([`ModelKind::invert`]), which may
//! refuse. Targets outside the reachable stroke are clamped and counted.
//!
//! [`ModelKind::invert`]: crate::method::model::ModelKind::invert

use anyhow::{bail, Result};

use crate::data::fem::FemMaps;
use crate::method::limits::within;
use crate::method::model::HostModel;
use crate::method::predict::{input_range, reachable_top};

pub use crate::method::series::Inversion;

/// How a model is inverted at each target sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Inverse {
    /// The closed-form inverse of the float model (the firmware's).
    ClosedForm,
    /// Bisection on the voltage (the extension rises with it): for weights that
    /// depend on the force.
    Search,
}

/// Inverts a target trajectory `x_fhps(t)` (µm) into voltages within `[0, u_max]`
/// (V; `u_max` finite, > 0 and within the model's [`input_range`]) as the model's
/// kind does it. Every voltage is finite, or this is an error naming the target
/// sample.
pub fn invert(
    model: &HostModel,
    fem: &FemMaps,
    t: &[f64],
    target: &[f64],
    u_max: f64,
) -> Result<Inversion> {
    if t.len() != target.len() || t.len() < 2 {
        bail!("a target needs at least two samples of time and position");
    }
    model.kind.invert(model, fem, t, target, u_max)
}

/// [`invert`] on the float model ([`HostModel::model`]), each sample by `how`.
pub fn by_model(
    model: &HostModel,
    fem: &FemMaps,
    t: &[f64],
    target: &[f64],
    u_max: f64,
    how: Inverse,
) -> Result<Inversion> {
    let (_, top) = input_range(model);
    within(
        "--u-max",
        u_max,
        "V",
        top,
        "the model's input range and the amplifier span",
    )?;
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let lo = fem.stage_at(0.0);
    let hi = reachable_top(model, fem, u_max, dt)?;
    if !(lo.is_finite() && hi.is_finite()) {
        bail!("the model predicts no finite stroke (stage output {lo}..{hi} µm at 0..{u_max} V)");
    }
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let f_ref = fem.rest_preload();
    let maps = fem.maps();
    let m = model.model();
    let mut st = m.state(dt);
    let prime = m.prime(&st);
    let inv = prime.inverse();
    let mut bank = inv.at_rest();
    let mut out = Inversion {
        t: t.to_vec(),
        u: Vec::with_capacity(t.len()),
        clamped_targets: 0,
        clamped_voltage: 0,
        reachable: (lo, hi),
    };
    let search = how == Inverse::Search;
    for &x in target {
        let xc = x.clamp(lo, hi);
        if (xc - x).abs() > 1e-9 {
            out.clamped_targets += 1;
        }
        let x_pea = maps.stack_for(xc);
        let force = maps.preload_at(x_pea);
        let u = if search {
            // The weights depend on the force: x(u) is non-decreasing, bisect on u.
            let (mut a, mut b) = (0.0, u_max);
            for _ in 0..60 {
                let mid = 0.5 * (a + b);
                if m.peek(&st, mid, force, 0.0, f_ref).x < x_pea {
                    a = mid;
                } else {
                    b = mid;
                }
            }
            0.5 * (a + b)
        } else {
            m.inverse(&inv, &mut bank, &st, x_pea, force, f_ref).0
        };
        if u.is_nan() {
            bail!(
                "target sample {} ({x} µm): the model's inverse gives no voltage (NaN)",
                out.u.len() + 1
            );
        }
        let uc = u.clamp(0.0, u_max);
        let clamped = (uc - u).abs() > 1e-9;
        out.clamped_voltage += clamped as usize;
        // Advance the model with what is applied; realign the inverse memory if that
        // is not what the inverse asked for.
        m.step(&mut st, uc, force, f_ref);
        if clamped && !search {
            prime.resync(&st.bank, &mut bank);
        }
        out.u.push(uc);
    }
    Ok(out)
}
