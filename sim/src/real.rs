//! The floating-point numbers the model runs on: `f64` on the host, `f32` on the
//! emulated board.
//!
//! `f32` always goes through `libm` (plain Rust, the same instructions on the host
//! and the Cortex-M4F), so the host's twin of the emulated board computes exactly
//! what the board does. `f64` uses std's functions with the `std` feature (the host
//! tools) and `libm` without it.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// A floating-point type the model is generic over.
pub trait Real:
    Copy
    + Debug
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Machine epsilon.
    const EPSILON: Self;
    /// +∞.
    const INFINITY: Self;
    /// The value nearest to an `f64`.
    fn of(x: f64) -> Self;
    /// As `f64` (exact).
    fn to_f64(self) -> f64;
    /// A count or an index (exact below 2^24 for `f32`).
    fn of_count(n: usize) -> Self;
    /// The integer part of a value in `[0, usize::MAX]` (0 below, saturating).
    fn to_index(self) -> usize;
    /// `e^x`.
    fn exp(self) -> Self;
    /// `e^x - 1`, accurate near 0.
    fn exp_m1(self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// `ln(1 + x)`, accurate near 0.
    fn ln_1p(self) -> Self;
    /// Square root (correctly rounded).
    fn sqrt(self) -> Self;
    /// Largest integer not above.
    fn floor(self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
    /// `|x|`.
    #[inline(always)]
    fn abs(self) -> Self {
        if self < Self::ZERO {
            -self
        } else {
            self
        }
    }
    /// The larger (plain compare: `other` if either is NaN).
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        if self > other {
            self
        } else {
            other
        }
    }
    /// The smaller (plain compare: `other` if either is NaN).
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        if self < other {
            self
        } else {
            other
        }
    }
    /// Clamped to `[lo, hi]` (`lo <= hi`).
    #[inline(always)]
    fn clamp_to(self, lo: Self, hi: Self) -> Self {
        self.max(lo).min(hi)
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const EPSILON: Self = f32::EPSILON;
    const INFINITY: Self = f32::INFINITY;
    #[inline(always)]
    fn of(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn of_count(n: usize) -> Self {
        n as f32
    }
    #[inline(always)]
    fn to_index(self) -> usize {
        self as usize
    }
    fn exp(self) -> Self {
        libm::expf(self)
    }
    fn exp_m1(self) -> Self {
        libm::expm1f(self)
    }
    fn ln(self) -> Self {
        libm::logf(self)
    }
    fn ln_1p(self) -> Self {
        libm::log1pf(self)
    }
    fn sqrt(self) -> Self {
        libm::sqrtf(self)
    }
    fn floor(self) -> Self {
        libm::floorf(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const EPSILON: Self = f64::EPSILON;
    const INFINITY: Self = f64::INFINITY;
    #[inline(always)]
    fn of(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn of_count(n: usize) -> Self {
        n as f64
    }
    #[inline(always)]
    fn to_index(self) -> usize {
        self as usize
    }
    #[cfg(feature = "std")]
    fn exp(self) -> Self {
        f64::exp(self)
    }
    #[cfg(feature = "std")]
    fn exp_m1(self) -> Self {
        f64::exp_m1(self)
    }
    #[cfg(feature = "std")]
    fn ln(self) -> Self {
        f64::ln(self)
    }
    #[cfg(feature = "std")]
    fn ln_1p(self) -> Self {
        f64::ln_1p(self)
    }
    #[cfg(feature = "std")]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[cfg(feature = "std")]
    fn floor(self) -> Self {
        f64::floor(self)
    }
    #[cfg(not(feature = "std"))]
    fn exp(self) -> Self {
        libm::exp(self)
    }
    #[cfg(not(feature = "std"))]
    fn exp_m1(self) -> Self {
        libm::expm1(self)
    }
    #[cfg(not(feature = "std"))]
    fn ln(self) -> Self {
        libm::log(self)
    }
    #[cfg(not(feature = "std"))]
    fn ln_1p(self) -> Self {
        libm::log1p(self)
    }
    #[cfg(not(feature = "std"))]
    fn sqrt(self) -> Self {
        libm::sqrt(self)
    }
    #[cfg(not(feature = "std"))]
    fn floor(self) -> Self {
        libm::floor(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
}
