//! Refining a several-axis stage's FEM grid from measured runs of the built
//! stage (`fpi axes refine`): the one-axis refinement ([`crate::method::refine`])
//! on every axis at once, with the coupled prediction.
//!
//! A built stage's axes differ from their FEM as a one-axis stage does: each
//! stack's preload by a few percent, each axis's kinematics by a few percent.
//! Three numbers per axis ([`FemCorrection`]) say so: the preload scale `s_i`
//! (preload on stack `i` `= s_i·f_F,i(x_1, …, x_N)`), the gain `g_i` and offset
//! `b_i` of axis `i`'s output (`= g_i·f_K,i(x_1, …, x_N) + b_i`).
//!
//! The scales change every stack's extension through the coupled equation, so
//! the estimate alternates as the one-axis one does: predict every run coupled
//! with the scales, re-estimate every `s_i` from stack `i`'s measured force
//! (least squares of `force_N@i` against the predicted preload), until no scale
//! moves by more than the tolerance; then each axis's `g_i`, `b_i` from its
//! measured output (`x_fhps_um@i`), exact for the last scales. The actuators'
//! parameters are not touched.

use anyhow::{bail, Context, Result};
use piezo_sim::axes::AXIS_NAMES;

use crate::method::axes::grid::FemGrid;
use crate::method::axes::predict::{self, AxesPrediction};
use crate::method::model::{FemCorrection, HostModel, CORRECTION_RANGE};
use crate::method::predict::{metrics, Metrics};
use crate::method::refine::{Options, Sums, UNEXPLAINED_FRACTION};

/// A measured run of every axis: `t_s`, and per axis `voltage_V@i`,
/// `force_N@i` and `x_fhps_um@i`.
#[derive(Debug, Clone, PartialEq)]
pub struct AxesRun {
    /// Its file, for messages.
    pub name: String,
    /// Time, s.
    pub t: Vec<f64>,
    /// Each axis's drive, V.
    pub u: Vec<Vec<f64>>,
    /// Each stack's measured force, N.
    pub f: Vec<Vec<f64>>,
    /// Each axis's measured output, µm.
    pub x: Vec<Vec<f64>>,
}

/// What [`estimate`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct AxesRefinement {
    /// Each axis's correction (with its RMSE before and after over all runs;
    /// the caller fills in the grid's file and the runs).
    pub corrections: Vec<FemCorrection>,
    /// Predict/estimate rounds taken.
    pub iterations: usize,
    /// Each axis's output error over all runs' samples, with the grid as it is.
    pub before: Vec<Metrics>,
    /// The same with the corrected grid.
    pub after: Vec<Metrics>,
    /// Runs and axes the corrected grid still does not explain (each names the
    /// file and the axis).
    pub warnings: Vec<String>,
}

/// Estimates the correction of every axis of `grid` from measured `runs` of
/// the built stage with `models` (one per stack, in axis order; `names` name
/// them in errors; their own corrections are ignored: the estimate is
/// relative to `grid` as it is).
pub fn estimate(
    models: &[&HostModel],
    names: &[String],
    grid: &FemGrid,
    runs: &[AxesRun],
    opt: &Options,
) -> Result<AxesRefinement> {
    let n = grid.axes();
    if runs.is_empty() {
        bail!("refining needs at least one measured run");
    }
    for r in runs {
        check_run(r, n)?;
        predict::check(models, names, grid, &r.u).with_context(|| r.name.clone())?;
    }
    // The models' own corrections are not applied: `coupled` runs on the
    // grid it is given, here the grid with the scales of this round.
    let run_all = |s: &[f64]| -> Result<Vec<AxesPrediction>> {
        let mut g = grid.clone();
        for (i, si) in s.iter().enumerate() {
            g = g.corrected(i, 1.0, 0.0, *si)?;
        }
        Ok(runs
            .iter()
            .map(|r| predict::coupled(models, &g, &r.t, &r.u))
            .collect())
    };
    let before = run_all(&vec![1.0; n])?;
    let (mut s, mut preds) = (vec![1.0; n], before.clone());
    let mut iterations = 0;
    loop {
        let sums = sums(runs, &preds, n);
        let mut next = s.clone();
        for i in 0..n {
            let Some(ratio) = sums[i].preload_ratio() else {
                bail!(
                    "{}: the grid's preload on stack {} is zero along the runs",
                    run_names(runs),
                    AXIS_NAMES[i]
                );
            };
            next[i] = s[i] * ratio;
            in_range(i, "preload scale", next[i], runs, "the measured force_N is not this grid's preload (another stage, or a force sensor in other units or not zeroed?)")?;
        }
        iterations += 1;
        let settled = (0..n).all(|i| (next[i] - s[i]).abs() <= opt.tolerance * s[i]);
        s = next;
        preds = run_all(&s)?;
        if settled {
            break;
        }
        if iterations >= opt.max_iterations {
            bail!(
                "{}: the preload scales did not settle in {} rounds (last {s:?}); the runs may \
                 not suit the models",
                run_names(runs),
                opt.max_iterations
            );
        }
    }
    let sums = sums(runs, &preds, n);
    let mut corrections = Vec::with_capacity(n);
    let (mut b4, mut af) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut warnings = Vec::new();
    for i in 0..n {
        let Some((g, b)) = sums[i].gain_offset() else {
            bail!(
                "{}: the predicted output of axis {} does not move: its gain cannot be estimated",
                run_names(runs),
                AXIS_NAMES[i]
            );
        };
        in_range(i, "stage gain", g, runs, "the measured x_fhps_um is not this grid's output (another stage, or a sensor in other units?)")?;
        let (mut m, mut p0, mut p1) = (Vec::new(), Vec::new(), Vec::new());
        for ((r, q0), q) in runs.iter().zip(&before).zip(&preds) {
            let after: Vec<f64> = q.x_fhps[i].iter().map(|y| g * y + b).collect();
            if let Some(w) = unexplained(r, i, &after) {
                warnings.push(w);
            }
            m.extend_from_slice(&r.x[i]);
            p0.extend_from_slice(&q0.x_fhps[i]);
            p1.extend(after);
        }
        let (before, after) = (metrics(&p0, &m), metrics(&p1, &m));
        let c = FemCorrection {
            stage_gain: g,
            stage_offset_um: b,
            preload_scale: s[i],
            rmse_before_um: Some(before.rmse),
            rmse_after_um: Some(after.rmse),
            ..FemCorrection::identity()
        };
        c.validate()?;
        corrections.push(c);
        b4.push(before);
        af.push(after);
    }
    Ok(AxesRefinement {
        corrections,
        iterations,
        before: b4,
        after: af,
        warnings,
    })
}

/// A warning where axis `i` of run `r`, refined (`after`, µm), still misses
/// its measured output by more than [`UNEXPLAINED_FRACTION`] of its stroke, as
/// the one-axis refinement warns.
fn unexplained(r: &AxesRun, i: usize, after: &[f64]) -> Option<String> {
    let x = &r.x[i];
    let lo = x.iter().copied().fold(f64::INFINITY, f64::min);
    let stroke = x.iter().copied().fold(f64::NEG_INFINITY, f64::max) - lo;
    let rmse = metrics(after, x).rmse;
    (rmse > UNEXPLAINED_FRACTION * stroke).then(|| {
        format!(
            "{}: refined, axis {}'s output RMSE is still {rmse:.3} µm ({:.1} % of its {stroke:.1} \
             µm stroke): the models do not explain this run (the mechanical dynamics of a fast \
             drive? another stage?) and the correction may be biased by it; refine on slow runs \
             and score on others (fpi axes compare)",
            r.name,
            AXIS_NAMES[i],
            100.0 * rmse / stroke.max(f64::MIN_POSITIVE)
        )
    })
}

/// The stacks' models, each with its axis's correction of `grid` estimated
/// from `runs` ([`estimate`]), naming the grid (its source) and the runs:
/// what `fpi axes refine` writes and Python's `refine_axes` returns.
pub fn refine_models(
    models: &[&HostModel],
    names: &[String],
    grid: &FemGrid,
    runs: &[AxesRun],
) -> Result<(Vec<HostModel>, AxesRefinement)> {
    let r = estimate(models, names, grid, runs, &Options::default())?;
    let refined = models
        .iter()
        .zip(&r.corrections)
        .map(|(m, c)| HostModel {
            fem_correction: Some(FemCorrection {
                fem: grid.source.clone(),
                refined_on: runs.iter().map(|r| r.name.clone()).collect(),
                ..c.clone()
            }),
            ..(*m).clone()
        })
        .collect();
    Ok((refined, r))
}

/// Each axis's least-squares sums over every run's samples.
fn sums(runs: &[AxesRun], preds: &[AxesPrediction], n: usize) -> Vec<Sums> {
    let mut out = vec![Sums::default(); n];
    for (r, p) in runs.iter().zip(preds) {
        for (i, s) in out.iter_mut().enumerate() {
            s.add_samples(&r.f[i], &r.x[i], &p.preload[i], &p.x_fhps[i]);
        }
    }
    out
}

/// Checks a run can refine: every axis's columns, of one length, a force
/// reading and motion on every axis.
fn check_run(r: &AxesRun, n: usize) -> Result<()> {
    let len = r.t.len();
    if r.u.len() != n || r.f.len() != n || r.x.len() != n {
        bail!(
            "{}: {} axes of drive, {} of force and {} of output for a grid of {n} stacks",
            r.name,
            r.u.len(),
            r.f.len(),
            r.x.len()
        );
    }
    if len < 2 {
        bail!("{}: a run needs at least two samples", r.name);
    }
    for (i, a) in AXIS_NAMES.iter().enumerate().take(n) {
        if [r.u[i].len(), r.f[i].len(), r.x[i].len()]
            .iter()
            .any(|&m| m != len)
        {
            bail!(
                "{}: the columns of axis {a} are not as long as t_s ({len})",
                r.name
            );
        }
        if r.f[i].iter().all(|f| f.abs() < 1e-9) {
            bail!(
                "{}: column force_N@{a} is zero throughout: no force was measured, and the \
                 preload scale comes from the force sensor's reading",
                r.name
            );
        }
    }
    Ok(())
}

/// The names of the runs, for messages.
fn run_names(runs: &[AxesRun]) -> String {
    runs.iter()
        .map(|r| r.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Refuses a scale or gain of axis `i` outside [`CORRECTION_RANGE`], naming
/// the runs.
fn in_range(i: usize, what: &str, v: f64, runs: &[AxesRun], hint: &str) -> Result<()> {
    let (lo, hi) = CORRECTION_RANGE;
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        bail!(
            "{}: the estimated {what} of axis {} is {v:.4}, outside {lo}..{hi}: {hint}",
            run_names(runs),
            AXIS_NAMES[i]
        );
    }
    Ok(())
}
