//! Ticks of the front end on mocked converters: the frames each tick sends, the
//! scaled sample, and a stalled ADC.

use super::*;
use crate::board::definition::precision::{DAC, FRONT_END as BOARD};
use crate::converters::testkit;
use embedded_hal_mock::eh1::digital::{Mock as Pin, State, Transaction as Level};
use embedded_hal_mock::eh1::spi::{Mock, Transaction};

/// The ADC's SPI, its BUSY line and the DAC's SPI, expecting what they are given.
fn mocks(
    adc: &[Vec<Transaction<u8>>],
    busy: &[State],
    dac: &[Vec<Transaction<u8>>],
) -> (Mock<u8>, Pin, Mock<u8>) {
    let levels: Vec<Level> = busy.iter().map(|s| Level::get(*s)).collect();
    (
        Mock::new(&adc.concat()),
        Pin::new(&levels),
        Mock::new(&dac.concat()),
    )
}

#[test]
fn a_tick_reads_one_frame_and_writes_one() {
    let (mut a, mut b, mut d) = mocks(
        // V1 = 0x0000 (0 V: 251 N), V2 = 0xC000 (−5 V: 10 µm).
        &[testkit::read(&[0x00, 0x00, 0xC0, 0x00])],
        &[State::Low],
        // 150 V: the AD5791's full scale, DAC register 0xFFFFF.
        &[testkit::write(&[0x1F, 0xFF, 0xFF])],
    );
    let mut fe = FrontEnd::new(
        Ad7606::new(a.clone(), b.clone()),
        Ad579x::new(d.clone(), DAC),
        [0, 0],
    );
    let s = tick_frames(&mut fe, &BOARD, Volts::from_num(150)).unwrap();
    assert_eq!(s.force, Newtons::from_num(251));
    assert_eq!(s.position_code, 0x4000);
    assert_eq!(s.position, Micrometres::from_num(10));
    assert_eq!(s.age, 0);
    a.done();
    b.done();
    d.done();
}

#[test]
fn the_setpoint_code_follows_the_scaling() {
    let (mut a, mut b, mut d) = mocks(
        &[],
        &[],
        &[
            testkit::write(&[0x10, 0x00, 0x00]), // 0 V
            testkit::write(&[0x18, 0x00, 0x00]), // 75 V: mid-scale
            testkit::write(&[0x10, 0x00, 0x00]), // below range: 0
        ],
    );
    let mut fe = FrontEnd::new(
        Ad7606::new(a.clone(), b.clone()),
        Ad579x::new(d.clone(), DAC),
        [0, 0],
    );
    for (u, code) in [(0.0, 0), (75.0, 0x8_0000), (-1.0, 0)] {
        assert_eq!(fe.drive(&BOARD, Volts::from_num(u)), Ok(code));
    }
    a.done();
    b.done();
    d.done();
}

#[test]
fn a_busy_adc_holds_the_last_sample_then_stalls() {
    let (mut a, mut b, mut d) = mocks(
        &[testkit::read(&[0x00, 0x00, 0x80, 0x00])],
        &[State::Low, State::High, State::High, State::High],
        &[],
    );
    let mut fe = FrontEnd::new(
        Ad7606::new(a.clone(), b.clone()),
        Ad579x::new(d.clone(), DAC),
        [0, 0],
    );
    let first = fe.sense(&BOARD).unwrap();
    assert_eq!(first.position, Micrometres::from_num(-10));
    for age in 1..=2 {
        let held = fe.sense(&BOARD).unwrap();
        assert_eq!(held, Sensed { age, ..first }, "no frame while BUSY is high");
    }
    assert_eq!(fe.sense(&BOARD), Err(Error::Stalled));
    assert_eq!(fe.misses(), (3, 3));
    a.done();
    b.done();
    d.done();
}
