//! Whether a recording fits the link: what `fpi board record` says before it
//! starts. A board keeps the recorded samples in a RAM ring and sends them as the
//! host reads them; a recording faster than the link carries fills the ring and
//! the rest is dropped (the emulated board paces its link so it drops the same).
//!
//! The estimate of a sample's size is deliberately generous: recorded values
//! travel as differences from the previous sample (`fpi_protocol::record`), one
//! byte for the tick at a decimation below 64, one for the status, and at most
//! three for each other signal while it moves less than 16 µm (16 V, 16 N) between
//! two samples; a batch adds its header, CRC and framing, and each read its request.

use std::time::Duration;

use fpi_protocol::record::{signal, wire_len};
use fpi_protocol::{Hello, LinkKind};

/// Bytes a moving signal's difference takes at most in the estimate.
const SIGNAL_BYTES: f64 = 3.0;
/// Bytes a batch adds (reply header, batch fields, CRC, COBS, delimiter).
const BATCH_BYTES: f64 = 24.0;
/// The longest the host waits between two polls of a board (and two reads of
/// a recording).
pub const LONGEST_PAUSE: Duration = Duration::from_millis(20);
/// The share of the link a recording may plan to use.
const HEADROOM: f64 = 0.9;

/// A recording's demand on the link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    /// The link.
    pub link: LinkKind,
    /// Samples per second asked for.
    pub samples_per_s: f64,
    /// Estimated bytes per sample on the link.
    pub bytes_per_sample: f64,
    /// Samples asked for in all.
    pub samples: f64,
    /// The board's ring, samples.
    pub ring: u32,
}

impl Budget {
    /// The demand of recording `signals` at `decimation` for `seconds` on the
    /// board that said `hello`.
    pub fn new(hello: &Hello, signals: u8, decimation: u16, seconds: f64) -> Self {
        // The status and the trigger lines change seldom: a byte each.
        let bits = signal::STATUS | signal::TRIGGER;
        let others = (signals & !bits).count_ones() as f64;
        let status = (signals & bits).count_ones() as f64;
        let tick = wire_len(i32::from(decimation.max(1))) as f64;
        let samples_per_s = f64::from(hello.rate_hz) / f64::from(decimation.max(1));
        Self {
            link: hello.link,
            samples_per_s,
            bytes_per_sample: tick + status + SIGNAL_BYTES * others,
            samples: samples_per_s * seconds,
            ring: hello.buffers[0],
        }
    }

    /// The demand of the same recording of `n` axes at once (a sample per
    /// axis of each kept tick).
    pub fn of_axes(self, n: u8) -> Self {
        let n = f64::from(n.max(1));
        Self {
            samples_per_s: self.samples_per_s * n,
            samples: self.samples * n,
            ..self
        }
    }

    /// How long the host waits between two reads while the recording runs:
    /// 20 ms, or a quarter of the time the board's ring takes to fill at this
    /// rate (6.4 ms for the 512-sample ring at every tick at 20 kHz), so that a
    /// late wake-up of the host's thread does not overrun the ring.
    pub fn pause(&self) -> Duration {
        let ring_s = f64::from(self.ring) / self.samples_per_s;
        Duration::from_secs_f64(ring_s / 4.0).min(LONGEST_PAUSE)
    }

    /// Bytes per second the recording needs, framing and reads included.
    pub fn needed(&self) -> f64 {
        self.samples_per_s * self.bytes_per_sample + BATCH_BYTES / self.pause().as_secs_f64()
    }

    /// Bytes per second the link carries.
    pub fn carried(&self) -> f64 {
        f64::from(self.link.bytes_per_s())
    }

    /// Whether every sample should arrive: the link keeps up, or the ring holds
    /// the whole recording.
    pub fn fits(&self) -> bool {
        self.needed() <= HEADROOM * self.carried() || self.samples <= f64::from(self.ring)
    }

    /// What is wrong with a recording that runs until stopped (a live one: the
    /// ring no help), or `None` where the link carries it for ever: "the stream
    /// needs about … kB/s, more than the … link carries (… kB/s)".
    pub fn beyond_the_link(&self) -> Option<String> {
        (self.needed() > self.carried()).then(|| {
            format!(
                "the stream needs about {:.0} kB/s, more than the {} link carries ({:.0} kB/s)",
                self.needed() / 1e3,
                self.link.name(),
                self.carried() / 1e3
            )
        })
    }

    /// The fewest ticks between samples at which the board that said `hello`
    /// streams `signals` for ever (1 where it streams every tick).
    pub fn continuous_decimation(hello: &Hello, signals: u8) -> u16 {
        (1..=u16::MAX)
            .find(|&d| {
                Self::new(hello, signals, d, 1.0)
                    .beyond_the_link()
                    .is_none()
            })
            .unwrap_or(u16::MAX)
    }

    /// The smallest decimation at which the link keeps up.
    pub fn decimation_that_fits(&self, rate_hz: u32) -> u16 {
        (1..=u16::MAX)
            .find(|&d| {
                let b = Self {
                    samples_per_s: f64::from(rate_hz) / f64::from(d),
                    ..*self
                };
                b.needed() <= HEADROOM * b.carried()
            })
            .unwrap_or(u16::MAX)
    }

    /// One line for the user: the demand against the link, and what to do if it
    /// does not fit.
    pub fn describe(&self, rate_hz: u32) -> String {
        let head = format!(
            "link: {} ({:.0} kB/s); this recording: {:.0} samples/s × ~{:.0} B ≈ {:.1} kB/s",
            self.link.name(),
            self.carried() / 1e3,
            self.samples_per_s,
            self.bytes_per_sample,
            self.needed() / 1e3
        );
        if self.fits() {
            format!("{head}: fits")
        } else {
            format!(
                "{head}: MORE THAN THE LINK CARRIES — the board's ring ({} samples) fills and \
                 the rest is dropped; --decimation {} or more fits{}",
                self.ring,
                self.decimation_that_fits(rate_hz),
                match self.link {
                    LinkKind::Uart => ", or use the USB link",
                    LinkKind::Usb => "",
                }
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpi_protocol::{BoardKind, ResetReason};

    fn hello(link: LinkKind) -> Hello {
        Hello {
            protocol: fpi_protocol::VERSION,
            firmware: Default::default(),
            board: BoardKind::Emulated,
            rate_hz: 20_000,
            capacity: [0; 4],
            buffers: [512, 1024],
            limits: [0; 5],
            reset: ResetReason::PowerOn,
            link,
            axes: 1,
            front_end: fpi_protocol::FrontEndKind::Internal,
        }
    }

    #[test]
    fn every_tick_fits_usb_and_not_the_uart() {
        let usb = Budget::new(&hello(LinkKind::Usb), signal::ALL, 1, 2.0);
        assert!(usb.fits(), "{}", usb.describe(20_000));
        let uart = Budget::new(&hello(LinkKind::Uart), signal::ALL, 1, 2.0);
        assert!(!uart.fits());
        let d = uart.decimation_that_fits(20_000);
        // 20 000 / d samples/s × 20 B + 1.2 kB/s ≤ 10.4 kB/s: d ≥ 44.
        assert_eq!(d, 44);
        assert!(Budget::new(&hello(LinkKind::Uart), signal::ALL, d, 2.0).fits());
        assert!(!Budget::new(&hello(LinkKind::Uart), signal::ALL, d - 1, 2.0).fits());
        assert!(uart.describe(20_000).contains("--decimation 44"));
    }

    #[test]
    fn the_host_reads_four_times_while_the_ring_fills() {
        let every_tick = Budget::new(&hello(LinkKind::Usb), signal::ALL, 1, 2.0);
        assert_eq!(every_tick.pause(), Duration::from_micros(6400));
        let slow = Budget::new(&hello(LinkKind::Uart), signal::ALL, 44, 2.0);
        assert_eq!(slow.pause(), Duration::from_millis(20));
    }

    #[test]
    fn a_recording_the_ring_holds_fits_any_link() {
        // 400 samples at every tick: 20 ms, held by the 512-sample ring.
        let b = Budget::new(&hello(LinkKind::Uart), signal::ALL, 1, 0.02);
        assert!(b.fits());
    }
}
