//! Why a model, table or limit set was rejected at construction.
//!
//! Construction runs at compile time for the firmware's embedded model (a bad
//! model file fails the build) and at run time for host tools; never in the ISR.

use core::fmt;

/// A configuration the core refuses to run, with the offending index where there is one.
///
/// Indices are 0-based positions in the array that was passed in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModelError {
    /// A partial weight sum `S_j = w0 + w_1 + … + w_j` is not positive: the PI is not
    /// strictly increasing and has no inverse (`index` 0 is `w0` alone).
    NonPositiveSlope {
        /// Position of the offending element.
        index: u8,
    },
    /// A threshold is negative (one-sided play operators need `r >= 0`).
    NegativeThreshold {
        /// Position of the offending element.
        index: u8,
    },
    /// Thresholds must be non-decreasing; `index` is the first that is smaller than its predecessor.
    ThresholdsNotSorted {
        /// Position of the offending element.
        index: u8,
    },
    /// A threshold lies beyond the input domain, so its operator could never move.
    ThresholdBeyondDomain {
        /// Position of the offending element.
        index: u8,
    },
    /// The input domain `[0, input_max]` is empty or beyond the signal range.
    DomainOutOfRange,
    /// `sum |w| * input_max` leaves the signal range: outputs would overflow.
    OutputOutOfRange,
    /// An inverse weight does not fit `VoltsPerUm` (±512 V/µm): `w0` is too small.
    InverseWeightOutOfRange {
        /// Position of the offending element.
        index: u8,
    },
    /// More than [`crate::q::MAX_OPERATORS`] operators.
    TooManyOperators,
    /// A lookup table needs at least two knots and at most [`crate::q::MAX_TABLE_LEN`].
    TableLength,
    /// The knot spacing `2^shift` LSB is outside `2..=2^16` LSB (at most one unit).
    TableSpacing,
    /// The table's last knot lies beyond the signal range.
    TableSpan,
    /// Table values are not monotone; `index` is the first knot that breaks the order.
    TableNotMonotone {
        /// Position of the offending element.
        index: u16,
    },
    /// Neighbouring knot values differ by half a unit or more: use a finer grid.
    TableTooSteep {
        /// Position of the offending element.
        index: u16,
    },
    /// A lower limit is above its upper limit, or a rate limit is not positive.
    LimitsInverted,
    /// An engineering value is not finite or does not fit its Q format.
    NotRepresentable,
}

impl ModelError {
    /// A one-line description, usable in `const` panics and logs.
    pub const fn message(&self) -> &'static str {
        match self {
            Self::NonPositiveSlope { .. } => {
                "a partial weight sum S_j is not positive: the PI model has no inverse"
            }
            Self::NegativeThreshold { .. } => "a play-operator threshold is negative",
            Self::ThresholdsNotSorted { .. } => "play-operator thresholds are not sorted",
            Self::ThresholdBeyondDomain { .. } => "a threshold lies beyond the input domain",
            Self::DomainOutOfRange => "the input domain is empty or beyond the signal range",
            Self::OutputOutOfRange => "sum |w| * input_max leaves the signal range",
            Self::InverseWeightOutOfRange { .. } => {
                "an inverse weight does not fit I10F22 (w0 too small)"
            }
            Self::TooManyOperators => "more play operators than the core supports",
            Self::TableLength => "a lookup table needs 2..=4096 knots",
            Self::TableSpacing => "table knot spacing outside 2..=2^16 LSB (at most one unit)",
            Self::TableSpan => "table span leaves the signal range",
            Self::TableNotMonotone { .. } => "table values are not monotone",
            Self::TableTooSteep { .. } => {
                "neighbouring table values differ by 0.5 or more: use a finer grid"
            }
            Self::LimitsInverted => {
                "a lower limit exceeds its upper limit or a rate is not positive"
            }
            Self::NotRepresentable => "a value is not finite or does not fit its Q format",
        }
    }

    /// The offending array index, when the error is about one element.
    pub const fn index(&self) -> Option<usize> {
        match *self {
            Self::NonPositiveSlope { index }
            | Self::NegativeThreshold { index }
            | Self::ThresholdsNotSorted { index }
            | Self::ThresholdBeyondDomain { index }
            | Self::InverseWeightOutOfRange { index } => Some(index as usize),
            Self::TableNotMonotone { index } | Self::TableTooSteep { index } => {
                Some(index as usize)
            }
            _ => None,
        }
    }
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.message())?;
        if let Some(i) = self.index() {
            write!(f, " (index {i})")?;
        }
        Ok(())
    }
}

impl core::error::Error for ModelError {}
