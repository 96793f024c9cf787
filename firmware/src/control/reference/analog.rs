//! The analog reference input: a second ADC channel, 0–3.3 V over the stage's
//! stroke, checked like the force sensor before the stage follows it.
//!
//! `x = lo + counts · (hi − lo) / 4095` with `[lo, hi]` the running model's
//! reference window (its reachable stroke), so every reading in range is a
//! reachable reference. Two checks, each latching
//! [`Fault::ReferenceInput`](piezo_fpi::control::Fault::ReferenceInput) in the
//! control loop:
//!
//! * **range** — a reading within [`RAIL_COUNTS`] of either rail (0 or 4095) is an
//!   open or shorted input, not a position (use 0.013–3.287 V);
//! * **plausibility** — a change of more than [`MAX_JUMP_COUNTS`] between two
//!   ticks (1/16 of the range in 50 µs) is a wire or connector fault, not a signal
//!   a piezo stage could follow.

use fixed::types::I4F28;
use piezo_fpi::control::Interval;
use piezo_fpi::q::Micrometres;

use crate::board::analog_in::ADC_MAX;

/// Readings this close to a rail are out of range, ADC counts.
pub const RAIL_COUNTS: u16 = 16;
/// Largest plausible change between two ticks, ADC counts.
pub const MAX_JUMP_COUNTS: u16 = 256;

/// What is wrong with a reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnalogFault {
    /// At a rail.
    OutOfRange,
    /// Jumped further than a stage signal can.
    Implausible,
}

/// The analog input's scaling (configuration) and its last reading (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnalogInput {
    lo: Micrometres,
    /// µm per count, `I4F28`.
    per_count: I4F28,
    last: Option<u16>,
}

impl AnalogInput {
    /// The scaling onto a stroke `[lo, hi]` (µm).
    pub fn over(stroke: Interval<Micrometres>) -> Self {
        let span = stroke.hi.to_bits() as i64 - stroke.lo.to_bits() as i64;
        // span is Q16.16; per_count Q4.28 = span · 2¹² / 4095, rounded.
        let per = ((span << 12) + ADC_MAX as i64 / 2) / ADC_MAX as i64;
        Self {
            lo: stroke.lo,
            per_count: I4F28::from_bits(per.clamp(i32::MIN as i64, i32::MAX as i64) as i32),
            last: None,
        }
    }

    /// Forgets the last reading (the plausibility check starts afresh).
    pub fn restart(&mut self) {
        self.last = None;
    }

    /// A reading in ADC counts as a position, µm, or why it cannot be one.
    #[inline]
    pub fn read(&mut self, counts: u16) -> Result<Micrometres, AnalogFault> {
        if !(RAIL_COUNTS..=ADC_MAX - RAIL_COUNTS).contains(&counts) {
            return Err(AnalogFault::OutOfRange);
        }
        if let Some(last) = self.last {
            if counts.abs_diff(last) > MAX_JUMP_COUNTS {
                return Err(AnalogFault::Implausible);
            }
        }
        self.last = Some(counts);
        let offset = (self.per_count.to_bits() as i64 * counts as i64 + (1 << 11)) >> 12;
        Ok(Micrometres::from_bits(
            self.lo.to_bits().wrapping_add(offset as i32),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stroke() -> Interval<Micrometres> {
        Interval {
            lo: Micrometres::from_num(0),
            hi: Micrometres::from_num(38.5),
        }
    }

    #[test]
    fn counts_map_onto_the_stroke() {
        let mut a = AnalogInput::over(stroke());
        for c in [RAIL_COUNTS, 1000, 2048, 3000, ADC_MAX - RAIL_COUNTS] {
            a.restart();
            let x = a.read(c).unwrap().to_num::<f64>();
            let want = 38.5 * c as f64 / 4095.0;
            assert!((x - want).abs() < 2e-4, "{c}: {x} vs {want}");
        }
    }

    #[test]
    fn rails_and_jumps_are_faults() {
        let mut a = AnalogInput::over(stroke());
        assert_eq!(a.read(0), Err(AnalogFault::OutOfRange));
        assert_eq!(a.read(ADC_MAX), Err(AnalogFault::OutOfRange));
        assert!(a.read(2000).is_ok());
        assert!(a.read(2000 + MAX_JUMP_COUNTS).is_ok());
        assert_eq!(a.read(1000), Err(AnalogFault::Implausible));
    }
}
