//! Where in the control period the converters act, and what a conversion that is
//! not ready does to a tick.
//!
//! **Timing** ([`TickTiming`]): one hardware timer runs the period. Its update
//! event starts the control ISR (phase 0); an output-compare channel drives CONVST
//! at `convst_ns`, so the instant of sampling never depends on software. The
//! conversion, at most `conversion_max_ns` long, ends before the next period
//! starts, and the ISR's read ends before the next CONVST: a read never overlaps a
//! conversion or falls on BUSY's falling edge. The sample a tick uses is
//! [`TickTiming::sample_age_ns`] old when the tick starts, every tick. With LDAC̅
//! on a second compare channel at phase 0, the DAC output also changes at a fixed
//! instant: the code the ISR of tick k writes reaches the amplifier at the start
//! of tick k + 1, one period later, however long the ISR took.
//!
//! **A conversion not ready** ([`Freshness`]): the ISR looks at BUSY once and never
//! waits. If a conversion is missing (BUSY still high, or the read failed), the
//! tick runs on the last good codes and counts the miss; `limit` misses in a row
//! are [`Error::Stalled`] (or the failed read's error), which the application
//! latches as a fault. One good conversion clears the run.

use super::ad7606::Conversion;
use super::Error;

/// Time from CONVST's compare event to the earliest moment the ISR may read, on
/// top of the longest conversion: BUSY's fall-time and timer-to-pin delays, ns.
pub const BUSY_MARGIN_NS: u32 = 500;

/// The phases of one control period, ns from the timer's update event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TickTiming {
    /// The control period.
    pub period_ns: u32,
    /// CONVST's rising edge (timer output compare).
    pub convst_ns: u32,
    /// The longest conversion (BUSY high) for the ADC's configuration.
    pub conversion_max_ns: u32,
    /// The latest phase by which the ISR has finished reading the ADC.
    pub read_done_ns: u32,
}

/// Why a [`TickTiming`] cannot work.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimingError {
    /// CONVST does not fall inside the period.
    ConvstOutsidePeriod,
    /// The conversion (with [`BUSY_MARGIN_NS`]) does not end before the next
    /// period starts, where the ISR reads it.
    ConversionOverrunsTick,
    /// The ISR's read may still run when the next CONVST comes.
    ReadOverlapsConversion,
}

impl TickTiming {
    /// The timing if it works: CONVST inside the period, the conversion over
    /// before the next ISR, the ISR's read over before the next CONVST.
    pub const fn check(self) -> Result<Self, TimingError> {
        if self.convst_ns == 0 || self.convst_ns >= self.period_ns {
            return Err(TimingError::ConvstOutsidePeriod);
        }
        let done = self.convst_ns as u64 + self.conversion_max_ns as u64 + BUSY_MARGIN_NS as u64;
        if done > self.period_ns as u64 {
            return Err(TimingError::ConversionOverrunsTick);
        }
        if self.read_done_ns > self.convst_ns {
            return Err(TimingError::ReadOverlapsConversion);
        }
        Ok(self)
    }

    /// How old the sample is when the tick that uses it starts, ns: the same every
    /// tick.
    pub const fn sample_age_ns(&self) -> u32 {
        self.period_ns - self.convst_ns
    }
}

/// The codes a tick runs on, and how old they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Held<const N: usize> {
    /// Channels V1…VN, two's complement.
    pub codes: [i16; N],
    /// 0: converted for this tick; k: the k-th tick in a row on the last good
    /// conversion.
    pub age: u16,
}

/// The last good conversion and the run of misses since (the state; the limit
/// is configuration, passed in).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Freshness<const N: usize> {
    last: [i16; N],
    missed: u16,
    missed_total: u32,
}

impl<const N: usize> Freshness<N> {
    /// Starting from a first conversion's codes (read at start-up).
    pub const fn new(first: [i16; N]) -> Self {
        Self {
            last: first,
            missed: 0,
            missed_total: 0,
        }
    }

    /// This tick's codes from its look at the ADC: a fresh conversion, or the last
    /// good one while fewer than `limit` (at least 1) ticks in a row have missed;
    /// at the limit, the error (a busy ADC is [`Error::Stalled`]).
    #[inline]
    pub fn take(
        &mut self,
        look: Result<Conversion<N>, Error>,
        limit: u16,
    ) -> Result<Held<N>, Error> {
        let cause = match look {
            Ok(Conversion::Ready(codes)) => {
                self.last = codes;
                self.missed = 0;
                return Ok(Held { codes, age: 0 });
            }
            Ok(Conversion::Busy) => Error::Stalled,
            Err(e) => e,
        };
        self.missed = self.missed.saturating_add(1);
        self.missed_total = self.missed_total.saturating_add(1);
        if self.missed >= limit {
            return Err(cause);
        }
        Ok(Held {
            codes: self.last,
            age: self.missed,
        })
    }

    /// Misses in the current run.
    pub const fn missed(&self) -> u16 {
        self.missed
    }

    /// Misses since start-up (saturating).
    pub const fn missed_total(&self) -> u32 {
        self.missed_total
    }
}

#[cfg(test)]
mod tests;
