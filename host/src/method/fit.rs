//! The least squares behind every kind built on play operators (Part I of the
//! method, Actuators 2025, 14(8):411, Table 1, Step 1).
//!
//! Every such kind is linear in its weights once its nonlinear parameters are
//! fixed: the columns ([`Layout`]) are the operator outputs `G_{r_i}[û]` (and
//! their products with the force for LDPI, the creep lags, a saturation term and
//! an offset), fitted by weighted non-negative least squares on the normal
//! equations ([`crate::method::lsq`]), accumulated over all recordings in
//! parallel. A kind searches its nonlinear parameters ([`Nonlinear`]) outside,
//! by [`golden`] section or [`nelder_mead`], always scoring the output error (RMSE
//! of the simulated extension against the recording, [`Problem::rmse`]).
//!
//! Calibration is linear in the samples, in time and memory: the columns'
//! recurrences run over every sample in one pass per trial, and only the rows of
//! the least squares are kept, at most [`SEARCH_SAMPLES`] of them: beyond that
//! the search decimates its rows (one sample in each run of `stride`, at a
//! pseudo-random place; the operators still see every sample), and the final
//! weights and figures come from every sample, its normal equations accumulated
//! in a streaming pass (exact; the design matrix is never stored).
//!
//! Thresholds: `r_i = U·i/N`, `i = 1..N-1`, with `U` the largest voltage in the
//! data rounded up to 10 % steps (10 operators on 0–100 V data: 0, 10, …, 90 V,
//! the paper's grid; `r = 0` is `w0`).

use std::sync::Mutex;

use anyhow::Result;
use argmin::core::{CostFunction, Error as ArgminError, Executor, State};
use argmin::solver::neldermead::NelderMead;
use piezo_sim::maps::dead_zone;
use piezo_sim::model::lag_rate;
use piezo_sim::play::play;
use piezo_sim::stats::ErrorStats;
use rayon::prelude::*;

use crate::method::lsq::Normal;
use crate::method::model::{HostModel, Kind, LdpiParams, Options, OutputMap};
use crate::method::sections::{pooled_rmse, FileFit};
use crate::method::series::{file_fit, CalibData};
use crate::model_file::{CouplingSection, CreepSection, PiSection};

mod layout;
pub use layout::{Input, Layout, MapFit, Nonlinear};
mod search;
pub use search::{golden, nelder_mead};

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
/// (one sample in each run of a stride) for the search, and the final weights
/// are fitted on all of them. Up to this many (the 166 000 of the pea-rig
/// recordings) the search uses every sample.
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
pub struct Problem<'a> {
    /// The columns.
    pub layout: Layout,
    /// The recordings.
    pub data: &'a [CalibData],
    search: Pick,
    /// Per recording: whether it is long, more than a thread's share of all
    /// samples, so that its serial scan would hold up the others: its effective
    /// voltages are then computed in parallel first (the same figures).
    long: Vec<bool>,
    work: Vec<Mutex<Workspace>>,
}

/// One fit: weights, and the output-error figures.
#[derive(Debug, Clone)]
pub struct Fit {
    /// The weights, in the columns' order.
    pub w: Vec<f64>,
    /// The output RMSE over every recording, µm (`f64::MAX` if not finite).
    pub rmse: f64,
    /// Per recording.
    pub per_file: Vec<FileFit>,
}

fn lock(m: &Mutex<Workspace>) -> std::sync::MutexGuard<'_, Workspace> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl<'a> Problem<'a> {
    /// The problem of fitting `layout` on `data`.
    pub fn new(layout: Layout, data: &'a [CalibData]) -> Self {
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

    /// The same recordings with other columns.
    pub fn with_layout(&self, layout: Layout) -> Problem<'a> {
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
    pub fn fit_all(&self, p: &Nonlinear) -> Result<Fit> {
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
    pub fn rmse(&self, p: &Nonlinear) -> f64 {
        self.fit(p, self.search).map_or(f64::MAX, |f| f.rmse)
    }
}

/// The data's top voltage rounded up to a tenth of its decade (100 V stays 100 V).
pub fn voltage_span(data: &[CalibData]) -> f64 {
    let u_top = data
        .iter()
        .flat_map(|d| d.u.iter())
        .fold(0.0f64, |a, &b| a.max(b));
    let decade = 10f64.powf(u_top.max(1e-9).log10().floor());
    (u_top / decade * 10.0).ceil() * decade / 10.0
}

/// The thresholds `r_i = U·i/N`, `i = 1..N-1`, over the voltage span `U`.
pub fn thresholds(span: f64, operators: usize) -> Vec<f64> {
    (1..operators)
        .map(|i| span * i as f64 / operators as f64)
        .collect()
}

/// The data's mean preload over the fitted windows, rounded to 5 N: the centre
/// of the preload offset's curvature.
pub fn mean_preload(data: &[CalibData]) -> f64 {
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

/// The model of `kind` a fit's weights and nonlinear parameters describe.
pub fn unpack(
    kind: Kind,
    layout: &Layout,
    params: &Nonlinear,
    w: &[f64],
    input_max: f64,
) -> HostModel {
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
    if layout.saturation() {
        c += 1;
    }
    if layout.offset {
        model.offset_um = w[c];
    }
    if layout.input != Input::Plain {
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

/// The float model's stack extension over a recording, driven by its voltage
/// with its measured force, µm.
pub fn simulate(model: &HostModel, d: &CalibData) -> Vec<f64> {
    let m = model.model();
    let mut st = m.state(d.dt);
    (0..d.u.len())
        .map(|k| m.step(&mut st, d.u[k], d.f[k], d.f0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data;
    use crate::method::calibrate::load;

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

    /// The columns of the paper's FPI (`coupled`), the extended FPI (`extended`:
    /// soft dead zone, creep, saturation, compliance), LDPI (`ldpi`) and a PI with a
    /// quadratic output map and an offset (`quadratic`).
    fn layout(which: &str, data: &[CalibData]) -> Layout {
        let span = voltage_span(data);
        let plain = Layout {
            input: Input::Plain,
            thresholds: thresholds(span, 10),
            ldpi: false,
            creep: Vec::new(),
            map: MapFit::Identity,
            offset: false,
            compliance: 0.0,
            force_q: mean_preload(data),
        };
        match which {
            "coupled" => Layout {
                input: Input::Coupled,
                ..plain
            },
            "extended" => Layout {
                input: Input::Extended,
                creep: vec![0.01, 0.03, 0.3, 3.0],
                map: MapFit::Saturation,
                compliance: 0.02,
                ..plain
            },
            "ldpi" => Layout {
                ldpi: true,
                ..plain
            },
            "quadratic" => Layout {
                thresholds: thresholds(span, 21),
                map: MapFit::Quadratic,
                offset: true,
                ..plain
            },
            _ => unreachable!("{which}"),
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
        for kind in ["extended", "ldpi", "quadratic"] {
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
        let mut pr = Problem::new(layout("coupled", &data), &data);
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
        let pr = Problem::new(layout("coupled", &data), &data);
        assert_eq!(pr.search, Pick { stride: 2 });
    }
}
