//! The one-sided play operator and the Prandtl–Ishlinskii model in floating point
//! (Actuators 2025, 14(8):411, eqs. 1–4), with its closed-form inverse.
//!
//! [`play`] is the operator, written once for every float type: the host's
//! reference, its calibration columns, the coupled solver and the virtual stage all
//! advance their operators through it.

use heapless::Vec;

use crate::real::Real;

/// Most play operators of a model (the core's limit).
pub const MAX_OPERATORS: usize = 32;

/// Operator parameters or outputs, one per operator.
pub type Values<F> = Vec<F, MAX_OPERATORS>;

/// One step of a one-sided play operator, eq. (3): `y' = max(u - r, min(u, y))`.
///
/// The output stays in the band `[u - r, u]`: dragged up by the lower edge while
/// the input rises, down by the upper edge while it falls. It is the composition
/// of its two halves, [`drag`] and [`push`].
#[inline(always)]
pub fn play<F: Real>(u: F, r: F, y: F) -> F {
    drag(u, r, push(u, y))
}

/// The lower half of eq. (3): `max(u - r, y)`, the output dragged up by the band's
/// lower edge. On its own it is the whole step while the input rises (then
/// `min(u, y) = y` for any output in the band of the last input).
#[inline(always)]
pub fn drag<F: Real>(u: F, r: F, y: F) -> F {
    (u - r).max(y)
}

/// The upper half of eq. (3): `min(u, y)`, the output pushed down by the band's
/// upper edge. On its own it is the whole step while the input falls (then the
/// lower edge is below every output in the band of the last input).
#[inline(always)]
pub fn push<F: Real>(u: F, y: F) -> F {
    u.min(y)
}

/// The operator outputs of a PI model and its last input (state).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Bank<F> {
    /// Operator outputs `y_i`.
    pub y: Values<F>,
    /// Last input.
    pub last: F,
}

impl<F: Real> Bank<F> {
    /// `n` operators at rest (`y = 0` after an input of 0); `n` at most
    /// [`MAX_OPERATORS`] (more are ignored).
    pub fn at_rest(n: usize) -> Self {
        let mut y = Values::new();
        for _ in 0..n.min(MAX_OPERATORS) {
            let _ = y.push(F::ZERO);
        }
        Self { y, last: F::ZERO }
    }

    /// Advances every operator to input `u` ([`play`] with thresholds `r`).
    ///
    /// The direction of the input is tested once: every output lies in the band
    /// of the last input, so a rising input only [`drag`]s and a falling one only
    /// [`push`]es — bit for bit what [`play`] gives (the band invariant holds in
    /// floating point too: `fl(u - r)` is monotone in `u`).
    #[inline]
    pub fn advance(&mut self, r: &[F], u: F) {
        if u >= self.last {
            for (y, &r) in self.y.iter_mut().zip(r) {
                *y = drag(u, r, *y);
            }
        } else {
            for y in self.y.iter_mut() {
                *y = push(u, *y);
            }
        }
        self.last = u;
    }

    /// [`advance`](Self::advance), returning `start + Σ w_i·y_i` of the new
    /// outputs, summed in operator order (`w` as long as `r`).
    #[inline(always)]
    pub fn advance_sum(&mut self, r: &[F], w: &[F], u: F, start: F) -> F {
        let rising = u >= self.last;
        self.last = u;
        step(&mut self.y, r, w, u, rising, start)
    }
}

/// One bank step: [`drag`] every operator while the input rises, [`push`] it
/// while it falls; returns `start + Σ w_i·y_i` of the new outputs (over the
/// shortest of the slices).
#[inline(always)]
fn step<F: Real>(y: &mut [F], r: &[F], w: &[F], u: F, rising: bool, start: F) -> F {
    let n = y.len().min(r.len()).min(w.len());
    let (y, r, w) = (&mut y[..n], &r[..n], &w[..n]);
    let mut acc = start;
    if rising {
        for i in 0..n {
            y[i] = drag(u, r[i], y[i]);
            acc += w[i] * y[i];
        }
    } else {
        for i in 0..n {
            y[i] = push(u, y[i]);
            acc += w[i] * y[i];
        }
    }
    acc
}

/// [`Pi::run`] with the operator count `N` a constant: the loop over the samples
/// keeps the operator outputs in registers. `None` if the model does not have `N`
/// operators.
fn run_fixed<F: Real, const N: usize>(
    pi: &Pi<F>,
    bank: &mut Bank<F>,
    u: &[F],
    out: &mut [F],
) -> Option<()> {
    let r: &[F; N] = pi.r.as_slice().try_into().ok()?;
    let w: &[F; N] = pi.w.as_slice().try_into().ok()?;
    let mut y: [F; N] = bank.y.as_slice().try_into().ok()?;
    let mut last = bank.last;
    let (lo, hi) = (F::ZERO, pi.input_max);
    // Blocks whose inputs all lie in the domain (nearly always) run without the
    // per-sample clamp.
    for (oc, uc) in out.chunks_mut(64).zip(u.chunks(64)) {
        let inside = uc.iter().fold(true, |ok, &u| ok & (u >= lo) & (u <= hi));
        for (o, &u) in oc.iter_mut().zip(uc) {
            let u = if inside { u } else { u.clamp_to(lo, hi) };
            let rising = u >= last;
            last = u;
            *o = step(&mut y, r, w, u, rising, pi.w0 * u);
        }
    }
    bank.y.copy_from_slice(&y);
    bank.last = last;
    Some(())
}

/// A PI model: `Y[u] = w0·u + Σ w_i·G_{r_i}[u]`, inputs clamped to `[0, input_max]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Pi<F> {
    /// Linear weight.
    pub w0: F,
    /// Thresholds (sorted).
    pub r: Values<F>,
    /// Weights.
    pub w: Values<F>,
    /// Upper end of the input domain.
    pub input_max: F,
}

impl<F: Real> Pi<F> {
    /// A model from its parameters; `None` for more than [`MAX_OPERATORS`]
    /// operators or thresholds and weights of different lengths.
    pub fn new(w0: F, r: &[F], w: &[F], input_max: F) -> Option<Self> {
        if r.len() != w.len() {
            return None;
        }
        Some(Self {
            w0,
            r: Values::from_slice(r).ok()?,
            w: Values::from_slice(w).ok()?,
            input_max,
        })
    }

    /// Number of play operators (`w0` apart).
    pub fn operators(&self) -> usize {
        self.r.len()
    }

    /// The state of this model at rest.
    pub fn at_rest(&self) -> Bank<F> {
        Bank::at_rest(self.operators())
    }

    /// `w0·u + Σ w_i·y_i` for operator outputs `y`.
    #[inline]
    pub fn sum(&self, u: F, y: &[F]) -> F {
        let mut x = self.w0 * u;
        for (w, y) in self.w.iter().zip(y) {
            x += *w * *y;
        }
        x
    }

    /// One sample of eqs. (3)–(4): advances the bank with `u` (clamped to the
    /// domain) and returns `Y[u]`.
    #[inline(always)]
    pub fn apply(&self, bank: &mut Bank<F>, u: F) -> F {
        let u = u.clamp_to(F::ZERO, self.input_max);
        bank.advance_sum(&self.r, &self.w, u, self.w0 * u)
    }

    /// Runs a whole input sequence into `out` (the shorter length): the same as
    /// [`apply`](Self::apply) sample by sample, faster for the common operator
    /// counts.
    pub fn run(&self, bank: &mut Bank<F>, u: &[F], out: &mut [F]) {
        macro_rules! fixed {
            ($($n:literal)*) => {
                match self.operators() {
                    $($n => run_fixed::<F, $n>(self, bank, u, out),)*
                    _ => None,
                }
            };
        }
        if fixed!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16).is_none() {
            for (o, &u) in out.iter_mut().zip(u) {
                *o = self.apply(bank, u);
            }
        }
    }

    /// `Y[u]` on the loading curve (every operator dragged from rest).
    pub fn loading(&self, u: F) -> F {
        let mut x = self.w0 * u;
        for (r, w) in self.r.iter().zip(&self.w) {
            x += *w * (u - *r).max(F::ZERO);
        }
        x
    }

    /// `Y[input_max]` on the loading curve: the largest output.
    pub fn output_max(&self) -> F {
        self.loading(self.input_max)
    }

    /// The same operators with another linear weight.
    pub fn with_w0(&self, w0: F) -> Self {
        Self { w0, ..self.clone() }
    }

    /// The closed-form inverse, itself a PI model: `w0' = 1/w0`,
    /// `r'_j = Σ_{i<=j} w_i (r_j - r_i)`, `w'_j = -w_j / (S_j·S_{j-1})`; its domain is
    /// `[0, output_max]`.
    pub fn inverse(&self) -> Self {
        let mut s_prev = self.w0;
        let mut sum_wr = F::ZERO;
        let (mut r, mut w) = (Values::new(), Values::new());
        for (&rj, &wj) in self.r.iter().zip(&self.w) {
            let s = s_prev + wj;
            sum_wr += wj * rj;
            let _ = r.push(s * rj - sum_wr);
            let _ = w.push(-wj / (s * s_prev));
            s_prev = s;
        }
        Self {
            w0: F::ONE / self.w0,
            r,
            w,
            input_max: self.output_max(),
        }
    }

    /// Sets an inverse bank to the state that matches a forward bank of this model:
    /// `z_j = S_j·y_j + Σ_{i>j} w_i·y_i`, last input `Y` (clamped to the inverse's
    /// domain).
    pub fn resync(&self, fwd: &Bank<F>, inv: &mut Bank<F>) {
        let mut s = self.w0;
        for w in &self.w {
            s += *w;
        }
        let mut tail = F::ZERO;
        for j in (0..self.w.len()).rev() {
            let y = fwd.y[j];
            if let Some(z) = inv.y.get_mut(j) {
                *z = s * y + tail;
            }
            tail += self.w[j] * y;
            s -= self.w[j];
        }
        inv.last = (self.w0 * fwd.last + tail).clamp_to(F::ZERO, self.output_max());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pi() -> Pi<f64> {
        Pi::new(
            0.064,
            &[10.0, 20.0, 40.0, 80.0],
            &[0.008, 0.011, 0.004, 0.012],
            150.0,
        )
        .unwrap()
    }

    #[test]
    fn the_operator_follows_the_paper_figure_1() {
        let mut y = 0.0;
        for (u, want) in [
            (5.0, 0.0),
            (30.0, 20.0),
            (25.0, 20.0),
            (15.0, 15.0),
            (24.0, 15.0),
            (27.0, 17.0),
        ] {
            y = play(u, 10.0, y);
            assert_eq!(y, want, "u {u}");
        }
    }

    #[test]
    fn the_inverse_undoes_the_model_on_any_history() {
        let (f, i) = (pi(), pi().inverse());
        let (mut fb, mut ib) = (f.at_rest(), i.at_rest());
        let mut u = 0.0f64;
        for k in 0..3000 {
            u = (u + 13.7 * (k as f64 * 0.37).sin()).clamp(0.0, 150.0);
            let back = i.apply(&mut ib, f.apply(&mut fb, u));
            assert!((back - u).abs() < 1e-10, "step {k}: {u} -> {back}");
        }
    }

    #[test]
    fn a_run_is_the_samples_one_by_one() {
        for n in [4, 17] {
            let r: std::vec::Vec<f64> = (0..n).map(|i| 8.0 * i as f64).collect();
            let w: std::vec::Vec<f64> = (0..n).map(|i| 0.001 * (i % 5) as f64).collect();
            let pi = Pi::new(0.06, &r, &w, 150.0).unwrap();
            let u: std::vec::Vec<f64> = (0..5000)
                .map(|k| 75.0 + 80.0 * (k as f64 * 0.013).sin() * (k as f64 * 0.0007).cos())
                .collect();
            let (mut a, mut b) = (pi.at_rest(), pi.at_rest());
            let mut out = std::vec![0.0; u.len()];
            pi.run(&mut a, &u, &mut out);
            for (k, &uk) in u.iter().enumerate() {
                assert_eq!(out[k], pi.apply(&mut b, uk), "n {n} sample {k}");
            }
            assert_eq!(a, b);
        }
    }

    #[test]
    fn resync_reproduces_the_inverse_state() {
        let (f, i) = (pi(), pi().inverse());
        let (mut fb, mut ib) = (f.at_rest(), i.at_rest());
        for u in [30.0, 120.0, 60.0, 90.0, 10.0, 140.0, 75.0] {
            i.apply(&mut ib, f.apply(&mut fb, u));
            let mut synced = i.at_rest();
            f.resync(&fb, &mut synced);
            for (a, b) in synced.y.iter().zip(&ib.y) {
                assert!((a - b).abs() < 1e-12);
            }
            assert!((synced.last - ib.last).abs() < 1e-12);
        }
    }
}
