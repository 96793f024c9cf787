//! The branch-polynomial hysteresis model (`--kind branch`, the second paper's
//! eqs. 6–7): continuous at every reversal (and why the transcribed Table 3 is
//! not), closure and wiping-out of minor loops, its fit on the rig recordings
//! (figures with a margin), its coupled prediction, its model file (round trip,
//! bad files refused by key) and the firmware export refusing it.

use std::path::PathBuf;

use fpi_host::data::{self, fem::FemMaps};
use fpi_host::method::calibrate::{self, CalibData, Options};
use fpi_host::method::export::{self, LoopSettings};
use fpi_host::method::kinds::branch::{BranchModel, BranchState};
use fpi_host::method::model::{BranchSection, HostModel, Kind, Memory};
use fpi_host::method::predict;

// ---------------------------------------------------------------------------
// The paper's equations as transcribed (seed 001, Table 3).

const P_UP: [f64; 4] = [42.36e-6, 3.65e-3, -53e-3, 0.137];
const B_UP: [f64; 3] = [-23.55e-3, 2.41, 1.72];
const P_DN: [f64; 5] = [1.7e-6, 4.54e-4, 2.51e-2, 0.438, 124.94];
const B_DN: [f64; 3] = [-17.67e-3, 2.1, 0.53];

/// Eq. 6.
fn hist_up(v: f64, v_min: f64) -> f64 {
    let d = v - v_min;
    P_UP[0] * d.powi(3)
        + P_UP[1] * d * d
        + P_UP[2] * d
        + P_UP[3]
        + B_UP[0] * v_min * v_min
        + B_UP[1] * v_min
        + B_UP[2]
}

/// Eq. 7, with the sign of the `B_dn1` term as printed (`sign` = −1) or read as
/// `+` (`sign` = +1).
fn hist_dn(v: f64, v_max: f64, sign: f64) -> f64 {
    let d = v - v_max;
    P_DN[0] * d.powi(4)
        + P_DN[1] * d.powi(3)
        + P_DN[2] * d * d
        + P_DN[3] * d
        + P_DN[4]
        + sign * B_DN[0] * v_max * v_max
        + B_DN[1] * v_max
        + B_DN[2]
}

#[test]
fn the_transcribed_table_3_is_continuous_on_its_major_loop_only() {
    // As printed: the descending branch starts hundreds of units above the
    // ascending one's end, wherever it turns.
    for v_max in [60.0, 100.0, 120.0] {
        let jump = hist_dn(v_max, v_max, -1.0) - hist_up(v_max, 0.0);
        assert!(jump > 290.0, "v_max {v_max}: jump {jump}");
    }
    // Read with `+ B_dn1·v_max²`: the branches meet at the paper's 0–120 V
    // major loop (within 2 of a 120 span), at the top and at the bottom…
    let top = hist_dn(120.0, 120.0, 1.0) - hist_up(120.0, 0.0);
    let bottom = hist_dn(0.0, 120.0, 1.0) - hist_up(0.0, 0.0);
    assert!(top.abs() < 2.0 && bottom.abs() < 2.0, "{top} {bottom}");
    // …but not at any other turning point: the B terms fit the major loop's
    // turning points, they do not keep the output continuous.
    let at_100 = hist_dn(100.0, 100.0, 1.0) - hist_up(100.0, 0.0);
    assert!(at_100 > 80.0, "{at_100}");
    let ascent_from_60 = hist_up(60.0, 60.0) - hist_dn(60.0, 120.0, 1.0);
    assert!(ascent_from_60 < -45.0, "{ascent_from_60}");
}

// ---------------------------------------------------------------------------
// Continuity, closure and wiping-out of our reading.

/// A branch model shaped like the one fitted on the rig (µm/V^k).
fn model(memory: Memory) -> BranchModel {
    BranchModel {
        k_f: 0.106,
        rest_um: 0.0,
        section: BranchSection {
            input_max_v: 150.0,
            memory,
            ascending_um_per_vk: vec![0.0648, 4.02e-4, -1.76e-6],
            descending_um_per_vk: vec![0.0, -9.95e-4, -1.089e-5, -5.1e-8],
        },
    }
}

/// A drive with many turning points: ramps between pseudo-random targets in
/// 0–100 V (nested and crossing minor loops) with a little jitter, steps of
/// 0.05–0.5 V.
fn drive() -> Vec<f64> {
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut v = vec![0.0];
    for _ in 0..300 {
        let target = 100.0 * rnd();
        let step = 0.05 + 0.45 * rnd();
        let mut x: f64 = *v.last().unwrap();
        while (target - x).abs() > step {
            x += step * (target - x).signum();
            v.push((x + 0.02 * (rnd() - 0.5)).clamp(0.0, 100.0));
        }
    }
    v
}

#[test]
fn the_output_is_continuous_at_every_reversal() {
    let eps = 1e-7;
    for memory in [Memory::Stack, Memory::Last] {
        let b = model(memory);
        let mut st = b.state();
        let (mut worst, mut turns) = (0.0f64, 0);
        let (mut prev, mut dir) = (0.0, 0.0);
        for &v in &drive() {
            let y = b.advance(&mut st, v);
            // Both one-sided limits at this sample: one continues the branch, the
            // other starts a new one at this very point.
            for side in [v - eps, v + eps] {
                let (ys, _) = b.peek(&st, side.max(0.0));
                worst = worst.max((ys - y).abs());
            }
            let d = (v - prev).signum();
            if v != prev && d != dir {
                turns += 1;
                dir = d;
            }
            prev = v;
        }
        // Slopes are below 0.3 µm/V: a step of 1e-7 V moves the output < 3e-8 µm.
        assert!(worst < 1e-7, "{memory:?}: jump {worst} µm at a reversal");
        assert!(turns > 100);
    }
}

#[test]
fn small_steps_never_jump_the_output() {
    // A fine drive through nested loops and their wiping-out: no step of 1 mV
    // moves the output by more than the steepest slope allows.
    let b = model(Memory::Stack);
    let mut st = b.state();
    let mut pts = vec![0.0];
    for target in [90.0, 30.0, 70.0, 40.0, 60.0, 50.0, 80.0, 20.0, 95.0, 0.0] {
        let from: f64 = *pts.last().unwrap();
        let n = ((target - from).abs() / 1e-3).round() as usize;
        pts.extend((1..=n).map(|i| from + (target - from) * i as f64 / n as f64));
    }
    let mut last = b.advance(&mut st, 0.0);
    for &v in &pts[1..] {
        let y = b.advance(&mut st, v);
        assert!(
            (y - last).abs() < 1e-3 * 0.3,
            "jump {} µm at {v} V",
            y - last
        );
        last = y;
    }
}

/// The outputs of `b` along `turning` points (straight ramps of 0.01 V between
/// them), at each turning point.
fn at_turns(b: &BranchModel, turning: &[f64]) -> (Vec<f64>, BranchState<f64>) {
    let mut st = b.state();
    let mut from = 0.0;
    let mut out = Vec::new();
    for &to in turning {
        let n = ((to - from) / 0.01).abs().round().max(1.0) as usize;
        let mut y = 0.0;
        for i in 1..=n {
            y = b.advance(&mut st, from + (to - from) * i as f64 / n as f64);
        }
        out.push(y);
        from = to;
    }
    (out, st)
}

#[test]
fn stack_memory_closes_minor_loops_and_wipes_them_out() {
    let b = model(Memory::Stack);
    // 0 → 80 → 30 → 60 → 30: the minor loop closes on its starting point.
    let (y, st) = at_turns(&b, &[80.0, 30.0, 60.0, 30.0]);
    assert!((y[3] - y[1]).abs() < 1e-12, "{} vs {}", y[3], y[1]);
    assert_eq!(
        st.depth(),
        4,
        "rest, 80, 30, 60: at 30 V the loop is closed, not yet passed"
    );
    // Below 30 V the loop is wiped out: the model is back on the descent from
    // 80 V, as if the loop had not happened.
    let (y, st) = at_turns(&b, &[80.0, 30.0, 60.0, 20.0]);
    let (plain, _) = at_turns(&b, &[80.0, 20.0]);
    assert_eq!(st.depth(), 2, "rest and 80 V");
    assert!((y[3] - plain[1]).abs() < 1e-12, "{} vs {}", y[3], plain[1]);
    // Past 80 V the model is back on the first ascent, as if the loops had not
    // happened (wiping-out).
    let (a, _) = at_turns(&b, &[80.0, 30.0, 60.0, 45.0, 70.0, 90.0]);
    let (plain, _) = at_turns(&b, &[90.0]);
    assert!((a[5] - plain[0]).abs() < 1e-12, "{} vs {}", a[5], plain[0]);
    // Every descent to 0 V closes the major loop on the rest state.
    let (c, _) = at_turns(&b, &[100.0, 0.0, 70.0, 0.0]);
    assert!(c[1].abs() < 1e-12 && c[3].abs() < 1e-12, "{c:?}");
    // The paper's last-point memory does not close the same loop.
    let (l, _) = at_turns(&model(Memory::Last), &[80.0, 30.0, 60.0, 30.0]);
    assert!((l[3] - l[1]).abs() > 0.05, "{} vs {}", l[3], l[1]);
}

#[test]
fn the_slope_peek_returns_is_the_branch_slope() {
    let b = model(Memory::Stack);
    let (_, st) = at_turns(&b, &[80.0, 30.0, 60.0]);
    for v in [45.0, 55.0, 70.0, 90.0] {
        let h = 1e-6;
        let fd = (b.peek(&st, v + h).0 - b.peek(&st, v - h).0) / (2.0 * h);
        let (_, slope) = b.peek(&st, v);
        assert!((fd - slope).abs() < 1e-7, "{v} V: {fd} vs {slope}");
    }
}

// ---------------------------------------------------------------------------
// Fit on the rig, prediction of stage A.

/// Four rig recordings: two minor-loop runs, the multisine and a sine.
fn rig() -> Vec<CalibData> {
    let names = [
        "preload_050N_minor_05Hz.csv.gz",
        "preload_125N_minor_05Hz.csv.gz",
        "preload_075N_multisine.csv.gz",
        "preload_100N_sine_05Hz.csv.gz",
    ];
    let paths: Vec<PathBuf> = data::datasets_in("pea-rig")
        .into_iter()
        .filter(|p| names.iter().any(|n| p.ends_with(n)))
        .collect();
    assert_eq!(paths.len(), 4, "{paths:?}");
    calibrate::load(&paths, None).unwrap()
}

fn branch_options(memory: Memory) -> Options {
    Options {
        branch_memory: memory,
        ..Options::for_kind(Kind::Branch)
    }
}

fn fitted() -> &'static HostModel {
    static M: std::sync::OnceLock<HostModel> = std::sync::OnceLock::new();
    M.get_or_init(|| calibrate::calibrate(&rig(), &branch_options(Memory::Stack)).unwrap())
}

#[test]
fn the_fit_on_the_rig_is_good_and_beats_the_last_point_memory() {
    let data = rig();
    let stack = fitted();
    let last = calibrate::calibrate(&data, &branch_options(Memory::Last)).unwrap();
    let fpi = calibrate::calibrate(&data, &Options::for_kind(Kind::Fpi)).unwrap();
    let c = &stack.calibration;
    println!(
        "branch (stack) RMSE {:.4} µm, k_f {:.4} V/N; branch (last) {:.4} µm; fpi {:.4} µm",
        c.rmse_um, stack.coupling.k_f_v_per_n, last.calibration.rmse_um, fpi.calibration.rmse_um
    );
    for f in &c.per_file {
        println!("  {} {:.4} µm", f.file, f.rmse_um);
    }
    // Measured: 0.0405 µm over the four recordings (k_f 0.1034 V/N); the
    // paper's last-point memory 0.183 µm, fpi 0.048 µm.
    assert!(c.rmse_um < 0.06, "{}", c.rmse_um);
    assert!((0.09..0.12).contains(&stack.coupling.k_f_v_per_n));
    assert!(c.rmse_um < 0.5 * last.calibration.rmse_um);
    assert!(c.rmse_um < fpi.calibration.rmse_um);
    // The figures the calibration stores are the model's own output error.
    let again = calibrate::score(stack, &data);
    assert_eq!(again, c.per_file);
}

#[test]
fn the_coupled_prediction_solves_the_coupled_equation() {
    let m = fitted();
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let run = data::read_stage(&data::dataset("stage-a/sine_15Hz.csv")).unwrap();
    let p = predict::predict(m, &fem, &run.t, &run.u).unwrap();
    // Re-run the model with the preload the solution implies: it gives back the
    // solution at every sample.
    let b = BranchModel::of(m).unwrap();
    let mut st = b.state();
    let mut worst = 0.0f64;
    for k in 0..run.u.len() {
        let x = b.step(&mut st, run.u[k], fem.preload_at(p.x_pea[k]));
        worst = worst.max((x - p.x_pea[k]).abs());
    }
    assert!(worst < 1e-9, "{worst} µm");
    assert!(p.iterations < 5 * run.u.len(), "{}", p.iterations);
    let rmse = predict::metrics(&p.x_fhps, &run.x).rmse;
    println!("stage A, 15 Hz sine: RMSE {rmse:.3} µm");
    // Measured 1.3–1.5 µm: as the paper's FPI, limited by the linear coupling.
    assert!(rmse < 2.0, "{rmse}");
}

// ---------------------------------------------------------------------------
// The model file.

fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join(format!("fpi-branch-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn model_files_round_trip() {
    let m = fitted();
    let p = scratch().join("branch.toml");
    m.write(&p).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(
        text.contains("[branch]") && !text.contains("[pi]"),
        "{text}"
    );
    assert!(text.contains("memory = \"stack\""), "{text}");
    assert_eq!(&HostModel::read(&p).unwrap(), m);
    // The memory defaults to the stack.
    let plain = text.replace("memory = \"stack\"\n", "");
    assert_eq!(&HostModel::parse(&plain, "m.toml").unwrap(), m);
}

#[test]
fn bad_model_files_name_the_key() {
    let text = toml::to_string(fitted()).unwrap();
    let first_up = {
        let s = fitted().branch.as_ref().unwrap();
        format!("ascending_um_per_vk = [{:?}", s.ascending_um_per_vk[0])
    };
    assert!(text.contains(&first_up), "{text}");
    let k_f = format!("k_f_v_per_n = {:?}", fitted().coupling.k_f_v_per_n);
    let cases: Vec<(String, &str)> = vec![
        (
            text.replace("input_max_v = 150.0", "input_max_v = -1.0"),
            "branch.input_max_v = -1",
        ),
        (
            text.replace(&first_up, "ascending_um_per_vk = [nan"),
            "branch.ascending_um_per_vk[0] = NaN",
        ),
        (
            text.replace("memory = \"stack\"", "memory = \"lifo\""),
            "memory",
        ),
        (
            text.replace("k_q_v_per_n2 = 0.0", "k_q_v_per_n2 = 0.001"),
            "coupling.k_q_v_per_n2 = 0.001",
        ),
        (
            text.replace(&k_f, "k_f_v_per_n = -0.1"),
            "coupling.k_f_v_per_n = -0.1",
        ),
        (text.replace("[branch]", "[branchy]"), "branch"),
        (
            text.replace("kind = \"branch\"", "kind = \"fpi\""),
            "branch: a fpi model has no [branch] section",
        ),
        (
            text.clone()
                + "\n[pi]\nw0_um_per_v = 0.1\nthresholds_v = []\nweights_um_per_v = []\ninput_max_v = 100.0\n",
            "pi: a branch model has no PI part",
        ),
        (
            text.replace("descending_um_per_vk = [", "descending_um_per_vk = [1,1,1,1,1,1,"),
            "branch.descending_um_per_vk has 10 coefficients",
        ),
    ];
    for (bad, want) in cases {
        let e = format!("{:#}", HostModel::parse(&bad, "m.toml").unwrap_err());
        assert!(
            e.contains("m.toml") && e.contains(want),
            "{want:?} not in: {e}"
        );
    }
}

#[test]
fn the_firmware_export_refuses_a_branch_model() {
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let s = LoopSettings {
        rate_hz: 20_000,
        u_max: 100.0,
        slew_v_per_ms: 10.0,
        stroke_voltage: 100.0,
        force_tolerance: 15.0,
    };
    let Err(e) = export::export(fitted(), std::path::Path::new("branch.toml"), &fem, &s) else {
        panic!("a branch model was exported");
    };
    assert!(
        format!("{e:#}").contains("a branch model cannot run in the firmware"),
        "{e:#}"
    );
}

// ---------------------------------------------------------------------------
// The book's figures (`docs/src/measured-figures.md`; slow in a debug build: run with
// `cargo test --release -p fpi-tests --test branch -- --ignored --nocapture`).

#[test]
#[ignore = "measurement: every rig recording, both memories, several degrees"]
fn figures_on_every_rig_recording() {
    let data = calibrate::load(&data::datasets_in("pea-rig"), None).unwrap();
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let runs: Vec<_> = ["sine_05Hz", "sine_15Hz"]
        .iter()
        .map(|n| data::read_stage(&data::dataset(&format!("stage-a/{n}.csv"))).unwrap())
        .collect();
    for (memory, degrees) in [
        (Memory::Stack, (3, 4)),
        (Memory::Last, (3, 4)),
        (Memory::Stack, (5, 5)),
        (Memory::Stack, (6, 6)),
    ] {
        let opt = Options {
            branch_degrees: degrees,
            ..branch_options(memory)
        };
        let m = calibrate::calibrate(&data, &opt).unwrap();
        let minor: Vec<String> = m
            .calibration
            .per_file
            .iter()
            .filter(|f| f.file.contains("minor") || f.file.contains("multisine"))
            .map(|f| format!("{} {:.4}", f.file, f.rmse_um))
            .collect();
        let stage: Vec<String> = runs
            .iter()
            .map(|r| {
                let p = predict::predict(&m, &fem, &r.t, &r.u).unwrap();
                format!("{:.3}", predict::metrics(&p.x_fhps, &r.x).rmse)
            })
            .collect();
        println!(
            "{memory:?} degrees {degrees:?}: rig RMSE {:.4} µm (k_f {:.4} V/N; {}); stage A \
             5/15 Hz RMSE {} µm",
            m.calibration.rmse_um,
            m.coupling.k_f_v_per_n,
            minor.join(", "),
            stage.join(" / ")
        );
    }
}
