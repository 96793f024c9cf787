//! The safety issue's messages (item 14), as the commands give them: each names
//! the file, the key, the value as the file gave it and the rule.
//!
//! * a TOML error in a firmware model is a TOML error for `board load` and
//!   `board autotune` too (they called the file "a CSV table (header "# Firmware
//!   model: …"), not a model": its header comment holds commas);
//! * `w0_um_per_v = 1e308` is named with its file and key, as `1e308`;
//! * a `lag_hz` below `mode_hz` names both, with the rule;
//! * a stage variant's `mode_hz = 1e308` is `1e308`, not `inf`.

use std::path::{Path, PathBuf};

mod common;
use common::{refused, s};

fn tmp() -> PathBuf {
    common::scratch("messages")
}

/// The factory model's file (`firmware/model/stage-a.toml`) with `extra`
/// appended, written to `dir/name`: its path and its text's line count.
fn firmware_with(dir: &Path, name: &str, extra: &str) -> (PathBuf, usize) {
    let path = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(path).unwrap() + extra;
    let out = dir.join(name);
    std::fs::write(&out, &text).unwrap();
    (out, text.lines().count())
}

/// `fpi board --port virtual ARGS…`.
fn board<'a>(args: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["board", "--port", "virtual"];
    a.extend_from_slice(args);
    a
}

#[test]
fn a_toml_error_in_a_firmware_model_is_reported_as_one_by_every_command() {
    let d = tmp();
    // The factory model's last table has `x0` already: a duplicate key.
    let (dup, lines) = firmware_with(&d, "dup.toml", "x0 = 1.0\n");
    let want = format!("dup.toml:{lines}:1: not a ");
    for args in [
        board(&["load", s(&dup)]),
        board(&["autotune", s(&dup), "--out", s(&d.join("tuned.toml"))]),
        vec!["tune", "--firmware", s(&dup), "--out", s(&d.join("t.toml"))],
    ] {
        let err = refused(&args, &[&want, "duplicate key (in \"x0 = 1.0\")"]);
        assert!(!err.contains("CSV"), "{err}");
    }
    assert!(!d.join("tuned.toml").exists() && !d.join("t.toml").exists());
    // A CSV table is still named as one (by its first line of content).
    refused(
        &board(&["load", "data/stage-a/fem.csv.gz"]),
        &["fem.csv.gz: a CSV table", "an FEM table goes with --fem"],
    );
}

#[test]
fn a_weight_beyond_its_format_names_file_key_value_and_rule() {
    let d = tmp();
    let path = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("w0_um_per_v = "))
        .unwrap();
    let w0 = d.join("w0.toml");
    std::fs::write(&w0, text.replacen(line, "w0_um_per_v = 1e308", 1)).unwrap();
    let want = "w0.toml: pi.w0_um_per_v = 1e308: not a finite value within ±7.999 (I4F28 gain \
                range)";
    refused(&board(&["load", s(&w0)]), &[want]);
    refused(
        &["tune", "--firmware", s(&w0), "--out", s(&d.join("t.toml"))],
        &[want],
    );
    // A calibrated model's weight within the host's range but beyond the
    // firmware's: its export names the model file.
    let model = d.join("big-w0.toml");
    std::fs::write(
        &model,
        MODEL.replacen("w0_um_per_v = 0.0645", "w0_um_per_v = 9.5", 1),
    )
    .unwrap();
    refused(
        &[
            "export",
            "--model",
            s(&model),
            "--fem",
            "data/stage-a/fem.csv.gz",
            "--out",
            s(&d.join("fw.toml")),
        ],
        &[
            "big-w0.toml: its export does not meet the firmware's formats: pi.w0_um_per_v = 9.5: \
           not a finite value within ±7.999 (I4F28 gain range)",
        ],
    );
}

/// A calibrated fpi model (as `fpi calibrate --kind fpi` writes one).
const MODEL: &str = r#"format = "piezo-fpi-model/1"
kind = "fpi"
dead_zone_softness_v = 0.0
offset_um = 0.0

[pi]
w0_um_per_v = 0.0645
thresholds_v = [10.0, 20.0, 30.0]
weights_um_per_v = [0.006, 0.01, 0.005]
input_max_v = 150.0

[coupling]
offset_v = 0.0
k_f_v_per_n = 0.1
k_q_v_per_n2 = 0.0
force_q_n = 0.0
compliance_um_per_n = 0.0

[output]
map = "identity"

[calibration]
created_by = "tests/messages.rs"
files = []
rmse_um = 0.05
mte_um = 0.2
per_file = []
method = "by hand"
"#;

#[test]
fn a_lag_below_the_mode_names_both_keys_and_the_rule() {
    let d = tmp();
    let (lag, _) = firmware_with(
        &d,
        "lag.toml",
        "\n[dynamics]\nmode_hz = 850.0\ndamping_ratio = 0.03\nlag_hz = 300.0\n",
    );
    let want = "lag.toml: dynamics.lag_hz = 300: must be above dynamics.mode_hz = 850 (the lag's \
                corner lies above the mode; no lag: leave lag_hz out)";
    refused(&board(&["load", s(&lag)]), &[want]);
    refused(
        &["tune", "--firmware", s(&lag), "--out", s(&d.join("t.toml"))],
        &[want],
    );
}

#[test]
fn a_stage_variant_value_is_named_as_given() {
    let d = tmp();
    let v = d.join("variant.toml");
    std::fs::write(&v, "base = \"built\"\nmode_hz = 1e308\n").unwrap();
    refused(
        &board(&["bench", "--stage", s(&v)]),
        &["variant.toml: mode_hz = 1e308: must lie in [100, 5000]"],
    );
}
