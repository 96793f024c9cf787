//! The position loop on a board, scored as a user would: the stage *as built*
//! (the emulated board's virtual stage differs from the model by a few percent
//! of kinematics, preload and creep, has an 850 Hz mode and a noisy position
//! sensor), a 15 Hz and a 100 Hz sine over most of the stroke and a step, each in
//! open loop (FPI feedforward), with feedback alone, and with feedback plus the
//! FPI feedforward.
//!
//! Every figure comes from the board's own recording: tracking error = the
//! virtual stage's true position − the reference, after the first period (the
//! sine) or over the whole response (the step).

use anyhow::{bail, Context, Result};
use fpi_firmware::closed_loop::LoopMode;
use fpi_firmware::link::protocol::{BenchOrder, Command};
use fpi_firmware::recorder::signal;
use fpi_firmware::reference::wave::Shape;
use fpi_firmware::reference::SourceKind;
use piezo_sim::stats::ErrorStats;

use super::client::{real, Client};
use super::follow::Follow;
use super::recording::Recording;

/// Ticks per recorded sample during the sines (1 kHz at 20 kHz).
pub const DECIMATION: u16 = 20;
/// Ticks per recorded sample during the steps (10 kHz: the 850 Hz mode's ringing
/// is seen, not aliased).
pub const STEP_DECIMATION: u16 = 2;
/// What the loop session records.
pub const SIGNALS: u8 = signal::X_REF | signal::VOLTAGE | signal::X_TRUE | signal::X_SENSOR;
/// The sine's mid-point and half-swing, µm (4–36 µm of the 0–40 µm stroke).
pub const SINE_UM: (f64, f64) = (20.0, 16.0);
/// The step: from and to, µm.
pub const STEP_UM: (f64, f64) = (10.0, 30.0);

/// The step's speed: the board's fastest move (1.5 µm per tick: 20 µm in 0.67 ms).
pub const STEP_SPEED_UM_S: f64 = 30_000.0;

/// The three ways of driving the stage, in the order they are run.
pub const MODES: [LoopMode; 3] = [LoopMode::Open, LoopMode::FeedbackOnly, LoopMode::Closed];

/// The mode's name in tables.
pub fn mode_name(m: LoopMode) -> &'static str {
    match m {
        LoopMode::Open => "open loop (FPI feedforward)",
        LoopMode::FeedbackOnly => "feedback only (PI)",
        LoopMode::Closed => "feedback + FPI feedforward",
    }
}

/// One sine run.
#[derive(Debug, Clone)]
pub struct SineRun {
    /// How the loop was closed.
    pub mode: LoopMode,
    /// Frequency, Hz.
    pub hz: f64,
    /// True position − reference after the first period, µm.
    pub tracking: ErrorStats<f64>,
    /// Its ticks `[from, to)`.
    pub ticks: (u32, u32),
}

/// One step response (true position, recorded at 10 kHz).
#[derive(Debug, Clone)]
pub struct StepRun {
    /// How the loop was closed.
    pub mode: LoopMode,
    /// 10–90 % rise time, ms.
    pub rise_ms: f64,
    /// Overshoot beyond the target, µm.
    pub overshoot_um: f64,
    /// Time until the stage stays within ±0.1 µm of the target, ms (`None`: it
    /// does not within the window).
    pub settle_ms: Option<f64>,
    /// The stage's mean offset from the target over the window's last 20 ms, µm.
    pub final_error_um: f64,
    /// Its ticks `[from, to)`.
    pub ticks: (u32, u32),
}

/// The whole loop session.
#[derive(Debug, Clone)]
pub struct LoopReport {
    /// The sines, mode by mode.
    pub sines: Vec<SineRun>,
    /// The steps, mode by mode.
    pub steps: Vec<StepRun>,
    /// The recording.
    pub recording: Recording,
}

impl LoopReport {
    /// The sine run of `mode` at `hz`.
    pub fn sine(&self, mode: LoopMode, hz: f64) -> Option<&SineRun> {
        self.sines.iter().find(|s| s.mode == mode && s.hz == hz)
    }
    /// The step of `mode`.
    pub fn step(&self, mode: LoopMode) -> Option<&StepRun> {
        self.steps.iter().find(|s| s.mode == mode)
    }
}

/// The loop session: a followed board whose waits fail on any fault.
struct Session<'c> {
    f: Follow<'c>,
}

impl<'c> Session<'c> {
    /// A session on `c`, its recording empty.
    fn new(c: &'c mut Client) -> Self {
        Self {
            f: Follow::new(c, SIGNALS),
        }
    }

    fn ticks(&self, seconds: f64) -> u32 {
        self.f.ticks(seconds)
    }

    /// Waits (reading the recorder) until `done` holds for the status; a fault
    /// other than *parked* is an error that says where the loop was.
    fn until(
        &mut self,
        what: &str,
        done: impl Fn(&fpi_firmware::link::protocol::Status) -> bool,
    ) -> Result<u32> {
        self.f.until(what, |s| {
            if let Some(f) = s
                .fault
                .filter(|f| f.code != piezo_fpi::control::Fault::Stopped as u8)
            {
                bail!(
                    "fault {} ({}) at tick {} while waiting for {what}; now: {:?}, reference {:.3} µm, \
                     position sensor {:.3} µm, estimate {:.3} µm",
                    f.code,
                    piezo_fpi::control::Fault::from_code(f.code).map_or("?", |f| f.message()),
                    f.at,
                    s.loop_mode,
                    real(s.signals[0]),
                    real(s.signals[4]),
                    real(s.signals[1])
                );
            }
            Ok(done(s))
        })
    }

    /// Stops recording (what it held is read), opens the loop, parks the stage
    /// and gives the bench its nominal stage back.
    fn finish(&mut self) -> Result<()> {
        self.f.c.ack(&Command::RecordStop)?;
        self.f.drain()?;
        self.f.c.ack(&Command::Loop {
            mode: LoopMode::Open,
        })?;
        self.f.c.ack(&Command::Safe)?;
        self.until("the safe voltage", |st| {
            st.fault.is_some_and(|f| f.safe_at.is_some())
        })?;
        self.f.c.bench(BenchOrder::Stage(false))?;
        Ok(())
    }

    fn until_hold(&mut self) -> Result<u32> {
        self.until("rest", |s| s.source == SourceKind::Hold && !s.approaching)
    }

    fn until_tick(&mut self, t: u32) -> Result<u32> {
        self.until(&format!("tick {t}"), |s| s.tick >= t)
    }

    /// A sine at `hz` for `cycles` periods in `mode`.
    fn sine(&mut self, mode: LoopMode, hz: f64, cycles: u32) -> Result<SineRun> {
        self.wave(Shape::Sine, mode, hz, cycles)
    }

    /// A waveform over [`SINE_UM`] at `hz` for `cycles` periods in `mode`.
    fn wave(&mut self, shape: Shape, mode: LoopMode, hz: f64, cycles: u32) -> Result<SineRun> {
        self.f.c.ack(&Command::Loop { mode })?;
        let (mid, half) = SINE_UM;
        self.f.c.wave(shape, half, mid, hz, cycles)?;
        // The wave starts after its approach: skip that and the first period.
        let started = self.until("the sine", |s| {
            !s.approaching && s.source == SourceKind::Wave
        })?;
        let to = self.until_hold()?;
        let from = started + self.ticks(1.0 / hz);
        Ok(SineRun {
            mode,
            hz,
            tracking: self.f.rec.tracking(from, to),
            ticks: (from, to),
        })
    }

    /// A step from [`STEP_UM`]'s first to its second position in `mode`.
    fn step(&mut self, mode: LoopMode) -> Result<StepRun> {
        let (a, b) = STEP_UM;
        self.f.c.ack(&Command::Loop { mode })?;
        self.f.c.move_to(a, 2000.0)?;
        let rest = self.until_hold()?;
        self.until_tick(rest + self.ticks(0.1))?;
        self.f.record(STEP_DECIMATION)?;
        let from = self.f.c.move_to(b, STEP_SPEED_UM_S)?;
        let to = from + self.ticks(0.08);
        self.until_tick(to)?;
        self.f.drain()?;
        Ok(step_response(&self.f.rec, mode, (from, to), (a, b)))
    }
}

/// Rise time, overshoot and settling of the recorded response to a step `a → b`
/// between ticks `from` and `to`.
fn step_response(
    rec: &Recording,
    mode: LoopMode,
    (from, to): (u32, u32),
    (a, b): (f64, f64),
) -> StepRun {
    let pts: Vec<(f64, f64)> = rec
        .between(from, to)
        .map(|s| ((s.tick - from) as f64 / rec.rate_hz * 1e3, real(s.x_true)))
        .collect();
    let first = |level: f64| pts.iter().find(|(_, x)| *x >= level).map(|p| p.0);
    let rise_ms = match (first(a + 0.1 * (b - a)), first(a + 0.9 * (b - a))) {
        (Some(t1), Some(t9)) => t9 - t1,
        _ => f64::NAN,
    };
    let overshoot_um = pts.iter().map(|p| p.1 - b).fold(0.0, f64::max);
    let settle_ms = pts
        .iter()
        .rposition(|(_, x)| (x - b).abs() > 0.1)
        .and_then(|i| pts.get(i + 1))
        .map(|p| p.0);
    let tail: Vec<f64> = pts
        .iter()
        .filter(|p| p.0 >= 60.0)
        .map(|p| p.1 - b)
        .collect();
    let final_error_um = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
    StepRun {
        mode,
        rise_ms,
        overshoot_um,
        settle_ms,
        final_error_um,
        ticks: (from, to),
    }
}

/// Runs the loop session on an open emulated board (parked) with `image` (a
/// model with a `[feedback]` section): the stage as built, sines and steps in
/// every mode; the board is left parked, open loop, with the nominal stage.
pub fn run(c: &mut Client, image: &[u8]) -> Result<LoopReport> {
    c.ack(&Command::Safe)?;
    c.upload(image, false, |_| {})
        .context("uploading the tuned model")?;
    c.bench(BenchOrder::Stage(true))?;
    let mut s = Session::new(c);
    s.f.record(DECIMATION)?;
    s.f.c.move_to(SINE_UM.0, 1000.0)?;
    s.until_hold()?;
    let mut sines = Vec::new();
    for (hz, cycles) in [(15.0, 5), (100.0, 20)] {
        for mode in MODES {
            match s.sine(mode, hz, cycles) {
                Ok(r) => sines.push(r),
                Err(e) => {
                    let _ = s.f.drain();
                    let _ =
                        s.f.rec
                            .write_csv(std::path::Path::new("/tmp/loop-debug.csv"));
                    return Err(e);
                }
            }
        }
    }
    let mut steps = Vec::new();
    for mode in MODES {
        steps.push(s.step(mode)?);
        s.f.record(DECIMATION)?;
    }
    s.finish()?;
    Ok(LoopReport {
        sines,
        steps,
        recording: s.f.rec,
    })
}

/// A fast triangle and a step, in open and closed loop, without and with the
/// reference shaping.
#[derive(Debug, Clone)]
pub struct ShapingRun {
    /// With the model's reference shaping.
    pub shaped: bool,
    /// How the loop was closed.
    pub mode: LoopMode,
    /// The triangle: true position − reference after the first period, µm.
    pub triangle: SineRun,
    /// The triangle's error against the reference delayed by the shaping's
    /// group delay (`delay_ms`), µm: what is left besides the lag.
    pub triangle_delayed: ErrorStats<f64>,
    /// The shaping's group delay at low frequency, ms (0 without shaping).
    pub delay_ms: f64,
    /// The step.
    pub step: StepRun,
}

/// The shaping session: its runs and its recording.
#[derive(Debug, Clone)]
pub struct ShapingReport {
    /// Without and with shaping, open and closed loop.
    pub runs: Vec<ShapingRun>,
    /// The recording.
    pub recording: Recording,
}

/// The triangle's frequency, Hz.
pub const TRIANGLE_HZ: f64 = 100.0;

/// Runs a [`TRIANGLE_HZ`] triangle over [`SINE_UM`] and a step, in open loop and
/// feedback + feedforward, with `plain` (no shaping) and with `shaped` (the same
/// model with the inverse of the stage's mode), on the stage as built; the board
/// is left parked with the nominal stage.
pub fn shaping_run(
    c: &mut Client,
    plain: &[u8],
    (shaped, delay_ms): (&[u8], f64),
) -> Result<ShapingReport> {
    let mut s = Session::new(c);
    let mut out = Vec::new();
    for (shaped_model, image, delay) in [(false, plain, 0.0), (true, shaped, delay_ms)] {
        s.f.c.ack(&Command::Loop {
            mode: LoopMode::Open,
        })?;
        s.f.c.ack(&Command::Safe)?;
        s.until("the safe voltage", |st| {
            st.fault.is_some_and(|f| f.safe_at.is_some())
        })?;
        s.f.c
            .upload(image, false, |_| {})
            .context("uploading a model")?;
        s.f.c.bench(BenchOrder::Stage(true))?;
        s.f.record(DECIMATION)?;
        s.f.c.move_to(SINE_UM.0, 1000.0)?;
        s.until_hold()?;
        for mode in [LoopMode::Open, LoopMode::Closed] {
            // Recorded at 10 kHz: the corners and the ringing are seen.
            s.f.record(STEP_DECIMATION)?;
            let triangle = s.wave(Shape::Triangle, mode, TRIANGLE_HZ, 20)?;
            let triangle_delayed = delayed_tracking(&s.f.rec, triangle.ticks, delay);
            let step = s.step(mode)?;
            s.f.record(DECIMATION)?;
            out.push(ShapingRun {
                shaped: shaped_model,
                mode,
                triangle,
                triangle_delayed,
                delay_ms: delay,
                step,
            });
        }
    }
    s.finish()?;
    Ok(ShapingReport {
        runs: out,
        recording: s.f.rec,
    })
}

/// True position − the reference `delay_ms` earlier (linearly interpolated
/// between recorded samples), between `ticks`.
fn delayed_tracking(rec: &Recording, (from, to): (u32, u32), delay_ms: f64) -> ErrorStats<f64> {
    let pts: Vec<(f64, f64, f64)> = rec
        .between(from.saturating_sub(rec.rate_hz as u32 / 100), to)
        .map(|s| {
            (
                s.tick as f64 / rec.rate_hz * 1e3,
                real(s.x_ref),
                real(s.x_true),
            )
        })
        .collect();
    let mut e = ErrorStats::new();
    for w in pts.windows(2) {
        let (t, x) = (w[1].0, w[1].2);
        if t < from as f64 / rec.rate_hz * 1e3 {
            continue;
        }
        let td = t - delay_ms;
        // The recorded reference around `td` (1 ms apart): the last sample at or
        // before it and the next.
        let Some(i) = pts.iter().rposition(|p| p.0 <= td) else {
            continue;
        };
        let (a, b) = (pts[i], pts[(i + 1).min(pts.len() - 1)]);
        let r = if b.0 > a.0 {
            a.1 + (b.1 - a.1) * (td - a.0) / (b.0 - a.0)
        } else {
            a.1
        };
        e.add(x - r);
    }
    e
}

/// The shaping table, for people (markdown).
pub fn shaping_table(runs: &[ShapingRun]) -> String {
    let mut t = format!(
        "| drive | reference shaping | {TRIANGLE_HZ:.0} Hz triangle RMS / max (µm) | … against the reference delayed by the shaping (µm RMS) | step overshoot (µm) | settles ±0.1 µm (ms) |\n|---|---|---|---|---|---|\n"
    );
    for r in runs {
        t.push_str(&format!(
            "| {} | {} | {:.3} / {:.3} | {:.3} ({:.2} ms) | {:.3} | {} |\n",
            mode_name(r.mode),
            if r.shaped { "mode inverse" } else { "none" },
            r.triangle.tracking.rms(),
            r.triangle.tracking.max_abs(),
            r.triangle_delayed.rms(),
            r.delay_ms,
            r.step.overshoot_um,
            r.step
                .settle_ms
                .map_or("> 80".to_string(), |v| format!("{v:.1}"))
        ));
    }
    t
}

/// The report's table, for people (markdown).
pub fn table(r: &LoopReport) -> String {
    let mut t = String::from(
        "| drive | 15 Hz RMS / max (µm) | 100 Hz RMS / max (µm) | step rise (ms) | overshoot (µm) | settles ±0.1 µm (ms) |\n|---|---|---|---|---|---|\n",
    );
    for mode in MODES {
        let sine = |hz| {
            r.sine(mode, hz).map_or("—".to_string(), |s| {
                format!("{:.3} / {:.3}", s.tracking.rms(), s.tracking.max_abs())
            })
        };
        let (rise, over, settle) =
            r.step(mode)
                .map_or(("—".into(), "—".into(), "—".into()), |s| {
                    (
                        format!("{:.2}", s.rise_ms),
                        format!("{:.3}", s.overshoot_um),
                        s.settle_ms
                            .map_or("> 80".to_string(), |v| format!("{v:.1}")),
                    )
                });
        t.push_str(&format!(
            "| {} | {} | {} | {rise} | {over} | {settle} |\n",
            mode_name(mode),
            sine(15.0),
            sine(100.0)
        ));
    }
    t
}
