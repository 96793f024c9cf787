//! The loops watched: an oscillating or saturating loop caught before the stage
//! leaves its stroke (a stage that changed, a wrong model), in the control ISR.
//! (Not the board's independent watchdog: that is [`crate::board::watchdog`].)
//!
//! **Oscillation.** The swing watched — the tracking error `x_ref − x_sensor`
//! (µm), whether the position loop is closed or the damping runs alone (on a
//! model that declares no position sensor, the damping's correction) —
//! less its own low-pass (`MEAN_SHIFT`: a one-pole at about 100 Hz at 20 kHz),
//! is a healthy loop's small, slow residue; an unstable loop makes it swing. A
//! *half-cycle* ends each time it goes beyond the *half swing* on the side
//! opposite to its last excursion: on the tracking error, the model's
//! (`feedback.watch_swing_um`, 0.075…0.2 µm: `fpi board autotune` sets it
//! from the noise the loops leave at rest, so that a quiet stage's unstable
//! loop is counted while it is a tenth of a micrometre), else, and with the
//! damping alone, `HALF_SWING` (0.2 µm). Its *peak* is the largest
//! swing since the previous one. It continues the half-cycles before it if it
//! lasted at least `MIN_HALF_TICKS` (two ticks) and at most `MAX_HALF_TICKS`
//! (4 ms), or, while the reference holds or the damping runs alone,
//! `MAX_HELD_HALF_TICKS` (8 ms): else every count starts again. Each rule
//! counts the half-cycles in a row that meet its condition and trips
//! [`Fault::Oscillation`] at one count while the reference moves and at a
//! smaller one where it held through them all (a still reference leaves a
//! healthy loop nothing to swing about but a decaying ringing; a moving one
//! forces an error that may swell as the wave starts). A reference that
//! creeps one way, by at most ±`TURN_STEP` in a tick (1.25 mm/s: a move at
//! 1 mm/s), holds: it forces no swing; one that goes back (an analog input's
//! noise, the turns of a wave however small: a bandwidth measurement's
//! ±0.2 µm sines force an error at their own period) moves. With the damping
//! alone, a chain of half-cycles lies where the reference held or kept
//! moving one way (below), which the sustained and growing rules take as
//! held (the undecaying rule, which a fast step's irregular transient would
//! fool, still wants it still):
//!
//! | rule | a half-cycle counts where its peak | moving | held |
//! |---|---|---|---|
//! | sustained | exceeds ±`SWING` (2.5 µm) | 6 | 4 |
//! | growing | exceeds ±`GROWTH_SWING` (0.5 µm) and the last peak by 2^-`GROWTH_SHIFT` (6.25 %) | 4 | 3 |
//! | undecaying | continues the ones before (a closed loop's chain's first aside), and, at this one's end and the last's (`KEPT_PAIRS`), the last two peaks sum to at least the two before less 2^-`DECAY_SHIFT` (a sixteenth) of theirs | — | 4 |
//!
//! * **sustained:** a loop in a limit cycle (that stopped growing at a limit):
//!   three periods of an oscillation above 125 Hz (3.5 ms at 850 Hz, 10 ms at
//!   300 Hz) while the reference moves, two periods down to 62 Hz while it
//!   holds. A 100 Hz triangle's corners (5 ms apart) or a step's two or three
//!   swings never do;
//! * **growing:** an unstable loop caught while it is small, however slowly it
//!   grows beyond 6 % per half-cycle. A ringing that decays (a step's, a
//!   triangle's corners), however lightly damped, never grows; a wave's forced
//!   error may swell for two or three half-cycles as the wave starts;
//! * **undecaying:** an oscillation of a tenth of a micrometre or a few that
//!   neither decays nor grows fast enough for the growing rule (a loop at the
//!   edge of stability, slowly growing from its noise): two periods of it,
//!   judged on pairs of peaks (the noise riding on a small oscillation moves
//!   single peaks by a tenth or more from one half-cycle to the next), once
//!   four half-cycles in a row ended since the reference last moved. A ringing loses more than a sixteenth over two half-cycles
//!   unless its mode is damped below ζ ≈ 0.010 (the position loop alone on
//!   the stage as built rings at about 0.02 after a step). A moving
//!   reference's forced error (a fast wave that the loops cannot follow)
//!   never counts here.
//!
//! The counts start again when the loop watched changes (the position loop
//! closed or opened): the half swings differ, and so do the rules below.
//!
//! **A wave's forced swing.** A half-cycle in which the reference *turned*
//! (went against the way it last went, or started again after holding or
//! creeping: a change within ±`TURN_STEP`, 1/16 µm in a tick, goes no way,
//! so an analog input's noise turns nothing) lasts about the wave's own half
//! period: it is the wave's. A closed loop's tracking error under a wave too
//! fast for it (±10 µm at 200 Hz with the shaping off on the stage as built:
//! ±3.0–3.5 µm, 60° behind) swings so, and the rules leave such half-cycles
//! out of every count, though one that does not meet a rule's condition
//! breaks its count (a 100 Hz triangle's corners on a closed loop whose
//! stage's mode moved to 700 Hz: the corner's half-cycle peaks at 1 µm, the
//! two between at 2.6 and 3.3 µm). An oscillation of the loop itself shows
//! in the half-cycles between the turns once it outgrows the forced swing,
//! and is counted there (growing by 15 % per half-cycle from 0.3 µm to
//! ±8 µm under that wave: caught at 16.0 ms at 850 Hz and at 37.6 ms at
//! 425 Hz, 6.3 and 18.2 ms after it outgrew the wave's error). With the
//! damping alone a turn ends the chain instead: a wave the shaping does not
//! explain (a 200 Hz sine with the shaping off, or on a
//! stage whose mode moved) leaves an open loop's error, and the damping's
//! correction, swinging at the wave's own period, ±3–6 µm: the feedforward's
//! error and the damping at work, not an oscillation. An oscillation of the
//! damping itself is counted between the turns (a wave's turns are 2.5 ms
//! apart at 200 Hz, an unstable loop's half-cycles near the mode under a
//! millisecond) and wherever the reference holds or keeps moving one way,
//! as held for the sustained and growing rules: a move's ramp forces no
//! swing on an open loop that the shaping explains, only a decaying
//! transient where it starts and ends. Its
//! half-cycles may last 8 ms there, so a damping that oscillates slowly
//! (about 100 Hz on a stage whose mode moved to 300 Hz: the stage swings
//! about the ramp by ±1 µm, growing by a tenth or a fifth per half-cycle) is
//! caught during the move that set it off. A closed loop's half-cycles last
//! at most 4 ms while the reference moves (a 100 Hz triangle's corners are
//! 5 ms apart). The rules count a half-cycle at the tick after it ended
//! (`Ended`): the tick it ends is often the costliest of the control task.
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
/// The swing that ends a half-cycle with the damping alone, and of a closed
/// loop's tracking error whose model sets none, µm (`I16F16` bits: 0.2 µm;
/// [`piezo_fpi::model::WATCH_SWING_MAX`]): well above the noise a healthy
/// loop leaves (on the stage as built, 0.02 µm RMS at rest; the model's half
/// swing follows it), below the half micrometre where the growing rule starts.
pub const HALF_SWING: i32 = piezo_fpi::model::WATCH_SWING_MAX.to_bits();
/// The undecaying rule's loss: the last two peaks sum to at least the two
/// before less 2^-DECAY_SHIFT (a sixteenth) of theirs.
pub const DECAY_SHIFT: u32 = 4;
/// The undecaying rule's pair comparisons in a row, the reference held: one
/// alone is fooled by the irregular peaks of a transient (a 200 Hz sine's
/// end on a stage whose mode moved to 700 Hz, ζ 0.015: 0.35, 0.10, 0.56,
/// 0.20 µm).
pub const KEPT_PAIRS: u16 = 2;
/// A growing half-cycle's peak exceeds the last one's by at least
/// 2^-GROWTH_SHIFT of it (6.25 %).
pub const GROWTH_SHIFT: u32 = 4;
/// The low-pass the swing is measured against: `m += (δ − m) >> MEAN_SHIFT`.
pub const MEAN_SHIFT: u32 = 5;
/// Shortest half-cycle that continues the ones before it, ticks (100 µs: a
/// swing across the half swing's band in one tick is a step's jump or a
/// noise spike, not an oscillation of the loops, whose modes lie below
/// 2 kHz).
pub const MIN_HALF_TICKS: u16 = 2;
/// Longest half-cycle that continues the ones before it, ticks (4 ms).
pub const MAX_HALF_TICKS: u16 = 80;
/// Longest half-cycle that continues the ones before it while the reference
/// holds, ticks (8 ms: an oscillation down to 62 Hz).
pub const MAX_HELD_HALF_TICKS: u16 = 160;
/// The least change of the reference in a tick that goes a way, µm (`I16F16`
/// bits: 1/16 µm, 1.25 mm/s; an analog input's noise of a few counts does
/// not, nor a wave slower than ±10 µm at 20 Hz, whose forced error is small):
/// a smaller one the way of the last creeps, which holds for the rules.
pub const TURN_STEP: i32 = 1 << 12;
/// Ticks in a row at a limit that trip the fault (20 ms at 20 kHz).
pub const SATURATED_TICKS: u16 = 400;

/// A rule's trip counts: half-cycles in a row that meet its condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rule {
    /// Where the reference moved during them (`u16::MAX`: never).
    pub moving: u16,
    /// Where it held through them all.
    pub held: u16,
}

/// Sustained: peaks beyond [`SWING`].
pub const SUSTAINED: Rule = Rule { moving: 6, held: 4 };
/// Growing: peaks beyond [`GROWTH_SWING`], each 2^-[`GROWTH_SHIFT`] larger than the last.
pub const GROWING: Rule = Rule { moving: 4, held: 3 };
/// Undecaying: the last two peaks sum to at least the two before less
/// 2^-[`DECAY_SHIFT`] of theirs, four half-cycles in a row (`held`) after the
/// reference last moved; its count is the half-cycles in a row but the
/// chain's first, at most the ones the reference held through, where the
/// pairs compare so.
pub const UNDECAYING: Rule = Rule {
    moving: u16::MAX,
    held: 4,
};

impl Rule {
    /// Whether `count` half-cycles in a row, the reference held through the
    /// last `held` of them, trip it.
    #[inline]
    const fn trips(&self, count: u16, held: u16) -> bool {
        count >= self.moving || (count >= self.held && held >= count)
    }
}

/// A half-cycle that ended at the last tick, for the rules to count at this
/// one: the tick a half-cycle ends is often one where the command jumps (a
/// step, a loop closed, a limit met) and the inverse model realigns, the
/// costliest the control task has; the tick after rarely is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Ended {
    /// Its peak (`I16F16` bits, ≥ 0).
    peak: i32,
    /// The reference held through it and the `held − 1` before (0: it moved
    /// during it).
    held: u16,
    /// Its length, ticks (`u16::MAX`: a turn ended the chain, with the
    /// damping alone).
    since: u16,
    /// Whether one ended before it (else the swing had never left the half
    /// swing's band since the counts started).
    after: bool,
    /// Whether the reference turned or started again during it: a closed
    /// loop's half-cycle at the wave's own period, which adds to no count
    /// (and breaks those it does not meet).
    turned: bool,
}

/// The watch (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoopWatch {
    mean: i32,
    side: i8,
    /// The largest swing of the half-cycle in progress and of the last one
    /// (`I16F16` bits, ≥ 0).
    peak: i32,
    last_peak: i32,
    /// Each rule's half-cycles in a row.
    sustained: u16,
    growing: u16,
    /// Half-cycles in a row (chained), the undecaying rule's window.
    run: u16,
    /// Half-cycles in a row at whose end the pairs of peaks did not decay.
    kept: u16,
    /// The peaks of the two half-cycles before the last one, the latest
    /// first (`I16F16` bits, ≥ 0).
    before: [i32; 2],
    /// Half-cycles ended since the reference last moved (beyond
    /// ±[`TURN_STEP`] in a tick, or against its last change), the one in
    /// progress then included: the reference held or crept one way through
    /// all but the first.
    still: u16,
    /// The reference of the last tick (`I16F16` bits).
    last_ref: i32,
    /// Its last change (`I16F16` bits; 0: none yet).
    last_step: i32,
    /// The way it went at the last tick: its change if beyond ±[`TURN_STEP`]
    /// (`I16F16` bits; 0: it held, or crept).
    way: i32,
    /// The reference turned or started again during the half-cycle in
    /// progress.
    turned: bool,
    since: u16,
    saturated: u16,
    /// The half-cycle that ended at the last tick, not yet counted.
    ended: Option<Ended>,
    /// Whether the damping runs alone (else the position loop is closed).
    alone: bool,
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
            sustained: 0,
            growing: 0,
            run: 0,
            kept: 0,
            before: [0; 2],
            still: 0,
            last_ref: 0,
            last_step: 0,
            way: 0,
            turned: false,
            since: 0,
            saturated: 0,
            ended: None,
            alone: false,
            tripped: false,
        }
    }

    /// Forgets (a loop opened, a fault, a new model).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Takes this tick's swing `delta` (µm), whether the damping runs
    /// `alone` (else the position loop is closed), the reference the loops
    /// track, whether the command was held at a limit and the half swings:
    /// of a closed loop's tracking error (µm: the model's) and of the damping
    /// alone's (µm: [`HALF_SWING`]), each widened while an analysis runs
    /// (`crate::control::task`'s `WATCH_WIDEN`); the fault, once one is seen.
    #[inline]
    pub fn update(
        &mut self,
        delta: Micrometres,
        alone: bool,
        reference: Micrometres,
        limited: bool,
        halves: &[Micrometres; 2],
    ) -> Option<Fault> {
        if alone != self.alone {
            // The counts start again: the next half-cycle to end continues
            // none, which clears them. The swing watched is the same (the
            // tracking error, or without a position sensor the damping's
            // correction, which then always runs alone): its low-pass, and
            // the reference's record, go on.
            self.alone = alone;
            self.side = 0;
            self.ended = None;
        }
        if self.ended.is_some() {
            self.count();
        }
        let r = reference.to_bits();
        let step = r.wrapping_sub(self.last_ref);
        // Beyond ±TURN_STEP (a change of exactly +TURN_STEP too: one bit, for
        // a test of three instructions).
        let far = (step.wrapping_add(TURN_STEP) as u32) >= 2 * TURN_STEP as u32;
        if step != 0 {
            // A change beyond ±TURN_STEP, or against the last one, moves; a
            // smaller one the same way creeps, which holds.
            if far | ((step ^ self.last_step) < 0) {
                self.still = 0;
            }
            self.last_step = step;
            self.last_ref = r;
        }
        // A reference that turned (went the other way) or started again (it
        // held or crept at the last tick) marks the half-cycle in progress as
        // the wave's (the module docs); with the damping alone it ends the
        // chain, too long to continue any. Changes within ±TURN_STEP (an analog
        // input's noise) go no way.
        let way = if far {
            if self.way == 0 || (step ^ self.way) < 0 {
                self.turned = true;
                if alone {
                    self.since = u16::MAX;
                }
            }
            step
        } else {
            0
        };
        self.way = way;
        let d = delta.to_bits();
        let hp = d.saturating_sub(self.mean);
        self.mean = self.mean.saturating_add(hp >> MEAN_SHIFT);
        let half = halves[alone as usize].to_bits();
        let side = if hp > half {
            1
        } else if hp < -half {
            -1
        } else {
            0
        };
        self.since = self.since.saturating_add(1);
        if side != 0 && side != self.side {
            self.ended = Some(self.half_cycle_ends());
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
    /// what the rules count at the next tick ([`Ended`]).
    #[inline]
    fn half_cycle_ends(&mut self) -> Ended {
        // The reference held through this half-cycle and the `held − 1` before.
        // Whether it continues the one before is judged at the next tick.
        let held = self.still;
        self.still = held.saturating_add(1);
        let peak = self.peak;
        self.peak = 0;
        let turned = self.turned;
        self.turned = false;
        Ended {
            peak,
            held,
            since: self.since,
            after: self.side != 0,
            turned,
        }
    }

    /// Counts the half-cycle that ended at the last tick for each rule, or,
    /// where it does not continue the one before, starts every count again.
    /// A few dozen instructions, no loop; out of line (the tick's own
    /// registers stay its own).
    #[inline(never)]
    fn count(&mut self) {
        let Some(e) = self.ended.take() else {
            return;
        };
        // It continues the one before if there was one and its length is
        // within the bounds.
        let longest = if e.held > 0 || self.alone {
            MAX_HELD_HALF_TICKS
        } else {
            MAX_HALF_TICKS
        };
        if !(e.after && e.since >= MIN_HALF_TICKS && e.since <= longest) {
            // Every count starts again, and the next chain's first peaks
            // meet none before.
            self.before = [0, 0];
            self.sustained = 0;
            self.growing = 0;
            self.run = 0;
            self.kept = 0;
            self.last_peak = 0;
            return;
        }
        let (peak, last, held) = (e.peak, self.last_peak, e.held);
        let [b0, b1] = self.before;
        self.before = [last, b0];
        self.last_peak = peak;
        let grew = peak > GROWTH_SWING && peak >= last.saturating_add(last >> GROWTH_SHIFT);
        // Undecaying: this peak and the last against the two before (the
        // first two of a chain against none).
        let earlier = b0.saturating_add(b1);
        let kept = peak.saturating_add(last) >= earlier - (earlier >> DECAY_SHIFT);
        // A closed loop's half-cycle in which the reference turned is the
        // wave's forced error (at its period): it adds to no count, but
        // breaks those it does not meet (with the damping alone it ended the
        // chain).
        let step = !e.turned as u16;
        let count = |n: u16, holds: bool| if holds { n.saturating_add(step) } else { 0 };
        self.sustained = count(self.sustained, peak > SWING);
        self.growing = count(self.growing, grew);
        self.run = self.run.saturating_add(1);
        self.kept = count(self.kept, kept);
        // A closed loop's chain's first half-cycle may hold a step's or a
        // close's own error: its peak is left out of the window. With the
        // damping alone a chain starts after the reference started or turned
        // (which ended the one before), where an open loop's error does not
        // jump (the feedforward moves the stage along): its first counts (a
        // stage whose mode moved to 350 Hz, the damping swinging it ±1 µm at
        // 110 Hz about a 1 mm/s move: caught 17.0 ms into the move, else 20.75).
        let undecaying = if self.kept.min(held) >= KEPT_PAIRS {
            self.run.saturating_sub(!self.alone as u16).min(held)
        } else {
            0
        };
        // With the damping alone, a chain lies between the reference's turns
        // and starts: it held or kept moving its way throughout, which the
        // sustained and growing rules take as held.
        let way = if self.alone { u16::MAX } else { held };
        self.tripped = SUSTAINED.trips(self.sustained, way)
            || GROWING.trips(self.growing, way)
            || UNDECAYING.trips(undecaying, held);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The half swings of [`LoopWatch::update`] for a closed loop's
    /// tracking error `closed` (and the damping alone's [`HALF_SWING`]).
    fn halves(closed: Micrometres) -> [Micrometres; 2] {
        [closed, Micrometres::from_bits(HALF_SWING)]
    }

    const TAU: f64 = core::f64::consts::TAU;
    /// The half swing of a model that sets none.
    const DEFAULT: Micrometres = Micrometres::from_bits(HALF_SWING);

    /// Feeds `swing(t)` (µm, `t` in s) as the tracking error, about a reference
    /// that moves every tick (`moving`) or holds at 20 µm, for at most
    /// `ticks`; the tick it trips and the fault.
    fn feed(
        w: &mut LoopWatch,
        moving: bool,
        ticks: u32,
        swing: impl Fn(f64) -> f64,
    ) -> Option<(u32, Fault)> {
        feed_at(w, DEFAULT, moving, ticks, swing)
    }

    /// [`feed`], the tracking error watched at the half swing `half`.
    fn feed_at(
        w: &mut LoopWatch,
        half: Micrometres,
        moving: bool,
        ticks: u32,
        swing: impl Fn(f64) -> f64,
    ) -> Option<(u32, Fault)> {
        (0..ticks).find_map(|k| {
            let r = if moving { k % 1000 } else { 20 };
            let v = swing(k as f64 / 20_000.0);
            w.update(
                Micrometres::from_num(v),
                false,
                Micrometres::from_num(r),
                false,
                &halves(half),
            )
            .map(|f| (k, f))
        })
    }

    /// A steady sine on a moving reference: the tick it trips and the fault.
    fn run(w: &mut LoopWatch, f_hz: f64, amp_um: f64, ticks: u32) -> Option<(u32, Fault)> {
        feed(w, true, ticks, |t| amp_um * (TAU * f_hz * t).sin())
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
    /// moving reference.
    fn growing(w: &mut LoopWatch, f_hz: f64, from_um: f64, growth: f64) -> Option<(u32, f64)> {
        let amp = |t: f64| from_um * growth.powf(2.0 * f_hz * t);
        let (k, f) = feed(w, true, 20_000, |t| amp(t) * (TAU * f_hz * t).sin())?;
        assert_eq!(f, Fault::Oscillation);
        Some((k, amp(k as f64 / 20_000.0)))
    }

    #[test]
    fn a_growing_oscillation_trips_while_it_is_small() {
        // Growing by a fifth per half-cycle from 0.2 µm: caught below 4 µm.
        for f_hz in [300.0, 850.0, 2000.0] {
            let mut w = LoopWatch::new();
            let (k, amp) = growing(&mut w, f_hz, 0.2, 1.2).unwrap();
            assert!(amp < 4.0, "{f_hz} Hz: {amp} µm after {k} ticks");
        }
    }

    #[test]
    fn a_wave_s_error_swelling_for_three_half_cycles_does_not_trip() {
        // A forced error as a wave starts on a moving reference: 0.6, 0.9,
        // 1.2 µm, then steady at 1.2 µm (below the sustained rule's swing).
        let mut w = LoopWatch::new();
        let amp = |t: f64| (0.6 + 0.3 * (2.0 * 400.0 * t).floor()).min(1.2);
        assert_eq!(
            feed(&mut w, true, 20_000, |t| amp(t) * (TAU * 400.0 * t).sin()),
            None
        );
    }

    #[test]
    fn a_decaying_ringing_does_not_trip_however_light_its_damping() {
        // ζ = 0.005 at 850 Hz: 1.6 % less per half-cycle, from 2.4 µm, kicked
        // again every 5 ms (a 100 Hz triangle's corners on an undamped stage).
        let mut w = LoopWatch::new();
        for k in 0..40_000u32 {
            let t = (k % 100) as f64 / 20_000.0;
            let v = 2.4 * (-0.005 * TAU * 850.0 * t).exp() * (TAU * 850.0 * t).sin();
            // The triangle's reference, 5 → 35 µm: 0.3 µm in a tick.
            let ramp = (k % 100) as f64 * 0.3;
            let at = Micrometres::from_num(5.0 + if k % 200 < 100 { ramp } else { 30.0 - ramp });
            assert_eq!(
                w.update(Micrometres::from_num(v), false, at, false, &halves(DEFAULT)),
                None,
                "tick {k}"
            );
        }
    }

    #[test]
    fn a_limit_held_for_twenty_ms_trips() {
        let mut w = LoopWatch::new();
        for k in 0..SATURATED_TICKS as u32 {
            let f = w.update(
                Micrometres::ZERO,
                false,
                Micrometres::ZERO,
                true,
                &halves(DEFAULT),
            );
            assert_eq!(f.is_some(), k + 1 == SATURATED_TICKS as u32);
        }
        let f = w.update(
            Micrometres::ZERO,
            false,
            Micrometres::ZERO,
            false,
            &halves(DEFAULT),
        );
        assert_eq!(f, None);
    }

    /// A sine about a held reference whose amplitude is multiplied by `growth`
    /// every half-period; the tick it trips.
    fn held(f_hz: f64, amp_um: f64, growth: f64) -> Option<u32> {
        let mut w = LoopWatch::new();
        let amp = |t: f64| amp_um * growth.powf(2.0 * f_hz * t);
        feed(&mut w, false, 20_000, |t| amp(t) * (TAU * f_hz * t).sin()).map(|(k, _)| k)
    }

    #[test]
    fn a_slowly_growing_oscillation_about_a_held_reference_trips_within_four_periods() {
        // 2.5 % per half-cycle (a loop at the edge of stability), ±0.7 µm: too
        // slow for the growing rule, too small for the sustained one. Four
        // half-cycles, after the first (whose start the watch did not see)
        // and the low-pass's own start.
        for f_hz in [300.0, 400.0, 850.0] {
            let k = held(f_hz, 0.7, 1.025).unwrap_or_else(|| panic!("{f_hz} Hz"));
            let periods = k as f64 * f_hz / 20_000.0;
            println!("{f_hz} Hz: {periods:.2} periods");
            assert!(periods <= 4.0, "{f_hz} Hz: {k} ticks");
        }
        // Steady, too, and at a few tenths of a micrometre.
        assert!(held(400.0, 0.7, 1.0).is_some_and(|k| k < 200));
        assert!(held(400.0, 0.3, 1.0).is_some_and(|k| k < 200));
    }

    #[test]
    fn a_slow_large_oscillation_about_a_held_reference_trips_within_two_periods() {
        // ±10 µm at 120 Hz, half-cycles of 4.2 ms (longer than a moving
        // reference's chain allows), decaying by a tenth per half-cycle (the
        // undecaying rule does not count): the sustained rule, held.
        let k = held(120.0, 10.0, 0.9).expect("caught");
        assert!(k as f64 * 120.0 / 20_000.0 <= 2.0, "{k} ticks");
    }

    #[test]
    fn a_held_reference_s_decaying_ringing_does_not_trip() {
        // ζ = 0.024 (the stage as built, undamped) at 850 Hz from 3 µm: 7.3 %
        // less per half-cycle.
        let d = (-core::f64::consts::PI * 0.024f64).exp();
        assert_eq!(held(850.0, 3.0, d), None);
        // Below ±0.2 µm, nothing counts.
        assert_eq!(held(400.0, 0.18, 1.0), None);
        // ζ = 0.015 (below the position loop alone's 0.02 on the stage as
        // built) at 850 Hz from 2 µm, at the least half swing too: 9 % less
        // over two half-cycles.
        let d = (-core::f64::consts::PI * 0.015f64).exp();
        for half in [0.2, 0.075] {
            assert_eq!(held_at(half, 850.0, 2.0, |n| d.powi(n as i32)), None);
        }
    }

    /// Feeds `swing(t)` (µm, `t` in s) about the reference `reference(t)`
    /// (µm), watched with the damping alone or the position loop closed; the
    /// tick it trips.
    fn feed_about(
        alone: bool,
        ticks: u32,
        reference: impl Fn(f64) -> f64,
        swing: impl Fn(f64) -> f64,
    ) -> Option<u32> {
        let mut w = LoopWatch::new();
        (0..ticks).find(|&k| {
            let t = k as f64 / 20_000.0;
            w.update(
                Micrometres::from_num(swing(t)),
                alone,
                Micrometres::from_num(reference(t)),
                false,
                &halves(DEFAULT),
            )
            .is_some()
        })
    }

    #[test]
    fn a_wave_s_forced_swing_does_not_trip() {
        // A 200 Hz sine, ±5 µm about 20 µm, that the shaping does not explain:
        // the open loop's error (and the damping's correction) follows it 60°
        // behind, swelling from 1 to 3.5 µm over its first period (the
        // correction on the emulated stage as built with the shaping off,
        // ±3.2 µm; on a 700 Hz stage, ±5.6 µm). A closed loop's tracking
        // error under ±10 µm at 200 Hz, the shaping off, swings ±3.0–3.5 µm
        // at the wave's period on the stage as built: a wave too fast for the
        // loop, not an oscillation of it.
        let f = 200.0;
        let reference = |t: f64| 20.0 + 5.0 * (TAU * f * t).sin();
        let swing = |t: f64| (1.0 + 500.0 * t).min(3.5) * (TAU * f * t - 1.05).sin();
        for alone in [true, false] {
            assert_eq!(
                feed_about(alone, 20_000, reference, swing),
                None,
                "alone {alone}"
            );
        }
    }

    /// A 200 Hz sine of ±10 µm about 20 µm, with the tracking error it forces
    /// on a closed loop (±3 µm, 60° behind).
    fn fast_wave(t: f64) -> (f64, f64) {
        let phase = TAU * 200.0 * t;
        (20.0 + 10.0 * phase.sin(), 3.0 * (phase - 1.05).sin())
    }

    #[test]
    fn a_closed_loop_s_oscillation_during_a_fast_wave_trips() {
        // An unstable loop growing by 15 % per half-cycle from 0.3 µm, at the
        // mode or half of it, to a limit cycle of ±8 µm. Its own half-cycles
        // show once it outgrows the wave's forced error (±3 µm: at 9.7 ms at
        // 850 Hz, 19.4 ms at 425 Hz), between the wave's turns, and are
        // counted there: caught within 20 ms of it (at 16.0 and 37.6 ms).
        for f in [850.0, 425.0] {
            let swing = |t: f64| {
                let grown = 0.3 * 1.15f64.powf(2.0 * f * t);
                fast_wave(t).1 + grown.min(8.0) * (TAU * f * t).sin()
            };
            let outgrown = 20_000.0 * 10f64.ln() / (2.0 * f * 1.15f64.ln());
            let k = feed_about(false, 20_000, |t| fast_wave(t).0, swing);
            assert!(
                k.is_some_and(|k| (k as f64) < outgrown + 400.0),
                "{f} Hz: {k:?}"
            );
        }
    }

    #[test]
    fn an_analog_reference_s_noise_leaves_the_damping_alone_watched() {
        // A reference read from the analog input jitters by a count or two
        // (0.01–0.02 µm over the stroke) at every tick: no wave turns there.
        let mut jitter = gaussian(0.01);
        let noisy: Vec<f64> = (0..20_000).map(|_| 20.0 + jitter()).collect();
        let reference = |t: f64| noisy[((t * 20_000.0).round() as usize).min(19_999)];
        let swing = |t: f64| 0.6 * 1.2f64.powf(1700.0 * t) * (TAU * 850.0 * t).sin();
        let k = feed_about(true, 20_000, reference, swing);
        assert!(k.is_some_and(|k| k < 200), "{k:?}");
    }

    #[test]
    fn the_damping_s_own_oscillation_during_a_slow_wave_trips() {
        // ±3 µm at 850 Hz with the damping alone while a 15 Hz sine runs:
        // counted between the wave's turns, caught within 10 ms.
        let reference = |t: f64| 20.0 + 15.0 * (TAU * 15.0 * t).sin();
        let k = feed_about(true, 20_000, reference, |t| 3.0 * (TAU * 850.0 * t).sin());
        assert!(k.is_some_and(|k| k < 200), "{k:?}");
    }

    #[test]
    fn the_damping_s_slow_oscillation_during_a_move_trips_within_twenty_ms() {
        // The damping alone on a stage whose mode moved to 300 Hz: the stage
        // swings about a move's ramp (0 → 20 µm in 20 ms) at 100 Hz, ±1 µm
        // growing by a tenth or a fifth per half-cycle. Its 5 ms half-cycles
        // continue one another while the reference moves one way, which holds
        // for the rules: caught in the move.
        let reference = |t: f64| (t * 1000.0).min(20.0);
        for growth in [1.1f64, 1.2] {
            let swing = |t: f64| growth.powf(200.0 * t) * (TAU * 100.0 * t).sin();
            let k = feed_about(true, 20_000, reference, swing);
            assert!(k.is_some_and(|k| k <= 400), "growth {growth}: {k:?}");
            // A closed loop's too: the ramp (0.05 µm in a tick) creeps,
            // which holds.
            let k = feed_about(false, 20_000, reference, swing);
            assert!(k.is_some_and(|k| k <= 400), "growth {growth}: {k:?}");
        }
    }

    #[test]
    fn the_damping_s_undecaying_oscillation_during_a_slow_move_trips_within_twenty_ms() {
        // The damping alone on a stage whose mode moved to 350 Hz: the stage
        // swings about a move's ramp (0 → 20 µm at 1 mm/s, which creeps) at
        // 110 Hz, ±0.9 µm, neither growing nor decaying by much: the
        // undecaying rule, the reference held, with the chain's first
        // half-cycle (the move's start ended the chain before it).
        let reference = |t: f64| (t * 1000.0).min(20.0);
        for amp in [0.5, 0.9, 3.0] {
            let swing = |t: f64| amp * (TAU * 110.0 * t).sin();
            let k = feed_about(true, 20_000, reference, swing);
            assert!(k.is_some_and(|k| k <= 400), "±{amp} µm: {k:?}");
        }
    }

    #[test]
    fn a_small_fast_wave_s_forced_error_does_not_trip() {
        // ±0.2 µm sines (a bandwidth measurement's) creep, under 1/16 µm in
        // a tick, but turn at every half-period: the tracking error they
        // force (±0.25 µm, lagging, watched at the least half swing) is the
        // wave's, not a held reference's undecaying oscillation.
        for f in [50.0, 200.0, 400.0, 800.0] {
            let reference = |t: f64| 20.0 + 0.2 * (TAU * f * t).sin();
            let swing = |t: f64| 0.25 * (TAU * f * t - 1.0).sin();
            let mut w = LoopWatch::new();
            let small = Micrometres::from_num(0.075);
            let tripped = (0..20_000u32).find(|&k| {
                let t = k as f64 / 2e4;
                let (r, v) = (reference(t), swing(t));
                let (r, v) = (Micrometres::from_num(r), Micrometres::from_num(v));
                w.update(v, false, r, false, &halves(small)).is_some()
            });
            assert_eq!(tripped, None, "{f} Hz");
            assert_eq!(feed_about(true, 20_000, reference, swing), None, "{f} Hz");
        }
    }

    #[test]
    fn the_damping_alone_s_ringing_after_steps_one_way_does_not_trip() {
        // A staircase of 2 µm steps up every 5 ms, each leaving a ringing at
        // 850 Hz from 2.4 µm that the damping takes down at ζ 0.1. The
        // reference never turns, but each step starts it again after holding,
        // which ends the chain: one ringing's tail does not chain into the
        // next step's larger peaks.
        let reference = |t: f64| 2.0 * (t / 0.005).floor();
        let swing = |t: f64| {
            let s = t % 0.005;
            2.4 * (-0.1 * TAU * 850.0 * s).exp() * (TAU * 850.0 * s).sin()
        };
        assert_eq!(feed_about(true, 20_000, reference, swing), None);
    }

    #[test]
    fn a_fast_step_s_transient_with_the_damping_alone_does_not_trip() {
        // An open loop's error through a 10 µm step in 0.5 ms on the stage as
        // built (the emulated board's, in half-cycles): a noise swing long
        // before, three small irregular ones during the step, the overshoot
        // and the slow return. Its pairs of peaks grow: with the reference
        // held through the step for the undecaying rule, it tripped.
        let halves: [(u32, u32, f64); 6] = [
            (0, 10, 0.3),
            (100, 109, -0.45),
            (109, 115, 0.35),
            (115, 118, -0.3),
            (118, 134, 1.5),
            (134, 182, -0.7),
        ];
        // The step: ticks 104 to 114.
        let reference = |t: f64| {
            let s = ((t - 0.0052) / 0.0005).clamp(0.0, 1.0);
            15.0 - 5.0 * (core::f64::consts::PI * s).cos()
        };
        let swing = |t: f64| {
            let k = (t * 20_000.0) as u32;
            halves
                .iter()
                .find(|&&(a, b, _)| k >= a && k < b)
                .map_or(0.0, |&(a, b, p)| {
                    p * (core::f64::consts::PI * (k - a) as f64 / (b - a) as f64).sin()
                })
        };
        assert_eq!(feed_about(true, 4000, reference, swing), None);
    }

    #[test]
    fn a_moving_reference_s_forced_error_does_not_trip_the_undecaying_rule() {
        // ±0.7 µm at 400 Hz, steady (the error of a wave the loops cannot follow).
        let mut w = LoopWatch::new();
        assert_eq!(
            feed(&mut w, true, 20_000, |t| 0.7 * (TAU * 400.0 * t).sin()),
            None
        );
    }

    #[test]
    fn the_counts_start_again_when_the_loop_watched_changes() {
        // A steady ±0.7 µm at 400 Hz, watched with the damping alone until
        // just before it would trip, then with the position loop closed: the
        // counts start again, and it trips a few half-cycles later.
        let sine = |t: f64| 0.7 * (TAU * 400.0 * t).sin();
        let alone = feed_about(true, 400, |_| 20.0, sine).expect("caught alone");
        let closed = held(400.0, 0.7, 1.0).expect("caught closed");
        let switch = alone - 5;
        let swing = |k: u32| Micrometres::from_num(sine(k as f64 / 2e4));
        let at = Micrometres::from_num(20);
        let mut w = LoopWatch::new();
        let tripped = (0..400u32).find(|&k| {
            w.update(swing(k), k < switch, at, false, &halves(DEFAULT))
                .is_some()
        });
        let k = tripped.expect("caught");
        assert!(
            k > switch + closed / 2,
            "{k} ticks (alone: {alone}, closed: {closed})"
        );
    }

    /// Gaussian samples of deviation `sigma` (a fixed sequence: an LCG and
    /// Box–Muller).
    fn gaussian(sigma: f64) -> impl FnMut() -> f64 {
        let mut state: u64 = 0x2545_f491_4f6c_dd1d;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        move || sigma * (-2.0 * uniform().ln()).sqrt() * (TAU * uniform()).cos()
    }

    /// A sine about a held reference at the half swing `half` (µm), its peaks
    /// scaled half-cycle by half-cycle by `scale(n)`; the tick it trips.
    fn held_at(half: f64, f_hz: f64, amp_um: f64, scale: impl Fn(u32) -> f64) -> Option<u32> {
        let mut w = LoopWatch::new();
        let swing = |t: f64| {
            let n = (2.0 * f_hz * t) as u32;
            amp_um * scale(n) * (TAU * f_hz * t).sin()
        };
        feed_at(&mut w, Micrometres::from_num(half), false, 20_000, swing).map(|(k, _)| k)
    }

    #[test]
    fn the_model_s_half_swing_counts_a_small_oscillation() {
        // A steady ±0.12 µm at 400 Hz about a held reference: below the
        // default half swing, nothing; at 0.075 µm, the undecaying rule within
        // three periods.
        assert_eq!(held_at(0.2, 400.0, 0.12, |_| 1.0), None);
        let k = held_at(0.075, 400.0, 0.12, |_| 1.0).expect("caught");
        assert!(k < 150, "{k} ticks");
        // With the damping alone, the swing is watched at 0.2 µm whatever the model's.
        let mut w = LoopWatch::new();
        let small = Micrometres::from_num(0.075);
        let at = Micrometres::from_num(20);
        let tripped = (0..20_000u32).find(|&k| {
            let v = 0.12 * (TAU * 400.0 * k as f64 / 2e4).sin();
            w.update(Micrometres::from_num(v), true, at, false, &halves(small))
                .is_some()
        });
        assert_eq!(tripped, None);
    }

    #[test]
    fn a_small_oscillation_whose_peaks_wander_trips_the_undecaying_rule() {
        // ±0.12 µm at 400 Hz, each peak off by up to a quarter at random (the
        // noise on it): judged on pairs of peaks, the undecaying rule trips
        // within five periods.
        let wander: Vec<f64> = {
            let mut g = gaussian(0.12);
            (0..1000).map(|_| (1.0 + g()).clamp(0.75, 1.25)).collect()
        };
        let k = held_at(0.075, 400.0, 0.12, |n| wander[n as usize % 1000]).expect("caught");
        assert!(k < 250, "{k} ticks");
        // A ringing that loses a tenth per half-cycle (ζ ≈ 0.034) never does,
        // nor white noise of σ 0.02 µm (a healthy stage at rest) at 0.075 µm.
        let d = 0.9f64;
        assert_eq!(held_at(0.075, 400.0, 3.0, |n| d.powi(n as i32)), None);
        let mut w = LoopWatch::new();
        let mut noise = gaussian(0.02);
        let at = Micrometres::from_num(20);
        let small = Micrometres::from_num(0.075);
        let tripped = (0..200_000u32).find(|_| {
            w.update(
                Micrometres::from_num(noise()),
                false,
                at,
                false,
                &halves(small),
            )
            .is_some()
        });
        assert_eq!(tripped, None);
    }
}
