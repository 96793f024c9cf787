//! Following a board while it runs: the client, the recording read as it grows,
//! and waits on the board's state (what the scripted session and the loop
//! session share).

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use fpi_protocol::SourceKind;
use fpi_protocol::{Command, Status};

use super::client::Client;
use super::recording::Recording;

/// How long a wait may take before it is an error.
const PATIENCE: Duration = Duration::from_secs(180);

/// A board being followed (state): its client and what it recorded so far.
pub struct Follow<'c> {
    /// The board's client.
    pub c: &'c mut Client,
    /// The recording so far.
    pub rec: Recording,
    /// Samples the board dropped in recordings restarted since.
    dropped_before: u32,
}

impl<'c> Follow<'c> {
    /// Follows `c`, recording `signals` (the recorder is not started).
    pub fn new(c: &'c mut Client, signals: u8) -> Self {
        let rate_hz = c.rate_hz();
        Self {
            c,
            rec: Recording {
                rate_hz,
                signals,
                ..Recording::default()
            },
            dropped_before: 0,
        }
    }

    /// The board's control rate, Hz.
    pub fn rate(&self) -> f64 {
        self.rec.rate_hz
    }

    /// Ticks in `seconds`.
    pub fn ticks(&self, seconds: f64) -> u32 {
        (seconds * self.rate()).round() as u32
    }

    /// Reads the recorder.
    pub fn drain(&mut self) -> Result<()> {
        let (s, dropped) = self.c.drain()?;
        self.rec.samples.extend(s);
        self.rec.dropped = self.dropped_before + dropped;
        Ok(())
    }

    /// (Re)starts the recorder at `decimation` (what it held is read first).
    pub fn record(&mut self, decimation: u16) -> Result<()> {
        self.drain()?;
        self.dropped_before = self.rec.dropped;
        self.c.ack(&Command::Record {
            decimation,
            signals: self.rec.signals,
        })?;
        Ok(())
    }

    /// Waits (reading the recorder) until `done` says so for the status, or
    /// fails with its error; the tick it saw.
    pub fn until(&mut self, what: &str, done: impl Fn(&Status) -> Result<bool>) -> Result<u32> {
        let start = Instant::now();
        loop {
            self.drain()?;
            let s = self.c.status()?;
            if done(&s)? {
                return Ok(s.tick);
            }
            if start.elapsed() > PATIENCE {
                bail!(
                    "the board did not reach {what} within {} s",
                    PATIENCE.as_secs()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits until tick `t` has passed.
    pub fn until_tick(&mut self, t: u32) -> Result<u32> {
        self.until(&format!("tick {t}"), |s| Ok(s.tick >= t))
    }

    /// Waits until the source is `hold` again; its tick.
    pub fn until_hold(&mut self) -> Result<u32> {
        self.until("rest", |s| {
            Ok(s.source == SourceKind::Hold && !s.approaching)
        })
    }
}
