//! What the board and its amplifier allow, in engineering units: the one place the
//! host tools take them from (the firmware's [`fpi_firmware::board::capacity::BOARD`]),
//! and the check of an option against such a limit.

use anyhow::{bail, Result};
use piezo_fpi::q::{Volts, SIGNAL_FRAC};

use fpi_firmware::board::capacity::{BOARD, RATE_HZ};

use crate::data::Num;

/// A voltage of the core in volts, exactly (the inverse of
/// `piezo_fpi::q::signal`).
const fn engineering(s: Volts) -> f64 {
    s.to_bits() as f64 / (1u32 << SIGNAL_FRAC) as f64
}

/// The board's amplifier span, V: its DAC drives the stack over `0..=150 V`
/// ([`BOARD`]); no drive, limit or stroke voltage may exceed it.
pub const AMPLIFIER_MAX_V: f64 = engineering(BOARD.limits.u_max);

/// The amplifier's largest slew, V/ms: its current limit into the stack's
/// capacitance (5 V per control step at the board's 20 kHz: 100 V/ms).
pub const AMPLIFIER_MAX_SLEW_V_PER_MS: f64 =
    engineering(BOARD.limits.max_step) * RATE_HZ as f64 / 1000.0;

/// Control rates the firmware model file accepts, Hz.
pub const RATE_RANGE_HZ: std::ops::RangeInclusive<u32> = 100..=200_000;

/// Refuses a value of option `what` that is not finite or outside `(0, max]`
/// (`limit` says what `max` is).
pub fn within(what: &str, v: f64, unit: &str, max: f64, limit: &str) -> Result<()> {
    if !v.is_finite() {
        bail!("{what} {v}: not a finite number");
    }
    let n = Num(v);
    if v <= 0.0 {
        bail!("{what} {n} {unit}: must be > 0 {unit}");
    }
    if v > max {
        bail!("{what} {n} {unit}: above {limit} ({max} {unit})");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_board_limits_in_engineering_units() {
        assert_eq!(AMPLIFIER_MAX_V, 150.0);
        assert_eq!(AMPLIFIER_MAX_SLEW_V_PER_MS, 100.0);
        // The core's conversion the other way gives the board's bits back.
        assert_eq!(
            piezo_fpi::q::signal(AMPLIFIER_MAX_V),
            Some(BOARD.limits.u_max.raw())
        );
    }
}
