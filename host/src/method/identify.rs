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

/// One chirp recording: `t_s,voltage_V,x_fhps_um[,current_mA]`.
#[derive(Debug, Clone)]
pub struct Chirp {
    /// Source file.
    pub path: PathBuf,
    /// Sample interval, s.
    pub dt: f64,
    /// Commanded voltage, V.
    pub u: Vec<f64>,
    /// Stage output, µm.
    pub x: Vec<f64>,
    /// Amplifier current, mA, when the file has the column.
    pub current_ma: Option<Vec<f64>>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
struct ChirpRow {
    t_s: f64,
    #[serde(rename = "voltage_V")]
    voltage_v: f64,
    x_fhps_um: f64,
    #[serde(rename = "current_mA", default)]
    current_ma: Option<f64>,
}

impl Finite for ChirpRow {
    fn non_finite(&self) -> Option<&'static str> {
        if !self.t_s.is_finite() {
            Some("t_s")
        } else if !self.voltage_v.is_finite() {
            Some("voltage_V")
        } else if !self.x_fhps_um.is_finite() {
            Some("x_fhps_um")
        } else if self.current_ma.is_some_and(|c| !c.is_finite()) {
            Some("current_mA")
        } else {
            None
        }
    }
}

/// Reads a chirp: uniformly sampled time (within 1 %), at least 1024 samples;
/// `current_mA` optional (but in every row or none).
pub fn read_chirp(path: &Path) -> Result<Chirp, DataError> {
    let (mut t, mut u, mut x, mut i) = (vec![], vec![], vec![], vec![]);
    let mut missing_current = None;
    let cols = ["t_s", "voltage_V", "x_fhps_um"];
    data::for_each_record(path, data::open(path)?, &cols, |r: ChirpRow| {
        match r.current_ma {
            Some(c) => i.push(c),
            None => missing_current = missing_current.or(Some(t.len())),
        }
        t.push(r.t_s);
        u.push(r.voltage_v);
        x.push(r.x_fhps_um);
    })?;
    data::strictly_increasing(path, "t_s", &t)?;
    if t.len() < 1024 {
        return Err(DataError::file(
            path,
            format!("{} samples: a chirp needs at least 1024", t.len()),
        ));
    }
    let dt = dynamics::uniform_step(&t).map_err(|(k, step, dt)| {
        let msg = format!("step {step} s differs from the mean {dt} s by more than 1 %");
        DataError::at(path, k as u64 + 3, "t_s", msg)
    })?;
    let current_ma = match missing_current {
        None => Some(i),
        Some(k) if !i.is_empty() => {
            let msg = "empty, while other rows have a current";
            return Err(DataError::at(path, k as u64 + 2, "current_mA", msg));
        }
        Some(_) => None,
    };
    Ok(Chirp {
        path: path.to_path_buf(),
        dt,
        u,
        x,
        current_ma,
    })
}

/// A frequency response estimated by Welch's method.
#[derive(Debug, Clone)]
pub struct Frf {
    /// Frequencies, Hz (bin 0 excluded).
    pub f_hz: Vec<f64>,
    /// `Pxy/Pxx`, µm/V.
    pub h: Vec<Complex<f64>>,
    /// Magnitude-squared coherence, 0..=1.
    pub coherence: Vec<f64>,
    /// Input auto spectrum `Pxx` (unscaled).
    pub pxx: Vec<f64>,
    /// Segments averaged.
    pub segments: usize,
}

/// Welch's estimate of the response `u → y` sampled every `dt` s, with segments
/// of `nperseg` samples (Hann window, half overlap, linear detrend).
pub fn welch(u: &[f64], y: &[f64], dt: f64, nperseg: usize) -> Frf {
    let n = u.len().min(y.len());
    let nperseg = nperseg.clamp(8, n.max(8));
    let window: Vec<f64> = (0..nperseg)
        .map(|k| 0.5 - 0.5 * (2.0 * PI * k as f64 / nperseg as f64).cos())
        .collect();
    let fft = RealFftPlanner::<f64>::new().plan_fft_forward(nperseg);
    let bins = nperseg / 2 + 1;
    let (mut pxx, mut pyy) = (vec![0.0; bins], vec![0.0; bins]);
    let mut pxy = vec![Complex::new(0.0, 0.0); bins];
    let mut segments = 0;
    let (mut xs, mut ys) = (fft.make_output_vec(), fft.make_output_vec());
    let mut start = 0;
    while start + nperseg <= n {
        let mut a = windowed(&u[start..start + nperseg], &window);
        let mut b = windowed(&y[start..start + nperseg], &window);
        // Lengths match the plan, so the transform cannot fail.
        let _ = fft.process(&mut a, &mut xs);
        let _ = fft.process(&mut b, &mut ys);
        for k in 0..bins {
            pxx[k] += xs[k].norm_sqr();
            pyy[k] += ys[k].norm_sqr();
            pxy[k] += xs[k].conj() * ys[k];
        }
        segments += 1;
        start += nperseg / 2;
    }
    let df = 1.0 / (nperseg as f64 * dt);
    let keep = 1..bins;
    Frf {
        f_hz: keep.clone().map(|k| k as f64 * df).collect(),
        h: keep.clone().map(|k| pxy[k] / pxx[k]).collect(),
        coherence: keep
            .clone()
            .map(|k| pxy[k].norm_sqr() / (pxx[k] * pyy[k]))
            .collect(),
        pxx: keep.map(|k| pxx[k]).collect(),
        segments,
    }
}

/// `v` less its least-squares line, times `window`.
fn windowed(v: &[f64], window: &[f64]) -> Vec<f64> {
    let n = v.len() as f64;
    let tm = (n - 1.0) / 2.0;
    let vm = v.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (k, &x) in v.iter().enumerate() {
        let d = k as f64 - tm;
        sxy += d * (x - vm);
        sxx += d * d;
    }
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    v.iter()
        .zip(window)
        .enumerate()
        .map(|(k, (&x, &w))| (x - vm - slope * (k as f64 - tm)) * w)
        .collect()
}

/// One chirp's response and what identification made of it.
#[derive(Debug, Clone)]
pub struct ChirpResponse {
    /// The chirp's file.
    pub path: PathBuf,
    /// Its Welch estimate.
    pub frf: Frf,
    /// Indices into `frf` of the fitted points.
    pub kept: Vec<usize>,
    /// Drive span (peak to peak over the last 90 % of the record), V.
    pub span_v: f64,
    /// Static gain: the least-squares factor between the response and the unit-DC
    /// model, µm/V.
    pub gain: f64,
}

impl ChirpResponse {
    /// Lowest and highest fitted frequency, Hz.
    pub fn band(&self) -> (f64, f64) {
        let f = |i: usize| self.frf.f_hz[i];
        match (self.kept.first(), self.kept.last()) {
            (Some(&a), Some(&b)) => (f(a), f(b)),
            _ => (f64::NAN, f64::NAN),
        }
    }
}

/// The frequency response of `c` and the points of it to fit.
pub fn response(c: &Chirp) -> ChirpResponse {
    let n = c.u.len();
    let nperseg = prev_pow2(n / 4).max(256);
    let frf = welch(&c.u, &c.x, c.dt, nperseg);
    let top = frf.pxx.iter().copied().fold(0.0, f64::max);
    let kept = (0..frf.f_hz.len())
        .filter(|&k| {
            frf.coherence[k] >= MIN_COHERENCE
                && frf.pxx[k] >= MIN_POWER * top
                && frf.f_hz[k] < 0.4 / c.dt
                && frf.h[k].norm() > 0.0
        })
        .collect();
    let tail = &c.u[n / 10..];
    let span_v = tail.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - tail.iter().copied().fold(f64::INFINITY, f64::min);
    ChirpResponse {
        path: c.path.clone(),
        frf,
        kept,
        span_v,
        gain: f64::NAN,
    }
}

fn prev_pow2(n: usize) -> usize {
    if n < 2 {
        1
    } else {
        1 << (usize::BITS - 1 - n.leading_zeros())
    }
}

/// A frequency point to fit: `s = jω/ω0`, response, weight.
#[derive(Debug, Clone, Copy)]
pub struct Point {
    /// Scaled Laplace variable `jω/ω0`.
    pub s: Complex<f64>,
    /// Measured response (normalised to unit static gain).
    pub h: Complex<f64>,
    /// Coherence `γ²`.
    pub coherence: f64,
}

impl Point {
    /// The fit weight `γ²/|H|²`.
    fn weight(&self) -> f64 {
        self.coherence / self.h.norm_sqr()
    }
}

/// A model structure: modes (complex pole pairs) and real poles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Structure {
    /// Second-order modes.
    pub modes: usize,
    /// Real poles (0 or 1: the amplifier's lag).
    pub lag: usize,
}

impl Structure {
    /// Denominator degree.
    pub fn na(&self) -> usize {
        2 * self.modes + self.lag
    }
    /// Numerator degree: zeros between the modes, and one with the real pole
    /// (so that it can stand for a delay, as a first-order Padé term).
    pub fn nb(&self) -> usize {
        (2 * self.modes).saturating_sub(2) + self.lag
    }
    /// Free parameters (the denominator is monic).
    pub fn parameters(&self) -> usize {
        self.nb() + 1 + self.na()
    }
}

/// A rational model in the scaled variable: `B(s')/A(s')`, ascending
/// coefficients, `A` monic.
#[derive(Debug, Clone, PartialEq)]
pub struct Rational {
    /// Numerator, ascending powers of `s'`.
    pub b: Vec<f64>,
    /// Denominator, ascending powers of `s'`, last = 1.
    pub a: Vec<f64>,
}

/// A polynomial with ascending coefficients at `s`.
fn poly_asc(c: &[f64], s: Complex<f64>) -> Complex<f64> {
    c.iter()
        .rev()
        .fold(Complex::new(0.0, 0.0), |acc, &k| acc * s + k)
}

impl Rational {
    /// `B(s)/A(s)`.
    pub fn at(&self, s: Complex<f64>) -> Complex<f64> {
        poly_asc(&self.b, s) / poly_asc(&self.a, s)
    }

    /// The transfer function in `s` (rad/s) for scale `w0` (rad/s), highest power
    /// first, the denominator monic.
    pub fn unscaled(&self, w0: f64) -> TransferFunction {
        let na = self.a.len() - 1;
        let up = |c: &[f64]| -> Vec<f64> {
            (0..c.len())
                .rev()
                .map(|i| c[i] * w0.powi((na - i) as i32))
                .collect()
        };
        let mut numerator = up(&self.b);
        while numerator.len() > 1 && numerator[0] == 0.0 {
            numerator.remove(0);
        }
        TransferFunction {
            numerator,
            denominator: up(&self.a),
        }
    }

    /// Whether every root of `A` lies in the open left half-plane.
    fn stable(&self) -> bool {
        let desc: Vec<f64> = self.a.iter().rev().copied().collect();
        dynamics::roots(&desc).iter().all(|p| p.re < 0.0)
    }
}

/// Weighted sum of squared output errors `Σ w|H − B/A|²`.
pub fn cost(r: &Rational, pts: &[Point]) -> f64 {
    pts.iter()
        .map(|p| p.weight() * (p.h - r.at(p.s)).norm_sqr())
        .sum()
}

/// Equation-error fit (`invfreqs`), then Sanathanan–Koerner re-weighting; unstable
/// roots reflected.
pub fn equation_error(pts: &[Point], st: Structure) -> Option<Rational> {
    let mut r = ee_solve(pts, st, None)?;
    for _ in 0..6 {
        r = ee_solve(pts, st, Some(&r.a)).unwrap_or(r);
    }
    Some(stabilise(r))
}

/// One linear least-squares solve of `Σ w/|A_prev|² · |H·A − B|²`.
fn ee_solve(pts: &[Point], st: Structure, prev: Option<&[f64]>) -> Option<Rational> {
    let (na, nb) = (st.na(), st.nb());
    let cols = nb + 1 + na;
    let mut m = DMatrix::<f64>::zeros(2 * pts.len(), cols);
    let mut rhs = DVector::<f64>::zeros(2 * pts.len());
    for (k, p) in pts.iter().enumerate() {
        let sk = prev.map_or(1.0, |a| poly_asc(a, p.s).norm());
        let w = p.weight().sqrt() / sk;
        let mut row = Vec::with_capacity(cols);
        row.extend((0..=nb).map(|i| -p.s.powu(i as u32) * w));
        row.extend((0..na).map(|i| p.h * p.s.powu(i as u32) * w));
        let r = -p.h * p.s.powu(na as u32) * w;
        for (j, v) in row.iter().enumerate() {
            m[(2 * k, j)] = v.re;
            m[(2 * k + 1, j)] = v.im;
        }
        rhs[2 * k] = r.re;
        rhs[2 * k + 1] = r.im;
    }
    let theta = solve_scaled(m, &rhs)?;
    Some(from_theta(&theta, st))
}

/// Least-squares solution of `m·θ = rhs` with the columns scaled to unit norm.
fn solve_scaled(mut m: DMatrix<f64>, rhs: &DVector<f64>) -> Option<DVector<f64>> {
    let norms: Vec<f64> = m
        .column_iter()
        .map(|c| c.norm().max(f64::MIN_POSITIVE))
        .collect();
    for (j, n) in norms.iter().enumerate() {
        m.column_mut(j).scale_mut(1.0 / n);
    }
    let x = m.svd(true, true).solve(rhs, 1e-13).ok()?;
    let x = DVector::from_iterator(x.len(), x.iter().zip(&norms).map(|(v, n)| v / n));
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// `θ = [b_0..b_nb, a_0..a_{na−1}]` as a model.
fn from_theta(theta: &DVector<f64>, st: Structure) -> Rational {
    let nb = st.nb();
    let b = theta.rows(0, nb + 1).iter().copied().collect();
    let mut a: Vec<f64> = theta.rows(nb + 1, st.na()).iter().copied().collect();
    a.push(1.0);
    Rational { b, a }
}

/// The parameter vector of a model.
fn to_theta(r: &Rational) -> DVector<f64> {
    let na = r.a.len() - 1;
    DVector::from_iterator(r.b.len() + na, r.b.iter().chain(&r.a[..na]).copied())
}

/// The model with the roots of `A` in the right half-plane reflected into the
/// left one (the gain at `s = 0` kept).
fn stabilise(r: Rational) -> Rational {
    if r.stable() || r.a.len() < 2 {
        return r;
    }
    let desc: Vec<f64> = r.a.iter().rev().copied().collect();
    let roots: Vec<Complex<f64>> = dynamics::roots(&desc)
        .into_iter()
        .map(|p| Complex::new(-p.re.abs().max(1e-6 * p.norm()), p.im))
        .collect();
    let a = poly_from_roots(&roots);
    let scale = a[0] / r.a[0];
    let b = if scale.is_finite() {
        r.b.iter().map(|c| c * scale).collect()
    } else {
        r.b
    };
    Rational { b, a }
}

/// The monic polynomial (ascending) with these roots (conjugates paired).
fn poly_from_roots(roots: &[Complex<f64>]) -> Vec<f64> {
    let mut c = vec![Complex::new(1.0, 0.0)];
    for &z in roots {
        let mut next = vec![Complex::new(0.0, 0.0); c.len() + 1];
        for (i, &k) in c.iter().enumerate() {
            next[i + 1] += k;
            next[i] -= k * z;
        }
        c = next;
    }
    c.iter().map(|z| z.re).collect()
}

/// Levenberg–Marquardt on the output error from `start` (which must be stable);
/// steps that make `A` unstable are refused.
pub fn output_error(pts: &[Point], st: Structure, start: Rational) -> Rational {
    let mut best = start;
    let mut c = cost(&best, pts);
    let mut lambda = 1e-3;
    for _ in 0..300 {
        let (j, r) = jacobian(&best, pts);
        let jt = j.transpose();
        let jtj = &jt * &j;
        let g = &jt * &r;
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj.clone();
            for i in 0..a.nrows() {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-300);
            }
            let Some(step) = a.lu().solve(&(-&g)) else {
                lambda *= 10.0;
                continue;
            };
            let cand = from_theta(&(to_theta(&best) + step), st);
            let cc = cost(&cand, pts);
            if cc.is_finite() && cc < c && cand.stable() {
                let done = (c - cc) < 1e-12 * c;
                best = cand;
                c = cc;
                lambda = (lambda / 3.0).max(1e-12);
                improved = !done;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    best
}

/// Residuals `√w·(H − B/A)` (re, im stacked) and their Jacobian in `θ`.
fn jacobian(r: &Rational, pts: &[Point]) -> (DMatrix<f64>, DVector<f64>) {
    let (nb, na) = (r.b.len() - 1, r.a.len() - 1);
    let mut j = DMatrix::<f64>::zeros(2 * pts.len(), nb + 1 + na);
    let mut res = DVector::<f64>::zeros(2 * pts.len());
    for (k, p) in pts.iter().enumerate() {
        let w = p.weight().sqrt();
        let (bv, av) = (poly_asc(&r.b, p.s), poly_asc(&r.a, p.s));
        let e = (p.h - bv / av) * w;
        res[2 * k] = e.re;
        res[2 * k + 1] = e.im;
        for i in 0..=nb {
            let d = -p.s.powu(i as u32) / av * w;
            j[(2 * k, i)] = d.re;
            j[(2 * k + 1, i)] = d.im;
        }
        for i in 0..na {
            let d = bv * p.s.powu(i as u32) / (av * av) * w;
            j[(2 * k, nb + 1 + i)] = d.re;
            j[(2 * k + 1, nb + 1 + i)] = d.im;
        }
    }
    (j, res)
}

/// One fitted structure and its scores.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// The structure.
    pub structure: Structure,
    /// The fitted model (scaled variable).
    pub model: Rational,
    /// Weighted RMS relative error `√(Σγ²|H − G|²/|H|² / Σγ²)`.
    pub rms: f64,
    /// Akaike's criterion `2N·ln(SSE/2N) + 2p` (N complex points).
    pub aic: f64,
}

/// Fits one structure: equation error, then output error.
pub fn fit(pts: &[Point], st: Structure) -> Option<Candidate> {
    let start = equation_error(pts, st)?;
    if !start.stable() {
        return None;
    }
    let model = output_error(pts, st, start);
    let sse = cost(&model, pts);
    let n2 = 2.0 * pts.len() as f64;
    let wsum: f64 = pts.iter().map(|p| p.coherence).sum();
    Some(Candidate {
        structure: st,
        rms: (sse / wsum).sqrt(),
        aic: n2 * (sse / n2).ln() + 2.0 * st.parameters() as f64,
        model,
    })
}

/// Every structure of [`CRITERION`], fitted (those that fail to fit left out).
pub fn candidates(pts: &[Point]) -> Vec<Candidate> {
    let mut out = vec![];
    for modes in 0..=3 {
        for lag in 0..=1 {
            let st = Structure { modes, lag };
            if st.parameters() * 2 < pts.len() {
                out.extend(fit(pts, st));
            }
        }
    }
    out
}

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
