//! Offline feedforward compensation: the voltage sequence that makes the stage
//! follow a target trajectory, from a calibrated model and the stage's FEM maps.
//!
//! For every target sample: `x_pea = f_K⁻¹(x_fhps)`, the preload the FEM predicts
//! there, `F = f_F(x_pea)`, and the model's inverse at that force — in closed form
//! for pi, fpi, efpi and gpi (the closed-form inverse PI, the inverse output map,
//! the inverse soft dead zone), numerically for ldpi (whose weights depend on the
//! force). Targets outside the reachable stroke are clamped and counted.

use anyhow::{bail, Result};

use crate::fem::FemMaps;
use crate::hmodel::{dead_zone_inverse, HostModel, Kind};
use crate::predict;
use crate::reference::BankF64;

/// An inverted trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Inversion {
    /// Time, s.
    pub t: Vec<f64>,
    /// Voltage to apply, V.
    pub u: Vec<f64>,
    /// Target samples outside the reachable stroke (clamped to it).
    pub clamped_targets: usize,
    /// Samples whose voltage hit the amplifier's range.
    pub clamped_voltage: usize,
    /// The reachable stroke, µm of stage output.
    pub reachable: (f64, f64),
}

/// The stage output the model reaches at `u_top` on the loading curve (a slow
/// ramp from rest), µm.
pub fn reachable_top(model: &HostModel, fem: &FemMaps, u_top: f64, dt: f64) -> Result<f64> {
    let n = 2000;
    let t: Vec<f64> = (0..=n).map(|k| k as f64 * dt).collect();
    let u: Vec<f64> = (0..=n).map(|k| u_top * k as f64 / n as f64).collect();
    let p = predict::predict(model, fem, &t, &u)?;
    Ok(p.x_fhps[p.x_fhps.len() - 1])
}

/// Inverts a target trajectory `x_fhps(t)` (µm) into voltages within `[0, u_max]`.
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
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let lo = fem.stage_at(0.0);
    let hi = reachable_top(model, fem, u_max, dt)?;
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let f_ref = fem.rest_preload();
    let mut st = model.state(dt);
    let inv = model.inverse_pi(&st);
    let mut bank = BankF64::new(model.operators());
    let c = if model.kind.uses_force() {
        model.coupling.compliance_um_per_n
    } else {
        0.0
    };
    let mut out = Inversion {
        t: t.to_vec(),
        u: Vec::with_capacity(t.len()),
        clamped_targets: 0,
        clamped_voltage: 0,
        reachable: (lo, hi),
    };
    for &x in target {
        let xc = x.clamp(lo, hi);
        if (xc - x).abs() > 1e-9 {
            out.clamped_targets += 1;
        }
        let x_pea = fem.stack_for(xc);
        let force = fem.preload_at(x_pea);
        let u = if model.kind == Kind::Ldpi {
            // x(u) is non-decreasing: bisection on the voltage.
            let (mut a, mut b) = (0.0, u_max);
            for _ in 0..60 {
                let mid = 0.5 * (a + b);
                if model.peek(&st, mid, force, 0.0, f_ref).x < x_pea {
                    a = mid;
                } else {
                    b = mid;
                }
            }
            0.5 * (a + b)
        } else {
            let z = x_pea + c * (force - f_ref);
            let y = model.output.invert(z) - model.offset_um;
            let held: f64 = model
                .creep
                .iter()
                .zip(&st.m)
                .zip(&st.rate)
                .map(|((cr, m), r)| cr.gain_um_per_v * (1.0 - r) * m)
                .sum();
            let uh = inv.apply(&mut bank, y - held);
            match model.kind {
                Kind::Fpi | Kind::Efpi => {
                    model.preload_offset(force).0
                        + dead_zone_inverse(model.dead_zone_softness_v, uh)
                }
                _ => uh,
            }
        };
        let uc = u.clamp(0.0, u_max);
        if (uc - u).abs() > 1e-9 {
            out.clamped_voltage += 1;
        }
        // Advance the model with what is applied; realign the inverse memory if that
        // is not what the inverse asked for.
        let p = model.peek(&st, uc, force, 0.0, f_ref);
        model.commit(&mut st, p.uh);
        if (uc - u).abs() > 1e-9 && model.kind != Kind::Ldpi {
            let fwd = BankF64 {
                y: st.y.clone(),
                last: p.uh,
            };
            let mut pi_prime = crate::reference::PiF64 {
                w0: model.pi.w0_um_per_v,
                r: model.pi.thresholds_v.clone(),
                w: model.pi.weights_um_per_v.clone(),
                input_max: model.pi.input_max_v,
            };
            pi_prime.w0 += model
                .creep
                .iter()
                .zip(&st.rate)
                .map(|(cr, r)| cr.gain_um_per_v * r)
                .sum::<f64>();
            pi_prime.resync(&fwd, &mut bank);
        }
        out.u.push(uc);
    }
    Ok(out)
}
