//! The tick's timing rules and the handling of missed conversions.

use super::*;
use crate::board::definition::precision::TIMING as BOARD;
use crate::converters::ad7606::Oversampling;
use crate::converters::Device;
use embedded_hal::spi::ErrorKind;

#[test]
fn the_boards_timing_leaves_the_sample_6_us_old() {
    assert_eq!(BOARD.check(), Ok(BOARD));
    assert_eq!(BOARD.period_ns, 50_000);
    assert_eq!(BOARD.sample_age_ns(), 6_000);
}

#[test]
fn timings_that_cannot_work_are_refused() {
    let t = BOARD;
    let at = |convst_ns| TickTiming { convst_ns, ..t };
    assert_eq!(at(0).check(), Err(TimingError::ConvstOutsidePeriod));
    assert_eq!(at(50_000).check(), Err(TimingError::ConvstOutsidePeriod));
    // 4.15 µs of conversion and 0.5 µs of margin do not fit after 46 µs.
    assert_eq!(at(46_000).check(), Err(TimingError::ConversionOverrunsTick));
    assert_eq!(
        TickTiming {
            convst_ns: 45_350,
            ..t
        }
        .check()
        .map(|t| t.sample_age_ns()),
        Ok(4_650)
    );
    // The ISR may still be reading at 44 µs: CONVST cannot come earlier.
    assert_eq!(at(40_000).check(), Err(TimingError::ReadOverlapsConversion));
    // Averaging by 8 (up to 39 µs) fits only with CONVST early and a short read.
    let os8 = TickTiming {
        convst_ns: 10_000,
        conversion_max_ns: Oversampling::X8.conversion_max_ns(),
        read_done_ns: 10_000,
        ..t
    };
    assert_eq!(os8.check().map(|t| t.sample_age_ns()), Ok(40_000));
    let os16 = TickTiming {
        conversion_max_ns: Oversampling::X16.conversion_max_ns(),
        ..os8
    };
    assert_eq!(os16.check(), Err(TimingError::ConversionOverrunsTick));
}

#[test]
fn misses_hold_the_last_sample_until_the_limit() {
    let mut f = Freshness::new([1, 2]);
    let ready = |c| Ok(Conversion::Ready(c));
    assert_eq!(
        f.take(ready([10, 20]), 3),
        Ok(Held {
            codes: [10, 20],
            age: 0
        })
    );
    // BUSY high twice: the last good codes, getting older.
    for age in 1..=2 {
        assert_eq!(
            f.take(Ok(Conversion::Busy), 3),
            Ok(Held {
                codes: [10, 20],
                age
            })
        );
    }
    // The third in a row is the fault, and stays one until a conversion comes.
    assert_eq!(f.take(Ok(Conversion::Busy), 3), Err(Error::Stalled));
    assert_eq!(f.take(Ok(Conversion::Busy), 3), Err(Error::Stalled));
    assert_eq!((f.missed(), f.missed_total()), (4, 4));
    // One good conversion ends the run.
    assert_eq!(f.take(ready([11, 21]), 3).map(|h| h.age), Ok(0));
    assert_eq!((f.missed(), f.missed_total()), (0, 4));
}

#[test]
fn a_failed_read_counts_as_a_miss_and_is_reported_at_the_limit() {
    let spi = Error::Spi(Device::Adc, ErrorKind::Overrun);
    let mut f = Freshness::new([5]);
    assert_eq!(f.take(Err(spi), 2).map(|h| h.codes), Ok([5]));
    assert_eq!(f.take(Err(spi), 2), Err(spi));
    // With a limit of 1 any miss is the fault.
    let mut g = Freshness::new([5]);
    assert_eq!(g.take(Ok(Conversion::Busy), 1), Err(Error::Stalled));
    assert_eq!(Error::Stalled.code(), 1);
}
