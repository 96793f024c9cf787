//! The actuator model in floating point: one structure for every kind of model
//! the project knows, the f64 reference of the fixed-point core, and the stack
//! of the virtual stage.
//!
//! ```text
//! e  = u - U_p(F),            U_p(F) = k0 + k_f·F + k_q·(F - F_q)²   (no coupling: e = u)
//! û  = g(e), clamped to [0, input_max]      dead zone: hard max(e, 0), soft, or a table
//! m_j ← m_j + (1 - a_j)(û - m_j)            creep: first-order lags of û
//! Y  = w0(F)·û + Σ w_i(F)·G_{r_i}[û] + Σ b_j·m_j      weights affine in F for LDPI
//! x  = h(Y + offset) - c·(F - F_ref)        output map h: analytic or a table
//! ```
//!
//! The FPI of Actuators 2025, 14(8):411, is `k0 = k_q = 0`, the hard dead zone, no creep, `h` the
//! identity, `c = 0`. [`Model::peek`] evaluates one sample without committing it
//! and returns the derivatives and the validity intervals the coupled solver
//! ([`crate::solve`]) needs; [`Model::inverse`] is the closed-form inverse the
//! control step runs.

use heapless::Vec;

use crate::maps::{dead_zone, dead_zone_inverse, OutputMap, TableMap};
use crate::play::{play, Bank, Pi, Values};
use crate::real::Real;

/// Most creep terms of a model (the core's limit).
pub const MAX_CREEP: usize = 8;

/// The curvature term `k_q·(F - F_q)²` is evaluated with `|F - F_q|` clamped to
/// this, N (the range over which the core's fixed-point product is exact).
pub const QUAD_FORCE_SPAN_N: f64 = 1024.0;

/// How the preload enters: the reverse voltage `U_p(F)` and the stack compliance.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Coupling<F> {
    /// Constant part `k0` of the preload offset, V.
    pub offset: F,
    /// `k_f`, V/N.
    pub k_f: F,
    /// Curvature `k_q`, V/N².
    pub k_q: F,
    /// Centre `F_q` of the curvature, N.
    pub force_q: F,
    /// Stack compliance `c`, µm/N.
    pub compliance: F,
}

impl<F: Real> Coupling<F> {
    /// `U_p(F)` (V), its slope (V/N) and its curvature (V/N²).
    #[inline]
    pub fn preload_offset(&self, force: F) -> (F, F, F) {
        let span = F::of(QUAD_FORCE_SPAN_N);
        let d = force - self.force_q;
        let (dc, inside) = if d > span {
            (span, false)
        } else if d < -span {
            (-span, false)
        } else {
            (d, true)
        };
        let two = F::of(2.0);
        let (slope, curv) = if inside {
            (self.k_f + two * self.k_q * dc, two * self.k_q)
        } else {
            (self.k_f, F::ZERO)
        };
        (
            self.offset + self.k_f * force + self.k_q * dc * dc,
            slope,
            curv,
        )
    }
}

/// The dead zone `g` between the effective voltage and the operators.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeadZone<'a, F> {
    /// `max(e, 0)`.
    Hard,
    /// `s·ln(1 + e^{e/s})` with softness `s`, V.
    Soft(F),
    /// Tabulated (the firmware's form).
    Table(TableMap<'a, F>),
}

impl<F: Real> DeadZone<'_, F> {
    /// `g(e)` and `g'(e)`.
    #[inline]
    pub fn apply(&self, e: F) -> (F, F) {
        match self {
            DeadZone::Hard => dead_zone(F::ZERO, e),
            DeadZone::Soft(s) => dead_zone(*s, e),
            DeadZone::Table(t) => {
                let h = F::of(1e-6);
                (t.apply(e), (t.apply(e + h) - t.apply(e - h)) / (h + h))
            }
        }
    }

    /// `g''` where the slope is `dg` (as [`apply`](Self::apply) returns it): the
    /// soft dead zone's `g' (1 - g') / s`, 0 for the others.
    #[inline]
    fn curvature(&self, dg: F) -> F {
        match self {
            DeadZone::Soft(s) => dg * (F::ONE - dg) / *s,
            _ => F::ZERO,
        }
    }

    /// `g⁻¹(û)`, and whether `û` lies below a table's first knot (the foot of a
    /// tabulated soft dead zone, where the inverse can only hold its first value).
    #[inline]
    fn invert(&self, uh: F) -> (F, bool) {
        match self {
            DeadZone::Hard => (uh, false),
            DeadZone::Soft(s) => (dead_zone_inverse(*s, uh), false),
            DeadZone::Table(t) => (t.invert(uh), uh < t.inverse.x_min()),
        }
    }
}

/// The map `h` after the PI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Output<'a, F> {
    /// Analytic.
    Map(OutputMap<F>),
    /// Tabulated (the firmware's form).
    Table(TableMap<'a, F>),
}

impl<F: Real> Output<'_, F> {
    /// `h(Y)` and `h'(Y)`.
    #[inline]
    fn apply(&self, y: F) -> (F, F) {
        match self {
            Output::Map(m) => m.apply(y),
            Output::Table(t) => {
                let h = F::of(1e-6);
                (t.apply(y), (t.apply(y + h) - t.apply(y - h)) / (h + h))
            }
        }
    }
    /// `h⁻¹(z)`.
    #[inline]
    fn invert(&self, z: F) -> F {
        match self {
            Output::Map(m) => m.invert(z),
            Output::Table(t) => t.invert(z),
        }
    }
}

/// One creep term: a first-order lag of `û` with time constant `tau_s` and gain
/// `gain` (µm/V).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Creep<F> {
    /// Time constant, s.
    pub tau_s: F,
    /// Gain `b`, µm/V.
    pub gain: F,
}

/// `1 - exp(-dt/τ)`: the per-sample rate of a first-order lag sampled every `dt`
/// (1 for `τ <= 0`: no lag).
pub fn lag_rate<F: Real>(dt: F, tau: F) -> F {
    if tau <= F::ZERO {
        F::ONE
    } else {
        -(-dt / tau).exp_m1()
    }
}

/// LDPI: the slopes of the weights in the preload, `w_i(F) = w_i + b_i·F`.
#[derive(Debug, Clone, PartialEq)]
pub struct Ldpi<F> {
    /// Slope of `w0`, µm/V/N.
    pub w0_per_n: F,
    /// Slopes of the operator weights, µm/V/N.
    pub w_per_n: Values<F>,
}

/// A model of the actuator (configuration; see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Model<'a, F> {
    /// The PI part.
    pub pi: Pi<F>,
    /// LDPI weight slopes.
    pub ldpi: Option<Ldpi<F>>,
    /// The preload's reverse voltage and the compliance; `None`: `e = u`, no compliance.
    pub coupling: Option<Coupling<F>>,
    /// `g`.
    pub dead_zone: DeadZone<'a, F>,
    /// `h`.
    pub output: Output<'a, F>,
    /// Added to `Y` before `h`, µm (recordings not zeroed at rest).
    pub offset: F,
    /// Creep lags.
    pub creep: Vec<Creep<F>, MAX_CREEP>,
}

/// A model's memory: operator outputs, creep memories (V) and the creep lags'
/// per-sample rates.
#[derive(Debug, Clone, PartialEq)]
pub struct State<F> {
    /// The operators.
    pub bank: Bank<F>,
    /// Creep memories, V.
    pub m: Vec<F, MAX_CREEP>,
    /// `1 - a_j` of each lag at the sample period.
    pub rate: Vec<F, MAX_CREEP>,
}

/// One evaluation without committing: the extension and what the coupled solver
/// needs to know about it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peek<F> {
    /// Stack extension, µm.
    pub x: F,
    /// d(x)/d(x_guess) through the preload: ≤ 0 for physical models.
    pub dx: F,
    /// The effective voltage the operators saw, V.
    pub uh: F,
    /// The effective voltage before the dead zone and the domain clamp, V, and its
    /// derivative along the extension guess, V/µm.
    pub e: (F, F),
    /// For piecewise-linear models, the interval of `e` in which the model is this
    /// same linear function (no operator switches, no dead-zone or domain edge
    /// crossed): a Newton step that stays inside it (and inside the preload map's
    /// segment) lands exactly on the root. `None` for the other models.
    pub linear_in: Option<(F, F)>,
    /// d(û)/d(x_guess), V/µm (0 where û is clamped).
    pub duh: F,
    /// d²(x)/d(x_guess)², 1/µm, inside the smooth piece (0 outside smooth models):
    /// with `dx` it bounds the error of a Newton step.
    pub ddx: F,
    /// For the smooth models, the open interval of `û` around this one in which no
    /// operator switches and no clamp or hard dead-zone edge acts, so the model is
    /// smooth there. `None` where `û` sits on such an edge, and for the other models.
    pub smooth_in: Option<(F, F)>,
}

/// Narrows the open interval `(lo, hi)` around `at` to exclude the switch points
/// `bs`; a switch point at `at` itself empties it.
#[inline]
fn narrow_to<F: Real>(mut lo: F, mut hi: F, at: F, bs: [F; 2]) -> (F, F) {
    for b in bs {
        if b < at {
            lo = lo.max(b);
        } else if b > at {
            hi = hi.min(b);
        } else {
            return (at, at);
        }
    }
    (lo, hi)
}

/// How much structure [`Model::peek`] can report about a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Smoothness {
    /// Hard dead zone, identity output: linear between switch points.
    PiecewiseLinear,
    /// Analytic soft dead zone or output map: smooth between switch points.
    Smooth,
    /// A tabulated map: neither is tracked.
    Tabulated,
}

impl<F: Real> Model<'_, F> {
    /// A plain PI model (no force, hard dead zone, identity output).
    pub fn pi(pi: Pi<F>) -> Self {
        Self {
            pi,
            ldpi: None,
            coupling: None,
            dead_zone: DeadZone::Hard,
            output: Output::Map(OutputMap::Identity),
            offset: F::ZERO,
            creep: Vec::new(),
        }
    }

    /// Play operators (`w0` apart).
    pub fn operators(&self) -> usize {
        self.pi.operators()
    }

    /// A state at rest for samples `dt` seconds apart.
    pub fn state(&self, dt: F) -> State<F> {
        let mut st = State {
            bank: self.pi.at_rest(),
            m: Vec::new(),
            rate: Vec::new(),
        };
        for c in &self.creep {
            let _ = st.m.push(F::ZERO);
            let _ = st.rate.push(lag_rate(dt, c.tau_s));
        }
        st
    }

    /// The preload offset `U_p(F)` (V) and its slope (V/N); 0 without coupling.
    pub fn preload_offset(&self, force: F) -> (F, F) {
        match &self.coupling {
            Some(c) => {
                let (up, dup, _) = c.preload_offset(force);
                (up, dup)
            }
            None => (F::ZERO, F::ZERO),
        }
    }

    /// The stack compliance, µm/N (0 without coupling).
    pub fn compliance(&self) -> F {
        self.coupling.map_or(F::ZERO, |c| c.compliance)
    }

    fn smoothness(&self) -> Smoothness {
        match (&self.dead_zone, &self.output) {
            (DeadZone::Table(_), _) | (_, Output::Table(_)) => Smoothness::Tabulated,
            (DeadZone::Hard, Output::Map(m)) if m.is_identity() => Smoothness::PiecewiseLinear,
            _ => Smoothness::Smooth,
        }
    }

    /// Evaluates one sample without committing the state: voltage `u` (V), force
    /// `force` (N, read from the preload map at the extension guess), the map's
    /// slope there `dforce` (N/µm), and the compliance reference `force_ref` (N).
    pub fn peek(&self, st: &State<F>, u: F, force: F, dforce: F, force_ref: F) -> Peek<F> {
        let p = &self.pi;
        let (zero, inf) = (F::ZERO, F::INFINITY);
        // Effective voltage and its first and second derivatives along the extension
        // guess (the preload map is linear in one FEM segment; U_p is quadratic in F).
        let (e, de, dde) = match &self.coupling {
            Some(c) => {
                let (up, dup, ddup) = c.preload_offset(force);
                (u - up, -dup * dforce, -ddup * dforce * dforce)
            }
            None => (u, zero, zero),
        };
        let (g, dg) = self.dead_zone.apply(e);
        let (uh, duh, clamped) = if g < zero {
            (zero, zero, true)
        } else if g > p.input_max {
            (p.input_max, zero, true)
        } else {
            (g, dg * de, false)
        };
        let kind = self.smoothness();
        let piecewise_linear = kind == Smoothness::PiecewiseLinear;
        let hard = matches!(self.dead_zone, DeadZone::Hard);
        // The e-interval of this linear piece: the dead-zone edge and the domain end…
        let (mut lo, mut hi) = if e <= zero {
            (-inf, zero)
        } else if e >= p.input_max {
            (p.input_max, inf)
        } else {
            (zero, p.input_max)
        };
        let linear_inside = piecewise_linear && e > zero && e < p.input_max;
        // …or, for smooth models, the û-interval without a clamp or the hard edge.
        let (mut u_lo, mut u_hi) = if kind != Smoothness::Smooth || clamped || (hard && e <= zero) {
            (uh, uh) // none, or on an edge: empty
        } else {
            (-inf, p.input_max)
        };
        let smooth_inside = u_lo < u_hi;
        // Weights (LDPI: affine in the force).
        let (w0, dw0) = match &self.ldpi {
            Some(l) => (p.w0 + l.w0_per_n * force, l.w0_per_n * dforce),
            None => (p.w0, zero),
        };
        let mut y_sum = w0 * uh;
        let mut slope = w0; // dY/dû
        let mut dy_w = dw0 * uh; // change through the weights (LDPI)
        for (i, (&r, &y)) in p.r.iter().zip(&st.bank.y).enumerate() {
            let v = play(uh, r, y);
            // The operator moves with û when its output changes; its switch points
            // are û = y + r (dragged up) and û = y (pushed down). At a switch point
            // itself the slope taken here is one side's only: the interval is empty.
            let active = v != y;
            if linear_inside {
                (lo, hi) = narrow_to(lo, hi, e, [y + r, y]);
            } else if smooth_inside {
                (u_lo, u_hi) = narrow_to(u_lo, u_hi, uh, [y + r, y]);
            }
            let mut w = p.w[i];
            if let Some(l) = &self.ldpi {
                w += l.w_per_n[i] * force;
                dy_w += l.w_per_n[i] * dforce * v;
            }
            y_sum += w * v;
            if active {
                slope += w;
            }
        }
        for ((c, &m), &rate) in self.creep.iter().zip(&st.m).zip(&st.rate) {
            y_sum += c.gain * (m + rate * (uh - m));
            slope += c.gain * rate;
        }
        let (z, dz) = self.output.apply(y_sum + self.offset);
        let c = self.compliance();
        // Second derivative inside a smooth piece: the PI is linear in û there, so the
        // curvature comes from U_p (through `dde`), the soft dead zone and the output map.
        let dy = slope * duh + dy_w;
        let ddx = match (&self.output, smooth_inside) {
            (Output::Map(map), true) => {
                let dduh = self.dead_zone.curvature(dg) * de * de + dg * dde;
                map.curvature(dz) * dy * dy + dz * slope * dduh
            }
            _ => zero,
        };
        Peek {
            x: z - c * (force - force_ref),
            dx: dz * dy - c * dforce,
            uh,
            e: (e, de),
            linear_in: piecewise_linear.then_some((lo, hi)),
            duh,
            ddx,
            smooth_in: smooth_inside.then_some((u_lo, u_hi)),
        }
    }

    /// Commits one sample with the effective voltage a [`peek`](Self::peek) found.
    pub fn commit(&self, st: &mut State<F>, uh: F) {
        st.bank.advance(&self.pi.r, uh);
        for (m, &rate) in st.m.iter_mut().zip(&st.rate) {
            *m += rate * (uh - *m);
        }
    }

    /// Forward model with a known force: advances the state and returns the stack
    /// extension, µm.
    pub fn step(&self, st: &mut State<F>, u: F, force: F, force_ref: F) -> F {
        let p = self.peek(st, u, force, F::ZERO, force_ref);
        self.commit(st, p.uh);
        p.x
    }

    /// The PI with this sample's creep folded into `w0` (`w0' = w0 + Σ b_j(1 - a_j)`):
    /// what the inverse inverts.
    pub fn prime(&self, st: &State<F>) -> Pi<F> {
        let mut w0 = self.pi.w0;
        for (c, &rate) in self.creep.iter().zip(&st.rate) {
            w0 += c.gain * rate;
        }
        self.pi.with_w0(w0)
    }

    /// The closed-form inverse of [`prime`](Self::prime).
    pub fn inverse_pi(&self, st: &State<F>) -> Pi<F> {
        self.prime(st).inverse()
    }

    /// Closed-form inverse (not for LDPI, whose weights depend on the force): the
    /// voltage that gives stack extension `x` (µm) under force `force` (N), given
    /// the inverse PI `inv` ([`inverse_pi`](Self::inverse_pi)) and its bank;
    /// advances that bank, reads the creep memories. Also whether `û` fell in the
    /// foot of a tabulated dead zone (the caller should then realign the inverse
    /// bank with the forward one, [`Pi::resync`] of [`prime`](Self::prime)).
    pub fn inverse(
        &self,
        inv: &Pi<F>,
        bank: &mut Bank<F>,
        st: &State<F>,
        x: F,
        force: F,
        force_ref: F,
    ) -> (F, bool) {
        let z = x + self.compliance() * (force - force_ref);
        let mut y = self.output.invert(z) - self.offset;
        for ((c, &m), &rate) in self.creep.iter().zip(&st.m).zip(&st.rate) {
            y -= c.gain * (F::ONE - rate) * m;
        }
        let uh = inv.apply(bank, y);
        let (e, foot) = self.dead_zone.invert(uh);
        (self.preload_offset(force).0 + e, foot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn efpi() -> Model<'static, f64> {
        let mut creep = Vec::new();
        let _ = creep.push(Creep {
            tau_s: 0.01,
            gain: 0.003,
        });
        Model {
            pi: Pi::new(0.06, &[10.0, 30.0, 60.0], &[0.01, 0.008, 0.004], 150.0).unwrap(),
            ldpi: None,
            coupling: Some(Coupling {
                offset: -0.4,
                k_f: 0.106,
                k_q: 1.6e-4,
                force_q: 75.0,
                compliance: 0.02,
            }),
            dead_zone: DeadZone::Soft(1.8),
            output: Output::Map(OutputMap::Saturation {
                beta_per_um: 0.0037,
            }),
            offset: 0.0,
            creep,
        }
    }

    /// The efpi model after a short history with reversals (operators held apart).
    fn efpi_driven() -> (Model<'static, f64>, State<f64>) {
        let m = efpi();
        let mut st = m.state(2e-4);
        for u in [20.0, 60.0, 45.0] {
            m.step(&mut st, u, 80.0, 61.8);
        }
        (m, st)
    }

    #[test]
    fn peek_derivative_matches_finite_differences() {
        let (m, st) = efpi_driven();
        let (f0, df) = (85.0, 4.5);
        let h = 1e-6;
        let a = m.peek(&st, 50.0, f0 - df * h, df, 61.8);
        let b = m.peek(&st, 50.0, f0 + df * h, df, 61.8);
        let mid = m.peek(&st, 50.0, f0, df, 61.8);
        let fd = (b.x - a.x) / (2.0 * h);
        assert!((fd - mid.dx).abs() < 1e-6, "{fd} vs {}", mid.dx);
        assert!(mid.dx < 0.0);
    }

    #[test]
    fn peek_curvature_matches_finite_differences() {
        let (m, st) = efpi_driven();
        // Deep in the stroke, and at the soft dead zone's edge (e ≈ 1 V), where the
        // curvature is largest.
        let df = 4.5;
        for (u, f0) in [(50.0, 85.0), (9.5, 80.0), (8.0, 75.0)] {
            let h = 1e-4;
            let at = |d: f64| m.peek(&st, u, f0 + df * d, df, 61.8);
            let (a, mid, b) = (at(-h), at(0.0), at(h));
            assert!(mid.smooth_in.is_some() && mid.linear_in.is_none());
            let fd = (b.dx - a.dx) / (2.0 * h);
            assert!(
                (fd - mid.ddx).abs() < 1e-6 * (1.0 + fd.abs()),
                "u {u}: {fd} vs {}",
                mid.ddx
            );
            assert!(mid.ddx != 0.0, "u {u}: the model is curved there");
        }
    }

    #[test]
    fn the_closed_form_inverse_undoes_the_forward_model() {
        let m = efpi();
        let mut st = m.state(2e-4);
        let inv = m.inverse_pi(&st);
        let mut ib = inv.at_rest();
        let mut worst = 0.0f64;
        for k in 0..3000 {
            let x = 4.0 + 3.5 * (k as f64 * 0.01).sin();
            let f = 70.0 + 4.0 * x;
            let (u, _) = m.inverse(&inv, &mut ib, &st, x, f, 61.8);
            let back = m.step(&mut st, u, f, 61.8);
            worst = worst.max((back - x).abs());
        }
        assert!(worst < 1e-9, "{worst} µm");
    }
}
