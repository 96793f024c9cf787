//! Part I of the method: identifying a model from Voltage–Force–Displacement
//! recordings (Actuators 2025, 14(8):411, Table 1, Step 1).
//!
//! Every kind is linear in its weights once its nonlinear parameters are fixed:
//! the columns are the operator outputs `G_{r_i}[û]` (and their products with the
//! force for LDPI, the creep lags, a saturation term and an offset), fitted by
//! weighted non-negative least squares on the normal equations ([`crate::method::lsq`]),
//! accumulated over all recordings in parallel. The nonlinear parameters are
//! searched outside: golden section on `k_f` (fpi) and on the output curvature
//! (gpi), Nelder–Mead (`argmin`) on `(k_f, k_q, k0, s)` (efpi), always scoring the
//! output error (RMSE of the simulated extension against the recording).
//!
//! Calibration is linear in the samples, in time and memory: the columns'
//! recurrences run over every sample in one pass per trial, and only the rows of
//! the least squares are kept, at most [`SEARCH_SAMPLES`] of them: beyond that
//! the search decimates its rows (one sample in each run of `stride`, at a
//! pseudo-random place; the operators still see every sample), and the final
//! weights and figures come from every sample, its normal equations accumulated
//! in a streaming pass (exact; the design matrix is never stored).
//!
//! * Thresholds: `r_i = U·i/N`, `i = 1..N-1`, with `U` the largest voltage in the
//!   data rounded up to 10 % steps (10 operators on 0–100 V data: 0, 10, …, 90 V,
//!   the paper's grid; `r = 0` is `w0`).
//! * `efpi`: stack compliance fixed at the datasheet value (0.02 µm/N for stage
//!   A's stack; the rig cannot identify it: there the force rises in proportion to
//!   the extension, so compliance only rescales the weights), creep time constants
//!   fixed at 10 ms, 30 ms, 0.3 s and 3 s, saturation `z + β·z² = Y` fitted by
//!   equation error (a `−z²` column), the curvature of `U_p` centred on the data's
//!   mean preload.

use std::path::Path;
use std::sync::Mutex;

use anyhow::{bail, Context, Result};
use argmin::core::{CostFunction, Error as ArgminError, Executor, State};
use argmin::solver::neldermead::NelderMead;
use piezo_sim::maps::dead_zone;
use piezo_sim::model::lag_rate;
use piezo_sim::play::play;
use piezo_sim::stats::ErrorStats;
use rayon::prelude::*;

use crate::data;
use crate::method::checks;
use crate::method::lsq::Normal;
use crate::method::model::{Calibration, FileFit, HostModel, Kind, LdpiParams, OutputMap};
use crate::model_file::{CouplingSection, CreepSection, PiSection};

/// One recording prepared for calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibData {
    /// Name for reports (the file name).
    pub name: String,
    /// Sample period, s.
    pub dt: f64,
    /// Commanded voltage, V.
    pub u: Vec<f64>,
    /// Preload, N (0 where the recording has none).
    pub f: Vec<f64>,
    /// Stack extension, µm.
    pub x: Vec<f64>,
    /// Force at zero extension (the compliance reference), N.
    pub f0: f64,
    /// Samples scored and fitted: `fit.0..fit.1` (the rest only builds history).
    pub fit: (usize, usize),
    /// Whether the recording has a force channel.
    pub has_force: bool,
}

/// Reads calibration recordings: `t_s,voltage_V,force_N,displacement_um` CSV (gz
/// allowed), or the micromanipulator's `.dat` (column 1 volts, column 5 µm, 200 Hz,
/// no force). `rows` (1-based, inclusive) restricts fitting to a window of a single
/// recording; the operators still see the whole history from the first row, and
/// the extension is zeroed at the window's first row.
pub fn load(paths: &[impl AsRef<Path>], rows: Option<(usize, usize)>) -> Result<Vec<CalibData>> {
    if rows.is_some() && paths.len() != 1 {
        bail!(
            "--rows selects a window of one recording; {} were given",
            paths.len()
        );
    }
    let mut out = Vec::new();
    for p in paths {
        let p = p.as_ref();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().trim_end_matches(".gz").to_string())
            .unwrap_or_default();
        let is_dat = name.ends_with(".dat");
        let (dt, u, f, x, has_force) = if is_dat {
            let m = data::read_micromanipulator(p)?;
            let n = m.u.len();
            (1.0 / 200.0, m.u, vec![0.0; n], m.sensor, false)
        } else {
            let r = data::read_rig(p)?;
            let dt = median_step(&r.t)
                .with_context(|| format!("{}: needs at least two samples", p.display()))?;
            (dt, r.u, r.f, r.x, true)
        };
        let n = u.len();
        let fit = match rows {
            Some((a, b)) => {
                if a < 1 || b < a || b > n {
                    bail!(
                        "{}: --rows {a}-{b} is outside the recording's {n} rows",
                        p.display()
                    );
                }
                (a - 1, b)
            }
            None => (0, n),
        };
        let f0 = f[fit.0];
        let mut d = CalibData {
            name,
            dt,
            u,
            f,
            x,
            f0,
            fit,
            has_force,
        };
        // Values beyond the fixed-point range, as the file has them.
        checks::ranges(&d)?;
        // Zero the extension at the first fitted sample (the recordings are zeroed at t = 0).
        let x0 = d.x[fit.0];
        d.x.iter_mut().for_each(|v| *v -= x0);
        out.push(d);
    }
    if out.is_empty() {
        bail!("no calibration recordings given");
    }
    Ok(out)
}

fn median_step(t: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// What to calibrate and how.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The model kind.
    pub kind: Kind,
    /// Play operators including the `r = 0` one (`w0`).
    pub operators: usize,
    /// Stack compliance for efpi, µm/N.
    pub compliance: f64,
    /// Creep time constants for efpi, s.
    pub creep_taus: Vec<f64>,
    /// Fit a constant offset (recordings not zeroed at rest).
    pub offset: bool,
    /// Input domain of the model, V.
    pub input_max: f64,
    /// Branch model: degrees of the ascending and descending polynomials.
    pub branch_degrees: (usize, usize),
    /// Branch model: how turning points are remembered.
    pub branch_memory: crate::method::branch::Memory,
}

impl Options {
    /// The defaults for a kind.
    pub fn for_kind(kind: Kind) -> Self {
        Self {
            kind,
            operators: if kind == Kind::Gpi { 21 } else { 10 },
            compliance: if kind == Kind::Efpi { 0.02 } else { 0.0 },
            creep_taus: if kind == Kind::Efpi {
                vec![0.01, 0.03, 0.3, 3.0]
            } else {
                Vec::new()
            },
            offset: kind == Kind::Gpi,
            input_max: crate::method::export::AMPLIFIER_MAX_V,
            branch_degrees: crate::method::branch::PAPER_DEGREES,
            branch_memory: crate::method::branch::Memory::Stack,
        }
    }

    /// The same options with another operator count.
    pub fn with_operators(mut self, n: usize) -> Self {
        self.operators = n;
        self
    }
}

/// The nonlinear parameters of one trial.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Nonlinear {
    k_f: f64,
    k_q: f64,
    k0: f64,
    softness: f64,
    gamma: f64,
}

/// The layout of the columns of a kind.
#[derive(Debug, Clone)]
struct Layout {
    kind: Kind,
    thresholds: Vec<f64>,
    ldpi: bool,
    creep: Vec<f64>,
    saturation: bool,
    offset: bool,
    compliance: f64,
    force_q: f64,
}

impl Layout {
    fn columns(&self) -> usize {
        let n = 1 + self.thresholds.len();
        n * if self.ldpi { 2 } else { 1 }
            + self.creep.len()
            + self.saturation as usize
            + self.offset as usize
    }

    fn nonneg(&self) -> Vec<bool> {
        let n = 1 + self.thresholds.len();
        let mut v = vec![!self.ldpi; n * if self.ldpi { 2 } else { 1 }];
        v.extend(std::iter::repeat_n(true, self.creep.len()));
        if self.saturation {
            v.push(true);
        }
        if self.offset {
            v.push(false);
        }
        v
    }

    /// The effective voltage of one sample.
    #[inline]
    fn effective(&self, u: f64, f: f64, p: &Nonlinear) -> f64 {
        match self.kind {
            Kind::Fpi => (u - p.k_f * f).max(0.0),
            Kind::Efpi => {
                let q = f - self.force_q;
                dead_zone(p.softness, u - (p.k0 + p.k_f * f + p.k_q * q * q)).0
            }
            _ => u.max(0.0),
        }
    }

    /// Runs the columns' recurrences (effective voltage, play operators, creep
    /// lags) over every sample of a recording up to the end of its fitted window,
    /// and calls `visit(k, row, target, weight)` for the fitted samples `pick`
    /// takes: the sample's columns, its equation-error target and its weight.
    /// Nothing is stored: memory does not grow with the samples. `pre`: the
    /// effective voltages, if [`effective_all`](Self::effective_all) computed them.
    fn scan(
        &self,
        d: &CalibData,
        p: &Nonlinear,
        pick: Pick,
        pre: Option<&[f64]>,
        mut visit: impl FnMut(usize, &[f64], f64, f64),
    ) {
        let nc = self.columns();
        let nt = self.thresholds.len();
        let mut row = vec![0.0; nc];
        let mut y = vec![0.0; nt];
        let rates: Vec<f64> = self.creep.iter().map(|&tau| lag_rate(d.dt, tau)).collect();
        let mut m = vec![0.0; self.creep.len()];
        let gpi = (self.kind == Kind::Gpi).then_some(OutputMap::Quadratic {
            gamma_per_um: p.gamma,
        });
        let end = d.fit.1.min(d.u.len());
        let mut run = 0;
        let mut next = d.fit.0 + pick.taken_in_run(0);
        for k in 0..end {
            let (u, f) = (d.u[k], d.f[k]);
            let v = match pre {
                Some(pre) => pre[k],
                None => self.effective(u, f, p).min(1e6),
            };
            for (yi, r) in y.iter_mut().zip(&self.thresholds) {
                *yi = play(v, *r, *yi);
            }
            for (mj, rate) in m.iter_mut().zip(&rates) {
                *mj += rate * (v - *mj);
            }
            if k != next {
                continue;
            }
            run += 1;
            next = d.fit.0 + pick.taken_in_run(run);
            row[0] = v;
            row[1..=nt].copy_from_slice(&y);
            let mut c = 1 + nt;
            if self.ldpi {
                for i in 0..c {
                    row[c + i] = row[i] * f;
                }
                c *= 2;
            }
            row[c..c + m.len()].copy_from_slice(&m);
            c += m.len();
            // Targets: the extension (plus the compliance term for efpi).
            let mut z = d.x[k] + self.compliance * (f - d.f0);
            if self.saturation {
                row[c] = -z * z;
                c += 1;
            }
            if self.offset {
                row[c] = 1.0;
            }
            let mut weight = 1.0;
            if let Some(map) = gpi {
                let yt = map.invert(z);
                let slope = map.apply(yt).1;
                z = yt;
                weight = slope * slope;
            }
            visit(k, &row, z, weight);
        }
    }

    /// The effective voltage of every sample [`scan`](Self::scan) runs over, in
    /// parallel chunks, into `out`: the costly part of a long recording's scan
    /// (the soft dead zone), taken off its serial recurrences. The same values
    /// as `scan` computes itself.
    fn effective_all(&self, d: &CalibData, p: &Nonlinear, out: &mut Vec<f64>) {
        const CHUNK: usize = 1 << 14;
        let end = d.fit.1.min(d.u.len());
        out.resize(end, 0.0);
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                let k0 = c * CHUNK;
                for (v, (u, f)) in chunk.iter_mut().zip(d.u[k0..].iter().zip(&d.f[k0..])) {
                    *v = self.effective(*u, *f, p).min(1e6);
                }
            });
    }

    /// The model's output at a sample with columns `row`, given weights `w` and
    /// the output map `map` ([`Layout::map`]).
    #[inline]
    fn output(&self, row: &[f64], w: &[f64], map: &OutputMap, d: &CalibData, k: usize) -> f64 {
        let sat_col = self.saturation_column();
        let mut yv = 0.0;
        for (j, (r, wj)) in row.iter().zip(w).enumerate() {
            if Some(j) != sat_col {
                yv += r * wj;
            }
        }
        map.apply(yv).0 - self.compliance * (d.f[k] - d.f0)
    }

    /// The column of the saturation term, if any (it shapes the output map, not
    /// the output's sum).
    fn saturation_column(&self) -> Option<usize> {
        self.saturation
            .then(|| self.columns() - 1 - self.offset as usize)
    }

    fn map(&self, w: &[f64], p: &Nonlinear) -> OutputMap {
        if let Some(c) = self.saturation_column() {
            OutputMap::Saturation { beta_per_um: w[c] }
        } else if self.kind == Kind::Gpi {
            OutputMap::Quadratic {
                gamma_per_um: p.gamma,
            }
        } else {
            OutputMap::Identity
        }
    }
}

/// Which fitted samples a fit uses: every one (`stride` 1), or one in each run
/// of `stride` consecutive samples at a pseudo-random place in the run (a
/// decimation that cannot alias with a periodic drive, as a fixed stride could).
/// The recurrences always run over every sample: only the rows of the least
/// squares and the scored samples are thinned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Pick {
    stride: usize,
}

impl Pick {
    const ALL: Pick = Pick { stride: 1 };

    /// The fitted sample taken in run `run` (samples `run·stride..(run+1)·stride`).
    #[inline]
    fn taken_in_run(self, run: usize) -> usize {
        let s = self.stride.max(1);
        if s == 1 {
            return run;
        }
        // SplitMix64's finaliser: a fixed, well-spread place in each run.
        let mut h = (run as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
        h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        h ^= h >> 31;
        run * s + (h % s as u64) as usize
    }

    /// Whether the `i`-th fitted sample is taken.
    #[cfg(test)]
    fn takes(self, i: usize) -> bool {
        self.taken_in_run(i / self.stride.max(1)) == i
    }

    /// How many of `n` fitted samples are taken.
    fn count(self, n: usize) -> usize {
        let s = self.stride.max(1);
        n / s + usize::from(!n.is_multiple_of(s) && self.taken_in_run(n / s) < n)
    }
}

/// Samples the nonlinear search fits and scores at most: more are decimated
/// ([`Pick`]) for the search, and the final weights are fitted on all of them.
/// Up to this many (the 166 000 of the pea-rig recordings) the search uses
/// every sample.
pub const SEARCH_SAMPLES: usize = 200_000;

/// Largest design matrix a fit keeps in memory, bytes; a larger one is streamed
/// twice (once for the normal equations, once for the output), which gives the
/// same figures.
const STORED_BYTES: usize = 64 << 20;

/// One recording's stored rows in a fit: the columns (row-major) and sample of
/// every taken sample (the output error needs no more). Kept between the trials of the
/// nonlinear search, so its buffers are allocated once.
#[derive(Debug, Default)]
struct Workspace {
    cols: Vec<f64>,
    sample: Vec<usize>,
    /// A long recording's effective voltages ([`Layout::effective_all`]).
    v: Vec<f64>,
}

/// A calibration problem: the columns' layout, the recordings, the decimation of
/// the nonlinear search and the recordings' buffers.
struct Problem<'a> {
    layout: Layout,
    data: &'a [CalibData],
    search: Pick,
    /// Per recording: whether it is long, more than a thread's share of all
    /// samples, so that its serial scan would hold up the others: its effective
    /// voltages are then computed in parallel first (the same figures).
    long: Vec<bool>,
    work: Vec<Mutex<Workspace>>,
}

/// One fit: weights, and the output-error figures.
#[derive(Debug, Clone)]
struct Fit {
    w: Vec<f64>,
    rmse: f64,
    per_file: Vec<FileFit>,
}

/// The output-error figures of a recording's window.
pub(crate) fn file_fit(d: &CalibData, e: &ErrorStats<f64>) -> FileFit {
    FileFit {
        file: d.name.clone(),
        samples: e.count() as usize,
        rmse_um: e.rms(),
        mte_um: e.max_abs(),
    }
}

/// RMSE over several files' fits, weighted by their samples.
pub(crate) fn pooled_rmse(per_file: &[FileFit]) -> f64 {
    let total: usize = per_file.iter().map(|f| f.samples).sum();
    let s2: f64 = per_file
        .iter()
        .map(|f| f.rmse_um * f.rmse_um * f.samples as f64)
        .sum();
    (s2 / total as f64).sqrt()
}

fn lock(m: &Mutex<Workspace>) -> std::sync::MutexGuard<'_, Workspace> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl<'a> Problem<'a> {
    fn new(layout: Layout, data: &'a [CalibData]) -> Self {
        let fitted: usize = data.iter().map(|d| d.fit.1 - d.fit.0).sum();
        let search = Pick {
            stride: fitted.div_ceil(SEARCH_SAMPLES).max(1),
        };
        let total: usize = data.iter().map(|d| d.fit.1).sum();
        let threads = rayon::current_num_threads();
        let long = data
            .iter()
            .map(|d| threads > 1 && d.fit.1 >= 1 << 16 && d.fit.1 * threads > total)
            .collect();
        let work = data.iter().map(|_| Mutex::default()).collect();
        Self {
            layout,
            data,
            search,
            long,
            work,
        }
    }

    fn with_layout(&self, layout: Layout) -> Problem<'a> {
        Problem::new(layout, self.data)
    }

    /// Fits the weights for nonlinear parameters `p` on the samples `pick`
    /// takes, and scores the output on the same samples.
    fn fit(&self, p: &Nonlinear, pick: Pick) -> Result<Fit> {
        let rows: usize = self
            .data
            .iter()
            .map(|d| pick.count(d.fit.1 - d.fit.0))
            .sum();
        let bytes = rows.saturating_mul(self.layout.columns()).saturating_mul(8);
        self.fit_with(p, pick, bytes <= STORED_BYTES)
    }

    /// [`fit`](Self::fit), keeping the rows in memory (`stored`) or streaming the
    /// recordings twice: the same figures either way.
    fn fit_with(&self, p: &Nonlinear, pick: Pick, stored: bool) -> Result<Fit> {
        let layout = &self.layout;
        let nc = layout.columns();
        // The normal equations, per recording in parallel, merged in order.
        let normals: Vec<Normal> = self
            .data
            .par_iter()
            .zip(&self.work)
            .zip(&self.long)
            .map(|((d, ws), &long)| {
                let mut ne = Normal::new(nc);
                let mut ws = lock(ws);
                let Workspace { cols, sample, v } = &mut *ws;
                let pre = long.then(|| {
                    layout.effective_all(d, p, v);
                    &v[..]
                });
                if stored {
                    cols.clear();
                    sample.clear();
                    layout.scan(d, p, pick, pre, |k, row, z, wt| {
                        ne.add(row, z, wt);
                        cols.extend_from_slice(row);
                        sample.push(k);
                    });
                } else {
                    layout.scan(d, p, pick, pre, |_, row, z, wt| ne.add(row, z, wt));
                }
                ne
            })
            .collect();
        let mut all = Normal::new(nc);
        for ne in &normals {
            all.merge(ne);
        }
        let (w, _) = all.solve(&layout.nonneg())?;
        // The output error, from the stored rows or a second pass.
        let map = layout.map(&w, p);
        let per_file: Vec<FileFit> = self
            .data
            .par_iter()
            .zip(&self.work)
            .zip(&self.long)
            .map(|((d, ws), &long)| {
                let mut e = ErrorStats::new();
                let ws = lock(ws);
                if stored {
                    for (row, &k) in ws.cols.chunks_exact(nc.max(1)).zip(&ws.sample) {
                        e.add(layout.output(row, &w, &map, d, k) - d.x[k]);
                    }
                } else {
                    let pre = long.then_some(&ws.v[..]);
                    layout.scan(d, p, pick, pre, |k, row, _, _| {
                        e.add(layout.output(row, &w, &map, d, k) - d.x[k]);
                    });
                }
                file_fit(d, &e)
            })
            .collect();
        let rmse = pooled_rmse(&per_file);
        Ok(Fit {
            w,
            rmse: if rmse.is_finite() { rmse } else { f64::MAX },
            per_file,
        })
    }

    /// The fit on every fitted sample: the result's weights and figures.
    fn fit_all(&self, p: &Nonlinear) -> Result<Fit> {
        // The search's buffers are not needed any more.
        let free = || {
            for ws in &self.work {
                *lock(ws) = Workspace::default();
            }
        };
        free();
        let f = self.fit(p, Pick::ALL);
        free();
        f
    }

    /// The output RMSE of a trial of the nonlinear search (`f64::MAX` if it
    /// cannot be fitted), on the search's samples.
    fn rmse(&self, p: &Nonlinear) -> f64 {
        self.fit(p, self.search).map_or(f64::MAX, |f| f.rmse)
    }
}

/// Golden-section minimisation of `f` on `[a, b]`.
pub(crate) fn golden(mut a: f64, mut b: f64, tol: f64, mut f: impl FnMut(f64) -> f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while (b - a).abs() > tol {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    (a + b) / 2.0
}

struct EfpiCost<'p, 'a> {
    problem: &'p Problem<'a>,
}

impl EfpiCost<'_, '_> {
    /// The efpi parameters of a Nelder–Mead point `(k_f, k_q·10⁴, k0, s)`.
    fn params(q: &[f64]) -> Nonlinear {
        Nonlinear {
            k_f: q[0],
            k_q: q[1] * 1e-4,
            k0: q[2],
            softness: q[3].abs().max(1e-3),
            gamma: 0.0,
        }
    }
}

impl CostFunction for EfpiCost<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, q: &Vec<f64>) -> Result<f64, ArgminError> {
        Ok(self.problem.rmse(&Self::params(q)))
    }
}

/// The data's top voltage rounded up to a tenth of its decade (100 V stays 100 V).
pub(crate) fn voltage_span(data: &[CalibData]) -> f64 {
    let u_top = data
        .iter()
        .flat_map(|d| d.u.iter())
        .fold(0.0f64, |a, &b| a.max(b));
    let decade = 10f64.powf(u_top.max(1e-9).log10().floor());
    (u_top / decade * 10.0).ceil() * decade / 10.0
}

/// The thresholds `r_i = U·i/N`, `i = 1..N-1`, over the voltage span `U`.
fn thresholds(span: f64, operators: usize) -> Vec<f64> {
    (1..operators)
        .map(|i| span * i as f64 / operators as f64)
        .collect()
}

/// The data's mean preload over the fitted windows, rounded to 5 N: the centre
/// of the preload offset's curvature.
fn mean_preload(data: &[CalibData]) -> f64 {
    let (s, c) = data
        .iter()
        .flat_map(|d| d.f[d.fit.0..d.fit.1].iter())
        .fold((0.0, 0usize), |(s, c), f| (s + f, c + 1));
    if c > 0 {
        (s / c as f64 * 0.2).round() * 5.0
    } else {
        0.0
    }
}

/// pi and ldpi: the weights alone.
fn fit_linear(pr: &Problem<'_>) -> Result<(Nonlinear, Fit, String)> {
    let p = Nonlinear::default();
    let f = pr.fit_all(&p)?;
    Ok((
        p,
        f,
        "weights by least squares (NNLS for pi; signed for ldpi)".into(),
    ))
}

/// fpi: `k_f` by golden section.
fn fit_fpi(pr: &Problem<'_>) -> Result<(Nonlinear, Fit, String)> {
    let with = |k_f| Nonlinear {
        k_f,
        ..Default::default()
    };
    let p = with(golden(0.0, 0.4, 1e-5, |k_f| pr.rmse(&with(k_f))));
    let f = pr.fit_all(&p)?;
    Ok((
        p,
        f,
        "k_f by golden section on the output RMSE; weights by NNLS".into(),
    ))
}

/// gpi: the output curvature by golden section (scaled by the data's range).
fn fit_gpi(pr: &Problem<'_>) -> Result<(Nonlinear, Fit, String)> {
    let scale = pr
        .data
        .iter()
        .flat_map(|d| d.x[d.fit.0..d.fit.1].iter())
        .fold(0.0f64, |a, &b| a.max(b.abs()))
        .max(1e-9);
    let with = |g: f64| Nonlinear {
        gamma: g / scale,
        ..Default::default()
    };
    let p = with(golden(-0.3, 0.3, 1e-6, |g| pr.rmse(&with(g))));
    let f = pr.fit_all(&p)?;
    Ok((
        p,
        f,
        "output curvature by golden section on the output RMSE; weights by weighted NNLS \
         on the inverse-mapped extension"
            .into(),
    ))
}

/// efpi: `(k_f, k_q, k0, s)` by Nelder–Mead from the paper's FPI fit.
fn fit_efpi(pr: &Problem<'_>, opt: &Options) -> Result<(Nonlinear, Fit, String)> {
    // Start from the paper's FPI: its k_f, no curvature, no offset, a 1 V soft edge.
    let fpi = pr.with_layout(Layout {
        kind: Kind::Fpi,
        creep: Vec::new(),
        saturation: false,
        compliance: 0.0,
        ..pr.layout.clone()
    });
    let k_f0 = golden(0.0, 0.4, 1e-4, |k_f| {
        fpi.rmse(&Nonlinear {
            k_f,
            ..Default::default()
        })
    });
    drop(fpi);
    let start = vec![k_f0, 0.0, 0.0, 1.0];
    let steps = [0.01, 1.0, 0.5, 0.5];
    let mut simplex = vec![start.clone()];
    for (i, s) in steps.iter().enumerate() {
        let mut v = start.clone();
        v[i] += s;
        simplex.push(v);
    }
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(1e-7)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let res = Executor::new(EfpiCost { problem: pr }, solver)
        .configure(|s| s.max_iters(400))
        .run()
        .map_err(|e| anyhow::anyhow!("Nelder–Mead: {e}"))?;
    let q = res.state().get_best_param().cloned().unwrap_or(start);
    let p = EfpiCost::params(&q);
    let f = pr.fit_all(&p)?;
    Ok((
        p,
        f,
        format!(
            "(k_f, k_q, k0, s) by Nelder–Mead on the output RMSE from the fpi fit; weights, \
             creep gains and saturation by NNLS (equation error); compliance {} µm/N \
             fixed; creep time constants {:?} s fixed",
            opt.compliance, opt.creep_taus
        ),
    ))
}

/// Calibrates a model on recordings.
pub fn calibrate(data: &[CalibData], opt: &Options) -> Result<HostModel> {
    let kind = opt.kind;
    let warnings = checks::check(data, kind)?;
    if opt.operators < 1 || opt.operators > 32 {
        bail!("--operators {}: must be 1..=32", opt.operators);
    }
    let efpi = kind == Kind::Efpi;
    let span = voltage_span(data);
    let layout = Layout {
        kind,
        thresholds: thresholds(span, opt.operators),
        ldpi: kind == Kind::Ldpi,
        creep: if efpi {
            opt.creep_taus.clone()
        } else {
            Vec::new()
        },
        saturation: efpi,
        offset: opt.offset,
        compliance: if efpi { opt.compliance } else { 0.0 },
        force_q: mean_preload(data),
    };
    let pr = Problem::new(layout, data);
    let (params, best, method) = match kind {
        Kind::Pi | Kind::Ldpi => fit_linear(&pr)?,
        Kind::Fpi => fit_fpi(&pr)?,
        Kind::Gpi => fit_gpi(&pr)?,
        Kind::Efpi => fit_efpi(&pr, opt)?,
        Kind::Branch => return crate::method::branch::calibrate(data, opt, warnings),
    };
    let mut model = unpack(&pr.layout, &params, &best.w, opt.input_max.max(span));
    model.calibration = Calibration {
        created_by: format!("fpi calibrate {}", env!("CARGO_PKG_VERSION")),
        files: data.iter().map(|d| d.name.clone()).collect(),
        rows: None,
        rmse_um: best.rmse,
        mte_um: best.per_file.iter().map(|f| f.mte_um).fold(0.0, f64::max),
        per_file: best.per_file,
        method,
        warnings,
    };
    Ok(model)
}

/// The model a fit's weights and nonlinear parameters describe.
fn unpack(layout: &Layout, params: &Nonlinear, w: &[f64], input_max: f64) -> HostModel {
    let kind = layout.kind;
    let n1 = 1 + layout.thresholds.len();
    let mut model = HostModel::new(
        kind,
        PiSection {
            w0_um_per_v: w[0],
            thresholds_v: layout.thresholds.clone(),
            weights_um_per_v: w[1..n1].to_vec(),
            input_max_v: input_max,
        },
    );
    let mut c = n1;
    if layout.ldpi {
        model.ldpi = Some(LdpiParams {
            w0_per_n: w[c],
            weights_per_n: w[c + 1..c + n1].to_vec(),
        });
        c += n1;
    }
    model.creep = layout
        .creep
        .iter()
        .enumerate()
        .map(|(j, &tau)| CreepSection {
            tau_s: tau,
            gain_um_per_v: w[c + j],
        })
        .collect();
    c += layout.creep.len();
    model.output = layout.map(w, params);
    if layout.saturation {
        c += 1;
    }
    if layout.offset {
        model.offset_um = w[c];
    }
    if matches!(kind, Kind::Fpi | Kind::Efpi) {
        model.coupling = CouplingSection {
            offset_v: params.k0,
            k_f_v_per_n: params.k_f,
            k_q_v_per_n2: params.k_q,
            force_q_n: if params.k_q != 0.0 {
                layout.force_q
            } else {
                0.0
            },
            compliance_um_per_n: layout.compliance,
            force_ref_n: None,
        };
        model.dead_zone_softness_v = params.softness;
    }
    model
}

/// The model's stack extension over a recording, driven by its voltage with its
/// measured force, µm.
pub fn simulate(model: &HostModel, d: &CalibData) -> Vec<f64> {
    let m = model.model();
    let mut st = m.state(d.dt);
    (0..d.u.len())
        .map(|k| m.step(&mut st, d.u[k], d.f[k], d.f0))
        .collect()
}

/// Scores a model on recordings by simulating it with the measured force
/// (output error), per file.
pub fn score(model: &HostModel, data: &[CalibData]) -> Vec<FileFit> {
    data.par_iter()
        .map(|d| {
            let window = d.fit.0..d.fit.1;
            let e = ErrorStats::of_difference(&simulate(model, d)[window.clone()], &d.x[window]);
            file_fit(d, &e)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_decimation_takes_one_sample_in_every_run() {
        assert!((0..50).all(|i| Pick::ALL.takes(i)));
        assert_eq!(Pick::ALL.count(17), 17);
        for stride in [2, 3, 7, 26] {
            let pick = Pick { stride };
            for run in 0..200 {
                let taken: Vec<usize> = (run * stride..(run + 1) * stride)
                    .filter(|&i| pick.takes(i))
                    .collect();
                assert_eq!(taken, vec![pick.taken_in_run(run)], "stride {stride}");
            }
            for n in [0, 1, stride - 1, stride, 5 * stride + 1, 1000] {
                let by_hand = (0..n).filter(|&i| pick.takes(i)).count();
                assert_eq!(pick.count(n), by_hand, "stride {stride}, {n} samples");
            }
            // Not a fixed phase: a drive whose period is the stride is sampled
            // at every phase.
            let phases: std::collections::BTreeSet<usize> =
                (0..400).map(|r| pick.taken_in_run(r) % stride).collect();
            assert_eq!(phases.len(), stride, "stride {stride}");
        }
    }

    /// Three pea-rig recordings at different preloads.
    fn rig() -> Vec<CalibData> {
        let names = [
            "preload_050N_sine_05Hz.csv.gz",
            "preload_100N_sine_15Hz.csv.gz",
            "preload_125N_minor_05Hz.csv.gz",
        ];
        let paths: Vec<_> = data::datasets_in("pea-rig")
            .into_iter()
            .filter(|p| names.iter().any(|n| p.ends_with(n)))
            .collect();
        assert_eq!(paths.len(), 3, "{paths:?}");
        load(&paths, None).unwrap()
    }

    fn layout(kind: Kind, data: &[CalibData]) -> Layout {
        let opt = Options::for_kind(kind);
        let efpi = kind == Kind::Efpi;
        Layout {
            kind,
            thresholds: thresholds(voltage_span(data), opt.operators),
            ldpi: kind == Kind::Ldpi,
            creep: opt.creep_taus.clone(),
            saturation: efpi,
            offset: opt.offset,
            compliance: opt.compliance,
            force_q: mean_preload(data),
        }
    }

    #[test]
    fn stored_and_streamed_fits_agree_to_the_bit() {
        let data = rig();
        let p = Nonlinear {
            k_f: 0.05,
            k_q: 1e-5,
            k0: 0.5,
            softness: 1.0,
            gamma: 0.0,
        };
        for kind in [Kind::Efpi, Kind::Ldpi, Kind::Gpi] {
            let pr = Problem::new(layout(kind, &data), &data);
            let mut long = Problem::new(layout(kind, &data), &data);
            long.long = vec![true; data.len()];
            for pick in [Pick::ALL, Pick { stride: 5 }] {
                let a = pr.fit_with(&p, pick, true).unwrap();
                let b = pr.fit_with(&p, pick, false).unwrap();
                assert_eq!(a.w, b.w, "{kind}");
                assert_eq!(a.per_file, b.per_file, "{kind}");
                for stored in [true, false] {
                    let c = long.fit_with(&p, pick, stored).unwrap();
                    assert_eq!((&a.w, &a.per_file), (&c.w, &c.per_file), "{kind}");
                }
                let rows: usize = data.iter().map(|d| pick.count(d.fit.1 - d.fit.0)).sum();
                let scored: usize = a.per_file.iter().map(|f| f.samples).sum();
                assert_eq!(scored, rows);
            }
        }
    }

    #[test]
    fn a_decimated_search_finds_the_same_coupling() {
        let data = rig();
        let mut pr = Problem::new(layout(Kind::Fpi, &data), &data);
        assert_eq!(pr.search, Pick::ALL, "few samples: no decimation");
        let with = |k_f| Nonlinear {
            k_f,
            ..Default::default()
        };
        let full = golden(0.0, 0.4, 1e-5, |k| pr.rmse(&with(k)));
        pr.search = Pick { stride: 10 };
        let thinned = golden(0.0, 0.4, 1e-5, |k| pr.rmse(&with(k)));
        assert!(
            (full - thinned).abs() < 0.02 * full,
            "k_f {full} from every sample, {thinned} from one in ten"
        );
        // The final weights and figures come from every sample.
        let a = pr.fit_all(&with(thinned)).unwrap();
        let all: usize = data.iter().map(|d| d.fit.1 - d.fit.0).sum();
        assert_eq!(a.per_file.iter().map(|f| f.samples).sum::<usize>(), all);
    }

    #[test]
    fn many_samples_decimate_the_search_only() {
        let mut d = rig().remove(0);
        let n = SEARCH_SAMPLES + SEARCH_SAMPLES / 2;
        let cat = |v: &[f64]| v.iter().cycle().take(n).copied().collect::<Vec<f64>>();
        d.u = cat(&d.u);
        d.f = cat(&d.f);
        d.x = cat(&d.x);
        d.fit = (0, n);
        let data = [d];
        let pr = Problem::new(layout(Kind::Fpi, &data), &data);
        assert_eq!(pr.search, Pick { stride: 2 });
    }
}
