//! The reference the control loop follows, from one of six sources chosen at run
//! time: hold, move (a slew-limited ramp to a position, or a step: a raised
//! cosine of a given duration), a waveform ([`wave`]), a streamed trajectory
//! ([`stream`]), the analog input ([`analog`]) or an axis's part of a raster
//! ([`raster`]: it waits at its start until the loop starts every axis of the
//! raster on one tick).
//!
//! Switching never makes the reference jump: a new waveform, stream or analog input
//! starts with an *approach*, a ramp at the board's approach speed from where the
//! reference is to where the new source begins (the wave's phase-0 value, the first
//! streamed point, the live analog reading), and only then hands over. A move is a
//! ramp by itself. When a move arrives, a finite wave has run its cycles or an
//! ended stream is drained, the source becomes *hold* at that point.
//!
//! Everything here runs in the control ISR (integer arithmetic, no division, no
//! panic, constant time per tick). What a source may ask of the stage is not
//! checked here, source by source: every source's reference passes the one
//! reference governor (`piezo_fpi::governor`, [`crate::control::governors`]) before
//! the loops track it.

pub mod analog;
pub mod raster;
pub mod stream;
pub mod wave;

use piezo_fpi::q::Micrometres;

use analog::{AnalogFault, AnalogInput};
use raster::{RasterAxis, RasterPhase};
use stream::{Playback, Points};
use wave::{Wave, WavePhase};

pub use fpi_protocol::SourceKind;

/// The shortest step the lead's mass ratio learns from, ticks (1.5 ms: the
/// steps `fpi board autotune` measures the ratio's baseline on). The fit's
/// ratio depends on the step's speed: on the stage as built, eight 1.0 ms
/// steps took it from 1 to 1.22 and their settling from 1.45 to 3.8 ms; 2 ms
/// steps to about 0.98 (book: `docs/src/mass-ratio.md`, *The learned mass ratio*).
pub const LEARNING_STEP_TICKS: u32 = 30;
/// The largest phase advance of a step the ratio learns from, 2⁻³² turns per
/// tick ([`step_phase_for`] of [`LEARNING_STEP_TICKS`]).
const LEARNING_PHASE_STEP: u32 = step_phase_for(LEARNING_STEP_TICKS);

/// A new source, as the link task orders it (values already checked against the
/// model's stroke).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceOrder {
    /// Stop where the reference is.
    Hold,
    /// Ramp to `target` (µm) at `step` µm per tick (> 0).
    Move {
        /// Where to, µm.
        target: Micrometres,
        /// Ramp speed, µm per tick.
        step: Micrometres,
    },
    /// Step to `target` (µm) along a raised cosine, `x = from + (target −
    /// from)·(1 − cos πτ)/2`, its phase advancing `phase_step` (2⁻³² turns) per
    /// tick over half a turn: zero speed at both ends, so that a feedforward of
    /// the stage's dynamics can follow it.
    Step {
        /// Where to, µm.
        target: Micrometres,
        /// Phase advance per tick, 2⁻³² turns (half a turn over the step).
        phase_step: u32,
    },
    /// Run a waveform.
    Wave(Wave),
    /// Play the streamed points, one every `interval` ticks.
    Stream {
        /// Ticks per point (≥ 1).
        interval: u16,
    },
    /// Follow the analog input.
    Analog,
    /// This axis's part of a raster: held at its start once there until the
    /// loop releases every axis of the raster on one tick
    /// ([`Reference::release`]).
    Raster(RasterAxis),
}

impl SourceOrder {
    /// A trigger input set to start motions holds it until its edge (a wave
    /// or a stream; a move, a step, a hold or the analog input start at once).
    pub const fn waits_for_trigger(&self) -> bool {
        matches!(self, Self::Wave(_) | Self::Stream { .. })
    }
}

/// The running source (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Active {
    Hold,
    Move {
        target: Micrometres,
        step: Micrometres,
    },
    Step {
        from: Micrometres,
        target: Micrometres,
        phase: u32,
        phase_step: u32,
    },
    Wave {
        wave: Wave,
        phase: WavePhase,
    },
    Stream {
        interval: u16,
        playback: Playback,
    },
    Analog,
    Raster {
        axis: RasterAxis,
        phase: RasterPhase,
        /// Released: the lines run.
        go: bool,
    },
}

/// The reference generator (state; its approach speed is configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reference {
    x: Micrometres,
    active: Active,
    /// Still ramping to the source's entry point.
    approaching: bool,
    /// Approach speed, µm per tick.
    approach: Micrometres,
    analog: AnalogInput,
}

/// Moves `x` toward `to` by at most `step`; whether it arrived.
#[inline]
fn toward(x: &mut Micrometres, to: Micrometres, step: Micrometres) -> bool {
    let d = to.to_bits() as i64 - x.to_bits() as i64;
    let s = step.to_bits() as i64;
    if d.abs() <= s {
        *x = to;
        true
    } else {
        let moved = if d > 0 { s } else { -s };
        *x = Micrometres::from_bits((x.to_bits() as i64 + moved) as i32);
        false
    }
}

/// Half a turn of phase, 2⁻³² turns.
const HALF_TURN: u32 = 1 << 31;

/// `from + (to − from)·(1 − cos 2πφ)/2` for a phase `φ` in 2⁻³² turns
/// (`φ ≤ ½` turn), µm.
#[inline]
fn raised_cosine(from: Micrometres, to: Micrometres, phase: u32) -> Micrometres {
    // (1 − cos)/2 in I2F30, from the shared cosine table.
    let s = ((1i64 << 30) - crate::control::cosine::cos_turns(phase) as i64) >> 1;
    let d = to.to_bits() as i64 - from.to_bits() as i64;
    Micrometres::from_bits((from.to_bits() as i64 + ((d * s + (1 << 29)) >> 30)) as i32)
}

/// The phase step of a step of `ticks` ticks (half a turn over them), 2⁻³² turns
/// per tick; at least one tick.
pub const fn step_phase_for(ticks: u32) -> u32 {
    let t = if ticks == 0 { 1 } else { ticks };
    HALF_TURN / t
}

impl Reference {
    /// Holding at `x`, with transitions at `approach` µm per tick and the analog
    /// input scaled by `analog`.
    pub const fn new(x: Micrometres, approach: Micrometres, analog: AnalogInput) -> Self {
        Self {
            x,
            active: Active::Hold,
            approaching: false,
            approach,
            analog,
        }
    }

    /// Switches to a new source (at the start of the next tick, without a jump).
    pub fn select(&mut self, order: SourceOrder) {
        self.approaching = !matches!(
            order,
            SourceOrder::Hold | SourceOrder::Move { .. } | SourceOrder::Step { .. }
        );
        self.active = match order {
            SourceOrder::Hold => Active::Hold,
            SourceOrder::Move { target, step } => Active::Move { target, step },
            SourceOrder::Step { target, phase_step } => Active::Step {
                from: self.x,
                target,
                phase: 0,
                phase_step,
            },
            SourceOrder::Wave(wave) => Active::Wave {
                wave,
                phase: WavePhase::default(),
            },
            SourceOrder::Stream { interval } => Active::Stream {
                interval,
                playback: Playback::new(self.x, interval),
            },
            SourceOrder::Analog => {
                self.analog.restart();
                Active::Analog
            }
            SourceOrder::Raster(axis) => Active::Raster {
                axis,
                phase: RasterPhase::default(),
                go: false,
            },
        };
    }

    /// Stops where the reference is (a fault, or a new model).
    pub fn freeze(&mut self) {
        self.active = Active::Hold;
        self.approaching = false;
    }

    /// Restarts holding at `x` (after a model swap: the stage is at rest there).
    pub fn reset(&mut self, x: Micrometres, analog: AnalogInput) {
        *self = Self::new(x, self.approach, analog);
    }

    /// The next reference, µm. `points` feeds a stream; `counts` is this tick's
    /// analog reading (read by the caller only while [`wants_analog`](Self::wants_analog)).
    #[inline]
    pub fn next<const P: usize>(
        &mut self,
        points: &mut Points<P>,
        counts: u16,
    ) -> Result<Micrometres, AnalogFault> {
        if self.approaching {
            let entry = match &self.active {
                Active::Wave { wave, .. } => wave.start_value(),
                Active::Raster { axis, .. } => axis.start_value(),
                Active::Stream { .. } => points.peek().unwrap_or(self.x),
                Active::Analog => self.analog.read(counts)?,
                Active::Hold | Active::Move { .. } | Active::Step { .. } => self.x,
            };
            self.approaching = !toward(&mut self.x, entry, self.approach);
            if let (false, Active::Stream { interval, playback }) =
                (self.approaching, &mut self.active)
            {
                *playback = Playback::new(self.x, *interval);
            }
            return Ok(self.x);
        }
        match &mut self.active {
            Active::Hold => {}
            Active::Move { target, step } => {
                if toward(&mut self.x, *target, *step) {
                    self.active = Active::Hold;
                }
            }
            Active::Step {
                from,
                target,
                phase,
                phase_step,
            } => {
                let (next, over) = phase.overflowing_add(*phase_step);
                if over || next >= HALF_TURN {
                    self.x = *target;
                    self.active = Active::Hold;
                } else {
                    *phase = next;
                    self.x = raised_cosine(*from, *target, next);
                }
            }
            Active::Wave { wave, phase } => {
                if phase.finished() {
                    // The tick after the last cycle's last value: back at
                    // phase 0, end exactly on the start value (the last
                    // value is not skipped: no double step at the end).
                    self.x = wave.start_value();
                    self.active = Active::Hold;
                } else {
                    self.x = wave.next(phase);
                }
            }
            Active::Stream { playback, .. } => {
                self.x = playback.next(points);
                if playback.done() {
                    self.active = Active::Hold;
                }
            }
            Active::Analog => self.x = self.analog.read(counts)?,
            Active::Raster { axis, phase, go } => {
                if *go {
                    match axis.next(phase) {
                        Some(x) => self.x = x,
                        None => {
                            self.x = axis.end_value();
                            self.active = Active::Hold;
                        }
                    }
                }
            }
        }
        Ok(self.x)
    }

    /// A raster's part that has reached its start and waits for the others.
    pub const fn waiting(&self) -> bool {
        matches!(self.active, Active::Raster { go: false, .. }) && !self.approaching
    }

    /// A raster's part that is still on its way to its start.
    pub const fn raster_approaching(&self) -> bool {
        matches!(self.active, Active::Raster { go: false, .. }) && self.approaching
    }

    /// Starts a waiting raster's lines from the next tick on.
    pub fn release(&mut self) {
        if let Active::Raster { go, .. } = &mut self.active {
            *go = true;
        }
    }

    /// The analog input is read this tick.
    #[inline]
    pub fn wants_analog(&self) -> bool {
        matches!(self.active, Active::Analog)
    }

    /// The current reference, µm.
    pub const fn position(&self) -> Micrometres {
        self.x
    }

    /// The source in charge.
    pub const fn kind(&self) -> SourceKind {
        match self.active {
            Active::Hold => SourceKind::Hold,
            Active::Move { .. } | Active::Step { .. } => SourceKind::Move,
            Active::Wave { .. } | Active::Raster { .. } => SourceKind::Wave,
            Active::Stream { .. } => SourceKind::Stream,
            Active::Analog => SourceKind::Analog,
        }
    }

    /// A step (the raised cosine of [`SourceOrder::Step`]) lasting at least
    /// [`LEARNING_STEP_TICKS`] is running, not its approach: the motion the
    /// lead's mass ratio learns from (`crate::control::tracking`).
    pub const fn stepping(&self) -> bool {
        matches!(self.active, Active::Step { phase_step, .. } if phase_step <= LEARNING_PHASE_STEP)
            && !self.approaching
    }

    /// Ramping to the new source's entry point.
    pub const fn approaching(&self) -> bool {
        self.approaching
    }

    /// A stream is holding its last point because the next one is missing.
    pub const fn underrun(&self) -> bool {
        match &self.active {
            Active::Stream { playback, .. } => playback.underrun(),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::wave::Shape;
    use super::*;
    use piezo_fpi::control::Interval;

    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    const STEP: f64 = 1.0 / 128.0;

    fn reference(x: f64) -> Reference {
        let stroke = Interval {
            lo: um(0.0),
            hi: um(40.95),
        };
        // 1/128 µm per tick: exact in I16F16.
        Reference::new(um(x), um(STEP), AnalogInput::over(stroke))
    }

    /// Runs `ticks` ticks; the largest step between two references, µm.
    fn run(r: &mut Reference, points: &mut Points<64>, counts: u16, ticks: usize) -> f64 {
        let mut last = r.position();
        let mut worst: f64 = 0.0;
        for _ in 0..ticks {
            let x = r.next(points, counts).unwrap();
            worst = worst.max((x - last).abs().to_num());
            last = x;
        }
        worst
    }

    #[test]
    fn a_step_follows_a_raised_cosine_and_holds_its_target() {
        let mut r = reference(10.0);
        let mut pts = Points::<64>::new();
        r.select(SourceOrder::Step {
            target: um(20.0),
            phase_step: step_phase_for(20),
        });
        let mut xs = Vec::new();
        for _ in 0..25 {
            xs.push(r.next(&mut pts, 0).unwrap().to_num::<f64>());
        }
        // Half-way at tick 10, there at tick 20, then held.
        assert!((xs[9] - 15.0).abs() < 1e-3, "{xs:?}");
        assert_eq!(xs[19], 20.0);
        assert_eq!(r.kind(), SourceKind::Hold);
        // Zero speed at both ends, the fastest in the middle: π/2·10/20 µm per tick.
        assert!(xs[0] - 10.0 < 0.07 && xs[18] > 19.93, "{xs:?}");
        let mid = xs[10] - xs[9];
        assert!(
            (mid - core::f64::consts::FRAC_PI_2 * 0.5).abs() < 0.01,
            "{mid}"
        );
    }

    #[test]
    fn the_mass_ratio_learns_from_steps_as_long_as_autotune_s_only() {
        // A step of LEARNING_STEP_TICKS or more steps (learns) while its
        // raised cosine runs; a shorter one, whose fit's ratio differs, never.
        for (ticks, learns) in [
            (LEARNING_STEP_TICKS, true),
            (40, true),
            (29, false),
            (20, false),
        ] {
            let mut r = reference(10.0);
            let mut pts = Points::<64>::new();
            r.select(SourceOrder::Step {
                target: um(20.0),
                phase_step: step_phase_for(ticks),
            });
            let seen: Vec<bool> = (0..ticks - 1)
                .map(|_| {
                    r.next(&mut pts, 0).unwrap();
                    r.stepping()
                })
                .collect();
            assert!(seen.iter().all(|&s| s == learns), "{ticks}: {seen:?}");
            // At the target (a tick later where the phase step was rounded
            // down), it holds.
            run(&mut r, &mut pts, 0, 2);
            assert_eq!((r.stepping(), r.kind()), (false, SourceKind::Hold));
        }
    }

    #[test]
    fn a_move_ramps_at_its_speed_then_holds() {
        let mut r = reference(5.0);
        let mut p = Points::new();
        r.select(SourceOrder::Move {
            target: um(6.0),
            step: um(0.125),
        });
        assert_eq!(run(&mut r, &mut p, 0, 7), 0.125);
        assert_eq!(r.kind(), SourceKind::Move);
        run(&mut r, &mut p, 0, 1);
        assert_eq!((r.position(), r.kind()), (um(6.0), SourceKind::Hold));
    }

    #[test]
    fn switching_to_a_wave_approaches_its_start_without_a_jump() {
        let mut r = reference(30.0);
        let mut p = Points::new();
        let wave = Wave {
            shape: Shape::RaisedCosine,
            offset: um(20.0),
            amplitude: um(15.0),
            phase_step: Wave::phase_step_for(15_000, 20_000),
            cycles: 2,
        };
        r.select(SourceOrder::Wave(wave));
        // 25 µm down to the wave's bottom at 1/128 µm per tick.
        let worst = run(&mut r, &mut p, 0, 3200);
        assert_eq!(worst, STEP);
        assert_eq!(r.position(), um(5.0));
        assert!(!r.approaching());
        // Two periods of 4000/3 ticks, never faster than the cosine's top speed.
        let worst = run(&mut r, &mut p, 0, 2700);
        assert!(
            worst < core::f64::consts::TAU * 15.0 / 1333.3 + 1e-4,
            "{worst}"
        );
        assert_eq!(r.kind(), SourceKind::Hold, "finite wave done");
        assert_eq!(r.position(), um(5.0), "ends where it started");
    }

    #[test]
    fn a_finite_sine_ends_on_its_start_value_without_a_double_step() {
        // ±10 µm at 200 Hz about 20 µm: 100 ticks per period, ending at full
        // speed (0.63 µm per tick). Its last value (phase 99/100, 19.37 µm)
        // once gave way to the start value, a step of 1.25 µm.
        let mut r = reference(20.0);
        let mut p = Points::new();
        r.select(SourceOrder::Wave(Wave {
            shape: Shape::Sine,
            offset: um(20.0),
            amplitude: um(10.0),
            phase_step: Wave::phase_step_for(200_000, 20_000),
            cycles: 2,
        }));
        let top = core::f64::consts::TAU * 10.0 / 100.0;
        // A tick to approach its start (there already), then two periods.
        let worst = run(&mut r, &mut p, 0, 201);
        assert!(worst < top * 1.001, "{worst}");
        assert_eq!(r.kind(), SourceKind::Wave, "its last value");
        let last = r.position().to_num::<f64>();
        assert!((last - 19.372).abs() < 1e-3, "{last}");
        let worst = run(&mut r, &mut p, 0, 1);
        assert!(worst < top * 1.001, "{worst}");
        assert_eq!((r.position(), r.kind()), (um(20.0), SourceKind::Hold));
    }

    #[test]
    fn a_stream_starts_at_its_first_point_and_flags_an_underrun() {
        let mut r = reference(1.0);
        let mut p = Points::new();
        p.push(um(1.5));
        p.push(um(1.6));
        r.select(SourceOrder::Stream { interval: 2 });
        run(&mut r, &mut p, 0, 100);
        assert_eq!(r.position(), um(1.6));
        assert!(r.underrun() && r.kind() == SourceKind::Stream);
        p.end();
        run(&mut r, &mut p, 0, 3);
        assert_eq!(r.kind(), SourceKind::Hold);
    }

    #[test]
    fn the_analog_input_is_approached_then_followed_and_checked() {
        let mut r = reference(0.0);
        let mut p = Points::new();
        r.select(SourceOrder::Analog);
        assert!(r.wants_analog());
        // 2048 counts = 20.48 µm on this stroke: approached at 1/128 µm per tick.
        let worst = run(&mut r, &mut p, 2048, 2700);
        assert_eq!(worst, STEP);
        assert!(!r.approaching());
        assert!((r.position().to_num::<f64>() - 20.48).abs() < 1e-3);
        assert_eq!(
            r.next(&mut p, 2100).map(|x| x.to_num::<f64>() > 20.5),
            Ok(true)
        );
        assert_eq!(r.next(&mut p, 4095), Err(AnalogFault::OutOfRange));
    }
}
