//! `fpi calibrate` on recordings gone wrong (issue 13, item 5): errors where the
//! result would be meaningless, `warning: …` lines (kept in the model file) where
//! the data look like a unit slip, each naming the file, the column and the
//! number. The recordings are a pea-rig file with one thing changed.

use std::path::{Path, PathBuf};

use fpi_host::data;
use fpi_host::method::model::{HostModel, Kind};

const RIG: &str = "data/pea-rig/preload_050N_sine_05Hz.csv.gz";

mod common;
use common::{fails, ok_split as ok, s};

fn tmp() -> PathBuf {
    common::scratch("calibration-checks")
}

/// The pea-rig recording with `change(row, [t, u, f, x])` applied to every row,
/// written as `name` in the test's folder.
fn recording(name: &str, change: impl Fn(usize, &mut [f64; 4])) -> PathBuf {
    let r = data::read_rig(&Path::new(env!("CARGO_MANIFEST_DIR")).join(RIG)).unwrap();
    let mut text = String::from("t_s,voltage_V,force_N,displacement_um\n");
    for k in 0..r.t.len() {
        let mut v = [r.t[k], r.u[k], r.f[k], r.x[k]];
        change(k, &mut v);
        text += &format!("{},{},{},{}\n", v[0], v[1], v[2], v[3]);
    }
    let p = tmp().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn calibrate<'a>(rig: &'a Path, out: &'a Path, kind: Option<&'a str>) -> Vec<&'a str> {
    let mut a = vec!["calibrate", "--rig", s(rig), "--out", s(out)];
    if let Some(k) = kind {
        a.extend(["--kind", k]);
    }
    a
}

#[test]
fn a_huge_cell_is_an_error_naming_file_column_row_and_value() {
    let rig = recording("huge.csv", |k, v| {
        if k == 99 {
            v[1] = 1e308;
        }
    });
    let out = tmp().join("huge.toml");
    let e = fails(&calibrate(&rig, &out, Some("pi")));
    assert!(
        e.contains("huge.csv: voltage_V = 1.000e308 V at row 100: beyond ±4096 V"),
        "{e}"
    );
    assert!(!out.exists(), "no model written");
}

#[test]
fn a_constant_force_cannot_identify_k_f_and_the_default_falls_back_to_epi() {
    let rig = recording("constant-force.csv", |_, v| v[2] = 50.0);
    let out = tmp().join("constant-force.toml");
    for kind in ["efpi", "fpi", "ldpi"] {
        let e = fails(&calibrate(&rig, &out, Some(kind)));
        assert!(
            e.contains("force_N is constant (50 N in every fitted row of constant-force.csv)")
                && e.contains("cannot be identified"),
            "{kind}: {e}"
        );
    }
    assert!(!out.exists());
    let (stdout, stderr) = ok(&calibrate(&rig, &out, None));
    assert!(
        stderr.contains(
            "note: force_N is constant (50 N in every fitted row of constant-force.csv), so \
             k_f cannot be identified: calibrating epi instead of the default efpi"
        ),
        "{stderr}"
    );
    assert!(stdout.starts_with("epi model"), "{stdout}");
    assert_eq!(HostModel::read(&out).unwrap().kind, Kind::Epi);
}

#[test]
fn a_unit_slip_warns_and_the_model_keeps_the_warning() {
    // Decivolts: 0–1000 "V".
    let rig = recording("decivolts.csv", |_, v| v[1] *= 10.0);
    let out = tmp().join("decivolts.toml");
    let (_, stderr) = ok(&calibrate(&rig, &out, Some("pi")));
    let line = stderr
        .lines()
        .find(|l| l.starts_with("warning: decivolts.csv: voltage_V reaches 1000 V at row "))
        .unwrap_or_else(|| panic!("{stderr}"));
    assert!(
        line.contains("beyond the amplifier's 0–150 V (millivolts?)"),
        "{line}"
    );
    let m = HostModel::read(&out).unwrap();
    assert_eq!(
        m.calibration.warnings.len(),
        1,
        "{:?}",
        m.calibration.warnings
    );
    assert_eq!(
        format!("warning: {}", m.calibration.warnings[0]),
        line,
        "the model records what was printed"
    );

    // Kilonewtons: a force that barely varies.
    let rig = recording("kilonewtons.csv", |_, v| v[2] /= 1000.0);
    let out = tmp().join("kilonewtons.toml");
    let (_, stderr) = ok(&calibrate(&rig, &out, Some("fpi")));
    assert!(
        stderr.contains("warning: force_N spans only 0.0105 N (0.0496–0.0601 N)"),
        "{stderr}"
    );

    // Millimetres: hardly any motion.
    let rig = recording("millimetres.csv", |_, v| v[3] /= 1000.0);
    let out = tmp().join("millimetres.toml");
    let (_, stderr) = ok(&calibrate(&rig, &out, Some("pi")));
    assert!(
        stderr.contains("warning: millimetres.csv: displacement_um spans only 0.0082 µm"),
        "{stderr}"
    );
}

#[test]
fn plausible_data_calibrates_without_warnings() {
    let out = tmp().join("plain.toml");
    let (_, stderr) = ok(&["calibrate", "--kind", "fpi", "--rig", RIG, "--out", s(&out)]);
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(HostModel::read(&out)
        .unwrap()
        .calibration
        .warnings
        .is_empty());
}

#[test]
fn no_voltage_or_displacement_variation_is_an_error() {
    let rig = recording("still.csv", |_, v| v[1] = 0.0);
    let out = tmp().join("still.toml");
    let e = fails(&calibrate(&rig, &out, None));
    assert!(
        e.contains("voltage_V is constant (0 V in every fitted row of still.csv)"),
        "{e}"
    );
    let rig = recording("stuck.csv", |_, v| v[3] = 1.5);
    let e = fails(&calibrate(&rig, &out, Some("gpi")));
    assert!(
        e.contains("displacement_um is constant (0 µm in every fitted row of stuck.csv)"),
        "{e}"
    );
    assert!(!out.exists());
}
