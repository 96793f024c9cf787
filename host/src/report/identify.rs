//! The figure of an identification of the stage's dynamics (`fpi identify
//! --plots`): measured and fitted frequency responses and their coherence.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use anyhow::Result;
use nalgebra::Complex;

use crate::method::compare::run_file_name;
use crate::method::identify::Identification;
use crate::report::plots::{bode, BodeSeries};

/// Writes the figures of an identification into `dir`: `bode.svg` (measured and
/// fitted magnitude and phase, and the coherence, of every chirp).
pub fn plots(id: &Identification, dir: &Path) -> Result<Vec<PathBuf>> {
    let names: Vec<String> = id
        .responses
        .iter()
        .map(|r| run_file_name(&r.path))
        .collect();
    let fitted: Vec<(Vec<f64>, Vec<Complex<f64>>)> = id
        .responses
        .iter()
        .map(|r| {
            let (lo, hi) = r.band();
            let f = log_grid(lo, hi, 400);
            let h = f
                .iter()
                .map(|&f| id.unit.at(Complex::new(0.0, 2.0 * PI * f)) * r.gain)
                .collect();
            (f, h)
        })
        .collect();
    let series: Vec<BodeSeries> = id
        .responses
        .iter()
        .zip(&fitted)
        .zip(&names)
        .map(|((r, (ff, fh)), name)| BodeSeries {
            name,
            f_hz: r.kept.iter().map(|&k| r.frf.f_hz[k]).collect(),
            h: r.kept.iter().map(|&k| r.frf.h[k]).collect(),
            fit_f_hz: ff.clone(),
            fit_h: fh.clone(),
            coherence_f_hz: r.frf.f_hz.clone(),
            coherence: r.frf.coherence.clone(),
        })
        .collect();
    let path = dir.join("bode.svg");
    bode(
        &path,
        "Stage dynamics: voltage → x_fhps (measured points, fitted lines)",
        &series,
    )?;
    Ok(vec![path])
}

/// `n` frequencies from `lo` to `hi`, evenly spaced on a log axis.
fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let (a, b) = (lo.max(1e-6).ln(), hi.max(lo).ln());
    (0..n)
        .map(|k| (a + (b - a) * k as f64 / (n - 1) as f64).exp())
        .collect()
}
