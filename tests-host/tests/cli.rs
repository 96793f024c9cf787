//! The `fpi` commands as scripts call them: exact columns, written files, and
//! errors that name the file, the line and the column.

use std::path::{Path, PathBuf};

mod common;
use common::{fails, ok, predict_args, s};

fn tmp() -> PathBuf {
    common::scratch("cli")
}

const FEM: &str = "data/stage-a/fem.csv.gz";
const RUN: &str = "data/stage-a/sine_15Hz.csv.gz";

/// A quick fpi model on three rig recordings, calibrated once and shared by the
/// tests (which run in parallel).
fn fpi_model(dir: &Path) -> PathBuf {
    static MODEL: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| common::quick_fpi(dir).0).clone()
}

#[test]
fn calibrate_prints_per_file_fit_and_records_it() {
    let d = tmp();
    let m = d.join("pi.toml");
    let text = ok(&[
        "calibrate",
        "--kind",
        "pi",
        "--rig",
        "data/pea-rig/preload_050N_sine_05Hz.csv.gz",
        "--out",
        s(&m),
        "--operators",
        "8",
    ]);
    assert!(
        text.contains("preload_050N_sine_05Hz.csv")
            && text.contains("RMSE µm")
            && text.contains("MTE µm"),
        "{text}"
    );
    let model = std::fs::read_to_string(&m).unwrap();
    assert!(
        model.contains("kind = \"pi\"")
            && model.contains("rmse_um")
            && model.contains("preload_050N_sine_05Hz.csv.gz"),
        "{model}"
    );
    assert!(model.contains("[[calibration.per_file]]"));
}

#[test]
fn predict_writes_the_documented_columns() {
    let d = tmp();
    let m = fpi_model(&d);
    let out = d.join("pred.csv");
    ok(&predict_args(s(&m), FEM, RUN, s(&out)));
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,voltage_V,x_pea_um,preload_N,x_fhps_um")
    );
    assert_eq!(
        text.lines().count(),
        1668,
        "header + one row per drive sample"
    );
}

#[test]
fn compare_writes_a_report_with_tables_and_plots() {
    let d = tmp();
    let m = fpi_model(&d);
    let out = d.join("cmp");
    let text = ok(&[
        "compare",
        "--fem",
        FEM,
        "--runs",
        RUN,
        "--model",
        s(&m),
        "--model",
        s(&m),
        "--out",
        s(&out),
    ]);
    assert!(text.contains("MAE reduction"), "{text}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("| Method |") && report.contains("FPI-FFEM"),
        "{report}"
    );
    assert!(out.join("loops_sine_15Hz.svg").exists() && out.join("errors_sine_15Hz.svg").exists());
    assert!(out.join("surface_sine_15Hz_fpi.svg").exists());
}

#[test]
fn invert_clamps_unreachable_targets_and_says_how_many() {
    let d = tmp();
    let m = fpi_model(&d);
    let target = d.join("target.csv");
    let mut t = String::from("t_s,x_fhps_um\n");
    for k in 0..100 {
        t.push_str(&format!("{},{}\n", k as f64 * 1e-3, k as f64 * 0.9));
    }
    std::fs::write(&target, t).unwrap();
    let out = d.join("drive.csv");
    let text = ok(&[
        "invert",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--target",
        s(&target),
        "--out",
        s(&out),
        "--u-max",
        "100",
    ]);
    assert!(
        text.contains("target samples lie outside the reachable stroke and were clamped"),
        "{text}"
    );
    let drive = std::fs::read_to_string(&out).unwrap();
    assert!(drive.starts_with("t_s,voltage_V\n") && drive.lines().count() == 101);
    let top: f64 = drive
        .lines()
        .last()
        .unwrap()
        .split(',')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!(top <= 100.0 + 1e-9, "{top}");
}

#[test]
fn export_writes_a_file_the_firmware_build_accepts_and_refuses_ldpi() {
    let d = tmp();
    let m = fpi_model(&d);
    let out = d.join("fw.toml");
    let text = ok(&["export", "--model", s(&m), "--fem", FEM, "--out", s(&out)]);
    assert!(text.contains("tables.f_k_inv"), "{text}");
    let fw = std::fs::read_to_string(&out).unwrap();
    fpi_host::model_file::FirmwareModel::parse(&fw, "fw.toml").unwrap();
    let l = d.join("ldpi.toml");
    ok(&[
        "calibrate",
        "--kind",
        "ldpi",
        "--rig",
        "data/pea-rig/preload_050N_sine_05Hz.csv.gz",
        "data/pea-rig/preload_150N_sine_05Hz.csv.gz",
        "--out",
        s(&l),
    ]);
    let err = fails(&[
        "export",
        "--model",
        s(&l),
        "--fem",
        FEM,
        "--out",
        s(&d.join("x.toml")),
    ]);
    assert!(
        err.contains("a ldpi model cannot run in the firmware"),
        "{err}"
    );
}

#[test]
fn bad_inputs_name_file_line_and_column() {
    let d = tmp();
    let m = fpi_model(&d);
    // A drive with a non-number.
    let drive = d.join("bad_drive.csv");
    std::fs::write(&drive, "t_s,voltage_V\n0,0\n0.001,1O\n").unwrap();
    let err = fails(&predict_args(s(&m), FEM, s(&drive), s(&d.join("p.csv"))));
    assert!(
        err.contains("bad_drive.csv:3: column voltage_V: \"1O\" is not a number"),
        "{err}"
    );
    // An FEM table whose x_pea does not increase.
    let fem = d.join("bad_fem.csv");
    std::fs::write(
        &fem,
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,63,2.8\n0.5,64,2.9\n",
    )
    .unwrap();
    let err = fails(&predict_args(s(&m), s(&fem), RUN, s(&d.join("p.csv"))));
    assert!(
        err.contains("bad_fem.csv:4: column x_pea_um: 0.5 does not increase"),
        "{err}"
    );
    // An FEM table with a non-finite value.
    std::fs::write(
        &fem,
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,nan,2.8\n",
    )
    .unwrap();
    let err = fails(&predict_args(s(&m), s(&fem), RUN, s(&d.join("p.csv"))));
    assert!(
        err.contains("bad_fem.csv:3: column preload_N: \"nan\" is not a finite number"),
        "{err}"
    );
    // A rig recording without force for an fpi model.
    let rig = d.join("no_force.csv");
    std::fs::write(&rig, "t_s,voltage_V,displacement_um\n0,0,0\n").unwrap();
    let err = fails(&[
        "calibrate",
        "--kind",
        "fpi",
        "--rig",
        s(&rig),
        "--out",
        s(&d.join("x.toml")),
    ]);
    assert!(
        err.contains("no_force.csv:1: column force_N: missing in the header"),
        "{err}"
    );
    // A model file with a wrong key.
    let bad = d.join("bad_model.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(&m)
            .unwrap()
            .replace("k_f_v_per_n", "k_f_volts"),
    )
    .unwrap();
    let err = fails(&predict_args(s(&bad), FEM, RUN, s(&d.join("p.csv"))));
    assert!(
        err.contains("bad_model.toml:16:1: not a model file") && err.contains("k_f_volts"),
        "{err}"
    );
    // An unknown kind.
    let err = fails(&[
        "calibrate",
        "--kind",
        "magic",
        "--rig",
        RUN,
        "--out",
        s(&d.join("x.toml")),
    ]);
    assert!(err.contains("unknown model kind \"magic\""), "{err}");
}

#[test]
fn the_micromanipulator_window_is_selectable() {
    let d = tmp();
    let m = d.join("epi.toml");
    let text = ok(&[
        "calibrate",
        "--rig",
        "data/real/micromanipulator/Model_Vi_Do.dat.gz",
        "--rows",
        "3152-3351",
        "--out",
        s(&m),
    ]);
    assert!(
        text.starts_with("epi model"),
        "no force: epi by default\n{text}"
    );
    let model = std::fs::read_to_string(&m).unwrap();
    assert!(
        model.contains("rows = [3152, 3351]") && model.contains("kind = \"epi\""),
        "{model}"
    );
    let err = fails(&[
        "calibrate",
        "--rig",
        "data/real/micromanipulator/Model_Vi_Do.dat.gz",
        "--rows",
        "3152-9999",
        "--out",
        s(&m),
    ]);
    assert!(err.contains("outside the recording's 8027 rows"), "{err}");
}

/// The authors' identification cycle (rows 3152–3351 of `Model_Vi_Do.dat`)
/// cut to a rig CSV — force 0, displacement from the cycle's first row — as a
/// user without the `.dat` reader would: `t_s,voltage_V,force_N,displacement_um`,
/// the displacement times `sign`.
fn micromanipulator_cycle_csv(path: &Path, sign: f64) {
    let m = fpi_host::data::read_micromanipulator(Path::new(
        "data/real/micromanipulator/Model_Vi_Do.dat.gz",
    ))
    .unwrap();
    let (u, x) = (&m.u[3151..3351], &m.sensor[3151..3351]);
    let mut text = String::from("t_s,voltage_V,force_N,displacement_um\n");
    for k in 0..u.len() {
        text += &format!("{},{},0,{}\n", k as f64 / 200.0, u[k], sign * (x[k] - x[0]));
    }
    std::fs::write(path, text).unwrap();
}

/// The cycle cut to a CSV gives a valid model as `--rows` does (it gave one with
/// `w0 = 0`, which its own check refused: a 10 ms creep lag is two samples at
/// 200 Hz and took the immediate slope). Both fits run with the same options
/// (the zero force column is no force channel: an offset; the lags the 200 Hz
/// samples resolve); they differ only by the operators' history before the
/// cycle, which `--rows` keeps. The same cycle with its sign flipped is refused
/// in terms of the data.
#[test]
fn the_micromanipulator_cycle_cut_to_a_csv_gives_a_valid_model() {
    use fpi_host::method::model::HostModel;
    let d = tmp();
    let csv = d.join("cycle.csv");
    micromanipulator_cycle_csv(&csv, 1.0);
    let (from_csv, from_rows) = (d.join("cycle-epi.toml"), d.join("rows-epi.toml"));
    let text = ok(&["calibrate", "--rig", s(&csv), "--out", s(&from_csv)]);
    assert!(text.contains("model written to"), "{text}");
    ok(&[
        "calibrate",
        "--rig",
        "data/real/micromanipulator/Model_Vi_Do.dat.gz",
        "--rows",
        "3152-3351",
        "--out",
        s(&from_rows),
    ]);
    let (a, b) = (
        HostModel::read(&from_csv).unwrap(),
        HostModel::read(&from_rows).unwrap(),
    );
    for m in [&a, &b] {
        m.validate().unwrap();
        assert_eq!(m.kind.name(), "epi");
        assert!(m.pi.w0_um_per_v > 0.5, "{:?}", m.pi);
        // Within 0.5 % of the cycle's 45 µm (measured 0.123 and 0.064 µm).
        assert!(m.calibration.rmse_um < 0.2, "{}", m.calibration.rmse_um);
        let taus: Vec<f64> = m.creep.iter().map(|c| c.tau_s).collect();
        assert_eq!(taus, [0.3], "the lags 200 Hz resolves within the cycle");
        assert!(
            m.offset_um != 0.0,
            "an offset, as for a recording without force"
        );
    }
    micromanipulator_cycle_csv(&csv, -1.0);
    let err = fails(&["calibrate", "--rig", s(&csv), "--out", s(&from_csv)]);
    assert!(
        err.contains(
            "the recordings give no valid epi model: the displacement of cycle.csv \
             does not rise with the voltage over its fitted rows (a straight line through them \
             goes -12.35 µm/V)"
        ) && err.contains("needs its sign flipped; nothing is written"),
        "{err}"
    );
}

/// `fpi board …` against the emulated board, as a user without a board runs it:
/// load a model (a calibrated model with the stage's FEM tables, as `fpi export`
/// takes them), move, run a wave, record it to a CSV that `fpi compare` reads as a
/// dataset; an unreachable target is refused with the reason.
#[test]
fn board_commands_drive_the_emulated_board() {
    if !fpi_host::board::emulator::available_for("board_commands_drive_the_emulated_board") {
        return;
    }
    let e = fpi_host::board::emulator::Emulator::start(None).unwrap_or_else(|e| panic!("{e:#}"));
    let port = e.port().to_string();
    let board = |args: &[&str]| -> Vec<String> {
        let mut a = vec!["board", "--port", port.as_str()];
        a.extend_from_slice(args);
        a.iter().map(|s| s.to_string()).collect()
    };
    let run = |args: &[&str]| {
        let a = board(args);
        ok(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let dir = tmp();
    let model = fpi_model(&dir);
    let out = run(&["load", s(&model), "--fem", FEM, "--store"]);
    assert!(out.contains("stored in flash as generation 1"), "{out}");
    let out = run(&["status"]);
    assert!(
        out.contains("received over the link") && out.contains("state: parked"),
        "{out}"
    );
    run(&["move", "10", "--speed", "2000"]);
    run(&[
        "wave",
        "--shape",
        "triangle",
        "--amplitude-um",
        "8",
        "--offset-um",
        "15",
        "--freq-hz",
        "10",
        "--cycles",
        "0",
    ]);
    let rec = dir.join("board-record.csv");
    let out = run(&[
        "record",
        "--seconds",
        "0.3",
        "--out",
        s(&rec),
        "--decimation",
        "20",
    ]);
    assert!(
        out.contains("300 samples") && out.contains("0 dropped"),
        "{out}"
    );
    let csv = std::fs::read_to_string(&rec).unwrap();
    assert!(
        csv.starts_with("t_s,voltage_V,force_N,x_ref_um,x_est_um,status,x_fhps_um,x_sensor_um\n")
    );
    assert!(
        out.contains("link: uart (12 kB/s)") && out.contains(": fits"),
        "{out}"
    );
    // Every tick for a second: more than the UART (the emulated board's link
    // until told otherwise) carries. Said up front, and the drops counted.
    let all = dir.join("board-record-all.csv");
    let out = run(&[
        "record",
        "--seconds",
        "1",
        "--out",
        s(&all),
        "--decimation",
        "1",
    ]);
    assert!(
        out.contains("MORE THAN THE LINK CARRIES") && out.contains("--decimation 44 or more fits"),
        "{out}"
    );
    let dropped: u32 = out
        .split(" dropped")
        .next()
        .and_then(|h| h.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{out}"));
    // 20 000 asked for; the ring and about 11.5 kB/s of 20-byte samples kept.
    println!("{out}");
    assert!(dropped > 15_000, "{out}");
    let a = board(&["move", "45"]);
    let err = fails(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(err.contains("outside the stroke"), "{err}");
    // The analog input on the virtual bench, then a broken sensor wire.
    run(&["bench", "--analog-v", "1.65"]);
    run(&["analog"]);
    std::thread::sleep(std::time::Duration::from_millis(300));
    let out = run(&["status"]);
    assert!(out.contains("source: Analog"), "{out}");
    run(&["bench", "--sensor", "open"]);
    std::thread::sleep(std::time::Duration::from_millis(300));
    let out = run(&["status"]);
    assert!(
        out.contains("FAULT") && out.contains("force reading outside the sensor range"),
        "{out}"
    );
    // The recording is a dataset: `fpi compare` scores the model on it.
    let cmp = dir.join("board-compare");
    let out = ok(&[
        "compare",
        "--fem",
        FEM,
        "--runs",
        s(&rec),
        "--model",
        s(&model),
        "--out",
        s(&cmp),
    ]);
    assert!(out.contains("board-record.csv"), "{out}");
}

/// A valid output name of 244 bytes failed with "File name too long": the
/// temporary file written beside it carried the name and more.
#[test]
fn the_longest_valid_output_name_is_written() {
    let d = tmp();
    let m = fpi_model(&d);
    let out = d.join(format!("{}.csv", "p".repeat(251))); // 255 bytes
    ok(&predict_args(s(&m), FEM, RUN, s(&out)));
    assert!(out.exists());
}

/// A 10 MB CSV cell and a TOML line of 200 000 `[` came back whole in the error
/// message: an error quotes at most 80 characters of what it read.
#[test]
fn errors_quote_at_most_eighty_characters() {
    let d = tmp();
    let cell = d.join("big-cell.csv");
    let text = format!(
        "t_s,voltage_V,force_N,displacement_um\n0,1,2,3\n0.1,{},2,3\n",
        "x".repeat(10_000_000)
    );
    std::fs::write(&cell, text).unwrap();
    let err = fails(&[
        "calibrate",
        "--rig",
        s(&cell),
        "--out",
        s(&d.join("o.toml")),
    ]);
    assert!(
        err.contains(&format!(
            "big-cell.csv:3: column voltage_V: \"{}…\" is not a number",
            "x".repeat(80)
        )),
        "{}",
        &err[..err.len().min(400)]
    );
    assert!(err.len() < 1000, "{} bytes", err.len());
    let brackets = d.join("brackets.toml");
    let text = format!(
        "format = \"piezo-fpi-model/1\"\nkind = {}\n",
        "[".repeat(200_000)
    );
    std::fs::write(&brackets, text).unwrap();
    let err = fails(&predict_args(s(&brackets), FEM, RUN, s(&d.join("p.csv"))));
    assert!(
        err.contains("brackets.toml:2:"),
        "{}",
        &err[..err.len().min(400)]
    );
    assert!(err.len() < 1000, "{} bytes", err.len());
}

/// A board of two axes (the in-process XY stage as designed): `--axis`
/// addresses each, an axis the board lacks is refused by name, and
/// `fpi board raster` records every axis into `<signal>@<axis>` columns.
#[test]
fn a_board_of_two_axes_addresses_each_and_rasters_over_both() {
    let xy = "virtual:usb:xy";
    let out = ok(&["board", "--port", xy, "--axis", "y", "status"]);
    assert!(out.contains("axis: y of 2 (x, y)"), "{out}");
    let err = fails(&["board", "--port", "virtual", "--axis", "y", "status"]);
    assert!(err.contains("has 1 axis (x): there is no axis y"), "{err}");
    let err = fails(&["board", "--port", xy, "--axis", "w", "status"]);
    assert!(err.contains("x, y or z"), "{err}");
    let csv = tmp().join("raster.csv");
    let raster = |fast: &str, to: &str| -> Vec<String> {
        [
            "board",
            "--port",
            xy,
            "raster",
            "--fast",
            fast,
            "--slow",
            "y",
            "--freq-hz",
            "50",
            "--lines",
            "4",
            "--from-um",
            "5",
            "--to-um",
            to,
            "--out",
            s(&csv),
        ]
        .map(str::to_string)
        .to_vec()
    };
    let out = ok(&strs(&raster("x", "35")));
    assert!(
        out.contains("raster recorded") && out.contains("of 2 axes, 0 samples dropped"),
        "{out}"
    );
    assert!(out.contains("on the true positions"), "{out}");
    let text = std::fs::read_to_string(&csv).unwrap();
    let head = text.lines().next().unwrap();
    assert!(
        head.starts_with("t_s,x_ref_um@x") && head.contains("x_fhps_um@y"),
        "{head}"
    );
    let out = ok(&["board", "--port", xy, "move", "--x", "12", "--y", "22"]);
    assert!(out.contains("moving x to 12 µm, y to 22 µm"), "{out}");
    let moved = tmp().join("moved.csv");
    let out = ok(&[
        "board",
        "--port",
        xy,
        "move",
        "--x",
        "10",
        "--y",
        "20",
        "--record",
        s(&moved),
    ]);
    assert!(
        out.contains("every axis recorded") && out.contains("0 samples dropped"),
        "{out}"
    );
    let text = std::fs::read_to_string(&moved).unwrap();
    let last: Vec<f64> = text
        .lines()
        .last()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    let head: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let at = |name: &str| last[head.iter().position(|h| *h == name).unwrap()];
    assert_eq!(
        (at("x_ref_um@x"), at("x_ref_um@y")),
        (10.0, 20.0),
        "{head:?}"
    );
    let err = fails(&["board", "--port", xy, "move", "12", "--y", "22"]);
    assert!(err.contains("cannot be used with"), "{err}");
    let err = fails(&strs(&raster("y", "35")));
    assert!(err.contains("fast and slow axes are two"), "{err}");
    let err = fails(&strs(&raster("x", "45")));
    assert!(
        err.contains("fast axis's end") && err.contains("45.000"),
        "{err}"
    );
}

/// `args` as the `&str`s `ok` and `fails` take.
fn strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

/// `fpi board autotune` without `--axis` on a board of two axes tunes every
/// axis and measures their coupling into one file of several axes; `fpi
/// board load` loads it whole on a board of two axes and refuses it on a
/// board of one; a coupling the board cannot undo is named by its key, its
/// value and the rule.
#[test]
fn autotune_of_every_axis_writes_one_file_that_loads_whole() {
    let d = tmp();
    let tuned = d.join("xy-tuned.toml");
    let out = ok(&[
        "board",
        "--port",
        "virtual:usb:xy-built",
        "autotune",
        "../firmware/model/stage-a.toml",
        "--trials",
        "0",
        "--points",
        "16",
        "--sensor-crosstalk",
        "0.002",
        "--out",
        s(&tuned),
    ]);
    assert!(
        out.contains("every axis tuned and the coupling measured"),
        "{out}"
    );
    assert!(
        out.contains("axis y:") && out.contains("parasitic motion"),
        "{out}"
    );
    let text = std::fs::read_to_string(&tuned).unwrap();
    assert!(
        text.contains("format = \"piezo-fpi-axes/1\"")
            && text.contains("[y.pi]")
            && text.contains("[coupling]"),
        "{text}"
    );
    let out = ok(&["board", "--port", "virtual:xy-built", "load", s(&tuned)]);
    assert!(
        out.contains("axis y: its model running") && out.contains("the decoupling"),
        "{out}"
    );
    let err = fails(&["board", "--port", "virtual", "load", s(&tuned)]);
    assert!(
        err.contains("the model file has 2 axes (x, y) and the board 1"),
        "{err}"
    );
    let bad = d.join("xy-bad.toml");
    let broken: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with("parasitic = ") {
                "parasitic = [[0.0, 0.3], [0.015, 0.0]]".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(&bad, broken.join("\n")).unwrap();
    let err = fails(&["board", "--port", "virtual:xy-built", "load", s(&bad)]);
    assert!(
        err.contains("xy-bad.toml: coupling.parasitic[0][1] = 0.3: finite, within ±0.1"),
        "{err}"
    );
}
