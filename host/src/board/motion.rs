//! A motion that records itself: `fpi board move|wave|stream … --record
//! OUT.csv` (and the Python package's `record=True`). The board's recorder is
//! armed before the motion's command is sent and keeps every tick, every
//! signal (the columns of `fpi board record`, the true position included on
//! the emulated board), from the tick the board took the command until the
//! motion has ended and [`TAIL_S`] more (or for a given time), so that a user
//! sees what the command did to the stage.
//!
//! The recorder is read while the motion runs, as `fpi board record` reads
//! it (one batch after the other while samples wait); it is stopped
//! however the recording ends (done, stopped by the user, failed). A fault the
//! board latches during the motion ends the recording ([`TAIL_S`] after it)
//! and is reported with the recording, as [`Client::order`] reports it.

use anyhow::{bail, Result};
use fpi_firmware::control::recorder::{signal, Sample};
use std::time::{Duration, Instant};

use fpi_protocol::{Command, SourceKind, EVERY_AXIS};
use piezo_fpi::control::Fault;

use super::budget::Budget;
use super::client::{axis_name, Client, Faulted};
use super::commands::{self, BadArgument, Streamed};
use super::recording::Recording;
use crate::data::Num;

/// What is recorded after the motion has ended (the loops settle), s.
pub const TAIL_S: f64 = 0.05;

/// The longest recording of a motion, s (as `fpi board record`'s).
pub const LONGEST_S: f64 = 3600.0;

/// How long a motion is recorded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Until {
    /// Until the reference holds again (a move ramped to its end, a finite
    /// wave or a stream played), or a fault, and [`TAIL_S`] more.
    Rest,
    /// This many seconds of board time from the motion's start.
    Seconds(f64),
}

impl Until {
    /// `Seconds(s)` for a time given as `--seconds` (`seconds` in Python),
    /// checked: within `(0, 3600]` s.
    pub fn seconds(s: f64) -> Result<Self> {
        if s > 0.0 && s <= LONGEST_S {
            Ok(Self::Seconds(s))
        } else {
            Err(BadArgument {
                name: "seconds",
                cli: "--seconds",
                message: format!("--seconds {}: within (0, {LONGEST_S}] s", Num(s)),
            }
            .into())
        }
    }
}

/// A motion and its recording.
#[derive(Debug)]
pub struct Motion<T> {
    /// What the motion's command returned.
    pub result: T,
    /// The tick the board took the command on (the recording's first).
    pub start: u32,
    /// Every tick from `start` (sample ticks consecutive unless
    /// `recording.dropped`).
    pub recording: Recording,
    /// `stop` ended the recording early (the motion went on).
    pub stopped: bool,
    /// The fault the board latched during the motion, if it did: an error
    /// naming it ([`Faulted`]), to report once the recording is kept.
    pub fault: Option<anyhow::Error>,
}

/// Records the motion that `go` starts on `c` (see the module docs): `go`
/// sends the command (with [`Client::ack`], not [`Client::order`], whose wait
/// would let the ring overrun) and returns its tick and result; it gets the
/// function that reads the recorder, to call between its own requests if it
/// keeps the link busy (a stream). `expected_s` is how long the motion is
/// expected to last, for the link's budget: a recording the link cannot carry
/// is refused before anything is sent. `stop` is polled while it waits.
pub fn record<T>(
    c: &mut Client,
    what: &str,
    expected_s: f64,
    until: Until,
    go: impl FnOnce(&mut Client, &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<(u32, T)>,
    stop: impl FnMut() -> bool,
) -> Result<Motion<T>> {
    let axis = c.axis();
    record_of(c, (axis, signal::ALL), what, expected_s, until, go, stop)
}

/// The signals a recording of every axis keeps of each: the reference, the
/// true and the sensed position, and the status (what two axes' every tick
/// fits the USB link with).
pub const EVERY_AXIS_SIGNALS: u8 =
    signal::X_REF | signal::X_TRUE | signal::X_SENSOR | signal::STATUS;

/// [`record`] of `signals` of every axis of a board of several: its
/// recording holds one sample per axis of each tick, in axis order ([`AxesRecording::split`](super::recording::AxesRecording::split)
/// parts them). The motion's end is the addressed axis's.
pub fn record_every_axis<T>(
    c: &mut Client,
    signals: u8,
    what: &str,
    expected_s: f64,
    until: Until,
    go: impl FnOnce(&mut Client, &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<(u32, T)>,
    stop: impl FnMut() -> bool,
) -> Result<Motion<T>> {
    record_of(c, (EVERY_AXIS, signals), what, expected_s, until, go, stop)
}

/// [`record`] of `signals` of `axis` (or [`EVERY_AXIS`]).
fn record_of<T>(
    c: &mut Client,
    (axis, signals): (u8, u8),
    what: &str,
    expected_s: f64,
    until: Until,
    go: impl FnOnce(&mut Client, &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<(u32, T)>,
    stop: impl FnMut() -> bool,
) -> Result<Motion<T>> {
    let seconds = match until {
        Until::Seconds(s) => s,
        Until::Rest => expected_s + TAIL_S,
    };
    let per_tick = if axis == EVERY_AXIS {
        c.hello().axes
    } else {
        1
    };
    let budget = Budget::new(c.hello(), signals, 1, seconds + 0.005).of_axes(per_tick);
    if !budget.fits() {
        return Err(BadArgument {
            name: "record",
            cli: "--record",
            message: format!(
                "--record: {what}'s recording at every tick needs about {:.0} kB/s, more than \
                 the {} link carries ({:.0} kB/s), and more than the board's ring holds \
                 ({} samples): it needs the USB link (`fpi board emulate --link usb`, its \
                 default, or the in-process board as `--port virtual:usb`)",
                budget.needed() / 1e3,
                budget.link.name(),
                budget.carried() / 1e3,
                budget.ring
            ),
        }
        .into());
    }
    c.ack(&Command::Record {
        axis,
        decimation: 1,
        signals,
    })?;
    let mut rec = Recording {
        rate_hz: c.rate_hz(),
        signals,
        ..Recording::default()
    };
    let followed = follow(c, (&mut rec.samples, per_tick), what, until, go, stop);
    // The recorder stops however the recording ended.
    let stopped_recorder = c.ack(&Command::RecordStop);
    let (result, start, end, stopped) = followed?;
    stopped_recorder?;
    read_all(c, &mut rec.samples, per_tick)?;
    rec.samples
        .retain(|s| s.tick >= start && end.is_none_or(|e| s.tick < e));
    // What the ring dropped of the ticks kept (not of those before the motion).
    let span = rec.samples.last().map_or(0, |s| s.tick - start + 1);
    rec.dropped = (span * u32::from(per_tick)).saturating_sub(rec.samples.len() as u32);
    let (status, by) = faulted_status(c)?;
    let fault = match status.fault {
        Some(x) if x.at >= start && x.code != Fault::Stopped as u8 => Some(
            Faulted {
                what: match by {
                    Some(a) => format!("{what} (on axis {})", axis_name(a)),
                    None => what.to_string(),
                },
                tick: x.at,
                reason: Fault::from_code(x.code).map_or("an unknown fault", |f| f.message()),
            }
            .into(),
        ),
        _ => None,
    };
    Ok(Motion {
        result,
        start,
        recording: rec,
        stopped,
        fault,
    })
}

/// The status of the addressed axis, or, where another axis's fault parked
/// the board, that axis's status and its number.
fn faulted_status(c: &mut Client) -> Result<(fpi_protocol::Status, Option<u8>)> {
    let s = c.status()?;
    let here = c.axis();
    match s.fault_axis {
        Some(a) if a != here => {
            c.on_axis(a)?;
            let other = c.status();
            c.on_axis(here)?;
            Ok((other?, Some(a)))
        }
        _ => Ok((s, None)),
    }
}

/// Reads the recorder until nothing waits, into `into` (`stride` axes'
/// samples interleaved: [`Sample::interleaved`]). One batch after the other,
/// as `fpi board record` reads: at every tick the link has little to spare,
/// so no other request comes between two while samples wait. At most
/// [`READ_RINGS`] rings' worth of samples a call: a recording the link
/// cannot keep up with (its ring drops, and says so) still lets the caller
/// poll the board.
fn read_all(c: &mut Client, into: &mut Vec<Sample>, stride: u8) -> Result<()> {
    let most = into.len() + READ_RINGS * c.hello().buffers[0] as usize;
    loop {
        let b = c.read_batch()?;
        into.extend(Sample::interleaved(b.signals, stride, &b.values));
        if b.waiting == 0 || into.len() >= most {
            return Ok(());
        }
    }
}

/// The most rings' worth of samples one [`read_all`] reads (1.6 s of every
/// tick with the 512-sample ring at 20 kHz): far more than a link that keeps
/// up leaves waiting.
const READ_RINGS: usize = 64;

/// Between two polls of the board's status while the recorder is read, at
/// most.
const POLL: Duration = Duration::from_millis(5);

/// Starts the motion and follows it until it is recorded: its result, its
/// start, the tick the recording ends before (`None`: where it stopped) and
/// whether `stop` ended it. The recorder is read into `samples` throughout.
fn follow<T>(
    c: &mut Client,
    (samples, stride): (&mut Vec<Sample>, u8),
    what: &str,
    until: Until,
    go: impl FnOnce(&mut Client, &mut dyn FnMut(&mut Client) -> Result<()>) -> Result<(u32, T)>,
    mut stop: impl FnMut() -> bool,
) -> Result<(T, u32, Option<u32>, bool)> {
    let (start, result) = go(c, &mut |c: &mut Client| read_all(c, samples, stride))?;
    let rate = c.rate_hz();
    let ticks = |s: f64| (s * rate).round() as u32;
    // Until the recording's end is known (the motion has ended), then until
    // the board has passed it.
    let mut end = match until {
        Until::Seconds(s) => Some(start + ticks(s)),
        Until::Rest => None,
    };
    let started = Instant::now();
    let mut polled: Option<Instant> = None;
    loop {
        read_all(c, samples, stride)?;
        if stop() {
            return Ok((result, start, None, true));
        }
        let now = c.last_tick().unwrap_or(start);
        if end.is_some_and(|e| now >= e) {
            break;
        }
        if end.is_none() && polled.is_none_or(|p| p.elapsed() >= POLL) {
            polled = Some(Instant::now());
            let s = c.status()?;
            let rest = s.tick > start && s.source == SourceKind::Hold && !s.approaching;
            if rest || s.fault.is_some_and(|f| f.at >= start) {
                end = Some(s.tick + ticks(TAIL_S));
            }
        }
        let longest = end.map_or(LONGEST_S, |e| (e - start) as f64 / rate);
        if started.elapsed() > Duration::from_secs_f64(longest * 20.0 + 30.0) {
            bail!("the board's clock does not advance during {what} (tick {now})");
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok((result, start, end, false))
}

/// A stream of `points` (µm) at `interval` ticks with every tick of it
/// recorded ([`record`] until the board holds): `progress` hears the points
/// sent, `stop` ends the stream early (the recording goes on until the
/// board holds). What `fpi board stream --record` and Python's
/// `stream(record=True)` run.
pub fn record_stream(
    c: &mut Client,
    points: &[f64],
    interval: u16,
    progress: impl FnMut(usize),
    stop: impl FnMut() -> bool,
) -> Result<Motion<Streamed>> {
    let seconds = points.len() as f64 * f64::from(interval) / c.rate_hz();
    record(
        c,
        "the stream",
        seconds,
        Until::Rest,
        |c, read| {
            let armed = c.last_tick().unwrap_or(0);
            let r = commands::stream_with(c, points, interval, progress, stop, read)?;
            let start = match r {
                Streamed::Played(p) => p.started,
                Streamed::Stopped { .. } => armed,
            };
            Ok((start, r))
        },
        || false,
    )
}

/// How long a move from `from_um` to `to_um` at `speed` µm/s lasts, s.
pub fn move_seconds(from_um: f64, to_um: f64, speed: f64) -> f64 {
    (to_um - from_um).abs() / speed
}
