//! Every axis of a stage of several stacks predicted from its FEM grid
//! ([`FemGrid`]), as the first paper's coupled equation asks for all stacks at
//! once: at each sample, the extensions `x_i` such that every stack's model,
//! under the preload the stage puts on it at *all* the stacks' extensions,
//! gives back its own,
//!
//! ```text
//! x_i = X_i(u_i, f_F,i(x_1, …, x_N))      i = 1 … N
//! ```
//!
//! then every axis's output `f_K,i(x_1, …, x_N)`. The system is solved by sweeps
//! of the one-stack solver ([`piezo_sim::solve::coupled`], exact on each slice of
//! the grid) over the stacks, each with the others at their latest extensions,
//! until no extension moves by more than [`TOLERANCE_UM`]. A stack's
//! sensitivity to the others' preload is small (its compliance and `k_f` times
//! the couplings: about 0.015 per sweep on the XY stage), so two or three sweeps
//! do.
//!
//! [`independent_axes`] is what a one-axis method gives: each axis predicted alone
//! from its own FEM tables ([`FemGrid::alone`]), blind to the others.

use anyhow::{bail, Context, Result};
use piezo_sim::axes::AXIS_NAMES;
use piezo_sim::solve::{coupled as solve, WarmStart};

use crate::method::axes::grid::{column, FemGrid};
use crate::method::model::HostModel;
use crate::method::predict::{self as one_axis, metrics, outside_range, Metrics};

/// Sweeps are done when no stack's extension moves more than this, µm.
pub const TOLERANCE_UM: f64 = 1e-11;
/// Most sweeps of one sample.
pub const MAX_SWEEPS: usize = 50;

/// A predicted run of every axis.
#[derive(Debug, Clone, PartialEq)]
pub struct AxesPrediction {
    /// Time, s.
    pub t: Vec<f64>,
    /// Each axis's drive, V.
    pub u: Vec<Vec<f64>>,
    /// Each stack's extension, µm.
    pub x_pea: Vec<Vec<f64>>,
    /// The preload on each stack, N.
    pub preload: Vec<Vec<f64>>,
    /// Each axis's output, µm.
    pub x_fhps: Vec<Vec<f64>>,
    /// Model evaluations, all stacks and samples.
    pub evaluations: usize,
    /// Sweeps over the stacks, all samples (one per sample for independent axes).
    pub sweeps: usize,
}

impl AxesPrediction {
    fn empty(t: &[f64], u: &[Vec<f64>]) -> Self {
        let n = u.len();
        Self {
            t: t.to_vec(),
            u: u.to_vec(),
            x_pea: vec![Vec::with_capacity(t.len()); n],
            preload: vec![Vec::with_capacity(t.len()); n],
            x_fhps: vec![Vec::with_capacity(t.len()); n],
            evaluations: 0,
            sweeps: 0,
        }
    }

    /// The prediction's columns, named as its file's (`t_s`, then per axis
    /// `voltage_V@x`, `x_pea_um@x`, `preload_N@x`, `x_fhps_um@x`, …).
    pub fn columns(&self) -> Vec<(String, &[f64])> {
        let mut cols = vec![("t_s".to_string(), self.t.as_slice())];
        for i in 0..self.u.len() {
            for (name, c) in [
                ("voltage_V", &self.u[i]),
                ("x_pea_um", &self.x_pea[i]),
                ("preload_N", &self.preload[i]),
                ("x_fhps_um", &self.x_fhps[i]),
            ] {
                cols.push((column(name, i), c.as_slice()));
            }
        }
        cols
    }

    /// Model evaluations per sample and stack.
    pub fn evaluations_per_sample(&self) -> f64 {
        self.evaluations as f64 / (self.t.len() * self.u.len()).max(1) as f64
    }

    /// Each axis's error figures against its measured output (µm).
    pub fn metrics(&self, measured: &[Vec<f64>]) -> Vec<Metrics> {
        self.x_fhps
            .iter()
            .zip(measured)
            .map(|(p, m)| metrics(p, m))
            .collect()
    }
}

/// Which of the `given` models each of `axes` stacks takes: one model for
/// every stack, or one per stack in axis order; refused otherwise, naming
/// `key` (the CLI's `--model`, Python's `models`).
pub fn model_of_each_stack(given: usize, axes: usize, key: &str) -> Result<Vec<usize>> {
    if given != 1 && given != axes {
        bail!(
            "{key}: {given} given for a grid of {axes} stacks; give one for every stack or one \
             per stack (in the order {})",
            super::record::names(axes)
        );
    }
    Ok((0..axes).map(|i| i.min(given - 1)).collect())
}

/// Refuses what the several-axis method cannot run: a model count other than
/// one per stack, a model of branch polynomials (its own solver) and a drive
/// outside a model's input range (a correction refined on another FEM is
/// refused by [`stage_grid`]). `names` name the models in errors.
pub fn check(
    models: &[&HostModel],
    names: &[String],
    grid: &FemGrid,
    u: &[Vec<f64>],
) -> Result<()> {
    let n = grid.axes();
    if models.len() != n || u.len() != n {
        bail!(
            "{}: {} stacks, but {} models and {} drives",
            grid.source,
            n,
            models.len(),
            u.len()
        );
    }
    for (i, m) in models.iter().enumerate() {
        if m.branch.is_some() {
            bail!(
                "{}: a model of branch polynomials has its own solver and no several-axis \
                 method; calibrate stack {} as efpi, fpi, pi, ldpi, epi or gpi",
                names[i],
                AXIS_NAMES[i]
            );
        }
        if let Some((k, v)) = outside_range(m, &u[i]) {
            let (lo, hi) = one_axis::input_range(m);
            bail!(
                "voltage_V@{} sample {}: {v} V is outside {}'s input range {lo}..{hi} V",
                AXIS_NAMES[i],
                k + 1,
                names[i]
            );
        }
    }
    Ok(())
}

/// Every axis of the drive `u` (V, one per stack) at times `t` (s) predicted
/// from the grid with `models` (one per stack; `names` name them in errors):
/// coupled, or each axis alone (`independent`). Checks the inputs first
/// ([`check`]).
pub fn run(
    models: &[&HostModel],
    names: &[String],
    grid: &FemGrid,
    t: &[f64],
    u: &[Vec<f64>],
    independent: bool,
) -> Result<AxesPrediction> {
    if u.len() != grid.axes() {
        bail!(
            "the drive has {} axes, the grid {} ({})",
            u.len(),
            grid.axes(),
            grid.source
        );
    }
    if t.len() < 2 || u.iter().any(|ui| ui.len() != t.len()) {
        bail!(
            "a drive needs at least two samples, as many of every axis as of time ({})",
            t.len()
        );
    }
    check(models, names, grid, u)?;
    let grid = stage_grid(models, names, grid)?;
    if independent {
        independent_axes(models, &grid, t, u)
    } else {
        Ok(coupled(models, &grid, t, u))
    }
}

/// The grid the `models` run with: `grid`, with each stack's model's
/// `[fem_correction]` (`fpi axes refine`) on its stack and axis
/// ([`FemCorrection::apply_grid`](crate::method::model::FemCorrection::apply_grid));
/// the several-axis counterpart of [`HostModel::stage_maps`]. `names` name
/// the models in errors.
pub fn stage_grid(models: &[&HostModel], names: &[String], grid: &FemGrid) -> Result<FemGrid> {
    let mut g = grid.clone();
    for (i, m) in models.iter().enumerate() {
        if let Some(c) = &m.fem_correction {
            g = c
                .apply_grid(&g, i)
                .with_context(|| format!("{} (stack {})", names[i], AXIS_NAMES[i]))?;
        }
    }
    Ok(g)
}

/// The coupled prediction of every axis (see the module docs); `models[i]` is
/// stack `i`'s, `u[i]` its drive (V) at times `t` (s). Call [`check`] first.
pub fn coupled(models: &[&HostModel], grid: &FemGrid, t: &[f64], u: &[Vec<f64>]) -> AxesPrediction {
    let n = grid.axes();
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1).max(1) as f64;
    let m: Vec<_> = models.iter().map(|h| h.model()).collect();
    let mut st: Vec<_> = m.iter().map(|m| m.state(dt)).collect();
    let zero = vec![0.0; n];
    let f_ref: Vec<f64> = (0..n).map(|i| grid.preload_at(i, &zero)).collect();
    let mut warm = vec![WarmStart::default(); n];
    let mut p = AxesPrediction::empty(t, u);
    let (mut x, mut uh) = (vec![0.0; n], vec![0.0; n]);
    for k in 0..t.len() {
        let uk: Vec<f64> = u.iter().map(|ui| ui[k]).collect();
        for i in 0..n {
            x[i] = warm[i].guess();
        }
        for _ in 0..MAX_SWEEPS {
            p.sweeps += 1;
            let mut moved: f64 = 0.0;
            for i in 0..n {
                let slice = grid.slice(i, &x);
                let s = solve(&m[i], &st[i], uk[i], &slice, f_ref[i], x[i]);
                p.evaluations += s.evaluations;
                moved = moved.max((s.x - x[i]).abs());
                (x[i], uh[i]) = (s.x, s.uh);
            }
            if moved <= TOLERANCE_UM {
                break;
            }
        }
        for i in 0..n {
            m[i].commit(&mut st[i], uh[i]);
            warm[i].push(x[i]);
            p.x_pea[i].push(x[i]);
            p.preload[i].push(grid.preload_at(i, &x));
            p.x_fhps[i].push(grid.output_at(i, &x));
        }
    }
    p
}

/// Each axis predicted alone from its own FEM tables ([`FemGrid::alone`]), as a
/// one-axis method does ([`crate::method::predict::predict`]).
pub fn independent_axes(
    models: &[&HostModel],
    grid: &FemGrid,
    t: &[f64],
    u: &[Vec<f64>],
) -> Result<AxesPrediction> {
    let mut p = AxesPrediction::empty(t, u);
    for (i, m) in models.iter().enumerate() {
        let Some(maps) = grid.alone(i) else {
            bail!(
                "{}: axis {} alone has no FEM table",
                grid.source,
                AXIS_NAMES[i]
            );
        };
        let one = one_axis::predict(m, &maps, t, &u[i])?;
        p.evaluations += one.iterations;
        p.x_pea[i] = one.x_pea;
        p.preload[i] = one.preload;
        p.x_fhps[i] = one.x_fhps;
    }
    p.sweeps = t.len();
    Ok(p)
}
