//! Part III of the method: predicting the stage from its design (seed 000, Table 1,
//! Step 4). For every sample of a drive signal, solve
//!
//! ```text
//! x_pea = X(u, f_F(x_pea))        X: the calibrated model, f_F: the FEM preload map
//! ```
//!
//! committing the model's memory only for the solution, then `x_fhps = f_K(x_pea)`.
//!
//! `φ(x) = X(u, f_F(x)) − x` is strictly decreasing (more extension, more preload,
//! less effective voltage), so the root is unique. It is found by Newton's method
//! with the exact derivative [`HostModel::peek`] returns, warm-started at the
//! previous sample's solution and safeguarded by the bracket the sign of `φ`
//! gives. For the piecewise-linear models (pi, ldpi, fpi with the FEM's linear
//! interpolation) `φ` is piecewise linear, so Newton lands exactly on the root
//! once it is in the right piece: typically one step and one check per sample.
//!
//! For the smooth models (efpi: soft dead zone, output saturation) a Newton step
//! `δ` from `x` that stays inside one smooth piece of `φ` (no operator switch, no
//! FEM knot, no clamp in between) lands within `|φ''|·δ²/(2|φ'|)` of the root, and
//! [`HostModel::peek`] gives `φ''` exactly: the step is accepted without evaluating
//! the model again once four times that estimate is below [`SMOOTH_TOL_UM`]. The
//! warm start extrapolates the last three solutions quadratically, so in steady
//! motion one evaluation per sample is the rule.

use anyhow::{bail, Result};

use crate::fem::FemMaps;
use crate::hmodel::{HostModel, ModelState};

/// A predicted run.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// Time, s.
    pub t: Vec<f64>,
    /// Drive voltage, V.
    pub u: Vec<f64>,
    /// Stack extension, µm.
    pub x_pea: Vec<f64>,
    /// Preload on the stack, N.
    pub preload: Vec<f64>,
    /// Stage output, µm.
    pub x_fhps: Vec<f64>,
    /// Solver iterations, total.
    pub iterations: usize,
}

/// Error (µm) below which a Newton step inside a smooth piece is final: four times
/// the step's estimated error `|φ''|·δ²/(2|φ'|)` must be below it. The bisection
/// fallback stops at 10⁻¹³ µm.
pub const SMOOTH_TOL_UM: f64 = 1e-14;

/// Solves one sample's coupled equation from `guess`; returns the extension, the
/// effective voltage to commit and the number of model evaluations.
pub fn solve(
    model: &HostModel,
    st: &ModelState,
    u: f64,
    fem: &FemMaps,
    f_ref: f64,
    guess: f64,
) -> (f64, f64, usize) {
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let mut x = guess;
    let mut best = (f64::INFINITY, x, 0.0);
    for it in 1..=100 {
        let (f, df) = fem.preload_with_slope(x);
        let p = model.peek(st, u, f, df, f_ref);
        let phi = p.x - x;
        if phi.abs() < best.0 {
            best = (phi.abs(), x, p.uh);
        }
        if phi == 0.0 || (hi - lo) < 1e-13 {
            return (x, p.uh, it);
        }
        if phi > 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let dphi = p.dx - 1.0;
        let mut next = x - phi / dphi;
        // Piecewise-linear models: a step that stays in this linear piece is the root.
        if let Some((e_lo, e_hi)) = p.linear_in {
            let e_next = p.e.0 + p.e.1 * (next - x);
            if next > lo && next < hi && e_next > e_lo && e_next < e_hi && fem.same_segment(x, next)
            {
                let uh = e_next.clamp(0.0, model.pi.input_max_v);
                return (next, uh, it);
            }
        }
        // Smooth models: a step whose error estimate is negligible, inside this
        // smooth piece, is final.
        if let Some((u_lo, u_hi)) = p.smooth_in {
            let step = next - x;
            let uh = p.uh + p.duh * step;
            if 2.0 * p.ddx.abs() * step * step <= SMOOTH_TOL_UM * dphi.abs()
                && next > lo
                && next < hi
                && uh > u_lo
                && uh < u_hi
                && fem.same_segment(x, next)
            {
                return (next, uh, it);
            }
        }
        if !(next > lo && next < hi && next.is_finite()) {
            next = match (lo.is_finite(), hi.is_finite()) {
                (true, true) => 0.5 * (lo + hi),
                (true, false) => lo + phi.abs().max(1.0),
                (false, true) => hi - phi.abs().max(1.0),
                (false, false) => x,
            };
        }
        if (next - x).abs() <= 1e-13 * (1.0 + x.abs()) {
            let (f, df) = fem.preload_with_slope(next);
            let p = model.peek(st, u, f, df, f_ref);
            return (next, p.uh, it + 1);
        }
        x = next;
    }
    (best.1, best.2, 100)
}

/// Predicts the stage for a drive `u(t)`: the coupled solve at every sample.
pub fn predict(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
    if t.len() != u.len() || t.len() < 2 {
        bail!("a drive needs at least two samples of time and voltage");
    }
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let mut st = model.state(dt);
    let f_ref = fem.rest_preload();
    let n = u.len();
    let (mut xs, mut fs, mut ks) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    // The last three solutions: the warm start extrapolates them quadratically.
    let (mut x, mut x1, mut x2) = (0.0, 0.0, 0.0);
    let mut iterations = 0;
    for &uk in u {
        let guess = 3.0 * (x - x1) + x2;
        let (xk, uh, it) = solve(model, &st, uk, fem, f_ref, guess);
        model.commit(&mut st, uh);
        iterations += it;
        (x, x1, x2) = (xk, x, x1);
        xs.push(xk);
        fs.push(fem.preload_at(xk));
        ks.push(fem.stage_at(xk));
    }
    Ok(Prediction {
        t: t.to_vec(),
        u: u.to_vec(),
        x_pea: xs,
        preload: fs,
        x_fhps: ks,
        iterations,
    })
}

/// Error figures of a prediction against a measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    /// Mean absolute error, µm.
    pub mae: f64,
    /// Root-mean-square error, µm.
    pub rmse: f64,
    /// Largest absolute error (MTE), µm.
    pub mte: f64,
}

/// MAE, RMSE and MTE of `predicted − measured`.
pub fn metrics(predicted: &[f64], measured: &[f64]) -> Metrics {
    let n = predicted.len().min(measured.len()).max(1) as f64;
    let (mut a, mut s, mut m) = (0.0, 0.0, 0.0f64);
    for (p, q) in predicted.iter().zip(measured) {
        let e = p - q;
        a += e.abs();
        s += e * e;
        m = m.max(e.abs());
    }
    Metrics {
        mae: a / n,
        rmse: (s / n).sqrt(),
        mte: m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::{self, Options};
    use crate::data;
    use crate::hmodel::Kind;

    /// Bisection on the coupled equation: slow, but obviously right.
    fn bisect(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Vec<f64> {
        let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
        let mut st = model.state(dt);
        let f_ref = fem.rest_preload();
        u.iter()
            .map(|&uk| {
                let (mut lo, mut hi) = (-20.0, 40.0);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    let (f, df) = fem.preload_with_slope(mid);
                    if model.peek(&st, uk, f, df, f_ref).x > mid {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let x = 0.5 * (lo + hi);
                let (f, df) = fem.preload_with_slope(x);
                let p = model.peek(&st, uk, f, df, f_ref);
                model.commit(&mut st, p.uh);
                x
            })
            .collect()
    }

    #[test]
    fn newton_solve_equals_bisection_for_every_kind() {
        let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
        let rig = calibrate::load(&data::datasets_in("pea-rig")[6..9], None).unwrap();
        let run = data::read_stage(&data::dataset("stage-a/sine_15Hz.csv")).unwrap();
        for kind in [Kind::Pi, Kind::Ldpi, Kind::Fpi, Kind::Efpi] {
            let m = calibrate::calibrate(&rig, &Options::for_kind(kind)).unwrap();
            let fast = predict(&m, &fem, &run.t, &run.u).unwrap();
            let slow = bisect(&m, &fem, &run.t, &run.u);
            let worst = fast
                .x_pea
                .iter()
                .zip(&slow)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            println!(
                "{kind}: worst |Newton - bisection| {worst:.2e} um, {:.2} evaluations/sample",
                fast.iterations as f64 / run.t.len() as f64
            );
            assert!(worst < 1e-12, "{kind}: {worst} um");
            assert!(
                fast.iterations < 5 * run.t.len(),
                "{kind}: {} iterations",
                fast.iterations
            );
        }
    }
}
