//! The intervals the controller checks its inputs against: the reference's
//! reachable stroke and the force sensor's plausible range.

use super::channel::force_channel_window;
use super::{ForceChannel, ForceSource};
use crate::error::{Field, Invalid, ModelError};
use crate::limits::OutputLimits;
use crate::q::{Micrometres, Newtons, Signal, Volts, SIGNAL_ABS_MAX_BITS};
use crate::table::Table;

/// A closed interval `[lo, hi]` of one quantity (µm, N…: `T`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interval<T> {
    /// Lower end.
    pub lo: T,
    /// Upper end.
    pub hi: T,
}

/// A validated interval (`lo <= hi`) as its lower end and its span, raw bits: `x`
/// lies in it iff `(x - lo) mod 2^32 <= span`, one unsigned compare.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Window {
    pub(super) lo: i32,
    pub(super) span: u32,
}

impl Window {
    /// `None` if the interval is inverted.
    pub(crate) const fn new(lo: i32, hi: i32) -> Option<Self> {
        if lo > hi {
            return None;
        }
        Some(Self {
            lo,
            span: hi.wrapping_sub(lo) as u32,
        })
    }

    #[inline(always)]
    pub(crate) fn contains<S: Signal>(&self, x: S) -> bool {
        self.contains_bits(x.to_bits())
    }

    #[inline(always)]
    pub(crate) fn contains_bits(&self, x: i32) -> bool {
        (x.wrapping_sub(self.lo) as u32) <= self.span
    }
}

/// What the controller supervises, and where it goes when something is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Supervision {
    /// Reachable references (µm of stage output); anything else is a fault.
    pub reference: Interval<Micrometres>,
    /// Plausible force readings (N); anything else is a fault.
    pub force: Interval<Newtons>,
    /// Largest tolerated `|F - f_F(x_pea_est)|` (N).
    pub force_tolerance: Newtons,
    /// Voltage of the safe state (V), inside the limits.
    pub safe_voltage: Volts,
    /// Measured or predicted preload.
    pub force_source: ForceSource,
    /// How the reading is split into its slow and dynamic parts, and the dynamic
    /// limit.
    pub channel: ForceChannel,
}

/// The supervision windows a validated controller checks its inputs against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Windows {
    pub(super) reference: Window,
    pub(super) force: Window,
    /// `[-tolerance, tolerance]`, for the slow part of the residual `F - f_F(x_pea_est)`.
    pub(super) residual: Window,
    /// `[-limit, limit]`, for the residual at once.
    pub(super) dynamic: Window,
}

/// Checks a controller's settings against its limits and its `f_K⁻¹` table: the
/// reference and force intervals not inverted, the reference interval inside the
/// `f_K⁻¹` grid, the safe voltage inside the limits, a positive tolerance, and the
/// force interval and tolerance inside the signal range (±4096 N, so that the
/// residual `F - f_F` is exact in 32 bits). The one check, shared by
/// [`ControllerConfig::new`](super::ControllerConfig::new) and the model validator.
pub const fn check_settings(
    limits: &OutputLimits,
    f_k_inv: &Table<'_>,
    s: &Supervision,
) -> Result<Windows, Invalid> {
    let (reference, force) = (s.reference, s.force);
    let (force_tolerance, safe_voltage) = (s.force_tolerance, s.safe_voltage);
    let s_channel = s.channel;
    let Some(reference_window) = Window::new(reference.lo.to_bits(), reference.hi.to_bits()) else {
        return Err(Invalid::at(Field::ReferenceMin, ModelError::LimitsInverted));
    };
    let Some(force_window) = Window::new(force.lo.to_bits(), force.hi.to_bits()) else {
        return Err(Invalid::at(Field::ForceMin, ModelError::LimitsInverted));
    };
    if reference.lo.to_bits() < f_k_inv.x_min().to_bits() {
        return Err(Invalid::at(
            Field::ReferenceMin,
            ModelError::ReferenceOutsideTable,
        ));
    }
    if reference.hi.to_bits() > f_k_inv.x_max().to_bits() {
        return Err(Invalid::at(
            Field::ReferenceMax,
            ModelError::ReferenceOutsideTable,
        ));
    }
    let s = safe_voltage.to_bits();
    if s < limits.min().to_bits() || s > limits.max().to_bits() {
        return Err(Invalid::at(
            Field::SafeVoltage,
            ModelError::SafeVoltageOutsideLimits,
        ));
    }
    let tol = force_tolerance.to_bits();
    if tol <= 0 {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NonPositiveTolerance,
        ));
    }
    if tol > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NotRepresentable,
        ));
    }
    if force.lo.to_bits() < -SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(Field::ForceMin, ModelError::NotRepresentable));
    }
    if force.hi.to_bits() > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(Field::ForceMax, ModelError::NotRepresentable));
    }
    let Some(residual) = Window::new(-tol, tol) else {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NonPositiveTolerance,
        ));
    };
    let dynamic = match force_channel_window(&s_channel, force_tolerance) {
        Ok(w) => w,
        Err(e) => return Err(e),
    };
    Ok(Windows {
        reference: reference_window,
        force: force_window,
        residual,
        dynamic,
    })
}
