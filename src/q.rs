//! Fixed-point formats of every quantity in the core (the "Q contract").
//!
//! | type | unit | `fixed` type | resolution (1 LSB) | accepted range |
//! |---|---|---|---|---|
//! | [`Volts`] | V | `I16F16` | 15.3 µV | ±4096 (inputs clamped to the model's domain, e.g. 0–150 V) |
//! | [`Micrometres`] | µm | `I16F16` | 15.3 pm | ±4096 |
//! | [`Newtons`] | N | `I16F16` | 15.3 µN | ±4096 |
//! | [`NewtonsPerUm`] | N/µm | `I16F16` | 15.3 µN/µm | ≥ 0 (the dynamic force gain κ) |
//! | [`UmPerVolt`] | µm/V | `I4F28` | 3.7·10⁻⁹ | ±8 (forward PI weights `w0`, `w_i`) |
//! | [`VoltsPerNewton`] | V/N | `I0F32` | 2.3·10⁻¹⁰ | ±0.5 (force–voltage coupling `k_f`; stacks: 0.01–0.2) |
//! | [`UmPerNewton`] | µm/N | `I0F32` | 2.3·10⁻¹⁰ | ±0.5 (stack compliance `c`; stacks: 0.005–0.1) |
//! | [`VoltsPerNewton2`] | V/N² | `I0F32` | 2.3·10⁻¹⁰ | ±0.00195 (curvature `k_q` of the preload offset) |
//! | [`CreepRate`] | 1/sample | `I0F32` | 2.3·10⁻¹⁰ | (0, 0.5) (`1 - a` of a creep lag) |
//! | creep memory | V | `I16F48` (raw `i64`) | 3.6·10⁻¹⁵ | ±4096 |
//! | [`VoltsPerUm`] | V/µm | `I10F22` | 2.4·10⁻⁷ | ±512 (inverse PI weights `w0'`, `w'_j`) |
//! | [`LoopGain`] | 1 (µm/µm), 1/tick | `I8F24` | 6.0·10⁻⁸ | kp 0–16, ki 0–1 per tick (position feedback) |
//! | [`LeadRatio`] | 1 | `I2F30` | 9.3·10⁻¹⁰ | [1/2, 2) (the explained force's mass ratio, `crate::lead`) |
//! | feedback integrator | µm | `I24F40` (raw `i64`) | 9.1·10⁻¹³ | ±4096 |
//!
//! Sums of products are accumulated exactly in 64 bits ([`GainAcc`] = `I20F44` for
//! gain × signal, [`InvGainAcc`] = `I26F38` for inverse gain × signal) and rounded
//! to nearest once, when narrowed back to a signal. A coupling × force product is
//! the rounded high word of one 32 × 32-bit multiply. The model constructors check
//! that every accumulator stays inside its range for inputs in the model's domain,
//! so the hot path needs no saturation and has no overflow.
//!
//! [`Volts`], [`Micrometres`] and [`Newtons`] are three distinct types
//! (`#[repr(transparent)]` newtypes over `I16F16`, with `I16F16`'s API inlined),
//! not aliases of one: the compiler refuses a voltage where a position or a force
//! is meant, and a product that changes the unit (gain × signal) is written
//! through a named helper or the raw bits, never by accident. They cost no
//! instruction: `cargo isr-bench` counts no more per phase than with the bare type.
//!
//! One 16-bit DAC LSB over 0–150 V is 2.29 mV = 150 LSB of [`Volts`]; one nm is
//! 65.5 LSB of [`Micrometres`].

use fixed::types::{I0F32, I10F22, I16F16, I20F44, I26F38, I2F30, I4F28, I8F24};

include!("qformat.rs");

/// A position-feedback gain: proportional (µm/µm) or integral (per tick), `I8F24`.
pub type LoopGain = I8F24;
const _: () = assert!(LoopGain::FRAC_NBITS == LOOP_GAIN_FRAC);

mod unit;
pub use unit::Signal;

unit::unit! {
    /// Electric potential in volts, `I16F16` (a distinct type: see [`q`](self)).
    Volts
}
unit::unit! {
    /// Length in micrometres, `I16F16` (a distinct type: see [`q`](self)).
    Micrometres
}
unit::unit! {
    /// Force in newtons, `I16F16` (a distinct type: see [`q`](self)).
    Newtons
}
/// The dynamic force per µm of command (the stage's stiffness above its mode,
/// κ of [`crate::damping`] and [`crate::lead`]), newtons per µm, `I16F16`: a
/// gain, not a force.
pub type NewtonsPerUm = I16F16;
/// Forward PI weight, µm per volt, `I4F28`.
pub type UmPerVolt = I4F28;
/// Force–voltage coupling `k_f`, volts per newton, `I0F32`.
pub type VoltsPerNewton = I0F32;
/// Stack compliance, µm per newton, `I0F32`.
pub type UmPerNewton = I0F32;
/// Curvature of the preload offset, volts per newton², `I0F32`.
pub type VoltsPerNewton2 = I0F32;
/// Per-sample rate `1 - a` of a creep lag, `I0F32`.
pub type CreepRate = I0F32;
/// Inverse PI weight, volts per µm, `I10F22`.
pub type VoltsPerUm = I10F22;
/// The explained force's mass ratio (`crate::lead`), `I2F30`.
pub type LeadRatio = I2F30;
/// Exact product accumulator of a forward gain and a signal, `I20F44`.
pub type GainAcc = I20F44;
/// Exact product accumulator of an inverse gain and a signal, `I26F38`.
pub type InvGainAcc = I26F38;

const _: () = {
    assert!(Volts::FRAC_NBITS == SIGNAL_FRAC);
    assert!(UmPerVolt::FRAC_NBITS == GAIN_FRAC);
    assert!(VoltsPerNewton::FRAC_NBITS == COUPLING_FRAC);
    assert!(VoltsPerUm::FRAC_NBITS == INV_GAIN_FRAC);
    assert!(GainAcc::FRAC_NBITS == GAIN_FRAC + SIGNAL_FRAC);
    assert!(InvGainAcc::FRAC_NBITS == INV_GAIN_FRAC + SIGNAL_FRAC);
};

/// Raw bits of [`SIGNAL_ABS_MAX`] in a signal (`I16F16`).
pub(crate) const SIGNAL_ABS_MAX_BITS: i32 = (SIGNAL_ABS_MAX as i32) << SIGNAL_FRAC;

/// Fractional bits of the dimensionless `I8F24` coefficients: the biquad
/// sections' (`crate::biquad::Coefficient`) and the feedforward's taps
/// (`crate::preview`); range ±128, resolution 2⁻²⁴.
pub const COEFF_FRAC: u32 = 24;

/// Rounds a gain × signal accumulator to the nearest signal LSB (ties toward +∞).
///
/// Callers guarantee `|acc| < SIGNAL_ABS_MAX`, which the model constructors check.
#[inline(always)]
pub(crate) const fn narrow_gain(acc: GainAcc) -> Micrometres {
    const SHIFT: u32 = GAIN_FRAC;
    Micrometres::from_bits(((acc.to_bits() + (1 << (SHIFT - 1))) >> SHIFT) as i32)
}

/// Rounds an inverse-gain × signal accumulator to the nearest signal LSB.
///
/// Callers guarantee `|acc| < SIGNAL_ABS_MAX`, which the model constructors check.
#[inline(always)]
pub(crate) const fn narrow_inv_gain(acc: InvGainAcc) -> Volts {
    const SHIFT: u32 = INV_GAIN_FRAC;
    Volts::from_bits(((acc.to_bits() + (1 << (SHIFT - 1))) >> SHIFT) as i32)
}

/// Narrows a gain × signal accumulator that already holds the rounding half LSB
/// (the bias of [`crate::play::Operators`]): the nearest signal, as [`narrow_gain`].
#[inline(always)]
pub(crate) const fn narrow_gain_biased(acc: i64) -> Micrometres {
    Micrometres::from_bits((acc >> GAIN_FRAC) as i32)
}

/// [`narrow_gain_biased`] for an inverse-gain × signal accumulator.
#[inline(always)]
pub(crate) const fn narrow_inv_gain_biased(acc: i64) -> Volts {
    Volts::from_bits((acc >> INV_GAIN_FRAC) as i32)
}

/// The bias that makes [`narrow_gain_biased`] round: half a signal LSB.
pub(crate) const GAIN_ROUND: i64 = 1 << (GAIN_FRAC - 1);
/// The bias that makes [`narrow_inv_gain_biased`] round: half a signal LSB.
pub(crate) const INV_GAIN_ROUND: i64 = 1 << (INV_GAIN_FRAC - 1);

/// Product of a force coupling (`I0F32`) and a force, rounded to a signal's
/// bits: the rounded high word of a 32 × 32-bit product.
#[inline(always)]
const fn coupling_mul_bits(c: I0F32, f: Newtons) -> i32 {
    let p = c.to_bits() as i64 * f.to_bits() as i64;
    ((p + (1 << 31)) >> COUPLING_FRAC) as i32
}

/// `k_f·F`: a force–voltage coupling (V/N) times a force, rounded to volts.
#[inline(always)]
pub(crate) const fn coupling_mul(k_f: VoltsPerNewton, f: Newtons) -> Volts {
    Volts::from_bits(coupling_mul_bits(k_f, f))
}

/// `c·F`: a compliance (µm/N) times a force, rounded to micrometres.
#[inline(always)]
pub(crate) const fn compliance_mul(c: UmPerNewton, f: Newtons) -> Micrometres {
    Micrometres::from_bits(coupling_mul_bits(c, f))
}

/// Force span (N, raw `I16F16`) over which the curvature product `quad_mul` is exact: `|F - F_q| <= 1024 N`.
pub const QUAD_FORCE_SPAN_BITS: i32 = 1024 << SIGNAL_FRAC;
/// Largest `|k_q|` (raw `I0F32`) so that `k_q·(1024 N)² <= 2048 V`.
pub const QUAD_MAX_BITS: i64 = (2048i64 << 32) / (1024 * 1024);

/// `c·d²` for a curvature `c` (V/N², `I0F32`) and a force difference `d` (N,
/// clamped to ±1024), rounded to volts: `c·d` kept to 32 fractional bits, then
/// times `d`.
#[inline(always)]
pub(crate) fn quad_mul(c: VoltsPerNewton2, d: Newtons) -> Volts {
    let d = within(
        d,
        Newtons::from_bits(-QUAD_FORCE_SPAN_BITS),
        Newtons::from_bits(QUAD_FORCE_SPAN_BITS),
    )
    .to_bits() as i64;
    let cd = (c.to_bits() as i64 * d + (1 << 15)) >> 16; // 32 fractional bits
    Volts::from_bits(((cd * d + (1 << 31)) >> 32) as i32)
}

/// `max(x, lo)` without the `Ord::clamp` panic path.
#[inline(always)]
pub(crate) fn at_least<T: PartialOrd>(x: T, lo: T) -> T {
    if x < lo {
        lo
    } else {
        x
    }
}

/// `min(x, hi)` without the `Ord::clamp` panic path.
#[inline(always)]
pub(crate) fn at_most<T: PartialOrd>(x: T, hi: T) -> T {
    if x > hi {
        hi
    } else {
        x
    }
}

/// `x` saturated to the `i32` range: the low word where the high word is its
/// sign (one compare on a Cortex-M4), else the end `x`'s sign points to.
#[inline(always)]
pub(crate) const fn saturate_i32(x: i64) -> i32 {
    let lo = x as i32;
    if lo as i64 == x {
        lo
    } else {
        ((x >> 63) as i32) ^ i32::MAX
    }
}

/// Clamps `x` to `[lo, hi]`; callers guarantee `lo <= hi` (checked at construction).
#[inline(always)]
pub(crate) fn within<T: PartialOrd>(x: T, lo: T, hi: T) -> T {
    at_most(at_least(x, lo), hi)
}

/// Quantises an `f64` to the raw bits of a format with `frac` fractional bits,
/// rounding to nearest; `None` if it is not finite or does not fit in `abs_max`.
///
/// Used by constructors that take engineering values (host tools, tests, `const`
/// model building); never on the ISR path.
pub const fn quantize(value: f64, frac: u32, abs_max: f64) -> Option<i32> {
    if !value.is_finite() || value > abs_max || value < -abs_max {
        return None;
    }
    let scaled = value * (1u64 << frac) as f64;
    // Round half away from zero, in const context (no `f64::round` in const fn).
    let r = if scaled >= 0.0 {
        (scaled + 0.5) as i64
    } else {
        (scaled - 0.5) as i64
    };
    Some(r as i32)
}

/// `I16F16` from an engineering value; `None` if not finite or beyond ±[`SIGNAL_ABS_MAX`].
pub const fn signal(value: f64) -> Option<I16F16> {
    match quantize(value, SIGNAL_FRAC, SIGNAL_ABS_MAX) {
        Some(b) => Some(I16F16::from_bits(b)),
        None => None,
    }
}

/// `I0F32` from an engineering value; `None` if not finite or beyond ±[`COUPLING_ABS_MAX`].
pub const fn coupling(value: f64) -> Option<I0F32> {
    if !value.is_finite() || value > COUPLING_ABS_MAX || value < -COUPLING_ABS_MAX {
        return None;
    }
    let scaled = value * 4_294_967_296.0;
    let r = if scaled >= 0.0 {
        scaled + 0.5
    } else {
        scaled - 0.5
    };
    Some(I0F32::from_bits(r as i64 as i32))
}

/// `I4F28` from an engineering value; `None` if not finite or beyond ±[`GAIN_ABS_MAX`].
pub const fn gain(value: f64) -> Option<I4F28> {
    match quantize(value, GAIN_FRAC, GAIN_ABS_MAX) {
        Some(b) => Some(I4F28::from_bits(b)),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saturating_to_i32_keeps_what_fits_and_holds_the_rest_at_the_ends() {
        for x in [
            0i64,
            1,
            -1,
            i32::MAX as i64,
            i32::MIN as i64,
            123_456_789,
            -987_654_321,
        ] {
            assert_eq!(saturate_i32(x), x as i32);
        }
        for x in [i32::MAX as i64 + 1, 1 << 40, i64::MAX] {
            assert_eq!(saturate_i32(x), i32::MAX);
        }
        for x in [i32::MIN as i64 - 1, -(1 << 40), i64::MIN] {
            assert_eq!(saturate_i32(x), i32::MIN);
        }
    }

    #[test]
    fn narrowing_rounds_to_nearest() {
        let half_lsb = GainAcc::from_bits(1 << (GAIN_FRAC - 1));
        assert_eq!(narrow_gain(half_lsb).to_bits(), 1);
        let below_half = GainAcc::from_bits((1 << (GAIN_FRAC - 1)) - 1);
        assert_eq!(narrow_gain(below_half).to_bits(), 0);
        let minus_below_half = GainAcc::from_bits(-((1 << (GAIN_FRAC - 1)) - 1));
        assert_eq!(narrow_gain(minus_below_half).to_bits(), 0);
    }

    #[test]
    fn quantize_rejects_non_finite_and_out_of_range() {
        assert_eq!(signal(f64::NAN), None);
        assert_eq!(signal(f64::INFINITY), None);
        assert_eq!(signal(5000.0), None);
        assert_eq!(signal(-1.5).map(I16F16::to_num::<f64>), Some(-1.5));
        assert_eq!(gain(8.5), None);
        assert_eq!(gain(0.1).map(|g| g.to_bits()), Some(26_843_546));
    }

    #[test]
    fn products_are_exact_then_rounded() {
        let f = signal(100.0).unwrap();
        let v = narrow_gain(gain(0.1).unwrap().wide_mul(f)).to_num::<f64>();
        assert!((v - 10.0).abs() < 1.0 / 65536.0);
        let v = coupling_mul(coupling(0.1).unwrap(), Newtons::from_raw(f)).to_num::<f64>();
        assert!((v - 10.0).abs() < 1.0 / 65536.0);
        let v = coupling_mul(coupling(-0.02).unwrap(), Newtons::from_num(-30.5)).to_num::<f64>();
        assert!((v - 0.61).abs() < 1.0 / 65536.0);
        let v = quad_mul(I0F32::from_num(1.655e-4), Newtons::from_num(-75.25)).to_num::<f64>();
        assert!((v - 1.655e-4 * 75.25 * 75.25).abs() < 1.0 / 65536.0, "{v}");
        let v = quad_mul(
            I0F32::from_bits(QUAD_MAX_BITS as i32),
            Newtons::from_num(4000),
        );
        assert_eq!(v.to_num::<f64>().round(), 2048.0);
        assert_eq!(coupling(0.6), None);
    }
}
