//! The loops watched: an oscillating or saturating loop caught before the stage
//! leaves its stroke (a stage that changed, a wrong model), in the control ISR.
//!
//! **Oscillation.** The correction the loops add to the feedforward, `δ` (µm:
//! PI plus damping), less its own low-pass (`MEAN_SHIFT`: a one-pole at about
//! 100 Hz at 20 kHz), is a healthy loop's small, slow residue; an unstable loop
//! makes it swing. A *half-cycle* is counted each time it goes beyond `±SWING`
//! on the side opposite to its last excursion, within `MAX_HALF_TICKS` of the
//! previous one (else the count starts again): `HALF_CYCLES` in a row — four
//! periods of an oscillation above 125 Hz — trip [`Fault::Oscillation`]: 4.7 ms
//! at 850 Hz, 13 ms at 300 Hz once the swing exceeds ±2.5 µm. A 100 Hz
//! triangle's corners (5 ms apart) or a step's two or three swings never do.
//!
//! **Saturation.** The command held at the stroke's edge or the step limited (by
//! the voltage range or the slew) for `SATURATED_TICKS` ticks in a row trips
//! [`Fault::Saturated`].
//!
//! Constant time, integer arithmetic, no panic.

use piezo_fpi::control::Fault;
use piezo_fpi::q::Micrometres;

/// The swing a half-cycle must exceed, µm (`I16F16` bits: 2.5 µm). Above the
/// ringing a 100 Hz triangle's corners leave in a PI's correction on an undamped
/// 850 Hz mode (a forced, bounded ringing that must not trip).
pub const SWING: i32 = 5 << 15;
/// The low-pass the swing is measured against: `m += (δ − m) >> MEAN_SHIFT`.
pub const MEAN_SHIFT: u32 = 5;
/// Half-cycles in a row that trip the fault.
pub const HALF_CYCLES: u16 = 8;
/// Longest time between two half-cycles of one oscillation, ticks (4 ms).
pub const MAX_HALF_TICKS: u16 = 80;
/// Ticks in a row at a limit that trip the fault (20 ms at 20 kHz).
pub const SATURATED_TICKS: u16 = 400;

/// The watch (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoopWatch {
    mean: i32,
    side: i8,
    half_cycles: u16,
    since: u16,
    saturated: u16,
}

impl LoopWatch {
    /// Quiet.
    pub const fn new() -> Self {
        Self {
            mean: 0,
            side: 0,
            half_cycles: 0,
            since: 0,
            saturated: 0,
        }
    }

    /// Forgets (a loop opened, a fault, a new model).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Takes this tick's correction `delta` and whether the command was held at
    /// a limit; the fault, once one is seen.
    #[inline]
    pub fn update(&mut self, delta: Micrometres, limited: bool) -> Option<Fault> {
        let d = delta.to_bits();
        let hp = d.saturating_sub(self.mean);
        self.mean = self.mean.saturating_add(hp >> MEAN_SHIFT);
        let side = if hp > SWING {
            1
        } else if hp < -SWING {
            -1
        } else {
            0
        };
        self.since = self.since.saturating_add(1);
        if side != 0 && side != self.side {
            self.half_cycles = if self.side != 0 && self.since <= MAX_HALF_TICKS {
                self.half_cycles.saturating_add(1)
            } else {
                0
            };
            self.side = side;
            self.since = 0;
        }
        self.saturated = if limited {
            self.saturated.saturating_add(1)
        } else {
            0
        };
        if self.half_cycles >= HALF_CYCLES {
            Some(Fault::Oscillation)
        } else if self.saturated >= SATURATED_TICKS {
            Some(Fault::Saturated)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(w: &mut LoopWatch, f_hz: f64, amp_um: f64, ticks: u32) -> Option<(u32, Fault)> {
        for k in 0..ticks {
            let v = amp_um * (core::f64::consts::TAU * f_hz * k as f64 / 20_000.0).sin();
            if let Some(f) = w.update(Micrometres::from_num(v), false) {
                return Some((k, f));
            }
        }
        None
    }

    #[test]
    fn an_oscillation_at_the_mode_trips_within_ten_ms() {
        let mut w = LoopWatch::new();
        let (k, f) = run(&mut w, 850.0, 4.0, 4000).unwrap();
        assert_eq!(f, Fault::Oscillation);
        assert!(k < 120, "{k} ticks");
        let mut w = LoopWatch::new();
        let (k, _) = run(&mut w, 300.0, 4.0, 4000).unwrap();
        assert!(k < 300, "{k} ticks at 300 Hz");
    }

    #[test]
    fn slow_or_small_corrections_do_not() {
        let mut w = LoopWatch::new();
        assert_eq!(run(&mut w, 100.0, 5.0, 40_000), None);
        let mut w = LoopWatch::new();
        assert_eq!(run(&mut w, 850.0, 2.0, 40_000), None);
    }

    #[test]
    fn a_limit_held_for_twenty_ms_trips() {
        let mut w = LoopWatch::new();
        for k in 0..SATURATED_TICKS as u32 {
            let f = w.update(Micrometres::ZERO, true);
            assert_eq!(f.is_some(), k + 1 == SATURATED_TICKS as u32);
        }
        assert_eq!(w.update(Micrometres::ZERO, false), None);
    }
}
