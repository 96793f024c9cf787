//! The hub's recorder, shared ([`super::hub`]): every client that arms the
//! recorder gets a recording of its own — its decimation, its signals, its
//! queue — cut from one live recording of the board ([`super::live`]) at the
//! finest decimation any of them asked (their greatest common divisor) with
//! the signals any of them asked, so that a scope, the CLI and a script can
//! each record the stage at once.
//!
//! A client's `Record`, `RecordStop` and `ReadRecord` are answered here, as
//! the board answers them: a recording starts after the tick it was armed on,
//! keeps one sample every `decimation` ticks, and is read in batches; a
//! stopped recording can still be read. A client that arms a finer
//! decimation or a signal the others did not restarts the board's recording:
//! the others' next sample may then fall off their grid, which their tick
//! numbers show. A read's reply carries the board's tick at the hub's latest
//! read of the board (not a ping of its own: the link's time goes to the
//! samples).
//! Nothing is lost silently: a batch's `dropped` counts what the board's ring
//! dropped and the samples a client's queue could not keep (a client that does
//! not read for [`QUEUE`] samples).

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use anyhow::Result;
use fpi_protocol::record::{Packer, Sample};
use fpi_protocol::{Batch, Command, Reply};
use heapless::Vec as HVec;

use super::client::Client;
use super::live::{Live, SharedClient};

/// The most samples a client's queue keeps unread.
pub const QUEUE: usize = 1 << 18;

/// One client's recording.
#[derive(Debug)]
struct Watch {
    decimation: u32,
    signals: u8,
    active: bool,
    /// The tick of the next sample it keeps.
    next: u32,
    queue: VecDeque<Sample>,
    /// Samples its queue could not keep.
    overflow: u32,
}

/// The recordings of the hub's clients, and the board's live recording they
/// are cut from.
pub struct Fanout {
    link: Arc<dyn SharedClient>,
    live: Option<Live>,
    watches: BTreeMap<u32, Watch>,
    /// What the board's recording lost before the live one now running.
    lost_before: u32,
}

impl Fanout {
    /// No recording yet, over the board's client `link`.
    pub fn new(link: Arc<dyn SharedClient>) -> Self {
        Self {
            link,
            live: None,
            watches: BTreeMap::new(),
            lost_before: 0,
        }
    }

    /// Client `id`'s command `cmd` (`Record`, `RecordStop` or `ReadRecord`;
    /// `None` for any other), answered: the reply's tick and the reply.
    pub fn answer(&mut self, id: u32, cmd: &Command<'_>) -> Option<Result<(u32, Reply)>> {
        Some(match *cmd {
            Command::Record { axis, .. } if axis != 0 => Err(anyhow::anyhow!(
                "the hub shares recordings of axis x only: record axis {} on a link of its own",
                super::client::axis_name(axis)
            )),
            Command::Record {
                decimation,
                signals,
                ..
            } => self.arm(id, decimation, signals).map(|t| (t, Reply::Ack)),
            Command::RecordStop => self.stop(id).map(|t| (t, Reply::Ack)),
            Command::ReadRecord { max } => self.read(id, max).map(|(t, b)| (t, Reply::Record(b))),
            _ => return None,
        })
    }

    /// Arms client `id`'s recording (a new one: its queue starts empty); the
    /// tick it was armed on.
    fn arm(&mut self, id: u32, decimation: u16, signals: u8) -> Result<u32> {
        self.distribute();
        let d = u32::from(decimation.max(1));
        let active = || self.watches.values().filter(|w| w.active);
        let wanted = active().fold(d, |g, w| gcd(g, w.decimation));
        let wanted_signals = active().fold(signals, |s, w| s | w.signals);
        let covers = self.live.as_ref().is_some_and(|l| {
            u32::from(l.decimation) == wanted && l.signals & wanted_signals == wanted_signals
        });
        let tick = if covers {
            self.tick()?
        } else {
            self.restart(wanted as u16, wanted_signals)?
        };
        self.watches.insert(
            id,
            Watch {
                decimation: d,
                signals,
                active: true,
                next: tick.wrapping_add(1),
                queue: VecDeque::new(),
                overflow: 0,
            },
        );
        Ok(tick)
    }

    /// Stops client `id`'s recording (what it kept can still be read); the
    /// board's recording stops with the last client's.
    fn stop(&mut self, id: u32) -> Result<u32> {
        self.distribute();
        if let Some(w) = self.watches.get_mut(&id) {
            w.active = false;
        }
        if !self.watches.values().any(|w| w.active) {
            self.halt()?;
        }
        self.tick()
    }

    /// Up to `max` of client `id`'s samples as a batch, and the board's tick.
    fn read(&mut self, id: u32, max: u16) -> Result<(u32, Batch)> {
        self.distribute();
        let lost = self.lost();
        // The board's tick at the hub's latest read of it (never later than
        // the board's: a client reads on), rather than a ping to the board
        // for every client's read.
        let tick = match self.live.as_ref().and_then(Live::board_tick) {
            Some(t) => t,
            None => self.tick()?,
        };
        let Some(w) = self.watches.get_mut(&id) else {
            // Never armed: an idle recorder, as the board's.
            let idle = Batch {
                signals: 0,
                decimation: 1,
                active: false,
                dropped: 0,
                waiting: 0,
                values: HVec::new(),
            };
            return Ok((tick, idle));
        };
        let mut packer = Packer::new(w.signals);
        for _ in 0..max {
            match w.queue.front() {
                Some(next) if packer.push(next) => {
                    w.queue.pop_front();
                }
                _ => break,
            }
        }
        let batch = Batch {
            signals: w.signals,
            decimation: w.decimation as u16,
            active: w.active,
            dropped: w.overflow.saturating_add(lost),
            waiting: w.queue.len() as u32,
            values: packer.values(),
        };
        Ok((tick, batch))
    }

    /// Client `id` went: its recording ends (the board's with the last one).
    pub fn gone(&mut self, id: u32) {
        self.watches.remove(&id);
        if !self.watches.values().any(|w| w.active) {
            let _ = self.halt();
        }
    }

    /// What the live recording brought since the last call, into each active
    /// client's queue (the samples on its grid).
    fn distribute(&mut self) {
        let Some(live) = &self.live else {
            return;
        };
        let Ok(block) = live.read() else {
            return;
        };
        self.hand_out(&block.samples);
    }

    /// The board's samples `samples` into each active client's queue: those on
    /// its grid, while its queue has room (else counted as its overflow).
    fn hand_out(&mut self, samples: &[Sample]) {
        for w in self.watches.values_mut().filter(|w| w.active) {
            for s in samples {
                if s.tick.wrapping_sub(w.next) as i32 >= 0 {
                    w.next = s.tick.wrapping_add(w.decimation);
                    if w.queue.len() < QUEUE {
                        w.queue.push_back(*s);
                    } else {
                        w.overflow = w.overflow.saturating_add(1);
                    }
                }
            }
        }
    }

    /// What the board's recordings lost so far (its ring's drops and gaps).
    fn lost(&self) -> u32 {
        let now = self.live.as_ref().map_or(0, |l| {
            let c = l.counts();
            c.dropped
                .saturating_add(c.missing.min(u64::from(u32::MAX)) as u32)
        });
        self.lost_before.saturating_add(now)
    }

    /// Restarts the board's recording at `decimation` with `signals`; the tick
    /// it started on.
    fn restart(&mut self, decimation: u16, signals: u8) -> Result<u32> {
        self.halt()?;
        let live = Live::start(self.link.clone(), signals, decimation, false)?;
        let tick = live.start;
        self.live = Some(live);
        Ok(tick)
    }

    /// Stops the board's recording, its last samples handed out first.
    fn halt(&mut self) -> Result<()> {
        self.distribute();
        if let Some(live) = self.live.take() {
            let (rec, counts) = live.stop()?;
            let lost = counts
                .dropped
                .saturating_add(counts.missing.min(u64::from(u32::MAX)) as u32);
            self.lost_before = self.lost_before.saturating_add(lost);
            self.hand_out(&rec.samples);
        }
        Ok(())
    }

    /// The board's tick now (a ping's reply).
    fn tick(&self) -> Result<u32> {
        let mut tick = 0;
        self.link.with_client(&mut |c: &mut Client| {
            tick = c.request(&Command::Ping)?.0;
            Ok(())
        })?;
        Ok(tick)
    }
}

fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}
