//! The loops a model closes, as a discrete-time linear system at the control
//! rate, and the check that they are stable on the stage dynamics the model
//! declares ([`DynamicsSpec`]).
//!
//! # The model
//!
//! From the command `u = x_cmd` (µm, held over a tick) to what the next tick
//! reads: a lag `1/(1 + s/ω_l)` (the amplifier's), then the mode
//! `ω²/(s² + 2ζω·s + ω²)`. The position sensor reads the mode's output `x`; the
//! force channel reads `κ·(v − x)` (with `v` the lagged command: the stack's
//! compression beyond what the FEM's preload at the estimated extension
//! accounts for — the dynamic force; [`crate::control`]) through the split's
//! high-pass. Discretised exactly with the command held (zero-order hold), the
//! plant has the one tick of delay the board has: the command written in tick
//! `k` is seen by the sensors read in tick `k + 1`.
//!
//! The laws, as the firmware runs them each tick `k`:
//!
//! ```text
//! r_s(k) = r_s(k−1) + a·(r(k) − r_s(k−1)),   r_d = r − r_s        force channel
//! δ_d    = −C(z)·r_d,  C(z) = (b0 + b1·z⁻¹ + b2·z⁻²)/(1 + a1·z⁻¹ + a2·z⁻²)   damping
//! e(k)   = r_ref − x(k),  δ_p = kp·e + I(k−1),  I(k) = I(k−1) + ki·e   PI
//! u(k)   = δ_p + δ_d                                              (the reference at 0)
//! ```
//!
//! (The channel's learned offset and scale adapt over seconds: for the loops'
//! dynamics they are constants and drop out.) The damping's section is written
//! with two states `w(k−1), w(k−2)` of `w = r_d − a1·w(k−1) − a2·w(k−2)`,
//! `C·r_d = b0·w + b1·w(k−1) + b2·w(k−2)`. The state `z = [v, x, ẋ/ω, r_s, w₁,
//! w₂, I]` evolves as `z(k+1) = A·z(k)`. The loops
//! are stable when every eigenvalue of `A` lies inside the unit circle; the check
//! asks that `A^(2²⁰)` (twenty squarings) has shrunk every state at least a
//! thousandfold, i.e. every pole decays by 1000 within 2²⁰ ticks (52 s at
//! 20 kHz; an integrator as slow as a 7 s time constant passes). A loop beyond
//! the edge of stability, or on it, is refused; the margins a design needs are
//! the tuner's business (`fpi tune`).
//!
//! `f64` arithmetic (software floating point on the Cortex-M4F): for the
//! validator and host tools, never for the ISR. About 9 000 multiplications.

use crate::biquad::Biquad;
use crate::damping::{DampingSpec, DynamicsSpec};
use crate::error::{Field, Invalid, ModelError};
use crate::feedback::FeedbackSpec;
use crate::q::{COUPLING_FRAC, LOOP_GAIN_FRAC};

/// States of the closed loop: lag, position, velocity/ω, split, damping (two),
/// PI.
pub const STATES: usize = 7;

/// A square matrix of the loop's size.
pub type Matrix = [[f64; STATES]; STATES];

/// The plant's zero-order-hold discretisation over one tick: `[v, x, ẋ/ω](k+1) =
/// Φ·[v, x, ẋ/ω](k) + Γ·u(k)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plant {
    /// Transition.
    pub phi: [[f64; 3]; 3],
    /// Input.
    pub gamma: [f64; 3],
    /// κ, N per µm of `v − x`.
    pub force_gain: f64,
}

/// The laws' coefficients per tick, as `f64`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Laws {
    /// The split's rate `a` (0: none).
    pub split: f64,
    /// The damping's section `[b0, b1, b2, a1, a2]` (all zero: no damping).
    pub damping: [f64; 5],
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain per tick (0: no integrator).
    pub ki: f64,
}

impl Laws {
    /// The coefficients of a model's force channel, damping and feedback (the
    /// quantised values the firmware runs); a damping the core cannot build
    /// (the validator refuses it first) counts as none.
    pub fn of(split: i32, damping: Option<&DampingSpec>, feedback: Option<&FeedbackSpec>) -> Self {
        let frac = |bits: i32, f: u32| bits as f64 / (1u64 << f) as f64;
        let damping = damping
            .and_then(|d| d.section().ok())
            .map_or([0.0; 5], |s| section_f64(&s));
        let (kp, ki) = feedback.map_or((0.0, 0.0), |f| {
            (
                frac(f.kp.to_bits(), LOOP_GAIN_FRAC),
                frac(f.ki.to_bits(), LOOP_GAIN_FRAC),
            )
        });
        Self {
            split: frac(split, COUPLING_FRAC),
            damping,
            kp,
            ki,
        }
    }

    /// Whether the laws damp (a non-zero section).
    pub fn damps(&self) -> bool {
        self.damping.iter().any(|c| *c != 0.0)
    }
}

/// A section's coefficients `[b0, b1, b2, a1, a2]` as `f64`.
pub fn section_f64(s: &Biquad) -> [f64; 5] {
    let [b0, b1, b2] = s.b();
    let [a1, a2] = s.a();
    [b0, b1, b2, a1, a2].map(|c| c.to_num::<f64>())
}

/// `2π`.
const TAU: f64 = core::f64::consts::TAU;

impl Plant {
    /// The plant of `d` at control rate `rate_hz`, its mode scaled by `mode_scale`
    /// and its damping ratio replaced by `zeta` where given (for robustness
    /// studies), its gain scaled by `gain` (the loops see the stage through a
    /// model that may be off).
    pub fn new(
        d: &DynamicsSpec,
        rate_hz: u32,
        mode_scale: f64,
        zeta: Option<f64>,
        gain: f64,
    ) -> Self {
        let t = 1.0 / rate_hz as f64;
        let w = TAU * d.mode_mhz as f64 / 1000.0 * mode_scale;
        let z = zeta.unwrap_or(d.damping_ratio());
        let wl = if d.lag_mhz == 0 {
            0.0
        } else {
            TAU * d.lag_mhz as f64 / 1000.0
        };
        // ẏ = M·y + b·u with y = [v, x, ẋ/ω]: v̇ = ω_l·(u − v) (v = u without a lag),
        // ẋ = ω·(ẋ/ω), d(ẋ/ω)/dt = ω·(v − x) − 2ζω·(ẋ/ω).
        let m = if wl > 0.0 {
            [
                [-wl, 0.0, 0.0, wl],
                [0.0, 0.0, w, 0.0],
                [w, -w, -2.0 * z * w, 0.0],
                [0.0, 0.0, 0.0, 0.0],
            ]
        } else {
            // No lag: v follows u at once; the v row only carries u.
            [
                [0.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, w, 0.0],
                [0.0, -w, -2.0 * z * w, w],
                [0.0, 0.0, 0.0, 0.0],
            ]
        };
        let e = expm4(&m, t);
        let mut phi = [[0.0; 3]; 3];
        let mut gamma = [0.0; 3];
        for i in 0..3 {
            for (j, p) in phi[i].iter_mut().enumerate() {
                *p = e[i][j];
            }
            gamma[i] = e[i][3] * gain;
        }
        if wl == 0.0 {
            // v(k+1) is the command held over the tick.
            phi[0] = [0.0, 0.0, 0.0];
            gamma[0] = gain;
        }
        Self {
            phi,
            gamma,
            force_gain: d.force_gain.to_num::<f64>(),
        }
    }

    /// The closed loop's state matrix under `laws` (see the module docs).
    pub fn closed_loop(&self, l: &Laws) -> Matrix {
        // Each tick: the sensors read y = [x, r] from the plant state at tick k;
        // the laws update their states; u(k) drives the plant to k + 1. Written as
        // z(k+1) = A·z(k), with the law states' new values substituted.
        let mut a = [[0.0; STATES]; STATES];
        let kappa = self.force_gain;
        // r(k) = κ·(v − x): row vector over z.
        let mut r = [0.0; STATES];
        r[0] = kappa;
        r[1] = -kappa;
        // r_s(k) = (1 − a)·r_s(k−1) + a·r(k)   (without a split r_s ≡ r, r_d = 0)
        let mut rs = [0.0; STATES];
        if l.split > 0.0 {
            for (o, ri) in rs.iter_mut().zip(r) {
                *o = l.split * ri;
            }
            rs[3] += 1.0 - l.split;
        } else {
            rs = r;
        }
        // w(k) = r_d − a1·w₁ − a2·w₂; y = b0·w + b1·w₁ + b2·w₂; no damping: w ≡ 0.
        let [b0, b1, b2, a1, a2] = l.damping;
        let mut w = [0.0; STATES];
        let mut y = [0.0; STATES];
        if l.damps() {
            for i in 0..STATES {
                w[i] = r[i] - rs[i];
            }
            w[4] -= a1;
            w[5] -= a2;
            for i in 0..STATES {
                y[i] = b0 * w[i];
            }
            y[4] += b1;
            y[5] += b2;
        }
        let mut w2 = [0.0; STATES];
        if l.damps() {
            w2[4] = 1.0;
        }
        // e = −x; δ_p = kp·e + I(k−1); I(k) = I(k−1) + ki·e; no integrator: I ≡ 0.
        let mut dp = [0.0; STATES];
        dp[1] = -l.kp;
        dp[6] = 1.0;
        let mut ii = [0.0; STATES];
        if l.ki != 0.0 {
            ii[1] = -l.ki;
            ii[6] = 1.0;
        }
        // u = δ_p − y
        let mut u = [0.0; STATES];
        for i in 0..STATES {
            u[i] = dp[i] - y[i];
        }
        for ((row, phi), gamma) in a.iter_mut().zip(&self.phi).zip(&self.gamma) {
            for (j, (aij, uj)) in row.iter_mut().zip(&u).enumerate() {
                let plant = if j < 3 { phi[j] } else { 0.0 };
                *aij = plant + gamma * uj;
            }
        }
        a[3] = rs;
        a[4] = w;
        a[5] = w2;
        a[6] = ii;
        a
    }
}

/// Squarings of [`decays`]: poles must decay within `2^HORIZON_LOG2` ticks.
pub const HORIZON_LOG2: u32 = 20;

/// Whether every pole of `a` decays a thousandfold within `2^20` ticks: the
/// largest row sum of `|A^(2²⁰)|` below 10⁻³ (squarings, each normalised to a
/// unit norm so the arithmetic neither overflows nor underflows; the scale is
/// kept as its logarithm).
pub fn decays(a: &Matrix) -> bool {
    let mut m = *a;
    // ‖A^(2^i)‖ = ‖m‖·e^{log_scale}, with ‖m‖ = 1 after each step.
    let mut log_scale = 0.0f64;
    for _ in 0..=HORIZON_LOG2 {
        let n = norm(&m);
        if !n.is_finite() {
            return false;
        }
        if n == 0.0 {
            return true;
        }
        for row in m.iter_mut() {
            for v in row.iter_mut() {
                *v /= n;
            }
        }
        log_scale += ln(n);
        if log_scale > 1e6 {
            return false;
        }
        m = mul(&m, &m);
        log_scale *= 2.0;
    }
    // After 21 normalisations and squarings m holds A^(2²¹): ‖A^(2²⁰)‖² below 10⁻⁶.
    let n = norm(&m);
    n == 0.0 || ln(n) + log_scale < 2.0 * -6.907_755 // ln 1000
}

/// Checks the loops a model closes on the dynamics it declares; where it
/// declares none there is nothing to check against. The error names the gain of
/// the outermost loop the model has (the PI's integral gain, else the damping's).
pub fn check(
    rate_hz: u32,
    dynamics: Option<&DynamicsSpec>,
    split: i32,
    damping: Option<&DampingSpec>,
    feedback: Option<&FeedbackSpec>,
) -> Result<(), Invalid> {
    let Some(d) = dynamics else {
        return Ok(());
    };
    if damping.is_none() && feedback.is_none() {
        return Ok(());
    }
    let plant = Plant::new(d, rate_hz, 1.0, None, 1.0);
    let laws = Laws::of(split, damping, feedback);
    if decays(&plant.closed_loop(&laws)) {
        return Ok(());
    }
    let field = if feedback.is_some() {
        Field::FeedbackKi
    } else {
        Field::DampingGain
    };
    Err(Invalid::at(field, ModelError::LoopUnstable))
}

fn mul(a: &Matrix, b: &Matrix) -> Matrix {
    let mut r = [[0.0; STATES]; STATES];
    for i in 0..STATES {
        for k in 0..STATES {
            let aik = a[i][k];
            if aik == 0.0 {
                continue;
            }
            for j in 0..STATES {
                r[i][j] += aik * b[k][j];
            }
        }
    }
    r
}

/// The largest absolute row sum.
fn norm(a: &Matrix) -> f64 {
    let mut n = 0.0f64;
    for row in a {
        let s: f64 = row.iter().map(|v| abs(*v)).sum();
        if s > n || s.is_nan() {
            n = s;
        }
    }
    n
}

const fn abs(x: f64) -> f64 {
    if x < 0.0 {
        -x
    } else {
        x
    }
}

/// Natural logarithm of a positive, finite `x` (`no_std`: by the exponent and a
/// series in `(m − 1)/(m + 1)`; 10⁻¹² relative, enough for a threshold).
fn ln(x: f64) -> f64 {
    let bits = x.to_bits();
    let exp = ((bits >> 52) & 0x7ff) as i64 - 1023;
    let m = f64::from_bits((bits & ((1u64 << 52) - 1)) | (1023u64 << 52));
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let mut term = s;
    let mut sum = 0.0;
    let mut k = 1.0;
    while k < 60.0 {
        sum += term / k;
        term *= s2;
        k += 2.0;
    }
    2.0 * sum + exp as f64 * core::f64::consts::LN_2
}

/// `e^{M·t}` of a 4 × 4 matrix (scaling and squaring, Taylor to 16 terms).
fn expm4(m: &[[f64; 4]; 4], t: f64) -> [[f64; 4]; 4] {
    let mut a = [[0.0; 4]; 4];
    let mut n = 0.0f64;
    for i in 0..4 {
        let mut s = 0.0;
        for j in 0..4 {
            a[i][j] = m[i][j] * t;
            s += abs(a[i][j]);
        }
        n = if s > n { s } else { n };
    }
    let mut squarings = 0;
    while n > 0.25 && squarings < 60 {
        n *= 0.5;
        squarings += 1;
        for row in a.iter_mut() {
            for v in row.iter_mut() {
                *v *= 0.5;
            }
        }
    }
    let mul4 = |x: &[[f64; 4]; 4], y: &[[f64; 4]; 4]| {
        let mut r = [[0.0; 4]; 4];
        for i in 0..4 {
            for k in 0..4 {
                for j in 0..4 {
                    r[i][j] += x[i][k] * y[k][j];
                }
            }
        }
        r
    };
    let mut e = [[0.0; 4]; 4];
    let mut term = [[0.0; 4]; 4];
    for i in 0..4 {
        e[i][i] = 1.0;
        term[i][i] = 1.0;
    }
    let mut k = 1.0;
    while k <= 16.0 {
        term = mul4(&term, &a);
        for row in term.iter_mut() {
            for v in row.iter_mut() {
                *v /= k;
            }
        }
        for i in 0..4 {
            for j in 0..4 {
                e[i][j] += term[i][j];
            }
        }
        k += 1.0;
    }
    for _ in 0..squarings {
        e = mul4(&e, &e);
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::split_rate;
    use crate::q::{CreepRate, LoopGain, Micrometres, NewtonsPerUm};

    fn dynamics() -> DynamicsSpec {
        DynamicsSpec {
            mode_mhz: 850_000,
            damping: CreepRate::from_num(0.03),
            lag_mhz: 2_000_000,
            force_gain: NewtonsPerUm::from_num(6.5),
        }
    }

    fn pi(kp: f64, ki: f64) -> FeedbackSpec {
        FeedbackSpec {
            kp: LoopGain::from_num(kp),
            ki: LoopGain::from_num(ki),
            limit: Micrometres::from_num(4),
            sensor: crate::control::Interval {
                lo: Micrometres::from_num(-10),
                hi: Micrometres::from_num(50),
            },
            tolerance: Micrometres::from_num(6),
        }
    }

    #[test]
    fn the_plant_settles_on_its_input_with_unit_gain() {
        let p = Plant::new(&dynamics(), 20_000, 1.0, None, 1.0);
        let mut y = [0.0; 3];
        for _ in 0..40_000 {
            y = core::array::from_fn(|i| {
                (0..3).map(|j| p.phi[i][j] * y[j]).sum::<f64>() + p.gamma[i]
            });
        }
        assert!(
            (y[1] - 1.0).abs() < 1e-9 && (y[0] - 1.0).abs() < 1e-9,
            "{y:?}"
        );
    }

    #[test]
    fn ln_is_accurate() {
        for x in [1e-300, 0.001, 0.5, 1.0, 2.0, 1000.0, 1e200] {
            let err = (ln(x) - x.ln()).abs();
            assert!(err < 1e-10 * (1.0 + x.ln().abs()), "{x}: {err}");
        }
    }

    #[test]
    fn the_open_stage_decays_and_an_aggressive_pi_does_not() {
        let d = dynamics();
        let split = split_rate(10, 20_000).to_bits();
        // The mode, under a slow integral loop: stable.
        assert_eq!(
            check(20_000, Some(&d), split, None, Some(&pi(0.0, 0.006))),
            Ok(())
        );
        // The issue's case: kp = 16 diverges at the mode.
        let e = check(20_000, Some(&d), split, None, Some(&pi(16.0, 0.0))).unwrap_err();
        assert_eq!(
            (e.field, e.error),
            (Field::FeedbackKi, ModelError::LoopUnstable)
        );
        // An integral gain of 1 per tick too.
        assert!(check(20_000, Some(&d), split, None, Some(&pi(0.0, 1.0))).is_err());
        // Without declared dynamics there is nothing to check against.
        assert_eq!(
            check(20_000, None, split, None, Some(&pi(16.0, 0.0))),
            Ok(())
        );
    }

    #[test]
    fn damping_from_the_force_channel_is_stable_and_too_much_is_not() {
        let d = dynamics();
        let split = split_rate(10, 20_000).to_bits();
        let damping = |g_per_s: f64| DampingSpec {
            gain: LoopGain::from_num(g_per_s / 20_000.0),
            highpass: split_rate(100, 20_000),
            leak: split_rate(100, 20_000),
            limit: Micrometres::from_num(4),
        };
        assert_eq!(
            check(20_000, Some(&d), split, Some(&damping(800.0)), None),
            Ok(())
        );
        let e = check(20_000, Some(&d), split, Some(&damping(100_000.0)), None).unwrap_err();
        assert_eq!(e.field, Field::DampingGain);
    }
}
