//! Issue 13: the `fpi` commands refuse bad input clearly. Each case runs the built
//! binary on small temporary files and checks that it fails (non-zero exit), does
//! not panic, names the file, option or key and the offending number, and leaves
//! no wrong output behind.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const FEM: &str = "data/stage-a/fem.csv.gz";
const RUN: &str = "data/stage-a/sine_15Hz.csv.gz";
const RIG: &str = "data/pea-rig/preload_050N_sine_05Hz.csv.gz";
const MM: &str = "data/real/micromanipulator/Model_Vi_Do.dat.gz";

/// An fpi model as calibrated on three rig recordings (`fpi calibrate --kind fpi`),
/// written by hand so that no test waits for a calibration.
const MODEL: &str = r#"format = "piezo-fpi-model/1"
kind = "fpi"
dead_zone_softness_v = 0.0
offset_um = 0.0

[pi]
w0_um_per_v = 0.0645675944760201
thresholds_v = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0]
weights_um_per_v = [0.005975975123342759, 0.010307079936977687, 0.005228197623804832, 0.004189142833857395, 0.002835838200989663, 0.0, 0.0, 0.014979333681724012, 0.002533891468331532]
input_max_v = 150.0

[coupling]
offset_v = 0.0
k_f_v_per_n = 0.10094876534708432
k_q_v_per_n2 = 0.0
force_q_n = 0.0
compliance_um_per_n = 0.0

[output]
map = "identity"

[calibration]
created_by = "tests/bad_inputs.rs"
files = []
rmse_um = 0.0564
mte_um = 0.246
per_file = []
method = "by hand"
"#;

mod common;
use common::{fpi, ok, refused, s};

/// A fresh folder for one test.
fn dir(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fpi-bad-inputs-{}/{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn write(p: &Path, text: &str) -> PathBuf {
    std::fs::write(p, text).unwrap();
    p.to_path_buf()
}

/// [`MODEL`] with each `(from, to)` replaced, written to `dir/name`.
fn model(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = MODEL.to_string();
    for (from, to) in edits {
        assert!(text.contains(from), "{from:?} not in the model");
        text = text.replacen(from, to, 1);
    }
    write(&dir.join(name), &text)
}

/// A target trajectory `t_s,x_fhps_um`: a ramp to 30 µm over 100 samples.
fn target(dir: &Path) -> PathBuf {
    let mut t = String::from("t_s,x_fhps_um\n");
    for k in 0..100 {
        t.push_str(&format!("{},{}\n", k as f64 * 1e-3, k as f64 * 0.3));
    }
    write(&dir.join("target.csv"), &t)
}

/// The `voltage_V` column of a CSV written by `fpi invert`.
fn voltages(path: &Path) -> Vec<f64> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect()
}

/// The files in a folder, sorted.
fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    v.sort();
    v
}

const ZERO_WEIGHTS: [(&str, &str); 3] = [
    ("w0_um_per_v = 0.0645675944760201", "w0_um_per_v = 0.0"),
    (
        "weights_um_per_v = [0.005975975123342759, 0.010307079936977687, 0.005228197623804832, 0.004189142833857395, 0.002835838200989663, 0.0, 0.0, 0.014979333681724012, 0.002533891468331532]",
        "weights_um_per_v = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
    ),
    ("k_f_v_per_n = 0.10094876534708432", "k_f_v_per_n = 0.1"),
];

/// Item 1: a recording at constant voltage gives a model without motion; calibrate
/// does not write it, and no command takes such a model file.
#[test]
fn a_model_without_motion_is_neither_written_nor_used() {
    let d = dir("no_motion");
    let mut rig = String::from("t_s,voltage_V,force_N,displacement_um\n");
    for k in 0..300 {
        rig.push_str(&format!("{:.3},50,60,0.5\n", k as f64 * 1e-3));
    }
    let rig = write(&d.join("constant.csv"), &rig);
    let out = d.join("constant.toml");
    refused(
        &[
            "calibrate",
            "--kind",
            "pi",
            "--rig",
            s(&rig),
            "--out",
            s(&out),
        ],
        &[
            "constant.csv",
            "voltage_V is constant (50 V",
            "nothing to fit",
        ],
    );
    assert!(!out.exists(), "a model without motion was written");

    let zero = model(&d, "zero.toml", &ZERO_WEIGHTS);
    let tgt = target(&d);
    let drive = d.join("drive.csv");
    let why = [
        "zero.toml",
        "pi.w0_um_per_v and pi.weights_um_per_v are all 0",
    ];
    let inv = [
        "invert",
        "--model",
        s(&zero),
        "--fem",
        FEM,
        "--target",
        s(&tgt),
        "--out",
        s(&drive),
    ];
    refused(&inv, &why);
    assert!(
        !drive.exists(),
        "invert wrote a drive for a model without motion"
    );
    let fw = d.join("fw.toml");
    refused(
        &["export", "--model", s(&zero), "--fem", FEM, "--out", s(&fw)],
        &why,
    );
    let p = d.join("p.csv");
    let pred = [
        "predict",
        "--model",
        s(&zero),
        "--fem",
        FEM,
        "--drive",
        RUN,
        "--out",
        s(&p),
    ];
    refused(&pred, &why);
    let cmp = d.join("cmp");
    let args = [
        "compare",
        "--fem",
        FEM,
        "--runs",
        RUN,
        "--model",
        s(&zero),
        "--out",
        s(&cmp),
    ];
    refused(&args, &why);
}

/// Item 2: `--u-max` must be a finite voltage within the amplifier's 0..150 V.
#[test]
fn u_max_outside_the_amplifier_span_is_refused_with_its_value() {
    let d = dir("u_max");
    let m = model(&d, "m.toml", &[]);
    let tgt = target(&d);
    let out = d.join("drive.csv");
    for (v, why) in [
        ("-5", "-5 V: must be > 0 V"),
        ("0", "0 V: must be > 0 V"),
        ("nan", "nan is not a finite number"),
        ("inf", "inf is not a finite number"),
        ("1000", "1000 V: above the board's amplifier span (150 V)"),
    ] {
        let args = [
            "invert",
            "--model",
            s(&m),
            "--fem",
            FEM,
            "--target",
            s(&tgt),
            "--out",
            s(&out),
            "--u-max",
            v,
        ];
        refused(&args, &["--u-max", why]);
        assert!(!out.exists(), "--u-max {v}: a drive was written");
    }
}

/// Item 2: weights whose partial sums turn negative are refused by key and value
/// in every command; a negative weight the slope survives inverts to finite
/// voltages within 0..u_max.
#[test]
fn negative_weights_are_refused_or_give_finite_voltages() {
    let d = dir("negative_weights");
    let w = "weights_um_per_v = [0.005975975123342759";
    let bad = model(&d, "falling.toml", &[(w, "weights_um_per_v = [-0.07")]);
    let why = [
        "falling.toml",
        "pi.weights_um_per_v[0] = -0.07: the slope w0 + w_1 = ",
        "is not positive",
    ];
    let tgt = target(&d);
    let out = d.join("drive.csv");
    let inv = |m: &Path| {
        vec![
            "invert".to_string(),
            "--model".into(),
            s(m).into(),
            "--fem".into(),
            FEM.into(),
            "--target".into(),
            s(&tgt).into(),
            "--out".into(),
            s(&out).into(),
            "--u-max".into(),
            "120".into(),
        ]
    };
    let args = inv(&bad);
    refused(&args.iter().map(String::as_str).collect::<Vec<_>>(), &why);
    let p = d.join("p.csv");
    let pred = [
        "predict",
        "--model",
        s(&bad),
        "--fem",
        FEM,
        "--drive",
        RUN,
        "--out",
        s(&p),
    ];
    refused(&pred, &why);
    let fw = d.join("fw.toml");
    refused(
        &["export", "--model", s(&bad), "--fem", FEM, "--out", s(&fw)],
        &why,
    );

    let dip = model(&d, "dip.toml", &[(w, "weights_um_per_v = [-0.03")]);
    let args = inv(&dip);
    ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let u = voltages(&out);
    assert_eq!(u.len(), 100);
    assert!(
        u.iter().all(|v| v.is_finite() && (0.0..=120.0).contains(v)),
        "{u:?}"
    );
}

/// Item 3: an FEM table reaching 1e9 or 1e300 µm is refused by line, column and
/// value, at once (no table is sized from it); one that is in range but needs
/// more knots than the firmware holds is refused without allocating them.
#[test]
fn an_fem_table_beyond_the_signal_range_is_refused_at_once() {
    let d = dir("huge_fem");
    let m = model(&d, "m.toml", &[]);
    let out = d.join("fw.toml");
    for (big, shown) in [("1e9", "1e9 µm"), ("1e300", "1e300 µm")] {
        let fem = write(
            &d.join(format!("fem_{big}.csv")),
            &format!("x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,63,2.8\n{big},64,5.6\n"),
        );
        let start = Instant::now();
        refused(
            &[
                "export",
                "--model",
                s(&m),
                "--fem",
                s(&fem),
                "--out",
                s(&out),
            ],
            &[&format!(
                "fem_{big}.csv:4: column x_pea_um: {shown} is outside ±4096 µm"
            )],
        );
        assert!(start.elapsed() < Duration::from_secs(20));
        assert!(!out.exists());
    }
    let fem = write(
        &d.join("fem_wide.csv"),
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,63,2.8\n4000,64,3000\n",
    );
    let err = refused(
        &[
            "export",
            "--model",
            s(&m),
            "--fem",
            s(&fem),
            "--out",
            s(&out),
        ],
        &["tables.f_f: no power-of-two grid over [0, 4000] with at most 4000 knots"],
    );
    assert!(
        err.contains("warning: ") && err.contains("4000 µm: longer than any piezo stack"),
        "the implausible value is warned about, with its number:\n{err}"
    );
}

/// Item 4: an output that is one of the command's inputs is refused, naming both,
/// and the input is left as it was.
#[test]
fn an_output_that_is_an_input_is_refused_and_the_input_kept() {
    let d = dir("out_is_input");
    let m = model(&d, "m.toml", &[]);
    let tgt = target(&d);
    let drive = write(
        &d.join("drive.csv"),
        "t_s,voltage_V\n0,0\n0.001,10\n0.002,20\n",
    );
    let rig = d.join("rig.csv.gz");
    std::fs::copy(RIG, &rig).unwrap();
    let fem = d.join("fem.csv.gz");
    std::fs::copy(FEM, &fem).unwrap();
    let before: Vec<Vec<u8>> = [&m, &tgt, &drive, &rig, &fem]
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    let alias = |p: &Path| d.join(".").join(p.file_name().unwrap());
    let why = "refusing to overwrite an input";
    let (a_drive, a_tgt, a_m, a_rig, a_fem) = (
        alias(&drive),
        alias(&tgt),
        alias(&m),
        alias(&rig),
        alias(&fem),
    );
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "predict",
                "--model",
                s(&m),
                "--fem",
                s(&fem),
                "--drive",
                s(&drive),
                "--out",
                s(&a_drive),
            ],
            "is the input --drive",
        ),
        (
            vec![
                "invert",
                "--model",
                s(&m),
                "--fem",
                s(&fem),
                "--target",
                s(&tgt),
                "--out",
                s(&a_tgt),
            ],
            "is the input --target",
        ),
        (
            vec![
                "export",
                "--model",
                s(&m),
                "--fem",
                s(&fem),
                "--out",
                s(&a_m),
            ],
            "is the input --model",
        ),
        (
            vec![
                "calibrate",
                "--kind",
                "pi",
                "--rig",
                s(&rig),
                "--out",
                s(&a_rig),
            ],
            "is the input --rig",
        ),
        (
            vec![
                "compare",
                "--fem",
                s(&fem),
                "--runs",
                RUN,
                "--model",
                s(&m),
                "--out",
                s(&a_fem),
            ],
            "is the input --fem",
        ),
    ];
    for (args, named) in cases {
        refused(&args, &["--out", named, why]);
    }
    let after: Vec<Vec<u8>> = [&m, &tgt, &drive, &rig, &fem]
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    assert!(before == after, "an input was changed");
    // A report folder holding an input the report would overwrite.
    let clash = write(&d.join("report.md"), "my notes");
    let args = [
        "compare",
        "--fem",
        FEM,
        "--runs",
        s(&clash),
        "--model",
        s(&m),
        "--out",
        s(&d),
    ];
    refused(&args, &["would overwrite the input --runs", "report.md"]);
    assert_eq!(std::fs::read_to_string(&clash).unwrap(), "my notes");
}

/// Item 4 and 8: an output that cannot be written is named, and found before the
/// command works (calibrate does not fit, the board does not record).
#[test]
fn an_unwritable_output_is_named_before_the_work() {
    let d = dir("unwritable");
    let m = model(&d, "m.toml", &[]);
    let file = write(&d.join("a-file"), "x");
    let under = file.join("x.csv");
    let proc_out = Path::new("/proc/fpi-bad-inputs/x.csv");
    for out in [under.as_path(), proc_out] {
        let pred = [
            "predict",
            "--model",
            s(&m),
            "--fem",
            FEM,
            "--drive",
            RUN,
            "--out",
            s(out),
        ];
        refused(&pred, &[s(out)]);
        let o = fpi(&["calibrate", "--kind", "pi", "--rig", RIG, "--out", s(out)]);
        let (stdout, err) = (
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
        );
        assert!(!o.status.success() && err.contains(s(out)), "{err}");
        assert!(
            !stdout.contains("calibrated on"),
            "calibrate fitted before finding its output unwritable:\n{stdout}"
        );
        let cmp = [
            "compare",
            "--fem",
            FEM,
            "--runs",
            RUN,
            "--model",
            s(&m),
            "--out",
            s(out),
        ];
        refused(&cmp, &[s(out)]);
        // Before connecting to a board (nothing listens on the discard port).
        let rec = [
            "board",
            "--port",
            "tcp:127.0.0.1:9",
            "record",
            "--seconds",
            "1",
            "--out",
            s(out),
        ];
        refused(&rec, &[s(out)]);
    }
    // A missing folder is created.
    let nested = d.join("new/deeper/drive.csv");
    let tgt = target(&d);
    ok(&[
        "invert",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--target",
        s(&tgt),
        "--out",
        s(&nested),
    ]);
    assert_eq!(voltages(&nested).len(), 100);
}

/// Item 4: a device is not replaced by an output file.
#[test]
fn dev_full_is_refused_and_left_alone() {
    let full = Path::new("/dev/full");
    if !full.exists() {
        return;
    }
    let d = dir("dev_full");
    let m = model(&d, "m.toml", &[]);
    let pred = [
        "predict",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--drive",
        RUN,
        "--out",
        "/dev/full",
    ];
    refused(&pred, &["/dev/full", "not a regular file"]);
    let tgt = target(&d);
    let inv = [
        "invert",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--target",
        s(&tgt),
        "--out",
        "/dev/full",
    ];
    refused(&inv, &["/dev/full"]);
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = std::fs::metadata(full).unwrap().file_type();
        assert!(t.is_char_device(), "/dev/full was replaced");
    }
    let leftovers: Vec<String> = files_in(Path::new("/dev"))
        .into_iter()
        .filter(|n| n.starts_with(".full"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// Item 4: a disk that fills up while the output is written (here: a file-size
/// limit, which fails the write the same way) leaves the old file, no partial or
/// temporary file, and an error naming the file.
#[cfg(unix)]
#[test]
fn a_full_disk_leaves_the_old_file_and_names_it() {
    let d = dir("full_disk");
    let m = model(&d, "m.toml", &[]);
    let out = write(&d.join("pred.csv"), "old content\n");
    let script = format!(
        "ulimit -f 8; trap '' XFSZ; exec \"$0\" predict --model '{}' --fem {FEM} --drive {RUN} \
         --out '{}'",
        s(&m),
        s(&out)
    );
    let o = Command::new("sh")
        .args(["-c", &script])
        .arg(fpi_tests::fpi_bin())
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(&format!("{}: cannot write", s(&out))), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old content\n");
    assert_eq!(files_in(&d), vec!["m.toml", "pred.csv"]);
}

/// Item 6: export's numeric options must be finite and within the board's limits.
#[test]
fn export_options_beyond_the_board_are_refused_with_their_value() {
    let d = dir("export_options");
    let m = model(&d, "m.toml", &[]);
    let out = d.join("fw.toml");
    let base = ["export", "--model", s(&m), "--fem", FEM, "--out", s(&out)];
    let cases: [(&[&str], &[&str]); 7] = [
        (
            &["--u-max", "1000"],
            &[
                "--u-max",
                "1000 V: above the board's amplifier span (150 V)",
            ],
        ),
        (&["--u-max", "0"], &["--u-max", "0 V: must be > 0 V"]),
        (
            &["--stroke-voltage", "nan"],
            &["--stroke-voltage", "nan is not a finite number"],
        ),
        (
            &["--stroke-voltage", "140", "--u-max", "100"],
            &["--stroke-voltage 140 V: above --u-max (100 V)"],
        ),
        (
            &["--slew", "1e9"],
            &[
                "--slew",
                "1e9 V/ms: above the amplifier's largest slew (100 V/ms)",
            ],
        ),
        (&["--slew", "-1"], &["--slew", "-1 V/ms: must be > 0"]),
        (&["--rate", "0"], &["--rate", "0 is not in 100..=200000"]),
    ];
    for (extra, why) in cases {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        refused(&args, why);
        assert!(!out.exists(), "{extra:?}: a firmware model was written");
    }
    let rig = [
        "calibrate",
        "--kind",
        "efpi",
        "--rig",
        RIG,
        "--out",
        s(&out),
    ];
    let mut args = rig.to_vec();
    args.extend_from_slice(&["--compliance", "-0.5"]);
    refused(
        &args,
        &["--compliance", "-0.5 µm/N: must be within 0–0.499999 µm/N"],
    );
    // A compliance far beyond any stack's (the fit it gave had an RMSE of 7·10⁷ µm).
    let mut args = rig.to_vec();
    args.extend_from_slice(&["--compliance", "1e9"]);
    refused(
        &args,
        &["--compliance", "1e9 µm/N: must be within 0–0.499999 µm/N"],
    );
    let mut args = rig.to_vec();
    args.extend_from_slice(&["--operators", "0"]);
    refused(
        &args,
        &["--operators", "0: a model has 1..=32 play operators"],
    );
}

/// Item 6: predict refuses a drive beyond the model's and the amplifier's range,
/// naming the file, the line and the voltage.
#[test]
fn predict_refuses_a_drive_beyond_the_amplifier() {
    let d = dir("drive_range");
    let m = model(&d, "m.toml", &[]);
    let out = d.join("p.csv");
    for (v, shown) in [("1000", "1000 V"), ("-3", "-3 V")] {
        let drive = write(
            &d.join("drive.csv"),
            &format!("t_s,voltage_V\n0,0\n0.001,50\n0.002,{v}\n0.003,20\n"),
        );
        let args = [
            "predict",
            "--model",
            s(&m),
            "--fem",
            FEM,
            "--drive",
            s(&drive),
            "--out",
            s(&out),
        ];
        refused(
            &args,
            &[&format!(
                "drive.csv:4: column voltage_V: {shown} is outside the model's input range 0..150 V"
            )],
        );
        assert!(!out.exists());
    }
}

/// Item 7: a gzip bomb (200 MB of zeros in ~200 kB) is refused after reading a
/// small part of it, naming the file.
#[test]
fn a_gzip_bomb_is_refused_quickly() {
    let d = dir("gzip_bomb");
    let m = model(&d, "m.toml", &[]);
    let bomb = d.join("bomb.csv.gz");
    let mut gz = flate2::write::GzEncoder::new(
        std::fs::File::create(&bomb).unwrap(),
        flate2::Compression::fast(),
    );
    gz.write_all(b"t_s,voltage_V\n").unwrap();
    let zeros = vec![b'0'; 1 << 20];
    for _ in 0..200 {
        gz.write_all(&zeros).unwrap();
    }
    gz.finish().unwrap();
    let out = d.join("p.csv");
    let start = Instant::now();
    let args = [
        "predict",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--drive",
        s(&bomb),
        "--out",
        s(&out),
    ];
    refused(&args, &["bomb.csv.gz", "a gzip bomb?"]);
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "{:?}",
        start.elapsed()
    );
    assert!(!out.exists());
}

/// Item 8: runs and models with the same file name in different folders get
/// their own plots (the second is renamed, with a note), none overwritten.
#[test]
fn compare_keeps_inputs_named_alike_apart() {
    let d = dir("same_names");
    for sub in ["a", "b"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
        std::fs::copy(RUN, d.join(sub).join("run.csv.gz")).unwrap();
    }
    let ma = model(&d.join("a"), "model.toml", &[]);
    let mb = model(
        &d.join("b"),
        "model.toml",
        &[("k_f_v_per_n = 0.10094876534708432", "k_f_v_per_n = 0.09")],
    );
    let (ra, rb) = (d.join("a/run.csv.gz"), d.join("b/run.csv.gz"));
    let out = d.join("report");
    let text = ok(&[
        "compare",
        "--fem",
        FEM,
        "--runs",
        s(&ra),
        s(&rb),
        "--model",
        s(&ma),
        "--model",
        s(&mb),
        "--out",
        s(&out),
    ]);
    assert!(
        text.contains("note: another run is also named \"run.csv\"")
            && text.contains("note: another model is also named \"model\""),
        "{text}"
    );
    let files = files_in(&out);
    for f in [
        "loops_run.svg",
        "loops_run-2.svg",
        "errors_run.svg",
        "errors_run-2.svg",
        "surface_run_model.svg",
        "surface_run_model-2.svg",
        "surface_run-2_model.svg",
        "surface_run-2_model-2.svg",
        "report.md",
    ] {
        assert!(files.contains(&f.to_string()), "{f} missing: {files:?}");
    }
    assert!(files.iter().all(|f| !f.ends_with(".tmp")), "{files:?}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("`model-2`") && report.contains("run-2.csv"),
        "{report}"
    );
}

/// Item 8: a header naming a column twice is refused by name, not as "column ?".
#[test]
fn a_duplicate_column_is_named() {
    let d = dir("duplicate_column");
    let m = model(&d, "m.toml", &[]);
    let drive = write(
        &d.join("dup.csv"),
        "t_s,voltage_V,voltage_V\n0,0,1\n0.001,50,2\n",
    );
    let out = d.join("p.csv");
    let args = [
        "predict",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--drive",
        s(&drive),
        "--out",
        s(&out),
    ];
    let err = refused(
        &args,
        &["dup.csv:1: column voltage_V: appears twice in the header (fields 2 and 3)"],
    );
    assert!(!err.contains("column ?"), "{err}");
}

/// Item 8: `--rows` must select enough rows to fit.
#[test]
fn rows_too_few_to_fit_are_refused() {
    let d = dir("rows");
    let out = d.join("m.toml");
    for (rows, why) in [
        ("1-1", "1-1: 1 row(s); a fit needs at least 20 rows"),
        ("0-40", "0-40: rows are numbered from 1"),
        ("40-30", "40-30: the last row 30 comes before the first 40"),
    ] {
        let args = ["calibrate", "--rig", MM, "--rows", rows, "--out", s(&out)];
        refused(&args, &["--rows", why]);
    }
    // Enough for the option, too few for a gpi model of 21 operators.
    let args = [
        "calibrate",
        "--kind",
        "gpi",
        "--rig",
        MM,
        "--rows",
        "3152-3181",
        "--out",
        s(&out),
    ];
    refused(
        &args,
        &["--rows 3152-3181: 30 rows; a gpi fit of 21 operators needs at least 42"],
    );
    assert!(!out.exists());
}

/// Item 8: a negative dead-zone softness in a model file is refused by key and value.
#[test]
fn a_negative_softness_is_refused() {
    let d = dir("softness");
    let m = model(
        &d,
        "soft.toml",
        &[("dead_zone_softness_v = 0.0", "dead_zone_softness_v = -1.5")],
    );
    let out = d.join("p.csv");
    let args = [
        "predict",
        "--model",
        s(&m),
        "--fem",
        FEM,
        "--drive",
        RUN,
        "--out",
        s(&out),
    ];
    refused(
        &args,
        &["soft.toml", "dead_zone_softness_v = -1.5: must be ≥ 0 V"],
    );
}

/// Plausibility warnings carry the number, line and column that triggered them,
/// and predict, export and compare print them.
#[test]
fn implausible_fem_values_are_warned_with_their_number() {
    let d = dir("warnings");
    let m = model(&d, "m.toml", &[]);
    let fem = write(
        &d.join("fem.csv"),
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n6,90,31\n12,3000,63.5\n",
    );
    let want = "warning: ";
    let number = "fem.csv:4: column preload_N: 3000 N";
    let p = d.join("p.csv");
    let text = ok(&[
        "predict",
        "--model",
        s(&m),
        "--fem",
        s(&fem),
        "--drive",
        RUN,
        "--out",
        s(&p),
    ]);
    assert!(text.contains(want) && text.contains(number), "{text}");
    let fw = d.join("fw.toml");
    let o = fpi(&[
        "export",
        "--model",
        s(&m),
        "--fem",
        s(&fem),
        "--out",
        s(&fw),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(want) && err.contains(number), "{err}");
    let cmp = d.join("cmp");
    let text = ok(&[
        "compare",
        "--fem",
        s(&fem),
        "--runs",
        RUN,
        "--model",
        s(&m),
        "--out",
        s(&cmp),
    ]);
    assert!(text.contains(want) && text.contains(number), "{text}");
}
