//! Actuator limits: voltage range and slew rate of the amplifier setpoint.

use crate::error::ModelError;
use crate::q::{at_least, at_most, within, Volts};

/// The range and per-step rate the amplifier setpoint must respect.
///
/// * `min`, `max` — V, `I16F16` (a unipolar stack: typically 0 and 150 V).
/// * `max_step` — largest change per control step, V, `I16F16` (slew rate × period);
///   it bounds the amplifier current `C·du/dt` into the stack's capacitance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputLimits {
    min: Volts,
    max: Volts,
    max_step: Volts,
}

impl OutputLimits {
    /// Validates `min <= max` and `max_step > 0`.
    pub const fn new(min: Volts, max: Volts, max_step: Volts) -> Result<Self, ModelError> {
        if min.to_bits() > max.to_bits() {
            return Err(ModelError::LimitsInverted);
        }
        if max_step.to_bits() <= 0 {
            return Err(ModelError::NonPositiveSlew);
        }
        Ok(Self { min, max, max_step })
    }

    /// Limits a requested voltage given the previous output; returns the voltage to
    /// apply and whether it differs from the request.
    ///
    /// `prev` is always a previous output of this function (or the initial safe
    /// voltage), hence inside `[min, max]`: the window `[max(prev - step, min),
    /// min(prev + step, max)]` is never empty.
    #[inline]
    pub fn apply(&self, prev: Volts, want: Volts) -> (Volts, bool) {
        let lo = at_least(prev.saturating_sub(self.max_step), self.min);
        let hi = at_most(prev.saturating_add(self.max_step), self.max);
        let u = within(want, lo, hi);
        (u, u != want)
    }

    /// Lower voltage limit, V.
    pub const fn min(&self) -> Volts {
        self.min
    }
    /// Upper voltage limit, V.
    pub const fn max(&self) -> Volts {
        self.max
    }
    /// Largest change per step, V.
    pub const fn max_step(&self) -> Volts {
        self.max_step
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64) -> Volts {
        Volts::from_num(x)
    }

    #[test]
    fn clamps_range_and_slew() {
        let l = OutputLimits::new(v(0.0), v(150.0), v(2.0)).unwrap();
        assert_eq!(l.apply(v(10.0), v(11.0)), (v(11.0), false));
        assert_eq!(l.apply(v(10.0), v(20.0)), (v(12.0), true));
        assert_eq!(l.apply(v(10.0), v(-5.0)), (v(8.0), true));
        assert_eq!(l.apply(v(149.0), v(170.0)), (v(150.0), true));
        assert_eq!(l.apply(v(1.0), v(-3.0)), (v(0.0), true));
    }

    #[test]
    fn rejects_inverted_limits() {
        assert_eq!(
            OutputLimits::new(v(10.0), v(0.0), v(1.0)).unwrap_err(),
            ModelError::LimitsInverted
        );
        assert_eq!(
            OutputLimits::new(v(0.0), v(10.0), v(0.0)).unwrap_err(),
            ModelError::NonPositiveSlew
        );
    }
}
