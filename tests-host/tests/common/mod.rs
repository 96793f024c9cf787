//! What the command-line tests share: running the `fpi` binary
//! ([`fpi_tests::fpi_bin`], built once per test file) from
//! `tests-host/` and checking how it ended, and a scratch folder per test file.

#![allow(dead_code)] // each test file uses its own part

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the built `fpi` with `args` in `tests-host/`.
pub fn fpi(args: &[&str]) -> Output {
    Command::new(fpi_tests::fpi_bin())
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("running fpi")
}

/// Runs `fpi` expecting success; its stdout and stderr.
pub fn ok_split(args: &[&str]) -> (String, String) {
    let o = fpi(args);
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    );
    assert!(o.status.success(), "fpi {args:?} failed:\n{out}\n{err}");
    (out, err)
}

/// Runs `fpi` expecting success; its stdout followed by its stderr.
pub fn ok(args: &[&str]) -> String {
    let (out, err) = ok_split(args);
    format!("{out}{err}")
}

/// Runs `fpi` expecting a clean failure (non-zero exit, no panic); its stderr.
pub fn fails(args: &[&str]) -> String {
    let o = fpi(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success(), "fpi {args:?} should fail:\n{err}");
    assert!(!err.contains("panicked"), "fpi {args:?} panicked:\n{err}");
    err
}

/// [`fails`], and its stderr contains every one of `wanted`.
pub fn refused(args: &[&str], wanted: &[&str]) -> String {
    let err = fails(args);
    for w in wanted {
        assert!(err.contains(w), "fpi {args:?}: {w:?} not in:\n{err}");
    }
    err
}

/// A scratch folder `fpi-<name>-<pid>` in the system's temporary folder.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fpi-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A path as the `&str` a command line takes.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The rig recordings of the tests' quick fpi model (three preloads, 5 Hz).
pub const QUICK_RIG: [&str; 3] = [
    "data/pea-rig/preload_050N_sine_05Hz.csv.gz",
    "data/pea-rig/preload_100N_sine_05Hz.csv.gz",
    "data/pea-rig/preload_150N_sine_05Hz.csv.gz",
];

/// Calibrates the tests' quick fpi model on [`QUICK_RIG`] into `dir/fpi.toml`;
/// the model's path and what `fpi calibrate` printed.
pub fn quick_fpi(dir: &Path) -> (PathBuf, String) {
    let m = dir.join("fpi.toml");
    let mut args = vec!["calibrate", "--kind", "fpi", "--rig"];
    args.extend(QUICK_RIG);
    args.extend(["--out", s(&m)]);
    let printed = ok(&args);
    (m, printed)
}

/// The arguments of `fpi predict --model MODEL --fem FEM --drive DRIVE --out OUT`.
pub fn predict_args<'a>(
    model: &'a str,
    fem: &'a str,
    drive: &'a str,
    out: &'a str,
) -> [&'a str; 9] {
    [
        "predict", "--model", model, "--fem", fem, "--drive", drive, "--out", out,
    ]
}
