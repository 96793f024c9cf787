//! Fixed-point biquad cascade for dynamic compensation in the control ISR: a notch
//! on a lightly damped mode, or a stable inverse of that mode, as cascaded
//! second-order sections (direct form I), in the style of quartiq's `idsp`:
//! configuration ([`Biquad`], [`Cascade`]) is separate from state ([`BiquadState`],
//! [`CascadeState`]), so one configuration can serve several channels and lives in
//! flash.
//!
//! One section computes
//!
//! ```text
//! y[n] = b0·x[n] + b1·x[n-1] + b2·x[n-2] - a1·y[n-1] - a2·y[n-2]     (a0 = 1)
//! ```
//!
//! # Formats (the section's part of the Q contract)
//!
//! | quantity | `fixed` type | resolution (1 LSB) | range |
//! |---|---|---|---|
//! | coefficients `b0 b1 b2 a1 a2` ([`Coefficient`]) | `I8F24` | 6.0·10⁻⁸ | ±(128 − 2⁻²⁴); [`Biquad::from_f64`] accepts \|c\| ≤ [`COEFF_ABS_MAX`] |
//! | input, output and state `x`, `y` | `I16F16` ([`crate::q::Volts`] or [`crate::q::Micrometres`]) | 15.3 µV / 15.3 pm | input clamped to ±4096 ([`crate::q::SIGNAL_ABS_MAX`]); output saturated to the section's `[min, max]` ⊆ ±4096 |
//! | accumulator | raw `i64`, `I24F40` | 9.1·10⁻¹³ | \|acc\| < 5·2⁵⁹ + 2³² < 2⁶² (no overflow, see below) |
//! | rounding residuals `e1`, `e2` of the last two outputs | raw `i32`, units of 2⁻⁴⁰ | — | `[−2²³, 2²³)`, i.e. within ±½ output LSB |
//!
//! The coefficients have eight integer bits so that a feedforward section can
//! invert the damped stage and the loop's lag (a numerator gain of tens at high
//! frequency); 24 fractional bits place a lightly damped zero pair to 10⁻⁶ of its
//! frequency.
//!
//! Each product of a coefficient (`I8F24`) and a signal (`I16F16`) is exact in 64
//! bits. The output is rounded to nearest `I16F16` and the part rounding dropped
//! (the residual `e`, 24 bits) is kept with it, so the state holds each past output
//! to 2⁻⁴⁰: the recursion adds `−(a1·e1 + a2·e2) >> 24` (two more products), which
//! makes it the full-precision recursion up to 2⁻⁴⁰ instead of a recursion on
//! rounded outputs. Quantising the outputs therefore neither shifts the DC gain
//! (a section whose quantised coefficients have `Σb = 1 + a1 + a2` settles on a
//! constant input *exactly*) nor starts granular limit cycles behind lightly
//! damped poles; each output is the exact one rounded (±½ LSB), plus the small
//! 2⁻⁴⁰ truncation of the correction. The sum is narrowed once and saturated once,
//! to the section's limits.
//!
//! **No overflow.** The input is clamped to ±4096 (raw ±2²⁸) and every output is
//! saturated to limits inside ±4096, so every state value has |raw| ≤ 2²⁸ and
//! every coefficient |raw| ≤ 2³¹: five products stay below 5·2⁵⁹; the residual
//! correction is below 2·2³¹·2²³ >> 24 = 2³¹, the rounding half 2²³ — in all less
//! than 2⁶², inside `i64`. The hot path therefore has no division, no panic branch
//! (overflow checks on or off give the same result) and no allocation.
//!
//! **Stability** is checked when a section is built (the stability triangle
//! `|a2| < 1`, `|a1| < 1 + a2`, in exact integer arithmetic on the quantised
//! coefficients): a section that was refused never runs. Constructors are
//! `const fn` and return a [`Result`]; they never panic.
//!
//! The coefficients are designed on the host in floating point
//! (`piezo_sim::filter`: a notch, or the stable inverse of a mode, discretised by
//! the bilinear transform with pre-warping) and quantised with
//! [`Biquad::from_f64`].

use core::fmt;

use fixed::types::{I16F16, I8F24};

use crate::error::{Field, Invalid, ModelError};
use crate::process::SplitProcess;
use crate::q::{SIGNAL_ABS_MAX, SIGNAL_ABS_MAX_BITS};

/// A biquad coefficient, dimensionless, `I8F24`: range ±128, resolution 2⁻²⁴.
pub type Coefficient = I8F24;

/// Fractional bits of a [`Coefficient`] (the core's `I8F24` gains' format).
pub use crate::q::COEFF_FRAC;

/// Largest coefficient magnitude [`Biquad::from_f64`] accepts (`I8F24` holds
/// `[-128, 128 - 2⁻²⁴]`).
pub const COEFF_ABS_MAX: f64 = 127.999_99;

/// Mask of the bits the output narrowing drops (the residual).
const RESIDUAL_MASK: i64 = (1 << COEFF_FRAC) - 1;
/// Half an output LSB in accumulator units: the narrowing rounds to nearest.
const RESIDUAL_HALF: i64 = 1 << (COEFF_FRAC - 1);

/// Why a section was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BiquadError {
    /// A coefficient is not finite or outside ±[`COEFF_ABS_MAX`] (`I8F24`).
    /// `index`: 0–2 are `b0 b1 b2`, 3–4 are `a1 a2`.
    CoefficientOutOfRange {
        /// Position in `[b0, b1, b2, a1, a2]`.
        index: u8,
    },
    /// The poles are not strictly inside the unit circle (`|a2| < 1` and
    /// `|a1| < 1 + a2` fail on the quantised coefficients).
    Unstable,
    /// The output limits are empty (`min > max`), not finite, or beyond ±4096.
    LimitsOutOfRange,
}

impl BiquadError {
    /// A one-line description.
    pub const fn message(&self) -> &'static str {
        match self {
            Self::CoefficientOutOfRange { .. } => {
                "biquad coefficient not finite or outside the I8F24 range ±128"
            }
            Self::Unstable => "biquad poles not strictly inside the unit circle",
            Self::LimitsOutOfRange => "biquad output limits empty or beyond ±4096",
        }
    }
}

impl fmt::Display for BiquadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::CoefficientOutOfRange { index } => {
                write!(f, "{} (coefficient {})", self.message(), index)
            }
            _ => f.write_str(self.message()),
        }
    }
}

/// Raw bits of `I16F16` at ±[`SIGNAL_ABS_MAX`]: the input clamp and the widest limits.
const LIM: i32 = SIGNAL_ABS_MAX_BITS;

/// Clamps raw signal bits to `[lo, hi]` without a panic path.
#[inline(always)]
const fn clamp_bits(x: i64, lo: i32, hi: i32) -> i32 {
    if x < lo as i64 {
        lo
    } else if x > hi as i64 {
        hi
    } else {
        x as i32
    }
}

/// One second-order section (configuration): coefficients in `I8F24`, `a0 = 1`,
/// and output limits in `I16F16`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Biquad {
    /// Raw `I8F24` bits of `b0, b1, b2, a1, a2`.
    ba: [i32; 5],
    /// Raw `I16F16` bits of the lower output limit (≥ −4096).
    min: i32,
    /// Raw `I16F16` bits of the upper output limit (≤ 4096).
    max: i32,
}

impl Biquad {
    /// The identity section (`b0 = 1`), limits ±4096.
    pub const IDENTITY: Self = Self {
        ba: [1 << COEFF_FRAC, 0, 0, 0, 0],
        min: -LIM,
        max: LIM,
    };

    /// A section from quantised coefficients `b = [b0, b1, b2]`, `a = [a1, a2]`
    /// (`a0 = 1`), output limits ±4096; refused if its poles are not strictly
    /// inside the unit circle.
    pub const fn new(b: [Coefficient; 3], a: [Coefficient; 2]) -> Result<Self, BiquadError> {
        let ba = [
            b[0].to_bits(),
            b[1].to_bits(),
            b[2].to_bits(),
            a[0].to_bits(),
            a[1].to_bits(),
        ];
        // Stability triangle on the exact integers (scale 2³⁰):
        // |a2| < 1 and |a1| < 1 + a2.
        let one = 1i64 << COEFF_FRAC;
        let a1 = ba[3] as i64;
        let a2 = ba[4] as i64;
        let abs_a1 = if a1 < 0 { -a1 } else { a1 };
        let abs_a2 = if a2 < 0 { -a2 } else { a2 };
        if abs_a2 >= one || abs_a1 >= one + a2 {
            return Err(BiquadError::Unstable);
        }
        Ok(Self {
            ba,
            min: -LIM,
            max: LIM,
        })
    }

    /// A section from engineering coefficients (`a0 = 1`), each rounded to the
    /// nearest `I8F24`; refused if one is not finite or beyond ±[`COEFF_ABS_MAX`]
    /// ([`BiquadError::CoefficientOutOfRange`]) or the quantised poles are not
    /// stable. Host tools and `const` model building; never in the ISR.
    pub const fn from_f64(b: [f64; 3], a: [f64; 2]) -> Result<Self, BiquadError> {
        let all = [b[0], b[1], b[2], a[0], a[1]];
        let mut raw = [Coefficient::ZERO; 5];
        let mut i = 0;
        while i < 5 {
            match crate::q::quantize(all[i], COEFF_FRAC, COEFF_ABS_MAX) {
                Some(bits) => raw[i] = Coefficient::from_bits(bits),
                None => return Err(BiquadError::CoefficientOutOfRange { index: i as u8 }),
            }
            i += 1;
        }
        Self::new([raw[0], raw[1], raw[2]], [raw[3], raw[4]])
    }

    /// The same section with `b1` set so that its static gain is exactly 1
    /// (`b0 + b1 + b2 = 1 + a1 + a2` in raw bits): what rounding each coefficient
    /// to `I8F24` on its own leaves off, for a design of unit gain. Refused if that
    /// `b1` leaves the format.
    pub const fn with_unit_static_gain(self) -> Result<Self, BiquadError> {
        let [b0, _, b2, a1, a2] = self.ba;
        let b1 = (1i64 << COEFF_FRAC) + a1 as i64 + a2 as i64 - b0 as i64 - b2 as i64;
        if b1 < i32::MIN as i64 || b1 > i32::MAX as i64 {
            return Err(BiquadError::CoefficientOutOfRange { index: 1 });
        }
        Ok(Self {
            ba: [b0, b1 as i32, b2, a1, a2],
            ..self
        })
    }

    /// The same section with its output saturated to `[min, max]` (`I16F16`);
    /// refused unless `-4096 <= min <= max <= 4096`.
    pub const fn with_limits(self, min: I16F16, max: I16F16) -> Result<Self, BiquadError> {
        let (lo, hi) = (min.to_bits(), max.to_bits());
        if lo > hi || lo < -LIM || hi > LIM {
            return Err(BiquadError::LimitsOutOfRange);
        }
        Ok(Self {
            min: lo,
            max: hi,
            ..self
        })
    }

    /// `[b0, b1, b2]`.
    pub const fn b(&self) -> [Coefficient; 3] {
        [
            Coefficient::from_bits(self.ba[0]),
            Coefficient::from_bits(self.ba[1]),
            Coefficient::from_bits(self.ba[2]),
        ]
    }

    /// `[a1, a2]` (`a0 = 1`).
    pub const fn a(&self) -> [Coefficient; 2] {
        [
            Coefficient::from_bits(self.ba[3]),
            Coefficient::from_bits(self.ba[4]),
        ]
    }

    /// The output limits `(min, max)`, `I16F16`.
    pub const fn limits(&self) -> (I16F16, I16F16) {
        (I16F16::from_bits(self.min), I16F16::from_bits(self.max))
    }

    /// The DC gain of the quantised section, `Σb / (1 + a1 + a2)` (host checks).
    pub fn dc_gain(&self) -> f64 {
        let one = (1i64 << COEFF_FRAC) as f64;
        let num = (self.ba[0] as i64 + self.ba[1] as i64 + self.ba[2] as i64) as f64;
        let den = (1i64 << COEFF_FRAC) as f64 + self.ba[3] as f64 + self.ba[4] as f64;
        (num / one) / (den / one)
    }

    /// The section's arithmetic on raw bits: input `x`, input history `xh`, output
    /// history `yh` with its residuals `eh` (updated); returns the saturated output.
    #[inline(always)]
    fn section(&self, x: i32, xh: [i32; 2], yh: [i32; 2], eh: &mut [i32; 2]) -> i32 {
        let [b0, b1, b2, a1, a2] = self.ba;
        // The past outputs' dropped fractions, `a1·e1 + a2·e2`, in accumulator units.
        let corr = (a1 as i64 * eh[0] as i64 + a2 as i64 * eh[1] as i64) >> COEFF_FRAC;
        let acc = b0 as i64 * x as i64 + b1 as i64 * xh[0] as i64 + b2 as i64 * xh[1] as i64
            - a1 as i64 * yh[0] as i64
            - a2 as i64 * yh[1] as i64
            - corr
            + RESIDUAL_HALF;
        *eh = [((acc & RESIDUAL_MASK) - RESIDUAL_HALF) as i32, eh[0]];
        clamp_bits(acc >> COEFF_FRAC, self.min, self.max)
    }
}

/// One sample through the section: `x` (clamped to ±4096) in, `y` out, both
/// `I16F16`; 7 exact 32 × 32 → 64-bit products (5 taps, 2 residual
/// corrections), one rounding shift, one saturation. No division, no panic.
impl SplitProcess<I16F16, I16F16, BiquadState> for Biquad {
    #[inline]
    fn process(&self, state: &mut BiquadState, x: I16F16) -> I16F16 {
        let x = clamp_bits(x.to_bits() as i64, -LIM, LIM);
        let y = self.section(x, state.x, state.y, &mut state.e);
        state.x = [x, state.x[0]];
        state.y = [y, state.y[0]];
        I16F16::from_bits(y)
    }
}

impl Default for Biquad {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// The memory of one [`Biquad`]: the last two inputs and outputs (`I16F16` raw
/// bits, |·| ≤ 4096) and the outputs' rounding residuals (`[−2²³, 2²³)`, units of
/// 2⁻⁴⁰).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BiquadState {
    x: [i32; 2],
    y: [i32; 2],
    e: [i32; 2],
}

impl BiquadState {
    /// At rest (all zero).
    pub const fn new() -> Self {
        Self {
            x: [0; 2],
            y: [0; 2],
            e: [0; 2],
        }
    }

    /// The state of a section with unity DC gain that has settled on the constant
    /// `v` (inputs and outputs `v`): start a compensator without a transient.
    pub const fn settled(v: I16F16) -> Self {
        let v = clamp_bits(v.to_bits() as i64, -LIM, LIM);
        Self {
            x: [v; 2],
            y: [v; 2],
            e: [0; 2],
        }
    }

    /// The last output, `I16F16`.
    pub const fn output(&self) -> I16F16 {
        I16F16::from_bits(self.y[0])
    }
}

/// `M` sections in series (configuration). `M = 0` is the identity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cascade<const M: usize> {
    sections: [Biquad; M],
}

impl<const M: usize> Cascade<M> {
    /// The identity cascade (every section [`Biquad::IDENTITY`]).
    pub const IDENTITY: Self = Self {
        sections: [Biquad::IDENTITY; M],
    };

    /// A cascade of validated sections, applied in order.
    pub const fn new(sections: [Biquad; M]) -> Self {
        Self { sections }
    }

    /// The sections.
    pub const fn sections(&self) -> &[Biquad; M] {
        &self.sections
    }

    /// A state at rest for this cascade.
    pub const fn initial_state(&self) -> CascadeState<M> {
        CascadeState::new()
    }

    /// The product of the sections' DC gains (host checks).
    pub fn dc_gain(&self) -> f64 {
        self.sections.iter().map(Biquad::dc_gain).product()
    }
}

impl<const M: usize> SplitProcess<I16F16, I16F16, CascadeState<M>> for Cascade<M> {
    /// One sample through every section: `x` (`I16F16`, clamped to ±4096) in, the
    /// last section's output out. Consecutive sections share their histories (the
    /// output history of section `k` is the input history of section `k + 1`), so
    /// the state holds `2(M + 1)` signals. No division, no panic.
    #[inline]
    fn process(&self, state: &mut CascadeState<M>, x: I16F16) -> I16F16 {
        let mut u = clamp_bits(x.to_bits() as i64, -LIM, LIM);
        let mut xh = state.x;
        state.x = [u, xh[0]];
        for ((s, yh), e) in self
            .sections
            .iter()
            .zip(state.y.iter_mut())
            .zip(state.e.iter_mut())
        {
            let old = *yh;
            let y = s.section(u, xh, old, e);
            *yh = [y, old[0]];
            xh = old;
            u = y;
        }
        I16F16::from_bits(u)
    }
}

impl<const M: usize> Default for Cascade<M> {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// The memory of a [`Cascade`]: the input history, each section's output history
/// (`I16F16` raw bits, |·| ≤ 4096) and rounding residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CascadeState<const M: usize> {
    x: [i32; 2],
    y: [[i32; 2]; M],
    e: [[i32; 2]; M],
}

impl<const M: usize> CascadeState<M> {
    /// At rest (all zero).
    pub const fn new() -> Self {
        Self {
            x: [0; 2],
            y: [[0; 2]; M],
            e: [[0; 2]; M],
        }
    }

    /// Settled on the constant `v` everywhere (for a cascade of unity DC gain):
    /// start a compensator without a transient.
    pub const fn settled(v: I16F16) -> Self {
        let v = clamp_bits(v.to_bits() as i64, -LIM, LIM);
        Self {
            x: [v; 2],
            y: [[v; 2]; M],
            e: [[0; 2]; M],
        }
    }

    /// The cascade's last output (its input if `M = 0`), `I16F16`.
    pub const fn output(&self) -> I16F16 {
        if M == 0 {
            I16F16::from_bits(self.x[0])
        } else {
            I16F16::from_bits(self.y[M - 1][0])
        }
    }
}

impl<const M: usize> Default for CascadeState<M> {
    fn default() -> Self {
        Self::new()
    }
}

const _: () = assert!(SIGNAL_ABS_MAX == 4096.0 && LIM == 1 << 28);

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64) -> I16F16 {
        I16F16::from_num(x)
    }

    #[test]
    fn identity_passes_signals_through() {
        let mut s = BiquadState::new();
        for x in [0.0, 1.5, -3.25, 4000.0, 150.0] {
            assert_eq!(Biquad::IDENTITY.process(&mut s, v(x)), v(x));
        }
        let c = Cascade::<2>::IDENTITY;
        let mut st = c.initial_state();
        assert_eq!(c.process(&mut st, v(12.5)), v(12.5));
        assert_eq!(st.output(), v(12.5));
    }

    #[test]
    fn out_of_format_and_unstable_are_refused() {
        assert_eq!(
            Biquad::from_f64([1.0, 140.0, 0.0], [0.0, 0.0]),
            Err(BiquadError::CoefficientOutOfRange { index: 1 })
        );
        assert_eq!(
            Biquad::from_f64([1.0, 0.0, 0.0], [0.0, f64::NAN]),
            Err(BiquadError::CoefficientOutOfRange { index: 4 })
        );
        assert_eq!(
            Biquad::from_f64([1.0, 0.0, 0.0], [-130.0, 1.0]),
            Err(BiquadError::CoefficientOutOfRange { index: 3 })
        );
        assert_eq!(
            Biquad::from_f64([1.0, 0.0, 0.0], [-2.0, 1.0]),
            Err(BiquadError::Unstable)
        );
        // A pole on the unit circle.
        assert_eq!(
            Biquad::from_f64([1.0, 0.0, 0.0], [0.0, 1.0]),
            Err(BiquadError::Unstable)
        );
        assert_eq!(
            Biquad::from_f64([1.0, 0.0, 0.0], [-1.5, 0.4]),
            Err(BiquadError::Unstable)
        );
        assert_eq!(
            Biquad::IDENTITY.with_limits(v(1.0), v(0.0)),
            Err(BiquadError::LimitsOutOfRange)
        );
        assert_eq!(
            Biquad::IDENTITY.with_limits(v(0.0), v(5000.0)),
            Err(BiquadError::LimitsOutOfRange)
        );
        assert!(Biquad::from_f64([0.5, 0.1, 0.2], [-1.9, 0.95]).is_ok());
    }

    #[test]
    fn output_saturates_and_extreme_inputs_do_not_overflow() {
        // Gain ~ (b sum)/(1 + a1 + a2) = 5.9/0.05: a large resonant gain.
        let q = Biquad::from_f64([1.99, 1.99, 1.92], [-1.9, 0.95])
            .unwrap()
            .with_limits(v(-100.0), v(100.0))
            .unwrap();
        let mut s = BiquadState::new();
        for n in 0..10_000 {
            let x = if n % 7 < 3 { I16F16::MAX } else { I16F16::MIN };
            let y = q.process(&mut s, x);
            assert!(y >= v(-100.0) && y <= v(100.0));
        }
    }
}

use crate::preview::{Fir, TAPS};

/// Sections of a model's reference-shaping filter ([`ShapingSpec`]).
pub const SHAPING_SECTIONS: usize = 2;

/// A model's reference-shaping filter as stored: the raw `I8F24` coefficients
/// `[b0, b1, b2, a1, a2]` of [`SHAPING_SECTIONS`] sections (unused ones are the
/// identity). It runs on the reference, in µm, before the inverse FPI: the stable
/// inverse of the stage's lightly damped modes, so that a fast reference is
/// followed without ringing (the stage is a Hammerstein chain: hysteresis, then
/// its linear dynamics, so the dynamics' inverse comes first).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShapingSpec {
    /// Raw coefficient bits, section by section.
    pub sections: [[i32; 5]; SHAPING_SECTIONS],
    /// Ticks the shaping runs ahead of the reference the loops track
    /// (`crate::preview`), `0..=PREVIEW_MAX`: 0, the sections run on the
    /// tracked reference; else the shaping is [`ShapingSpec::taps`] on the
    /// preview's delay line and the sections are the identity. Where the model
    /// damps, the damping then also leaves the force the shaped reference's own
    /// motion explains out of the force it damps (`firmware`'s closed loop).
    pub preview: u8,
    /// The feedforward's raw `I8F24` taps on the delay line, newest first
    /// (`crate::preview::Fir`; zero without a preview).
    pub taps: [i32; TAPS],
}

impl ShapingSpec {
    /// No shaping (both sections the identity).
    pub const IDENTITY: Self = Self {
        sections: [[1 << COEFF_FRAC, 0, 0, 0, 0]; SHAPING_SECTIONS],
        preview: 0,
        taps: [0; TAPS],
    };

    /// The cascade, each section checked: stable, and of unit static gain exactly
    /// (`b0 + b1 + b2 = 1 + a1 + a2` in raw bits), so that the filter never moves
    /// a held position. The one check, shared by the model validator and the
    /// firmware; the error names the first refused section.
    pub const fn cascade(&self) -> Result<Cascade<SHAPING_SECTIONS>, Invalid> {
        let mut out = [Biquad::IDENTITY; SHAPING_SECTIONS];
        let mut i = 0;
        while i < SHAPING_SECTIONS {
            let c = self.sections[i];
            let b_sum = c[0] as i64 + c[1] as i64 + c[2] as i64;
            let a_sum = (1i64 << COEFF_FRAC) + c[3] as i64 + c[4] as i64;
            if b_sum != a_sum {
                return Err(Invalid::at_index(
                    Field::Shaping,
                    i,
                    ModelError::FilterStaticGain,
                ));
            }
            let q = Coefficient::from_bits;
            match Biquad::new([q(c[0]), q(c[1]), q(c[2])], [q(c[3]), q(c[4])]) {
                Ok(b) => out[i] = b,
                Err(_) => {
                    return Err(Invalid::at_index(
                        Field::Shaping,
                        i,
                        ModelError::FilterUnstable,
                    ))
                }
            }
            i += 1;
        }
        Ok(Cascade::new(out))
    }

    /// The feedforward on the preview's delay line where the shaping runs
    /// ahead (`preview > 0`), checked ([`Fir::new`]; the sections must then be
    /// the identity); `None` where it runs its sections.
    pub const fn fir(&self) -> Result<Option<Fir>, Invalid> {
        if self.preview == 0 {
            return Ok(None);
        }
        let mut i = 0;
        while i < SHAPING_SECTIONS {
            let (c, id) = (self.sections[i], Self::IDENTITY.sections[i]);
            if c[0] != id[0] || c[1] != 0 || c[2] != 0 || c[3] != 0 || c[4] != 0 {
                return Err(Invalid::at(Field::Preview, ModelError::PreviewWithSections));
            }
            i += 1;
        }
        match Fir::new(self.preview, self.taps) {
            Ok(f) => Ok(Some(f)),
            Err(e) => Err(e),
        }
    }
}
