//! The board's analog front end: how ADC counts become newtons and volts become DAC
//! codes, and the analog reference input's channel. The driver board and the
//! emulated board share it.

use piezo_fpi::io::{AdcScale, DacScale};
use piezo_fpi::q::{Micrometres, Newtons};

/// The force-sensor front end: 12 bits over −5…506.9 N (0.125 N per count), so a
/// broken wire reads a rail.
pub const FORCE_ADC: AdcScale = AdcScale {
    offset: Newtons::from_bits(-5 << 16),
    per_count: fixed::types::I4F28::from_bits(1 << 25),
};
/// The setpoint: the STM32's 12-bit DAC behind a 0–150 V (150 V / 3.3 V) amplifier.
pub const SETPOINT_DAC: DacScale = DacScale {
    codes_per_volt: fixed::types::I16F16::from_bits(1_789_132), // 4095 / 150
    max_code: 4095,
};
/// Largest code of the 12-bit ADC.
pub const ADC_MAX: u16 = 4095;
/// The stage-position sensor's front end, as a 16-bit code over −10…+70 µm
/// (1.22 nm per code): a 16-bit converter's result, or the board's 12-bit ADC
/// left-aligned (19.5 nm steps). A broken wire reads a rail.
pub const POSITION_ADC: AdcScale = AdcScale {
    offset: Micrometres::from_bits(-10 << 16),
    per_count: fixed::types::I4F28::from_bits(80 << 12), // 80 µm / 65536
};
/// Largest code of the position channel.
pub const POSITION_MAX: u16 = u16::MAX;

/// The board's further analog channels: the analog reference input
/// (`crate::reference::analog` scales it) and the stage-position sensor.
pub trait AnalogIn {
    /// The reference input's latest conversion, 12-bit counts.
    fn read_counts(&mut self) -> u16;
    /// The position sensor's latest conversion, a 16-bit code ([`POSITION_ADC`]).
    fn read_position(&mut self) -> u16;
}
