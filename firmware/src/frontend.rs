//! The board's analog front end: how ADC counts become newtons and volts become DAC
//! codes, and the analog reference input's channel. The driver board and the
//! emulated board share it.

use piezo_fpi::io::{AdcScale, DacScale};
use piezo_fpi::q::Newtons;

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

/// The analog reference input's ADC channel (`crate::reference::analog` scales it).
pub trait AnalogIn {
    /// The latest conversion, 12-bit counts.
    fn read_counts(&mut self) -> u16;
}
