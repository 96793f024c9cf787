//! Damping, autotune and the loops on the stage as built, on the firmware built
//! for the host, in-process (`fpi_tests::behaviour_board`: the same control
//! task and virtual bench as the emulated board's, at the board's real-time
//! pace, where QEMU runs slower than real time), driven
//! through the library a user's `fpi board …` runs:
//!
//! * `fpi board frf`'s measurement on the quasi-static nominal stage (a flat
//!   unit response) and on the stage as built (its 850 Hz mode found);
//! * `fpi board step`'s figures;
//! * `fpi board autotune`: the fitted plant, the loops designed and loaded, the
//!   verification step; then the four drives compared (open loop, PI,
//!   damping and PI, damping, PI and feedforward) and the damped drives'
//!   tracking bandwidth — the targets are **printed**
//!   (run with `--nocapture`), generous bounds are asserted;
//! * robustness: the tuning loaded unchanged onto stage variants (mode
//!   700–1000 Hz, damping 0.015–0.05, gains a few percent off).

use std::sync::OnceLock;

use fpi_host::board::autotune::{self, Autotune};
use fpi_host::board::bandwidth;
use fpi_host::board::client::{real, Client};
use fpi_host::board::closed_loop::{self, Drive};
use fpi_host::board::follow::Follow;
use fpi_host::board::frf::{self, FrfSettings};
use fpi_host::board::mass;
use fpi_host::board::step::{self, StepSettings};
use fpi_host::method::tune::TuneOptions;
use fpi_protocol::{BenchOrder, StageVariant};
use fpi_tests::behaviour_board as board;
use piezo_sim::file::{FirmwareModel, ShapingSection};

/// `fw` loaded onto a parked board with the stage `v`.
fn load(c: &mut Client, fw: &FirmwareModel, v: StageVariant) {
    c.park().unwrap();
    c.upload(&fw.image().unwrap(), false, |_| {}).unwrap();
    c.bench(BenchOrder::Stage(v)).unwrap();
}

/// The stage as built with its mode at `mode_hz`, damped `zeta`, and its
/// output gain scaled by `gain` where given.
fn built_with_mode(mode_hz: f32, zeta: f32, gain: Option<f32>) -> StageVariant {
    StageVariant {
        mode_hz: Some(mode_hz),
        mode_damping: Some(zeta),
        output_gain: gain,
        ..StageVariant::BUILT
    }
}

/// A freshly loaded tuning's first steps on the board `c` (`name` in a
/// failure): autotune's verification (the loop closed and warmed up, then the
/// 10 → 20 µm step), then two more of the same step.
fn three_steps(c: &mut Client, name: &str) -> Vec<step::StepFigures> {
    let mut figs = vec![autotune::verify(c).unwrap_or_else(|e| panic!("{name}: {e:#}"))];
    for _ in 0..2 {
        figs.push(step::run(c, &StepSettings::default()).unwrap().1);
    }
    figs
}

/// Autotune on the stage as built (once), and the board it ran on.
///
/// Its autotune is the longest wait of this file (half a minute). The harness
/// starts the tests in the order of their names, so the first (`a_fast_wave_s_…`) runs it, while the other thread runs the next two,
/// which need it not (`a_fault_latched_…`, and `a_force_sensor_s_noise_…` with
/// an autotune of its own), rather than waiting for it.
fn tuned() -> &'static Autotune {
    static TUNED: OnceLock<Autotune> = OnceLock::new();
    TUNED.get_or_init(|| {
        let (_e, mut c) = board("autotune");
        let fw = fpi_tests::factory_model();
        load(&mut c, &fw, StageVariant::BUILT);
        let a = autotune_as_a_user_would(&mut c, &fw).unwrap_or_else(|e| panic!("{e:#}"));
        println!("{}", autotune::table(&a));
        // The governor's tests run on it too (tests/governor.rs).
        fpi_tests::keep_tuned(&a.model);
        a
    })
}

/// `fpi board autotune` with its defaults, not stored, on the board `c` runs
/// `fw` on.
fn autotune_as_a_user_would(c: &mut Client, fw: &FirmwareModel) -> anyhow::Result<Autotune> {
    let settings = autotune::Settings::default();
    autotune::run(c, fw, &TuneOptions::default(), &settings, false, |m| {
        println!("{m}")
    })
}

#[test]
fn the_analyser_measures_a_flat_stage_flat_and_finds_the_built_stages_mode() {
    let (_e, mut c) = board("frf");
    let fw = fpi_tests::factory_model();
    let s = FrfSettings {
        points: 12,
        zoom_points: 0,
        ..FrfSettings::default()
    };
    load(&mut c, &fw, StageVariant::NOMINAL);
    let flat = frf::measure(&mut c, &s, |_, _| {}).unwrap();
    for p in &flat {
        // The quasi-static twin: the command reaches the stage through the
        // inverse model (gain ≈ 1), the amplifier's lag and one tick: flat
        // below 300 Hz, falling above, never a peak.
        assert!(p.x.norm() < 1.1, "{p:?}");
        if p.f_hz < 300.0 {
            assert!((p.x.norm() - 1.0).abs() < 0.1, "{p:?}");
        }
    }
    load(&mut c, &fw, StageVariant::BUILT);
    let built = frf::measure(&mut c, &FrfSettings::default(), |_, _| {}).unwrap();
    let peak = built
        .iter()
        .max_by(|a, b| a.x.norm().total_cmp(&b.x.norm()))
        .unwrap();
    println!(
        "built stage's peak: {:.1} Hz, |x/u| {:.2}",
        peak.f_hz,
        peak.x.norm()
    );
    assert!(
        (peak.f_hz - 850.0).abs() < 60.0 && peak.x.norm() > 5.0,
        "{peak:?}"
    );
    // Faults void an analysis: a refusal is the board's, not a silent zero.
    c.park().unwrap();
}

#[test]
fn autotune_fits_the_stage_and_its_loops_settle_a_step() {
    let a = tuned();
    let d = a.fit.spec;
    // The stage as built: 850 Hz, ζ 0.03; the fit within a few percent (the
    // mode) and within the family's spread (ζ).
    assert!((d.mode_hz() - 850.0).abs() < 30.0, "{d:?}");
    assert!(
        d.damping_ratio() > 0.01 && d.damping_ratio() < 0.06,
        "{d:?}"
    );
    assert!(d.force_gain.to_num::<f64>() > 3.0, "{d:?}");
    // The position misfit: 7 % in-process; 23 % in one QEMU run, where the
    // governor halved the stimulus at frequencies about the mode and the
    // response there was measured with less signal over the same noise.
    // Within `fpi tune --frf`'s 30 % warning either way.
    assert!(a.fit.x_misfit < 0.25, "{:?}", a.fit);
    // The loops: damped, with margin, fast.
    let t = &a.tuning;
    assert!(t.mode_damping.1 > 0.2, "{:?}", t.mode_damping);
    assert!(
        t.sensitivity_peak <= 1.6 + 1e-9 && t.bandwidth_hz > 200.0,
        "{t:?}"
    );
    // The verification step: settled (generous; the figures are printed).
    let settle = a.step.settle_ms.unwrap_or(f64::INFINITY);
    assert!(settle < 10.0 && a.step.overshoot_um < 1.5, "{:?}", a.step);
    // The feedforward runs ahead of the tracked reference.
    let preview = a.model.shaping.as_ref().map(|s| s.preview_ticks);
    assert_eq!(preview, Some(5));
    // Its taps were refined on the default trials, and the round kept has
    // less error on the position sensor than the taps as designed (on the
    // stage as built, about a quarter: the figures are printed).
    assert_eq!(
        a.rounds.len(),
        autotune::TRIALS as usize + 1,
        "{:?}",
        a.rounds
    );
    assert!(
        a.rounds[a.kept].score() < 0.7 * a.rounds[0].score(),
        "{:?}",
        a.rounds
    );
    let notes = &a.model.shaping.as_ref().unwrap().notes;
    assert!(a.kept == 0 || notes.contains("trial"), "{notes}");
    // The lead's baseline was measured on the board and written into the
    // model: the fit's ratio on the stage as built (0.86–0.89 in the runs
    // recorded in the book, `docs/src/autotune.md`), settled within the steps
    // allowed.
    let (b, steps) = a.baseline.expect("a lead baseline");
    assert!(b > 0.7 && b < 1.0, "{b}");
    assert!(steps <= autotune::BASELINE_STEPS.1, "{steps}");
    assert_eq!(a.model.damping.as_ref().unwrap().lead_baseline, Some(b));
    // The tuned model is a model file any board loads.
    let text = a.model.to_toml().unwrap();
    let back = FirmwareModel::parse(&text, "tuned").unwrap();
    assert_eq!(back.image().unwrap(), a.model.image().unwrap());
}

#[test]
fn damping_and_feedforward_beat_the_pi_alone() {
    let a = tuned();
    let (_e, mut c) = board("drives");
    let fw = fpi_tests::factory_model();
    let pi_only = TuneOptions {
        damping: false,
        feedforward: None,
        ..TuneOptions::default()
    };
    let t = fpi_host::method::tune::tune_measured(&fw, a.fit.spec, &pi_only).unwrap();
    let pi = fpi_host::method::tune::with_tuning(&fw, &t, &pi_only)
        .unwrap()
        .image()
        .unwrap();
    let r = closed_loop::run(&mut c, &pi, &a.model.image().unwrap())
        .unwrap_or_else(|e| panic!("{e:#}"));
    println!("{}", closed_loop::table(&r));
    let run = |d| r.run(d).unwrap();
    let (open, pi, ff) = (
        run(Drive::Open),
        run(Drive::Pi),
        run(Drive::DampedFeedforward),
    );
    // 15 Hz: ≤ 0.3 % of the 30 µm span and ≤ 0.3× open loop (the target).
    assert!(ff.sine.rms() < 0.003 * 30.0, "{:?}", ff.sine.rms());
    assert!(ff.sine.rms() < 0.3 * open.sine.rms());
    // The triangle and the step: better than the PI alone.
    assert!(ff.triangle.rms() < pi.triangle.rms());
    let settle = |s: Option<f64>| s.unwrap_or(f64::INFINITY);
    assert!(settle(ff.step.settle_ms) < settle(pi.step.settle_ms));
    // The tracking bandwidth, measured through the board: ≥ 200 Hz (the
    // issue's target) for both damped drives, flat at low frequency.
    for d in [Drive::Damped, Drive::DampedFeedforward] {
        let resp = &run(d).response;
        assert_eq!(resp.len(), closed_loop::RESPONSE_SINE.3, "{d:?}");
        assert!(resp[0].db().abs() < 0.5, "{d:?}: {:?}", resp[0]);
        let bw = bandwidth::bandwidth_hz(resp).unwrap_or(f64::INFINITY);
        assert!(bw >= 200.0, "{d:?}: {bw} Hz");
    }
}

#[test]
fn the_preview_runs_the_shaping_ahead_and_the_loops_that_many_ticks_late() {
    let (_e, mut c) = board("preview");
    let mut fw = fpi_tests::factory_model();
    let s = StepSettings {
        from_um: 10.0,
        to_um: 20.0,
        seconds: 0.01,
        ..StepSettings::default()
    };
    // The tick the tracked (and recorded) reference leaves its start, from the
    // step's first tick, for a model whose shaping (the identity) runs `ticks`
    // ahead.
    let mut starts = Vec::new();
    for ticks in [0u8, 5] {
        // The shaping is the newest reference itself (one tap of 1).
        fw.shaping = (ticks > 0).then(|| ShapingSection {
            sections: Vec::new(),
            preview_ticks: ticks,
            taps: vec![1.0],
            notes: String::new(),
        });
        load(&mut c, &fw, StageVariant::NOMINAL);
        let (rec, fig) = step::run(&mut c, &s).unwrap();
        let from = rec.samples[0].tick;
        let moved = rec
            .samples
            .iter()
            .find(|x| real(x.x_ref) > s.from_um + 1e-3)
            .map(|x| x.tick - from)
            .unwrap();
        println!("preview {ticks}: the reference moves {moved} ticks after the step; {fig:?}");
        starts.push(moved);
    }
    assert_eq!(starts[1], starts[0] + 5, "{starts:?}");
    c.park().unwrap();
}

/// The explained force's learned ratio in the board's status, and whether the
/// damping applies it.
fn lead_ratio(c: &mut Client) -> Option<(f64, bool)> {
    let s = c.status().unwrap();
    s.lead_ratio.map(|(b, applied)| {
        (
            piezo_fpi::q::LeadRatio::from_bits(b).to_num::<f64>(),
            applied,
        )
    })
}

/// The tuning loaded unchanged onto variants as `fpi board load
/// --match-mass` loads it: the board measures the stage's mode and starts its
/// mass ratio there (`fpi_host::board::mass`), then steps three times
/// (autotune's verification, then two more 10 → 20 µm steps) while it learns
/// the mass on (`piezo_fpi::lead`). The settling times (the 6 ms target) and
/// the ratios are printed; asserted: every step settles within the record, a
/// new model starts the ratio at 1, the match finds the variant's mode and its
/// true mass ratio `(850 Hz/f)²` (1.47 at 700 Hz, 0.72 at 1000 Hz) within 3 %,
/// the ratio learned on stays within 20 % of it, and a park keeps it.
#[test]
fn the_tuning_holds_on_stage_variants() {
    let a = tuned();
    let (_e, mut c) = board("variants");
    println!(
        "| variant | mode measured (Hz) | mass ratio set | overshoot (µm) | settles ±0.1 µm (ms) | mass ratio learned (true) |\n|---|---|---|---|---|---|"
    );
    let mut worst: f64 = 0.0;
    for (mode_hz, zeta, gain) in [
        (700.0, 0.015, 0.97),
        (700.0, 0.05, 1.03),
        (1000.0, 0.015, 1.03),
        (1000.0, 0.05, 0.97),
    ] {
        let v = built_with_mode(mode_hz, zeta, Some(gain));
        load(&mut c, &a.model, v);
        assert_eq!(lead_ratio(&mut c), Some((1.0, true)));
        // The model's shaping is taps on the preview's line: shown, and on.
        assert_eq!(c.status().unwrap().shaping, Some(true));
        let name = format!("{mode_hz} Hz, ζ {zeta}, gain {gain}");
        let truth = (850.0 / f64::from(mode_hz)).powi(2);
        let m = mass::match_mass(&mut c, &a.model).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert!((m.ratio / truth - 1.0).abs() < 0.03, "{name}: {m:?}");
        let set = lead_ratio(&mut c).unwrap().0;
        assert!((set - m.ratio).abs() < 1e-6, "{name}: {set}");
        // The match leaves the model's damping and shaping on, the loop open.
        let s = c.status().unwrap();
        assert_eq!((s.damping, s.shaping), (Some(true), Some(true)));
        assert_eq!(s.loop_mode, fpi_protocol::LoopMode::Open);
        let figs = three_steps(&mut c, &name);
        let (beta, _) = lead_ratio(&mut c).unwrap();
        let ms = |f: &step::StepFigures| f.settle_ms.map_or("—".into(), |v| format!("{v:.2}"));
        println!(
            "| {name} | {:.1} | {:.3} | {} | {} | {beta:.3} ({truth:.2}) |",
            m.stage_hz,
            m.ratio,
            figs.iter()
                .map(|f| format!("{:.3}", f.overshoot_um))
                .collect::<Vec<_>>()
                .join(", "),
            figs.iter().map(ms).collect::<Vec<_>>().join(", "),
        );
        for f in &figs {
            // Stable and settled within the record (the 6 ms target is printed).
            let settle = f.settle_ms.unwrap_or_else(|| panic!("{name}: {f:?}"));
            worst = worst.max(settle);
        }
        // Learning on from the match keeps the ratio near the true one (on
        // the 700 Hz ζ 0.015 variant it rises past it, to about 1.7).
        assert!((beta / truth - 1.0).abs() < 0.2, "{name}: {beta}");
        // A park (a fault) keeps what was learned; the stage is the same.
        c.park().unwrap();
        assert_eq!(lead_ratio(&mut c), Some((beta, true)));
    }
    println!("worst settling over the variants' steps: {worst:.2} ms (target 6 ms)");
}

/// The mass ratio is set only where the running model applies it, and only
/// within `[1/2, 2)`: the board refuses anything else with the reason, and
/// `--match-mass` refuses a model without the lead before it moves the stage.
#[test]
fn the_mass_ratio_is_set_only_where_a_model_applies_it() {
    use fpi_host::board::client::refusal;
    use fpi_protocol::{Command, Refusal};
    let set = |c: &mut Client, ratio: f64| {
        c.ack(&Command::LeadRatio {
            axis: 0,
            ratio: (ratio * f64::from(1u32 << 30)) as i32,
        })
    };
    let (_e, mut c) = board("mass ratio");
    let fw = fpi_tests::factory_model();
    load(&mut c, &fw, StageVariant::BUILT);
    let e = mass::match_mass(&mut c, &fw).unwrap_err();
    assert!(format!("{e:#}").contains("lead_baseline"), "{e:#}");
    let e = set(&mut c, 1.2).unwrap_err();
    let r = refusal(&e).unwrap_or_else(|| panic!("{e:#}"));
    assert_eq!(r.code, Refusal::BadArgument);
    assert!(r.reason.contains("no learned mass ratio"), "{r:?}");
    load(&mut c, &tuned().model, StageVariant::BUILT);
    for bad in [0.25, 0.49, -1.0] {
        let e = set(&mut c, bad).unwrap_err();
        let r = refusal(&e).unwrap_or_else(|| panic!("{e:#}"));
        assert!(r.reason.contains("mass ratio"), "{}", r.reason);
    }
    assert_eq!(lead_ratio(&mut c), Some((1.0, true)));
    set(&mut c, 1.25).unwrap();
    assert_eq!(lead_ratio(&mut c), Some((1.25, true)));
    // A new model starts from 1 again.
    load(&mut c, &tuned().model, StageVariant::BUILT);
    assert_eq!(lead_ratio(&mut c), Some((1.0, true)));
}

/// A move out of a park that followed a hold elsewhere starts from where the
/// stage rests, not from the old reference: with the tuning's preview and
/// damping on, the held reference (20 µm) once read as a 20 µm jump of the
/// shaped reference, whose lead force (over 100 N) wound up the damping's
/// integral and threw the 700 Hz ζ 0.015 variant to 33 µm on a move that
/// had reached 2 µm, tripping a force fault (found by `--match-mass`, which
/// parks after its sweep at 20 µm: in experiments the next move faulted on
/// 9 of 14 fresh autotunes' boards, none of 3 after the fix). Asserted: no fault, and the true
/// position never passes the target by more than 0.3 µm (it stops short of
/// it in open loop).
#[test]
fn a_move_after_a_park_starts_where_the_stage_rests() {
    use fpi_host::board::follow::Capture;
    use fpi_protocol::record::signal;
    let a = tuned();
    let (_e, mut c) = board("move after a park");
    load(&mut c, &a.model, built_with_mode(700.0, 0.015, Some(0.97)));
    // The match holds at 20 µm for its sweep, with damping and shaping off,
    // then parks and switches them on again.
    mass::match_mass(&mut c, &a.model).unwrap();
    for round in 0..2 {
        let mut f = Follow::new(&mut c, signal::X_TRUE | signal::STATUS);
        let cap = Capture {
            what: "the move",
            decimation: 1,
            seconds: 0.04,
            hint: "",
        };
        let from = f
            .capture(
                &cap,
                |c| c.move_to(20.0, 1000.0),
                |st, from| Ok(st.fault.is_some() || st.tick >= from + 700),
            )
            .unwrap();
        let status = f.c.status().unwrap();
        assert_eq!(status.fault, None, "round {round}");
        let peak = f
            .rec
            .samples
            .iter()
            .filter(|x| x.tick >= from)
            .map(|x| f64::from(x.x_true) / 65536.0)
            .fold(f64::MIN, f64::max);
        println!("round {round}: the true position's peak {peak:.3} µm (target 20)");
        assert!(peak < 20.3, "round {round}: {peak}");
        Follow::new(&mut c, 0).until_hold().unwrap();
        c.park().unwrap();
    }
}

#[test]
fn a_step_through_the_board_is_scored_on_the_true_position() {
    let (_e, mut c) = board("step");
    load(&mut c, &fpi_tests::factory_model(), StageVariant::NOMINAL);
    let s = StepSettings {
        from_um: 10.0,
        to_um: 20.0,
        tol_um: Some(0.5),
        ..StepSettings::default()
    };
    let (rec, fig) = step::run(&mut c, &s).unwrap();
    println!("{}", step::describe(&fig, s.tol_um));
    assert!(fig.true_position && rec.dropped == 0);
    // The quasi-static twin follows the 1.5 ms raised cosine: rise about 0.75 ms
    // (10–90 % of a half cosine is 59 % of its duration: 0.89 ms, less the lag).
    assert!(fig.rise_ms > 0.5 && fig.rise_ms < 1.2, "{fig:?}");
    assert!(fig.settle_tol_ms.unwrap() <= fig.settle_ms.unwrap_or(f64::INFINITY));
    c.park().unwrap();
}

/// The tuned loops on a stage far outside the family they were designed for:
/// moved to 20 µm in open loop without the damping, then the damping switched
/// on, the position loop closed and a 1 µm step commanded (what a user does
/// next; a quiet close with no command: `a_quiet_close_…`) — what trips, how
/// soon after the step
/// (which the link delivers a few milliseconds after the close), and how far
/// the stage went. (The damping alone on such a stage: `the_damping_alone_…`.)
fn unstable_run(c: &mut Client, a: &Autotune, v: StageVariant) -> Unstable {
    use fpi_protocol::{Command, LoopMode};
    load(c, &a.model, v);
    c.damping(false).unwrap();
    c.move_to(20.0, 1000.0).unwrap();
    Follow::new(c, 0).until_hold().unwrap();
    watched(c, |f| {
        f.c.damping(true).unwrap();
        f.c.ack(&Command::Loop {
            axis: 0,
            mode: LoopMode::Closed,
        })
        .unwrap();
        f.c.step(21.0, 1.5).unwrap()
    })
}

/// Records the true position from the tick `start` returns (it starts
/// something on the board, and may wait on the `Follow`) until 100 ms after it
/// or after the fault that latched: the fault, how soon, and the true
/// position's range up to it and after it (the park).
fn watched(c: &mut Client, start: impl FnOnce(&mut Follow) -> u32) -> Unstable {
    use fpi_firmware::control::recorder::signal;
    use fpi_host::board::client::real;
    use fpi_protocol::Command;
    let mut f = Follow::new(c, signal::X_TRUE | signal::X_REF | signal::STATUS);
    f.record(1).unwrap();
    f.rec.samples.clear();
    let started = start(&mut f);
    let end = started + f.ticks(0.1);
    f.until_tick(end).unwrap();
    let fault = f.c.status().unwrap().fault.filter(|x| x.at >= started);
    let end = fault.map_or(end, |x| end.max(x.at + f.ticks(0.1)));
    f.until_tick(end).unwrap();
    f.c.ack(&Command::RecordStop).unwrap();
    f.drain().unwrap();
    let at = fault.map_or(end, |x| x.at);
    let range = |before: bool| {
        f.rec
            .samples
            .iter()
            .filter(|s| s.tick >= started && (s.tick <= at) == before)
            .map(|s| real(s.x_true))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            })
    };
    let last = f.ticks(0.01);
    let tail: Vec<f64> = f
        .rec
        .samples
        .iter()
        .filter(|s| s.tick + last > end)
        .map(|s| real(s.x_true))
        .collect();
    let rest = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
    let residual_um = tail.iter().map(|x| (x - rest).abs()).fold(0.0, f64::max);
    let ring_ms = f
        .rec
        .samples
        .iter()
        .filter(|s| s.tick > at && (real(s.x_true) - rest).abs() > 0.5)
        .map(|s| s.tick)
        .max()
        .filter(|t| t + last <= end)
        .map(|t| (t - at) as f64 / 20.0);
    Unstable {
        ring_ms,
        residual_um,
        fault: fault.and_then(|x| piezo_fpi::control::Fault::from_code(x.code)),
        ms: (at - started) as f64 / 20.0,
        safe_ms: fault
            .and_then(|x| x.safe_at)
            .map(|s| (s - at) as f64 / 20.0),
        before: range(true),
        after: range(false),
    }
}

/// What [`unstable_run`] saw.
#[derive(Debug)]
struct Unstable {
    fault: Option<piezo_fpi::control::Fault>,
    /// From the start to the fault, ms.
    ms: f64,
    /// From the fault to the safe voltage, ms.
    safe_ms: Option<f64>,
    /// The true position's range up to the fault and after it (the park), µm.
    before: (f64, f64),
    after: (f64, f64),
    /// From the fault until the true position stays within ±0.5 µm of where
    /// it rests (its mean over the record's last 10 ms), ms; `None` if it does
    /// not within the record.
    ring_ms: Option<f64>,
    /// The true position's largest departure from where it rests over the
    /// record's last 10 ms, µm.
    residual_um: f64,
}

#[test]
fn an_unstable_loop_is_caught_before_the_stroke_is_left() {
    let a = tuned();
    let (_e, mut c) = board("unstable");
    for (mode_hz, zeta) in [(300.0, 0.01), (400.0, 0.01), (2000.0, 0.01)] {
        let v = built_with_mode(mode_hz, zeta, None);
        let u = unstable_run(&mut c, a, v);
        println!(
            "{mode_hz} Hz, ζ {zeta}: {:?} after {:.2} ms; true position {:.2}–{:.2} µm until \
             then, {:.2}–{:.2} µm while parking (safe voltage after {:?} ms); within ±0.5 µm \
             of its rest after {:?} ms (swing over the last 10 ms ±{:.2} µm)",
            u.fault,
            u.ms,
            u.before.0,
            u.before.1,
            u.after.0,
            u.after.1,
            u.safe_ms,
            u.ring_ms,
            u.residual_um
        );
        if mode_hz < 1000.0 {
            // Caught, named, within 20 ms of the step after closing the loops
            // and inside the stroke; the park sets off no ringing of its own,
            // and the force feedback, kept through the park, damps the
            // oscillation caught
            // (undamped it rang down to −3.1…−3.8 µm at 300 Hz; damped −0.18…−1.95
            // µm over four runs, depending on the phase at which the fault lands).
            assert!(u.after.0 > -2.5, "a damped park: {u:?}");
            assert_eq!(
                u.fault,
                Some(piezo_fpi::control::Fault::Oscillation),
                "{u:?}"
            );
            assert!(
                u.ms <= 20.0 && u.before.0 > 0.0 && u.before.1 < 39.9,
                "{u:?}"
            );
        }
        c.park().unwrap();
        c.ack(&fpi_protocol::Command::ClearFault).ok();
    }
}

/// A quiet close, no command, on a stage whose mode moved to 400–425 Hz:
/// the oscillation starts at a tenth of a micrometre or less and grows by a
/// few percent per half-cycle. The watch, at the half swing autotune set from
/// the stage's noise (0.075…0.2 µm; at 0.2 µm it took 40–50 ms), counts it
/// while it is small: caught, named, inside the stroke. The latency is
/// printed; the bound asserted is generous. The oscillation grows from the
/// sensor noise the close meets, whose phase the host's timing sets (the
/// close is a command, sent at a wall-clock instant), so the latency spreads:
/// in-process, 15 runs at 400, 425 and 450 Hz: 11.05–19.85 ms; under QEMU on a
/// loaded machine 9.75–67.7 ms (the slowest with the stage inside
/// 19.68–20.83 µm until caught). What the test holds to is the stroke: the
/// true position stays inside 15–25 µm until the watch parks it.
#[test]
fn a_quiet_close_on_a_stage_that_changed_is_caught() {
    use fpi_protocol::{Command, LoopMode};
    let a = tuned();
    let swing = a.model.feedback.as_ref().and_then(|f| f.watch_swing_um);
    println!(
        "the watch's half swing: {swing:?} µm ({:.4} µm RMS at rest)",
        a.swing_rms_um
    );
    // Within the model's range (its least, 0.075 µm, is 4915 I16F16 bits).
    assert!(
        swing.is_some_and(|h| (0.0749..=0.2).contains(&h)),
        "{swing:?}"
    );
    let (_e, mut c) = board("quiet close");
    for mode_hz in [400.0, 425.0] {
        load(&mut c, &a.model, built_with_mode(mode_hz, 0.01, None));
        c.damping(false).unwrap();
        c.move_to(20.0, 1000.0).unwrap();
        Follow::new(&mut c, 0).until_hold().unwrap();
        let u = watched(&mut c, |f| {
            f.c.damping(true).unwrap();
            f.c.ack(&Command::Loop {
                axis: 0,
                mode: LoopMode::Closed,
            })
            .unwrap()
        });
        println!(
            "{mode_hz} Hz, ζ 0.01, quiet close: {:?} after {:.2} ms; true position {:.2}–{:.2} µm \
             until then",
            u.fault, u.ms, u.before.0, u.before.1
        );
        assert_eq!(
            u.fault,
            Some(piezo_fpi::control::Fault::Oscillation),
            "{u:?}"
        );
        assert!(
            u.ms <= 100.0 && u.before.0 > 15.0 && u.before.1 < 25.0,
            "{u:?}"
        );
        c.park().unwrap();
        c.ack(&Command::ClearFault).ok();
    }
}

/// The price of a small half swing: the model autotune tuned on the quiet
/// stage as built, loaded onto one whose position sensor is far noisier
/// (σ 0.08 µm instead of 0.003), parks at rest with `Oscillation`; the
/// board's status then names the model's half swing and the remedies.
#[test]
fn a_model_tuned_on_a_quiet_stage_says_why_it_parks_on_a_noisier_one() {
    use fpi_protocol::{Command, LoopMode};
    let a = tuned();
    let (_e, mut c) = board("noisier board");
    let noisy = StageVariant {
        position_noise_um: Some(0.08),
        ..StageVariant::BUILT
    };
    load(&mut c, &a.model, noisy);
    c.move_to(20.0, 1000.0).unwrap();
    Follow::new(&mut c, 0).until_hold().unwrap();
    let start = c
        .ack(&Command::Loop {
            axis: 0,
            mode: LoopMode::Closed,
        })
        .unwrap();
    let text = parks_oscillating(&mut c, start, "σ 0.08 µm");
    assert!(
        text.contains("loop watch counts swings beyond") && text.contains("watch_swing_um = 0.2"),
        "{text}"
    );
}

/// Follows the board from `start` (its tick) until a fault or for 1 s,
/// prints when, asserts it is `Oscillation`, and parks after it; the board's
/// status, printed.
fn parks_oscillating(c: &mut Client, start: u32, what: &str) -> String {
    let mut f = Follow::new(c, 0);
    let at = f
        .until("a fault", |s| {
            Ok(s.fault.is_some() || s.tick > start + 20_000)
        })
        .unwrap();
    let fault = f.c.status().unwrap().fault.map(|x| x.code);
    println!(
        "{what}: {fault:?} after {:.2} ms",
        (at - start) as f64 / 20.0
    );
    assert_eq!(fault, Some(piezo_fpi::control::Fault::Oscillation as u8));
    let text = fpi_host::cli::board::status_text(c).unwrap();
    println!("{text}");
    c.park().unwrap();
    c.ack(&fpi_protocol::Command::ClearFault).ok();
    text
}

/// The same for the force sensor: the model autotune tuned on the stage as
/// built (force noise σ 0.14 N), loaded onto one whose force sensor reads
/// σ 3 N, with the damping alone (open loop): the damping, designed for the
/// quieter sensor, turns the noise into motion that the watch takes for an
/// oscillation; the board's status then points at the damping's design and
/// the remedies.
#[test]
fn a_model_tuned_with_a_quieter_force_sensor_says_why_it_parks() {
    let a = tuned();
    let (_e, mut c) = board("noisier force sensor");
    let noisy = StageVariant {
        force_noise_n: Some(3.0),
        ..StageVariant::BUILT
    };
    load(&mut c, &a.model, noisy);
    let start = c.status().unwrap().tick;
    // The move may be refused once the board has parked.
    c.move_to(20.0, 1000.0).ok();
    let text = parks_oscillating(&mut c, start, "force noise σ 3 N, damping alone");
    assert!(
        text.contains(fpi_host::board::noise::DAMPING_HINT),
        "{text}"
    );
}

/// The damping alone (open loop) on a stage whose mode moved far below the
/// one it was designed for: at 300 Hz the damping loop itself oscillates at
/// about 100 Hz from the move's start: the stage swings about the ramp by
/// ±1 µm and more, in half-cycles of 5 ms; at 350 Hz, at about 110 Hz, it
/// stays about ±1 µm, barely growing (the undecaying rule: the 1 mm/s move
/// creeps, which holds). Caught and named inside the stroke, during the 20 ms
/// move or in the oscillation about its end (measured: 16.25–17.95 ms once,
/// 40.2 and 40.9 ms at 300 Hz in later runs, the stage inside 0.03–32.2 µm
/// until then: the growth starts from the noise the move meets); the stroke is
/// what is asserted, with a bound of 50 ms on the latency.
#[test]
fn the_damping_alone_on_a_stage_that_changed_is_caught() {
    let a = tuned();
    let (_e, mut c) = board("damping alone");
    for mode_hz in [300.0, 350.0] {
        load(&mut c, &a.model, built_with_mode(mode_hz, 0.01, None));
        let u = watched(&mut c, |f| f.c.move_to(20.0, 1000.0).unwrap());
        println!(
            "{mode_hz} Hz, ζ 0.01, open loop, move 0 → 20 µm at 1 mm/s: {:?} after {:.2} ms; \
             true position {:.2}–{:.2} µm until then, {:.2}–{:.2} µm while parking (safe \
             voltage after {:?} ms)",
            u.fault, u.ms, u.before.0, u.before.1, u.after.0, u.after.1, u.safe_ms
        );
        assert_eq!(
            u.fault,
            Some(piezo_fpi::control::Fault::Oscillation),
            "{mode_hz} Hz: {u:?}"
        );
        // From the park at the stroke's foot (0.03 µm), during the move.
        assert!(
            u.ms <= 50.0 && u.before.0 > -0.5 && u.before.1 < 39.9,
            "{mode_hz} Hz: {u:?}"
        );
        c.park().unwrap();
        c.ack(&fpi_protocol::Command::ClearFault).ok();
    }
}

/// Fast waves the loops cannot follow exactly, the forced error they leave
/// not taken for an oscillation: no fault.
///
/// * The damping alone (open loop) under ±10 µm at 200 Hz, which the shaping
///   does not explain: its correction follows the wave's force (±4.8 falling
///   to ±3.6 µm on the stage as built with the shaping off; ±2.2 rising to
///   ±2.9 µm on a stage whose mode moved to 700 Hz, with the shaping on). Before
///   the reference's turns restarted the watch's counts, the first was parked
///   within the wave's first periods.
/// * The closed loop, the shaping off, under the same sine on the stage as
///   built: its tracking error swings ±3.0–3.5 µm at the wave's period (parked
///   18.7 ms into the wave before the watch left such half-cycles out); and
///   under a 100 Hz triangle on the 700 Hz stage, whose corners' half-cycles
///   peak at 1 µm between two of 2.6 and 3.3 µm (parked within 5 ms while the
///   watch let the corners' half-cycles add to no count without breaking it).
#[test]
fn a_fast_wave_s_forced_error_is_not_taken_for_an_oscillation() {
    use fpi_protocol::{Command, LoopMode, Shape};
    let a = tuned();
    let (_e, mut c) = board("fast waves");
    let m700 = built_with_mode(700.0, 0.015, Some(1.05));
    let sine = (Shape::Sine, 10.0, 200.0, 20);
    let triangle = (Shape::Triangle, 15.0, 100.0, 10);
    for (v, mode, shaping, (shape, amplitude, hz, periods)) in [
        (StageVariant::BUILT, LoopMode::Open, false, sine),
        (m700, LoopMode::Open, true, sine),
        (StageVariant::BUILT, LoopMode::Closed, false, sine),
        (m700, LoopMode::Closed, false, triangle),
    ] {
        load(&mut c, &a.model, v);
        c.move_to(20.0, 1000.0).unwrap();
        Follow::new(&mut c, 0).until_hold().unwrap();
        c.ack(&Command::Loop { axis: 0, mode }).unwrap();
        c.shaping(shaping).unwrap();
        let st = c.status().unwrap();
        assert_eq!((st.loop_mode, st.damping), (mode, Some(true)));
        c.wave(shape, amplitude, 20.0, hz, periods).unwrap();
        let ended = Follow::new(&mut c, 0).until_rest("the wave");
        ended.unwrap_or_else(|e| panic!("{v:?}, {mode:?}, shaping {shaping}, {shape:?}: {e:#}"));
        c.park().unwrap();
    }
}

/// A wave at the mode with the damping off (5 µm about 20 µm at 850 Hz:
/// ±83 µm on the undamped mode) and a triangle whose third harmonic meets it
/// are no longer refused command by command: the reference governor keeps
/// what reaches the loops within what the stage can follow in its stroke
/// (`tests/governor.rs` scores it on the true position). Here: they run, are
/// governed, and latch nothing.
#[test]
fn a_wave_the_mode_would_amplify_out_of_the_stroke_is_governed() {
    use fpi_firmware::control::recorder::{signal, status};
    use fpi_protocol::{Command, Shape};
    let a = tuned();
    let (_e, mut c) = board("wave at the mode");
    for (shape, amplitude, hz) in [(Shape::Sine, 5.0, 850.0), (Shape::Triangle, 15.0, 285.0)] {
        load(&mut c, &a.model, StageVariant::BUILT);
        c.move_to(20.0, 1000.0).unwrap();
        Follow::new(&mut c, 0).until_hold().unwrap();
        c.damping(false).unwrap();
        let mut f = Follow::new(&mut c, signal::X_TRUE | signal::STATUS);
        f.record(1).unwrap();
        let t0 = f.c.status().unwrap().tick;
        f.c.wave(shape, amplitude, 20.0, hz, 0).unwrap();
        f.until_tick(t0 + 2000).unwrap();
        f.c.ack(&Command::RecordStop).unwrap();
        f.drain().unwrap();
        let st = f.c.status().unwrap();
        let governed = f
            .rec
            .samples
            .iter()
            .filter(|s| s.status & status::GOVERNED != 0)
            .count();
        let (lo, hi) = f
            .rec
            .samples
            .iter()
            .map(|s| real(s.x_true))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                (l.min(x), h.max(x))
            });
        println!("{shape:?} ±{amplitude} µm at {hz} Hz, damping off: {governed} ticks governed, true {lo:.2}…{hi:.2} µm");
        assert_eq!(st.fault, None, "{shape:?} at {hz} Hz");
        assert!(governed > 0, "{shape:?} at {hz} Hz");
        assert!(lo > -1.0 && hi < 40.92, "{lo}…{hi}");
        c.park().unwrap();
    }
}

/// The stage's RMS motion at rest (µm, true position, less its 5 ms mean)
/// over 0.3 s with the loops closed at 20 µm, and the fault latched meanwhile.
fn motion_at_rest(c: &mut Client) -> (f64, Option<u8>) {
    use fpi_firmware::control::recorder::signal;
    use fpi_protocol::{Command, LoopMode};
    c.move_to(20.0, 1000.0).unwrap();
    Follow::new(c, 0).until_hold().unwrap();
    c.ack(&Command::Loop {
        axis: 0,
        mode: LoopMode::Closed,
    })
    .unwrap();
    let mut f = Follow::new(c, signal::X_TRUE);
    let t0 = f.c.status().unwrap().tick;
    f.until_tick(t0 + 400).unwrap();
    f.record(2).unwrap();
    f.rec.samples.clear();
    f.until_tick(t0 + 400 + 6000).unwrap();
    f.c.ack(&Command::RecordStop).unwrap();
    f.drain().unwrap();
    let fault = f.c.status().unwrap().fault.map(|x| x.code);
    let x: Vec<f64> = f.rec.samples.iter().map(|s| real(s.x_true)).collect();
    let w = 50;
    assert!(x.len() > 10 * w, "{} samples", x.len());
    let d: Vec<f64> = (w..x.len())
        .map(|i| x[i] - x[i - w..i].iter().sum::<f64>() / w as f64)
        .collect();
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    (rms, fault)
}

/// The force sensor's noise, measured through the board at rest; the damping
/// designed for it. At σ 1 N the default damping moved the stage 0.14 µm RMS at
/// rest and the loop watch parked the healthy loop (`fpi board autotune`
/// failed): autotune now lowers the damping until the predicted motion is
/// within [`tune::NOISE_BUDGET_UM`], and the stage's true motion agrees with
/// the prediction. A tuning made for a quieter sensor still trips the watch on
/// it, and autotune's error then names the noise.
#[test]
fn a_force_sensor_s_noise_is_measured_and_the_damping_designed_for_it() {
    use fpi_host::board::noise;
    use fpi_host::method::tune;
    let (_e, mut c) = board("noisy force sensor");
    let fw = fpi_tests::factory_model();
    for (sigma, ok) in [(0.15, 0.12..0.18), (3.0, 2.4..3.6)] {
        load(&mut c, &fw, built_with_force_noise(sigma));
        let n = noise::force_noise(&mut c).unwrap();
        println!("σ {sigma} N: measured {n:.3} N");
        assert!(ok.contains(&n), "σ {sigma}: {n}");
    }
    load(&mut c, &fw, built_with_force_noise(1.0));
    let a = autotune_as_a_user_would(&mut c, &fw).unwrap_or_else(|e| panic!("{e:#}"));
    println!("{}", autotune::table(&a));
    let (asked, used) = a.tuning.damping_target;
    assert!(used < asked && used > 0.0, "{used}");
    let predicted = a.tuning.noise_motion_um_per_n * a.force_noise_n;
    assert!(predicted <= tune::NOISE_BUDGET_UM, "{predicted}");
    load(&mut c, &a.model, built_with_force_noise(1.0));
    let (rms, fault) = motion_at_rest(&mut c);
    println!("σ 1 N, tuned for it: {rms:.4} µm RMS at rest (predicted {predicted:.4})");
    assert_eq!(fault, None);
    assert!((rms / predicted - 1.0).abs() < 0.3, "{rms} {predicted}");
    // Tuned for σ 0.15 N, on σ 1 N: the watch parks it; autotune names the noise.
    let o = TuneOptions {
        force_noise_n: Some(0.15),
        ..TuneOptions::default()
    };
    load(&mut c, &fw, built_with_force_noise(1.0));
    let e = autotune::run(
        &mut c,
        &fw,
        &o,
        &autotune::Settings::default(),
        false,
        |_| {},
    )
    .expect_err("the watch trips on the damping's noise-driven motion");
    let text = format!("{e:#}");
    println!("{text}");
    assert!(
        text.contains("noise at rest") && text.contains("--no-damping"),
        "{text}"
    );
    c.park().unwrap();
}

/// Design options autotune cannot use are refused before it measures
/// anything (the damping target was checked only after the sweep).
#[test]
fn bad_design_options_are_refused_before_the_stage_is_measured() {
    let (_e, mut c) = board("bad design options");
    let fw = fpi_tests::factory_model();
    load(&mut c, &fw, StageVariant::BUILT);
    let run = |c: &mut Client, o: TuneOptions| {
        let mut said = Vec::new();
        let e = autotune::run(c, &fw, &o, &autotune::Settings::default(), false, |m| {
            said.push(m.to_string())
        })
        .unwrap_err();
        (format!("{e:#}"), said)
    };
    for (o, says) in [
        (
            TuneOptions {
                target_damping: 2.0,
                ..TuneOptions::default()
            },
            "--target-damping 2: between 0 and 1",
        ),
        (
            TuneOptions {
                force_noise_n: Some(-1.0),
                ..TuneOptions::default()
            },
            "--force-noise-n -1: a σ in newtons, at least 0",
        ),
        (
            TuneOptions {
                damping_band_hz: (100.0, f64::NAN),
                ..TuneOptions::default()
            },
            "damping_band_hz (100, NaN): the damping's high-pass and leak, each between 0 \
             and the Nyquist frequency (10000 Hz)",
        ),
    ] {
        let (e, said) = run(&mut c, o);
        assert_eq!(e, says);
        assert!(said.is_empty(), "{said:?}");
    }
}

/// A fault latched before autotune's warm-up (the board then refuses its
/// sines) is named with its tick, not left as the refusal alone.
#[test]
fn a_fault_latched_before_the_warm_up_is_named() {
    use fpi_host::board::warm;
    use fpi_protocol::BenchOrder;
    use piezo_fpi::control::Fault;
    let (_e, mut c) = board("fault before the warm-up");
    load(&mut c, &fpi_tests::factory_model(), StageVariant::BUILT);
    c.move_to(20.0, 1000.0).unwrap();
    Follow::new(&mut c, 0).until_hold().unwrap();
    c.bench(BenchOrder::SensorOpen(true)).unwrap();
    while c
        .status()
        .unwrap()
        .fault
        .is_none_or(|f| f.code != Fault::ForceOutOfRange as u8)
    {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    c.bench(BenchOrder::SensorOpen(false)).unwrap();
    let e = format!("{:#}", warm::warm_up(&mut c).unwrap_err());
    println!("{e}");
    assert!(
        e.starts_with("fault 1 (") && e.contains("before the warm-up"),
        "{e}"
    );
    c.park().unwrap();
}

/// The stage as built with the force sensor's noise `sigma_n` (N).
fn built_with_force_noise(sigma_n: f32) -> StageVariant {
    StageVariant {
        force_noise_n: Some(sigma_n),
        ..StageVariant::BUILT
    }
}

/// A step faster than the stage's mass lets the force sensor's window take
/// (25 µm in 0.5 ms asks about 110 N of the stage as built; its window leaves
/// about 40 N about the preload) is no longer refused with the shortest that
/// fits: the governor slows it to the acceleration the force room allows.
/// Shaped and not, in closed loop, and with the damping alone: no fault, the
/// force within its window, the step governed.
#[test]
fn a_step_too_fast_for_the_force_sensor_is_governed() {
    use fpi_firmware::control::recorder::{signal, status};
    use fpi_protocol::{Command, LoopMode};
    let a = tuned();
    let (_e, mut c) = board("step too fast");
    let cases = [
        ("closed, shaped", 30.0, 5.0, Some(true)),
        ("closed, unshaped", 30.0, 5.0, Some(false)),
        ("damping alone, shaped", 10.0, 20.0, None),
    ];
    for (what, from, to, closed_shaping) in cases {
        load(&mut c, &a.model, StageVariant::BUILT);
        c.move_to(from, 1000.0).unwrap();
        Follow::new(&mut c, 0).until_hold().unwrap();
        if let Some(shaping) = closed_shaping {
            c.ack(&Command::Loop {
                axis: 0,
                mode: LoopMode::Closed,
            })
            .unwrap();
            c.shaping(shaping).unwrap();
        }
        let mut f = Follow::new(&mut c, signal::FORCE | signal::STATUS);
        f.record(1).unwrap();
        let t0 = f.c.status().unwrap().tick;
        f.c.step(to, 0.5).unwrap();
        f.until_tick(t0 + 600).unwrap();
        f.c.ack(&Command::RecordStop).unwrap();
        f.drain().unwrap();
        let st = f.c.status().unwrap();
        assert_eq!(st.fault, None, "{what}");
        let governed = f
            .rec
            .samples
            .iter()
            .filter(|s| s.status & status::GOVERNED != 0)
            .count();
        let force = f.rec.samples.iter().map(|s| real(s.force));
        let (lo, hi) = force.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
        println!("{what}: {from} → {to} µm in 0.5 ms: {governed} ticks governed, force {lo:.1}–{hi:.1} N");
        assert!(governed > 0, "{what}");
        c.park().unwrap();
    }
}

#[test]
fn a_stage_that_no_longer_matches_its_model_is_caught_in_open_and_closed_loop() {
    use fpi_protocol::Command;
    use fpi_protocol::LoopMode;
    use piezo_fpi::control::Fault;
    let a = tuned();
    let (_e, mut c) = board("changed stage");
    // Its lever lost 40 % of its gain: the model's estimate runs ahead of the
    // position sensor, and in closed loop the PI asks for more than 150 V.
    let v = StageVariant {
        output_gain: Some(0.6),
        ..StageVariant::BUILT
    };
    for mode in [LoopMode::Open, LoopMode::Closed] {
        load(&mut c, &a.model, v);
        c.move_to(8.0, 1000.0).unwrap();
        Follow::new(&mut c, 0).until_hold().unwrap();
        c.ack(&Command::Loop { axis: 0, mode }).unwrap();
        let u = watched(&mut c, |f| f.c.move_to(35.0, 1000.0).unwrap());
        println!(
            "output gain 0.6, {mode:?} loop, move 8 → 35 µm at 1 mm/s: {:?} after {:.2} ms; \
             true position {:.2}–{:.2} µm until then, {:.2}–{:.2} µm while parking (safe \
             voltage after {:?} ms)",
            u.fault, u.ms, u.before.0, u.before.1, u.after.0, u.after.1, u.safe_ms
        );
        assert!(
            matches!(u.fault, Some(Fault::PositionImplausible | Fault::Saturated)),
            "{u:?}"
        );
        assert!(
            u.ms <= 30.0 && u.before.0 > 0.0 && u.before.1 < 39.9,
            "{u:?}"
        );
        assert!(
            u.after.0 > -1.0 && u.after.1 < 39.9,
            "parks without ringing: {u:?}"
        );
        c.park().unwrap();
        c.ack(&Command::ClearFault).ok();
    }
}

/// What the oscillation watch makes of references the loops cannot follow
/// (printed; run with `--ignored --nocapture`): on the stage as built and four variants, with the
/// shaping on and off, the loops closed, ±1 µm sines at 100–1100 Hz about
/// 20 µm, a 10 → 20 µm step and the 100 Hz triangle over 5–35 µm; the faults
/// latched. Asserts only that the shaping on latches none.
#[test]
#[ignore = "a survey of 90 runs (about a minute in-process): run by hand"]
fn the_watch_on_references_the_loops_cannot_follow() {
    use fpi_protocol::{Command, LoopMode, Shape};
    let a = tuned();
    let (_e, mut c) = board("watch survey");
    let stage = |mode_hz, zeta, gain| built_with_mode(mode_hz, zeta, Some(gain));
    let stages = [
        ("as built", StageVariant::BUILT),
        ("700 Hz, ζ 0.015", stage(700.0, 0.015, 0.97)),
        ("700 Hz, ζ 0.05", stage(700.0, 0.05, 1.03)),
        ("1000 Hz, ζ 0.015", stage(1000.0, 0.015, 1.03)),
        ("1000 Hz, ζ 0.05", stage(1000.0, 0.05, 0.97)),
    ];
    let sines = [100.0, 200.0, 300.0, 430.0, 600.0, 800.0, 1100.0];
    let mut runs = 0;
    println!("| shaping | stage | faults latched |\n|---|---|---|");
    for shaping in [true, false] {
        for (name, v) in stages {
            let mut tripped = Vec::new();
            for what in (0..sines.len() + 2).map(Some) {
                load(&mut c, &a.model, v);
                let mut f = Follow::new(&mut c, 0);
                f.rest_at(20.0, "the move to 20 µm").unwrap();
                f.c.ack(&Command::Loop {
                    axis: 0,
                    mode: LoopMode::Closed,
                })
                .unwrap();
                f.c.shaping(shaping).unwrap();
                let started = f.c.status().unwrap().tick;
                let label = match what {
                    Some(k) if k < sines.len() => {
                        let hz = sines[k];
                        f.c.wave(Shape::Sine, 1.0, 20.0, hz, (hz * 0.03).ceil() as u32)
                            .unwrap();
                        format!("{hz} Hz sine")
                    }
                    Some(k) if k == sines.len() => {
                        f.c.step(10.0, 1.5).unwrap();
                        f.until_tick(started + f.ticks(0.03)).unwrap();
                        f.c.step(20.0, 1.5).unwrap();
                        "step".into()
                    }
                    _ => {
                        f.c.wave(Shape::Triangle, 15.0, 20.0, 100.0, 5).unwrap();
                        "100 Hz triangle".into()
                    }
                };
                f.until_tick(started + f.ticks(0.08)).unwrap();
                runs += 1;
                if let Some(x) = f.c.status().unwrap().fault.filter(|x| x.at >= started) {
                    let fault = piezo_fpi::control::Fault::from_code(x.code)
                        .map_or_else(|| format!("code {}", x.code), |f| format!("{f:?}"));
                    let ms = (x.at - started) as f64 / 20.0;
                    tripped.push(format!("{label}: {fault} at {ms:.2} ms"));
                }
                c.park().unwrap();
                c.ack(&Command::ClearFault).ok();
            }
            let seen = if tripped.is_empty() {
                "none".to_string()
            } else {
                tripped.join("; ")
            };
            println!(
                "| {} | {name} | {seen} |",
                if shaping { "on" } else { "off" }
            );
            assert!(!shaping || tripped.is_empty(), "{name}: {seen}");
        }
    }
    println!("{runs} runs");
}

/// The learned mass ratio under steps faster and slower than autotune's
/// (printed; run with `--ignored --nocapture`): the tuned model loaded afresh on the stage as
/// built, then eight 10 ↔ 20 µm steps of 1.0 ms, and again of 2.0 ms; each
/// step's settling, overshoot and the `β` it left. The fit's ratio depends on
/// the step's speed and `α_b` was measured on 1.5 ms steps, so the board
/// learns from steps that long or longer only (book, `docs/src/mass-ratio.md`,
/// *The learned mass ratio*). Asserts only that every step settles.
#[test]
#[ignore = "a survey of 16 steps (about half a minute in-process): run by hand"]
fn the_mass_ratio_under_steps_of_another_speed() {
    let a = tuned();
    let (_e, mut c) = board("mass ratio survey");
    println!(
        "| step | duration | settles ±0.1 µm | overshoot | β after it |\n|---|---|---|---|---|"
    );
    for duration_ms in [1.0, 2.0] {
        load(&mut c, &a.model, StageVariant::BUILT);
        autotune::verify(&mut c).unwrap();
        for k in 0..8 {
            let (from_um, to_um) = if k % 2 == 0 {
                (10.0, 20.0)
            } else {
                (20.0, 10.0)
            };
            let s = StepSettings {
                from_um,
                to_um,
                duration_ms,
                ..StepSettings::default()
            };
            let (_, fig) = step::run(&mut c, &s).unwrap();
            let beta = lead_ratio(&mut c).map(|(b, _)| b);
            let settle = fig.settle_ms.expect("settled within the record");
            println!(
                "| {from_um} → {to_um} µm | {duration_ms} ms | {settle:.2} ms | {:.3} µm | {} |",
                fig.overshoot_um,
                beta.map_or("—".into(), |b| format!("{b:.3}"))
            );
        }
        c.park().unwrap();
    }
}

/// The first step after a tuning is loaded onto a stage whose mode fell 18 %,
/// over fresh autotunes (printed; run with `--ignored --nocapture`;
/// `SURVEY_BOARDS` boards, 4 by default): each
/// board autotunes the stage as built afresh (its own measurement, its own
/// noise), then the tuning is loaded onto the 700 Hz, ζ 0.015, gain 0.97
/// variant and stepped 10 → 20 µm three times (autotune's verification, then
/// two more) while the board learns the variant's mass — loaded plainly (the
/// mass ratio starts at 1), then again with the mass matched (`fpi board load
/// --match-mass`). The spread of that first step is what issue 19's
/// robustness target (6 ms) hinges on; this is the survey to judge a change
/// by (book, `docs/src/mass-ratio.md`, *Why the first step on a heavier stage
/// misses*). Asserts only that every step settles.
#[test]
#[ignore = "a survey of several autotunes (about 30 s each in-process): run by hand"]
fn the_first_step_on_a_heavier_stage_over_fresh_autotunes() {
    let boards: usize = std::env::var("SURVEY_BOARDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(4)
        .max(1);
    let fw = fpi_tests::factory_model();
    let heavier = built_with_mode(700.0, 0.015, Some(0.97));
    println!(
        "| board | as built: autotune's step | load | 700 Hz: settles ±0.1 µm, steps 1–3 | overshoot | β after |\n|---|---|---|---|---|---|"
    );
    let list = |v: Vec<f64>, unit: &str| {
        v.iter()
            .map(|x| format!("{x:.2}"))
            .collect::<Vec<_>>()
            .join(", ")
            + unit
    };
    let mut firsts = [Vec::new(), Vec::new()];
    for b in 0..boards {
        let (_e, mut c) = board("first step survey");
        load(&mut c, &fw, StageVariant::BUILT);
        let a = autotune_as_a_user_would(&mut c, &fw).unwrap_or_else(|e| panic!("{e:#}"));
        for (matched, firsts) in [false, true].into_iter().zip(&mut firsts) {
            load(&mut c, &a.model, heavier);
            if matched {
                mass::match_mass(&mut c, &a.model).unwrap_or_else(|e| panic!("{e:#}"));
            }
            let figs = three_steps(&mut c, "700 Hz variant");
            let settle: Vec<f64> = figs
                .iter()
                .map(|f| f.settle_ms.expect("settled within the record"))
                .collect();
            firsts.push(settle[0]);
            let (beta, _) = lead_ratio(&mut c).unwrap();
            println!(
                "| {b} | {} | {} | {} | {} | {beta:.3} |",
                a.step
                    .settle_ms
                    .map_or("—".into(), |v| format!("{v:.2} ms")),
                if matched { "--match-mass" } else { "plain" },
                list(settle, " ms"),
                list(figs.iter().map(|f| f.overshoot_um).collect(), " µm"),
            );
        }
        c.park().unwrap();
    }
    for (how, mut f) in ["plain", "--match-mass"].into_iter().zip(firsts) {
        f.sort_by(f64::total_cmp);
        println!(
            "first step on the 700 Hz variant, loaded {how}: {:.2}–{:.2} ms over {boards} \
             autotunes (target 6 ms)",
            f[0],
            f[f.len() - 1]
        );
    }
}
