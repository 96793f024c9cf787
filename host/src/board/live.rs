//! A recording that runs while other commands do: the board's recorder read
//! continuously, for as long as asked, by a thread of its own that shares the
//! client with the caller's commands (it takes the link for one read at a time,
//! between them). PI's data recorder as a lab uses it: arm the recorder
//! ([`Live::start`]), start a motion, read what came meanwhile ([`Live::read`],
//! in blocks numbered one after the other), stop ([`Live::stop`]: the whole
//! recording). A recording armed before a wave starts has the wave from its
//! first tick.
//!
//! **Nothing is lost silently.** Each sample carries its tick, so the reader
//! checks that every sample follows the one before by the decimation: a sample
//! that does not marks a gap, and the gaps, the samples they miss and the
//! board's own count of the samples its ring dropped (the link could not keep
//! up, or a command held the link too long) travel with every block.
//!
//! While it runs, the commands that use the recorder themselves (`record`,
//! `step`, `frf`, `autotune`, a motion's own recording) must wait: the caller
//! refuses them (the Python package does, naming the recording).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{anyhow, bail, Result};
use fpi_firmware::control::recorder::Sample;
use fpi_protocol::{Batch, Command};

use super::budget::Budget;
use super::client::Client;
use super::commands::BadArgument;
use super::recording::Recording;

/// A client shared between a live recording's reader and the caller's
/// commands: each takes it for one request (or one command) at a time.
pub trait SharedClient: Send + Sync {
    /// Runs `f` on the client once no command holds it.
    fn with_client(&self, f: &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<()>;
}

impl SharedClient for Mutex<Client> {
    fn with_client(&self, f: &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<()> {
        let mut c = self
            .lock()
            .map_err(|_| anyhow!("the link failed in another thread"))?;
        f(&mut c)
    }
}

/// A client that can be closed (`None`): the Python package's board.
impl SharedClient for Mutex<Option<Client>> {
    fn with_client(&self, f: &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<()> {
        let mut c = self
            .lock()
            .map_err(|_| anyhow!("the link failed in another thread"))?;
        match c.as_mut() {
            Some(c) => f(c),
            None => bail!("the link is closed"),
        }
    }
}

/// What came since the last read, and the stream's counts so far.
#[derive(Debug, Clone, Default)]
pub struct Block {
    /// The block's number: 0 for the first read, then one more each read.
    pub seq: u64,
    /// The samples, in tick order.
    pub samples: Vec<Sample>,
    /// The stream's counts after this block.
    pub counts: Counts,
}

/// A live recording's counts so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Samples received.
    pub samples: u64,
    /// Batches read from the board.
    pub batches: u64,
    /// Places where a sample did not follow the one before by the decimation.
    pub gaps: u32,
    /// Samples those gaps miss.
    pub missing: u64,
    /// Samples the board's ring dropped (its own count).
    pub dropped: u32,
}

impl Counts {
    /// Nothing was lost.
    pub fn whole(&self) -> bool {
        self.gaps == 0 && self.missing == 0 && self.dropped == 0
    }

    /// What was lost, in words ("" where nothing was).
    pub fn losses(&self) -> String {
        if self.whole() {
            return String::new();
        }
        format!(
            "{} gaps missing {} samples, {} dropped by the board's ring (the link could not \
             keep up, or a command held it): raise the decimation, or read more often",
            self.gaps, self.missing, self.dropped
        )
    }
}

/// The stream as the reader leaves it.
#[derive(Debug, Default)]
struct Stream {
    /// Received and not yet read.
    fresh: Vec<Sample>,
    /// Every sample received (where the whole recording is kept).
    kept: Vec<Sample>,
    keep: bool,
    decimation: u32,
    last_tick: Option<u32>,
    counts: Counts,
    blocks: u64,
    /// Why the reader stopped, if it failed.
    failed: Option<String>,
    /// The board's tick at the reply to the latest read.
    board_tick: Option<u32>,
}

impl Stream {
    /// Takes a batch's samples, checking each follows the one before.
    fn take(&mut self, samples: impl Iterator<Item = Sample>, dropped: u32) {
        for s in samples {
            if let Some(t) = self.last_tick {
                let step = s.tick.wrapping_sub(t);
                if step != self.decimation {
                    self.counts.gaps += 1;
                    let missed = (step / self.decimation.max(1)).saturating_sub(1);
                    self.counts.missing += u64::from(missed.max(1));
                }
            }
            self.last_tick = Some(s.tick);
            self.counts.samples += 1;
            if self.keep {
                self.kept.push(s);
            }
            self.fresh.push(s);
        }
        self.counts.dropped = self.counts.dropped.max(dropped);
    }

    fn batch(&mut self, b: &Batch) {
        self.counts.batches += 1;
        self.take(Sample::batch(b.signals, &b.values), b.dropped);
    }
}

/// A recording read continuously (see the module docs).
pub struct Live {
    link: Arc<dyn SharedClient>,
    stream: Arc<Mutex<Stream>>,
    halt: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
    /// The tick the board took the recording's start on (its first sample is
    /// the next one).
    pub start: u32,
    /// The board's control rate, Hz.
    pub rate_hz: f64,
    /// The signals recorded (`signal` bits).
    pub signals: u8,
    /// Ticks between samples.
    pub decimation: u16,
}

impl Live {
    /// Arms the board's recorder for `signals` (`signal` bits, `signal::ALL`
    /// for every one) at every `decimation`-th tick and starts reading it.
    /// `keep`: the whole recording is kept for [`Self::stop`] (32 bytes a
    /// sample); else only what [`Self::read`] has not taken. Refused before
    /// anything is sent where the decimation is 0, no signal is named, or the
    /// link cannot carry the stream.
    pub fn start(
        link: Arc<dyn SharedClient>,
        signals: u8,
        decimation: u16,
        keep: bool,
    ) -> Result<Self> {
        if decimation == 0 {
            return Err(bad(
                "decimation",
                "--decimation",
                "--decimation 0: keep one tick in 1 or more",
            ));
        }
        if signals == 0 {
            return Err(bad(
                "signals",
                "--signals",
                "--signals: name at least one signal to record",
            ));
        }
        let mut armed = None;
        link.with_client(&mut |c| {
            let budget = Budget::new(c.hello(), signals, decimation, 1.0);
            if let Some(why) = budget.beyond_the_link() {
                return Err(bad(
                    "decimation",
                    "--decimation",
                    &format!(
                        "--decimation {decimation}: {why}: raise the decimation or record fewer \
                         signals"
                    ),
                ));
            }
            let start = c.ack(&Command::Record {
                axis: c.axis(),
                decimation,
                signals,
            })?;
            armed = Some((start, c.rate_hz(), budget.pause()));
            Ok(())
        })?;
        let (start, rate_hz, pause) = armed.ok_or_else(|| anyhow!("the recorder was not armed"))?;
        let stream = Arc::new(Mutex::new(Stream {
            keep,
            decimation: u32::from(decimation),
            ..Stream::default()
        }));
        let halt = Arc::new(AtomicBool::new(false));
        let reader = {
            let (link, stream, halt) = (link.clone(), stream.clone(), halt.clone());
            std::thread::Builder::new()
                .name("fpi-live-recording".into())
                .spawn(move || read_on(&*link, &stream, &halt, pause))?
        };
        Ok(Self {
            link,
            stream,
            halt,
            reader: Some(reader),
            start,
            rate_hz,
            signals,
            decimation,
        })
    }

    /// What came since the last read (an empty block where nothing did), with
    /// the counts so far. An error where the reader stopped (the link failed).
    pub fn read(&self) -> Result<Block> {
        let mut s = lock(&self.stream)?;
        if let Some(why) = &s.failed {
            bail!("the live recording stopped: {why}");
        }
        let seq = s.blocks;
        s.blocks += 1;
        Ok(Block {
            seq,
            samples: std::mem::take(&mut s.fresh),
            counts: s.counts,
        })
    }

    /// The counts so far.
    pub fn counts(&self) -> Counts {
        lock(&self.stream).map(|s| s.counts).unwrap_or_default()
    }

    /// The board's tick at the reply to the reader's latest read (at most one
    /// pause old, [`Budget::pause`]); `None` before the first.
    pub fn board_tick(&self) -> Option<u32> {
        lock(&self.stream).ok().and_then(|s| s.board_tick)
    }

    /// Whether the reader still runs.
    pub fn running(&self) -> bool {
        self.reader.as_ref().is_some_and(|r| !r.is_finished())
    }

    /// Stops the recorder and reads what it still holds: the whole recording
    /// (where it was kept), else what [`Self::read`] had not taken; its
    /// `dropped` counts every loss (gaps and the ring's drops).
    pub fn stop(mut self) -> Result<(Recording, Counts)> {
        self.halt_reader();
        let stream = self.stream.clone();
        self.link.with_client(&mut |c| {
            c.ack(&Command::RecordStop)?;
            let (samples, dropped) = c.drain()?;
            lock(&stream)?.take(samples.into_iter(), dropped);
            Ok(())
        })?;
        let mut s = lock(&self.stream)?;
        let samples = if s.keep {
            std::mem::take(&mut s.kept)
        } else {
            std::mem::take(&mut s.fresh)
        };
        let counts = s.counts;
        let lost = counts.missing.min(u64::from(u32::MAX)) as u32;
        Ok((
            Recording {
                rate_hz: self.rate_hz,
                signals: self.signals,
                samples,
                dropped: counts.dropped.max(lost),
            },
            counts,
        ))
    }

    fn halt_reader(&mut self) {
        self.halt.store(true, Ordering::Relaxed);
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }
}

/// Dropped without [`Live::stop`]: the reader ends and the recorder is
/// stopped (what it held is left unread).
impl Drop for Live {
    fn drop(&mut self) {
        if self.reader.is_some() {
            self.halt_reader();
            let _ = self
                .link
                .with_client(&mut |c| c.ack(&Command::RecordStop).map(|_| ()));
        }
    }
}

/// A recording on this thread for as long as `stop` says no (asked between
/// reads): the recorder armed for `signals` every `decimation`-th tick, each
/// batch handed to `sink` as it comes (its samples checked as [`Live`] checks
/// them), the recorder stopped and its last samples handed over however it
/// ends. The tick it was armed on, and the counts. For a caller that keeps the
/// link to itself meanwhile (`fpi board record` without `--seconds`).
pub fn follow(
    c: &mut Client,
    signals: u8,
    decimation: u16,
    mut sink: impl FnMut(&[Sample]) -> Result<()>,
    mut stop: impl FnMut() -> bool,
) -> Result<(u32, Counts)> {
    if decimation == 0 {
        return Err(bad(
            "decimation",
            "--decimation",
            "--decimation 0: keep one tick in 1 or more",
        ));
    }
    let pause = Budget::new(c.hello(), signals, decimation, 1.0).pause();
    let start = c.ack(&Command::Record {
        axis: c.axis(),
        decimation,
        signals,
    })?;
    let mut s = Stream {
        decimation: u32::from(decimation),
        ..Stream::default()
    };
    let mut run = || -> Result<()> {
        while !stop() {
            let b = c.read_batch()?;
            s.batch(&b);
            sink(&std::mem::take(&mut s.fresh))?;
            if b.waiting == 0 {
                std::thread::sleep(pause);
            }
        }
        Ok(())
    };
    let ran = run();
    let stopped = c.ack(&Command::RecordStop).and_then(|_| c.drain());
    ran?;
    let (samples, dropped) = stopped?;
    s.take(samples.into_iter(), dropped);
    sink(&s.fresh)?;
    Ok((start, s.counts))
}

/// The reader: a batch at a time while samples wait, pausing (a quarter of
/// the ring's time, at most 20 ms) when none do; ends at `halt` or when the
/// link fails (the reason kept for [`Live::read`]).
fn read_on(link: &dyn SharedClient, stream: &Mutex<Stream>, halt: &AtomicBool, pause: Duration) {
    const SLICE: Duration = Duration::from_millis(2);
    while !halt.load(Ordering::Relaxed) {
        let mut waiting = 0;
        let r = link.with_client(&mut |c| {
            let (tick, b) = c.read_batch_at()?;
            waiting = b.waiting;
            let mut s = lock(stream)?;
            s.board_tick = Some(tick);
            s.batch(&b);
            Ok(())
        });
        if let Err(e) = r {
            if let Ok(mut s) = stream.lock() {
                s.failed = Some(format!("{e:#}"));
            }
            return;
        }
        if waiting == 0 {
            let mut slept = Duration::ZERO;
            while slept < pause && !halt.load(Ordering::Relaxed) {
                std::thread::sleep(SLICE);
                slept += SLICE;
            }
        }
    }
}

fn lock(s: &Mutex<Stream>) -> Result<MutexGuard<'_, Stream>> {
    s.lock()
        .map_err(|_| anyhow!("the live recording's reader failed"))
}

fn bad(name: &'static str, cli: &'static str, message: &str) -> anyhow::Error {
    BadArgument {
        name,
        cli,
        message: message.to_string(),
    }
    .into()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(tick: u32) -> Sample {
        Sample {
            tick,
            ..Sample::default()
        }
    }

    #[test]
    fn a_gap_is_counted_with_the_samples_it_misses() {
        let mut s = Stream {
            decimation: 2,
            keep: true,
            ..Stream::default()
        };
        s.take([10, 12, 14, 20, 22].into_iter().map(sample), 0);
        assert_eq!(s.counts.gaps, 1);
        assert_eq!(s.counts.missing, 2);
        assert_eq!(s.counts.samples, 5);
        assert!(!s.counts.whole());
        s.take([24].into_iter().map(sample), 3);
        assert_eq!((s.counts.gaps, s.counts.dropped), (1, 3));
        assert!(s
            .counts
            .losses()
            .contains("1 gaps missing 2 samples, 3 dropped"));
    }

    #[test]
    fn a_stream_that_follows_the_decimation_is_whole() {
        let mut s = Stream {
            decimation: 1,
            ..Stream::default()
        };
        s.take((100..200).map(sample), 0);
        assert!(s.counts.whole());
        assert_eq!(s.counts.losses(), "");
        assert_eq!(s.fresh.len(), 100);
        assert!(s.kept.is_empty());
    }
}
