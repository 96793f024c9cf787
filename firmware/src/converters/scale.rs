//! Converter codes in the project's units, in the style of the core's
//! [`DacScale`](piezo_fpi::io::DacScale) and [`AdcScale`].
//!
//! * Setpoint: amplifier volts (`I16F16`) to an 18/20-bit DAC code (`u32`) with
//!   [`PrecisionDacScale`]; `codes_per_volt` is `I16F16` (20 bits over 150 V:
//!   6990.5 codes/V, exact in `I16F16`; 18 bits: 1747.62, within 5·10⁻⁶ codes/V).
//! * Sensors: the AD7606's two's complement code becomes an offset-binary `u16`
//!   ([`offset_binary`]: 0 at −full scale, 32 768 at 0 V), which the core's
//!   [`AdcScale`] turns into newtons or micrometres (`I16F16`; `per_count` is
//!   `I4F28`, `offset` the value at code 0).

use super::ad7606::Range;
use fixed::types::I16F16;
use piezo_fpi::io::AdcScale;
use piezo_fpi::q::{self, Volts};

/// Volts of amplifier output to DAC codes: `code = round(u · codes_per_volt)`,
/// saturated to `0..=max_code`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrecisionDacScale {
    /// DAC codes per volt of amplifier output, `I16F16`.
    pub codes_per_volt: I16F16,
    /// The largest code (2^18 − 1 or 2^20 − 1).
    pub max_code: u32,
}

impl PrecisionDacScale {
    /// `max_code` at `volts` of amplifier output, code 0 at 0 V (V_REFN = 0 V);
    /// `None` for 0 V or a ratio beyond `I16F16`.
    pub const fn full_scale(max_code: u32, volts: u16) -> Option<Self> {
        if volts == 0 {
            return None;
        }
        let v = volts as i64;
        let bits = (((max_code as i64) << 16) + v / 2) / v;
        if bits > i32::MAX as i64 {
            return None;
        }
        Some(Self {
            codes_per_volt: I16F16::from_bits(bits as i32),
            max_code,
        })
    }

    /// The code for an amplifier voltage: negative volts give 0, volts beyond the
    /// range `max_code`. Exact product in 64 bits, rounded once. No division.
    #[inline]
    pub fn to_code(&self, voltage: Volts) -> u32 {
        let u = voltage.to_bits().max(0) as i64;
        let c = (u * self.codes_per_volt.to_bits() as i64 + (1 << 31)) >> 32;
        if c > self.max_code as i64 {
            self.max_code
        } else {
            c as u32
        }
    }

    /// The amplifier voltage a code stands for (for tests and simulated stages).
    pub fn to_voltage(&self, code: u32) -> f32 {
        code as f32 / self.codes_per_volt.to_num::<f32>()
    }
}

/// The same with an AD5781: 0–150 V in 18 bits (572 µV per code).
pub const SETPOINT_18: PrecisionDacScale = PrecisionDacScale {
    codes_per_volt: I16F16::from_bits(114_532_024), // 262 143 / 150, within 5·10⁻⁶
    max_code: (1 << 18) - 1,
};

/// The offset-binary code of an AD7606 result: 0 at −full scale, 32 768 at 0 V,
/// 65 535 one code below +full scale.
#[inline]
pub const fn offset_binary(code: i16) -> u16 {
    (code as u16) ^ 0x8000
}

/// The scaling of a channel on the ±`range` input whose sensor reads `at_zero` (in
/// its unit) at 0 V and changes by `per_volt` per volt; `None` if the offset or
/// the step per code does not fit its format.
pub const fn channel(range: Range, at_zero: f64, per_volt: f64) -> Option<AdcScale> {
    let fs = range.full_scale_volts();
    let at_minus = at_zero - per_volt * fs;
    match (q::signal(at_minus), q::gain(per_volt * 2.0 * fs / 65536.0)) {
        (Some(offset), Some(per_count)) => Some(AdcScale { offset, per_count }),
        _ => None,
    }
}

#[cfg(test)]
mod tests;
