//! `fpi board …`: the commands that drive a board (or the emulated board)
//! through the same [`Client`] the tests and the demo use. The binary parses the
//! arguments; every handler is here. Each command that sets the stage in motion
//! checks its effect ([`Client::order`]): a command the board took and faulted
//! on fails with the fault.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{anyhow, bail, Context, Result};
use fpi_protocol::record::signal;
use fpi_protocol::{BoardKind, Command, LoopMode, Origin, ResetReason, SlotReport, Status};
use indicatif::{ProgressBar, ProgressStyle};
use piezo_fpi::control::Fault;
use piezo_fpi::q::LoopGain;
use piezo_sim::file::{AxesModel, FirmwareModel};

use crate::board::budget::Budget;
use crate::board::client::{axis_name, real, Client};
use crate::board::motion::{self, Until};
use crate::board::recording::{AxesRecording, Recording};
use crate::board::restore::or_restore;
use crate::board::{commands, inprocess, mass, noise};
use crate::data::Quoted;
use crate::method::export::{self, ExportOptions, LoopSettings};
use crate::method::model::HostModel;

/// The image of a model file for the board: a firmware model file
/// (`format = "piezo-fpi-firmware/1"`, from `fpi export`) as it is, or a
/// calibrated model (`fpi calibrate`) exported with the stage's FEM tables and the
/// loop settings, as `fpi export` would.
pub fn model_image(model: &Path, fem: Option<&Path>, o: &ExportOptions) -> Result<Vec<u8>> {
    model_and_image(model, fem, o).map(|(_, image)| image)
}

/// The firmware model of a model file ([`firmware_model`]) and its image
/// ([`model_image`]): what `fpi board load` uploads and, with
/// `--match-mass`, reads the stage's mode from.
pub fn model_and_image(
    model: &Path,
    fem: Option<&Path>,
    o: &ExportOptions,
) -> Result<(FirmwareModel, Vec<u8>)> {
    let fw = firmware_model(model, fem, o)?;
    let image = fw
        .image()
        .map_err(|e| anyhow!("{}: {e}", model.display()))?;
    Ok((fw, image))
}

/// A model file as a board takes it.
pub enum Loadable {
    /// One axis's model and its image.
    One(Box<FirmwareModel>, Vec<u8>),
    /// The file of several axes.
    Axes(Box<AxesModel>),
}

impl Loadable {
    /// The model of each of `n` axes: the one model on every axis, or the
    /// file's models in axis order.
    pub fn every_axis(self, n: usize) -> Vec<FirmwareModel> {
        match self {
            Self::One(fw, _) => vec![*fw; n],
            Self::Axes(f) => f.models().into_iter().cloned().collect(),
        }
    }

    /// The model of `axis`: the one model, or the file's of that axis
    /// (`None` where the file has none).
    pub fn of_axis(self, axis: u8) -> Option<FirmwareModel> {
        match self {
            Self::One(fw, _) => Some(*fw),
            Self::Axes(f) => f.models().get(usize::from(axis)).map(|m| (*m).clone()),
        }
    }
}

/// The model file `model` as a board takes it: a file of several axes
/// (checked whole: [`AxesModel::parse`]), or one model ([`model_and_image`]).
pub fn loadable(model: &Path, fem: Option<&Path>, o: &ExportOptions) -> Result<Loadable> {
    let shown = model.display().to_string();
    let text = String::from_utf8(crate::data::read_bytes(model)?)
        .map_err(|_| anyhow!("{shown}: not a text file, so not a model file"))?;
    if model_file(&text, &shown)? != ModelFile::Axes {
        let (fw, image) = model_and_image(model, fem, o)?;
        return Ok(Loadable::One(Box::new(fw), image));
    }
    if fem.is_some() {
        bail!("{shown} is a model file of several axes (it carries its tables): drop --fem");
    }
    Ok(Loadable::Axes(Box::new(
        AxesModel::parse(&text, &shown).map_err(|e| anyhow!(e))?,
    )))
}

/// What a file given as a model is, by its `format` key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelFile {
    /// A firmware model file (`fpi export`).
    Firmware,
    /// A calibrated model (`fpi calibrate`).
    Calibrated,
    /// A model file of several axes (`fpi board autotune` of every axis).
    Axes,
}

/// What the file `shown` with text `text` is ([`ModelFile`]), or why it is no
/// model file these tools read: not TOML (a CSV table, e.g. an FEM export, by
/// its first line that is not a `#` comment; any other file that does not parse
/// is reported by the TOML error, with its line and column), no `format` key,
/// or a format of another version or of another file.
pub fn model_file(text: &str, shown: &str) -> Result<ModelFile> {
    let both = format!(
        "a model file is a calibrated model (`fpi calibrate`, format = {:?}) or a firmware \
         model (`fpi export`, format = {:?})",
        crate::method::model::FORMAT,
        piezo_sim::file::FORMAT
    );
    let table: toml::Table = toml::from_str(text).map_err(|e| {
        // A model's header comment may hold commas: the first line of content
        // tells a table from TOML.
        let first = text
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty() && !l.starts_with('#'))
            .unwrap_or("");
        if first.contains(',') && !first.contains('=') && !first.starts_with('[') {
            anyhow!(
                "{shown}: a CSV table (header {}), not a model: {both}; an FEM table goes with \
                 --fem",
                Quoted(first)
            )
        } else {
            anyhow!(
                "{}; {both}",
                piezo_sim::quote::toml_error(shown, "model file", text, &e)
            )
        }
    })?;
    let format = match table.get("format") {
        None => bail!("{shown}: no `format` key, so not a model file: {both}"),
        Some(f) => f.as_str().unwrap_or(""),
    };
    let family = |f: &str| f.split('/').next().unwrap_or("").to_string();
    match format {
        f if f == piezo_sim::file::FORMAT => Ok(ModelFile::Firmware),
        f if f == crate::method::model::FORMAT => Ok(ModelFile::Calibrated),
        f if f == piezo_sim::file::AXES_FORMAT => Ok(ModelFile::Axes),
        f if [piezo_sim::file::FORMAT, crate::method::model::FORMAT]
            .iter()
            .any(|known| family(known) == family(f)) =>
        {
            bail!(
                "{shown}: format = {}: a version these tools do not read ({both})",
                Quoted(f)
            )
        }
        f => bail!("{shown}: format = {}: not a model file: {both}", Quoted(f)),
    }
}

/// The firmware model of a model file (see [`model_image`]).
pub fn firmware_model(
    model: &Path,
    fem: Option<&Path>,
    o: &ExportOptions,
) -> Result<FirmwareModel> {
    let bytes = crate::data::read_bytes(model)?;
    let shown = model.display().to_string();
    let text = String::from_utf8(bytes)
        .map_err(|_| anyhow!("{shown}: not a text file, so not a model file"))?;
    match (model_file(&text, &shown)?, fem) {
        (ModelFile::Axes, _) => bail!(
            "{shown} is a model file of several axes (format = {:?}): `fpi board load` loads it \
             whole, and `fpi board autotune` on its board tunes from it; elsewhere give one \
             axis's model",
            piezo_sim::file::AXES_FORMAT
        ),
        (ModelFile::Firmware, Some(_)) => {
            bail!("{shown} is a firmware model (it carries its tables): drop --fem")
        }
        (ModelFile::Firmware, None) => FirmwareModel::parse(&text, &shown).map_err(|e| anyhow!(e)),
        (ModelFile::Calibrated, None) => {
            bail!("{shown} is a calibrated model: give the stage's FEM tables with --fem FEM.csv")
        }
        (ModelFile::Calibrated, Some(fem)) => {
            let m = HostModel::read(model)?;
            let maps = super::stage_maps(&m, model, fem)?;
            let settings = LoopSettings::for_model(&m, o);
            Ok(export::export(&m, model, &maps, &settings)?.model)
        }
    }
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

/// `fpi board load` (`match_mass`: then [`mass::match_mass`]).
pub fn load(
    c: &mut Client,
    (fw, image): &(FirmwareModel, Vec<u8>),
    store: bool,
    match_mass: bool,
) -> Result<()> {
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
    if match_mass {
        println!("{}", mass::describe(&mass::match_mass(c, fw)?));
    }
    Ok(())
}

/// `fpi board load` of a model file: one axis's model onto the addressed
/// axis ([`load`]), or a file of several axes whole
/// ([`crate::board::axes::load`]).
pub fn load_file(c: &mut Client, file: &Loadable, store: bool, match_mass: bool) -> Result<()> {
    let axes = match file {
        Loadable::One(fw, image) => {
            return load(c, &((**fw).clone(), image.clone()), store, match_mass)
        }
        Loadable::Axes(a) => a,
    };
    if match_mass {
        bail!(
            "--match-mass measures one axis: load the file of several axes without it, then \
             `fpi board --axis A load` that axis's model with it"
        );
    }
    crate::board::axes::load(c, axes, store, |axis, tick| {
        println!(
            "axis {}: its model running since tick {tick}",
            axis_name(axis)
        )
    })?;
    println!(
        "every axis's model loaded{}, and the decoupling of its coupling set (every axis parked)",
        if store {
            "; x's stored in flash (the flash keeps the first axis's model)"
        } else {
            ""
        }
    );
    Ok(())
}

/// `fpi board status`.
pub fn status(c: &mut Client) -> Result<()> {
    print!("{}", status_text(c)?);
    Ok(())
}

/// What `fpi board status` prints: the board, its model, the loop's state and
/// the link's counters, one line each.
pub fn status_text(c: &mut Client) -> Result<String> {
    let mut out = String::new();
    let h = c.hello().clone();
    let s = c.status()?;
    let m = c.model()?;
    let k = c.counters()?;
    let rate = h.rate_hz as f64;
    let _ = writeln!(
        out,
        "board: {}, firmware {}, protocol {}, control at {} Hz; room for {} operators, {} creep \
         terms, {} table intervals",
        match h.board {
            BoardKind::Driver => "STM32F405 driver board",
            BoardKind::Emulated if inprocess::is_in_process(c.port_name()) => {
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
    if h.axes > 1 {
        let names: Vec<String> = (0..h.axes).map(axis_name).collect();
        let _ = writeln!(
            out,
            "axis: {} of {} ({}); --axis names another",
            axis_name(c.axis()),
            h.axes,
            names.join(", ")
        );
    }
    let _ = writeln!(
        out,
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
    let _ = writeln!(
        out,
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
        None => {
            let _ = writeln!(
                out,
                "feedback: none in this model (open loop only; `fpi tune` adds it)"
            );
        }
        Some(f) => {
            let _ = writeln!(
                out,
                "feedback: kp {:.4}, ki {:.1}/s, correction within ±{:.3} µm; position sensor \
             {:.2}–{:.2} µm, tolerance {:.3} µm",
                LoopGain::from_bits(f[0]).to_num::<f64>(),
                LoopGain::from_bits(f[1]).to_num::<f64>() * rate,
                real(f[2]),
                real(f[3]),
                real(f[4]),
                real(f[5]),
            );
        }
    }
    out.push_str(&state_text(&s, rate));
    if let Some(a) = s.fault_axis.filter(|_| h.axes > 1) {
        let _ = writeln!(
            out,
            "every axis parked by axis {}'s fault (`fpi board --axis {} status` says which)",
            axis_name(a),
            axis_name(a)
        );
    }
    if s.fault.is_some_and(|f| f.code == Fault::Oscillation as u8) {
        // The model's half swing watches a closed loop (the damping alone is
        // watched at the default): the model is read only then.
        let closed = s.loop_mode != LoopMode::Open;
        if let Some(h) = closed.then(|| noise::model_watch_swing(c)).flatten() {
            let _ = writeln!(out, "  {}", noise::watch_hint(h));
        }
        if s.damping.is_some() {
            let _ = writeln!(out, "  {}", noise::DAMPING_HINT);
        }
    }
    let _ = writeln!(
        out,
        "link: {} ({} B/s{}); {} requests, {} refused; {} malformed ({} CRC errors, {} too \
         long), {} of another protocol version, {} unknown commands",
        h.link.name(),
        h.link.bytes_per_s(),
        if h.board == BoardKind::Emulated {
            ", paced in board time"
        } else {
            ""
        },
        k.requests,
        k.refused,
        k.malformed,
        k.crc_errors,
        k.overlong,
        k.version,
        k.unknown
    );
    Ok(out)
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

/// `fpi board loop`: opens or closes the loop, without a jump.
pub fn set_loop(c: &mut Client, mode: &str) -> Result<()> {
    let tick = commands::set_loop(c, mode)?;
    let s = c.status()?;
    println!(
        "from tick {tick}: {}",
        loop_text(s.loop_mode, s.compensated)
    );
    Ok(())
}

/// The loop's state, for people.
pub fn print_state(s: &Status, rate: f64) {
    print!("{}", state_text(s, rate));
}

/// The damping, the shaping and the learned mass ratio, where the model has
/// them: `damping on, shaping on, stage mass 1.020 × the tuned one's (learned)`.
fn loops_text(s: &Status) -> Option<String> {
    let on = |b: bool| if b { "on" } else { "off" };
    let mut parts = Vec::new();
    if let Some(d) = s.damping {
        parts.push(format!("damping {}", on(d)));
    }
    if let Some(sh) = s.shaping {
        parts.push(format!("shaping {}", on(sh)));
    }
    match s
        .lead_ratio
        .map(|(b, a)| (piezo_fpi::q::LeadRatio::from_bits(b).to_num::<f64>(), a))
    {
        Some((b, true)) => parts.push(format!("stage mass {b:.3} × the tuned one's (learned)")),
        Some((b, false)) => parts.push(format!("lead fit {b:.3} (not applied: no lead baseline)")),
        None => {}
    }
    (!parts.is_empty()).then(|| parts.join(", "))
}

/// The loop's state, for people: what [`print_state`] prints.
pub fn state_text(s: &Status, rate: f64) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
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
    let _ = writeln!(
        out,
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
    if let Some(line) = loops_text(s) {
        let _ = writeln!(out, "{line}");
    }
    match s.fault {
        None => {
            let _ = writeln!(out, "state: running");
        }
        Some(f) => {
            let what = Fault::from_code(f.code).map_or("unknown fault", |f| f.message());
            let safe = f
                .safe_at
                .map_or("still ramping to the safe voltage".to_string(), |t| {
                    format!("at the safe voltage since tick {t}")
                });
            if f.code == Fault::Stopped as u8 {
                let _ = writeln!(out, "state: parked ({safe}); a motion command re-arms it");
            } else {
                let _ = writeln!(
                    out,
                    "state: FAULT since tick {}: {what}; {safe}; clear it with `clear-fault`",
                    f.at
                );
            }
        }
    }
    let _ = writeln!(
        out,
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
    let _ = writeln!(
        out,
        "reference governor: {} ticks governed since start-up (the sources asked for more than \
         the stage can take within its stroke); {} stale streamed points dropped by a motion",
        s.governed_ticks, s.ended_points
    );
    let armed: Vec<&str> = [("a motion", s.armed[0]), ("a recording", s.armed[1])]
        .iter()
        .filter(|(_, on)| *on)
        .map(|(what, _)| *what)
        .collect();
    if !armed.is_empty() {
        let _ = writeln!(
            out,
            "armed for the trigger input's next rising edge: {}",
            armed.join(" and ")
        );
    }
    out
}

/// `fpi board record` or `fpi board stream` was stopped by Ctrl-C (or
/// `SIGTERM`, [`catch_ctrl_c`]): what was
/// recorded is written, the board's recorder stopped, the stage left as it was;
/// or the stream ended with the board holding. The binary exits with
/// status 130, as a shell does for an interrupted command.
#[derive(Debug, Clone, PartialEq)]
pub struct Interrupted {
    /// What was kept, for people.
    pub kept: String,
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted: {}", self.kept)
    }
}

impl std::error::Error for Interrupted {}

/// Set by Ctrl-C (SIGINT), `SIGTERM` or `SIGHUP` once [`catch_ctrl_c`] has run.
static CTRL_C: AtomicBool = AtomicBool::new(false);

/// From now on Ctrl-C (SIGINT), `SIGTERM` (`kill`, a service manager) and
/// `SIGHUP` (the terminal closed) set the `CTRL_C` flag instead of ending the
/// process, so that the command stops the board's side in order and keeps
/// what it recorded; a second one ends it (status 130). (`SIGKILL` cannot be
/// caught: a `record` killed so leaves the board's recorder running, and the
/// next command that records restarts it afresh.) Installed once per process.
pub fn catch_ctrl_c() -> Result<()> {
    static INSTALLED: std::sync::OnceLock<std::result::Result<(), String>> =
        std::sync::OnceLock::new();
    INSTALLED
        .get_or_init(|| {
            ctrlc::set_handler(|| {
                if CTRL_C.swap(true, Ordering::SeqCst) {
                    std::process::exit(130);
                }
            })
            .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(|e| anyhow!("catching Ctrl-C and SIGTERM: {e}"))
}

/// Whether Ctrl-C, `SIGTERM` or `SIGHUP` came since [`catch_ctrl_c`].
pub fn stop_asked() -> bool {
    CTRL_C.load(Ordering::SeqCst)
}

/// `fpi board record` without `--seconds`: records every `decimation`-th tick
/// until stopped (Ctrl-C, SIGTERM or SIGHUP), the CSV written as the samples come
/// (into a temporary file renamed to `out` at the end: memory stays flat however
/// long it runs). Every sample's tick is checked, so a loss is counted and
/// reported, never silent.
pub fn record_until_stopped(
    c: &mut Client,
    decimation: u16,
    signals: u8,
    out: &Path,
) -> Result<()> {
    catch_ctrl_c()?;
    let rate = c.rate_hz();
    let budget = Budget::new(c.hello(), signals, decimation, 1.0);
    if let Some(why) = budget.beyond_the_link() {
        anyhow::bail!(
            "--decimation {decimation}: recording until stopped: {why}: raise --decimation, or \
             give --seconds (the board's ring holds a short recording)"
        );
    }
    let header = Recording {
        rate_hz: rate,
        signals,
        ..Recording::default()
    };
    println!(
        "recording every {decimation}th tick ({:.0} Hz) into {} until stopped (Ctrl-C)",
        rate / decimation as f64,
        out.display()
    );
    let (mut n, mut failed, mut counts) = (0usize, None, None);
    crate::output::write_atomic_with(out, |w| {
        header.write_header(w)?;
        let r = crate::board::live::follow(
            c,
            signals,
            decimation,
            |samples| {
                n += samples.len();
                header.write_samples(w, samples).map_err(Into::into)
            },
            stop_asked,
        );
        match r {
            Ok((_, k)) => {
                counts = Some(k);
                Ok(())
            }
            Err(e) => {
                let m = format!("{e:#}");
                failed = Some(e);
                Err(std::io::Error::other(m))
            }
        }
    })
    .map_err(|e| failed.take().unwrap_or(e))?;
    let counts = counts.unwrap_or_default();
    println!(
        "{n} samples ({:.3} s at {:.0} Hz) written to {}; the recorder is stopped{}",
        n as f64 * decimation as f64 / rate,
        rate / decimation as f64,
        out.display(),
        if counts.whole() {
            ", nothing lost".to_string()
        } else {
            format!("; lost: {}", counts.losses())
        }
    );
    Ok(())
}

/// `fpi board record`: records every `decimation`-th tick for `seconds` of board
/// time into a CSV ([`commands::record`]). Ctrl-C stops it early: the recorder is
/// stopped, what it recorded is written (a valid CSV) and the error is
/// [`Interrupted`].
pub fn record(
    c: &mut Client,
    seconds: f64,
    decimation: u16,
    signals: u8,
    out: &Path,
) -> Result<Recording> {
    catch_ctrl_c()?;
    let rate = c.rate_hz();
    let budget = Budget::new(c.hello(), signals, decimation, seconds);
    if budget.fits() {
        println!("{}", budget.describe(c.hello().rate_hz));
    } else {
        eprintln!("warning: {}", budget.describe(c.hello().rate_hz));
    }
    let pb = bar((seconds * rate).round() as u64, "record");
    let r = commands::record(
        c,
        seconds,
        decimation,
        signals,
        |done, _| pb.set_position(u64::from(done)),
        stop_asked,
    )?;
    pb.finish_and_clear();
    let rec = r.recording;
    rec.write_csv(out)?;
    if r.stopped {
        let kept = format!(
            "{} samples ({:.3} s of the {seconds} s asked for, at {:.0} Hz) written to {}; \
             the recorder is stopped and the stage left as it was",
            rec.samples.len(),
            r.seconds,
            rate / decimation as f64,
            out.display()
        );
        return Err(Interrupted { kept }.into());
    }
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

/// `fpi board stream` ([`commands::stream`]); with `record`, records every
/// tick of it into that CSV ([`motion::record`]). Ctrl-C stops it with the
/// board holding where the reference was (and the host supervision the stream
/// switched on off again); the error is then [`Interrupted`].
pub fn stream(c: &mut Client, points: &[f64], interval: u16, record: Option<&Path>) -> Result<()> {
    catch_ctrl_c()?;
    let pb = bar(points.len() as u64, "stream");
    let stop = stop_asked;
    let r = match record {
        None => commands::stream(c, points, interval, |n| pb.set_position(n as u64), stop)?,
        Some(out) => {
            // The stream stops itself on Ctrl-C; the recording goes on until
            // the board holds.
            let m =
                motion::record_stream(c, points, interval, |n| pb.set_position(n as u64), stop)?;
            pb.finish_and_clear();
            if let commands::Streamed::Stopped { sent, held_at } = m.result {
                m.recording.write_csv(out)?;
                return Err(Interrupted {
                    kept: format!(
                        "{sent} of {} points sent; the board holds from tick {held_at}; {} ticks \
                         recorded to {}",
                        points.len(),
                        m.recording.samples.len(),
                        out.display()
                    ),
                }
                .into());
            }
            recorded(m, out)?
        }
    };
    pb.finish_and_clear();
    match r {
        commands::Streamed::Played(r) => {
            let from = if r.armed {
                format!("armed at tick {}, started on the trigger input", r.started)
            } else {
                format!("from tick {}", r.started)
            };
            println!(
                "{} points streamed {from} ({:.3} s at {} ticks per point); {} underrun ticks",
                r.points,
                r.points as f64 * interval as f64 / c.rate_hz(),
                interval,
                r.underruns
            );
            Ok(())
        }
        commands::Streamed::Stopped { sent, held_at } => Err(Interrupted {
            kept: format!(
                "{sent} of {} points sent; the board holds from tick {held_at}",
                points.len()
            ),
        }
        .into()),
    }
}

pub use crate::board::commands::{loop_mode, shape, BenchSettings, WAVE_STEP_HZ};

/// `fpi board bench`: the emulated board's virtual bench (a real board refuses).
pub fn bench(c: &mut Client, b: &BenchSettings) -> Result<()> {
    for line in commands::bench(c, b)? {
        println!("{line}");
    }
    Ok(())
}

/// Opens the board on `port` (`--port`: a serial device, `tcp:HOST:PORT` or
/// `virtual`).
pub fn open(port: &str) -> Result<Client> {
    Client::open(port).with_context(|| format!("--port {}", Quoted(port)))
}

/// `fpi board move --x … --y …`: each axis named ramps to its target at
/// `speed` µm/s, all from the same tick, and holds it; with `record`,
/// every axis of it is recorded into that CSV (`<signal>@<axis>` columns),
/// until the axis with the longest way holds its target.
pub fn move_axes(
    c: &mut Client,
    targets: [Option<f64>; 3],
    speed: f64,
    record: Option<&Path>,
) -> Result<()> {
    let cmd = commands::move_axes_command(targets, speed)?;
    let named: Vec<String> = targets
        .iter()
        .enumerate()
        .filter_map(|(i, t)| t.map(|um| format!("{} to {um} µm", axis_name(i as u8))))
        .collect();
    let Some(out) = record else {
        let t = c.order(&cmd)?;
        println!("moving {} at {speed} µm/s from tick {t}", named.join(", "));
        return Ok(());
    };
    // The axis with the longest way: the move has ended when it holds.
    let here = c.axis();
    let mut longest = (0.0, here);
    for (i, t) in targets.iter().enumerate() {
        if let Some(to) = *t {
            c.on_axis(i as u8)?;
            let way = (to - real(c.status()?.signals[0])).abs();
            if way >= longest.0 {
                longest = (way, i as u8);
            }
        }
    }
    c.on_axis(longest.1)?;
    catch_ctrl_c()?;
    let m = motion::record_every_axis(
        c,
        motion::EVERY_AXIS_SIGNALS,
        "the move",
        motion::move_seconds(0.0, longest.0, speed),
        Until::Rest,
        |c, _| Ok((c.ack(&cmd)?, ())),
        stop_asked,
    );
    c.on_axis(here)?;
    let m = m?;
    let rec = AxesRecording::split(&m.recording, usize::from(c.hello().axes));
    rec.write_csv(out)?;
    println!(
        "moved {} at {speed} µm/s from tick {}, every axis recorded to {} ({} samples dropped)",
        named.join(", "),
        m.start,
        out.display(),
        m.recording.dropped
    );
    match m.fault {
        Some(f) => Err(f),
        None => Ok(()),
    }
}

/// `fpi board move`: ramps to `um` at `speed` µm/s and holds it; with
/// `record`, records every tick of it into that CSV ([`motion::record`]).
pub fn move_to(c: &mut Client, um: f64, speed: f64, record: Option<&Path>) -> Result<()> {
    let Some(out) = record else {
        let t = commands::move_to(c, um, speed)?;
        println!("moving to {um} µm at {speed} µm/s from tick {t}");
        return Ok(());
    };
    let cmd = commands::move_command(c.axis(), um, speed)?;
    let from = real(c.status()?.signals[0]);
    catch_ctrl_c()?;
    let m = motion::record(
        c,
        "the move",
        motion::move_seconds(from, um, speed),
        Until::Rest,
        |c, _| Ok((c.ack(&cmd)?, ())),
        stop_asked,
    )?;
    println!("moved to {um} µm at {speed} µm/s from tick {}", m.start);
    recorded(m, out).map(|_| ())
}

/// `fpi board wave`: the waveform generator (`cycles` 0: until the next
/// command); with `record`, records every tick of it into that CSV for
/// `seconds` (default: until a finite wave has ended).
pub fn wave(
    c: &mut Client,
    shape_name: &str,
    amplitude_um: f64,
    offset_um: f64,
    freq_hz: f64,
    cycles: u32,
    record: Option<(&Path, Option<f64>)>,
) -> Result<()> {
    let Some((out, seconds)) = record else {
        let t = commands::wave(c, shape_name, amplitude_um, offset_um, freq_hz, cycles)?;
        println!("{shape_name} wave from tick {t} (after an approach to its start)");
        return Ok(());
    };
    let cmd = commands::wave_command(c, shape_name, amplitude_um, offset_um, freq_hz, cycles)?;
    let until = match (seconds, cycles) {
        (Some(s), _) => Until::seconds(s)?,
        (None, 0) => {
            return Err(commands::BadArgument {
                name: "seconds",
                cli: "--seconds",
                message: "--seconds: how long to record a wave that runs until the next command \
                          (--cycles 0); or give --cycles"
                    .into(),
            }
            .into())
        }
        (None, _) => Until::Rest,
    };
    // The approach to the wave's start takes a few milliseconds.
    let expected = f64::from(cycles) / freq_hz + 0.1;
    catch_ctrl_c()?;
    let m = motion::record(
        c,
        "the wave",
        expected,
        until,
        |c, _| Ok((c.ack(&cmd)?, ())),
        stop_asked,
    )?;
    println!(
        "{shape_name} wave from tick {} (after an approach to its start)",
        m.start
    );
    recorded(m, out).map(|_| ())
}

/// Writes the recording of a motion to `out` and says so; then the motion's
/// result, or [`Interrupted`] where Ctrl-C ended the recording, the fault the
/// board latched meanwhile, or the samples the board dropped.
fn recorded<T>(m: motion::Motion<T>, out: &Path) -> Result<T> {
    let rec = &m.recording;
    rec.write_csv(out)?;
    let seconds = rec.samples.len() as f64 / rec.rate_hz;
    let what = format!(
        "{} ticks ({seconds:.3} s from tick {}, every tick) recorded to {}",
        rec.samples.len(),
        m.start,
        out.display()
    );
    if m.stopped {
        return Err(Interrupted {
            kept: format!("{what}; the recorder is stopped; the motion goes on"),
        }
        .into());
    }
    if let Some(e) = m.fault {
        return Err(e.context(what));
    }
    if rec.dropped > 0 {
        bail!(
            "{what}, but the board dropped {} samples of it (the link could not keep up)",
            rec.dropped
        );
    }
    println!("{what}");
    Ok(m.result)
}

/// `fpi board safe|clear-fault|hold|analog|factory`: the command, checked for its
/// effect ([`Client::order`]), and what the board does from which tick.
pub fn simple(c: &mut Client, cmd: &Command<'_>) -> Result<()> {
    let t = c.order(cmd)?;
    match cmd {
        Command::Safe => println!("parking from tick {t}"),
        Command::ClearFault => println!("cleared at tick {t}; parked"),
        Command::Hold { .. } => println!("holding from tick {t}"),
        Command::Analog { .. } => println!("following the analog input from tick {t}"),
        Command::ModelFactory { .. } => println!("factory model from tick {t}"),
        _ => println!("done at tick {t}"),
    }
    Ok(())
}

/// `fpi board drive compensated|uncompensated`.
pub fn drive(c: &mut Client, mode: &str) -> Result<()> {
    let t = commands::drive(c, mode)?;
    println!("{mode} from tick {t}");
    Ok(())
}

/// `--signals NAME,…` as signal bits: the recording's columns named (none:
/// every signal of a default recording), or the name that is none.
pub fn signals_arg(names: &[String]) -> Result<u8> {
    use crate::board::recording;
    if names.is_empty() {
        return Ok(signal::ALL);
    }
    recording::signals_named(names.iter().map(String::as_str)).map_err(|name| {
        anyhow::anyhow!(
            "--signals {name}: no such signal (one of {})",
            recording::column_names().collect::<Vec<_>>().join(", ")
        )
    })
}

/// `fpi board damping on|off`.
pub fn damping(c: &mut Client, state: &str) -> Result<()> {
    let t = commands::damping(c, state)?;
    println!("active damping {state} from tick {t}");
    Ok(())
}

/// `fpi board get [KEY]`: one setting's value, or every setting's.
pub fn get(c: &mut Client, key: Option<&str>) -> Result<()> {
    use crate::board::settings;
    match key {
        Some(k) => println!("{}", c.setting(&settings::path(k)?)?),
        None => {
            let all = settings::read_all(c)?;
            let width = all
                .iter()
                .map(|(p, _)| p[1..].chars().count())
                .max()
                .unwrap_or(0);
            for (path, value) in all {
                let v = value.unwrap_or_else(|| "(the running model has none)".into());
                println!("{:<width$} {v}", &path[1..]);
            }
        }
    }
    Ok(())
}

/// `fpi board set KEY VALUE`.
pub fn set(c: &mut Client, key: &str, value: &str) -> Result<()> {
    use crate::board::settings;
    let path = settings::path(key)?;
    let t = c.set_setting(&path, &settings::json(value))?;
    println!("{} = {} from tick {t}", &path[1..], c.setting(&path)?);
    Ok(())
}

/// `fpi board trigger MODE [levels]`.
pub fn trigger(c: &mut Client, mode: &str, levels: &crate::board::trigger::Levels) -> Result<()> {
    use crate::board::trigger;
    let (t, s) = trigger::set(c, trigger::mode(mode)?, levels)?;
    println!("trigger output {} from tick {t}", trigger::describe(&s));
    Ok(())
}

/// `fpi board trigger-in off|motion|recorder|both`.
pub fn trigger_in(c: &mut Client, starts: &str) -> Result<()> {
    use crate::board::trigger;
    let t = trigger::set_input(c, trigger::starts(starts)?)?;
    println!("the trigger input's rising edge starts {starts} from tick {t}");
    Ok(())
}

/// `fpi board shaping on|off`.
pub fn shaping(c: &mut Client, state: &str) -> Result<()> {
    let t = commands::shaping(c, state)?;
    println!("reference shaping {state} from tick {t}");
    Ok(())
}

/// `fpi board supervise MS`.
pub fn supervise(c: &mut Client, ms: u32) -> Result<()> {
    commands::supervise(c, ms)?;
    if ms == 0 {
        println!("host supervision off");
    } else {
        println!("the stage parks if the host is silent for {ms} ms while it drives it");
    }
    Ok(())
}

/// Says so where the motion just ordered ended a stream a previous client
/// left (the board dropped its queued points, `ended_points` above `before`,
/// and the supervision it had switched on).
pub fn say_ended_stream(c: &mut Client, before: u32) {
    if let Ok(s) = c.status() {
        let dropped = s.ended_points.wrapping_sub(before);
        if dropped > 0 {
            eprintln!(
                "note: this motion ended a stream a previous client left: {dropped} queued points \
                 dropped, and its host supervision switched off"
            );
        }
    }
}

/// `fpi board reset`.
pub fn reset(c: &mut Client) -> Result<()> {
    let h = c.reset()?;
    println!("reset; the board answers again ({:?})", h.reset);
    Ok(())
}

/// `fpi board step`: steps the reference, records and scores the response into
/// `out`.
pub fn step(c: &mut Client, s: &crate::board::step::StepSettings, out: &Path) -> Result<()> {
    let (rec, fig) = or_restore(c, |c| crate::board::step::run(c, s))?;
    rec.write_csv(out)?;
    println!(
        "step {} → {} µm over {} ms, recorded to {}:",
        s.from_um,
        s.to_um,
        s.duration_ms,
        out.display()
    );
    println!("  {}", crate::board::step::describe(&fig, s.tol_um));
    Ok(())
}

/// `fpi board raster`: the raster `spec`, every axis recorded to `out`, its
/// figures printed; a fault during it is an error once the recording is
/// kept.
pub fn raster(c: &mut Client, spec: &crate::board::raster::RasterSpec, out: &Path) -> Result<()> {
    use crate::board::raster;
    let (m, rec) = or_restore(c, |c| raster::run(c, spec))?;
    rec.write_csv(out)?;
    let ticks = rec.axes.first().map_or(0, |a| a.samples.len());
    println!(
        "raster recorded to {} ({ticks} ticks of {} axes, {} samples dropped)",
        out.display(),
        rec.axes.len(),
        m.recording.dropped
    );
    match raster::figures(spec, &rec) {
        Some(f) => println!("  {}", raster::describe(spec, &f)),
        None => println!("  no whole line recorded: no figures"),
    }
    match m.fault {
        Some(f) => Err(f),
        None => Ok(()),
    }
}

/// `fpi board frf`: the frequency response measured through the board, to `out`.
pub fn frf(c: &mut Client, s: &crate::board::frf::FrfSettings, out: &Path) -> Result<()> {
    let conditions = crate::board::frf::conditions(c)?;
    let points = or_restore(c, |c| {
        crate::board::frf::measure(c, s, |k, p| {
            eprintln!("  {:>3}: {:8.1} Hz  |x/u| {:.4}", k + 1, p.f_hz, p.x.norm())
        })
    })?;
    crate::method::tune::frf::write_csv(out, &points, &conditions)?;
    println!(
        "{} frequencies written to {}, {}",
        points.len(),
        out.display(),
        conditions.header().trim_start_matches("# ")
    );
    if !conditions.is_plant() {
        eprintln!(
            "warning: measured with the loops acting (the damping on or the loop closed): the \
             damped stage's response, not the stage's own; `fpi tune --frf` refuses it as a \
             plant"
        );
    }
    Ok(())
}

/// What `fpi board autotune` takes besides the board.
pub struct AutotuneArgs<'a> {
    /// The model the board runs (or a file of several axes), and the FEM
    /// tables of a calibrated one.
    pub model: (&'a Path, Option<&'a Path>),
    /// The loop settings of its export.
    pub export: ExportOptions,
    /// How the loops are designed.
    pub tune: crate::method::tune::TuneOptions,
    /// The sweep and the trials.
    pub settings: crate::board::autotune::Settings,
    /// Also keep the tuned model in flash (of several axes: x's).
    pub store: bool,
    /// Where the tuned model goes, and the measured response (if wanted).
    pub out: (&'a Path, Option<&'a Path>),
    /// Tune every axis of a board of several, and their coupling (no
    /// `--axis` given).
    pub every_axis: bool,
    /// How the coupling is measured (a board of several axes).
    pub coupling: crate::board::decoupling::Settings,
}

/// `fpi board autotune`: measures, fits, tunes, loads and verifies
/// ([`crate::board::autotune::run`]); writes the tuned model. On a board of
/// several axes without `--axis`: every axis, then their coupling
/// ([`crate::board::axes::autotune`]), into one file of several axes.
pub fn autotune(c: &mut Client, a: &AutotuneArgs<'_>) -> Result<()> {
    use crate::board::autotune;
    let file = loadable(a.model.0, a.model.1, &a.export)?;
    let n = usize::from(c.hello().axes);
    if a.every_axis && n > 1 {
        return autotune_every_axis(c, a, file, n);
    }
    let axis = c.axis();
    let fw = file.of_axis(axis).ok_or_else(|| {
        anyhow!(
            "{}: no model of axis {}",
            a.model.0.display(),
            axis_name(axis)
        )
    })?;
    // The model is written before it runs for good: if it cannot be, the board
    // is put back to the model it ran.
    let tuned = autotune::run_keeping(
        c,
        &fw,
        &a.tune,
        &a.settings,
        a.store,
        &mut |m| autotune::write_model(m, a.out.0),
        |m| eprintln!("{m}"),
    )?;
    if let Some(p) = a.out.1 {
        crate::method::tune::frf::write_csv(p, &tuned.frf, &tuned.frf_conditions)?;
    }
    println!(
        "tuned model written to {} and running on the board",
        a.out.0.display()
    );
    print!("{}", autotune::table(&tuned));
    Ok(())
}

/// [`autotune`] of every axis of a board of `n` and their coupling, from
/// `file` (one model for every axis, or a file of several axes).
fn autotune_every_axis(
    c: &mut Client,
    a: &AutotuneArgs<'_>,
    file: Loadable,
    n: usize,
) -> Result<()> {
    if a.out.1.is_some() {
        bail!(
            "--frf-out writes one axis's response: give --axis with it (without --axis, autotune \
             tunes every axis of the board)"
        );
    }
    let models = file.every_axis(n);
    let out = a.out.0;
    let tuned = crate::board::axes::autotune(
        c,
        &models,
        &a.tune,
        (&a.settings, &a.coupling),
        a.store,
        &mut |f| crate::board::axes::write(f, out),
        |m| eprintln!("{m}"),
    )?;
    println!(
        "every axis tuned and the coupling measured; written to {} (`fpi board load` loads it \
         whole); each axis runs its tuned model, the decoupling is set and the board is parked",
        out.display()
    );
    print!("{}", crate::board::axes::table(&tuned));
    Ok(())
}
