//! The coupled equation of the FPI-FFEM method (Actuators 2025, 14(8):411, Table 1, step 4a): at
//! every sample, the stack extension that the model gives under the preload the
//! stage puts on the stack at that very extension,
//!
//! ```text
//! x_pea = X(u, f_F(x_pea))        X: the model, f_F: the FEM preload map
//! ```
//!
//! `φ(x) = X(u, f_F(x)) − x` is strictly decreasing (more extension, more preload,
//! less effective voltage), so the root is unique. It is found by Newton's method
//! with the exact derivative [`Model::peek`] returns, warm-started by the caller and
//! safeguarded by the bracket the sign of `φ` gives.
//!
//! * For the piecewise-linear models (pi, ldpi, fpi with the FEM's linear
//!   interpolation) a Newton step that stays inside one linear piece lands exactly
//!   on the root: typically one step and one check per sample.
//! * For the smooth models (efpi: soft dead zone, output saturation) a step `δ`
//!   inside one smooth piece lands within `|φ''|·δ²/(2|φ'|)` of the root, and
//!   [`Model::peek`] gives `φ''` exactly: the step is final without another
//!   evaluation once four times that estimate is below the smooth tolerance.
//!
//! The tolerances are those of the number type: 10⁻¹³ µm (bracket and step) and
//! 10⁻¹⁴ µm (smooth) in `f64`, a few ulps of the extension in `f32`.

use crate::fem::Fem;
use crate::model::{Model, State};
use crate::real::Real;

/// What loads the stack in the coupled equation: the force on the stack at an
/// extension guess, its slope, and whether two guesses fall in the same linear
/// piece (so that a Newton step inside it is exact for piecewise-linear models).
pub trait PreloadMap<F> {
    /// The force (N) at extension `x` (µm) and its slope (N/µm).
    fn preload_with_slope(&self, x: F) -> (F, F);
    /// `a` and `b` lie in one linear piece of the map.
    fn same_segment(&self, a: F, b: F) -> bool;
}

impl<F: Real> PreloadMap<F> for Fem<'_, F> {
    #[inline]
    fn preload_with_slope(&self, x: F) -> (F, F) {
        Fem::preload_with_slope(self, x)
    }
    #[inline]
    fn same_segment(&self, a: F, b: F) -> bool {
        Fem::same_segment(self, a, b)
    }
}

/// A linear spring in series with the stack's free stroke: the force
/// `force + stiffness·(x − at)` (N) on a stack whose free stroke is `x` (µm)
/// while its end sits at `at` (µm) — the stack's own stiffness in the
/// electromechanical model ([`crate::electromech`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spring<F> {
    /// Force when the free stroke equals `at`, N.
    pub force: F,
    /// Stiffness, N/µm.
    pub stiffness: F,
    /// Where the stack's end is, µm.
    pub at: F,
}

impl<F: Real> PreloadMap<F> for Spring<F> {
    #[inline]
    fn preload_with_slope(&self, x: F) -> (F, F) {
        (self.force + self.stiffness * (x - self.at), self.stiffness)
    }
    #[inline]
    fn same_segment(&self, _: F, _: F) -> bool {
        true
    }
}

/// Most model evaluations of one solve.
pub const MAX_EVALUATIONS: usize = 100;

/// (bracket width, smooth-step error, step size) below which a solve is done, µm.
fn tolerances<F: Real>(x: F) -> (F, F, F) {
    if F::EPSILON < F::of(1e-10) {
        (
            F::of(1e-13),
            F::of(1e-14),
            F::of(1e-13) * (F::ONE + x.abs()),
        )
    } else {
        let ulp = F::EPSILON * (F::ONE + x.abs());
        (F::of(16.0) * ulp, F::of(4.0) * ulp, F::of(2.0) * ulp)
    }
}

/// A solved sample: the extension, the effective voltage to commit, and the
/// number of model evaluations it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution<F> {
    /// Stack extension, µm.
    pub x: F,
    /// Effective voltage to [`Model::commit`], V.
    pub uh: F,
    /// Model evaluations.
    pub evaluations: usize,
}

/// Solves one sample's coupled equation for voltage `u` from `guess`, the stack
/// loaded by `fem` (the FEM's preload map, or the stack's own [`Spring`]); `f_ref`
/// is the compliance reference force (the FEM's rest preload). Commits nothing.
pub fn coupled<F: Real, M: PreloadMap<F>>(
    model: &Model<'_, F>,
    st: &State<F>,
    u: F,
    fem: &M,
    f_ref: F,
    guess: F,
) -> Solution<F> {
    let (mut lo, mut hi) = (-F::INFINITY, F::INFINITY);
    let mut x = guess;
    let mut best = (F::INFINITY, x, F::ZERO);
    let done = |x: F, uh: F, evaluations: usize| Solution { x, uh, evaluations };
    for it in 1..=MAX_EVALUATIONS {
        let (bracket, smooth, step_tol) = tolerances(x);
        let (f, df) = fem.preload_with_slope(x);
        let p = model.peek(st, u, f, df, f_ref);
        let phi = p.x - x;
        if phi.abs() < best.0 {
            best = (phi.abs(), x, p.uh);
        }
        if phi == F::ZERO || (hi - lo) < bracket {
            return done(x, p.uh, it);
        }
        if phi > F::ZERO {
            lo = x;
        } else {
            hi = x;
        }
        let dphi = p.dx - F::ONE;
        let mut next = x - phi / dphi;
        // Piecewise-linear models: a step that stays in this linear piece is the root.
        if let Some((e_lo, e_hi)) = p.linear_in {
            let e_next = p.e.0 + p.e.1 * (next - x);
            if next > lo && next < hi && e_next > e_lo && e_next < e_hi && fem.same_segment(x, next)
            {
                return done(next, e_next.clamp_to(F::ZERO, model.pi.input_max), it);
            }
        }
        // Smooth models: a step whose error estimate is negligible, inside this
        // smooth piece, is final.
        if let Some((u_lo, u_hi)) = p.smooth_in {
            let step = next - x;
            let uh = p.uh + p.duh * step;
            if F::of(2.0) * p.ddx.abs() * step * step <= smooth * dphi.abs()
                && next > lo
                && next < hi
                && uh > u_lo
                && uh < u_hi
                && fem.same_segment(x, next)
            {
                return done(next, uh, it);
            }
        }
        if !(next > lo && next < hi && next.is_finite()) {
            let one = F::ONE;
            next = match (lo.is_finite(), hi.is_finite()) {
                (true, true) => (lo + hi) / F::of(2.0),
                (true, false) => lo + phi.abs().max(one),
                (false, true) => hi - phi.abs().max(one),
                (false, false) => x,
            };
        }
        if (next - x).abs() <= step_tol {
            let (f, df) = fem.preload_with_slope(next);
            let p = model.peek(st, u, f, df, f_ref);
            return done(next, p.uh, it + 1);
        }
        x = next;
    }
    done(best.1, best.2, MAX_EVALUATIONS)
}

/// A warm start for the next sample: the last three solutions extrapolated
/// quadratically.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WarmStart<F> {
    last: [F; 3],
}

impl<F: Real> WarmStart<F> {
    /// The guess for the next sample.
    pub fn guess(&self) -> F {
        let [x, x1, x2] = self.last;
        F::of(3.0) * (x - x1) + x2
    }
    /// Records a solution.
    pub fn push(&mut self, x: F) {
        self.last = [x, self.last[0], self.last[1]];
    }
}
