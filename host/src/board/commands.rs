//! The board's commands with their arguments checked, as `fpi board …` and the
//! Python package (`python/`) both give them: each checks its arguments (an
//! argument the link cannot carry or the generator cannot run is refused by the
//! host, naming it: [`BadArgument`]), sends the command and checks its effect
//! ([`Client::order`]), and returns the tick the board took it on. Nothing here
//! prints: the callers say what happened.
//!
//! Also the host's side of the long commands that a user may stop (Ctrl-C):
//! [`record`] and [`stream`] take a `stop` callback, polled while they wait.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use fpi_firmware::control::recorder::Sample;
use fpi_protocol::{BenchOrder, Command, LoopMode, Shape, SourceKind};

use super::budget::Budget;
use super::client::{real, to_link, Client, StreamReport};
use super::recording::Recording;
use super::variant;
use crate::data::{Num, Quoted};

/// An argument the host refuses before anything is sent: its name as the Python
/// package spells it (`freq_hz`), as the command line spells it (`--freq-hz`),
/// and the message, which starts with the command line's spelling.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BadArgument {
    /// The argument's name in the Python package (snake case).
    pub name: &'static str,
    /// The argument as `fpi board` takes it (`--freq-hz`, or `the target` for a
    /// positional one).
    pub cli: &'static str,
    /// What is wrong with it, starting with [`cli`](Self::cli).
    pub message: String,
}

impl BadArgument {
    /// The message with the arguments named as the Python package names them:
    /// the argument itself, and every other command-line option it mentions
    /// (`--decimation` → `decimation`: the package's arguments are the long
    /// options in snake case).
    pub fn python_message(&self) -> String {
        let m = self.message.replacen(self.cli, self.name, 1);
        let mut out = String::with_capacity(m.len());
        let mut rest = m.as_str();
        while let Some(at) = rest.find("--") {
            out.push_str(&rest[..at]);
            let after = &rest[at + 2..];
            let end = after
                .find(|c: char| !(c.is_ascii_lowercase() || c == '-'))
                .unwrap_or(after.len());
            if end == 0 {
                out.push_str("--");
            } else {
                out.push_str(&after[..end].replace('-', "_"));
            }
            rest = &after[end..];
        }
        out.push_str(rest);
        out
    }
}

impl std::fmt::Display for BadArgument {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for BadArgument {}

/// The bad argument inside an error, if the host refused one.
pub fn bad_argument(e: &anyhow::Error) -> Option<&BadArgument> {
    e.downcast_ref::<BadArgument>()
}

pub(crate) fn bad(name: &'static str, cli: &'static str, message: String) -> anyhow::Error {
    BadArgument { name, cli, message }.into()
}

/// [`to_link`] of argument `name` (`cli` on the command line), in `unit`.
fn link_value(name: &'static str, cli: &'static str, x: f64, unit: &str) -> Result<i32> {
    to_link(cli, x, unit).map_err(|e| bad(name, cli, e.to_string()))
}

/// A waveform shape by name: `sine`, `triangle` or `cosine` (`raised-cosine`).
pub fn shape(name: &str) -> Result<Shape> {
    Ok(match name {
        "sine" => Shape::Sine,
        "triangle" => Shape::Triangle,
        "cosine" | "raised-cosine" => Shape::RaisedCosine,
        _ => {
            return Err(bad(
                "shape",
                "--shape",
                format!("--shape {}: sine, triangle or cosine", Quoted(name)),
            ))
        }
    })
}

/// A loop mode by name: `open`, `closed` or `feedback`.
pub fn loop_mode(name: &str) -> Result<LoopMode> {
    Ok(match name {
        "open" => LoopMode::Open,
        "closed" => LoopMode::Closed,
        "feedback" | "feedback-only" => LoopMode::FeedbackOnly,
        _ => {
            return Err(bad(
                "mode",
                "loop",
                format!("loop {}: open, closed or feedback", Quoted(name)),
            ))
        }
    })
}

/// `on` or `off` of argument `name` (`cli` on the command line).
fn on_off(name: &'static str, cli: &'static str, s: &str) -> Result<bool> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(bad(name, cli, format!("{cli} {}: on or off", Quoted(s)))),
    }
}

/// Ramps to `um` (µm) at `speed` µm/s and holds it; the tick it started.
pub fn move_to(c: &mut Client, um: f64, speed: f64) -> Result<u32> {
    c.order(&move_command(c.axis(), um, speed)?)
}

/// Ramps each axis that has a target (`targets`: x, y, z, µm) to it at
/// `speed` µm/s, all from the same tick, and holds them; the tick they
/// started.
pub fn move_axes(c: &mut Client, targets: [Option<f64>; 3], speed: f64) -> Result<u32> {
    c.order(&move_axes_command(targets, speed)?)
}

/// The command of [`move_axes`], its arguments checked.
pub fn move_axes_command(targets: [Option<f64>; 3], speed: f64) -> Result<Command<'static>> {
    const OPTIONS: [&str; 3] = ["--x", "--y", "--z"];
    let speed = speed_bits(speed)?;
    let mut mask = 0;
    let mut bits = [0; 3];
    for (i, ((t, b), cli)) in targets.iter().zip(&mut bits).zip(OPTIONS).enumerate() {
        if let Some(um) = *t {
            *b = link_value("target_um", cli, um, "µm")?;
            mask |= 1 << i;
        }
    }
    if mask == 0 {
        return Err(bad(
            "target_um",
            "--x",
            "name a target: --x, --y or --z".into(),
        ));
    }
    Ok(Command::MoveAxes {
        mask,
        targets: bits,
        speed,
    })
}

/// The command of [`move_to`] for `axis`, its arguments checked.
pub fn move_command(axis: u8, um: f64, speed: f64) -> Result<Command<'static>> {
    let target = link_value("target_um", "the target", um, "µm")?;
    Ok(Command::Move {
        axis,
        target,
        speed: speed_bits(speed)?,
    })
}

/// A move's speed (µm/s) as the link carries it, checked above 0.
fn speed_bits(speed: f64) -> Result<i32> {
    if speed.is_nan() || speed <= 0.0 {
        return Err(bad(
            "speed",
            "--speed",
            format!("--speed {} µm/s: must be above 0", Num(speed)),
        ));
    }
    link_value("speed", "--speed", speed, "µm/s")
}

/// The waveform generator's frequency resolution, Hz (it takes mHz).
pub const WAVE_STEP_HZ: f64 = 1e-3;

/// Runs the waveform generator: `shape` (see [`shape`]) with half-swing
/// `amplitude_um` about `offset_um` (µm) at `freq_hz` (Hz, below half the control
/// rate) for `cycles` periods (0: until the next command); the tick its approach
/// started.
pub fn wave(
    c: &mut Client,
    shape_name: &str,
    amplitude_um: f64,
    offset_um: f64,
    freq_hz: f64,
    cycles: u32,
) -> Result<u32> {
    let cmd = wave_command(c, shape_name, amplitude_um, offset_um, freq_hz, cycles)?;
    c.order(&cmd)
}

/// The command of [`wave`], its arguments checked (against the board's rate).
pub fn wave_command(
    c: &Client,
    shape_name: &str,
    amplitude_um: f64,
    offset_um: f64,
    freq_hz: f64,
    cycles: u32,
) -> Result<Command<'static>> {
    let shape = shape(shape_name)?;
    let top = c.rate_hz() / 2.0;
    if freq_hz.is_nan() || freq_hz >= top {
        return Err(bad(
            "freq_hz",
            "--freq-hz",
            format!(
                "--freq-hz {}: at or above half the board's control rate ({top} Hz)",
                Num(freq_hz)
            ),
        ));
    }
    let freq_mhz = (freq_hz / WAVE_STEP_HZ).round();
    if freq_mhz < 1.0 {
        return Err(bad(
            "freq_hz",
            "--freq-hz",
            format!(
                "--freq-hz {}: below the generator's resolution of {WAVE_STEP_HZ} Hz",
                Num(freq_hz)
            ),
        ));
    }
    if amplitude_um.is_nan() || amplitude_um <= 0.0 {
        return Err(bad(
            "amplitude_um",
            "--amplitude-um",
            format!("--amplitude-um {} µm: must be above 0", Num(amplitude_um)),
        ));
    }
    Ok(Command::Wave {
        axis: c.axis(),
        shape,
        offset: link_value("offset_um", "--offset-um", offset_um, "µm")?,
        amplitude: link_value("amplitude_um", "--amplitude-um", amplitude_um, "µm")?,
        freq_mhz: freq_mhz as u32,
        cycles,
    })
}

/// Compensated (inverse FPI) or uncompensated (straight line) drive, by name;
/// the tick it took effect.
pub fn drive(c: &mut Client, mode: &str) -> Result<u32> {
    let compensated = match mode {
        "compensated" => true,
        "uncompensated" => false,
        m => {
            return Err(bad(
                "mode",
                "drive",
                format!("drive {}: compensated or uncompensated", Quoted(m)),
            ))
        }
    };
    c.order(&Command::Drive {
        axis: c.axis(),
        compensated,
    })
}

/// Opens or closes the loop (see [`loop_mode`]), without a jump; the tick.
pub fn set_loop(c: &mut Client, mode: &str) -> Result<u32> {
    let mode = loop_mode(mode)?;
    c.order(&Command::Loop {
        axis: c.axis(),
        mode,
    })
}

/// Switches the model's active damping `on` or `off`; the tick.
pub fn damping(c: &mut Client, state: &str) -> Result<u32> {
    let on = on_off("state", "damping", state)?;
    c.order(&Command::Damping { axis: c.axis(), on })
}

/// Switches the model's reference shaping `on` or `off`; the tick.
pub fn shaping(c: &mut Client, state: &str) -> Result<u32> {
    let on = on_off("state", "shaping", state)?;
    c.order(&Command::Shaping { axis: c.axis(), on })
}

/// Parks the stage if the host is silent for `ms` ms while it drives it (0: off).
pub fn supervise(c: &mut Client, ms: u32) -> Result<u32> {
    c.ack(&Command::Supervise { timeout_ms: ms })
}

/// What the emulated board's virtual bench is set to (also `fpi board bench`'s
/// options).
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct BenchSettings {
    /// Voltage on the analog reference input, 0–3.3 V.
    #[arg(long, allow_negative_numbers = true)]
    pub analog_v: Option<f64>,
    /// The force sensor: ok, open (a broken wire) or stuck (frozen reading).
    #[arg(long)]
    pub sensor: Option<String>,
    /// A step added to the force reading, N (a loose connector; 0 removes it).
    #[arg(long, allow_negative_numbers = true)]
    pub force_offset_n: Option<f64>,
    /// Make this many control ticks overrun their period.
    #[arg(long)]
    pub stall_ticks: Option<u16>,
    /// Raise the trigger input for this many control ticks (a pulse: its
    /// rising edge starts what is armed).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    pub trigger_in_ticks: Option<u16>,
    /// Damage the newest model stored in flash (the next start refuses it).
    #[arg(long)]
    pub damage_stored: bool,
    /// The position sensor: ok, open (a broken wire) or stuck (frozen reading).
    #[arg(long)]
    pub position_sensor: Option<String>,
    /// The virtual stage, replaced by a fresh one at rest (send it parked):
    /// nominal (the model's twin), built (kinematics, preload and creep a few
    /// percent off the model, an 850 Hz mode, position-sensor noise) or a TOML
    /// file naming one of them as `base` and the values it changes (mode_hz,
    /// mode_damping, output_gain, force_scale, creep_scale, position_noise_um,
    /// force_noise_n).
    #[arg(long)]
    pub stage: Option<String>,
}

/// Sets the emulated board's virtual bench (a real board refuses); what was set,
/// one line each, for people.
pub fn bench(c: &mut Client, b: &BenchSettings) -> Result<Vec<String>> {
    b.check()?;
    if *b == BenchSettings::default() {
        bail!(
            "nothing to set: --analog-v V, --sensor ok|open|stuck, --force-offset-n N, \
             --stall-ticks T, --trigger-in-ticks T, --damage-stored, --position-sensor \
             ok|open|stuck or --stage nominal|built|VARIANT.toml"
        );
    }
    let mut done = Vec::new();
    if let Some(v) = b.analog_v {
        if !(0.0..=3.3).contains(&v) {
            return Err(bad(
                "analog_v",
                "--analog-v",
                format!("--analog-v {v}: the input spans 0–3.3 V"),
            ));
        }
        let counts = (v / 3.3 * fpi_firmware::board::analog_in::ADC_MAX as f64).round() as u16;
        c.bench(BenchOrder::Analog(counts))?;
        done.push(format!("analog input at {v} V ({counts} counts)"));
    }
    if let Some(s) = b.sensor.as_deref() {
        let orders = [BenchOrder::SensorOpen, BenchOrder::SensorStuck];
        sensor_state(c, ("sensor", "--sensor"), s, orders)?;
        done.push(format!("force sensor {s}"));
    }
    bench_faults(c, b, &mut done)?;
    bench_position(c, b, &mut done)?;
    Ok(done)
}

impl BenchSettings {
    /// Checks what can be checked without the board, before any order goes
    /// out (a bad value after a good one would leave the bench half set): the
    /// analog voltage's range, the sensors' states and the stage's file.
    pub fn check(&self) -> Result<()> {
        if let Some(v) = self.analog_v.filter(|v| !(0.0..=3.3).contains(v)) {
            return Err(bad(
                "analog_v",
                "--analog-v",
                format!("--analog-v {v}: the input spans 0–3.3 V"),
            ));
        }
        for (key, option, state) in [
            ("sensor", "--sensor", &self.sensor),
            (
                "position_sensor",
                "--position-sensor",
                &self.position_sensor,
            ),
        ] {
            if let Some(s) = state
                .as_deref()
                .filter(|s| !["ok", "open", "stuck"].contains(s))
            {
                return Err(bad(
                    key,
                    option,
                    format!("{option} {}: ok, open or stuck", Quoted(s)),
                ));
            }
        }
        if let Some(s) = self.stage.as_deref() {
            variant::parse(s)?;
        }
        Ok(())
    }
}

/// Puts a sensor of the virtual bench in state `s` (`ok`, `open` or `stuck`,
/// given as argument `name`), through its bench orders `[open, stuck]`.
fn sensor_state(
    c: &mut Client,
    name: (&'static str, &'static str),
    s: &str,
    [open, stuck]: [fn(bool) -> BenchOrder; 2],
) -> Result<()> {
    let orders = match s {
        "ok" => vec![open(false), stuck(false)],
        "open" => vec![open(true)],
        "stuck" => vec![stuck(true)],
        _ => {
            return Err(bad(
                name.0,
                name.1,
                format!("{} {}: ok, open or stuck", name.1, Quoted(s)),
            ))
        }
    };
    for o in orders {
        c.bench(o)?;
    }
    Ok(())
}

/// The fault injections of [`bench`]: a force step, overrunning ticks, a damaged
/// stored model.
fn bench_faults(c: &mut Client, b: &BenchSettings, done: &mut Vec<String>) -> Result<()> {
    if let Some(n) = b.force_offset_n {
        if !n.is_finite() || n.abs() > 4096.0 {
            return Err(bad(
                "force_offset_n",
                "--force-offset-n",
                format!("--force-offset-n {n}: a finite step within ±4096 N"),
            ));
        }
        let bits = link_value("force_offset_n", "--force-offset-n", n, "N")?;
        let tick = c.bench(BenchOrder::SensorOffset(bits))?;
        done.push(format!("force reading offset by {n} N from tick {tick}"));
    }
    if let Some(t) = b.trigger_in_ticks {
        if t == 0 {
            return Err(bad(
                "trigger_in_ticks",
                "--trigger-in-ticks",
                "--trigger-in-ticks 0: a pulse lasts 1 tick or more".into(),
            ));
        }
        let tick = c.bench(BenchOrder::TriggerIn(t))?;
        done.push(format!("trigger input high for {t} ticks from tick {tick}"));
    }
    if let Some(t) = b.stall_ticks {
        let tick = c.bench(BenchOrder::Stall(t))?;
        done.push(format!(
            "{t} control ticks overrun their period from tick {tick}"
        ));
    }
    if b.damage_stored {
        c.bench(BenchOrder::DamageStored)?;
        done.push(
            "the newest stored model is damaged: `fpi board reset` shows the start-up check".into(),
        );
    }
    Ok(())
}

/// The position sensor's faults and the choice of virtual stage of [`bench`].
fn bench_position(c: &mut Client, b: &BenchSettings, done: &mut Vec<String>) -> Result<()> {
    if let Some(s) = b.position_sensor.as_deref() {
        let orders = [BenchOrder::PositionOpen, BenchOrder::PositionStuck];
        sensor_state(c, ("position_sensor", "--position-sensor"), s, orders)?;
        done.push(format!("position sensor {s}"));
    }
    if let Some(s) = b.stage.as_deref() {
        let v = variant::parse(s)?;
        let tick = c.bench(BenchOrder::Stage(v))?;
        done.push(format!(
            "virtual stage: stage A, {}, at rest from tick {tick}",
            variant::describe(&v)
        ));
    }
    Ok(())
}

/// A recording taken by [`record`].
#[derive(Debug, Clone)]
pub struct Recorded {
    /// What was recorded.
    pub recording: Recording,
    /// The tick the recorder started.
    pub start: u32,
    /// Board time recorded, s.
    pub seconds: f64,
    /// `stop` ended it before the time asked for.
    pub stopped: bool,
}

/// Records every `decimation`-th tick for `seconds` (s) of board time, the
/// `signals` asked for (`signal::ALL`: the datasets' columns, [`Recording`]). `progress` gets the ticks
/// recorded and the ticks asked for; `stop` is polled between reads (every
/// 20 ms at most, [`Budget::pause`]) and ends the recording early (the recorder
/// is stopped, what it recorded kept, the stage left as it was:
/// [`Recorded::stopped`]).
pub fn record(
    c: &mut Client,
    seconds: f64,
    decimation: u16,
    signals: u8,
    mut progress: impl FnMut(u32, u32),
    mut stop: impl FnMut() -> bool,
) -> Result<Recorded> {
    if !(seconds > 0.0 && seconds <= 3600.0) {
        return Err(bad(
            "seconds",
            "--seconds",
            format!("--seconds {}: within (0, 3600] s", Num(seconds)),
        ));
    }
    if decimation == 0 {
        return Err(bad(
            "decimation",
            "--decimation",
            "--decimation 0: keep one tick in 1 or more".into(),
        ));
    }
    let rate = c.rate_hz();
    let ticks = (seconds * rate).round() as u32;
    if signals == 0 {
        return Err(bad(
            "signals",
            "--signals",
            "--signals: name one signal or more".into(),
        ));
    }
    let start = c.ack(&Command::Record {
        axis: c.axis(),
        decimation,
        signals,
    })?;
    let mut rec = Recording {
        rate_hz: rate,
        signals,
        ..Recording::default()
    };
    // Between reads while nothing waits.
    let pause = Budget::new(c.hello(), signals, decimation, seconds).pause();
    let started = Instant::now();
    let mut stopped = false;
    loop {
        // One batch at a time: on a link slower than the recording, reading
        // everything waiting would run past the end.
        let b = c.read_batch()?;
        rec.samples.extend(Sample::batch(b.signals, &b.values));
        // The read's own reply says the tick: no status poll takes the link's time.
        let now = c.last_tick().unwrap_or(start);
        progress(now.saturating_sub(start).min(ticks), ticks);
        if now >= start + ticks {
            break;
        }
        if stop() {
            stopped = true;
            break;
        }
        if started.elapsed() > Duration::from_secs_f64(seconds * 20.0 + 30.0) {
            bail!("the board's clock does not advance (tick {now})");
        }
        if b.waiting == 0 {
            std::thread::sleep(pause);
        }
    }
    c.ack(&Command::RecordStop)?;
    let (samples, _) = c.drain()?;
    rec.samples.extend(samples);
    rec.samples.retain(|s| s.tick < start + ticks);
    let recorded = rec
        .samples
        .last()
        .map_or(0.0, |s| (s.tick - start) as f64 / rate);
    // What the ring dropped within the time asked for (it went on recording,
    // and dropping, until the stop arrived).
    let asked = if stopped {
        (recorded * rate) as u32 / u32::from(decimation) + 1
    } else {
        ticks.div_ceil(u32::from(decimation))
    };
    rec.dropped = asked.saturating_sub(rec.samples.len() as u32);
    Ok(Recorded {
        recording: rec,
        start,
        seconds: recorded,
        stopped,
    })
}

/// How a [`stream`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Streamed {
    /// Every point was played.
    Played(StreamReport),
    /// `stop` ended it: the board holds where the reference was, and host
    /// supervision the stream switched on is off again.
    Stopped {
        /// Points sent before it stopped.
        sent: usize,
        /// The tick the board took the hold.
        held_at: u32,
    },
}

/// Why a stream stopped early (inside the error of the client's `idle`).
#[derive(Debug)]
struct StopAsked;

impl std::fmt::Display for StopAsked {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("stopped by the host")
    }
}

impl std::error::Error for StopAsked {}

/// Streams `points_um` (µm, each finite and within what the link carries), one
/// every `interval` control ticks (≥ 1), through [`Client::stream`]; `progress`
/// gets the points sent. `stop` is polled while the host waits for room or for
/// the last point: it ends the stream with the board holding ([`Streamed::Stopped`]).
pub fn stream(
    c: &mut Client,
    points_um: &[f64],
    interval: u16,
    progress: impl FnMut(usize),
    stop: impl FnMut() -> bool,
) -> Result<Streamed> {
    stream_with(c, points_um, interval, progress, stop, |_| Ok(()))
}

/// [`stream`], and `idle` run on the board between the host's requests
/// (every few milliseconds: what reads a recording made meanwhile).
pub fn stream_with(
    c: &mut Client,
    points_um: &[f64],
    interval: u16,
    progress: impl FnMut(usize),
    mut stop: impl FnMut() -> bool,
    mut idle: impl FnMut(&mut Client) -> Result<()>,
) -> Result<Streamed> {
    if points_um.is_empty() {
        return Err(bad(
            "points_um",
            "the trajectory",
            "the trajectory: no points".into(),
        ));
    }
    if let Some((k, x)) = points_um
        .iter()
        .enumerate()
        .find(|(_, x)| to_link("", **x, "µm").is_err())
    {
        return Err(bad(
            "points_um",
            "the trajectory",
            format!(
                "the trajectory, point {k}: {} µm is not a finite value the link carries",
                Num(*x)
            ),
        ));
    }
    if interval == 0 {
        return Err(bad(
            "interval",
            "--interval",
            "--interval 0: one point every 1 or more ticks".into(),
        ));
    }
    let supervised = c.status()?.supervision[0] != 0;
    let mut sent = 0;
    let mut progress = progress;
    let result = c.stream(
        points_um,
        interval,
        |n| {
            sent = n;
            progress(n);
        },
        |c| {
            if stop() {
                Err(StopAsked.into())
            } else {
                idle(c)
            }
        },
    );
    match result {
        Ok(r) => Ok(Streamed::Played(r)),
        Err(e) if e.downcast_ref::<StopAsked>().is_some() => {
            let held_at = c.ack(&Command::Hold { axis: c.axis() })?;
            c.ack(&Command::StreamClear { axis: c.axis() })?;
            if !supervised {
                c.ack(&Command::Supervise { timeout_ms: 0 })?;
            }
            Ok(Streamed::Stopped { sent, held_at })
        }
        Err(e) => Err(e),
    }
}

/// The stage's position, µm: the position sensor's reading when the running
/// model closes a loop on it (it has a `[feedback]` section, so the board has a
/// position sensor), else the model's estimate.
pub fn position(c: &mut Client) -> Result<f64> {
    let sensor = c.model()?.feedback.is_some();
    let s = c.status()?;
    Ok(real(s.signals[if sensor { 4 } else { 1 }]))
}

/// The default band of [`on_target`], µm.
pub const ON_TARGET_UM: f64 = 0.1;

/// Whether the stage is on target (PI's `ONT?`): running (no fault, not
/// parked), the reference standing still (held: a move ramped to its end, a
/// finite wave or a stream done; not approaching), and the position
/// ([`position`]) within `tolerance_um` of the reference. With the position.
pub fn on_target(c: &mut Client, tolerance_um: f64) -> Result<(bool, f64)> {
    let sensor = c.model()?.feedback.is_some();
    let s = c.status()?;
    let x = real(s.signals[if sensor { 4 } else { 1 }]);
    let held = s.source == SourceKind::Hold && !s.approaching;
    let near = (x - real(s.signals[0])).abs() <= tolerance_um;
    Ok((s.fault.is_none() && held && near, x))
}

/// Waits until [`on_target`] (polling every 5 ms) for up to `timeout_s` seconds
/// of wall-clock time; the position, or `None` on a timeout or when `stop` says
/// so (polled as often). A fault while waiting is an error naming it.
pub fn wait_on_target(
    c: &mut Client,
    tolerance_um: f64,
    timeout_s: f64,
    mut stop: impl FnMut() -> bool,
) -> Result<Option<f64>> {
    if tolerance_um.is_nan() || tolerance_um <= 0.0 {
        return Err(bad(
            "tolerance_um",
            "--tolerance-um",
            format!("--tolerance-um {}: must be above 0", Num(tolerance_um)),
        ));
    }
    if !(timeout_s >= 0.0 && timeout_s.is_finite()) {
        return Err(bad(
            "timeout",
            "--timeout",
            format!("--timeout {} s: a finite time, 0 or more", Num(timeout_s)),
        ));
    }
    let start = Instant::now();
    loop {
        let (on, x) = on_target(c, tolerance_um)?;
        if on {
            return Ok(Some(x));
        }
        if let Some(f) = c.status()?.fault {
            if f.code != piezo_fpi::control::Fault::Stopped as u8 {
                let what = piezo_fpi::control::Fault::from_code(f.code)
                    .map_or("an unknown fault", |f| f.message());
                return Err(super::client::Faulted {
                    what: "the wait for the target".into(),
                    tick: f.at,
                    reason: what,
                }
                .into());
            }
        }
        if stop() || start.elapsed().as_secs_f64() > timeout_s {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Parks the stage: ramps to the safe voltage, amplifier off; the tick.
pub fn safe(c: &mut Client) -> Result<u32> {
    c.order(&Command::Safe)
}

/// Clears a latched fault (the stage stays parked); the tick.
pub fn clear_fault(c: &mut Client) -> Result<u32> {
    c.order(&Command::ClearFault)
}

/// Stops the reference where it is; the tick.
pub fn hold(c: &mut Client) -> Result<u32> {
    c.order(&Command::Hold { axis: c.axis() })
}

/// Follows the analog reference input; the tick.
pub fn analog(c: &mut Client) -> Result<u32> {
    c.order(&Command::Analog { axis: c.axis() })
}

/// Forgets the stored model and runs the factory default; the tick.
pub fn factory(c: &mut Client) -> Result<u32> {
    c.order(&Command::ModelFactory { axis: c.axis() })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error names the Python package's arguments for Python: the
    /// argument, and every option the message mentions.
    #[test]
    fn a_bad_argument_names_python_s_arguments_for_python() {
        let b = BadArgument {
            name: "decimation",
            cli: "--decimation",
            message: "the step's recording would drop samples: --decimation 31 or more fits \
                      (shorten --seconds or raise --decimation); a -- alone stays"
                .into(),
        };
        assert_eq!(
            b.python_message(),
            "the step's recording would drop samples: decimation 31 or more fits \
             (shorten seconds or raise decimation); a -- alone stays"
        );
        let b = BadArgument {
            name: "to_hz",
            cli: "--to-hz",
            message: "--to-hz 50: above --from-hz 100".into(),
        };
        assert_eq!(b.python_message(), "to_hz 50: above from_hz 100");
    }
}
