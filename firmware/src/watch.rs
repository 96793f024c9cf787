//! The loops watched: an oscillating or saturating loop caught before the stage
//! leaves its stroke (a stage that changed, a wrong model), in the control ISR.
//!
//! **Oscillation.** The swing watched — the tracking error `x_ref − x_sensor`
//! where the position loop is closed, else the damping's correction (µm) —
//! less its own low-pass (`MEAN_SHIFT`: a one-pole at about 100 Hz at 20 kHz),
//! is a healthy loop's small, slow residue; an unstable loop makes it swing. A
//! *half-cycle* ends each time it goes beyond `±HALF_SWING` (0.2 µm)
//! on the side opposite to its last excursion, within `MAX_HALF_TICKS` of the
//! previous one (else the count starts again); its *peak* is the largest swing
//! since the previous one. Three rules trip [`Fault::Oscillation`]:
//!
//! * **growing:** `GROWING_HALF_CYCLES` half-cycles in a row, each peak at least
//!   `1 + 2^-GROWTH_SHIFT` times the one before and beyond ±`GROWTH_SWING`
//!   (0.5 µm) — an unstable loop, caught while
//!   it is small: 1.8 ms at 850 Hz, 5 ms at 300 Hz once the swing exceeds
//!   0.5 µm, however slowly it grows beyond 6 % per half-cycle. A ringing that
//!   decays (a step's, a triangle's corners), however lightly damped, never
//!   grows;
//! * **sustained:** `HALF_CYCLES` half-cycles in a row with peaks beyond
//!   `±SWING` — a loop in a limit cycle (that stopped growing at a limit): three
//!   periods of an oscillation above 125 Hz, 3.5 ms at 850 Hz, 10 ms at 300 Hz.
//!   A 100 Hz triangle's corners (5 ms apart) or a step's two or three swings
//!   never do;
//! * **held:** while the reference holds (it has not changed since the
//!   half-cycles began), `HELD_HALF_CYCLES` half-cycles in a row, none below
//!   `1 − 2^-GROWTH_SHIFT` of the one before — an oscillation of a few tenths of
//!   a micrometre that neither decays nor grows fast enough for the growing
//!   rule (a loop at the edge of stability, slowly growing from its noise):
//!   within 4.6 periods of a steady one (11.4 ms at 400 Hz, 15.2 ms at 300 Hz).
//!   A still reference leaves a healthy loop nothing to swing about but a
//!   decaying ringing, and one that loses less than 6.25 % per half-cycle (a
//!   mode damped below ζ ≈ 0.02) for six half-cycles beyond ±0.2 µm is not a
//!   loop to keep closed. A moving reference's forced error (a fast wave that
//!   the loops cannot follow) never counts here.
//!
//! **Saturation.** The command held at the stroke's edge or the step limited (by
//! the voltage range or the slew) for `SATURATED_TICKS` ticks in a row trips
//! [`Fault::Saturated`].
//!
//! Constant time, integer arithmetic, no panic.

use piezo_fpi::control::Fault;
use piezo_fpi::q::Micrometres;

/// The swing a sustained oscillation's half-cycles must exceed, µm (`I16F16`
/// bits: 2.5 µm). Above the ringing a 100 Hz triangle's corners leave in the
/// swing watched on an undamped 850 Hz mode (a forced, bounded ringing that
/// must not trip).
pub const SWING: i32 = 5 << 15;
/// The least peak the growing rule counts, µm (`I16F16` bits: 0.5 µm).
pub const GROWTH_SWING: i32 = 1 << 15;
/// The swing that ends a half-cycle, µm (`I16F16` bits: 0.2 µm): well above
/// the position sensor's noise (the as-built stage's σ is 0.003 µm; it must
/// stay below about 0.04 µm), below the half micrometre where the growing rule
/// starts.
pub const HALF_SWING: i32 = 13_107;
/// A growing half-cycle's peak exceeds the last one's by at least 2^-GROWTH_SHIFT
/// of it (6.25 %).
pub const GROWTH_SHIFT: u32 = 4;
/// The low-pass the swing is measured against: `m += (δ − m) >> MEAN_SHIFT`.
pub const MEAN_SHIFT: u32 = 5;
/// Half-cycles in a row beyond [`SWING`] that trip the fault.
pub const HALF_CYCLES: u16 = 6;
/// Growing half-cycles in a row that trip the fault.
pub const GROWING_HALF_CYCLES: u16 = 3;
/// Undecaying half-cycles in a row, while the reference holds, that trip the
/// fault.
pub const HELD_HALF_CYCLES: u16 = 6;
/// Longest time between two half-cycles of one oscillation, ticks (4 ms).
pub const MAX_HALF_TICKS: u16 = 80;
/// Ticks in a row at a limit that trip the fault (20 ms at 20 kHz).
pub const SATURATED_TICKS: u16 = 400;

/// The watch (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoopWatch {
    mean: i32,
    side: i8,
    /// The largest swing of the half-cycle in progress and of the last one
    /// (`I16F16` bits, ≥ 0).
    peak: i32,
    last_peak: i32,
    half_cycles: u16,
    growing: u16,
    /// Undecaying half-cycles in a row since the reference last changed.
    held: u16,
    /// The reference of the last tick (`I16F16` bits).
    last_ref: i32,
    since: u16,
    saturated: u16,
    /// An oscillation rule tripped (at a half-cycle's end).
    tripped: bool,
}

impl LoopWatch {
    /// Quiet.
    pub const fn new() -> Self {
        Self {
            mean: 0,
            side: 0,
            peak: 0,
            last_peak: 0,
            half_cycles: 0,
            growing: 0,
            held: 0,
            last_ref: 0,
            since: 0,
            saturated: 0,
            tripped: false,
        }
    }

    /// Forgets (a loop opened, a fault, a new model).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Takes this tick's correction `delta`, the reference the loops track and
    /// whether the command was held at a limit; the fault, once one is seen.
    #[inline]
    pub fn update(
        &mut self,
        delta: Micrometres,
        reference: Micrometres,
        limited: bool,
    ) -> Option<Fault> {
        let r = reference.to_bits();
        if r != self.last_ref {
            self.last_ref = r;
            self.held = 0;
        }
        let d = delta.to_bits();
        let hp = d.saturating_sub(self.mean);
        self.mean = self.mean.saturating_add(hp >> MEAN_SHIFT);
        let side = if hp > HALF_SWING {
            1
        } else if hp < -HALF_SWING {
            -1
        } else {
            0
        };
        self.since = self.since.saturating_add(1);
        if side != 0 && side != self.side {
            self.half_cycle_ends();
            self.side = side;
            self.since = 0;
        }
        self.peak = self.peak.max(hp.saturating_abs());
        self.saturated = if limited {
            self.saturated.saturating_add(1)
        } else {
            0
        };
        if self.tripped {
            Some(Fault::Oscillation)
        } else if self.saturated >= SATURATED_TICKS {
            Some(Fault::Saturated)
        } else {
            None
        }
    }

    /// The half-cycle in progress ended (the swing crossed to the other side):
    /// counts it for each rule, or starts the counts again.
    #[inline]
    fn half_cycle_ends(&mut self) {
        let chained = self.side != 0 && self.since <= MAX_HALF_TICKS;
        let (peak, last) = (self.peak, self.last_peak);
        let count = |n: u16, holds: bool| {
            if chained && holds {
                n.saturating_add(1)
            } else {
                0
            }
        };
        self.half_cycles = count(self.half_cycles, peak > SWING);
        let grew = peak > GROWTH_SWING && peak >= last.saturating_add(last >> GROWTH_SHIFT);
        self.growing = count(self.growing, grew);
        self.held = count(self.held, peak >= last - (last >> GROWTH_SHIFT));
        self.tripped = self.half_cycles >= HALF_CYCLES
            || self.growing >= GROWING_HALF_CYCLES
            || self.held >= HELD_HALF_CYCLES;
        self.last_peak = if chained { peak } else { 0 };
        self.peak = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A steady sine on a moving reference (the held rule does not count):
    /// the tick it trips and the fault.
    fn run(w: &mut LoopWatch, f_hz: f64, amp_um: f64, ticks: u32) -> Option<(u32, Fault)> {
        for k in 0..ticks {
            let v = amp_um * (core::f64::consts::TAU * f_hz * k as f64 / 20_000.0).sin();
            if let Some(f) = w.update(
                Micrometres::from_num(v),
                Micrometres::from_num(k % 1000),
                false,
            ) {
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

    /// A sine whose amplitude is multiplied by `growth` every half-period, on a
    /// moving reference (the held rule does not count).
    fn growing(w: &mut LoopWatch, f_hz: f64, from_um: f64, growth: f64) -> Option<(u32, f64)> {
        for k in 0..20_000u32 {
            let t = k as f64 / 20_000.0;
            let amp = from_um * growth.powf(2.0 * f_hz * t);
            let v = amp * (core::f64::consts::TAU * f_hz * t).sin();
            if let Some(f) = w.update(
                Micrometres::from_num(v),
                Micrometres::from_num(k % 1000),
                false,
            ) {
                assert_eq!(f, Fault::Oscillation);
                return Some((k, amp));
            }
        }
        None
    }

    #[test]
    fn a_growing_oscillation_trips_while_it_is_small() {
        // Growing by a fifth per half-cycle from 0.2 µm: caught below 3 µm.
        for f_hz in [300.0, 850.0, 2000.0] {
            let mut w = LoopWatch::new();
            let (k, amp) = growing(&mut w, f_hz, 0.2, 1.2).unwrap();
            assert!(amp < 3.0, "{f_hz} Hz: {amp} µm after {k} ticks");
        }
    }

    #[test]
    fn a_decaying_ringing_does_not_trip_however_light_its_damping() {
        // ζ = 0.005 at 850 Hz: 1.6 % less per half-cycle, from 2.4 µm, kicked
        // again every 5 ms (a 100 Hz triangle's corners on an undamped stage).
        let mut w = LoopWatch::new();
        for k in 0..40_000u32 {
            let t = (k % 100) as f64 / 20_000.0;
            let v = 2.4
                * (-0.005 * core::f64::consts::TAU * 850.0 * t).exp()
                * (core::f64::consts::TAU * 850.0 * t).sin();
            let at = Micrometres::from_num(k / 100 % 1000);
            assert_eq!(
                w.update(Micrometres::from_num(v), at, false),
                None,
                "tick {k}"
            );
        }
    }

    #[test]
    fn a_limit_held_for_twenty_ms_trips() {
        let mut w = LoopWatch::new();
        for k in 0..SATURATED_TICKS as u32 {
            let f = w.update(Micrometres::ZERO, Micrometres::ZERO, true);
            assert_eq!(f.is_some(), k + 1 == SATURATED_TICKS as u32);
        }
        assert_eq!(w.update(Micrometres::ZERO, Micrometres::ZERO, false), None);
    }

    /// A sine about a held reference whose amplitude is multiplied by `growth`
    /// every half-period; the tick it trips.
    fn held(f_hz: f64, amp_um: f64, growth: f64) -> Option<u32> {
        let mut w = LoopWatch::new();
        (0..20_000u32).find(|&k| {
            let t = k as f64 / 20_000.0;
            let v =
                amp_um * growth.powf(2.0 * f_hz * t) * (core::f64::consts::TAU * f_hz * t).sin();
            w.update(Micrometres::from_num(v), Micrometres::from_num(20), false)
                .is_some()
        })
    }

    #[test]
    fn a_slowly_growing_oscillation_about_a_held_reference_trips_within_five_periods() {
        // 2.5 % per half-cycle (a loop at the edge of stability), ±0.7 µm: too
        // slow for the growing rule, too small for the sustained one.
        for f_hz in [300.0, 400.0, 850.0] {
            let k = held(f_hz, 0.7, 1.025).unwrap_or_else(|| panic!("{f_hz} Hz"));
            let periods = k as f64 * f_hz / 20_000.0;
            println!("{f_hz} Hz: {periods:.2} periods");
            assert!(periods <= 5.0, "{f_hz} Hz: {k} ticks");
        }
        // Steady, too, and at a few tenths of a micrometre.
        assert!(held(400.0, 0.7, 1.0).is_some_and(|k| k < 300));
        assert!(held(400.0, 0.3, 1.0).is_some_and(|k| k < 300));
    }

    #[test]
    fn a_held_reference_s_decaying_ringing_does_not_trip() {
        // ζ = 0.024 (the stage as built, undamped) at 850 Hz from 3 µm: 7.3 %
        // less per half-cycle.
        let d = (-core::f64::consts::PI * 0.024f64).exp();
        assert_eq!(held(850.0, 3.0, d), None);
        // Below ±0.2 µm, nothing counts.
        assert_eq!(held(400.0, 0.18, 1.0), None);
    }

    #[test]
    fn a_moving_reference_s_forced_error_does_not_trip_the_held_rule() {
        // ±0.7 µm at 400 Hz, steady (the error of a wave the loops cannot follow).
        let mut w = LoopWatch::new();
        for k in 0..20_000u32 {
            let v = 0.7 * (core::f64::consts::TAU * 400.0 * k as f64 / 20_000.0).sin();
            let r = Micrometres::from_num(k % 1000) / 50;
            assert_eq!(
                w.update(Micrometres::from_num(v), r, false),
                None,
                "tick {k}"
            );
        }
    }
}
