//! The physical signals as distinct types: [`Volts`](super::Volts),
//! [`Micrometres`](super::Micrometres) and [`Newtons`](super::Newtons) are each a
//! `#[repr(transparent)]` newtype over `I16F16`, so that the compiler tells a
//! voltage from a position and from a force.
//!
//! Each has the part of `I16F16`'s API the code base uses, every method
//! `#[inline(always)]` (and `const` where `fixed`'s is) and delegating to
//! `I16F16`, so that a step costs the same instructions as with the bare type.
//! Arithmetic is within one unit only (`+`, `-`, negation, the saturating and
//! wrapping sums, scaling by a plain integer); a product of a gain and a signal,
//! which changes the unit, goes through the raw bits or a named helper of
//! [`q`](super), and [`raw`](super::Volts::raw)/[`from_raw`](super::Volts::from_raw)
//! reach the bare `I16F16` where a block is generic over the unit (the biquad
//! sections).

/// Defines one physical-signal newtype over `I16F16`.
macro_rules! unit {
    ($(#[$doc:meta])* $Unit:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Default, PartialEq, Eq, Hash)]
        #[repr(transparent)]
        pub struct $Unit(I16F16);

        impl $Unit {
            /// Zero.
            pub const ZERO: Self = Self(I16F16::ZERO);
            /// The largest value, 32768 − 2⁻¹⁶.
            pub const MAX: Self = Self(I16F16::MAX);
            /// The smallest value, −32768.
            pub const MIN: Self = Self(I16F16::MIN);
            /// One LSB, 2⁻¹⁶.
            pub const DELTA: Self = Self(I16F16::DELTA);
            /// Fractional bits (16).
            pub const FRAC_NBITS: u32 = I16F16::FRAC_NBITS;

            /// The value whose raw `I16F16` bits are `bits` (LSB 2⁻¹⁶).
            #[inline(always)]
            #[must_use]
            pub const fn from_bits(bits: i32) -> Self {
                Self(I16F16::from_bits(bits))
            }

            /// The raw `I16F16` bits.
            #[inline(always)]
            #[must_use]
            pub const fn to_bits(self) -> i32 {
                self.0.to_bits()
            }

            /// The value whose bare `I16F16` is `raw` (the unit is asserted by the caller).
            #[inline(always)]
            #[must_use]
            pub const fn from_raw(raw: I16F16) -> Self {
                Self(raw)
            }

            /// The bare `I16F16` (the unit is dropped).
            #[inline(always)]
            #[must_use]
            pub const fn raw(self) -> I16F16 {
                self.0
            }

            /// An integer number of units (`I16F16::const_from_int`).
            #[inline(always)]
            #[must_use]
            pub const fn const_from_int(src: i32) -> Self {
                Self(I16F16::const_from_int(src))
            }

            /// `I16F16::from_num`: rounds toward zero and panics on overflow in debug builds.
            #[inline(always)]
            #[must_use]
            pub fn from_num<Src: fixed::traits::ToFixed>(src: Src) -> Self {
                Self(I16F16::from_num(src))
            }

            /// `I16F16::checked_from_num`: `None` if `src` does not fit.
            #[inline(always)]
            #[must_use]
            pub fn checked_from_num<Src: fixed::traits::ToFixed>(src: Src) -> Option<Self> {
                match I16F16::checked_from_num(src) {
                    Some(x) => Some(Self(x)),
                    None => None,
                }
            }

            /// `I16F16::to_num`: the value in units, as `Dst`.
            #[inline(always)]
            #[must_use]
            pub fn to_num<Dst: fixed::traits::FromFixed>(self) -> Dst {
                self.0.to_num()
            }

            /// Sum saturated at [`MIN`](Self::MIN) and [`MAX`](Self::MAX).
            #[inline(always)]
            #[must_use]
            pub const fn saturating_add(self, rhs: Self) -> Self {
                Self(self.0.saturating_add(rhs.0))
            }

            /// Difference saturated at [`MIN`](Self::MIN) and [`MAX`](Self::MAX).
            #[inline(always)]
            #[must_use]
            pub const fn saturating_sub(self, rhs: Self) -> Self {
                Self(self.0.saturating_sub(rhs.0))
            }

            /// Sum modulo 2¹⁶ units.
            #[inline(always)]
            #[must_use]
            pub const fn wrapping_add(self, rhs: Self) -> Self {
                Self(self.0.wrapping_add(rhs.0))
            }

            /// Difference modulo 2¹⁶ units.
            #[inline(always)]
            #[must_use]
            pub const fn wrapping_sub(self, rhs: Self) -> Self {
                Self(self.0.wrapping_sub(rhs.0))
            }

            /// The magnitude saturated at [`MAX`](Self::MAX).
            #[inline(always)]
            #[must_use]
            pub const fn saturating_abs(self) -> Self {
                Self(self.0.saturating_abs())
            }

            /// The magnitude (`I16F16::abs`: overflows on [`MIN`](Self::MIN)).
            #[inline(always)]
            #[must_use]
            pub const fn abs(self) -> Self {
                Self(self.0.abs())
            }

            /// The product with a plain number, saturated at [`MIN`](Self::MIN) and [`MAX`](Self::MAX).
            #[inline(always)]
            #[must_use]
            pub const fn saturating_mul_int(self, rhs: i32) -> Self {
                Self(self.0.saturating_mul_int(rhs))
            }

        }

        impl PartialOrd for $Unit {
            #[inline(always)]
            fn partial_cmp(&self, other: &Self) -> Option<core::cmp::Ordering> {
                Some(Ord::cmp(&self.0, &other.0))
            }
            #[inline(always)]
            fn lt(&self, other: &Self) -> bool {
                self.0 < other.0
            }
            #[inline(always)]
            fn le(&self, other: &Self) -> bool {
                self.0 <= other.0
            }
            #[inline(always)]
            fn gt(&self, other: &Self) -> bool {
                self.0 > other.0
            }
            #[inline(always)]
            fn ge(&self, other: &Self) -> bool {
                self.0 >= other.0
            }
        }

        impl Ord for $Unit {
            #[inline(always)]
            fn cmp(&self, other: &Self) -> core::cmp::Ordering {
                Ord::cmp(&self.0, &other.0)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                Self(Ord::max(self.0, other.0))
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                Self(Ord::min(self.0, other.0))
            }
            #[inline(always)]
            fn clamp(self, lo: Self, hi: Self) -> Self {
                Self(Ord::clamp(self.0, lo.0, hi.0))
            }
        }

        impl core::ops::Add for $Unit {
            type Output = Self;
            #[inline(always)]
            fn add(self, rhs: Self) -> Self {
                Self(self.0 + rhs.0)
            }
        }

        impl core::ops::Sub for $Unit {
            type Output = Self;
            #[inline(always)]
            fn sub(self, rhs: Self) -> Self {
                Self(self.0 - rhs.0)
            }
        }

        impl core::ops::Neg for $Unit {
            type Output = Self;
            #[inline(always)]
            fn neg(self) -> Self {
                Self(-self.0)
            }
        }

        impl core::ops::AddAssign for $Unit {
            #[inline(always)]
            fn add_assign(&mut self, rhs: Self) {
                self.0 += rhs.0;
            }
        }

        impl core::ops::SubAssign for $Unit {
            #[inline(always)]
            fn sub_assign(&mut self, rhs: Self) {
                self.0 -= rhs.0;
            }
        }

        /// Scaling by a plain number keeps the unit.
        impl core::ops::Mul<i32> for $Unit {
            type Output = Self;
            #[inline(always)]
            fn mul(self, rhs: i32) -> Self {
                Self(self.0 * rhs)
            }
        }

        /// Halving (an arithmetic shift) keeps the unit.
        impl core::ops::Shr<u32> for $Unit {
            type Output = Self;
            #[inline(always)]
            fn shr(self, rhs: u32) -> Self {
                Self(self.0 >> rhs)
            }
        }

        impl core::fmt::Debug for $Unit {
            #[inline]
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                core::fmt::Debug::fmt(&self.0, f)
            }
        }

        impl core::fmt::Display for $Unit {
            #[inline]
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                core::fmt::Display::fmt(&self.0, f)
            }
        }

        #[cfg(feature = "defmt")]
        impl defmt::Format for $Unit {
            #[inline]
            fn format(&self, f: defmt::Formatter<'_>) {
                defmt::Format::format(&self.0, f)
            }
        }
    };
}

pub(super) use unit;

use fixed::types::I16F16;

/// One of the physical signals as its raw `I16F16` bits: for the few places
/// generic over the unit (an [`Interval`](crate::control::Interval) of any of
/// them, a supervision window's test).
pub trait Signal: Copy + Ord {
    /// The value of raw `I16F16` bits.
    fn from_bits(bits: i32) -> Self;
    /// The raw `I16F16` bits.
    fn to_bits(self) -> i32;
}

macro_rules! signal {
    ($($T:ty),*) => {$(
        impl Signal for $T {
            #[inline(always)]
            fn from_bits(bits: i32) -> Self {
                <$T>::from_bits(bits)
            }
            #[inline(always)]
            fn to_bits(self) -> i32 {
                <$T>::to_bits(self)
            }
        }
    )*};
}
signal!(super::Volts, super::Micrometres, super::Newtons, I16F16);
