//! The data recorder: what the control loop did, tick by tick, in a RAM ring.
//!
//! The ISR offers every tick's [`Sample`]; while recording, one in every
//! `decimation` is kept. The link task takes them out in batches and sends the
//! signals the host chose. When the ring is full (the host reads too slowly)
//! new samples are dropped and counted — never overwritten silently — and the
//! count travels with every batch.
//!
//! Values are the core's raw fixed-point bits (`I16F16`: µm, V, N), so a recording
//! carries exactly what the loop computed.

pub use fpi_protocol::record::{lines, signal, status, wire_len, Packer, Sample, NO_TRUE_POSITION};

/// The recorder: its ring (state) and settings.
#[derive(Debug, Clone)]
pub struct Recorder<const N: usize> {
    buf: [Sample; N],
    head: u32,
    tail: u32,
    active: bool,
    decimation: u16,
    countdown: u16,
    dropped: u32,
    kept: u32,
}

impl<const N: usize> Default for Recorder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Recorder<N> {
    const MASK: u32 = {
        assert!(N.is_power_of_two());
        N as u32 - 1
    };

    /// Idle and empty (all zero: a static recorder costs no flash).
    pub const fn new() -> Self {
        Self {
            buf: [Sample {
                tick: 0,
                x_ref: 0,
                voltage: 0,
                force: 0,
                x_est: 0,
                x_true: 0,
                x_sensor: 0,
                status: 0,
                lines: 0,
            }; N],
            head: 0,
            tail: 0,
            active: false,
            decimation: 0,
            countdown: 0,
            dropped: 0,
            kept: 0,
        }
    }

    /// Starts a recording of every `decimation`-th tick (0 reads as 1), from the
    /// next tick on; the ring and the counters start empty.
    pub fn start(&mut self, decimation: u16) {
        // Field by field: a whole new recorder would be built on the stack first.
        self.head = 0;
        self.tail = 0;
        self.active = true;
        self.decimation = decimation.max(1);
        self.countdown = 0;
        self.dropped = 0;
        self.kept = 0;
    }

    /// Stops recording; what is in the ring can still be read.
    pub fn stop(&mut self) {
        self.active = false;
    }

    /// The ISR's side: keeps `s` if it is a recorded tick, counting it as dropped
    /// if the ring is full.
    #[inline]
    pub fn offer(&mut self, s: &Sample) {
        if !self.kept_tick() {
            return;
        }
        if self.tail.wrapping_sub(self.head) >= N as u32 {
            self.dropped = self.dropped.wrapping_add(1);
            return;
        }
        if let Some(slot) = self.buf.get_mut((self.tail & Self::MASK) as usize) {
            *slot = *s;
        }
        self.tail = self.tail.wrapping_add(1);
        self.kept = self.kept.wrapping_add(1);
    }

    /// The ISR's side for a tick of several axes: keeps `samples` (one per
    /// axis, in axis order) if it is a recorded tick, all of them or, the
    /// ring without room for all, none (each counted as dropped): a
    /// recording's ticks stay whole.
    #[inline]
    pub fn offer_all(&mut self, samples: &[Sample]) {
        if !self.kept_tick() {
            return;
        }
        let n = samples.len() as u32;
        if self.tail.wrapping_sub(self.head).saturating_add(n) > N as u32 {
            self.dropped = self.dropped.wrapping_add(n);
            return;
        }
        for s in samples {
            if let Some(slot) = self.buf.get_mut((self.tail & Self::MASK) as usize) {
                *slot = *s;
            }
            self.tail = self.tail.wrapping_add(1);
        }
        self.kept = self.kept.wrapping_add(1);
    }

    /// Whether this tick is one a recording keeps (one in every
    /// `decimation` while recording), counted.
    #[inline]
    fn kept_tick(&mut self) -> bool {
        if !self.active {
            return false;
        }
        if self.countdown > 0 {
            self.countdown -= 1;
            return false;
        }
        self.countdown = self.decimation - 1;
        true
    }

    /// The oldest sample, left in the ring.
    pub fn peek(&self) -> Option<Sample> {
        if self.head == self.tail {
            return None;
        }
        self.buf.get((self.head & Self::MASK) as usize).copied()
    }

    /// The link task's side: the oldest sample, removed.
    pub fn take(&mut self) -> Option<Sample> {
        if self.head == self.tail {
            return None;
        }
        let s = self.buf.get((self.head & Self::MASK) as usize).copied();
        self.head = self.head.wrapping_add(1);
        s
    }

    /// Samples waiting to be read.
    pub const fn len(&self) -> usize {
        self.tail.wrapping_sub(self.head) as usize
    }

    /// No sample waiting.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Recording now.
    pub const fn active(&self) -> bool {
        self.active
    }

    /// Ticks kept since the recording started.
    pub const fn kept(&self) -> u32 {
        self.kept
    }

    /// Recorded ticks lost because the ring was full.
    pub const fn dropped(&self) -> u32 {
        self.dropped
    }

    /// The decimation in use (0 before the first recording).
    pub const fn decimation(&self) -> u16 {
        self.decimation
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(tick: u32) -> Sample {
        Sample {
            tick,
            x_ref: tick as i32 * 3,
            ..Sample::default()
        }
    }

    #[test]
    fn keeps_every_decimated_tick_and_counts_what_it_drops() {
        let mut r = Recorder::<8>::new();
        r.offer(&sample(0));
        assert!(r.is_empty(), "idle until started");
        r.start(3);
        for t in 0..30 {
            r.offer(&sample(t));
        }
        // Ticks 0, 3, …, 27 are recorded: 10, of which 8 fit.
        assert_eq!((r.kept(), r.dropped(), r.len()), (8, 2, 8));
        let ticks: Vec<u32> = core::iter::from_fn(|| r.take()).map(|s| s.tick).collect();
        assert_eq!(ticks, [0, 3, 6, 9, 12, 15, 18, 21]);
        r.offer(&sample(30));
        assert_eq!(r.take().map(|s| s.tick), Some(30));
        r.stop();
        r.offer(&sample(33));
        assert!(r.is_empty());
    }

    #[test]
    fn wire_values_round_trip_for_any_mask() {
        let s = Sample {
            tick: 77,
            x_ref: 1,
            voltage: -2,
            force: 3,
            x_est: 4,
            x_true: 5,
            x_sensor: 7,
            status: 6,
            lines: 1,
        };
        for mask in 0..=signal::ANY {
            let v: Vec<i32> = s.values(mask).collect();
            assert_eq!(v.len(), Sample::width(mask));
            let back = Sample::from_values(mask, &v).unwrap();
            let want = Sample::from_values(mask, &s.values(mask).collect::<Vec<_>>()).unwrap();
            assert_eq!(back, want);
            if mask == signal::ANY {
                assert_eq!(back, s);
            }
        }
        assert_eq!(Sample::from_values(signal::ALL, &[1, 2]), None);
    }
}
