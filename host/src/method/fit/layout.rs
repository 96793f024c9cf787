//! The columns of the least squares ([`Layout`]): which operator outputs,
//! products with the force, creep lags, saturation and offset a kind fits, for
//! the nonlinear parameters of one trial ([`Nonlinear`]).

use super::*;

/// The nonlinear parameters of one trial (0 where a kind has none).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Nonlinear {
    /// Force coupling `k_f`, V/N.
    pub k_f: f64,
    /// Curvature `k_q` of the preload offset, V/N².
    pub k_q: f64,
    /// Constant `k0` of the preload offset, V.
    pub k0: f64,
    /// Softness of the dead zone, V.
    pub softness: f64,
    /// Curvature `γ` of a quadratic output map, 1/µm.
    pub gamma: f64,
}

/// How the effective voltage `û` of a sample is formed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Input {
    /// The voltage: `û = max(u, 0)`.
    Plain,
    /// The paper's FPI: `û = max(u − k_f·F, 0)`.
    Coupled,
    /// The extended FPI: `û = g(u − U_p(F))`, `U_p(F) = k0 + k_f·F + k_q·(F − F_q)²`,
    /// `g` the dead zone of softness `s`.
    Extended,
}

/// The map after the PI, as the least squares fit it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapFit {
    /// None.
    Identity,
    /// The saturation `z + β·z² = Y`, `β` fitted by equation error (a `−z²` column).
    Saturation,
    /// The quadratic `x = Y + γ·Y²`, `γ` given ([`Nonlinear::gamma`]): the weights are
    /// fitted to the inverse-mapped extension, weighted by the map's slope.
    Quadratic,
}

/// The columns of a calibration: what the least squares fit, for given
/// nonlinear parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// The effective voltage.
    pub input: Input,
    /// Thresholds of the play operators (`w0` has none), V.
    pub thresholds: Vec<f64>,
    /// Weights affine in the force (LDPI): a second column per operator, times `F`.
    pub ldpi: bool,
    /// Time constants of the creep lags, s.
    pub creep: Vec<f64>,
    /// The map after the PI.
    pub map: MapFit,
    /// A constant offset column.
    pub offset: bool,
    /// Stack compliance, µm/N (fixed, not fitted).
    pub compliance: f64,
    /// The preload the curvature of `U_p` is centred on, N.
    pub force_q: f64,
}

impl Layout {
    /// What every play-operator kind starts from: `opt.operators` operators over
    /// the data's voltage span ([`thresholds`]) on the plain voltage, an offset if
    /// `opt` asks for one, nothing else.
    pub fn plain(opt: &Options, data: &[CalibData]) -> Self {
        Self {
            input: Input::Plain,
            thresholds: thresholds(voltage_span(data), opt.operators),
            ldpi: false,
            creep: Vec::new(),
            map: MapFit::Identity,
            offset: opt.offset,
            compliance: 0.0,
            force_q: mean_preload(data),
        }
    }

    pub(super) fn saturation(&self) -> bool {
        self.map == MapFit::Saturation
    }

    pub(super) fn columns(&self) -> usize {
        let n = 1 + self.thresholds.len();
        n * if self.ldpi { 2 } else { 1 }
            + self.creep.len()
            + self.saturation() as usize
            + self.offset as usize
    }

    pub(super) fn nonneg(&self) -> Vec<bool> {
        let n = 1 + self.thresholds.len();
        let mut v = vec![!self.ldpi; n * if self.ldpi { 2 } else { 1 }];
        v.extend(std::iter::repeat_n(true, self.creep.len()));
        if self.saturation() {
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
        match self.input {
            Input::Coupled => (u - p.k_f * f).max(0.0),
            Input::Extended => {
                let q = f - self.force_q;
                dead_zone(p.softness, u - (p.k0 + p.k_f * f + p.k_q * q * q)).0
            }
            Input::Plain => u.max(0.0),
        }
    }

    /// Runs the columns' recurrences (effective voltage, play operators, creep
    /// lags) over every sample of a recording up to the end of its fitted window,
    /// and calls `visit(k, row, target, weight)` for the fitted samples `pick`
    /// takes: the sample's columns, its equation-error target and its weight.
    /// Nothing is stored: memory does not grow with the samples. `pre`: the
    /// effective voltages, if [`effective_all`](Self::effective_all) computed them.
    pub(super) fn scan(
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
        let quadratic = (self.map == MapFit::Quadratic).then_some(OutputMap::Quadratic {
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
            // Targets: the extension (plus the compliance term).
            let mut z = d.x[k] + self.compliance * (f - d.f0);
            if self.saturation() {
                row[c] = -z * z;
                c += 1;
            }
            if self.offset {
                row[c] = 1.0;
            }
            let mut weight = 1.0;
            if let Some(map) = quadratic {
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
    pub(super) fn effective_all(&self, d: &CalibData, p: &Nonlinear, out: &mut Vec<f64>) {
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
    pub(super) fn output(
        &self,
        row: &[f64],
        w: &[f64],
        map: &OutputMap,
        d: &CalibData,
        k: usize,
    ) -> f64 {
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
        self.saturation()
            .then(|| self.columns() - 1 - self.offset as usize)
    }

    pub(super) fn map(&self, w: &[f64], p: &Nonlinear) -> OutputMap {
        if let Some(c) = self.saturation_column() {
            OutputMap::Saturation { beta_per_um: w[c] }
        } else if self.map == MapFit::Quadratic {
            OutputMap::Quadratic {
                gamma_per_um: p.gamma,
            }
        } else {
            OutputMap::Identity
        }
    }
}
