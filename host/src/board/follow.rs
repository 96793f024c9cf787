//! Following a board while it runs: the client, the recording read as it grows,
//! and waits on the board's state (what the scripted session and the loop
//! session share).

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use fpi_protocol::SourceKind;
use fpi_protocol::{Command, Status};
use piezo_fpi::control::Fault;

use super::budget::{Budget, LONGEST_PAUSE};
use super::client::Client;
use super::recording::Recording;

/// How long a wait may take before it is an error.
const PATIENCE: Duration = Duration::from_secs(180);

/// Fails on a latched fault other than *parked*, naming it.
pub fn no_fault(s: &Status, what: &str) -> Result<bool> {
    if let Some(f) = s.fault.filter(|f| f.code != Fault::Stopped as u8) {
        bail!(
            "fault {} ({}) at tick {} during {what}",
            f.code,
            Fault::from_code(f.code).map_or("?", |f| f.message()),
            f.at
        );
    }
    Ok(false)
}

/// What [`Follow::capture`] records (configuration).
#[derive(Debug, Clone, Copy)]
pub struct Capture<'a> {
    /// The action recorded, for errors ("the step").
    pub what: &'a str,
    /// Ticks per recorded sample.
    pub decimation: u16,
    /// The longest the recording runs, board time, s.
    pub seconds: f64,
    /// What to do where the link cannot carry it ("shorten --seconds").
    pub hint: &'a str,
}

/// A board being followed (state): its client and what it recorded so far.
pub struct Follow<'c> {
    /// The board's client.
    pub c: &'c mut Client,
    /// The recording so far.
    pub rec: Recording,
    /// Samples the board dropped in recordings restarted since.
    dropped_before: u32,
    /// The wait between two polls while the recorder runs at its decimation.
    pause: Duration,
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
            pause: LONGEST_PAUSE,
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

    /// (Re)starts the recorder at `decimation` (what it held is read first);
    /// the waits poll often enough that its ring does not overrun
    /// ([`Budget::pause`]).
    pub fn record(&mut self, decimation: u16) -> Result<()> {
        self.drain()?;
        self.dropped_before = self.rec.dropped;
        self.pause = Budget::new(self.c.hello(), self.rec.signals, decimation, 0.0).pause();
        self.c.ack(&Command::Record {
            axis: self.c.axis(),
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
            std::thread::sleep(self.pause);
        }
    }

    /// Records an action: starts the recorder, lets `go` start the action
    /// (it returns the tick the action starts on) and records until `done`
    /// says so for a status and that tick; the tick. The recording is
    /// `self.rec`, from a request before the action. Refused before the
    /// recorder starts where the link and the board's ring cannot hold
    /// `cap.seconds` (and the 5 ms a request and its reply may take); fails
    /// where the board dropped a sample of it.
    pub fn capture(
        &mut self,
        cap: &Capture<'_>,
        go: impl FnOnce(&mut Client) -> Result<u32>,
        done: impl Fn(&Status, u32) -> Result<bool>,
    ) -> Result<u32> {
        let budget = Budget::new(
            self.c.hello(),
            self.rec.signals,
            cap.decimation,
            cap.seconds + 0.005,
        );
        if !budget.fits() {
            // The caller's argument: a larger decimation (or less time) fits.
            return Err(super::commands::bad(
                "decimation",
                "--decimation",
                format!(
                    "{}'s recording would drop samples: {} ({})",
                    cap.what,
                    budget.describe(self.c.hello().rate_hz),
                    cap.hint
                ),
            ));
        }
        self.record(cap.decimation)?;
        self.rec.samples.clear();
        let from = go(self.c)?;
        self.until(&format!("the end of {}", cap.what), |s| done(s, from))?;
        self.c.ack(&Command::RecordStop)?;
        self.pause = LONGEST_PAUSE;
        self.drain()?;
        if self.rec.dropped > self.dropped_before {
            bail!(
                "the board dropped {} samples of {}'s recording: the link cannot keep up at \
                 decimation {} ({})",
                self.rec.dropped - self.dropped_before,
                cap.what,
                cap.decimation,
                cap.hint
            );
        }
        Ok(from)
    }

    /// Moves the reference to `um` and waits until it rests there, and 50 ms
    /// more (the loops settle); fails on a fault during `what`.
    pub fn rest_at(&mut self, um: f64, what: &str) -> Result<()> {
        self.c.move_to(um, 1000.0)?;
        let rest = self.until_rest(what)?;
        self.until_tick(rest + self.ticks(0.05))?;
        Ok(())
    }

    /// Waits until the reference holds again after `what`; its tick. Fails on
    /// a fault meanwhile.
    pub fn until_rest(&mut self, what: &str) -> Result<u32> {
        self.until(&format!("the end of {what}"), |s| {
            no_fault(s, what)?;
            Ok(s.source == SourceKind::Hold && !s.approaching)
        })
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
