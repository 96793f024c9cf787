//! `fpi refine`: a model's stage FEM tables corrected from one measured run, the
//! refined model taken wherever a model is (predict, invert, export, compare, the
//! board's load), scored on runs it was not refined on, and bad runs refused by
//! name.

use std::path::{Path, PathBuf};

mod common;
use common::{fails, ok, s, scratch};

const FEM: &str = "data/stage-a/fem.csv.gz";
const FIT: &str = "data/stage-a/sine_05Hz.csv.gz";
const HELD_OUT: [&str; 2] = [
    "data/stage-a/sine_15Hz.csv.gz",
    "data/stage-a/chirp_large_080V.csv.gz",
];

fn tmp() -> PathBuf {
    scratch("refine")
}

/// A quick fpi model on three rig recordings and its refinement on [`FIT`],
/// made once and shared by the tests (which run in parallel): (model, refined,
/// the refine command's output).
fn models() -> &'static (PathBuf, PathBuf, String) {
    static M: std::sync::OnceLock<(PathBuf, PathBuf, String)> = std::sync::OnceLock::new();
    M.get_or_init(|| {
        let d = tmp();
        let (m, _) = common::quick_fpi(&d);
        let r = d.join("fpi-refined.toml");
        let text = ok(&[
            "refine",
            "--model",
            s(&m),
            "--fem",
            FEM,
            "--run",
            FIT,
            "--out",
            s(&r),
        ]);
        (m, r, text)
    })
}

/// The number after `key` on the line of `text` that starts with it.
fn number_after(text: &str, key: &str) -> f64 {
    text.lines()
        .find_map(|l| l.trim_start().strip_prefix(key))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no number after {key} in {text}"))
}

#[test]
fn refine_prints_the_correction_and_the_fit_before_and_after() {
    let (_, refined, text) = models();
    println!("{text}");
    for key in ["stage_gain", "stage_offset_um", "preload_scale"] {
        let v = number_after(text, key);
        assert!(v.is_finite(), "{key} {v}");
    }
    assert!(
        (number_after(text, "preload_scale") - 0.97).abs() < 0.03,
        "{text}"
    );
    assert!(
        text.contains("RMSE before") && text.contains("RMSE after"),
        "{text}"
    );
    // The fit on its run: before and after (the row of the run).
    let row = text.lines().find(|l| l.contains("sine_05Hz.csv")).unwrap();
    let v: Vec<f64> = row
        .split_whitespace()
        .skip(2)
        .take(4)
        .map(|x| x.parse().unwrap())
        .collect();
    assert!(v[1] < v[0] && v[3] < v[2], "{row}");
    let file = std::fs::read_to_string(refined).unwrap();
    assert!(file.contains("[fem_correction]"), "{file}");
    assert!(
        file.contains("refined_on = [\"data/stage-a/sine_05Hz.csv.gz\"]"),
        "{file}"
    );
    assert!(file.contains("fem = \"data/stage-a/fem.csv.gz\""), "{file}");
}

/// The `x_fhps_um` column of a prediction file.
fn predicted_output(path: &Path) -> Vec<f64> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.rsplit(',').next().unwrap().parse().unwrap())
        .collect()
}

#[test]
fn the_refined_model_is_taken_by_predict_invert_export_and_the_board() {
    let (model, refined, _) = models();
    let d = tmp();
    let (p0, p1) = (d.join("pred-fem.csv"), d.join("pred-refined.csv"));
    for (m, out) in [(model, &p0), (refined, &p1)] {
        ok(&[
            "predict",
            "--model",
            s(m),
            "--fem",
            FEM,
            "--drive",
            HELD_OUT[0],
            "--out",
            s(out),
        ]);
    }
    // The correction acts: the predicted output differs by about its gain and offset.
    let (a, b) = (predicted_output(&p0), predicted_output(&p1));
    let worst = a
        .iter()
        .zip(&b)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst > 0.05, "{worst}");

    let target = d.join("target.csv");
    std::fs::write(
        &target,
        "t_s,x_fhps_um\n0,2\n0.001,10\n0.002,20\n0.003,30\n",
    )
    .unwrap();
    ok(&[
        "invert",
        "--model",
        s(refined),
        "--fem",
        FEM,
        "--target",
        s(&target),
        "--out",
        s(&d.join("drive.csv")),
    ]);

    let (e0, e1) = (d.join("fw-fem.toml"), d.join("fw-refined.toml"));
    for (m, out) in [(model, &e0), (refined, &e1)] {
        ok(&["export", "--model", s(m), "--fem", FEM, "--out", s(out)]);
    }
    let (f0, f1) = (
        std::fs::read_to_string(&e0).unwrap(),
        std::fs::read_to_string(&e1).unwrap(),
    );
    assert!(f1.contains("FEM tables corrected (fpi refine"), "{f1}");
    let tables = |t: &str| t[t.find("[tables").unwrap()..].to_string();
    assert_ne!(
        tables(&f0),
        tables(&f1),
        "the exported tables are the corrected ones"
    );

    // The board's load builds its image the same way (no board needed for that).
    let o = fpi_host::method::export::ExportOptions {
        rate_hz: 20_000,
        u_max: 150.0,
        slew: 100.0,
        stroke_voltage: None,
    };
    let fem = Path::new(env!("CARGO_MANIFEST_DIR")).join(FEM);
    let image = |m: &Path| fpi_host::cli::board::model_image(m, Some(&fem), &o).unwrap();
    assert_ne!(image(model), image(refined));
    // And a board takes it (the in-process board: the firmware built for the host).
    let text = ok(&[
        "board",
        "--port",
        "virtual",
        "load",
        s(refined),
        "--fem",
        FEM,
    ]);
    assert!(text.contains("running since tick"), "{text}");
}

#[test]
fn compare_shows_both_and_the_held_out_runs_are_not_worse() {
    let (model, refined, _) = models();
    let out = tmp().join("compare");
    let text = ok(&[
        "compare",
        "--fem",
        FEM,
        "--runs",
        FIT,
        HELD_OUT[0],
        HELD_OUT[1],
        "--model",
        s(model),
        "--model",
        s(refined),
        "--out",
        s(&out),
    ]);
    println!("{text}");
    assert!(text.contains("fpi-refined"), "{text}");
    // The run it was refined on is marked, and only that one.
    assert_eq!(
        text.matches("(refined on this run: in-sample)").count(),
        1,
        "{text}"
    );
    let fit = text
        .lines()
        .skip_while(|l| !l.starts_with("sine_05Hz"))
        .nth(3)
        .unwrap();
    assert!(
        fit.contains("fpi-refined") && fit.contains("in-sample"),
        "{fit}"
    );
    // Each held-out run: RMSE of the FEM-only model, then of the refined one.
    let held = &text[text.find("held-out runs").expect("a held-out summary")..];
    assert!(
        held.contains("sine_15Hz.csv") && held.contains("chirp_large_080V.csv"),
        "{held}"
    );
    for run in ["sine_15Hz.csv:", "chirp_large_080V.csv:"] {
        let block: Vec<&str> = text.lines().skip_while(|l| *l != run).take(4).collect();
        let rmse = |l: &str| l.split_whitespace().nth(3).unwrap().parse::<f64>().unwrap();
        let (fem_only, refined) = (rmse(block[2]), rmse(block[3]));
        println!("{run} held-out RMSE: FEM as it is {fem_only:.3} µm, refined {refined:.3} µm");
        assert!(refined <= fem_only, "{block:?}");
    }
    // The report says the same: the in-sample cell marked, the held-out summary.
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert_eq!(
        report.matches("(refined on this run: in-sample)").count(),
        1
    );
    let summary = &report[report.find("## Held-out runs").expect("held-out section")..];
    assert!(summary.contains("sine_15Hz.csv") && summary.contains("FEM refined: gain"));
}

/// A stage run of 50 samples: a voltage ramp (2 V a sample), the output rising
/// 0.6 µm a sample, the force reading `force_n` throughout.
fn ramp_at_force(force_n: f64) -> String {
    let rows: String = (0..50)
        .map(|k| {
            let k = k as f64;
            format!("{},{},{force_n},{}\n", k * 1e-3, 2.0 * k, 0.6 * k)
        })
        .collect();
    format!("t_s,voltage_V,force_N,x_fhps_um\n{rows}")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_runs_are_refused_naming_the_file_and_nothing_is_written() {
    let (model, _, _) = models();
    let d = tmp();
    let out = d.join("never.toml");
    let refine = |run: &Path| {
        fails(&[
            "refine",
            "--model",
            s(model),
            "--fem",
            FEM,
            "--run",
            s(run),
            "--out",
            s(&out),
        ])
    };
    let mut rows = String::new();
    for k in 0..50 {
        let t = k as f64 * 1e-3;
        rows += &format!("{t},{},{}\n", 2.0 * k as f64, 0.6 * k as f64);
    }
    // No force column.
    let run = write(
        &d,
        "noforce.csv",
        &format!("t_s,voltage_V,x_fhps_um\n{rows}"),
    );
    let e = refine(&run);
    assert!(e.contains("noforce.csv") && e.contains("force_N"), "{e}");
    // A row shorter than the header (columns of different lengths).
    let run = write(
        &d,
        "short.csv",
        "t_s,voltage_V,force_N,x_fhps_um\n0,0,61.8,0\n0.001,10,62\n0.002,20,62.5,1.2\n",
    );
    let e = refine(&run);
    assert!(e.contains("short.csv:3"), "{e}");
    // A force column of zeros (no sensor).
    let run = write(&d, "zeros.csv", &ramp_at_force(0.0));
    let e = refine(&run);
    assert!(e.contains("zeros.csv: column force_N is zero"), "{e}");
    // A force in kN: a preload scale no stage has.
    let run = write(&d, "kn.csv", &ramp_at_force(0.0618));
    let e = refine(&run);
    assert!(e.contains("kn.csv") && e.contains("preload scale"), "{e}");
    assert!(!out.exists());
    // The output may not be a run.
    let e = fails(&[
        "refine",
        "--model",
        s(model),
        "--fem",
        FEM,
        "--run",
        FIT,
        "--out",
        FIT,
    ]);
    assert!(e.contains("--out"), "{e}");
}

#[test]
fn a_bad_correction_in_a_model_file_names_its_key() {
    let (_, refined, _) = models();
    let d = tmp();
    let text = std::fs::read_to_string(refined).unwrap();
    let i = text.find("stage_gain = ").unwrap();
    let end = i + text[i..].find('\n').unwrap();
    let bad = write(
        &d,
        "bad.toml",
        &format!("{}stage_gain = 2.5{}", &text[..i], &text[end..]),
    );
    let e = fails(&[
        "predict",
        "--model",
        s(&bad),
        "--fem",
        FEM,
        "--drive",
        FIT,
        "--out",
        s(&d.join("p.csv")),
    ]);
    assert!(
        e.contains("bad.toml") && e.contains("fem_correction.stage_gain = 2.5"),
        "{e}"
    );
}
