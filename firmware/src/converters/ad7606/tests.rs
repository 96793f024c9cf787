//! The AD7606 driver against the serial interface's frame (V1, V2, … on DOUTA, 16
//! bits each, MSB first, two's complement, one CS̅ frame), the BUSY handshake and
//! the configuration pins.

use super::*;
use crate::board::definition::precision::ADC as BOARD;
use crate::converters::testkit::{self, Broken};
use embedded_hal::spi::ErrorKind;
use embedded_hal_mock::eh1::delay::{CheckedDelay, Transaction as Wait};
use embedded_hal_mock::eh1::digital::{Mock as Pin, State, Transaction as Level};
use embedded_hal_mock::eh1::spi::Mock;
use embedded_hal_mock::eh1::MockError;

/// A BUSY line read once at each level in `levels`.
fn busy(levels: &[State]) -> Pin {
    let t: Vec<Level> = levels.iter().map(|s| Level::get(*s)).collect();
    Pin::new(&t)
}

#[test]
fn a_ready_conversion_is_one_frame_of_16_bits_per_channel() {
    // V1 = 0x7FFF (+full scale − 1 LSB), V2 = 0x8000 (−full scale): two's complement.
    let mut spi = Mock::new(&testkit::read(&[0x7F, 0xFF, 0x80, 0x00]));
    let mut b = busy(&[State::Low]);
    let mut adc: Ad7606<_, _, 2> = Ad7606::new(spi.clone(), b.clone());
    assert_eq!(adc.read(), Ok(Conversion::Ready([32_767, -32_768])));
    spi.done();
    b.done();

    // All eight channels in ascending order, still one frame (128 SCLK).
    let reply = [
        0x00, 0x01, 0xFF, 0xFF, 0x12, 0x34, 0xED, 0xCC, 0x40, 0x00, 0xC0, 0x00, 0x00, 0x00, 0x7F,
        0xFE,
    ];
    let mut spi = Mock::new(&testkit::read(&reply));
    let mut b = busy(&[State::Low]);
    let mut adc: Ad7606<_, _, 8> = Ad7606::new(spi.clone(), b.clone());
    let expect = [1, -1, 0x1234, -0x1234, 16_384, -16_384, 0, 32_766];
    assert_eq!(adc.read(), Ok(Conversion::Ready(expect)));
    spi.done();
    b.done();
}

#[test]
fn a_busy_adc_is_not_read() {
    let mut spi = Mock::new(&[]);
    let mut b = busy(&[State::High]);
    let mut adc: Ad7606<_, _, 2> = Ad7606::new(spi.clone(), b.clone());
    assert_eq!(adc.read(), Ok(Conversion::Busy));
    spi.done();
    b.done();
}

#[test]
fn a_failed_busy_or_spi_read_is_the_adcs_error() {
    let mut b =
        Pin::new(&[Level::get(State::Low).with_error(MockError::Io(std::io::ErrorKind::Other))]);
    let mut spi = Mock::new(&[]);
    let mut adc: Ad7606<_, _, 2> = Ad7606::new(spi.clone(), b.clone());
    assert_eq!(adc.read(), Err(Error::Pin(Device::Adc)));
    spi.done();
    b.done();

    let mut b = busy(&[State::Low]);
    let mut adc: Ad7606<_, _, 2> = Ad7606::new(Broken(ErrorKind::Overrun), b.clone());
    assert_eq!(adc.read(), Err(Error::Spi(Device::Adc, ErrorKind::Overrun)));
    b.done();
}

/// The five configuration pins, each expecting the levels given, in order.
fn pins(os: [&[State]; 3], range: &[State], reset: &[State]) -> ConfigPins<Pin> {
    let pin = |levels: &[State]| {
        let t: Vec<Level> = levels.iter().map(|s| Level::set(*s)).collect();
        Pin::new(&t)
    };
    ConfigPins {
        os: os.map(pin),
        range: pin(range),
        reset: pin(reset),
    }
}

/// Checks every pin's expectations were met.
fn done(p: &mut ConfigPins<Pin>) {
    p.os.iter_mut().for_each(Pin::done);
    p.range.done();
    p.reset.done();
}

#[test]
fn configure_sets_range_and_oversampling_then_pulses_reset() {
    use State::{High, Low};
    // The board: OS = 000, RANGE high (±10 V), RESET high for 1 µs, then 1 µs.
    let mut p = pins([&[Low], &[Low], &[Low]], &[High], &[High, Low]);
    let mut delay = CheckedDelay::new(&[Wait::delay_us(1), Wait::delay_us(1)]);
    assert_eq!(configure(&BOARD, &mut p, &mut delay), Ok(()));
    done(&mut p);
    delay.done();

    // Oversampling by 8 (OS2..OS0 = 011), ±5 V (RANGE low).
    let cfg = Config {
        range: Range::PlusMinus5V,
        oversampling: Oversampling::X8,
    };
    let mut p = pins([&[High], &[High], &[Low]], &[Low], &[High, Low]);
    let mut delay = CheckedDelay::new(&[Wait::delay_us(1), Wait::delay_us(1)]);
    assert_eq!(configure(&cfg, &mut p, &mut delay), Ok(()));
    done(&mut p);
    delay.done();
}

#[test]
fn a_pin_that_cannot_be_driven_stops_the_configuration() {
    let fail = Level::set(State::Low).with_error(MockError::Io(std::io::ErrorKind::Other));
    let mut p = ConfigPins {
        os: [Pin::new(&[fail]), Pin::new(&[]), Pin::new(&[])],
        range: Pin::new(&[]),
        reset: Pin::new(&[]),
    };
    let mut delay = CheckedDelay::new(&[]);
    assert_eq!(
        configure(&BOARD, &mut p, &mut delay),
        Err(Error::Pin(Device::Adc))
    );
    done(&mut p);
    delay.done();
}

#[test]
fn conversion_times_grow_with_the_averaging() {
    let all = [
        Oversampling::Off,
        Oversampling::X2,
        Oversampling::X4,
        Oversampling::X8,
        Oversampling::X16,
        Oversampling::X32,
        Oversampling::X64,
    ];
    for pair in all.windows(2) {
        assert!(pair[0].conversion_max_ns() < pair[1].conversion_max_ns());
    }
    // Without averaging a conversion fits the AD7606's 5 µs cycle (200 kSPS).
    assert!(Oversampling::Off.conversion_max_ns() < 5_000);
    assert_eq!(Range::PlusMinus10V.full_scale_volts(), 10.0);
}
