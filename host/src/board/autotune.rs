//! `fpi board autotune`: a stage's loops tuned through its board, in one
//! command.
//!
//! 1. The board must run the model given (read back and compared byte for
//!    byte: the tuning is written into that model's file).
//! 2. Open loop, damping and shaping off, holding mid-stroke: the force
//!    sensor's noise at rest is measured ([`super::noise`]: the damping is
//!    designed for it, and it is named in the error where the loop watch trips
//!    later on the motion it drives), then the
//!    board's analyser measures the response from the command to the
//!    position sensor and to the force channel ([`super::frf`]).
//! 3. The core's plant model is fitted to it ([`crate::method::tune::frf`]):
//!    mode, damping, lag, κ.
//! 4. The loops are designed on it ([`crate::method::tune`]: damping for the
//!    mode's family ±20 % with ζ 0.01–0.06, the PI for a sensitivity peak, the
//!    feedforward), written into the model and loaded.
//! 5. The feedforward's taps are refined on trials through the board
//!    ([`super::trial`], [`crate::method::tune::trials`]): each round closes
//!    the loops, warms up, runs the step and the triangle at every tick and
//!    updates the taps from the error the position sensor measured; the taps
//!    of the round with the least error are kept.
//! 6. The loops closed at rest, the swing the loop watch sees on the tracking
//!    error is measured ([`noise::tracking_swing`]) and the watch's half
//!    swing set to [`tune::WATCH_SWING_RMS`] of its RMS (0.075…0.2 µm), so
//!    that on this stage an unstable loop is counted while it is a tenth of a
//!    micrometre (`firmware/src/control/watch.rs`).
//!    Where the damping leaves the shaped reference's force out (a preview),
//!    the lead's baseline is measured ([`lead_baseline`]): the ratio the
//!    board's fit of that force settles at over [`BASELINE_STEPS`] steps on
//!    this stage, written into the model and loaded, so that on a stage whose
//!    mass differs the board scales the force by the ratio it learns
//!    (`piezo_fpi::lead`).
//! 7. After a warm-up (slow sines: the force channel learns the stage's preload
//!    map), a 10 → 20 µm step verifies it; a table says what was achieved.

use std::path::Path;

use anyhow::{bail, Context, Result};
use fpi_protocol::Command;
use fpi_protocol::LoopMode;
use piezo_sim::file::FirmwareModel;

use super::client::{refusal, Client};
use super::frf::{self, FrfSettings};
use super::noise;
use super::restore::Before;
use super::step::{self, StepFigures, StepSettings};
use super::trial;
use super::warm::close_and_warm_up;
use crate::method::tune::feedforward::Feedforward;
use crate::method::tune::frf::{self as fit, FrfConditions, FrfFit, FrfPoint};
use crate::method::tune::trials;
use crate::method::tune::{self, TuneOptions, Tuning};

/// Trials the feedforward's taps are refined on, by default.
pub const TRIALS: u32 = 2;
/// Steps the lead's baseline is measured over: at least the first, at most
/// the second, until two in a row move it by less than [`BASELINE_SETTLED`].
pub const BASELINE_STEPS: (usize, usize) = (4, 10);
/// The change of the fit's ratio over one step that counts as settled.
pub const BASELINE_SETTLED: f64 = 0.005;

/// How autotune measures (configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// The frequency-response sweep.
    pub sweep: FrfSettings,
    /// Trials through the board the feedforward's taps are refined on (0: the
    /// taps as designed on the fitted plant).
    pub trials: u32,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            sweep: FrfSettings::default(),
            trials: TRIALS,
        }
    }
}

/// One round of the feedforward's refinement: the RMS tracking errors the
/// position sensor measured with that round's taps, µm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Round {
    /// On the 10 → 20 µm step (30 ms from its start).
    pub step_um: f64,
    /// On the 100 Hz triangle (three periods).
    pub triangle_um: f64,
}

impl Round {
    /// What the rounds are ranked by: the two errors' sum, µm.
    pub fn score(&self) -> f64 {
        self.step_um + self.triangle_um
    }
}

/// What autotune did.
#[derive(Debug, Clone)]
pub struct Autotune {
    /// The measured response.
    pub frf: Vec<FrfPoint>,
    /// What the board ran while it measured it (the loop open, damping and
    /// shaping off).
    pub frf_conditions: FrfConditions,
    /// The plant fitted to it.
    pub fit: FrfFit,
    /// The force sensor's noise at rest, N (σ; [`noise::force_noise`]).
    pub force_noise_n: f64,
    /// The loops designed.
    pub tuning: Tuning,
    /// The tuned model (loaded on the board).
    pub model: FirmwareModel,
    /// The feedforward's refinement: round 0 with the taps as designed, round
    /// `k` after `k` trials (empty: not refined).
    pub rounds: Vec<Round>,
    /// The round whose taps the model holds.
    pub kept: usize,
    /// The lead's baseline measured, and over how many steps (`None`: the
    /// model leaves no lead out).
    pub baseline: Option<(f64, usize)>,
    /// The swing the loop watch sees on the tracking error at rest with the
    /// loops tuned, µm RMS ([`noise::tracking_swing`]): the model's watch
    /// swing is [`tune::WATCH_SWING_RMS`] of it.
    pub swing_rms_um: f64,
    /// The verification step, 10 → 20 µm.
    pub step: StepFigures,
}

/// Opens the loop and switches damping and shaping off (a model without them
/// refuses the switch: nothing to switch).
pub(crate) fn bare(c: &mut Client) -> Result<()> {
    c.ack(&Command::Loop {
        axis: c.axis(),
        mode: LoopMode::Open,
    })?;
    for r in [c.damping(false), c.shaping(false)] {
        if let Err(e) = r {
            if refusal(&e).is_none() {
                return Err(e);
            }
        }
    }
    Ok(())
}

/// Runs autotune on `c`, which must run `fw`; loads the tuned model (`store`:
/// also into flash). `progress` hears what is happening.
pub fn run(
    c: &mut Client,
    fw: &FirmwareModel,
    o: &TuneOptions,
    settings: &Settings,
    store: bool,
    progress: impl FnMut(&str),
) -> Result<Autotune> {
    run_keeping(c, fw, o, settings, store, &mut |_| Ok(()), progress)
}

/// [`run`], and `keep` hears the tuned model before it is loaded for good
/// (and stored): where it fails (the file it writes cannot be written), as
/// where anything else fails once autotune has changed the board, the board
/// is put back as it was found ([`Before`]: parked, running `fw` with its
/// loop mode, damping and shaping), so it never runs a model nobody has.
pub fn run_keeping(
    c: &mut Client,
    fw: &FirmwareModel,
    o: &TuneOptions,
    settings: &Settings,
    store: bool,
    keep: &mut dyn FnMut(&FirmwareModel) -> Result<()>,
    progress: impl FnMut(&str),
) -> Result<Autotune> {
    tune::check_options(fw, o)?;
    let image = fw.image().map_err(anyhow::Error::msg)?;
    let running = c.read_model().context("reading the board's model back")?;
    if running != image {
        bail!(
            "the board runs another model ({} bytes, not the {} of the one given): load it first \
             (fpi board load MODEL)",
            running.len(),
            image.len()
        );
    }
    let before = Before::capture(c)?.with_model(c, image)?;
    before.on_failure(c, |c| tune_on(c, fw, o, settings, store, keep, progress))
}

/// Steps 2–7 of the module docs on the board `c`, which runs `fw` (see
/// [`run_keeping`]).
fn tune_on(
    c: &mut Client,
    fw: &FirmwareModel,
    o: &TuneOptions,
    settings: &Settings,
    store: bool,
    keep: &mut dyn FnMut(&FirmwareModel) -> Result<()>,
    mut progress: impl FnMut(&str),
) -> Result<Autotune> {
    let rate = fw.controller.rate_hz;
    let split = fw
        .controller
        .force_split_hz
        .unwrap_or(piezo_fpi::control::DEFAULT_SPLIT_HZ as f64);
    let split_rate = tune::split_rate_f64(split, rate);
    bare(c)?;
    let force_noise_n = noise::force_noise(c)?;
    progress(&format!(
        "the force sensor's noise at rest: σ {force_noise_n:.3} N"
    ));
    progress("measuring the frequency response through the board");
    let frf_conditions = frf::conditions(c)?;
    let points = frf::measure(c, &settings.sweep, |k, p| {
        progress(&format!(
            "  {:>2}: {:7.1} Hz  |x/u| {:.3}",
            k + 1,
            p.f_hz,
            p.x.norm()
        ))
    })?;
    let fitted = fit::fit(&points, rate, split_rate)?;
    progress(&fit::describe(&fitted));
    let problems = fit::problems(&fitted, Some(&frf_conditions));
    if !problems.is_empty() {
        progress(&format!("warning: {}", problems.join("; ")));
    }
    // The damping is designed for the noise measured (or the one given).
    let o = &TuneOptions {
        force_noise_n: o.force_noise_n.or(Some(force_noise_n)),
        ..o.clone()
    };
    let mut t = tune::tune_measured(fw, fitted.spec, o)?;
    progress("loading the tuned model");
    // The loops run on the stage from here: a tripped watch may be the damping's
    // noise-driven motion.
    let motion = t.noise_motion_um_per_n * force_noise_n;
    let done = on_board(c, fw, o, (settings, store), &mut t, keep, &mut progress)
        .map_err(|e| noise::explain(c, e, force_noise_n, motion))?;
    Ok(Autotune {
        frf: points,
        frf_conditions,
        fit: fitted,
        force_noise_n,
        tuning: t,
        model: done.model,
        rounds: done.rounds,
        kept: done.kept,
        baseline: done.baseline,
        swing_rms_um: done.swing_rms_um,
        step: done.step,
    })
}

/// What autotune did on the board with the loops it designed.
struct OnBoard {
    model: FirmwareModel,
    rounds: Vec<Round>,
    kept: usize,
    baseline: Option<(f64, usize)>,
    swing_rms_um: f64,
    step: StepFigures,
}

/// Loads the tuning `t`, refines its feedforward on trials, measures the
/// lead's baseline (both written into `t`), stores it where asked and verifies
/// it with a step (steps 4–7 of the module docs).
fn on_board(
    c: &mut Client,
    fw: &FirmwareModel,
    o: &TuneOptions,
    (settings, store): (&Settings, bool),
    t: &mut Tuning,
    keep: &mut dyn FnMut(&FirmwareModel) -> Result<()>,
    progress: &mut impl FnMut(&str),
) -> Result<OnBoard> {
    load(c, fw, t, o, false)?;
    let (mut rounds, mut kept) = (Vec::new(), 0);
    if let (Some(Feedforward::Preview { ticks, taps, .. }), 1..) =
        (t.feedforward.clone(), settings.trials)
    {
        let best;
        (rounds, kept, best) = refine(c, fw, t, o, (ticks, taps), settings.trials, progress)?;
        t.feedforward = Some(Feedforward::Preview {
            ticks,
            taps: best,
            trials: kept as u32,
        });
        if kept + 1 != rounds.len() {
            load(c, fw, t, o, false)?;
        }
    }
    progress("measuring the tracking error at rest");
    let swing_rms_um = noise::tracking_swing(c)?;
    let swing_um = tune::watch_swing_um(swing_rms_um);
    t.watch_swing_um = Some(swing_um);
    progress(&format!(
        "  {swing_rms_um:.4} µm RMS: the loop watch's half swing {swing_um:.3} µm"
    ));
    let baseline = lead_baseline(c, progress)?;
    if let Some((b, _)) = baseline {
        t.lead_baseline = Some(b);
    }
    // Kept (its file written) before it runs for good.
    keep(&tune::with_tuning(fw, t, o)?)?;
    let model = load(c, fw, t, o, false)?;
    if store {
        load(c, fw, t, o, true)?;
    }
    let step = verify(c)?;
    Ok(OnBoard {
        model,
        rounds,
        kept,
        baseline,
        swing_rms_um,
        step,
    })
}

/// The lead's baseline of the model the board runs (one without a baseline):
/// closes the loop, warms up and steps 10 → 20 µm until the fit's ratio in
/// the board's status settles ([`BASELINE_STEPS`]); the ratio and the steps
/// taken. `None` where the model leaves no lead out. The board is left parked.
pub fn lead_baseline(
    c: &mut Client,
    progress: &mut impl FnMut(&str),
) -> Result<Option<(f64, usize)>> {
    let ratio = |c: &mut Client| -> Result<Option<f64>> {
        match c.status()?.lead_ratio {
            Some((_, true)) => bail!("the board's model carries a lead baseline already"),
            r => Ok(r.map(|(b, _)| piezo_fpi::q::LeadRatio::from_bits(b).to_num::<f64>())),
        }
    };
    if ratio(c)?.is_none() {
        return Ok(None);
    }
    progress("measuring the lead's baseline");
    close_and_warm_up(c)?;
    let (least, most) = BASELINE_STEPS;
    let (mut last, mut quiet, mut steps) = (f64::NAN, 0, 0);
    while steps < most && !(steps >= least && quiet >= 2) {
        step::run(c, &StepSettings::default()).context("the lead's baseline")?;
        steps += 1;
        let now = ratio(c)?.context("the lead's ratio left the board's status")?;
        progress(&format!("  step {steps}: the fit's ratio {now:.4}"));
        quiet = if (now - last).abs() < BASELINE_SETTLED {
            quiet + 1
        } else {
            0
        };
        last = now;
    }
    c.park()?;
    Ok(Some((last, steps)))
}

/// Loads `fw` with the tuning `t` onto the parked board (`store`: also into
/// flash); the model loaded.
fn load(
    c: &mut Client,
    fw: &FirmwareModel,
    t: &Tuning,
    o: &TuneOptions,
    store: bool,
) -> Result<FirmwareModel> {
    let model = tune::with_tuning(fw, t, o)?;
    let image = model.image().map_err(anyhow::Error::msg)?;
    c.park()?;
    c.upload(&image, store, |_| {})
        .context("loading the tuned model")?;
    Ok(model)
}

/// Refines the taps `(ticks, taps)` of the tuning `t`, which the board runs, on
/// `trials` trials (see the module docs): the rounds' errors, the round with
/// the least, and its taps (the board is left parked, running the last round's).
fn refine(
    c: &mut Client,
    fw: &FirmwareModel,
    t: &Tuning,
    o: &TuneOptions,
    (ticks, taps): (u8, Vec<f64>),
    trials: u32,
    progress: &mut impl FnMut(&str),
) -> Result<(Vec<Round>, usize, Vec<f64>)> {
    let spec = t
        .dynamics
        .ok_or_else(|| anyhow::anyhow!("taps designed without the stage's dynamics"))?;
    let plant = piezo_fpi::stability::Plant::new(&spec, fw.controller.rate_hz, 1.0, None, 1.0);
    let ridge = o.feedforward.map_or(0.0, |f| f.ridge);
    let mut candidates = vec![taps];
    let mut rounds = Vec::new();
    for k in 0..=trials as usize {
        if k > 0 {
            let mut next = t.clone();
            next.feedforward = Some(Feedforward::Preview {
                ticks,
                taps: candidates[k].clone(),
                trials: k as u32,
            });
            load(c, fw, &next, o, false)?;
        }
        close_and_warm_up(c)?;
        let run = trial::run(c).with_context(|| format!("the feedforward's trial {k}"))?;
        let round = Round {
            step_um: run[0].rms_error(),
            triangle_um: run[1].rms_error(),
        };
        progress(&format!(
            "  trial {k}: RMS error {:.3} µm on the step, {:.3} µm on the triangle",
            round.step_um, round.triangle_um
        ));
        rounds.push(round);
        if k == trials as usize {
            break;
        }
        match trials::refine(&plant, &t.laws, ticks, &candidates[k], &run, ridge) {
            Ok(h) => candidates.push(h),
            Err(e) => {
                progress(&format!("  the refinement stops: {e:#}"));
                break;
            }
        }
    }
    c.park()?;
    let kept = (0..rounds.len())
        .min_by(|&a, &b| rounds[a].score().total_cmp(&rounds[b].score()))
        .unwrap_or(0);
    Ok((rounds, kept, candidates.swap_remove(kept)))
}

/// Closes the loop, warms up and steps 10 → 20 µm; the step's figures.
pub fn verify(c: &mut Client) -> Result<StepFigures> {
    close_and_warm_up(c)?;
    let (_, fig) = step::run(c, &StepSettings::default())?;
    Ok(fig)
}

/// The table autotune prints (markdown).
pub fn table(a: &Autotune) -> String {
    let t = &a.tuning;
    let ms = |v: Option<f64>| v.map_or("—".into(), |v| format!("{v:.2} ms"));
    let rows = [
        (
            "stage (measured)",
            format!(
                "mode {:.1} Hz, ζ {:.4}, lag {:.0} Hz, κ {:.2} N/µm",
                a.fit.spec.mode_hz(),
                a.fit.spec.damping_ratio(),
                a.fit.spec.lag_mhz as f64 / 1000.0,
                a.fit.spec.force_gain.to_num::<f64>()
            ),
        ),
        (
            "force sensor's noise at rest",
            format!(
                "σ {:.3} N: the damping moves the stage {:.3} µm RMS (budget {:.2} µm)",
                a.force_noise_n,
                t.noise_motion_um_per_n * a.force_noise_n,
                tune::NOISE_BUDGET_UM
            ),
        ),
        (
            "damping target",
            match t.damping_target {
                (0.0, _) => "none (no damping asked, or nothing to design it on)".into(),
                (asked, 0.0) => format!("none (asked {asked:.2}): the noise allows no damping"),
                (asked, used) if used < asked => {
                    format!("{used:.2} (asked {asked:.2}; lowered for the noise)")
                }
                (asked, _) => format!("{asked:.2}"),
            },
        ),
        (
            "mode damping (family's least)",
            format!("{:.3} → {:.3}", t.mode_damping.0, t.mode_damping.1),
        ),
        (
            "damping loop margins",
            format!("{:.1} dB, {:.0}°", t.damping_margins.0, t.damping_margins.1),
        ),
        (
            "position PI",
            format!("kp {:.3}, ki {:.0}/s", t.kp, t.ki_per_s),
        ),
        (
            "crossover / −3 dB bandwidth (design)",
            format!("{:.0} Hz / {:.0} Hz", t.crossover_hz, t.bandwidth_hz),
        ),
        (
            "position loop margins",
            format!("{:.1} dB, {:.0}°", t.margins.0, t.margins.1),
        ),
        (
            "sensitivity peak (family)",
            format!("{:.2}", t.sensitivity_peak),
        ),
        ("feedforward refined through the board", refinement(a)),
        (
            "loop watch's half swing",
            format!(
                "{:.3} µm: {} × the tracking error's {:.4} µm RMS at rest (within 0.075…0.2 µm)",
                t.watch_swing_um
                    .unwrap_or(piezo_fpi::model::WATCH_SWING_MAX.to_num::<f64>()),
                tune::WATCH_SWING_RMS,
                a.swing_rms_um
            ),
        ),
        (
            "lead baseline (mass ratio learned from it)",
            a.baseline.map_or("— (no lead)".into(), |(b, n)| {
                format!("{b:.3}, measured over {n} steps")
            }),
        ),
        ("step 10 → 20 µm: rise", format!("{:.2} ms", a.step.rise_ms)),
        ("overshoot", format!("{:.3} µm", a.step.overshoot_um)),
        ("settles within ±0.1 µm", ms(a.step.settle_ms)),
    ];
    let mut s = String::from("| | |\n|---|---|\n");
    for (k, v) in rows {
        s.push_str(&format!("| {k} | {v} |\n"));
    }
    s
}

/// The refinement's row: the position sensor's RMS errors (step / triangle)
/// round by round, and the round kept.
fn refinement(a: &Autotune) -> String {
    if a.rounds.is_empty() {
        return "no (taps as designed on the fitted plant)".into();
    }
    let rounds: Vec<String> = a
        .rounds
        .iter()
        .map(|r| format!("{:.3} / {:.3}", r.step_um, r.triangle_um))
        .collect();
    format!(
        "RMS error step / triangle (position sensor) {} µm; {} trial(s), round {} kept",
        rounds.join(" → "),
        a.rounds.len() - 1,
        a.kept
    )
}

/// Writes the tuned model and the measured response next to it.
pub fn write(a: &Autotune, out: &Path, frf_out: Option<&Path>) -> Result<()> {
    write_model(&a.model, out)?;
    if let Some(p) = frf_out {
        fit::write_csv(p, &a.frf, &a.frf_conditions)?;
    }
    Ok(())
}

/// Writes a tuned model to `out` (atomically): what [`run_keeping`] is given
/// to keep it before it is loaded for good.
pub fn write_model(model: &FirmwareModel, out: &Path) -> Result<()> {
    let text = model.to_toml().map_err(anyhow::Error::msg)?;
    crate::output::write_atomic(out, text.as_bytes())
}
