//! The force channel: the reading split into the preload the FPI uses and the
//! dynamic force the damping gets, and the learned correction of the FEM's
//! preload map (see the parent module's docs for the law and its formats).

use super::Window;
use crate::error::{Field, Invalid, ModelError};
use crate::q::{CreepRate, Newtons, SIGNAL_ABS_MAX_BITS};

/// How the force reading is split and checked (configuration, see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceChannel {
    /// Per-tick rate `a` of the slow part's low-pass, `I0F32` (`1 − e^{−2π·f_c/f_s}`);
    /// 0: no split, the reading is used as it is.
    pub split: CreepRate,
    /// Largest tolerated `|F − f_F(x_pea_est)|` at once, N (the dynamic force
    /// included); the slow part is held to [`Supervision::force_tolerance`](super::Supervision::force_tolerance).
    pub dynamic_limit: Newtons,
}

/// The force channel's scale adaptation: `b` moves by `2⁻¹⁸·r_s·Δ` per tick
/// (N², `Δ = f_F(x̂) − f_F(x_0)`): at 20 kHz and a 10 N swing of the preload, a
/// time constant of 0.13 s. As a shift of the `I32F32` product into `b`'s
/// `I0F32`: `18 + 32 − 32` (rounded toward −∞).
pub const SCALE_ADAPT_SHIFT: u32 = 18;
/// The force channel's offset adaptation: `r_0` moves by `2⁻¹¹·r_s` per tick
/// (a time constant of 0.1 s at 20 kHz), so that an offset the tare missed (a
/// stage that settled after it) does not bias the scale.
pub const OFFSET_ADAPT_SHIFT: u32 = 11;
/// Largest learned scale error `|b|` (`I0F32` bits): 0.25 (`b` is held to
/// `[−2³⁰, 2³⁰ − 1]`, one `ssat`).
pub(super) const SCALE_MAX_BITS: i32 = 1 << 30;
/// The slow part `r_s` the scale's step takes, held to `[−2²¹, 2²¹ − 1]`
/// (`I16F16` bits: ±32 N).
pub const SCALE_ERROR_MAX_BITS: i32 = 1 << 21;
/// The preload's change `Δ` the scale's step takes, held to `[−2²⁷, 2²⁷ − 1]`
/// (`I16F16` bits: ±2048 N). With [`SCALE_ERROR_MAX_BITS`], `|r_s·Δ| ≤ 2⁴⁸`:
/// the step is at most 2³⁰, and `b` plus it cannot overflow 32 bits.
pub const DELTA_MAX_BITS: i32 = 1 << 27;
/// Half an `I16F16` LSB in `I16F48` (raw `i64`): the rounding bias `r_s` and
/// `r_0` carry.
pub(super) const HALF_LSB_I16F48: i64 = 1 << 31;

/// The high word of an `I16F48` (raw `i64`): the `I16F16` bits, rounded for a
/// value stored with [`HALF_LSB_I16F48`].
#[inline(always)]
pub(super) const fn hi_word(x: i64) -> i32 {
    (x >> 32) as i32
}

/// The force channel's default split corner, Hz: well above the motion a preload
/// change follows, well below any first mode of a stage.
pub const DEFAULT_SPLIT_HZ: u32 = 10;

/// The force channel's split rate `a = 1 − e^{−2π·f_c/f_s}` for a corner
/// `corner_hz` at a control rate `rate_hz`, `I0F32` (its Taylor series to the fourth
/// power in integer arithmetic, exact to 10⁻⁶ of `a` up to `f_c/f_s = 1/64`); 0 for
/// a zero corner or rate, or a corner above `f_s/64`.
pub const fn split_rate(corner_hz: u32, rate_hz: u32) -> CreepRate {
    if corner_hz == 0 || rate_hz == 0 || corner_hz as u64 * 64 > rate_hz as u64 {
        return CreepRate::ZERO;
    }
    // x = 2π·f_c/f_s in units of 2⁻³²; a = x − x²/2 + x³/6 − x⁴/24.
    const TWO_PI_Q32: u128 = 26_986_075_409; // round(2π·2³²)
    let x = (TWO_PI_Q32 * corner_hz as u128 / rate_hz as u128) as i128;
    let x2 = (x * x) >> 32;
    let x3 = (x2 * x) >> 32;
    let x4 = (x3 * x) >> 32;
    let a = x - x2 / 2 + x3 / 6 - x4 / 24;
    CreepRate::from_bits(a as i32)
}

/// What the force channel gives one tick: the force the FPI uses and the dynamic
/// force, N.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Forces {
    /// The sensor's reading.
    pub reading: Newtons,
    /// `f_F(x_pea_est) + r_s`: the force the inverse and the virtual sensor use
    /// (the reading itself without a split).
    pub feedforward: Newtons,
    /// `r_d = F_read − f_F(x_pea_est) − r_s`: the dynamic force (0 without a
    /// split, or for a reading outside the sensor's range).
    pub dynamic: Newtons,
    /// The reading lies in the sensor's range.
    pub in_range: bool,
}

/// `x + 2⁻¹¹·rs` for an `I16F48` `x` (raw `i64`) and an `I16F16` `rs` (raw
/// `i32`), exact and wrapping ([`OFFSET_ADAPT_SHIFT`]): written as its two words
/// with the carry, so that it is one `adds` and one `adc` with shifted operands.
#[inline(always)]
pub(super) const fn add_shifted(x: i64, rs: i32) -> i64 {
    let (lo, carry) = (x as u32).overflowing_add((rs as u32) << (32 - OFFSET_ADAPT_SHIFT));
    let hi = ((x >> 32) as i32)
        .wrapping_add(rs >> OFFSET_ADAPT_SHIFT)
        .wrapping_add(carry as i32);
    ((hi as i64) << 32) | lo as i64
}

/// `reading − model` (N): exact for readings and maps inside ±4096 N.
#[inline(always)]
pub(super) const fn residual(reading: Newtons, model: Newtons) -> Newtons {
    Newtons::from_bits(reading.to_bits().wrapping_sub(model.to_bits()))
}

/// Checks a force channel against the force tolerance: the split rate in
/// `[0, 0.5)`, the dynamic limit at least the tolerance and inside the signal
/// range. The one check, shared by [`check_settings`](super::check_settings) and
/// the model validator.
pub const fn check_force_channel(c: &ForceChannel, tolerance: Newtons) -> Result<(), Invalid> {
    match force_channel_window(c, tolerance) {
        Ok(_) => Ok(()),
        Err(e) => Err(e),
    }
}

/// [`check_force_channel`], and the window of the dynamic limit.
pub(super) const fn force_channel_window(
    c: &ForceChannel,
    tolerance: Newtons,
) -> Result<Window, Invalid> {
    let a = c.split.to_bits();
    if a < 0 {
        return Err(Invalid::at(
            Field::ForceSplit,
            ModelError::CreepRateOutOfRange,
        ));
    }
    let lim = c.dynamic_limit.to_bits();
    if lim < tolerance.to_bits() || lim > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(
            Field::ForceDynamicLimit,
            ModelError::DynamicLimitBelowTolerance,
        ));
    }
    match Window::new(-lim, lim) {
        Some(w) => Ok(w),
        None => Err(Invalid::at(
            Field::ForceDynamicLimit,
            ModelError::NonPositiveTolerance,
        )),
    }
}
