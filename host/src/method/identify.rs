//! Frequency-domain identification of the stage's dynamics from chirps (second
//! paper, Levy & Shapiro 2022, section 4.2): `fpi identify`.
//!
//! 1. **Frequency response** voltage → `x_fhps_um` of each chirp: Welch's averaged
//!    cross and auto spectra (Hann window, half-overlapping segments of a quarter
//!    of the record, each detrended by its least-squares line), `H = Pxy/Pxx`,
//!    with the magnitude-squared coherence `γ² = |Pxy|²/(Pxx·Pyy)`. Points with
//!    `γ² ≥` [`MIN_COHERENCE`] where the chirp put power (`Pxx` within
//!    [`MIN_POWER`] of its largest) are kept. Each chirp's response is divided by
//!    its static gain (the mean of its lowest kept points) and the chirps are
//!    pooled: the paper's "uniform, normalised" transfer function.
//! 2. **Fit** of a rational `G(s) = B(s)/A(s)` to the pooled points, in the scaled
//!    variable `s/ω0` (`ω0` the highest fitted frequency) for conditioning:
//!    equation error `Σ w|H·A − B|²` as `invfreqs` (linear least squares, `A`
//!    monic), re-weighted by `1/|A|` of the previous solution
//!    (Sanathanan–Koerner) a few times, unstable roots reflected into the left
//!    half-plane; then damped Gauss–Newton (Levenberg–Marquardt) on the output
//!    error `Σ w|H − B/A|²`, refusing steps that make `A` unstable. The weight is
//!    `w = γ²/|H|²`: a coherence-weighted *relative* error, so the roll-off above
//!    the mode counts as much as the plateau.
//! 3. **Order**: every structure of 0–3 modes (complex pole pairs, with `2m − 2`
//!    numerator zeros between them) with and without a real pole (the amplifier's
//!    lag) is fitted. [`CRITERION`]: the structure with the fewest parameters
//!    whose weighted RMS relative error is within 10 % of the best candidate's.
//!    Akaike's criterion is printed beside it.
//! 4. **Gains** (eq. 13): each chirp's static gain is the least-squares factor
//!    between its response and the unit-DC-gain model; a polynomial of up to
//!    second degree in the drive's span (peak to peak) is fitted to them. The
//!    file's transfer function carries the gain of the chirp reaching highest in
//!    frequency (the small-signal one that identifies the mode).
//! 5. **Capacitance** (eq. 14): `i = C·du/dt` fitted on the `current_mA` column
//!    in the frequency domain, through the amplifier's lag ([`capacitance`]).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use nalgebra::{Complex, DMatrix, DVector};
use realfft::RealFftPlanner;
use serde::Deserialize;

use crate::data::{self, DataError, Finite};
use crate::method::dynamics::{
    self, modes_of, real_poles_of, Dynamics, FitInfo, TransferFunction, VoltageGain,
};

mod chirp;
use chirp::prev_pow2;
pub use chirp::{read_chirp, response, welch, Chirp, ChirpResponse, Frf};
mod rational;
use rational::solve_scaled;
pub use rational::{
    candidates, cost, equation_error, fit, output_error, Candidate, Point, Rational, Structure,
};

/// Least magnitude-squared coherence of a fitted frequency point.
pub const MIN_COHERENCE: f64 = 0.9;

/// Least input power of a fitted point, relative to the chirp's largest `Pxx`.
pub const MIN_POWER: f64 = 1e-4;

/// The transfer function is fitted on the chirps whose band reaches at least this
/// fraction of the highest band; the others (slow, large chirps: quasi-static,
/// their response is hysteresis and creep, which the FPI model holds) give only
/// their static gain (eq. 13).
pub const DYNAMIC_BAND: f64 = 0.5;

/// Default lowest frequency of the transfer-function fit, Hz: below it the stage's
/// response is the rate-independent model's (hysteresis and creep, a few degrees
/// of phase and a gain that falls with frequency), which the FPI model holds;
/// fitted as poles, it would be counted twice.
pub const MIN_DYNAMICS_HZ: f64 = 20.0;

/// Lowest kept points of a chirp whose mean response is its provisional static
/// gain.
const GAIN_POINTS: usize = 5;

/// The order criterion, as stated in the file and the book (`docs/src/dynamics.md`).
pub const CRITERION: &str = "fewest parameters within 10 % of the best weighted RMS \
                             relative error (0-3 modes, with or without a real pole)";

/// Relative margin of [`CRITERION`].
const CRITERION_MARGIN: f64 = 0.10;

/// Least damping ratio of an admissible mode: below it a "mode" is a fitting
/// artefact (an undamped pole pair standing for a delay).
pub const MIN_DAMPING: f64 = 1e-3;

/// Why candidate `c` (fitted with scale `w0`, rad/s) is not admissible, if it is
/// not: the data identify no mode above the fitted band `band_hz` (+20 %) or
/// with `ζ <` [`MIN_DAMPING`], no pole below the band (such a pole models
/// the quasi-static response, and makes the DC gain arbitrary), and no real pole
/// more than ten times above it (a pole and a zero standing for a constant).
pub fn inadmissible(c: &Candidate, w0: f64, band_hz: (f64, f64)) -> Option<String> {
    let poles = c.model.unscaled(w0).poles();
    let low = |f: f64| f < band_hz.0;
    let bad_mode = modes_of(&poles).into_iter().find_map(|(f, z)| {
        if f > 1.2 * band_hz.1 {
            Some(format!("mode at {f:.0} Hz above the band"))
        } else if low(f) {
            Some(format!("mode at {f:.1} Hz below the band"))
        } else if z < MIN_DAMPING {
            Some(format!("mode at {f:.0} Hz with ζ {z:.1e}"))
        } else {
            None
        }
    });
    bad_mode.or_else(|| {
        real_poles_of(&poles).into_iter().find_map(|f| {
            if low(f) {
                Some(format!("real pole at {f:.2} Hz below the band"))
            } else if f > 10.0 * band_hz.1 {
                Some(format!("real pole at {f:.3e} Hz far above the band"))
            } else {
                None
            }
        })
    })
}

/// The poles of a candidate in words: `"850.7 Hz ζ 0.0299, 2141.6 Hz real"`.
pub fn describe(c: &Candidate, w0: f64) -> String {
    let poles = c.model.unscaled(w0).poles();
    let mut parts: Vec<String> = modes_of(&poles)
        .iter()
        .map(|(f, z)| format!("{f:.1} Hz ζ {z:.4}"))
        .collect();
    parts.extend(
        real_poles_of(&poles)
            .iter()
            .map(|f| format!("{f:.1} Hz real")),
    );
    if parts.is_empty() {
        "-".into()
    } else {
        parts.join(", ")
    }
}

/// The candidate [`CRITERION`] picks among the admissible ones (`ok`).
pub fn choose<'a>(c: &'a [Candidate], ok: &[bool]) -> Option<&'a Candidate> {
    let admissible = || c.iter().zip(ok).filter(|(_, &o)| o).map(|(k, _)| k);
    let best = admissible().map(|k| k.rms).fold(f64::INFINITY, f64::min);
    admissible()
        .filter(|k| k.rms <= best * (1.0 + CRITERION_MARGIN))
        .min_by(|a, b| {
            (a.structure.parameters(), a.rms)
                .partial_cmp(&(b.structure.parameters(), b.rms))
                .unwrap_or(std::cmp::Ordering::Equal)
        })
}

/// Eq. 14: the capacitance `C` (µF) of `i = C·du/dt` over the chirps with a
/// current column, and the weighted RMS relative error of the fit. Fitted in the
/// frequency domain: the Welch response `u → i` (mA/V) against `C·jω·L(jω)`,
/// coherence-weighted relative least squares over the points with `γ² ≥`
/// [`MIN_COHERENCE`]. `L` is the amplifier's lag, a first-order low-pass at
/// `lag_hz` when the dynamics have one: the current follows the stack's voltage,
/// not the command. (A time-domain fit on a finite-difference `du/dt` would be
/// biased: at 3 kHz and 20 kHz sampling the central difference is 14 % low.)
pub fn capacitance(chirps: &[Chirp], lag_hz: Option<f64>) -> Option<(f64, f64)> {
    let mut pts: Vec<(Complex<f64>, Complex<f64>, f64)> = vec![];
    for c in chirps {
        let Some(i) = &c.current_ma else { continue };
        let frf = welch(&c.u, i, c.dt, prev_pow2(c.u.len() / 4).max(256));
        let top = frf.pxx.iter().copied().fold(0.0, f64::max);
        for k in 0..frf.f_hz.len() {
            let f = frf.f_hz[k];
            if frf.coherence[k] < MIN_COHERENCE || frf.pxx[k] < MIN_POWER * top || f > 0.4 / c.dt {
                continue;
            }
            let s = Complex::new(0.0, 2.0 * PI * f);
            let lag = lag_hz.map_or(Complex::new(1.0, 0.0), |fl| {
                1.0 / (1.0 + s / (2.0 * PI * fl))
            });
            // mA per V for C = 1 µF.
            pts.push((s * lag * 1e-3, frf.h[k], frf.coherence[k]));
        }
    }
    let (mut num, mut den) = (0.0, 0.0);
    for (g, h, c) in &pts {
        let w = c / h.norm_sqr();
        num += w * (g.conj() * h).re;
        den += w * g.norm_sqr();
    }
    if pts.is_empty() || den <= 0.0 {
        return None;
    }
    let c_uf = num / den;
    let (mut se, mut ws) = (0.0, 0.0);
    for (g, h, c) in &pts {
        se += c * ((h - g * c_uf) / h).norm_sqr();
        ws += c;
    }
    Some((c_uf, (se / ws).sqrt()))
}

/// Least-squares polynomial (ascending, `terms` coefficients) through `(x, y)`.
fn polyfit(x: &[f64], y: &[f64], terms: usize) -> Option<Vec<f64>> {
    let m = DMatrix::from_fn(x.len(), terms, |i, j| x[i].powi(j as i32));
    let rhs = DVector::from_column_slice(y);
    solve_scaled(m, &rhs).map(|v| v.iter().copied().collect())
}

/// The whole identification.
#[derive(Debug, Clone)]
pub struct Identification {
    /// The result, as written to `DYN.toml`.
    pub dynamics: Dynamics,
    /// Each chirp's response.
    pub responses: Vec<ChirpResponse>,
    /// Every structure fitted.
    pub candidates: Vec<Candidate>,
    /// Index of the chosen one.
    pub chosen: usize,
    /// Why each candidate is not admissible (`None`: it is).
    pub rejected: Vec<Option<String>>,
    /// The unit-DC-gain model in `s` (rad/s).
    pub unit: TransferFunction,
    /// The frequency scale of the fit, rad/s.
    pub w0: f64,
    /// Lowest and highest frequency of the transfer-function fit, Hz.
    pub fit_band_hz: (f64, f64),
    /// Each chirp's capacitance on its own, µF (`None`: no current column).
    pub capacitance_per_file: Vec<Option<f64>>,
}

/// Identifies the dynamics from `chirps`, the transfer function on the
/// frequencies from `min_hz` (Hz; [`MIN_DYNAMICS_HZ`] by default) up.
pub fn identify(chirps: &[Chirp], min_hz: f64) -> Result<Identification> {
    let mut responses: Vec<ChirpResponse> = chirps.iter().map(response).collect();
    for r in &responses {
        if r.kept.len() < 2 * GAIN_POINTS {
            bail!(
                "{}: {} frequency points with coherence ≥ {MIN_COHERENCE}: too few to fit \
                 (is x_fhps_um driven by voltage_V?)",
                r.path.display(),
                r.kept.len()
            );
        }
    }
    let top_hz = responses.iter().map(|r| r.band().1).fold(0.0, f64::max);
    let w0 = 2.0 * PI * top_hz;
    let dynamic: Vec<ChirpResponse> = responses
        .iter()
        .filter(|r| r.band().1 >= DYNAMIC_BAND * top_hz)
        .cloned()
        .collect();
    let pts = pooled(&dynamic, w0, min_hz)?;
    let candidates = candidates(&pts);
    let fit_band = (
        pts.iter()
            .map(|p| p.s.im * w0 / (2.0 * PI))
            .fold(f64::INFINITY, f64::min),
        top_hz,
    );
    let rejected: Vec<Option<String>> = candidates
        .iter()
        .map(|c| inadmissible(c, w0, fit_band))
        .collect();
    let ok: Vec<bool> = rejected.iter().map(Option::is_none).collect();
    let chosen = choose(&candidates, &ok)
        .map(|c| c.structure)
        .and_then(|s| candidates.iter().position(|c| c.structure == s))
        .ok_or_else(|| anyhow::anyhow!("no model structure could be fitted"))?;
    let unit = candidates[chosen].model.unscaled(w0).unit_dc();
    for r in &mut responses {
        r.gain = projected_gain(r, &unit);
    }
    let lag_hz = real_poles_of(&unit.poles()).last().copied();
    let dynamics = assemble(&responses, &candidates[chosen], &unit, chirps, lag_hz)?;
    let capacitance_per_file = chirps
        .iter()
        .map(|c| capacitance(std::slice::from_ref(c), lag_hz).map(|x| x.0))
        .collect();
    Ok(Identification {
        dynamics,
        responses,
        candidates,
        chosen,
        rejected,
        unit,
        w0,
        fit_band_hz: fit_band,
        capacitance_per_file,
    })
}

/// The kept points from `min_hz` (Hz) up of every chirp, each divided by its
/// provisional static gain (the mean response of its lowest such points).
fn pooled(responses: &[ChirpResponse], w0: f64, min_hz: f64) -> Result<Vec<Point>> {
    let mut pts = vec![];
    for r in responses {
        let kept: Vec<usize> = r
            .kept
            .iter()
            .copied()
            .filter(|&k| r.frf.f_hz[k] >= min_hz)
            .collect();
        if kept.len() < 4 * GAIN_POINTS {
            bail!(
                "{}: {} coherent frequency points from {min_hz} Hz up: too few to fit the \
                 dynamics (lower --min-hz?)",
                r.path.display(),
                kept.len()
            );
        }
        let g = kept[..GAIN_POINTS]
            .iter()
            .map(|&k| r.frf.h[k])
            .sum::<Complex<f64>>()
            .norm()
            / GAIN_POINTS as f64;
        pts.extend(kept.iter().map(|&k| Point {
            s: Complex::new(0.0, 2.0 * PI * r.frf.f_hz[k] / w0),
            h: r.frf.h[k] / g,
            coherence: r.frf.coherence[k],
        }));
    }
    Ok(pts)
}

/// The weighted least-squares factor `K` of `H ≈ K·G` over the kept points.
fn projected_gain(r: &ChirpResponse, unit: &TransferFunction) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for &k in &r.kept {
        let g = unit.at(Complex::new(0.0, 2.0 * PI * r.frf.f_hz[k]));
        let h = r.frf.h[k];
        let w = r.frf.coherence[k] / h.norm_sqr();
        num += w * (g.conj() * h).re;
        den += w * g.norm_sqr();
    }
    num / den
}

/// The file's content from the chosen candidate.
fn assemble(
    responses: &[ChirpResponse],
    chosen: &Candidate,
    unit: &TransferFunction,
    chirps: &[Chirp],
    lag_hz: Option<f64>,
) -> Result<Dynamics> {
    let reference = responses
        .iter()
        .max_by(|a, b| a.band().1.total_cmp(&b.band().1))
        .map_or(1.0, |r| r.gain);
    let tf = TransferFunction {
        numerator: unit.numerator.iter().map(|c| c * reference).collect(),
        denominator: unit.denominator.clone(),
    };
    let poles = tf.poles();
    let modes = modes_of(&poles);
    let Some((c_uf, i_rms)) = capacitance(chirps, lag_hz) else {
        bail!("no chirp has a current_mA column: the capacitance (eq. 14) cannot be identified");
    };
    let lo = responses
        .iter()
        .map(|r| r.band().0)
        .fold(f64::INFINITY, f64::min);
    let hi = responses.iter().map(|r| r.band().1).fold(0.0, f64::max);
    Ok(Dynamics {
        format: dynamics::FORMAT.to_string(),
        natural_frequency_hz: modes.iter().map(|m| m.0).collect(),
        damping_ratio: modes.iter().map(|m| m.1).collect(),
        capacitance_uf: c_uf,
        dc_gain_um_per_v: tf.dc_gain(),
        real_pole_hz: real_poles_of(&poles),
        voltage_gain: voltage_gain(responses),
        fit: Some(FitInfo {
            files: chirps
                .iter()
                .map(|c| c.path.display().to_string())
                .collect(),
            band_hz: [lo, hi],
            points: responses.iter().map(|r| r.kept.len()).sum(),
            criterion: CRITERION.to_string(),
            modes: chosen.structure.modes,
            real_poles: chosen.structure.lag,
            rms_relative_error: chosen.rms,
            aic: chosen.aic,
            current_rms_relative_error: i_rms,
        }),
        transfer_function: tf,
    })
}

/// Eq. 13: the static gains against the drive spans, and a polynomial through
/// them (as many terms as chirps, at most three).
fn voltage_gain(responses: &[ChirpResponse]) -> Option<VoltageGain> {
    let span_v: Vec<f64> = responses.iter().map(|r| r.span_v).collect();
    let gain: Vec<f64> = responses.iter().map(|r| r.gain).collect();
    let coefficients = polyfit(&span_v, &gain, responses.len().min(3))?;
    Some(VoltageGain {
        span_v,
        gain_um_per_v: gain,
        coefficients,
    })
}

/// The lines `fpi identify` prints: each chirp's band and gain, every candidate
/// structure with its scores (the chosen one marked), the modes, the gains of
/// eq. 13 and the capacitance of eq. 14.
pub fn summary(id: &Identification) -> Vec<String> {
    let mut out = vec![format!(
        "  {:<34} {:>7} {:>17} {:>8} {:>13} {:>9}",
        "chirp", "points", "band Hz", "span V", "gain µm/V", "C µF"
    )];
    for (r, c) in id.responses.iter().zip(&id.capacitance_per_file) {
        let (lo, hi) = r.band();
        let name = r
            .path
            .file_name()
            .map_or(String::new(), |n| n.to_string_lossy().to_string());
        let cap = c.map_or("-".to_string(), |v| format!("{v:.4}"));
        out.push(format!(
            "  {name:<34} {:>7} {:>8.1}-{:<8.1} {:>8.2} {:>13.5} {cap:>9}",
            r.kept.len(),
            lo,
            hi,
            r.span_v,
            r.gain
        ));
    }
    out.push(format!(
        "structures fitted on {:.1}-{:.1} Hz ({CRITERION}):",
        id.fit_band_hz.0, id.fit_band_hz.1
    ));
    out.push(format!(
        "  {:>5} {:>4} {:>6} {:>12} {:>12}  poles",
        "modes", "lag", "params", "rms rel.err", "AIC"
    ));
    for (i, c) in id.candidates.iter().enumerate() {
        let mark = match &id.rejected[i] {
            _ if i == id.chosen => "  <- chosen".to_string(),
            Some(why) => format!("  (not admissible: {why})"),
            None => String::new(),
        };
        out.push(format!(
            "  {:>5} {:>4} {:>6} {:>12.5} {:>12.1}  {}{mark}",
            c.structure.modes,
            c.structure.lag,
            c.structure.parameters(),
            c.rms,
            c.aic,
            describe(c, id.w0)
        ));
    }
    let d = &id.dynamics;
    for (i, (f, z)) in d
        .natural_frequency_hz
        .iter()
        .zip(&d.damping_ratio)
        .enumerate()
    {
        out.push(format!(
            "  mode {}: natural_frequency_hz {f:.2}, damping_ratio {z:.5}",
            i + 1
        ));
    }
    for f in &d.real_pole_hz {
        out.push(format!("  real pole: {f:.1} Hz"));
    }
    out.push(format!("  dc_gain_um_per_v {:.5}", d.dc_gain_um_per_v));
    if let Some(g) = &d.voltage_gain {
        let terms: Vec<String> = g
            .coefficients
            .iter()
            .enumerate()
            .map(|(k, c)| match k {
                0 => format!("{c:.5}"),
                1 => format!("{c:+.4e}·V"),
                _ => format!("{c:+.4e}·V^{k}"),
            })
            .collect();
        out.push(format!("  eq. 13: gain(span V) = {} µm/V", terms.join(" ")));
    }
    let i_err = d
        .fit
        .as_ref()
        .map_or(f64::NAN, |f| f.current_rms_relative_error);
    out.push(format!(
        "  eq. 14: capacitance_uf {:.4} (i = C·du/dt through the lag; weighted RMS relative \
         error {:.2} %)",
        d.capacitance_uf,
        100.0 * i_err
    ));
    out
}

#[cfg(test)]
mod tests {
    use super::rational::poly_from_roots;
    use super::*;

    #[test]
    fn welch_of_a_gain_is_the_gain() {
        let u: Vec<f64> = (0..8192).map(|k| ((k * 7919) % 1013) as f64).collect();
        let y: Vec<f64> = u.iter().map(|v| 0.5 * v).collect();
        let frf = welch(&u, &y, 1e-3, 1024);
        assert_eq!(frf.segments, 15);
        for (h, c) in frf.h.iter().zip(&frf.coherence) {
            assert!((h - Complex::new(0.5, 0.0)).norm() < 1e-9 && (c - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn poly_from_roots_round_trip() {
        let a = poly_from_roots(&[Complex::new(-1.0, 2.0), Complex::new(-1.0, -2.0)]);
        assert_eq!(a, vec![5.0, 2.0, 1.0]);
    }
}
