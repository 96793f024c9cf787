//! The chirps and their frequency responses: reading a chirp recording, Welch's
//! estimate of its response and the points of it kept for the fit (step 1 of
//! [`super`]).

use super::*;

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

pub(super) fn prev_pow2(n: usize) -> usize {
    if n < 2 {
        1
    } else {
        1 << (usize::BITS - 1 - n.leading_zeros())
    }
}
