//! The scalings at the ends of their ranges and at mid-scale.

use super::*;
use crate::board::definition::precision::{FORCE, SETPOINT as SETPOINT_20};
use crate::board::definition::POSITION;
use crate::converters::ad579x::Part;
use piezo_fpi::q::{Micrometres, Newtons};

#[test]
fn the_setpoint_covers_0_to_150_v_within_half_a_code() {
    for (s, part) in [(SETPOINT_20, Part::Ad5791), (SETPOINT_18, Part::Ad5781)] {
        let max = part.max_code();
        assert_eq!(PrecisionDacScale::full_scale(max, 150), Some(s));
        assert_eq!(s.to_code(Volts::ZERO), 0);
        assert_eq!(s.to_code(Volts::from_num(150)), max);
        assert_eq!(s.to_code(Volts::from_num(-3)), 0, "below range");
        assert_eq!(s.to_code(Volts::MAX), max, "above range");
        for k in 0..=15_000 {
            let u = Volts::from_bits((k * (150i64 << 16) / 15_000) as i32);
            let ideal = u.to_num::<f64>() * max as f64 / 150.0;
            let code = s.to_code(u) as f64;
            assert!((code - ideal).abs() <= 0.5 + 1e-3, "u = {u}");
        }
    }
    // 75 V is 524 287.5 codes: rounded up to 2^19, the AD5791's mid-scale.
    assert_eq!(SETPOINT_20.to_code(Volts::from_num(75)), 0x8_0000);
    assert!((SETPOINT_20.to_voltage(0x8_0000) - 75.0).abs() < 2e-4);
    assert_eq!(PrecisionDacScale::full_scale(0xF_FFFF, 0), None);
    assert_eq!(PrecisionDacScale::full_scale(u32::MAX, 1), None);
}

#[test]
fn adc_codes_are_offset_binary_from_minus_full_scale() {
    assert_eq!(offset_binary(i16::MIN), 0);
    assert_eq!(offset_binary(-1), 0x7FFF);
    assert_eq!(offset_binary(0), 0x8000);
    assert_eq!(offset_binary(i16::MAX), 0xFFFF);
}

#[test]
fn the_sensor_channels_span_their_range() {
    // Force: −5 N at −10 V, 251 N at 0 V, 507 N − 1 code at +10 V − 1 LSB.
    assert_eq!(
        FORCE.to_force(offset_binary(i16::MIN)),
        Newtons::from_num(-5)
    );
    assert_eq!(FORCE.to_force(offset_binary(0)), Newtons::from_num(251));
    assert_eq!(
        FORCE.to_force(offset_binary(i16::MAX)),
        Newtons::from_num(507.0 - 1.0 / 128.0)
    );
    // Position: −10 µm, 30 µm, 70 µm − 1 code.
    assert_eq!(POSITION.to_position(0), Micrometres::from_num(-10));
    assert_eq!(POSITION.to_position(0x8000), Micrometres::from_num(30));
    // The same scalings from the sensors' sensitivities: 25.6 N/V about 251 N,
    // 4 µm/V about 30 µm, on the ±10 V range.
    assert_eq!(channel(Range::PlusMinus10V, 251.0, 25.6), Some(FORCE));
    assert_eq!(channel(Range::PlusMinus10V, 30.0, 4.0), Some(POSITION));
    // On ±5 V the same sensor spans half the force in twice the resolution.
    let half = channel(Range::PlusMinus5V, 251.0, 25.6).unwrap();
    assert_eq!(half.to_force(0), Newtons::from_num(123));
    assert_eq!(half.per_count.to_bits(), FORCE.per_count.to_bits() / 2);
    assert_eq!(channel(Range::PlusMinus10V, 1e9, 1.0), None);
}
