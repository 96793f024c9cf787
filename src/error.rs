//! The one vocabulary of model errors: what is wrong ([`ModelError`]) and, for a
//! whole model, where ([`Field`], named by the model file's keys) — [`Invalid`].
//!
//! The constructors of the core's types report a [`ModelError`]; the model
//! validator ([`crate::model::validate`]) locates it in the model. Build time
//! (`firmware/build.rs`), the host tools and the board's model upload all report
//! an invalid model with these, so a problem reads the same wherever it is found.
//! Construction runs at compile time for the firmware's embedded model and at run
//! time elsewhere; never in the ISR.

use core::fmt;

pub use crate::fields::{Field, TableId, TablePart};

/// A configuration the core refuses to run, with the offending index where there is one.
///
/// Indices are 0-based positions in the array that was passed in (for a table:
/// the knot).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModelError {
    /// A partial weight sum `S_j = w0 + w_1 + … + w_j` is not positive: the PI is not
    /// strictly increasing and has no inverse (`index` 0 is `w0` alone).
    NonPositiveSlope {
        /// `j` of the partial sum.
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
    /// An inverse weight does not fit `VoltsPerUm` (±512 V/µm): a partial sum
    /// `S_j` (`index` = `j`) is too small.
    InverseWeightOutOfRange {
        /// `j` of the partial sum the weight is built from.
        index: u8,
    },
    /// More than [`crate::q::MAX_OPERATORS`] operators.
    TooManyOperators,
    /// More than [`crate::q::MAX_CREEP_TERMS`] creep terms.
    TooManyCreepTerms,
    /// A creep rate `1 - a` is not in `(0, 0.5)` per sample: the time constant is
    /// not positive or shorter than `T_s / ln 2`.
    CreepRateOutOfRange,
    /// The curvature `k_q` of the preload offset exceeds ±0.00195 V/N², the range
    /// over which `k_q·(1024 N)²` stays inside the signal range.
    CurvatureOutOfRange,
    /// A lookup table needs at least two knots and at most [`crate::q::MAX_TABLE_LEN`].
    TableLength,
    /// The knot spacing `2^shift` LSB is outside `2..=2^16` LSB (2⁻¹⁵ to one unit).
    TableSpacing,
    /// A knot (the first, the last, or a value) lies beyond the signal range.
    TableSpan,
    /// Table values are not monotone; `index` is the first knot that breaks the order.
    TableNotMonotone {
        /// Knot.
        index: u16,
    },
    /// Neighbouring knot values differ by half a unit or more: use a finer grid.
    TableTooSteep {
        /// Knot.
        index: u16,
    },
    /// The preload `f_F` falls as the stack extends (the model's coupled
    /// equation needs more extension to bring at least as much preload);
    /// `index` is the knot where it falls.
    PreloadFalls {
        /// Knot.
        index: u16,
    },
    /// The stage output `f_K` does not rise as the stack extends, so it has no
    /// inverse; `index` is the knot it does not rise to.
    OutputNotInvertible {
        /// Knot.
        index: u16,
    },
    /// `f_K⁻¹` does not invert `f_K`: at its knot `index`, `f_K(f_K⁻¹(y))` is
    /// more than [`crate::table::INVERSE_TOLERANCE`] from `y`.
    InverseDisagrees {
        /// Knot of `f_K⁻¹`.
        index: u16,
    },
    /// A lower limit is above its upper limit.
    LimitsInverted,
    /// The slew limit (largest change per step) is not positive.
    NonPositiveSlew,
    /// A correction's limit is not above zero, or beyond the signal range.
    LimitOutOfRange,
    /// The reference interval reaches beyond the `f_K⁻¹` table's grid.
    ReferenceOutsideTable,
    /// The safe voltage lies outside the voltage limits.
    SafeVoltageOutsideLimits,
    /// The force-plausibility tolerance is not positive.
    NonPositiveTolerance,
    /// The control rate is outside 100 Hz – 200 kHz.
    RateOutOfRange,
    /// Two arrays that go together have different lengths (thresholds and
    /// weights, a count and its items).
    LengthMismatch,
    /// An engineering value is not finite or does not fit its Q format.
    NotRepresentable,
    /// A model image does not start with the format's magic number.
    NotAModelImage,
    /// A model image's format version is not the one this build reads.
    UnsupportedVersion,
    /// A model image's checksum does not match its contents.
    ChecksumMismatch,
    /// A model image ends before its contents do, or runs on past them.
    Truncated,
    /// The model needs more operators, creep terms or table knots, or a longer
    /// reference preview, than the board has room for.
    OverCapacity,
    /// The model's control rate is not the board's.
    RateMismatch,
    /// The model asks for a wider voltage range, a faster slew or a safe voltage
    /// outside the window the board's hardware allows (a model may only narrow them).
    WidensHardwareLimit,
    /// A feedback gain is negative, beyond its range (kp 0–16, ki 0–1 per tick), or
    /// both gains are zero.
    GainOutOfRange,
    /// A filter section's poles are not strictly inside the unit circle.
    FilterUnstable,
    /// A filter section's static gain is not exactly 1.
    FilterStaticGain,
    /// The force channel's dynamic limit is below the force tolerance or beyond
    /// the signal range.
    DynamicLimitBelowTolerance,
    /// A damping or stage-dynamics setting is not finite, not positive or beyond
    /// its range.
    DampingOutOfRange,
    /// The loops this model closes (position feedback, damping) are unstable on the
    /// stage dynamics it declares, or on the edge (their poles do not decay a
    /// thousandfold within 2²⁰ control ticks).
    LoopUnstable,
    /// Active damping needs the stage's dynamics (a `[dynamics]` section).
    DampingWithoutDynamics,
    /// A shaping that runs ahead (a preview) is taps on the delay line: its
    /// sections must be the identity.
    PreviewWithSections,
    /// The lead's baseline (`crate::lead`) scales the force the shaped
    /// reference's motion explains: it needs active damping and a shaping that
    /// runs ahead.
    LeadWithoutPreview,
    /// The oscillation watch's half swing on the tracking error is outside
    /// [`crate::model::WATCH_SWING_MIN`]…[`crate::model::WATCH_SWING_MAX`].
    WatchSwingOutOfRange,
    /// The oscillation watch's half swing on the tracking error needs a
    /// position loop (`[feedback]`).
    WatchWithoutFeedback,
    /// A sensor's window takes in (or passes) a rail of the board's channel
    /// for it: a broken wire, which reads a rail, would not be seen.
    OutsideRails,
    /// A tolerance so wide that its check could never trip: beyond a quarter
    /// of the sensor's window (a reading that disagrees with the model by
    /// more than a quarter of all it may read is seen).
    ToleranceTooWide,
    /// The feedforward's taps amplify the reference more than
    /// [`crate::preview::TAPS_GAIN_MAX`] times (`Σ|h| >` it): no stage's
    /// inverse needs that much.
    FeedforwardTooLarge,
    /// A decoupling matrix's entry lies outside its range
    /// ([`crate::decoupling::DIAGONAL`] on the diagonal, ±
    /// [`crate::decoupling::OFF_DIAGONAL_MAX`] off it) or is not a number.
    MatrixEntryOutOfRange {
        /// Row (the axis out).
        row: u8,
        /// Column (the axis in).
        col: u8,
    },
    /// A preload coupling lies beyond ±[`crate::decoupling::PRELOAD_MAX`]
    /// N/µm, sits on the diagonal (a stack's own preload is its FEM
    /// table's), or is not a number.
    PreloadCouplingOutOfRange {
        /// Row (the stack loaded).
        row: u8,
        /// Column (the stack that loads it).
        col: u8,
    },
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
                "an inverse weight does not fit I10F22 (a partial weight sum is too small)"
            }
            Self::TooManyOperators => "more play operators than the core supports (32)",
            Self::TooManyCreepTerms => "more creep terms than the core supports (8)",
            Self::CreepRateOutOfRange => {
                "creep time constant not longer than T_s / ln 2 (rate 1 - a outside (0, 0.5))"
            }
            Self::CurvatureOutOfRange => "k_q beyond ±0.00195 V/N²",
            Self::TableLength => "a lookup table needs 2..=4096 knots",
            Self::TableSpacing => {
                "table knot spacing outside 2^-15..=1 units (step_log2 must be -15..=0)"
            }
            Self::TableSpan => "a table knot lies beyond the signal range (±4096)",
            Self::TableNotMonotone { .. } => "table values are not monotone",
            Self::TableTooSteep { .. } => {
                "neighbouring table values differ by 0.5 or more: use a finer grid"
            }
            Self::PreloadFalls { .. } => {
                "the preload falls as the stack extends (f_f must not fall: more extension, \
                 at least as much preload)"
            }
            Self::OutputNotInvertible { .. } => {
                "the stage output does not rise as the stack extends, so f_k has no inverse \
                 (f_k must rise between every two knots)"
            }
            Self::InverseDisagrees { .. } => {
                "f_k_inv does not invert f_k here: f_k(f_k_inv(y)) is more than 1/64 µm from y"
            }
            Self::LimitsInverted => "the lower limit exceeds the upper limit",
            Self::NonPositiveSlew => "the slew limit is not positive",
            Self::LimitOutOfRange => "the limit must be > 0 µm and within ±32 767 µm",
            Self::ReferenceOutsideTable => "the reference range reaches beyond the f_K⁻¹ table",
            Self::SafeVoltageOutsideLimits => "the safe voltage lies outside the voltage limits",
            Self::NonPositiveTolerance => "the tolerance is not positive",
            Self::RateOutOfRange => "the control rate is outside 100..=200000 Hz",
            Self::LengthMismatch => "arrays that go together have different lengths",
            Self::NotRepresentable => "a value is not finite or does not fit its Q format",
            Self::NotAModelImage => "not a model image (wrong magic number)",
            Self::UnsupportedVersion => "model image format version not supported by this build",
            Self::ChecksumMismatch => "model image checksum mismatch (corrupted)",
            Self::Truncated => "model image truncated or longer than its contents",
            Self::OverCapacity => "more operators, creep terms or table knots than the board holds",
            Self::RateMismatch => "the model's control rate is not the board's",
            Self::WidensHardwareLimit => {
                "widens a hardware limit of the board (a model may only narrow them)"
            }
            Self::FilterUnstable => "a filter section's poles are not inside the unit circle",
            Self::FilterStaticGain => {
                "a filter section's static gain is not exactly 1 (b0+b1+b2 = 1+a1+a2)"
            }
            Self::GainOutOfRange => {
                "a feedback gain is negative or beyond its range (kp 0..=2, ki 0..=0.25 per tick), or both are zero"
            }
            Self::DynamicLimitBelowTolerance => {
                "the dynamic force limit is below the force tolerance, or beyond the force window's span (then it could never trip)"
            }
            Self::DampingOutOfRange => {
                "a damping or stage-dynamics setting is not positive or beyond its range"
            }
            Self::LoopUnstable => {
                "the loops are unstable on the stage dynamics the model declares (their poles do not decay a thousandfold within 2^20 ticks)"
            }
            Self::DampingWithoutDynamics => {
                "active damping needs the stage's dynamics with its force gain ([dynamics] force_gain_n_per_um)"
            }
            Self::PreviewWithSections => {
                "a shaping that runs ahead (preview_ticks > 0) is its taps: it has no sections"
            }
            Self::LeadWithoutPreview => {
                "a lead baseline needs active damping ([damping]) and a shaping that runs ahead (preview_ticks > 0)"
            }
            Self::WatchSwingOutOfRange => {
                "the oscillation watch's half swing must lie within 0.075…0.2 µm"
            }
            Self::WatchWithoutFeedback => {
                "the oscillation watch's half swing is the tracking error's: it needs position feedback ([feedback])"
            }
            Self::OutsideRails => {
                "must lie inside the rails of the board's sensor channel (position −10…70 µm, force −5…507 N): a broken wire reads a rail, and a window that takes the rail in cannot see it"
            }
            Self::ToleranceTooWide => {
                "too wide for its check to trip: a tolerance may be at most a quarter of its sensor's window (position_min_um…position_max_um, force_min_n…force_max_n)"
            }
            Self::FeedforwardTooLarge => {
                "the feedforward's taps amplify the reference more than 32 times (the sum of their magnitudes): no stage's inverse needs it"
            }
            Self::MatrixEntryOutOfRange { .. } => {
                "a decoupling matrix entry is outside its range (diagonal 0.8…1.25, off the diagonal ±0.1) or not a number"
            }
            Self::PreloadCouplingOutOfRange { .. } => {
                "a preload coupling is beyond ±4 N/µm, on the diagonal (a stack's own preload is its FEM table's) or not a number"
            }
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
            Self::TableNotMonotone { index }
            | Self::TableTooSteep { index }
            | Self::PreloadFalls { index }
            | Self::OutputNotInvertible { index }
            | Self::InverseDisagrees { index } => Some(index as usize),
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
        if let Self::MatrixEntryOutOfRange { row, col }
        | Self::PreloadCouplingOutOfRange { row, col } = *self
        {
            write!(f, " (row {row}, column {col})")?;
        }
        Ok(())
    }
}

impl core::error::Error for ModelError {}

/// Why a model is invalid, and where: the field, the element (when the field is an
/// array) and the problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Invalid {
    /// Where.
    pub field: Field,
    /// Which element of the field, if it is an array.
    pub index: Option<u16>,
    /// What is wrong.
    pub error: ModelError,
}

impl Invalid {
    /// An error about a whole field.
    pub const fn at(field: Field, error: ModelError) -> Self {
        Self {
            field,
            index: None,
            error,
        }
    }
    /// An error about element `index` of a field.
    pub const fn at_index(field: Field, index: usize, error: ModelError) -> Self {
        Self {
            field,
            index: Some(index as u16),
            error,
        }
    }
}

/// `key`, e.g. `pi.weights_um_per_v`, `tables.f_f.step_log2`, `creep[].tau_s`.
impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())?;
        if let Self::Table(_, part) = self {
            write!(f, ".{}", part.key())?;
        }
        Ok(())
    }
}

/// A field at an element: `pi.weights_um_per_v[3]`, `creep[1].tau_s` (the
/// index goes into the key's `[]`, where it has one), `tables.f_f.x0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Located(pub Field, pub Option<u16>);

impl Field {
    /// This field at element `index` (of an array, or an array of tables).
    pub const fn at(self, index: usize) -> Located {
        Located(self, Some(index as u16))
    }
}

impl fmt::Display for Located {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.0.key().split_once("[]"), self.1) {
            (Some((array, leaf)), Some(i)) => write!(f, "{array}[{i}]{leaf}"),
            (_, Some(i)) => write!(f, "{}[{i}]", self.0),
            (_, None) => write!(f, "{}", self.0),
        }
    }
}

impl Invalid {
    /// Writes the located key ([`Located`]).
    pub fn write_key(&self, f: &mut impl fmt::Write) -> fmt::Result {
        write!(f, "{}", Located(self.field, self.index))
    }
}

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_key(f)?;
        write!(f, ": {}", self.error.message())
    }
}

impl core::error::Error for Invalid {}
