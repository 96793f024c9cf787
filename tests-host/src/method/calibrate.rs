//! Part I of the method: identifying a model from Voltage–Force–Displacement
//! recordings (Actuators 2025, 14(8):411, Table 1, Step 1).
//!
//! Every kind is linear in its weights once its nonlinear parameters are fixed:
//! the columns are the operator outputs `G_{r_i}[û]` (and their products with the
//! force for LDPI, the creep lags, a saturation term and an offset), fitted by
//! weighted non-negative least squares on the normal equations ([`crate::method::lsq`]),
//! accumulated over all recordings in parallel (each recording's columns are built
//! into a buffer it keeps for the whole calibration). The nonlinear parameters are
//! searched outside: golden section on `k_f` (fpi) and on the output curvature
//! (gpi), Nelder–Mead (`argmin`) on `(k_f, k_q, k0, s)` (efpi), always scoring the
//! output error (RMSE of the simulated extension against the recording).
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
        let (dt, u, f, mut x, has_force) = if is_dat {
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
        // Zero the extension at the first fitted sample (the recordings are zeroed at t = 0).
        let x0 = x[fit.0];
        x.iter_mut().for_each(|v| *v -= x0);
        let f0 = f[fit.0];
        out.push(CalibData {
            name,
            dt,
            u,
            f,
            x,
            f0,
            fit,
            has_force,
        });
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
            input_max: 150.0,
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

    /// Columns of every sample of a recording (row-major), and the equation-error
    /// target and weight of each sample, into the recording's buffers.
    fn build(&self, d: &CalibData, p: &Nonlinear, ws: &mut Workspace) {
        let nc = self.columns();
        let n = d.u.len();
        ws.cols.resize(n * nc, 0.0);
        ws.target.resize(n, 0.0);
        ws.weight.resize(n, 1.0);
        let mut y = vec![0.0; self.thresholds.len()];
        let rates: Vec<f64> = self.creep.iter().map(|&tau| lag_rate(d.dt, tau)).collect();
        let mut m = vec![0.0; self.creep.len()];
        for k in 0..n {
            let v = self.effective(d.u[k], d.f[k], p).min(1e6);
            let row = &mut ws.cols[k * nc..(k + 1) * nc];
            row[0] = v;
            for (i, r) in self.thresholds.iter().enumerate() {
                y[i] = play(v, *r, y[i]);
                row[1 + i] = y[i];
            }
            let mut c = 1 + self.thresholds.len();
            if self.ldpi {
                for i in 0..c {
                    row[c + i] = row[i] * d.f[k];
                }
                c *= 2;
            }
            for (j, rate) in rates.iter().enumerate() {
                m[j] += rate * (v - m[j]);
                row[c + j] = m[j];
            }
            c += rates.len();
            // Targets: the extension (plus the compliance term for efpi).
            let mut z = d.x[k] + self.compliance * (d.f[k] - d.f0);
            if self.saturation {
                row[c] = -z * z;
                c += 1;
            }
            if self.offset {
                row[c] = 1.0;
            }
            ws.weight[k] = 1.0;
            if self.kind == Kind::Gpi {
                let map = OutputMap::Quadratic {
                    gamma_per_um: p.gamma,
                };
                let yt = map.invert(z);
                let slope = map.apply(yt).1;
                z = yt;
                ws.weight[k] = slope * slope;
            }
            ws.target[k] = z;
        }
    }

    /// The model's output for every sample given weights `w`.
    fn output(&self, cols: &[f64], d: &CalibData, w: &[f64], p: &Nonlinear) -> Vec<f64> {
        let nc = self.columns();
        let sat_col = if self.saturation {
            Some(nc - 1 - self.offset as usize)
        } else {
            None
        };
        let map = self.map(w, p);
        (0..d.u.len())
            .map(|k| {
                let row = &cols[k * nc..(k + 1) * nc];
                let mut yv = 0.0;
                for (j, (r, wj)) in row.iter().zip(w).enumerate() {
                    if Some(j) != sat_col {
                        yv += r * wj;
                    }
                }
                map.apply(yv).0 - self.compliance * (d.f[k] - d.f0)
            })
            .collect()
    }

    fn map(&self, w: &[f64], p: &Nonlinear) -> OutputMap {
        if self.saturation {
            OutputMap::Saturation {
                beta_per_um: w[self.columns() - 1 - self.offset as usize],
            }
        } else if self.kind == Kind::Gpi {
            OutputMap::Quadratic {
                gamma_per_um: p.gamma,
            }
        } else {
            OutputMap::Identity
        }
    }
}

/// One recording's column buffers, kept for the whole calibration: every trial of
/// the nonlinear search rebuilds its columns in place.
#[derive(Debug, Default)]
struct Workspace {
    cols: Vec<f64>,
    target: Vec<f64>,
    weight: Vec<f64>,
}

/// A calibration problem: the columns' layout, the recordings and their buffers.
struct Problem<'a> {
    layout: Layout,
    data: &'a [CalibData],
    work: Vec<Mutex<Workspace>>,
}

/// One fit: weights, and the output-error figures.
#[derive(Debug, Clone)]
struct Fit {
    w: Vec<f64>,
    rmse: f64,
    per_file: Vec<FileFit>,
}

/// The output-error figures of a simulated window against the recording.
fn file_fit(d: &CalibData, simulated: &[f64]) -> FileFit {
    let window = d.fit.0..d.fit.1;
    let e = ErrorStats::of_difference(&simulated[window.clone()], &d.x[window]);
    FileFit {
        file: d.name.clone(),
        samples: e.count() as usize,
        rmse_um: e.rms(),
        mte_um: e.max_abs(),
    }
}

/// RMSE over several files' fits, weighted by their samples.
fn pooled_rmse(per_file: &[FileFit]) -> f64 {
    let total: usize = per_file.iter().map(|f| f.samples).sum();
    let s2: f64 = per_file
        .iter()
        .map(|f| f.rmse_um * f.rmse_um * f.samples as f64)
        .sum();
    (s2 / total as f64).sqrt()
}

impl<'a> Problem<'a> {
    fn new(layout: Layout, data: &'a [CalibData]) -> Self {
        let work = data.iter().map(|_| Mutex::default()).collect();
        Self { layout, data, work }
    }

    fn with_layout(&self, layout: Layout) -> Problem<'a> {
        Problem::new(layout, self.data)
    }

    fn fit(&self, p: &Nonlinear) -> Result<Fit> {
        let layout = &self.layout;
        let nc = layout.columns();
        fn lock(m: &Mutex<Workspace>) -> std::sync::MutexGuard<'_, Workspace> {
            m.lock().unwrap_or_else(|e| e.into_inner())
        }
        let normals: Vec<Normal> = self
            .data
            .par_iter()
            .zip(&self.work)
            .map(|(d, ws)| {
                let mut ws = lock(ws);
                layout.build(d, p, &mut ws);
                let mut ne = Normal::new(nc);
                for k in d.fit.0..d.fit.1 {
                    ne.add(&ws.cols[k * nc..(k + 1) * nc], ws.target[k], ws.weight[k]);
                }
                ne
            })
            .collect();
        let mut all = Normal::new(nc);
        for ne in &normals {
            all.merge(ne);
        }
        let (w, _) = all.solve(&layout.nonneg())?;
        let per_file: Vec<FileFit> = self
            .data
            .par_iter()
            .zip(&self.work)
            .map(|(d, ws)| file_fit(d, &layout.output(&lock(ws).cols, d, &w, p)))
            .collect();
        let rmse = pooled_rmse(&per_file);
        Ok(Fit {
            w,
            rmse: if rmse.is_finite() { rmse } else { f64::MAX },
            per_file,
        })
    }

    /// The output RMSE of a trial (`f64::MAX` if it cannot be fitted).
    fn rmse(&self, p: &Nonlinear) -> f64 {
        self.fit(p).map_or(f64::MAX, |f| f.rmse)
    }
}

/// Golden-section minimisation of `f` on `[a, b]`.
fn golden(mut a: f64, mut b: f64, tol: f64, mut f: impl FnMut(f64) -> f64) -> f64 {
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
fn voltage_span(data: &[CalibData]) -> f64 {
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
    let f = pr.fit(&p)?;
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
    let f = pr.fit(&p)?;
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
    let f = pr.fit(&p)?;
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
    let f = pr.fit(&p)?;
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
    if kind.uses_force() {
        if let Some(d) = data.iter().find(|d| !d.has_force) {
            bail!(
                "{}: a {kind} model needs a force channel; this recording has none",
                d.name
            );
        }
    }
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
        .map(|d| file_fit(d, &simulate(model, d)))
        .collect()
}
