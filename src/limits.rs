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
//!
//! **A damped park** ([`OutputLimits::park_damped`]). After a fault that leaves
//! the force sensor and the damping law above suspicion
//! ([`crate::control::Fault::damps_park`]), the application may keep its
//! active damping running through the park: its correction (V) is added to the
//! profile's point with a weight that is 1 while the profile is more than
//! [`PARK_FADE`] from the target or the park younger than
//! [`PARK_DAMPED_TICKS`] less [`PARK_FADE_TICKS`], and fades to 0 over the
//! last of both; the share is held to ±[`PARK_SPAN`] times the weight. The
//! output does not touch the target while the damping has a say, and arrives
//! there (the amplifier off) once the weight is zero. The profile itself is
//! the undamped park's (at most [`PARK_RATE`] per tick); the output's step,
//! profile and damping together, never exceeds the slew limit (below three
//! times the park rate: the undamped park), and the output stays in the range. A
//! caught oscillation then dies out at the damped stage's rate instead of its
//! own, also after a short park (the damping runs on at the target for at
//! least [`PARK_DAMPED_TICKS`]): such a park ends within
//! [`damped_park_ticks`].

use crate::error::ModelError;
use crate::q::{at_least, at_most, within, Volts};

/// Highest rate of a park, V per tick, `I16F16` (0.25 V: 5 kV/s at 20 kHz).
pub const PARK_RATE: Volts = Volts::from_bits(1 << 14);
/// Change of a park's rate per tick, V per tick², `I16F16` (reaches
/// [`PARK_RATE`] in 40 ticks: 2 ms at 20 kHz).
pub const PARK_ACCEL: Volts = Volts::from_bits((1 << 14) / PARK_RAMP_TICKS as i32);
/// Ticks a park takes to reach [`PARK_RATE`] (and to brake from it).
pub const PARK_RAMP_TICKS: u32 = 40;

/// The profile's distance to go over which a damped park fades its damping out,
/// V, `I16F16` (16 V, a power of two: the weight `min(d, PARK_FADE)/PARK_FADE`
/// is a shift).
pub const PARK_FADE: Volts = Volts::from_bits(1 << PARK_FADE_SHIFT);
/// `log2` of [`PARK_FADE`]'s raw bits.
const PARK_FADE_SHIFT: u32 = 20;
/// The least ticks a damped park keeps its damping (200 at full weight, then
/// faded out over [`PARK_FADE_TICKS`]): 13.2 ms at 20 kHz, some 4 time
/// constants of a 300 Hz mode damped to ζ 0.2.
pub const PARK_DAMPED_TICKS: u32 = 264;
/// Ticks over which a damped park's time weight fades out.
pub const PARK_FADE_TICKS: u32 = 64;
/// The largest share the damping takes of a damped park's output, V, `I16F16`
/// (32 V; at the last faded tick `PARK_SPAN/PARK_FADE_TICKS` = 2·[`PARK_RATE`]).
pub const PARK_SPAN: Volts = Volts::from_bits(1 << 21);

/// The most ticks a damped park ([`OutputLimits::park_damped`]) over
/// `distance` volts takes: [`park_ticks`], at least [`PARK_DAMPED_TICKS`] and
/// the one step after the damping's last.
pub const fn damped_park_ticks(distance: Volts) -> u32 {
    let t = park_ticks(distance);
    if t > PARK_DAMPED_TICKS + 1 {
        t
    } else {
        PARK_DAMPED_TICKS + 1
    }
}

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

    /// One tick of a damped park toward `target` (see the module docs): from
    /// the output `prev`, whose departure from the park's profile is `offset`
    /// (V, `I16F16`; zero when the park starts), the profile moving at `rate`,
    /// `tick` ticks into the park (0 at its first), and the damping's
    /// `correction` (V, `I16F16`), the next output, rate and offset.
    ///
    /// The profile is [`park`](Self::park)'s. The damping's share is
    /// `correction·w`, held to `±PARK_SPAN·w`, with the weight
    /// `w = max(min(1, d/PARK_FADE), min(1, (PARK_DAMPED_TICKS − tick)/PARK_FADE_TICKS))`
    /// (`d` the profile's distance still to go; `Q16` in `[0, 1]`): full while
    /// the profile is far from `target` or the park is young, faded out over
    /// the profile's last [`PARK_FADE`] and the park's last
    /// [`PARK_FADE_TICKS`] of [`PARK_DAMPED_TICKS`], zero after both. While the
    /// damping has a say (`w` nonzero, and the correction or the last offset)
    /// the output never touches `target` (it stays a bit away, on `prev`'s
    /// side): the
    /// application takes the target's first touch for the park's end. The
    /// output itself stays within `±PARK_SPAN·w` of the profile (a window whose
    /// ends move by at most 3·[`PARK_RATE`] per tick), so once `w` is zero it
    /// is the profile's and arrives with it; under a slew limit below
    /// 3·[`PARK_RATE`] the correction is ignored. The output's step never exceeds the slew
    /// limit, the output stays in the range. With a zero correction and
    /// offset it is [`park`](Self::park). Integer arithmetic, no panic.
    #[inline]
    pub fn park_damped(
        &self,
        prev: Volts,
        offset: Volts,
        rate: Volts,
        target: Volts,
        tick: u32,
        correction: Volts,
    ) -> (Volts, Volts, Volts) {
        let (p, rate) = self.park(prev.saturating_sub(offset), rate, target);
        // d ≤ the range (≤ 2¹⁶ V in I16F16); w in Q16: the products fit i64.
        let d = (target.to_bits() as i64 - p.to_bits() as i64).abs();
        let by_distance = d.min(1 << PARK_FADE_SHIFT) >> (PARK_FADE_SHIFT - 16);
        let left = PARK_DAMPED_TICKS.saturating_sub(tick).min(PARK_FADE_TICKS) as i64;
        let by_time = (left << 16) / PARK_FADE_TICKS as i64;
        let w = by_distance.max(by_time);
        // Under a slew limit below three times the park rate the window below
        // could move faster than the output: no damping there.
        let c = if self.max_step.to_bits() >= 3 * PARK_RATE.to_bits() {
            correction.to_bits() as i64
        } else {
            0
        };
        let span = (PARK_SPAN.to_bits() as i64 * w) >> 16;
        // `max`/`min`, not `clamp`: no panic path.
        let share = ((c * w) >> 16).max(-span).min(span);
        let want = (p.to_bits() as i64 + share)
            .max(i32::MIN as i64)
            .min(i32::MAX as i64);
        let (u, _) = self.apply(prev, Volts::from_bits(want as i32));
        // The output itself within ±PARK_SPAN·w of the profile, however the
        // slew limit lags the correction: that window's ends move by at most
        // PARK_RATE + PARK_SPAN/PARK_FADE_TICKS = 3·PARK_RATE per tick, within
        // the slew limit, and it closes on the profile with the weight. Moving
        // toward `p` (in the range) keeps `u` in the range.
        let mut u = within(
            u,
            Volts::from_bits((p.to_bits() as i64 - span).max(i32::MIN as i64) as i32),
            Volts::from_bits((p.to_bits() as i64 + span).min(i32::MAX as i64) as i32),
        );
        if u == target && w != 0 && (c != 0 || offset != Volts::ZERO) {
            // A damped park (the damping moves the output now, or moved it
            // last tick) whose weight is not yet zero: a bit away from the
            // target, toward `prev` (inside the slew window, which holds both),
            // or into the range where `prev` is the target.
            let up = prev > target || (prev == target && target == self.min);
            u = if up {
                target.saturating_add(Volts::DELTA)
            } else {
                target.saturating_sub(Volts::DELTA)
            };
            u = within(u, self.min, self.max);
        }
        (u, rate, u.saturating_sub(p))
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
    use fixed::types::I16F16;

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

    /// A damped park with the correction `c(k)` at tick `k`, from `from` to
    /// `to`, until the output first touches `to`: the outputs and offsets,
    /// checking every tick's rates and range, and that the output stays there.
    fn damped_path(
        l: &OutputLimits,
        from: f64,
        to: f64,
        c: impl Fn(usize) -> f64,
    ) -> Vec<(Volts, Volts)> {
        let (mut u, mut off, mut rate) = (v(from), Volts::ZERO, Volts::ZERO);
        let mut path = Vec::new();
        let step = |u: &mut Volts, off: &mut Volts, rate: &mut Volts, k: usize| {
            let prev = (*u, *u - *off);
            (*u, *rate, *off) = l.park_damped(*u, *off, *rate, v(to), k as u32, v(c(k)));
            let p = *u - *off;
            assert!((*u - prev.0).abs() <= l.max_step(), "{k}: slew");
            assert!((p - prev.1).abs() <= PARK_RATE, "{k}: the profile's rate");
            assert!(*u >= l.min() && *u <= l.max(), "{k}: range");
            assert!(off.abs() <= PARK_SPAN, "{k}: {off}");
        };
        while u != v(to) || path.is_empty() {
            step(&mut u, &mut off, &mut rate, path.len());
            path.push((u, off));
            assert!(path.len() < 100_000, "never arrives");
        }
        for k in path.len()..path.len() + 50 {
            step(&mut u, &mut off, &mut rate, k);
            assert_eq!((u, off), (v(to), Volts::ZERO), "{k}: stays");
        }
        path
    }

    #[test]
    fn a_damped_park_fades_its_damping_and_arrives_in_its_bound() {
        let ring = |amp: f64, hz: f64| {
            move |k: usize| amp * (k as f64 * hz / 20_000.0 * std::f64::consts::TAU).cos()
        };
        for step in [5.0, 0.75, 0.5, 0.1] {
            let l = OutputLimits::new(v(0.0), v(150.0), v(step)).unwrap();
            for (from, to) in [
                (120.0, 0.0),
                (0.0, 75.0),
                (60.0, 59.0),
                (0.3, 0.0),
                (150.0, 0.0),
                (140.0, 150.0),
            ] {
                for (amp, hz) in [
                    (0.0, 0.0),
                    (12.0, 300.0),
                    (40.0, 850.0),
                    (-200.0, 0.0),
                    (200.0, 0.0),
                ] {
                    let path = damped_path(&l, from, to, ring(amp, hz));
                    let n = path.len() as u32;
                    let plain = park_path(&l, from, to);
                    let d = v(from) - v(to);
                    // The bound at the park rate; under a slower slew limit, the
                    // undamped park's length.
                    let bound = damped_park_ticks(d).max(plain.len() as u32);
                    let what = format!("{from}→{to}, {amp} V at {hz} Hz, slew {step}");
                    assert!(n <= bound, "{what}: {n} ticks, bound {bound}");
                    let u: Vec<_> = path.iter().map(|x| x.0).collect();
                    if step < 0.75 || amp == 0.0 {
                        assert_eq!(u, plain, "{what}: undamped");
                    } else {
                        // The damping had its say for its least time.
                        assert!(n > PARK_DAMPED_TICKS, "{what}: {n} ticks");
                    }
                }
            }
        }
        // Far from the target and early the correction passes whole (slew
        // permitting); late and near it, in proportion to the weight.
        let l = OutputLimits::new(v(0.0), v(150.0), v(5.0)).unwrap();
        let z = Volts::ZERO;
        let (u, _, off) = l.park_damped(v(100.0), z, z, v(0.0), 0, v(3.0));
        assert_eq!((u, off), (v(100.0) - PARK_ACCEL + v(3.0), v(3.0)));
        let (_, _, off) = l.park_damped(v(8.0), z, z, v(0.0), 0, v(3.0));
        assert_eq!(off, v(3.0), "young");
        let late = PARK_DAMPED_TICKS - PARK_FADE_TICKS / 4;
        let (_, _, off) = l.park_damped(v(100.0), z, z, v(0.0), late, v(3.0));
        assert_eq!(off, v(3.0), "far");
        let (_, _, off) = l.park_damped(v(8.0), z, z, v(0.0), late, v(3.0));
        let d = v(8.0) - PARK_ACCEL;
        // The fade's weight, a ratio of voltages: dimensionless.
        let w = (d.raw() / PARK_FADE.raw()).max(I16F16::from_num(0.25));
        assert!(
            (off - Volts::from_raw(v(3.0).raw() * w)).abs() <= Volts::from_bits(2),
            "{off}"
        );
        // A large correction: held to PARK_SPAN·w (16 V here), the slew limit
        // permitting.
        let (u, _, off) = l.park_damped(v(20.0), v(12.0), z, v(0.0), late, v(100.0));
        let w = (v(8.0) - PARK_ACCEL).raw() / PARK_FADE.raw();
        assert!(
            (off - Volts::from_raw(PARK_SPAN.raw() * w)).abs() <= Volts::from_bits(4),
            "{off}"
        );
        assert!(u < v(25.0), "the window, not the slew limit");
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
