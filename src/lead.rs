//! The force the reference's own motion explains, at the stage's real mass.
//!
//! Where the shaping runs ahead of the tracked reference, the damping leaves out
//! the force the shaped reference's motion explains, `f_m = κ·(S_{k−1} − x_ref)`
//! (`firmware::closed_loop`): it damps what departs from the motion asked for,
//! not the motion itself. `f_m` is the identified stage's. On a stage whose mass
//! differs (a mode that moved, a payload) the sensor reads more or less force
//! during a fast move, the damping takes the difference for a disturbance, and
//! its integral throws the move off (loops tuned at 856 Hz on a 700 Hz stage: a
//! 10 µm step overshoots by about 1.2 µm and settles in 5.5–6.8 ms).
//!
//! [`LeadGain`] learns the stage's mass relative to the tuned one, `β`, and the
//! damping gets `r_d − β·f_m`.
//!
//! **What is learned.** The ratio that fits the sensor's dynamic force `r_d`
//! to `f_m` during fast moves, `α`, is a closed-loop quantity, not the mass
//! ratio itself: on the tuned stage it settles near 0.88, not 1, because the
//! loops and the damping shape the force the sensor reads. So the model
//! carries the value `α_b` it settles at on the stage it was tuned on
//! ([`LeadSpec::baseline`], measured by `fpi board autotune`), and the board
//! learns `β = α/α_b`, which is 1 on that stage and the mass ratio on another
//! (about 1.5 on a stage whose mode fell from 856 to 700 Hz):
//!
//! ```text
//! e = r_d − α_b·β·f_m                 the fit's error, N
//! β ← β + μ·e·M·a                     (the step held to ±2⁻⁶, β to [1/2, 2))
//! ```
//!
//! **The instrument.** One gain fitted by least squares on `f_m` itself would
//! drift: most of `f_m` is not inertial (with the preview `n` ticks ahead,
//! `S − x_ref` on a ramp is about the velocity times `n` ticks), so it would fit
//! a lag and the mass together, in proportions that depend on the motion. The
//! update therefore correlates the error with the inertial force the tracked
//! reference asks for, `M·a`: its acceleration `a` (µm/tick²,
//! the tracked reference's second difference `x_k − 2x_{k−1} + x_{k−2}`)
//! times the stage's mass `M`
//! (`κ/(2π·f_n/f_s)²`, N per µm/tick²). Over a move velocity and
//! acceleration are orthogonal (a step's velocity is even about its middle,
//! its acceleration odd; a triangle accelerates at its turns, where its
//! velocity is zero), so a lag leaves `β` nearly where it is (20 % of lag
//! misread moves it by about 2 %). Slow scans ask for almost no inertial force
//! and barely move it; a held reference does not move it at all. `μ` is
//! 2⁻⁸ per N², `M` is rounded to a power of two ([`LeadSpec::mass_log2`]) and
//! `a` held to ±½ µm/tick² (2·10⁸ µm/s², beyond any stage's motion), so the
//! update is one 32-bit multiply's high word and shifts (`e` taken to
//! 1/256 N within ±128 N, the step to 2⁻¹⁶): a 10 µm step in 1.5 ms asks for up to
//! about 5 N for a millisecond, and `β` covers about half the way to a new
//! stage's ratio in one step. (On the emulated board a faster update — 2⁻⁷,
//! or steps up to 2⁻⁵ — learns a 700 Hz stage's ratio in fewer steps but
//! lets `β` wander on the tuned stage and slows its steps; 2⁻⁹ learns too
//! slowly for the first step on a changed stage; a faster rate for the
//! first step after a load only helps a changed stage by slowing the tuned
//! one's: book, `docs/src/mass-ratio.md`, *Why the first step on a heavier
//! stage misses*.)
//!
//! **What it learns from.** The fit's ratio depends on the motion, not only
//! on the stage: on the emulated stage as built, whose steps hold `β` at 1,
//! five periods of a 15 Hz sine took it to 0.92 (a force error that follows
//! the position correlates with a sine's acceleration), 100 Hz triangles to
//! 0.74, ±0.2 µm sines near the mode to 1.5–2. So the caller says when to
//! learn: the board learns from its step commands (raised cosines, the motion
//! autotune measures `α_b` on) and holds `β` through every other motion. The
//! ratio depends on the step's speed too (`α_b` is measured on 1.5 ms steps):
//! on the stage as built eight 10 ↔ 20 µm steps of 1.0 ms took `β` to 1.22
//! and their settling from 1.45 to 3.8 ms, so the board learns only from
//! steps at least as long as autotune's (`firmware::reference`'s
//! `LEARNING_STEP_TICKS`; figures in the book's `docs/src/measured-figures.md`).
//!
//! **Where it starts.** A new model starts `β` at 1: the first step on a
//! heavier stage is then made with the tuned mass (book,
//! `docs/src/mass-ratio.md`, *Why the first step on a heavier stage misses*).
//! [`LeadGain::starting_at`] starts it at a ratio measured before that step:
//! `fpi board load --match-mass` measures the stage's mode and sends
//! `(f_model/f_stage)²` (the board's `LeadRatio` command).
//!
//! A model without a baseline (what autotune loads to measure it) learns `α`
//! (`α_b = 1`) and does not apply it: its damping gets `r_d − f_m`.
//!
//! | quantity | unit | format | range |
//! |---|---|---|---|
//! | `r_d`, `e`, output | N | `I16F16` | saturated to the format |
//! | `f_m` | N | `I16F16` | within ±4096 (the signals' range: `S − x_ref` held to `4096 N/κ`), so `β·f_m` and `α_b·β·f_m` need no saturation |
//! | `e` in the update | N | 1/256 N | ±128 |
//! | the update's step | 1 | `I2F30`, multiples of 2⁻¹⁶ | ±2⁻⁶ |
//! | κ ([`LeadSpec::force_gain`]) | N/µm | `I16F16` | ≥ 0 |
//! | `S − x_ref`, `a` | µm, µm/tick² | `I16F16` | |
//! | `β`, `α_b` | 1 | `I2F30` ([`LeadRatio`]) | `β` in `[1/2, 2)` from 1; `α_b` in `[1/2, 2)` |
//!
//! Every product is exact in `i64` before one truncation; no division, no
//! panic. The update's inputs are truncated as the table says: against its
//! f64 law, one tick's `β` is within 8·10⁻⁵ (the step's 2⁻¹⁶, and 1/256 N of
//! `e` times `μ·M·|a|`).

use crate::damping::DynamicsSpec;
use crate::process::SplitProcess;
use crate::q::{LeadRatio, Micrometres, Newtons, NewtonsPerUm};

/// `1` in raw [`LeadRatio`] bits.
pub const ONE: i32 = 1 << 30;
/// The least `β`, and the least baseline a model may carry: one half.
pub const RATIO_MIN: LeadRatio =
    LeadRatio::from_bits(crate::fields::Field::LeadBaseline.decl().bits().0 as i32);
/// `μ = 2^-ADAPT_SHIFT` per N² and tick.
pub const ADAPT_SHIFT: u32 = 8;
/// The largest `log₂ M` the rate takes (a heavier stage learns more slowly).
pub const MASS_LOG2_MAX: u8 = 15;
/// `|a|` is held to ½ µm/tick² (raw `I16F16`) before it is scaled by `M`.
const ACCEL_MAX: i32 = 1 << 15;
/// The largest change of `β` in one tick, raw bits (2⁻⁶).
pub const STEP_MAX: i32 = ONE >> 6;
/// The fit's error is held to ±128 N (±2¹⁵ in 1/256 N) in the update.
const E8_MAX: i32 = 1 << 15;
/// The update's product `e·M·a·2⁻²⁴` (raw) becomes `μ·e·M·a` in `I2F30` bits
/// shifted left by this: `2 + ADAPT_SHIFT + Q_SHIFT = 24`.
const Q_SHIFT: u32 = 22 - ADAPT_SHIFT;
/// The product held to the largest step, before the shift.
const Q_MAX: i32 = STEP_MAX >> Q_SHIFT;

/// What the lead needs of the model (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeadSpec {
    /// κ: the dynamic force per µm of `S − x_ref`, N/µm, `I16F16`.
    pub force_gain: NewtonsPerUm,
    /// `|S − x_ref|` is held to this, µm (`I16F16`): `4096 N/κ` rounded down,
    /// so that `f_m` stays within ±4096 N without a wide clamp.
    pub moved_max: Micrometres,
    /// `log₂ M`, `M` the stage's mass (N per µm/tick²) rounded to a power of
    /// two, held to `0..=MASS_LOG2_MAX` (0 also where the model declares no κ).
    pub mass_log2: u8,
    /// `α_b`, the fit's ratio on the tuned stage (1 where the model has none).
    pub baseline: LeadRatio,
    /// The model carries `α_b`: the damping gets `r_d − β·f_m` (else `r_d − f_m`).
    pub applied: bool,
}

impl LeadSpec {
    /// The lead of the stage the model declares (a checked [`DynamicsSpec`]: its
    /// mode above 1 Hz), at control rate `rate_hz`, with the model's baseline if
    /// it has one. `f32` and integer arithmetic, once per model (not in the
    /// ISR): the mass is `κ/(2π·f_n/f_s)²`, N per µm/tick².
    pub fn of(d: &DynamicsSpec, rate_hz: u32, baseline: Option<LeadRatio>) -> Self {
        let w = core::f32::consts::TAU * d.mode_mhz as f32 / 1000.0 / rate_hz as f32;
        let mass = d.force_gain.to_num::<f32>() / (w * w);
        // log₂ M rounded, from the float's exponent (no libm): M·√2's.
        let log2 = if mass > 0.0 {
            ((mass * core::f32::consts::SQRT_2).to_bits() >> 23) as i32 - 127
        } else {
            0
        };
        // κ·moved_max ≤ 4096 N in raw bits: 2⁴⁴ over κ's bits, rounded down
        // (integer arithmetic: no float-to-fixed conversion that could panic).
        let k = i64::from(d.force_gain.to_bits());
        let moved_max = if k > 0 {
            let m = (1i64 << 44) / k;
            Micrometres::from_bits(m.min(i64::from(i32::MAX)) as i32)
        } else {
            Micrometres::MAX
        };
        Self {
            force_gain: d.force_gain,
            moved_max,
            mass_log2: log2.clamp(0, i32::from(MASS_LOG2_MAX)) as u8,
            baseline: baseline.unwrap_or(LeadRatio::from_bits(ONE)),
            applied: baseline.is_some(),
        }
    }
}

/// The learned ratio `β` (state; see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeadGain {
    beta: LeadRatio,
}

impl Default for LeadGain {
    fn default() -> Self {
        Self::new()
    }
}

impl LeadGain {
    /// `β = 1`: the tuned stage.
    pub const fn new() -> Self {
        Self {
            beta: LeadRatio::from_bits(ONE),
        }
    }

    /// `β` starting at `ratio` (a mass ratio measured before the first step,
    /// e.g. from the stage's mode), where it lies in `[1/2, 2)`; `None` else.
    pub const fn starting_at(ratio: LeadRatio) -> Option<Self> {
        if ratio.to_bits() >= RATIO_MIN.to_bits() {
            Some(Self { beta: ratio })
        } else {
            None
        }
    }

    /// `β`, the stage's mass over the tuned one's (over the identified one's,
    /// scaled by the fit, where the model has no baseline).
    pub const fn ratio(&self) -> LeadRatio {
        self.beta
    }
}

/// The explained force's block: dynamic force, lead, acceleration and whether
/// to learn in, the force left for the damping out.
impl SplitProcess<(Newtons, Micrometres, Micrometres, bool), Newtons, LeadGain> for LeadSpec {
    /// The force left for the damping (N) from the dynamic force `dynamic`, the
    /// shaped reference's lead `moved = S_{k−1} − x_ref` (µm) and the tracked
    /// reference's acceleration `accel` (µm/tick²); where `learn`, `β` takes one
    /// step (see the module docs). Saturating, no division, no panic.
    #[inline]
    fn process(
        &self,
        gain: &mut LeadGain,
        (dynamic, moved, accel, learn): (Newtons, Micrometres, Micrometres, bool),
    ) -> Newtons {
        let r = dynamic.to_bits();
        // f_m: I16F16 × I16F16 → I16F16, within ±4096 N by the held lead
        // (κ ≥ 0 and κ·moved_max ≤ 4096 N).
        let mm = self.moved_max.to_bits();
        #[allow(clippy::manual_clamp)]
        let m = moved.to_bits().max(-mm).min(mm);
        let fm = ((i64::from(self.force_gain.to_bits()) * i64::from(m)) >> 16) as i32;
        let beta = gain.beta.to_bits();
        // β·f_m and α_b·β·f_m (I2F30 × I16F16 → I16F16): below 2¹³ and 2¹⁴ N.
        let scaled = ((i64::from(beta) * i64::from(fm)) >> 30) as i32;
        let fit = ((i64::from(self.baseline.to_bits()) * i64::from(scaled)) >> 30) as i32;
        let e = r.saturating_sub(fit);
        // μ·e·M·a in 32 bits: e to 1/256 N within ±128 N (in the high half),
        // M·a (I16F16 bits, below 2³⁰), their product's high word (e·M·a·2⁻²⁴
        // in raw bits), held to the largest step and shifted to I2F30 (2⁻¹⁶
        // resolution).
        #[allow(clippy::manual_clamp)]
        let e8 = (e >> 8).max(-E8_MAX).min(E8_MAX - 1) << 16;
        #[allow(clippy::manual_clamp)]
        let a = accel.to_bits().max(-ACCEL_MAX).min(ACCEL_MAX - 1);
        let inertial = a << (self.mass_log2 & 15);
        let q = ((i64::from(e8) * i64::from(inertial)) >> 32) as i32;
        #[allow(clippy::manual_clamp)]
        let d = q.max(-Q_MAX).min(Q_MAX - 1) << Q_SHIFT;
        let next = beta.saturating_add(d).max(RATIO_MIN.to_bits());
        if learn {
            gain.beta = LeadRatio::from_bits(next);
        }
        let left = if self.applied { scaled } else { fm };
        Newtons::from_bits(r.saturating_sub(left))
    }
}

#[cfg(test)]
mod tests;
