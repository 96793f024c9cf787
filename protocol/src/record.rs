//! What a recording carries: the recorded signals' mask bits (in wire order),
//! the status bits of each sample, and a sample as the board keeps it.

use serde::{Deserialize, Serialize};

/// Bits of [`Sample::status`].
pub mod status {
    /// A fault is latched (the output ramps to, or sits at, the safe voltage).
    pub const FAULT: u8 = 1;
    /// The amplifier is enabled.
    pub const AMPLIFIER_ON: u8 = 2;
    /// The output limits changed the voltage this tick.
    pub const LIMITED: u8 = 4;
    /// A stream is holding its last point: the host fell behind.
    pub const UNDERRUN: u8 = 8;
    /// Straight-line drive (uncompensated) instead of the inverse FPI.
    pub const UNCOMPENSATED: u8 = 16;
    /// The reference is approaching a new source's entry point.
    pub const APPROACHING: u8 = 32;
    /// The loop is closed on the position sensor (with [`UNCOMPENSATED`]: feedback
    /// alone, else feedback plus the inverse FPI).
    pub const FEEDBACK: u8 = 64;
}

/// Which signals a recording sends (bits of a mask, in this order on the wire).
pub mod signal {
    /// Reference, µm.
    pub const X_REF: u8 = 1;
    /// Setpoint voltage, V.
    pub const VOLTAGE: u8 = 2;
    /// Force reading, N.
    pub const FORCE: u8 = 4;
    /// Estimated stage position `f_K(x̂_pea)`, µm.
    pub const X_EST: u8 = 8;
    /// Status bits ([`super::status`]).
    pub const STATUS: u8 = 16;
    /// The true stage position (the emulated board's virtual stage), µm.
    pub const X_TRUE: u8 = 32;
    /// The position sensor's reading, µm.
    pub const X_SENSOR: u8 = 64;
    /// Every signal.
    pub const ALL: u8 = 127;
}

/// One recorded tick. Lengths, voltage and force as raw `I16F16` bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Sample {
    /// Tick number since start-up.
    pub tick: u32,
    /// Reference, µm.
    pub x_ref: i32,
    /// Setpoint applied, V.
    pub voltage: i32,
    /// Force reading, N.
    pub force: i32,
    /// Estimated stage position, µm.
    pub x_est: i32,
    /// True stage position, µm ([`NO_TRUE_POSITION`] on a real board).
    pub x_true: i32,
    /// Position sensor reading, µm.
    pub x_sensor: i32,
    /// [`status`] bits.
    pub status: u8,
}

/// `x_true` of a board that has no true position.
pub const NO_TRUE_POSITION: i32 = i32::MIN;

impl Sample {
    /// The values of the signals in `mask`, in wire order, after the tick.
    pub fn values(&self, mask: u8) -> impl Iterator<Item = i32> + '_ {
        let all = [
            (signal::X_REF, self.x_ref),
            (signal::VOLTAGE, self.voltage),
            (signal::FORCE, self.force),
            (signal::X_EST, self.x_est),
            (signal::STATUS, self.status as i32),
            (signal::X_TRUE, self.x_true),
            (signal::X_SENSOR, self.x_sensor),
        ];
        core::iter::once(self.tick as i32).chain(
            all.into_iter()
                .filter(move |(bit, _)| mask & bit != 0)
                .map(|(_, v)| v),
        )
    }

    /// Values per sample on the wire for `mask` (the tick included).
    pub fn width(mask: u8) -> usize {
        1 + (mask & signal::ALL).count_ones() as usize
    }

    /// A sample back from its wire values for `mask` (absent signals are 0, the
    /// true position [`NO_TRUE_POSITION`]); `None` if `values` is too short.
    pub fn from_values(mask: u8, values: &[i32]) -> Option<Self> {
        let mut it = values.iter().copied();
        let mut s = Sample {
            tick: it.next()? as u32,
            x_true: NO_TRUE_POSITION,
            ..Sample::default()
        };
        for bit in [1u8, 2, 4, 8, 16, 32, 64] {
            if mask & bit == 0 {
                continue;
            }
            let v = it.next()?;
            match bit {
                signal::X_REF => s.x_ref = v,
                signal::VOLTAGE => s.voltage = v,
                signal::FORCE => s.force = v,
                signal::X_EST => s.x_est = v,
                signal::STATUS => s.status = v as u8,
                signal::X_TRUE => s.x_true = v,
                _ => s.x_sensor = v,
            }
        }
        Some(s)
    }
}
