//! The trigger output: a digital line that a camera, an AFM controller or a
//! data logger lines its samples up with, driven once a tick from the stage's
//! measured position (PI's E-727 has three such outputs, piezosystem jena's
//! NV200 one).
//!
//! | condition | the line | its memory |
//! |---|---|---|
//! | [`Off`](Condition::Off) | low | — |
//! | [`Travel`](Condition::Travel) | a pulse each time the position has travelled `step` from the last pulse's point, either way | the last pulse's point (a multiple of `step` from where the trigger was set) |
//! | [`OnTarget`](Condition::OnTarget) | high while `|x − x_ref| ≤ band` | — |
//! | [`Window`](Condition::Window) | high while `low ≤ x ≤ high` | — |
//! | [`Point`](Condition::Point) | a pulse each time a stream takes its next point | the points taken |
//!
//! A pulse is high for [`Trigger::pulse_ticks`] ticks, from the tick its
//! condition is met (a new pulse within one restarts the count). A trigger
//! set anew starts its memory from the readings at that moment
//! ([`TriggerState::at`]). The line is
//! computed from the tick's own readings and written at the tick's end: the
//! latency from condition to edge is 0 ticks (the edge lies within the period
//! in which the position sensor saw the condition met).
//!
//! Positions are `I16F16` µm ([`Micrometres`]); every comparison is exact, so
//! an `f64` implementation of the same rule on the same readings gives the
//! same line, tick for tick (tested below).

use crate::process::SplitProcess;
use crate::q::Micrometres;

/// What drives the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Condition {
    /// The line stays low.
    #[default]
    Off,
    /// A pulse every `step` of travel (either way), counted from where the
    /// position was when the trigger was set. `step > 0`.
    Travel {
        /// Travel between pulses, µm.
        step: Micrometres,
    },
    /// High while the position is within `band` of the reference. `band ≥ 0`.
    OnTarget {
        /// Half-width of the band, µm.
        band: Micrometres,
    },
    /// High while `low ≤ x ≤ high`. `low ≤ high`.
    Window {
        /// Lower edge, µm.
        low: Micrometres,
        /// Upper edge, µm.
        high: Micrometres,
    },
    /// A pulse at each point a streamed trajectory takes.
    Point,
}

/// The trigger output's configuration (validated: [`Trigger::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trigger {
    condition: Condition,
    pulse_ticks: u16,
}

/// Why a trigger's configuration is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriggerError {
    /// `Travel`'s step is not above zero.
    Step,
    /// `OnTarget`'s band is below zero.
    Band,
    /// `Window`'s low edge is above its high edge.
    Window,
    /// A pulse lasts no tick.
    Pulse,
}

impl TriggerError {
    /// The rule broken, for the refusal a host prints.
    pub const fn rule(self) -> &'static str {
        match self {
            Self::Step => "a travel trigger's step must be above 0 µm",
            Self::Band => "an on-target trigger's band must be at least 0 µm",
            Self::Window => "a window trigger's low edge must not lie above its high edge",
            Self::Pulse => "a travel or point trigger's pulse lasts at least 1 tick",
        }
    }
}

impl Trigger {
    /// The line low (all zero: a static holding it costs no flash).
    pub const OFF: Self = Self {
        condition: Condition::Off,
        pulse_ticks: 0,
    };

    /// `condition`, its pulses `pulse_ticks` long (`Travel` and `Point`: at
    /// least 1; the other conditions have no pulse), or the rule it breaks.
    pub fn new(condition: Condition, pulse_ticks: u16) -> Result<Self, TriggerError> {
        let z = Micrometres::ZERO;
        match condition {
            Condition::Travel { step } if step <= z => return Err(TriggerError::Step),
            Condition::OnTarget { band } if band < z => return Err(TriggerError::Band),
            Condition::Window { low, high } if low > high => return Err(TriggerError::Window),
            _ => {}
        }
        let pulsed = matches!(condition, Condition::Travel { .. } | Condition::Point);
        if pulsed && pulse_ticks == 0 {
            return Err(TriggerError::Pulse);
        }
        Ok(Self {
            condition,
            pulse_ticks,
        })
    }

    /// What drives the line.
    pub const fn condition(&self) -> Condition {
        self.condition
    }

    /// Ticks a pulse stays high.
    pub const fn pulse_ticks(&self) -> u16 {
        self.pulse_ticks
    }
}

impl Default for Trigger {
    fn default() -> Self {
        Self::OFF
    }
}

/// The trigger output's memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TriggerState {
    /// The last pulse's point (`Travel`), µm.
    anchor: Micrometres,
    /// Ticks the pulse stays high.
    left: u16,
    /// The stream's points taken, as last seen (`Point`).
    points: u32,
}

impl TriggerState {
    /// The memory of a trigger set now, with the position at `x` and the
    /// stream's points taken at `points`: a travel trigger counts from `x`,
    /// a point trigger from the next point.
    pub const fn at(x: Micrometres, points: u32) -> Self {
        Self {
            anchor: x,
            left: 0,
            points,
        }
    }
}

/// One tick's readings for the trigger.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Readings {
    /// The measured position, µm.
    pub x: Micrometres,
    /// The reference the loops track, µm.
    pub x_ref: Micrometres,
    /// The stream's points taken so far (free-running; a new stream starts
    /// it from 0 again).
    pub points: u32,
}

impl SplitProcess<Readings, bool, TriggerState> for Trigger {
    /// This tick's line (`true`: high). Bounded, no division, no panic.
    #[inline]
    fn process(&self, s: &mut TriggerState, r: Readings) -> bool {
        let hit = match self.condition {
            Condition::Off => false,
            Condition::OnTarget { band } => {
                return r.x.saturating_sub(r.x_ref).saturating_abs() <= band
            }
            Condition::Window { low, high } => return low <= r.x && r.x <= high,
            Condition::Travel { step } => {
                let d = r.x.saturating_sub(s.anchor);
                if d >= step {
                    s.anchor = s.anchor.saturating_add(step);
                } else if d <= -step {
                    s.anchor = s.anchor.saturating_sub(step);
                }
                d.saturating_abs() >= step
            }
            Condition::Point => {
                // A stream cleared counts from 0 again: no pulse.
                let taken = r.points.wrapping_sub(s.points) as i32 > 0;
                s.points = r.points;
                taken
            }
        };
        if hit {
            s.left = self.pulse_ticks;
        }
        if s.left == 0 {
            return false;
        }
        s.left -= 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    /// The rule in `f64`, on the same readings: the reference the fixed-point
    /// line is held to, tick for tick.
    fn reference(c: Condition, pulse: u16, xs: &[(f64, f64, u32)]) -> Vec<bool> {
        let f = |m: Micrometres| m.to_num::<f64>();
        let (mut anchor, mut left, mut seen) = (xs[0].0, 0u16, xs[0].2);
        xs.iter()
            .map(|&(x, x_ref, points)| {
                let hit = match c {
                    Condition::Off => return false,
                    Condition::OnTarget { band } => return (x - x_ref).abs() <= f(band),
                    Condition::Window { low, high } => return f(low) <= x && x <= f(high),
                    Condition::Travel { step } => {
                        if x - anchor >= f(step) {
                            anchor += f(step);
                            true
                        } else if x - anchor <= -f(step) {
                            anchor -= f(step);
                            true
                        } else {
                            false
                        }
                    }
                    Condition::Point => {
                        let hit = points > seen;
                        seen = points;
                        hit
                    }
                };
                if hit {
                    left = pulse;
                }
                let high = left > 0;
                left = left.saturating_sub(1);
                high
            })
            .collect()
    }

    fn run(t: &Trigger, xs: &[(f64, f64, u32)]) -> Vec<bool> {
        let (x0, _, p0) = xs[0];
        let mut s = TriggerState::at(um(x0), p0);
        xs.iter()
            .map(|&(x, x_ref, points)| {
                t.process(
                    &mut s,
                    Readings {
                        x: um(x),
                        x_ref: um(x_ref),
                        points,
                    },
                )
            })
            .collect()
    }

    /// A noisy raster: up and down a 10 µm line at varying speed, the
    /// reference ahead of the position, points taken every 7th tick. Every
    /// reading is an `I16F16` value, so `f64` holds it exactly.
    fn raster() -> Vec<(f64, f64, u32)> {
        let q = |x: f64| um(x).to_num::<f64>();
        let mut seed = 0x2545_F491u32;
        (0..4000)
            .map(|k| {
                seed ^= seed << 13;
                seed ^= seed >> 17;
                seed ^= seed << 5;
                let noise = (seed as f64 / u32::MAX as f64 - 0.5) * 0.02;
                let t = k as f64 / 4000.0;
                let x = 20.0 + 5.0 * (std::f64::consts::TAU * 3.0 * t).sin();
                (q(x + noise), q(x + 0.05), k / 7)
            })
            .collect()
    }

    #[test]
    fn every_condition_gives_the_f64_reference_s_line_tick_for_tick() {
        let xs = raster();
        for (c, pulse) in [
            (Condition::Off, 1),
            (Condition::Travel { step: um(0.5) }, 3),
            (Condition::Travel { step: um(0.013) }, 1),
            (Condition::OnTarget { band: um(0.055) }, 1),
            (
                Condition::Window {
                    low: um(18.0),
                    high: um(22.5),
                },
                1,
            ),
            (Condition::Point, 2),
        ] {
            let t = Trigger::new(c, pulse).unwrap();
            let line = run(&t, &xs);
            assert_eq!(line, reference(c, pulse, &xs), "{c:?}");
            assert_eq!(line.contains(&true), c != Condition::Off, "{c:?}");
            assert!(line.contains(&false), "{c:?}");
        }
    }

    #[test]
    fn travel_pulses_once_per_step_of_a_line_in_either_direction() {
        // 0 → 10 µm and back in 0.01 µm ticks: 20 pulses of 0.5 µm each way.
        let up = (0..=1000).map(|k| (k as f64 * 0.01, 0.0, 0));
        let down = (0..=1000).rev().map(|k| (k as f64 * 0.01, 0.0, 0));
        let xs: Vec<_> = up
            .chain(down)
            .map(|(x, r, p)| (um(x).to_num(), r, p))
            .collect();
        let t = Trigger::new(Condition::Travel { step: um(0.5) }, 1).unwrap();
        let line = run(&t, &xs);
        let rising = line.windows(2).filter(|w| !w[0] && w[1]).count();
        assert_eq!(rising, 40);
    }

    #[test]
    fn a_point_pulses_as_long_as_asked_and_the_first_tick_does_not() {
        let xs: Vec<_> = (0..40).map(|k| (0.0, 0.0, 5 + k / 10)).collect();
        let t = Trigger::new(Condition::Point, 4).unwrap();
        let line = run(&t, &xs);
        let high: Vec<usize> = (0..40).filter(|&k| line[k]).collect();
        assert_eq!(high, [10, 11, 12, 13, 20, 21, 22, 23, 30, 31, 32, 33]);
    }

    #[test]
    fn a_configuration_that_breaks_a_rule_is_refused_by_name() {
        let cases = [
            (Condition::Travel { step: um(0.0) }, 1, TriggerError::Step),
            (
                Condition::OnTarget { band: um(-0.1) },
                1,
                TriggerError::Band,
            ),
            (
                Condition::Window {
                    low: um(2.0),
                    high: um(1.0),
                },
                1,
                TriggerError::Window,
            ),
            (Condition::Point, 0, TriggerError::Pulse),
        ];
        for (c, p, e) in cases {
            assert_eq!(Trigger::new(c, p), Err(e));
            assert!(!e.rule().is_empty());
        }
    }
}
