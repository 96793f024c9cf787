//! The stage's dynamics from a frequency response measured through the board
//! (`fpi board frf`, `fpi board autotune`): the core's plant model
//! ([`piezo_fpi::stability::Plant`]: a real lag, the first mode, one tick of
//! delay) fitted to the responses from the command to the position sensor and
//! to the force channel's dynamic part.
//!
//! # The file
//!
//! `FRF.csv`, one row per frequency: `freq_hz`, then the real and imaginary parts
//! of each response — `x_re, x_im` (command → position sensor, µm/µm),
//! `force_re, force_im` (command → force reading, N/µm), `dynamic_re,
//! dynamic_im` (command → the force channel's dynamic part, N/µm), `x_per_v_re,
//! x_per_v_im` (setpoint → position sensor, µm/V) — and `excitation_um`, `ticks`
//! (how it was measured).
//!
//! # The fit
//!
//! For a mode `f`, damping `ζ` and lag `f_l`, the plant's responses at unit gain
//! and unit κ, `P_x` and `P_r` ([`super::loops::responses`]), are compared with
//! the measured ones: `H_x ≈ g·P_x` and `H_d ≈ κ·S·P_r` (`S` the force
//! channel's high-pass at the model's split; from a quarter of the peak's
//! frequency up, where the dynamic force stands above the sensor's noise), `g` and `κ` by linear least
//! squares for each `(f, ζ, f_l)`, which a pattern search in their logarithms
//! chooses by the relative misfit `Σ|H − Ĥ|²/|H|²` over both responses.

use std::f64::consts::TAU;
use std::path::Path;

use anyhow::{bail, Context, Result};
use nalgebra::Complex;
use piezo_fpi::damping::DynamicsSpec;
use piezo_fpi::q::{CreepRate, Newtons};
use piezo_fpi::stability::Plant;
use serde::{Deserialize, Serialize};

use super::loops::responses;

/// One measured frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrfPoint {
    /// Frequency, Hz.
    pub f_hz: f64,
    /// Command → position sensor, µm/µm.
    pub x: Complex<f64>,
    /// Command → force reading, N/µm.
    pub force: Complex<f64>,
    /// Command → the force channel's dynamic part, N/µm.
    pub dynamic: Complex<f64>,
    /// Setpoint → position sensor, µm/V.
    pub x_per_v: Complex<f64>,
    /// Excitation amplitude, µm.
    pub excitation_um: f64,
    /// Ticks correlated.
    pub ticks: u32,
}

/// A CSV row.
#[derive(Debug, Serialize, Deserialize)]
struct Row {
    freq_hz: f64,
    x_re: f64,
    x_im: f64,
    force_re: f64,
    force_im: f64,
    dynamic_re: f64,
    dynamic_im: f64,
    x_per_v_re: f64,
    x_per_v_im: f64,
    excitation_um: f64,
    ticks: u32,
}

/// Writes `points` as `FRF.csv`.
pub fn write_csv(path: &Path, points: &[FrfPoint]) -> Result<()> {
    let mut w =
        csv::Writer::from_path(path).with_context(|| format!("writing {}", path.display()))?;
    for p in points {
        w.serialize(Row {
            freq_hz: p.f_hz,
            x_re: p.x.re,
            x_im: p.x.im,
            force_re: p.force.re,
            force_im: p.force.im,
            dynamic_re: p.dynamic.re,
            dynamic_im: p.dynamic.im,
            x_per_v_re: p.x_per_v.re,
            x_per_v_im: p.x_per_v.im,
            excitation_um: p.excitation_um,
            ticks: p.ticks,
        })?;
    }
    w.flush()?;
    Ok(())
}

/// Reads `FRF.csv`; a bad row is named by its line and the field at fault.
pub fn read_csv(path: &Path) -> Result<Vec<FrfPoint>> {
    let shown = path.display();
    let mut r = csv::Reader::from_path(path).with_context(|| format!("reading {shown}"))?;
    let mut out = Vec::new();
    for (i, row) in r.deserialize::<Row>().enumerate() {
        let line = i + 2;
        let row = row.with_context(|| format!("{shown}:{line}"))?;
        let values = [
            ("freq_hz", row.freq_hz),
            ("x_re", row.x_re),
            ("x_im", row.x_im),
            ("dynamic_re", row.dynamic_re),
            ("dynamic_im", row.dynamic_im),
        ];
        if let Some((field, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
            bail!("{shown}:{line}: {field} = {v}: not a number");
        }
        if row.freq_hz.is_nan() || row.freq_hz <= 0.0 {
            bail!(
                "{shown}:{line}: freq_hz = {}: must be positive",
                row.freq_hz
            );
        }
        out.push(FrfPoint {
            f_hz: row.freq_hz,
            x: Complex::new(row.x_re, row.x_im),
            force: Complex::new(row.force_re, row.force_im),
            dynamic: Complex::new(row.dynamic_re, row.dynamic_im),
            x_per_v: Complex::new(row.x_per_v_re, row.x_per_v_im),
            excitation_um: row.excitation_um,
            ticks: row.ticks,
        });
    }
    if out.len() < 8 {
        bail!(
            "{shown}: {} frequencies: at least 8 are needed to fit the dynamics",
            out.len()
        );
    }
    Ok(out)
}

/// What the fit found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrfFit {
    /// The core's dynamics (mode, damping, lag, κ).
    pub spec: DynamicsSpec,
    /// Gain of the command → position response relative to 1 (the inverse
    /// model's accuracy at small signal).
    pub gain: f64,
    /// RMS relative misfit of the position response.
    pub x_misfit: f64,
    /// RMS relative misfit of the dynamic-force response.
    pub force_misfit: f64,
}

/// The fit in one line.
pub fn describe(f: &FrfFit) -> String {
    format!(
        "fitted to the board's response: mode {:.1} Hz, ζ {:.4}, lag {:.0} Hz, κ {:.2} N/µm, \
         gain {:.3} (RMS relative misfit {:.1} % position, {:.1} % force)",
        f.spec.mode_hz(),
        f.spec.damping_ratio(),
        f.spec.lag_mhz as f64 / 1000.0,
        f.spec.force_gain.to_num::<f64>(),
        f.gain,
        100.0 * f.x_misfit,
        100.0 * f.force_misfit
    )
}

/// The force channel's high-pass at `split` (its rate per tick) at `z⁻¹`.
fn highpass(split: f64, z1: Complex<f64>) -> Complex<f64> {
    let one = Complex::new(1.0, 0.0);
    (1.0 - split) * (one - z1) / (one - (1.0 - split) * z1)
}

/// The least-squares scalar `k` of `h ≈ k·p`, relative weights, and the summed
/// relative misfit.
fn scale(h: &[Complex<f64>], p: &[Complex<f64>]) -> (f64, f64) {
    let (mut num, mut den) = (0.0, 0.0);
    for (h, p) in h.iter().zip(p) {
        let w = 1.0 / h.norm_sqr().max(1e-30);
        num += w * (p.conj() * h).re;
        den += w * p.norm_sqr();
    }
    let k = if den > 0.0 { num / den } else { 0.0 };
    let misfit = h
        .iter()
        .zip(p)
        .map(|(h, p)| (h - k * p).norm_sqr() / h.norm_sqr().max(1e-30))
        .sum();
    (k, misfit)
}

/// The spec of `(f, ζ, f_l)` with κ.
fn spec(f_hz: f64, zeta: f64, lag_hz: f64, kappa: f64) -> DynamicsSpec {
    DynamicsSpec {
        mode_mhz: (f_hz * 1000.0).round() as u32,
        damping: CreepRate::from_num(zeta.clamp(1e-4, 0.49)),
        lag_mhz: (lag_hz * 1000.0).round() as u32,
        force_gain: Newtons::from_num(kappa.clamp(0.0, 4000.0)),
    }
}

/// Fits the dynamics to `points` measured at `rate_hz` with the force channel's
/// split rate `split` (per tick).
pub fn fit(points: &[FrfPoint], rate_hz: u32, split: f64) -> Result<FrfFit> {
    let fs = rate_hz as f64;
    let pts: Vec<&FrfPoint> = points.iter().filter(|p| p.f_hz < 0.45 * fs).collect();
    if pts.len() < 8 {
        bail!(
            "{} frequencies below 0.45·f_s: at least 8 are needed",
            pts.len()
        );
    }
    let z1: Vec<Complex<f64>> = pts
        .iter()
        .map(|p| Complex::from_polar(1.0, -TAU * p.f_hz / fs))
        .collect();
    let hx: Vec<Complex<f64>> = pts.iter().map(|p| p.x).collect();
    // The force's dynamic part is fitted where the split has let it through and
    // the mode makes it large (from a quarter of the position response's peak:
    // below, the force sensor's noise is of its size).
    let split_hz = -(1.0 - split).ln() * fs / TAU;
    let peak = pts
        .iter()
        .max_by(|a, b| a.x.norm().total_cmp(&b.x.norm()))
        .map_or(1000.0, |p| p.f_hz);
    let fi: Vec<usize> = (0..pts.len())
        .filter(|&i| pts[i].f_hz >= (5.0 * split_hz).max(0.25 * peak))
        .collect();
    let hd: Vec<Complex<f64>> = fi.iter().map(|&i| pts[i].dynamic).collect();
    let cost = |f: f64, z: f64, l: f64| -> (f64, f64, f64, f64, f64) {
        let d = spec(f, z, l, 1.0);
        let plant = Plant::new(&d, rate_hz, 1.0, None, 1.0);
        let (px, pr) = responses(&plant, &z1);
        let (g, mx) = scale(&hx, &px);
        let prs: Vec<Complex<f64>> = fi.iter().map(|&i| pr[i] * highpass(split, z1[i])).collect();
        let (k, mf) = scale(&hd, &prs);
        (mx + mf, g, k, mx, mf)
    };
    // Start: the peak of the position response, ζ from its height, a lag an
    // octave above the highest point.
    let low = pts.first().map_or(1.0, |p| p.x.norm()).max(1e-9);
    let height = pts.iter().map(|p| p.x.norm()).fold(0.0, f64::max) / low;
    let mut th = [
        peak.ln(),
        (0.5 / height.max(1.0)).clamp(0.003, 0.4).ln(),
        (2.0 * pts.last().map_or(2000.0, |p| p.f_hz))
            .min(0.45 * fs)
            .ln(),
    ];
    let bounds = [
        (pts[0].f_hz.ln(), (0.45 * fs).ln()),
        (0.002_f64.ln(), 0.45_f64.ln()),
        (100.0_f64.ln(), (0.45 * fs).ln()),
    ];
    let eval = |t: &[f64; 3]| cost(t[0].exp(), t[1].exp(), t[2].exp()).0;
    let mut best = eval(&th);
    let mut step = [0.2, 0.5, 0.5];
    for _ in 0..400 {
        let mut moved = false;
        for k in 0..3 {
            for dir in [1.0, -1.0] {
                let mut t = th;
                t[k] = (t[k] + dir * step[k]).clamp(bounds[k].0, bounds[k].1);
                let c = eval(&t);
                if c < best {
                    (best, th, moved) = (c, t, true);
                }
            }
        }
        if !moved {
            step.iter_mut().for_each(|s| *s *= 0.5);
            if step.iter().all(|s| *s < 1e-4) {
                break;
            }
        }
    }
    let (f, z, l) = (th[0].exp(), th[1].exp(), th[2].exp());
    let (_, g, k, mx, mf) = cost(f, z, l);
    if g.is_nan() || g <= 0.0 {
        bail!("the position response does not follow the command (gain {g:.3}): is the position sensor connected?");
    }
    Ok(FrfFit {
        spec: spec(f, z, l, k / g),
        gain: g,
        x_misfit: (mx / hx.len() as f64).sqrt(),
        force_misfit: (mf / hd.len().max(1) as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of the core's own plant (with a gain) are fitted back.
    #[test]
    fn the_plant_model_is_fitted_back() {
        let truth = spec(850.0, 0.03, 2000.0, 7.0);
        let rate = 20_000;
        let split = 1.0 - (-TAU * 10.0 / rate as f64).exp();
        let plant = Plant::new(&truth, rate, 1.0, None, 1.0);
        let f: Vec<f64> = (0..40)
            .map(|k| 20.0 * 200f64.powf(k as f64 / 39.0))
            .collect();
        let z1: Vec<Complex<f64>> = f
            .iter()
            .map(|f| Complex::from_polar(1.0, -TAU * f / rate as f64))
            .collect();
        let (px, pr) = responses(&plant, &z1);
        let pts: Vec<FrfPoint> = (0..f.len())
            .map(|i| FrfPoint {
                f_hz: f[i],
                x: 1.02 * px[i],
                force: pr[i],
                dynamic: 1.02 * pr[i] * highpass(split, z1[i]),
                x_per_v: px[i],
                excitation_um: 0.1,
                ticks: 1000,
            })
            .collect();
        let r = fit(&pts, rate, split).unwrap();
        assert!((r.spec.mode_hz() - 850.0).abs() < 1.0, "{r:?}");
        assert!((r.spec.damping_ratio() - 0.03).abs() < 0.001, "{r:?}");
        assert!(
            (r.spec.lag_mhz as f64 / 1000.0 - 2000.0).abs() < 40.0,
            "{r:?}"
        );
        assert!(
            (r.spec.force_gain.to_num::<f64>() - 7.0).abs() < 0.05,
            "{r:?}"
        );
        assert!((r.gain - 1.02).abs() < 0.002, "{r:?}");
    }
}
