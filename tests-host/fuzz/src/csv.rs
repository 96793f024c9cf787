//! The datasets' readers on arbitrary bytes, through their public entry points.
//!
//! Input: one selector byte, then the file's bytes. The bytes are written to a
//! scratch file of this process (the readers take a path: `read_drive`,
//! `read_target` and `FemMaps::read` have no in-memory form, and their row types
//! are private) and read back with the reader the selector names:
//!
//! | `(sel & 0x7f) % 7` | reader |
//! |---|---|
//! | 0 | `data::read_rig` (`t_s,voltage_V,force_N,displacement_um`) |
//! | 1 | `data::read_stage` (`t_s,voltage_V,force_N,x_fhps_um[,…]`) |
//! | 2 | `data::read_drive` (`t_s,voltage_V`) |
//! | 3 | `data::read_target` (`t_s,x_fhps_um`) |
//! | 4 | `FemMaps::read` (`read_fem`, range, monotonicity, plausibility), then the maps |
//! | 5 | `data::read_micromanipulator` (tab-separated, no header) |
//! | 6 | `data::read_points` (`x_ref_um`, `fpi board stream`) |
//!
//! `sel & 0x80`: the file is named `….csv.gz`, so the bytes go through the gzip
//! reader (`read_bytes`) first.
//!
//! Checked: a reader either refuses with an error that names the file, or returns
//! what it promises: at least one row, every number finite, columns of one length,
//! time strictly increasing; FEM maps whose lookups inside the table stay finite
//! and whose inverse (`stack_for`) lands inside the table.

use std::path::{Path, PathBuf};

use fpi_host::data::read_points;
use fpi_host::data::fem::FemMaps;
use fpi_host::data::{
    read_drive, read_micromanipulator, read_rig, read_stage, read_target, DataError,
};
use piezo_fpi::q::SIGNAL_ABS_MAX;

/// The readers the selector chooses from.
pub const READERS: u8 = 7;

/// This process's scratch file (`gz`: named `.csv.gz`).
fn scratch(gz: bool) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("fpi-fuzz-csv-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    dir.join(if gz { "input.csv.gz" } else { "input.csv" })
}

/// One input: selector byte, then the file.
pub fn run(input: &[u8]) {
    let Some((&sel, bytes)) = input.split_first() else {
        return;
    };
    let path = scratch(sel & 0x80 != 0);
    std::fs::write(&path, bytes).expect("the scratch file is writable");
    let _ = read(&path, sel);
}

/// Reads `path` with the reader `sel` names and checks the outcome; whether the
/// reader accepted the file.
pub fn read(path: &Path, sel: u8) -> bool {
    match (sel & 0x7f) % READERS {
        0 => ok(path, read_rig(path)).map(|r| columns(&r.t, &[&r.u, &r.f, &r.x])),
        1 => ok(path, read_stage(path)).map(|r| columns(&r.t, &[&r.u, &r.f, &r.x])),
        2 => ok(path, read_drive(path)).map(|(t, u)| columns(&t, &[&u])),
        3 => ok(path, read_target(path)).map(|(t, x)| columns(&t, &[&x])),
        4 => ok(path, FemMaps::read(path)).map(|maps| fem(&maps)),
        5 => ok(path, read_micromanipulator(path)).map(|m| {
            assert_eq!(m.u.len(), m.sensor.len(), "columns of different lengths");
            assert!(
                m.u.iter().chain(&m.sensor).all(|v| v.is_finite()),
                "a non-finite value read"
            );
        }),
        _ => match read_points(path) {
            Ok(p) => {
                assert!(!p.is_empty(), "no points without an error");
                assert!(p.iter().all(|v| v.is_finite()), "a non-finite point read");
                Some(())
            }
            Err(e) => {
                named(path, &format!("{e:#}"));
                None
            }
        },
    }
    .is_some()
}

/// The value, or `None` after checking that the error names the file.
fn ok<T>(path: &Path, r: Result<T, DataError>) -> Option<T> {
    match r {
        Ok(v) => Some(v),
        Err(e) => {
            assert_eq!(e.file, path, "the error names another file: {e:?}");
            named(path, &e.to_string());
            None
        }
    }
}

fn named(path: &Path, message: &str) {
    let p = path.display().to_string();
    assert!(
        message.starts_with(&p),
        "the error does not name the file: {message}"
    );
}

/// A recording: rows, all finite, time strictly increasing, columns of one length.
fn columns(t: &[f64], others: &[&Vec<f64>]) {
    assert!(!t.is_empty(), "no rows without an error");
    assert!(
        t.windows(2).all(|w| w[1] > w[0]),
        "the time column does not increase"
    );
    for c in others {
        assert_eq!(c.len(), t.len(), "columns of different lengths");
    }
    assert!(
        t.iter()
            .chain(others.iter().flat_map(|c| c.iter()))
            .all(|v| v.is_finite()),
        "a non-finite value read"
    );
}

/// FEM maps `FemMaps::read` accepted: every lookup inside the table is finite and
/// the inverse kinematics lands inside the table (within rounding).
pub fn fem(maps: &FemMaps) {
    let x = maps.x_pea();
    assert!(x.len() >= 2, "an FEM table of {} points", x.len());
    assert!(
        x.windows(2).all(|w| w[1] > w[0]),
        "x_pea_um does not increase"
    );
    assert!(
        x.iter().all(|v| v.abs() <= SIGNAL_ABS_MAX),
        "an x_pea_um beyond ±{SIGNAL_ABS_MAX}"
    );
    let (lo, hi) = (x[0], maps.x_pea_max());
    let mut probes = vec![lo, hi, 0.5 * (lo + hi)];
    probes.extend(x.iter().take(64));
    probes.extend(x.windows(2).take(64).map(|w| 0.5 * (w[0] + w[1])));
    for &p in &probes {
        let (f, s) = maps.preload_with_slope(p);
        assert!(f.is_finite() && s.is_finite(), "f_F({p}) = {f}, slope {s}");
        assert!(maps.preload_at(p).is_finite(), "f_F({p}) is not finite");
        let y = maps.stage_at(p);
        assert!(y.is_finite(), "f_K({p}) = {y}");
        let back = maps.stack_for(y);
        let tol = 1e-6 * (hi - lo).max(1.0);
        assert!(
            back >= lo - tol && back <= hi + tol,
            "f_K⁻¹(f_K({p})) = {back}, outside the table {lo}..{hi}"
        );
    }
    // Outside the table and NaN: no panic (values extrapolate or hold).
    for p in [lo - 1.0, hi + 1.0, f64::NAN] {
        let _ = maps.preload_with_slope(p);
        let _ = maps.stage_at(p);
        let _ = maps.stack_for(p);
    }
    assert!(maps.rest_preload().is_finite() || !(lo..=hi).contains(&0.0));
    let _ = maps.warnings();
}
