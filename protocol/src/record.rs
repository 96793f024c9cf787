//! What a recording carries: the recorded signals' mask bits (in wire order),
//! the status bits of each sample, and a sample as the board keeps it.

use serde::{Deserialize, Serialize};

use crate::MAX_AXES;

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
    /// The reference governor departed from the source's reference this tick
    /// (it asked for more than the stage can do within its stroke).
    pub const GOVERNED: u8 = 128;
}

/// Bits of [`Sample::lines`]: the board's trigger lines after the tick.
pub mod lines {
    /// The trigger output is high.
    pub const TRIGGER_OUT: u8 = 1;
    /// The trigger input is high.
    pub const TRIGGER_IN: u8 = 2;
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
    /// The trigger lines ([`super::lines`] bits).
    pub const TRIGGER: u8 = 128;
    /// Every signal of a default recording: the positions, the voltage, the
    /// force and the status (the trigger lines are asked for by name).
    pub const ALL: u8 = 127;
    /// Every bit a recording may ask for.
    pub const ANY: u8 = 255;
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
    /// [`lines`] bits.
    pub lines: u8,
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
            (signal::TRIGGER, self.lines as i32),
        ];
        core::iter::once(self.tick as i32).chain(
            all.into_iter()
                .filter(move |(bit, _)| mask & bit != 0)
                .map(|(_, v)| v),
        )
    }

    /// The values of `self` for `mask` as the board sends them in a batch: each
    /// the difference (wrapping) from the same value of `prev`, the batch's
    /// previous sample ([`Sample::default`] before the first). Successive ticks
    /// and slowly moving signals then take one to three bytes each instead of
    /// three to five.
    pub fn deltas<'a>(&'a self, prev: &'a Sample, mask: u8) -> impl Iterator<Item = i32> + 'a {
        self.values(mask)
            .zip(prev.values(mask))
            .map(|(v, p)| v.wrapping_sub(p))
    }

    /// The sample whose [`Sample::deltas`] from `prev` for `mask` are `deltas`;
    /// `None` if `deltas` is too short.
    pub fn from_deltas(prev: &Sample, mask: u8, deltas: &[i32]) -> Option<Self> {
        let mut values = [0i32; 9];
        let width = Self::width(mask);
        let (values, deltas) = (values.get_mut(..width)?, deltas.get(..width)?);
        for ((v, d), p) in values.iter_mut().zip(deltas).zip(prev.values(mask)) {
            *v = p.wrapping_add(*d);
        }
        Self::from_values(mask, values)
    }

    /// The samples of a batch's values (see [`Sample::deltas`]), in order; a
    /// trailing partial sample is ignored.
    pub fn batch(mask: u8, deltas: &[i32]) -> impl Iterator<Item = Sample> + '_ {
        Self::interleaved(mask, 1, deltas)
    }

    /// The samples of a batch of `stride` interleaved axes' samples (a
    /// recording of every axis: each sample the difference from the one
    /// `stride` before, [`Packer::interleaved`]), in order.
    pub fn interleaved(mask: u8, stride: u8, deltas: &[i32]) -> impl Iterator<Item = Sample> + '_ {
        let stride = usize::from(stride.clamp(1, MAX_AXES));
        let mut prev = [Sample::default(); MAX_AXES as usize];
        let mut k = 0;
        deltas.chunks_exact(Self::width(mask)).filter_map(move |d| {
            let p = prev.get_mut(k)?;
            let s = Self::from_deltas(p, mask, d)?;
            *p = s;
            k = (k + 1) % stride;
            Some(s)
        })
    }

    /// Values per sample on the wire for `mask` (the tick included).
    pub fn width(mask: u8) -> usize {
        1 + mask.count_ones() as usize
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
        for bit in [1u8, 2, 4, 8, 16, 32, 64, 128] {
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
                signal::X_SENSOR => s.x_sensor = v,
                _ => s.lines = v as u8,
            }
        }
        Some(s)
    }
}

/// A batch's values being packed ([`Batch::values`](crate::Batch::values)):
/// samples as [`Sample::deltas`] from the one before, while they fit a batch
/// ([`MAX_BATCH_BYTES`](crate::MAX_BATCH_BYTES) on the wire,
/// [`MAX_VALUES`](crate::MAX_VALUES) values). The board packs its ring with it,
/// the host's hub the queues it keeps for its clients.
#[derive(Debug, Clone)]
pub struct Packer {
    signals: u8,
    values: heapless::Vec<i32, { crate::MAX_VALUES }>,
    bytes: usize,
    /// The last sample of each interleaved axis.
    prev: [Sample; MAX_AXES as usize],
    /// Axes interleaved.
    stride: usize,
    /// The axis of the next sample.
    next: usize,
}

impl Packer {
    /// Empty, for the signals `signals` (`signal` bits).
    pub fn new(signals: u8) -> Self {
        Self::interleaved(signals, 1)
    }

    /// Empty, for the signals `signals` of `stride` axes whose samples
    /// alternate (a recording of every axis): each sample packed as the
    /// difference from the one `stride` before, the same axis's, so that a
    /// slowly moving axis still takes a few bytes ([`Sample::interleaved`]
    /// reads it back).
    pub fn interleaved(signals: u8, stride: u8) -> Self {
        Self {
            signals,
            values: heapless::Vec::new(),
            bytes: 0,
            prev: [Sample::default(); MAX_AXES as usize],
            stride: usize::from(stride.clamp(1, MAX_AXES)),
            next: 0,
        }
    }

    /// Packs `s` if it fits the batch; whether it did (a sample that does not
    /// is left for the next batch).
    pub fn push(&mut self, s: &Sample) -> bool {
        let Some(prev) = self.prev.get(self.next).copied() else {
            return false;
        };
        let len: usize = s.deltas(&prev, self.signals).map(wire_len).sum();
        if self.bytes + len > crate::MAX_BATCH_BYTES
            || self.values.len() + Sample::width(self.signals) > crate::MAX_VALUES
        {
            return false;
        }
        for v in s.deltas(&prev, self.signals) {
            // Room for every value was checked above.
            let _ = self.values.push(v);
        }
        self.bytes += len;
        if let Some(p) = self.prev.get_mut(self.next) {
            *p = *s;
        }
        self.next = (self.next + 1) % self.stride;
        true
    }

    /// The signals it packs.
    pub const fn signals(&self) -> u8 {
        self.signals
    }

    /// The batch's values.
    pub fn values(self) -> heapless::Vec<i32, { crate::MAX_VALUES }> {
        self.values
    }
}

/// Bytes one value takes on the wire (postcard's zigzag varint: 7 bits a byte).
pub const fn wire_len(v: i32) -> usize {
    let z = ((v << 1) ^ (v >> 31)) as u32;
    match z {
        0..=0x7f => 1,
        0x80..=0x3fff => 2,
        0x4000..=0x1f_ffff => 3,
        0x20_0000..=0xfff_ffff => 4,
        _ => 5,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleaved_axes_pack_as_each_axis_s_differences_and_read_back() {
        // Two axes far apart, each moving slowly: X near 5 µm, Y near 35 µm.
        let samples: std::vec::Vec<Sample> = (0..40u32)
            .map(|k| Sample {
                tick: 100 + k / 2,
                x_ref: if k % 2 == 0 { 5 << 16 } else { 35 << 16 } + (k as i32) * 100,
                x_true: NO_TRUE_POSITION,
                ..Sample::default()
            })
            .collect();
        let mask = signal::X_REF;
        let (mut one, mut two) = (Packer::new(mask), Packer::interleaved(mask, 2));
        for s in &samples {
            assert!(one.push(s) && two.push(s));
        }
        let (one, two) = (one.values(), two.values());
        let bytes = |v: &[i32]| v.iter().map(|&x| wire_len(x)).sum::<usize>();
        assert!(
            bytes(&two) * 3 < bytes(&one) * 2,
            "{} vs {}",
            bytes(&two),
            bytes(&one)
        );
        let back: std::vec::Vec<Sample> = Sample::interleaved(mask, 2, &two).collect();
        assert_eq!(back, samples);
    }

    #[test]
    fn deltas_round_trip_whatever_the_mask_and_wrap() {
        let a = Sample {
            tick: u32::MAX - 1,
            x_ref: i32::MAX,
            voltage: -5,
            force: i32::MIN,
            x_est: 7,
            x_true: 9,
            x_sensor: -11,
            status: 255,
            lines: 1,
        };
        let b = Sample {
            tick: 3,
            x_ref: i32::MIN,
            voltage: 6,
            force: i32::MAX,
            x_est: -8,
            x_true: 10,
            x_sensor: 12,
            status: 1,
            lines: 0,
        };
        for mask in 0..=signal::ANY {
            let mut values = Vec::new();
            let mut prev = Sample::default();
            for s in [a, b, a] {
                values.extend(s.deltas(&prev, mask));
                prev = s;
            }
            let back: Vec<Sample> = Sample::batch(mask, &values).collect();
            let want = |s: &Sample| Sample::from_values(mask, &s.values(mask).collect::<Vec<_>>());
            assert_eq!(back.len(), 3);
            for (got, s) in back.iter().zip([a, b, a]) {
                assert_eq!(Some(*got), want(&s), "mask {mask}");
            }
        }
    }

    #[test]
    fn wire_len_is_postcards() {
        for v in [
            0,
            1,
            -1,
            63,
            -64,
            64,
            -65,
            8191,
            -8192,
            8192,
            1 << 20,
            -(1 << 20),
            (1 << 20) + 5,
            1 << 27,
            i32::MAX,
            i32::MIN,
        ] {
            let mut buf = [0u8; 8];
            let n = postcard::to_slice(&v, &mut buf).unwrap().len();
            assert_eq!(wire_len(v), n, "{v}");
        }
    }
}
