//! `fpi board …`: a board (or the emulated board) driven from the command line,
//! through the same [`Client`] the tests and the demo use.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use fpi_firmware::closed_loop::LoopMode;
use fpi_firmware::link::protocol::{BoardKind, Command, ResetReason, SlotReport, Status};
use fpi_firmware::recorder::signal;
use fpi_firmware::reference::wave::Shape;
use fpi_firmware::slots::Origin;
use indicatif::{ProgressBar, ProgressStyle};
use piezo_fpi::control::Fault;
use piezo_sim::file::FirmwareModel;

use super::client::{bits, real, Client};
use super::recording::Recording;
use crate::method::export::{self, ExportOptions, LoopSettings};
use crate::method::model::HostModel;

/// The image of a model file for the board: a firmware model file
/// (`format = "piezo-fpi-firmware/1"`, from `fpi export`) as it is, or a
/// calibrated model (`fpi calibrate`) exported with the stage's FEM tables and the
/// loop settings, as `fpi export` would.
pub fn model_image(model: &Path, fem: Option<&Path>, o: &ExportOptions) -> Result<Vec<u8>> {
    firmware_model(model, fem, o)?
        .image()
        .map_err(|e| anyhow::anyhow!("{}: {e}", model.display()))
}

/// The firmware model of a model file (see [`model_image`]).
pub fn firmware_model(
    model: &Path,
    fem: Option<&Path>,
    o: &ExportOptions,
) -> Result<FirmwareModel> {
    let text =
        std::fs::read_to_string(model).with_context(|| format!("reading {}", model.display()))?;
    let shown = model.display().to_string();
    let firmware = if text.contains(piezo_sim::file::FORMAT) {
        if fem.is_some() {
            bail!("{shown} is a firmware model (it carries its tables): drop --fem");
        }
        FirmwareModel::parse(&text, &shown).map_err(anyhow::Error::msg)?
    } else {
        let Some(fem) = fem else {
            bail!("{shown} is a calibrated model: give the stage's FEM tables with --fem FEM.csv");
        };
        let m = HostModel::read(model)?;
        let maps = crate::cli::stage_maps(&m, model, fem)?;
        let settings = LoopSettings::for_model(&m, o);
        export::export(&m, model, &maps, &settings)?.model
    };
    Ok(firmware)
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// `fpi board load`.
pub fn load(c: &mut Client, image: &[u8], store: bool) -> Result<()> {
    let pb = bar(image.len() as u64, "upload");
    let tick = c.upload(image, store, |n| pb.set_position(n as u64))?;
    pb.finish_and_clear();
    let m = c.model()?;
    println!(
        "model {:08x} ({} bytes) running since tick {tick}{}",
        m.crc,
        image.len(),
        match (store, m.stored) {
            (true, Some((g, _))) => format!("; stored in flash as generation {g}"),
            _ => String::new(),
        }
    );
    Ok(())
}

/// `fpi board status`.
pub fn status(c: &mut Client) -> Result<()> {
    let h = c.hello().clone();
    let s = c.status()?;
    let m = c.model()?;
    let k = c.counters()?;
    let rate = h.rate_hz as f64;
    println!(
        "board: {}, firmware {}, protocol {}, control at {} Hz; room for {} operators, {} creep \
         terms, {} table intervals",
        match h.board {
            BoardKind::Driver => "STM32F405 driver board",
            BoardKind::Emulated if c.port_name() == super::inprocess::PORT_NAME => {
                "emulated board's firmware built for this host (in-process, virtual stage)"
            }
            BoardKind::Emulated => "emulated board (QEMU netduinoplus2, virtual stage)",
        },
        h.firmware,
        h.protocol,
        h.rate_hz,
        h.capacity[0],
        h.capacity[1],
        h.capacity[2]
    );
    println!(
        "started by: {}; flash slots at start-up: {}",
        match h.reset {
            ResetReason::PowerOn => "power-on",
            ResetReason::Pin => "the reset pin",
            ResetReason::Command => "a reset command",
            ResetReason::Watchdog => "THE WATCHDOG (a task hung)",
            ResetReason::BrownOut => "a brown-out",
            ResetReason::Unknown => "unknown",
        },
        m.slots
            .iter()
            .map(|s| match s {
                SlotReport::Empty => "empty".to_string(),
                SlotReport::Valid(g) => format!("model generation {g}"),
                SlotReport::Damaged => "DAMAGED (ignored)".to_string(),
                SlotReport::Refused(g) => format!("generation {g} REFUSED by the validator"),
            })
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "model: {:08x}, {}; {} operators, {} creep terms{}{}; stroke {:.3}–{:.3} µm, safe at {:.3} V",
        m.crc,
        match m.origin {
            Origin::Factory => "factory default".to_string(),
            Origin::Stored(g) => format!("read from flash (generation {g})"),
            Origin::Received => "received over the link".to_string(),
        },
        m.size[0],
        m.size[1],
        if m.maps[0] { ", soft dead zone" } else { "" },
        if m.maps[1] { ", saturation" } else { "" },
        real(m.window[0]),
        real(m.window[1]),
        real(m.window[2]),
    );
    match m.feedback {
        None => println!("feedback: none in this model (open loop only; `fpi tune` adds it)"),
        Some(f) => println!(
            "feedback: kp {:.4}, ki {:.1}/s, correction within ±{:.3} µm; position sensor \
             {:.2}–{:.2} µm, tolerance {:.3} µm",
            f[0] as f64 / (1u64 << 24) as f64,
            f[1] as f64 / (1u64 << 24) as f64 * rate,
            real(f[2]),
            real(f[3]),
            real(f[4]),
            real(f[5]),
        ),
    }
    print_state(&s, rate);
    println!(
        "link: {} requests, {} refused; {} malformed ({} CRC errors, {} too long), {} of another \
         protocol version, {} unknown commands",
        k.requests, k.refused, k.malformed, k.crc_errors, k.overlong, k.version, k.unknown
    );
    Ok(())
}

/// The loop's mode and drive, for people.
pub fn loop_text(mode: LoopMode, compensated: bool) -> &'static str {
    match (mode, compensated) {
        (LoopMode::Open, true) => "open loop, compensated drive (inverse FPI)",
        (LoopMode::Open, false) => "open loop, uncompensated drive (straight line)",
        (LoopMode::Closed, _) => "closed loop on the position sensor, inverse FPI feedforward",
        (LoopMode::FeedbackOnly, _) => "closed loop on the position sensor, feedback only",
    }
}

/// A loop mode by name: `open`, `closed` or `feedback`.
pub fn loop_mode(name: &str) -> Result<LoopMode> {
    Ok(match name {
        "open" => LoopMode::Open,
        "closed" => LoopMode::Closed,
        "feedback" | "feedback-only" => LoopMode::FeedbackOnly,
        _ => bail!("loop {name:?}: open, closed or feedback"),
    })
}

/// `fpi board loop`: opens or closes the loop, without a jump.
pub fn set_loop(c: &mut Client, mode: LoopMode) -> Result<()> {
    let tick = c.ack(&Command::Loop { mode })?;
    let s = c.status()?;
    println!("from tick {tick}: {}", loop_text(mode, s.compensated));
    Ok(())
}

/// The loop's state, for people.
pub fn print_state(s: &Status, rate: f64) {
    println!(
        "tick {} ({:.3} s): reference {:.4} µm, estimate {:.4} µm, position sensor {:.4} µm, \
         setpoint {:.3} V, force {:.2} N; amplifier {}",
        s.tick,
        s.tick as f64 / rate,
        real(s.signals[0]),
        real(s.signals[1]),
        real(s.signals[4]),
        real(s.signals[2]),
        real(s.signals[3]),
        if s.amplifier_on { "on" } else { "off" }
    );
    println!(
        "source: {:?}{}, {}; host supervision {}",
        s.source,
        if s.approaching { " (approaching)" } else { "" },
        loop_text(s.loop_mode, s.compensated),
        if s.supervision[0] == 0 {
            "off".to_string()
        } else {
            format!(
                "{:.0} ms (last request {:.0} ms ago)",
                s.supervision[0] as f64 / rate * 1e3,
                s.supervision[1] as f64 / rate * 1e3
            )
        }
    );
    match s.fault {
        None => println!("state: running"),
        Some(f) => {
            let what = Fault::from_code(f.code).map_or("unknown fault", |f| f.message());
            let safe = f
                .safe_at
                .map_or("still ramping to the safe voltage".to_string(), |t| {
                    format!("at the safe voltage since tick {t}")
                });
            if f.code == Fault::Stopped as u8 {
                println!("state: parked ({safe}); a motion command re-arms it");
            } else {
                println!(
                    "state: FAULT since tick {}: {what}; {safe}; clear it with `clear-fault`",
                    f.at
                );
            }
        }
    }
    println!(
        "stream: {} points queued, {} free, {} received, {} underrun ticks; recorder: {}, {} \
         samples kept, {} dropped, {} waiting; late control ticks: {}",
        s.stream[0],
        s.stream[1],
        s.stream[2],
        s.stream[3],
        if s.recorder[0] == 1 {
            "recording"
        } else {
            "idle"
        },
        s.recorder[1],
        s.recorder[2],
        s.recorder[3],
        s.overruns
    );
}

/// `fpi board record`: records every `decimation`-th tick for `seconds` of board
/// time into a CSV.
pub fn record(c: &mut Client, seconds: f64, decimation: u16, out: &Path) -> Result<Recording> {
    let rate = c.rate_hz();
    let ticks = (seconds * rate).round() as u32;
    let start = c.ack(&Command::Record {
        decimation,
        signals: signal::ALL,
    })?;
    let pb = bar(ticks as u64, "record");
    let mut rec = Recording {
        rate_hz: rate,
        signals: signal::ALL,
        ..Recording::default()
    };
    let started = Instant::now();
    loop {
        let (samples, dropped) = c.drain()?;
        rec.samples.extend(samples);
        rec.dropped = dropped;
        let now = c.status()?.tick;
        pb.set_position(now.saturating_sub(start).min(ticks) as u64);
        if now >= start + ticks {
            break;
        }
        if started.elapsed() > Duration::from_secs_f64(seconds * 20.0 + 30.0) {
            bail!("the board's clock does not advance (tick {now})");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    c.ack(&Command::RecordStop)?;
    let (samples, dropped) = c.drain()?;
    rec.samples.extend(samples);
    rec.dropped = dropped;
    rec.samples.retain(|s| s.tick < start + ticks);
    pb.finish_and_clear();
    rec.write_csv(out)?;
    println!(
        "{} samples ({} s at {:.0} Hz) written to {}; {} dropped",
        rec.samples.len(),
        seconds,
        rate / decimation as f64,
        out.display(),
        rec.dropped
    );
    if rec.dropped > 0 {
        eprintln!(
            "warning: the board dropped {} samples (the link could not keep up): raise --decimation",
            rec.dropped
        );
    }
    Ok(rec)
}

/// Reads column `x_ref_um` of a CSV, µm.
pub fn read_points(path: &Path) -> Result<Vec<f64>> {
    let bytes = crate::data::read_bytes(path)?;
    let mut r = csv::Reader::from_reader(bytes.as_slice());
    let col = r
        .headers()
        .with_context(|| format!("{}: no header", path.display()))?
        .iter()
        .position(|h| h.trim() == "x_ref_um")
        .with_context(|| format!("{}: no column x_ref_um", path.display()))?;
    let mut out = Vec::new();
    for (k, rec) in r.records().enumerate() {
        let rec = rec.with_context(|| format!("{}:{}", path.display(), k + 2))?;
        let v = rec.get(col).unwrap_or("").trim();
        let x: f64 = v
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .with_context(|| {
                format!(
                    "{}:{}: column x_ref_um: {v:?} is not a number",
                    path.display(),
                    k + 2
                )
            })?;
        out.push(x);
    }
    if out.is_empty() {
        bail!("{}: no points", path.display());
    }
    Ok(out)
}

/// `fpi board stream`.
pub fn stream(c: &mut Client, points: &[f64], interval: u16) -> Result<()> {
    let pb = bar(points.len() as u64, "stream");
    let r = c.stream(points, interval, |n| pb.set_position(n as u64), |_| Ok(()))?;
    pb.finish_and_clear();
    println!(
        "{} points streamed from tick {} ({:.3} s at {} ticks per point); {} underrun ticks",
        r.points,
        r.started,
        r.points as f64 * interval as f64 / c.rate_hz(),
        interval,
        r.underruns
    );
    Ok(())
}

/// A waveform shape by name.
pub fn shape(name: &str) -> Result<Shape> {
    Ok(match name {
        "sine" => Shape::Sine,
        "triangle" => Shape::Triangle,
        "cosine" | "raised-cosine" => Shape::RaisedCosine,
        _ => bail!("--shape {name:?}: sine, triangle or cosine"),
    })
}

/// What `fpi board bench` sets on the emulated board's virtual bench (also its
/// command-line options).
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct BenchSettings {
    /// Voltage on the analog reference input, 0–3.3 V.
    #[arg(long)]
    pub analog_v: Option<f64>,
    /// The force sensor: ok, open (a broken wire) or stuck (frozen reading).
    #[arg(long)]
    pub sensor: Option<String>,
    /// A step added to the force reading, N (a loose connector; 0 removes it).
    #[arg(long)]
    pub force_offset_n: Option<f64>,
    /// Make this many control ticks overrun their period.
    #[arg(long)]
    pub stall_ticks: Option<u16>,
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

/// `fpi board bench`: the emulated board's virtual bench (a real board refuses).
pub fn bench(c: &mut Client, b: &BenchSettings) -> Result<()> {
    use fpi_firmware::link::protocol::BenchOrder;
    if *b == BenchSettings::default() {
        bail!(
            "nothing to set: --analog-v V, --sensor ok|open|stuck, --force-offset-n N, \
             --stall-ticks T, --damage-stored, --position-sensor ok|open|stuck or \
             --stage nominal|built|VARIANT.toml"
        );
    }
    let (analog_v, sensor) = (b.analog_v, b.sensor.as_deref());
    if let Some(v) = analog_v {
        if !(0.0..=3.3).contains(&v) {
            bail!("--analog-v {v}: the input spans 0–3.3 V");
        }
        let counts = (v / 3.3 * fpi_firmware::frontend::ADC_MAX as f64).round() as u16;
        c.bench(BenchOrder::Analog(counts))?;
        println!("analog input at {v} V ({counts} counts)");
    }
    if let Some(s) = sensor {
        let orders: &[BenchOrder] = match s {
            "ok" => &[
                BenchOrder::SensorOpen(false),
                BenchOrder::SensorStuck(false),
            ],
            "open" => &[BenchOrder::SensorOpen(true)],
            "stuck" => &[BenchOrder::SensorStuck(true)],
            _ => bail!("--sensor {s:?}: ok, open or stuck"),
        };
        for o in orders {
            c.bench(*o)?;
        }
        println!("force sensor {s}");
    }
    bench_faults(c, b)
}

/// The fault injections of [`bench`]: a force step, overrunning ticks, a damaged
/// stored model.
fn bench_faults(c: &mut Client, b: &BenchSettings) -> Result<()> {
    use fpi_firmware::link::protocol::BenchOrder;
    if let Some(n) = b.force_offset_n {
        if !n.is_finite() || n.abs() > 4096.0 {
            bail!("--force-offset-n {n}: a finite step within ±4096 N");
        }
        let tick = c.bench(BenchOrder::SensorOffset(bits(n)))?;
        println!("force reading offset by {n} N from tick {tick}");
    }
    if let Some(t) = b.stall_ticks {
        let tick = c.bench(BenchOrder::Stall(t))?;
        println!("{t} control ticks overrun their period from tick {tick}");
    }
    if b.damage_stored {
        c.bench(BenchOrder::DamageStored)?;
        println!("the newest stored model is damaged: `fpi board reset` shows the start-up check");
    }
    bench_position(c, b)
}

/// The position sensor's faults and the choice of virtual stage of [`bench`].
fn bench_position(c: &mut Client, b: &BenchSettings) -> Result<()> {
    use fpi_firmware::link::protocol::BenchOrder;
    if let Some(s) = b.position_sensor.as_deref() {
        let orders: &[BenchOrder] = match s {
            "ok" => &[
                BenchOrder::PositionOpen(false),
                BenchOrder::PositionStuck(false),
            ],
            "open" => &[BenchOrder::PositionOpen(true)],
            "stuck" => &[BenchOrder::PositionStuck(true)],
            _ => bail!("--position-sensor {s:?}: ok, open or stuck"),
        };
        for o in orders {
            c.bench(*o)?;
        }
        println!("position sensor {s}");
    }
    if let Some(s) = b.stage.as_deref() {
        let v = super::variant::parse(s)?;
        let tick = c.bench(BenchOrder::Stage(v))?;
        println!(
            "virtual stage: stage A, {}, at rest from tick {tick}",
            super::variant::describe(&v)
        );
    }
    Ok(())
}
