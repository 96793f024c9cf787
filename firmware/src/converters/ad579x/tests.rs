//! The AD5781/AD5791 driver against the data sheets' frame layout (AD5791 Table 7:
//! R/W̅ in DB23, the address in DB22–DB20, data in DB19–DB0, MSB first), the
//! control register's bits (Table 11) and the chip-select framing.

use super::*;
use crate::board::definition::precision::DAC as BOARD;
use crate::converters::testkit::{self, Broken};
use embedded_hal::spi::ErrorKind;
use embedded_hal_mock::eh1::spi::{Mock, Transaction};

/// A mock expecting `frames` in turn.
fn mock(frames: &[Vec<Transaction<u8>>]) -> Mock<u8> {
    Mock::new(&frames.concat())
}

const AD5781: Config = Config {
    part: Part::Ad5781,
    ..BOARD
};

#[test]
fn frames_follow_the_input_shift_register_format() {
    // 0 | 001 | 1000 0000 0000 0000 0000: DAC register, mid-scale code.
    assert_eq!(write_frame(Register::Dac, 0x8_0000), [0x18, 0x00, 0x00]);
    // 0 | 010 | data 0x00012: control register.
    assert_eq!(write_frame(Register::Control, 0x12), [0x20, 0x00, 0x12]);
    // 0 | 011 | all ones: clearcode register.
    assert_eq!(
        write_frame(Register::ClearCode, 0xF_FFFF),
        [0x3F, 0xFF, 0xFF]
    );
    // 0 | 100 | RESET (DB2): software control register.
    assert_eq!(
        write_frame(Register::SoftwareControl, 0b100),
        [0x40, 0x00, 0x04]
    );
    // 1 | 010 | 0…: read the control register; 1 | 001: read the DAC register.
    assert_eq!(read_frame(Register::Control), [0xA0, 0x00, 0x00]);
    assert_eq!(read_frame(Register::Dac), [0x90, 0x00, 0x00]);
    // Data beyond DB19 never reaches the address or R/W̅ bits.
    assert_eq!(write_frame(Register::Dac, u32::MAX), [0x1F, 0xFF, 0xFF]);
    assert_eq!(NOP, [0x00, 0x00, 0x00]);
}

#[test]
fn control_words_set_table_11s_bits() {
    // BIN/2sC (DB4) and RBUF (DB1), LIN COMP 0000 for a 10 V span.
    assert_eq!(BOARD.control(Output::On), 0b0000_0001_0010);
    // Plus OPGND (DB2) and DACTRI (DB3): the power-on clamp.
    assert_eq!(BOARD.control(Output::Clamped), 0b0000_0001_1110);
    // A 20 V span (LIN COMP 1100 in DB9–DB6), a gain-of-two stage (RBUF 0).
    let wide = Config {
        span: Span::Span20V,
        gain_of_two: true,
        ..BOARD
    };
    assert_eq!(wide.control(Output::On), 0b0011_0001_0000);
    assert_eq!(
        (Part::Ad5781.max_code(), Part::Ad5791.max_code()),
        (0x3_FFFF, 0xF_FFFF)
    );
}

#[test]
fn init_sets_the_code_before_it_releases_the_clamp_and_reads_the_control_back() {
    let mut spi = mock(&[
        testkit::write(&[0x20, 0x00, 0x1E]), // control: coding, span, still clamped
        testkit::write(&[0x10, 0x00, 0x00]), // DAC: code 0 (the safe voltage)
        testkit::write(&[0x20, 0x00, 0x12]), // control: OPGND = DACTRI = 0, output on
        testkit::write(&[0xA0, 0x00, 0x00]), // read control…
        // …clocked out during a NOP frame; DB23–DB20 of the answer are ignored.
        testkit::transfer(&NOP, &[0xA0, 0x00, 0x12]),
    ]);
    let mut dac = Ad579x::new(spi.clone(), BOARD);
    assert_eq!(dac.init(0), Ok(()));
    spi.done();
}

#[test]
fn codes_reach_db19_to_db0_saturated_to_the_part() {
    let mut spi = mock(&[
        testkit::write(&[0x10, 0x00, 0x00]), // AD5791: 0
        testkit::write(&[0x18, 0x00, 0x00]), // mid-scale 0x80000
        testkit::write(&[0x1F, 0xFF, 0xFF]), // full scale 0xFFFFF
        testkit::write(&[0x1F, 0xFF, 0xFF]), // beyond: saturated
    ]);
    let mut dac = Ad579x::new(spi.clone(), BOARD);
    for code in [0, 0x8_0000, 0xF_FFFF, 0x10_0000] {
        dac.write_code(code).unwrap();
    }
    spi.done();

    // The AD5781's 18 bits sit in DB19–DB2 (AD5781 Table 10).
    let mut spi = mock(&[
        testkit::write(&[0x10, 0x00, 0x04]), // code 1
        testkit::write(&[0x18, 0x00, 0x00]), // mid-scale 0x20000
        testkit::write(&[0x1F, 0xFF, 0xFC]), // full scale 0x3FFFF
        testkit::write(&[0x1F, 0xFF, 0xFC]), // a 20-bit code: saturated
    ]);
    let mut dac = Ad579x::new(spi.clone(), AD5781);
    for code in [1, 0x2_0000, 0x3_FFFF, 0xF_FFFF] {
        dac.write_code(code).unwrap();
    }
    spi.done();
}

#[test]
fn the_self_test_reads_both_registers_back() {
    let good = [
        testkit::write(&[0xA0, 0x00, 0x00]),
        testkit::transfer(&NOP, &[0x20, 0x00, 0x12]),
        testkit::write(&[0x90, 0x00, 0x00]),
        testkit::transfer(&NOP, &[0x1F, 0xFF, 0xFC]),
    ];
    let mut spi = mock(&good);
    let mut dac = Ad579x::new(spi.clone(), AD5781);
    assert_eq!(dac.self_test(0x3_FFFF), Ok(()));
    spi.done();

    // The DAC holds another code.
    let mut spi = mock(&good);
    let mut dac = Ad579x::new(spi.clone(), AD5781);
    assert_eq!(
        dac.self_test(0x2_0000),
        Err(Error::Readback {
            register: Register::Dac,
            wrote: 0x2_0000,
            read: 0x3_FFFF
        })
    );
    spi.done();

    // SDO stuck low (unconnected, or a part in reset): the control word reads 0.
    let mut spi = mock(&[
        testkit::write(&[0xA0, 0x00, 0x00]),
        testkit::transfer(&NOP, &[0x00, 0x00, 0x00]),
    ]);
    let mut dac = Ad579x::new(spi.clone(), BOARD);
    assert_eq!(
        dac.self_test(0),
        Err(Error::Readback {
            register: Register::Control,
            wrote: 0x12,
            read: 0
        })
    );
    spi.done();
}

#[test]
fn clamping_writes_the_power_on_state_back() {
    let mut spi = mock(&[testkit::write(&[0x20, 0x00, 0x1E])]);
    let mut dac = Ad579x::new(spi.clone(), BOARD);
    dac.set_output(Output::Clamped).unwrap();
    spi.done();
}

#[test]
fn a_failed_transfer_is_the_dacs_spi_error() {
    let mut dac = Ad579x::new(Broken(ErrorKind::ModeFault), BOARD);
    let e = Error::Spi(Device::Dac, ErrorKind::ModeFault);
    assert_eq!(dac.write_code(1), Err(e));
    assert_eq!(dac.init(0), Err(e));
    assert_eq!(dac.read_code(), Err(e));
    assert_eq!(e.code(), 2);
}
