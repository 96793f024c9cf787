//! The loops on a board, compared as a user would score them: the stage *as
//! built* (a few percent off the model, an 850 Hz mode of damping 0.03, a noisy
//! position sensor), driven four ways —
//!
//! * **open loop**: the inverse FPI alone (damping off);
//! * **PI**: the position PI around the inverse FPI, tuned for the undamped
//!   stage (`fpi tune --no-damping --no-feedforward`);
//! * **damped + PI**: integral force feedback damps the mode, the PI tuned
//!   around the damped stage (autotune's model, shaping off);
//! * **damped + PI + feedforward**: the same with the reference shaping that
//!   inverts the damped loop.
//!
//! Each drive gets a fresh stage and a warm-up (slow sines: the force channel
//! learns the preload map), then a 15 Hz sine and a 100 Hz triangle over 5–35 µm
//! and a 10 → 20 µm raised-cosine step ([`super::step`]); the damped drives
//! then their tracking bandwidth ([`super::bandwidth`]: ±0.2 µm sines on the
//! reference, 20 Hz–2 kHz). Every figure is on
//! the virtual stage's true position from the board's own recording: the sine
//! after its first period, the triangle over the central 80 % of each ramp
//! (the reference within 80 % of the half-swing of the mid-point) after two
//! periods.

use anyhow::{Context, Result};
use fpi_firmware::control::recorder::{signal, status};
use fpi_protocol::LoopMode;
use fpi_protocol::Shape;
use fpi_protocol::SourceKind;
use fpi_protocol::{BenchOrder, Command, FrontEndKind, StageVariant};
use piezo_sim::stats::ErrorStats;

use super::bandwidth::{self, Point};
use super::client::{real, refusal, Client};
use super::follow::no_fault;
use super::follow::Follow;
use super::recording::Recording;
use super::step::{self, StepFigures, StepSettings};
use super::warm::warm_up;

/// The waves' mid-point and half-swing, µm (5–35 µm of the 0–40 µm stroke).
pub const WAVE_UM: (f64, f64) = (20.0, 15.0);
/// The sine's frequency, Hz.
pub const SINE_HZ: f64 = 15.0;
/// The triangle's frequency, Hz.
pub const TRIANGLE_HZ: f64 = 100.0;
/// The bandwidth's sines: half-swing, µm, and frequencies (log-spaced), Hz.
pub const RESPONSE_SINE: (f64, f64, f64, usize) = (0.2, 20.0, 2000.0, 16);
/// The share of each ramp the triangle is scored on.
pub const RAMP_CENTRE: f64 = 0.8;
/// What the waves record.
pub const SIGNALS: u8 = signal::X_REF | signal::X_TRUE | signal::STATUS;

/// How the stage is driven.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    /// The inverse FPI alone.
    Open,
    /// PI around the inverse FPI, undamped stage.
    Pi,
    /// Damping + PI around the inverse FPI.
    Damped,
    /// Damping + PI + reference shaping.
    DampedFeedforward,
}

/// The drives in the order they are run.
pub const DRIVES: [Drive; 4] = [
    Drive::Open,
    Drive::Pi,
    Drive::Damped,
    Drive::DampedFeedforward,
];

impl Drive {
    /// Its name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Drive::Open => "open loop (inverse FPI)",
            Drive::Pi => "PI (undamped stage)",
            Drive::Damped => "damping + PI",
            Drive::DampedFeedforward => "damping + PI + feedforward",
        }
    }
}

/// One drive's figures and traces.
#[derive(Debug, Clone)]
pub struct DriveRun {
    /// The drive.
    pub drive: Drive,
    /// The sine: true position − reference after the first period, µm.
    pub sine: ErrorStats<f64>,
    /// The triangle over the ramps' centres, µm.
    pub triangle: ErrorStats<f64>,
    /// The step's figures.
    pub step: StepFigures,
    /// The step: time from its start (ms) and true position (µm).
    pub step_trace: Vec<(f64, f64)>,
    /// Two periods of the triangle: time (ms), reference and true position (µm).
    pub triangle_trace: Vec<(f64, f64, f64)>,
    /// The response from the reference to the true position (the damped
    /// drives; empty for the others).
    pub response: Vec<Point>,
}

/// The comparison.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// One run per drive.
    pub runs: Vec<DriveRun>,
}

impl Comparison {
    /// The run of `d`.
    pub fn run(&self, d: Drive) -> Option<&DriveRun> {
        self.runs.iter().find(|r| r.drive == d)
    }
}

/// Switches damping or shaping, where the model has it.
fn switch(r: Result<u32>) -> Result<()> {
    match r {
        Err(e) if refusal(&e).is_none() => Err(e),
        _ => Ok(()),
    }
}

/// Loads `image` onto a fresh stage as built and sets the drive up, warmed up.
fn prepare(c: &mut Client, image: &[u8], d: Drive) -> Result<()> {
    prepare_on(c, image, d, StageVariant::BUILT)
}

/// Loads `image` onto a fresh stage `v` and sets the drive up, warmed up.
fn prepare_on(c: &mut Client, image: &[u8], d: Drive, v: StageVariant) -> Result<()> {
    c.park()?;
    c.upload(image, false, |_| {})
        .context("uploading a model")?;
    c.bench(BenchOrder::Stage(v))?;
    c.move_to(WAVE_UM.0, 1000.0)?;
    Follow::new(c, 0).until_hold()?;
    let mode = if d == Drive::Open {
        LoopMode::Open
    } else {
        LoopMode::Closed
    };
    switch(c.damping(matches!(d, Drive::Damped | Drive::DampedFeedforward)))?;
    switch(c.shaping(d == Drive::DampedFeedforward))?;
    c.ack(&Command::Loop {
        axis: c.axis(),
        mode,
    })?;
    warm_up(c)
}

/// Runs a wave of `cycles` periods at `hz` over [`WAVE_UM`], recording at
/// `decimation`; the recording and the tick its first period began.
fn wave(
    c: &mut Client,
    shape: Shape,
    hz: f64,
    cycles: u32,
    decimation: u16,
) -> Result<(Recording, u32)> {
    let mut f = Follow::new(c, SIGNALS);
    f.record(decimation)?;
    f.rec.samples.clear();
    f.c.wave(shape, WAVE_UM.1, WAVE_UM.0, hz, cycles)?;
    let started = f.until("the wave", |s| {
        no_fault(s, "the wave")?;
        Ok(!s.approaching && s.source == SourceKind::Wave)
    })?;
    // The end: the source holds and the governed reference has arrived
    // (the next measurement starts from rest).
    f.until("the wave's end", |s| {
        no_fault(s, "the wave")?;
        Ok(s.source == SourceKind::Hold && !s.approaching)
    })?;
    f.c.ack(&Command::RecordStop)?;
    f.drain()?;
    Ok((f.rec, started))
}

/// Tracking samples of `rec` from tick `from` on (no fault, not approaching):
/// `(tick, reference, true position)`.
fn tracking(rec: &Recording, from: u32) -> impl Iterator<Item = (u32, f64, f64)> + '_ {
    rec.samples
        .iter()
        .filter(move |s| s.tick >= from && s.status & (status::FAULT | status::APPROACHING) == 0)
        .map(|s| (s.tick, real(s.x_ref), real(s.x_true)))
}

/// Runs the four drives on a parked board `c`: `pi` is the undamped stage's
/// tuning, `tuned` autotune's; the board is left parked with the nominal stage.
pub fn run(c: &mut Client, pi: &[u8], tuned: &[u8]) -> Result<Comparison> {
    let rate = c.rate_hz();
    let mut runs = Vec::new();
    for d in DRIVES {
        let image = if d == Drive::Pi { pi } else { tuned };
        prepare(c, image, d).with_context(|| format!("setting up {}", d.name()))?;
        let (rec, started) = wave(c, Shape::Sine, SINE_HZ, 5, 10)?;
        let mut sine = ErrorStats::new();
        for (_, r, x) in tracking(&rec, started + (rate / SINE_HZ) as u32) {
            sine.add(x - r);
        }
        let (rec, started) = wave(c, Shape::Triangle, TRIANGLE_HZ, 20, 2)?;
        let from = started + (2.0 * rate / TRIANGLE_HZ) as u32;
        let mut triangle = ErrorStats::new();
        for (_, r, x) in tracking(&rec, from) {
            if (r - WAVE_UM.0).abs() <= RAMP_CENTRE * WAVE_UM.1 {
                triangle.add(x - r);
            }
        }
        let triangle_trace = tracking(&rec, from + (8.0 * rate / TRIANGLE_HZ) as u32)
            .take_while(|(t, _, _)| *t < from + (10.0 * rate / TRIANGLE_HZ) as u32)
            .map(|(t, r, x)| ((t - from) as f64 / rate * 1e3, r, x))
            .collect();
        let (srec, fig) = step::run(c, &StepSettings::default())
            .with_context(|| format!("the step, {}", d.name()))?;
        let t0 = srec.samples.first().map_or(0, |s| s.tick);
        let step_trace = srec
            .samples
            .iter()
            .map(|s| ((s.tick - t0) as f64 / rate * 1e3, real(s.x_true)))
            .collect();
        let response = if matches!(d, Drive::Damped | Drive::DampedFeedforward) {
            let (a, lo, hi, n) = RESPONSE_SINE;
            bandwidth::measure(c, &bandwidth::log_spaced(lo, hi, n), a, WAVE_UM.0)
                .with_context(|| format!("the bandwidth, {}", d.name()))?
        } else {
            Vec::new()
        };
        runs.push(DriveRun {
            drive: d,
            sine,
            triangle,
            step: fig,
            step_trace,
            triangle_trace,
            response,
        });
    }
    c.park()?;
    c.bench(BenchOrder::Stage(StageVariant::NOMINAL))?;
    Ok(Comparison { runs })
}

/// The comparison's table, for people (markdown): RMS errors in µm and in % of
/// the 30 µm span, step figures.
pub fn table(r: &Comparison) -> String {
    let span = 2.0 * WAVE_UM.1;
    let mut t = format!(
        "| drive | {SINE_HZ:.0} Hz sine RMS | {TRIANGLE_HZ:.0} Hz triangle RMS (central {:.0} %) | step rise | overshoot | settles ±0.1 µm | −3 dB bandwidth (peak) |\n|---|---|---|---|---|---|---|\n",
        100.0 * RAMP_CENTRE
    );
    for run in &r.runs {
        t.push_str(&format!(
            "| {} | {:.3} µm ({:.2} %) | {:.3} µm ({:.2} %) | {:.2} ms | {:.3} µm | {} | {} |\n",
            run.drive.name(),
            run.sine.rms(),
            100.0 * run.sine.rms() / span,
            run.triangle.rms(),
            100.0 * run.triangle.rms() / span,
            run.step.rise_ms,
            run.step.overshoot_um,
            run.step
                .settle_ms
                .map_or("> 50 ms".to_string(), |v| format!("{v:.2} ms")),
            describe_response(&run.response)
        ));
    }
    t
}

/// A response's bandwidth and peak, for the table.
fn describe_response(points: &[Point]) -> String {
    let Some((db, f)) = bandwidth::peak(points) else {
        return "—".into();
    };
    let bw = bandwidth::bandwidth_hz(points).map_or_else(
        || format!("> {:.0} Hz", points.last().map_or(0.0, |p| p.f_hz)),
        |b| format!("{b:.0} Hz"),
    );
    format!("{bw} ({db:+.1} dB at {f:.0} Hz)")
}

/// Where the hold noise is measured, µm.
pub const HOLD_UM: f64 = 20.0;
/// How long the hold is scored, s.
pub const HOLD_S: f64 = 0.2;
/// The hold is recorded every this many ticks (10 000 samples/s).
pub const HOLD_DECIMATION: u16 = 2;
/// How long the stage settles at [`HOLD_UM`] before the hold is scored, s.
pub const HOLD_SETTLE_S: f64 = 0.05;

/// One front end's figures in closed loop (damping + PI + feedforward) on the
/// stage as built, on the true position.
#[derive(Debug, Clone)]
pub struct FrontEndRun {
    /// The front end the board converted with.
    pub kind: FrontEndKind,
    /// The true position while holding [`HOLD_UM`] for [`HOLD_S`] (every
    /// [`HOLD_DECIMATION`]-th tick):
    /// its mean minus the target, µm.
    pub hold_offset_um: f64,
    /// Its standard deviation about its mean, µm.
    pub hold_rms_um: f64,
    /// Its peak-to-peak, µm.
    pub hold_pp_um: f64,
    /// Samples scored in the hold.
    pub hold_samples: usize,
    /// The 15 Hz sine over 5–35 µm: true position − reference after the first
    /// period, µm.
    pub sine: ErrorStats<f64>,
}

/// The hold noise and the 15 Hz sine of `tuned` (a model with damping, PI and
/// feedforward) on a fresh stage `stage` (the stage as built:
/// [`StageVariant::BUILT`]), with each front end in turn; the board is left
/// parked with the nominal stage and the internal front end.
pub fn front_ends(c: &mut Client, tuned: &[u8], stage: StageVariant) -> Result<Vec<FrontEndRun>> {
    let rate = c.rate_hz();
    let mut runs = Vec::new();
    for &kind in FrontEndKind::ALL {
        c.park()?;
        c.front_end(kind)
            .with_context(|| format!("selecting the {} front end", kind.name()))?;
        prepare_on(c, tuned, Drive::DampedFeedforward, stage)
            .with_context(|| format!("setting up, {} front end", kind.name()))?;
        // The hold: every tick of the true position.
        c.move_to(HOLD_UM, 1000.0)?;
        let mut f = Follow::new(c, SIGNALS);
        let at = f.until_hold()?;
        let from = at + f.ticks(HOLD_SETTLE_S);
        let to = from + f.ticks(HOLD_S);
        f.record(HOLD_DECIMATION)?;
        f.until_tick(to)?;
        f.c.ack(&Command::RecordStop)?;
        f.drain()?;
        let held: Vec<f64> = tracking(&f.rec, from)
            .filter(|&(t, _, _)| t < to)
            .map(|(_, _, x)| x)
            .collect();
        // The in-process board keeps time with the wall clock: a busy host may
        // read the recorder late and lose samples (CI once kept 1719 of 2000);
        // the figures are statistics over what is kept, and half the hold is
        // still a thousand samples of its noise.
        let expected = ((to - from) / u32::from(HOLD_DECIMATION)) as usize;
        if held.len() * 2 < expected {
            anyhow::bail!(
                "the hold kept {} of {expected} samples ({} front end)",
                held.len(),
                kind.name()
            );
        }
        let n = held.len() as f64;
        let mean = held.iter().sum::<f64>() / n;
        let rms = (held.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        let (lo, hi) = held
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                (lo.min(x), hi.max(x))
            });
        let (rec, started) = wave(c, Shape::Sine, SINE_HZ, 5, 10)?;
        let mut sine = ErrorStats::new();
        for (_, r, x) in tracking(&rec, started + (rate / SINE_HZ) as u32) {
            sine.add(x - r);
        }
        runs.push(FrontEndRun {
            kind,
            hold_offset_um: mean - HOLD_UM,
            hold_rms_um: rms,
            hold_pp_um: hi - lo,
            hold_samples: held.len(),
            sine,
        });
    }
    c.park()?;
    c.front_end(FrontEndKind::Internal)?;
    c.bench(BenchOrder::Stage(StageVariant::NOMINAL))?;
    Ok(runs)
}

/// The front ends' table, for people (markdown): hold noise in nm, the sine's
/// RMS error in µm and % of the 30 µm span.
pub fn front_end_table(runs: &[FrontEndRun]) -> String {
    let span = 2.0 * WAVE_UM.1;
    let mut t = format!(
        "| front end | hold at {HOLD_UM:.0} µm: RMS | peak-to-peak | mean − target | {SINE_HZ:.0} Hz sine 5–35 µm RMS |\n|---|---|---|---|---|\n"
    );
    for r in runs {
        t.push_str(&format!(
            "| {} | {:.2} nm | {:.2} nm | {:+.2} nm | {:.4} µm ({:.3} %) |\n",
            r.kind.name(),
            1e3 * r.hold_rms_um,
            1e3 * r.hold_pp_um,
            1e3 * r.hold_offset_um,
            r.sine.rms(),
            100.0 * r.sine.rms() / span
        ));
    }
    t
}
