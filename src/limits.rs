//! Actuator limits: voltage range and slew rate of the amplifier setpoint, and the
//! gentle profile the output parks along.
//!
//! **Parking** ([`OutputLimits::park`]). A fault or a stop takes the output to
//! the safe voltage along a trapezoidal velocity profile: the rate grows by
//! [`PARK_ACCEL`] per tick up to [`PARK_RATE`] (never beyond the slew limit) and
//! shrinks again so that the output arrives at rest. Ramping at the slew limit
//! instead (5 V per tick: 60 V in 0.6 ms) would be a step to a stage's first mode
//! and leave it ringing by about the distance travelled; the profile's residual
//! vibration is `v/ω·|sinc(ωT_a/2)|` per corner (`v` the stage speed, `T_a` =
//! 2 ms the ramp-up): on stage A (0.27 µm/V, 1.35 mm/s at full rate) 0.04 µm at
//! an 850 Hz mode and 0.4 µm at 300 Hz. A park over the whole 150 V range takes
//! 32 ms at 20 kHz.

use crate::error::ModelError;
use crate::q::{at_least, at_most, within, Volts};

/// Highest rate of a park, V per tick, `I16F16` (0.25 V: 5 kV/s at 20 kHz).
pub const PARK_RATE: Volts = Volts::from_bits(1 << 14);
/// Change of a park's rate per tick, V per tick², `I16F16` (reaches
/// [`PARK_RATE`] in 40 ticks: 2 ms at 20 kHz).
pub const PARK_ACCEL: Volts = Volts::from_bits((1 << 14) / PARK_RAMP_TICKS as i32);
/// Ticks a park takes to reach [`PARK_RATE`] (and to brake from it).
pub const PARK_RAMP_TICKS: u32 = 40;

/// The most ticks a park over `distance` volts takes (at most the slew limit's
/// rate permitting): `distance / PARK_RATE + PARK_RAMP_TICKS`, plus two for the
/// rounding of the last steps (`2√(d/a) ≤ d/R + R/a` covers the short parks that
/// never reach the full rate).
pub const fn park_ticks(distance: Volts) -> u32 {
    (distance.to_bits().unsigned_abs() / PARK_RATE.to_bits() as u32) + PARK_RAMP_TICKS + 2
}

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

    /// One tick of a park toward `target` (inside the range): from the output
    /// `prev` moving at `rate` (V per tick, signed), the next output and rate.
    /// The rate's magnitude changes by at most [`PARK_ACCEL`] per tick, stays
    /// within [`PARK_RATE`] and the slew limit, and falls early enough to
    /// arrive at `target` with a rate of at most [`PARK_ACCEL`]; the output then
    /// stays there. Integer arithmetic, no panic.
    #[inline]
    pub fn park(&self, prev: Volts, rate: Volts, target: Volts) -> (Volts, Volts) {
        let left = target.saturating_sub(prev);
        if left == Volts::ZERO {
            return (prev, Volts::ZERO);
        }
        let dist = left.saturating_abs();
        // The speed along the way to the target; a rate away from it is stopped.
        let along = if (rate > Volts::ZERO) == (left > Volts::ZERO) {
            rate.saturating_abs()
        } else {
            Volts::ZERO
        };
        // Braking from `along` at PARK_ACCEL covers along²/(2a) + along/2: brake
        // once that reaches the distance left (exact, in i64 of the raw bits).
        let (v, a) = (along.to_bits() as i64, PARK_ACCEL.to_bits() as i64);
        let brake = v * v >= 2 * a * (dist.to_bits() as i64 - v / 2);
        let top = at_most(PARK_RATE, self.max_step);
        let speed = if brake {
            at_least(along.saturating_sub(PARK_ACCEL), PARK_ACCEL)
        } else {
            at_most(along.saturating_add(PARK_ACCEL), top)
        };
        let speed = at_most(at_most(speed, top), dist);
        let next = if left > Volts::ZERO {
            prev.saturating_add(speed)
        } else {
            prev.saturating_sub(speed)
        };
        let rate = if left > Volts::ZERO { speed } else { -speed };
        (within(next, self.min, self.max), rate)
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

    /// Parks from `from` to `to`; the outputs.
    fn park_path(l: &OutputLimits, from: f64, to: f64) -> Vec<Volts> {
        let (mut u, mut rate, mut path) = (v(from), Volts::ZERO, Vec::new());
        while u != v(to) {
            (u, rate) = l.park(u, rate, v(to));
            path.push(u);
            assert!(path.len() < 100_000, "never arrives");
        }
        path
    }

    #[test]
    fn a_park_accelerates_cruises_and_arrives_at_rest() {
        let l = OutputLimits::new(v(0.0), v(150.0), v(5.0)).unwrap();
        for (from, to) in [(120.0, 0.0), (0.0, 75.0), (30.0, 29.99), (0.3, 0.0)] {
            let path = park_path(&l, from, to);
            let mut prev = (v(from), Volts::ZERO);
            for &u in &path {
                let rate = u - prev.0;
                assert!(rate.abs() <= PARK_RATE, "{from}→{to}: rate {rate}");
                // Rate changes by at most the acceleration (plus one bit of
                // the last, shortened step).
                assert!(
                    (rate - prev.1).abs() <= PARK_ACCEL || u == v(to),
                    "{from}→{to}: {} → {rate}",
                    prev.1
                );
                assert!((u - v(to)).abs() <= (prev.0 - v(to)).abs(), "monotone");
                prev = (u, rate);
            }
            assert!(prev.1.abs() <= PARK_ACCEL * 2, "arrives slowly: {}", prev.1);
        }
        // 120 V: 40 ticks up, cruise, 40 down: 120/0.25 + 40 ticks.
        let n = park_path(&l, 120.0, 0.0).len() as u32;
        assert!((515..=park_ticks(v(120.0))).contains(&n), "{n} ticks");
        for d in [0.001, 0.5, 3.0, 9.9, 10.1, 40.0, 150.0] {
            let n = park_path(&l, d, 0.0).len() as u32;
            assert!(n <= park_ticks(v(d)), "{d} V: {n} ticks");
        }
        // A slew limit below the park rate bounds it.
        let slow = OutputLimits::new(v(0.0), v(150.0), v(0.1)).unwrap();
        let path = park_path(&slow, 10.0, 0.0);
        assert!(path.windows(2).all(|w| (w[0] - w[1]).abs() <= v(0.1)));
        // A rate away from the target is stopped, not continued.
        let (u, rate) = l.park(v(50.0), v(-0.25), v(60.0));
        assert!(u > v(50.0) && rate > Volts::ZERO);
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
