//! Feedback on a stage-position sensor: a PI law with anti-windup, and the
//! sensor's supervision.
//!
//! ```text
//! e = x_ref − x_sensor                               µm, I16F16
//! δ = clamp(kp·e + I, lo, hi)                        µm, I16F16
//! I ← clamp(I + ki·e, lo, hi)                        µm, I24F40 (raw i64)
//!     unless the last output saturated in the direction ki·e pushes
//! ```
//!
//! `kp` (µm/µm) and `ki` (per tick: `Ki·T_s`) are [`LoopGain`]s (`I8F24`); the
//! products `kp·e`, `ki·e` are exact in 64 bits (40 fractional bits) and the
//! integrator keeps all of them, so a 1 nm error with `ki = 0.01` still integrates
//! (a plain `I16F16` integrator would drop it). The output is rounded once.
//!
//! **Anti-windup** is conditional integration: when the last control step was
//! limited ([`Saturation`]: the output limits, the slew limit or the command's
//! clamp to the stroke) the integrator does not move further into that limit; it
//! may always unwind. Its value is clamped to the output range too.
//!
//! **Bumpless transfer**: [`Pi::preset`] sets the integrator so that the next
//! output equals the command in use, whatever the error; the application calls it
//! when it switches from open to closed loop or between laws.
//!
//! The law is the application's to place: with the FPI inverse as feedforward the
//! correction is added to the reference (`x_cmd = x_ref + δ`, range `±limit`); as
//! feedback only, `δ` is the whole command (range: the stroke).
//!
//! The sensor is supervised like the force sensor: a reading outside its
//! plausible range is [`Fault::PositionOutOfRange`]; a reading that disagrees with
//! the model's estimate `f_K(x̂_pea)` by more than a tolerance is
//! [`Fault::PositionImplausible`] (a stuck sensor in closed loop drives the output
//! away from the model until the two part).

use crate::control::{Fault, Interval, Window};
use crate::error::{Field, Invalid, ModelError};
use crate::process::SplitProcess;
use crate::q::{LoopGain, Micrometres, Volts, INTEGRAL_FRAC, LOOP_GAIN_FRAC, SIGNAL_ABS_MAX_BITS};

/// Largest proportional gain, µm/µm.
pub const KP_MAX: LoopGain = LoopGain::from_bits(Field::FeedbackKp.decl().bits().1 as i32);
const _: () = assert!(KP_MAX.to_bits() == 16 << LOOP_GAIN_FRAC);
/// Largest integral gain, per tick.
pub const KI_MAX: LoopGain = LoopGain::from_bits(1 << LOOP_GAIN_FRAC);

/// Feedback settings as a model stores them (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeedbackSpec {
    /// Proportional gain, µm/µm, `I8F24`, 0..=16.
    pub kp: LoopGain,
    /// Integral gain per tick (`Ki·T_s`), `I8F24`, 0..=1.
    pub ki: LoopGain,
    /// Largest correction the feedback adds to the reference, µm (> 0).
    pub limit: Micrometres,
    /// Plausible sensor readings, µm.
    pub sensor: Interval<Micrometres>,
    /// Largest tolerated `|x_sensor − f_K(x̂_pea)|`, µm (> 0).
    pub tolerance: Micrometres,
}

/// Validated feedback settings with the supervision windows (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeedbackConfig {
    spec: FeedbackSpec,
    sensor: Window,
    residual: Window,
}

impl FeedbackConfig {
    /// Checks `spec`: gains in range and not both zero, a positive limit and
    /// tolerance inside the signal range, the sensor interval not inverted. The one
    /// check, shared by the model validator and the firmware.
    pub const fn new(spec: FeedbackSpec) -> Result<Self, Invalid> {
        let (kp, ki) = (spec.kp.to_bits(), spec.ki.to_bits());
        if kp < 0 || kp > KP_MAX.to_bits() {
            return Err(Invalid::at(Field::FeedbackKp, ModelError::GainOutOfRange));
        }
        if ki < 0 || ki > KI_MAX.to_bits() || (kp == 0 && ki == 0) {
            return Err(Invalid::at(Field::FeedbackKi, ModelError::GainOutOfRange));
        }
        let limit = spec.limit.to_bits();
        if limit <= 0 || limit > SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::FeedbackLimit,
                ModelError::LimitOutOfRange,
            ));
        }
        let tol = spec.tolerance.to_bits();
        if tol <= 0 || tol > SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::PositionTolerance,
                ModelError::NonPositiveTolerance,
            ));
        }
        let Some(sensor) = Window::new(spec.sensor.lo.to_bits(), spec.sensor.hi.to_bits()) else {
            return Err(Invalid::at(Field::PositionMin, ModelError::LimitsInverted));
        };
        if spec.sensor.lo.to_bits() < -SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::PositionMin,
                ModelError::NotRepresentable,
            ));
        }
        if spec.sensor.hi.to_bits() > SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::PositionMax,
                ModelError::NotRepresentable,
            ));
        }
        let Some(residual) = Window::new(-tol, tol) else {
            return Err(Invalid::at(
                Field::PositionTolerance,
                ModelError::NonPositiveTolerance,
            ));
        };
        Ok(Self {
            spec,
            sensor,
            residual,
        })
    }

    /// The settings.
    pub const fn spec(&self) -> &FeedbackSpec {
        &self.spec
    }

    /// The correction's range with feedforward, `[−limit, limit]`, µm.
    pub const fn correction(&self) -> Interval<Micrometres> {
        Interval {
            lo: Micrometres::from_bits(-self.spec.limit.to_bits()),
            hi: self.spec.limit,
        }
    }

    /// Checks a position reading (µm) against the sensor's range and against the
    /// model's estimate of the stage position (µm); the fault, if any.
    #[inline]
    pub fn check(&self, reading: Micrometres, estimate: Micrometres) -> Option<Fault> {
        if !self.sensor.contains(reading) {
            Some(Fault::PositionOutOfRange)
        } else if !self
            .residual
            .contains_bits(reading.to_bits().wrapping_sub(estimate.to_bits()))
        {
            Some(Fault::PositionImplausible)
        } else {
            None
        }
    }
}

/// Whether, and in which direction, the last control step was limited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Saturation {
    /// The step gave what was asked.
    Free,
    /// It gave less than asked (the limits or the clamp held it down).
    High,
    /// It gave more than asked (held up).
    Low,
}

impl Saturation {
    /// The direction of a limited step from the voltages before and after it: a
    /// rise (or a stay in the upper half of `[u_min, u_max]`) was held down, a fall
    /// (or a stay in the lower half) held up.
    #[inline]
    pub fn of_step(limited: bool, before: Volts, after: Volts, mid: Volts) -> Self {
        if !limited {
            Self::Free
        } else if after > before || (after == before && after >= mid) {
            Self::High
        } else {
            Self::Low
        }
    }

    /// This saturation, or the command's own clamp to `[lo, hi]` when it bit.
    #[inline]
    pub fn or_clamp(self, wanted: Micrometres, lo: Micrometres, hi: Micrometres) -> Self {
        if wanted > hi {
            Self::High
        } else if wanted < lo {
            Self::Low
        } else {
            self
        }
    }
}

/// The PI law's memory: the integrator, µm as `I24F40` (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Pi {
    integral: i64,
}

/// `x` (µm, `I16F16`) in the integrator's format.
const fn wide(x: Micrometres) -> i64 {
    (x.to_bits() as i64) << (INTEGRAL_FRAC - 16)
}

impl Pi {
    /// An empty integrator.
    pub const fn new() -> Self {
        Self { integral: 0 }
    }

    /// The integrator's value, µm (rounded to `I16F16`).
    pub const fn integral(&self) -> Micrometres {
        Micrometres::from_bits(narrow(self.integral))
    }

    /// Sets the integrator so that the law's next step with `error` returns
    /// `output` (bumpless transfer); `output` within `[lo, hi]`.
    pub fn preset(&mut self, cfg: &FeedbackConfig, output: Micrometres, error: Micrometres) {
        self.integral = wide(output) - cfg.spec.kp.to_bits() as i64 * error.to_bits() as i64;
    }
}

/// The position PI: error, saturation and output range in, µm out.
impl SplitProcess<(Micrometres, Saturation, Interval<Micrometres>), Micrometres, Pi>
    for FeedbackConfig
{
    /// One step of the law on the error `e` (µm): the output `kp·e + I` clamped
    /// to the output range `[lo, hi]` (µm), then
    /// the integrator advanced by `ki·e` unless `sat` says the last step was held
    /// in that direction. Bounded time, no division, no panic.
    #[inline]
    fn process(
        &self,
        pi: &mut Pi,
        (error, sat, range): (Micrometres, Saturation, Interval<Micrometres>),
    ) -> Micrometres {
        let e = error.to_bits() as i64;
        let (lo, hi) = (wide(range.lo), wide(range.hi));
        // The sums cannot overflow (plain adds, cheaper than saturating ones):
        // |kp·e| < 2^59 and |ki·e| < 2^55 (gains validated, `e` an `i32`), and
        // the integrator stays below 2^55 + 2^59 (within a range of `I16F16`
        // values, or a preset: an output less kp·e).
        // `max`/`min`, not `clamp`: no panic path for an inverted range.
        let out = (self.spec.kp.to_bits() as i64 * e)
            .wrapping_add(pi.integral)
            .max(lo)
            .min(hi);
        let step = self.spec.ki.to_bits() as i64 * e;
        let winds = match sat {
            Saturation::Free => false,
            Saturation::High => step > 0,
            Saturation::Low => step < 0,
        };
        if !winds {
            pi.integral = pi.integral.wrapping_add(step).max(lo).min(hi);
        }
        Micrometres::from_bits(narrow(out))
    }
}

/// `I24F40` to `I16F16` bits, rounded to nearest (the caller keeps it in ±4096).
const fn narrow(x: i64) -> i32 {
    const SHIFT: u32 = INTEGRAL_FRAC - 16;
    ((x + (1 << (SHIFT - 1))) >> SHIFT) as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    fn spec() -> FeedbackSpec {
        FeedbackSpec {
            kp: LoopGain::from_num(0.5),
            ki: LoopGain::from_num(0.02),
            limit: um(4.0),
            sensor: Interval {
                lo: um(-5.0),
                hi: um(60.0),
            },
            tolerance: um(3.0),
        }
    }

    fn cfg() -> FeedbackConfig {
        FeedbackConfig::new(spec()).unwrap()
    }

    #[test]
    fn settings_are_checked_naming_the_key() {
        let bad = |s: FeedbackSpec| FeedbackConfig::new(s).unwrap_err().field;
        let kp = LoopGain::from_num(-0.1);
        assert_eq!(bad(FeedbackSpec { kp, ..spec() }), Field::FeedbackKp);
        let ki = LoopGain::from_num(1.5);
        assert_eq!(bad(FeedbackSpec { ki, ..spec() }), Field::FeedbackKi);
        let zero = LoopGain::ZERO;
        assert_eq!(
            bad(FeedbackSpec {
                kp: zero,
                ki: zero,
                ..spec()
            }),
            Field::FeedbackKi
        );
        assert_eq!(
            bad(FeedbackSpec {
                limit: um(0.0),
                ..spec()
            }),
            Field::FeedbackLimit
        );
        let e = FeedbackConfig::new(FeedbackSpec {
            limit: um(0.0),
            ..spec()
        })
        .unwrap_err();
        assert!(
            e.error.message().contains("must be > 0"),
            "{}",
            e.error.message()
        );
        assert_eq!(
            bad(FeedbackSpec {
                tolerance: um(-1.0),
                ..spec()
            }),
            Field::PositionTolerance
        );
        let inverted = Interval {
            lo: um(10.0),
            hi: um(0.0),
        };
        assert_eq!(
            bad(FeedbackSpec {
                sensor: inverted,
                ..spec()
            }),
            Field::PositionMin
        );
    }

    /// A plant `x = 0.9·u + 1` (a 10 % gain error and an offset) under the law
    /// with feedforward `u = x_ref + δ`: the integrator removes the error.
    #[test]
    fn integral_action_removes_a_gain_and_offset_error() {
        let c = cfg();
        let mut pi = Pi::new();
        let (mut x, r) = (0.0, 20.0);
        for _ in 0..2000 {
            let d = c.process(&mut pi, (um(r - x), Saturation::Free, c.correction()));
            x = 0.9 * (r + d.to_num::<f64>()) + 1.0;
        }
        assert!((x - r).abs() < 1e-4, "{x}");
        // δ settles where 0.9·(r + δ) + 1 = r.
        let want = r / 0.9 - 1.0 / 0.9 - r;
        assert!((pi.integral().to_num::<f64>() - want).abs() < 1e-3);
    }

    #[test]
    fn tiny_errors_still_integrate() {
        let c = cfg();
        let mut pi = Pi::new();
        // 1 nm × 0.02 per tick is 0.3 LSB of I16F16: it must not be lost.
        let e = um(0.001);
        for _ in 0..10_000 {
            c.process(&mut pi, (e, Saturation::Free, c.correction()));
        }
        let want = 10_000.0 * c.spec().ki.to_num::<f64>() * e.to_num::<f64>();
        let i = pi.integral().to_num::<f64>();
        assert!((i - want).abs() < 2e-5, "{i} vs {want}");
    }

    #[test]
    fn the_integrator_does_not_wind_into_a_limit_but_unwinds() {
        let c = cfg();
        let mut pi = Pi::new();
        for _ in 0..100 {
            c.process(&mut pi, (um(1.0), Saturation::High, c.correction()));
        }
        assert_eq!(pi.integral(), Micrometres::ZERO, "held while saturated");
        for _ in 0..10 {
            c.process(&mut pi, (um(-1.0), Saturation::High, c.correction()));
        }
        assert!(pi.integral() < Micrometres::ZERO, "unwinds");
        // Free: it integrates, clamped to the range.
        for _ in 0..10_000 {
            c.process(&mut pi, (um(50.0), Saturation::Free, c.correction()));
        }
        assert_eq!(pi.integral(), um(4.0));
        let out = c.process(&mut pi, (um(50.0), Saturation::Free, c.correction()));
        assert_eq!(out, um(4.0), "the output is clamped");
    }

    #[test]
    fn preset_makes_the_next_output_the_command_in_use() {
        let c = cfg();
        let mut pi = Pi::new();
        pi.preset(&c, um(1.25), um(0.7));
        let out = c.process(&mut pi, (um(0.7), Saturation::Free, c.correction()));
        assert_eq!(out, um(1.25));
    }

    #[test]
    fn the_sensor_is_checked_for_range_and_plausibility() {
        let c = cfg();
        assert_eq!(c.check(um(20.0), um(22.9)), None);
        assert_eq!(
            c.check(um(20.0), um(23.1)),
            Some(Fault::PositionImplausible)
        );
        assert_eq!(
            c.check(um(20.0), um(16.9)),
            Some(Fault::PositionImplausible)
        );
        assert_eq!(c.check(um(61.0), um(61.0)), Some(Fault::PositionOutOfRange));
        assert_eq!(c.check(um(-5.0), um(-4.0)), None);
    }

    #[test]
    fn saturation_direction_follows_the_step() {
        let (a, b, mid) = (
            Volts::from_num(10),
            Volts::from_num(11),
            Volts::from_num(75),
        );
        assert_eq!(Saturation::of_step(false, a, b, mid), Saturation::Free);
        assert_eq!(Saturation::of_step(true, a, b, mid), Saturation::High);
        assert_eq!(Saturation::of_step(true, b, a, mid), Saturation::Low);
        let top = Volts::from_num(150);
        assert_eq!(Saturation::of_step(true, top, top, mid), Saturation::High);
        assert_eq!(Saturation::of_step(true, a, a, mid), Saturation::Low);
        let s = Saturation::Free.or_clamp(um(5.0), um(0.0), um(4.0));
        assert_eq!(s, Saturation::High);
    }
}
