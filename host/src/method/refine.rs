//! Refining a stage's FEM tables from measured runs of the built stage (`fpi refine`).
//!
//! The method predicts a stage from its design; what remains of its error on a
//! built stage is mostly the FEM's: its kinematics `f_K` and its preload `f_F` are
//! a few percent off. One measured run (`t_s,voltage_V,force_N,x_fhps_um`) is
//! enough to estimate three numbers ([`FemCorrection`]):
//!
//! * the preload scale `s` (preload `= s·f_F(x_pea)`): from the force column,
//!   least squares of the measured force against the preload predicted at the
//!   predicted stack extension;
//! * the gain `g` and offset `b` of the stage output (`= g·f_K(x_pea) + b`): least
//!   squares of the measured output against `f_K` at the predicted extension.
//!
//! The scale changes the prediction through the coupling (more preload, less
//! effective voltage, less extension), so the two steps alternate: predict with
//! `s`, re-estimate `s`, `g`, `b`, until `s` settles. `g` and `b` do not act on
//! the stack extension, so they are exact for the last `s`. The actuator's
//! parameters (its hysteresis, coupling, creep) are not touched.
//!
//! Three numbers from thousands of samples cannot over-fit in the usual sense,
//! but they can absorb an actuator error into the stage's: score a refined model
//! on runs it was not refined on (`fpi compare` marks the runs a model was
//! refined on and sums up the others).

use std::path::Path;

use anyhow::{bail, Context, Result};
use rayon::prelude::*;

use crate::data::fem::FemMaps;
use crate::data::StageRun;
use crate::method::model::{FemCorrection, HostModel, CORRECTION_RANGE};
use crate::method::predict::{self, Metrics, Prediction};

/// How the alternation stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Most predict/estimate rounds.
    pub max_iterations: usize,
    /// Stop when the preload scale changes by less than this (relative).
    pub tolerance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tolerance: 1e-10,
        }
    }
}

/// The fit of one run before and after the correction.
#[derive(Debug, Clone, PartialEq)]
pub struct RunFit {
    /// The run's file.
    pub file: String,
    /// Samples.
    pub samples: usize,
    /// Stage output error with the FEM tables as they are.
    pub before: Metrics,
    /// Stage output error with the corrected tables.
    pub after: Metrics,
    /// RMS of measured − predicted force with the FEM tables as they are, N.
    pub force_rmse_before_n: f64,
    /// The same with the corrected tables, N.
    pub force_rmse_after_n: f64,
}

/// What [`estimate`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// The correction (with the fit's RMSE before and after over all runs; the
    /// caller fills in the FEM file and the runs).
    pub correction: FemCorrection,
    /// Predict/estimate rounds taken.
    pub iterations: usize,
    /// Each run's fit.
    pub runs: Vec<RunFit>,
    /// Over all runs' samples, before.
    pub before: Metrics,
    /// Over all runs' samples, after.
    pub after: Metrics,
    /// Runs the corrected model still does not explain (each names the file).
    pub warnings: Vec<String>,
}

/// A run whose stage-output RMSE after the correction is above this fraction of
/// its stroke is not explained by the model (mechanical dynamics of a fast drive,
/// another stage): the correction may be biased by it, and [`estimate`] warns.
pub const UNEXPLAINED_FRACTION: f64 = 0.02;

/// Sums of the least-squares problems over all runs' samples (also of each
/// axis of a several-axis stage's, [`crate::method::axes::refine`]).
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct Sums {
    n: f64,
    /// Measured force × predicted preload, predicted preload².
    fp: f64,
    pp: f64,
    /// Predicted `f_K` (y) and measured output (x): Σy, Σx, Σy², Σxy.
    y: f64,
    x: f64,
    yy: f64,
    xy: f64,
}

impl Sums {
    fn add(&mut self, run: &StageRun, p: &Prediction) {
        self.add_samples(&run.f, &run.x, &p.preload, &p.x_fhps);
    }

    /// Adds samples: measured force `f` (N) and output `x` (µm), predicted
    /// preload `preload` (N) and output `x_fhps` (µm).
    pub(crate) fn add_samples(&mut self, f: &[f64], x: &[f64], preload: &[f64], x_fhps: &[f64]) {
        for k in 0..x.len() {
            let (f, pf) = (f[k], preload[k]);
            let (x, y) = (x[k], x_fhps[k]);
            self.n += 1.0;
            self.fp += f * pf;
            self.pp += pf * pf;
            self.y += y;
            self.x += x;
            self.yy += y * y;
            self.xy += x * y;
        }
    }

    /// The least-squares scale of the predicted preload to the measured force
    /// (`Σ f·p / Σ p²`); `None` when the predicted preload is zero throughout.
    pub(crate) fn preload_ratio(&self) -> Option<f64> {
        (self.pp > 0.0).then(|| self.fp / self.pp)
    }

    /// The least-squares gain and offset of `x ≈ g·y + b`; `None` when `y` does not
    /// vary (the prediction does not move the stage).
    pub(crate) fn gain_offset(&self) -> Option<(f64, f64)> {
        let (my, mx) = (self.y / self.n, self.x / self.n);
        let var = self.yy / self.n - my * my;
        let cov = self.xy / self.n - mx * my;
        (var > 1e-12 * (1.0 + my * my)).then(|| {
            let g = cov / var;
            (g, mx - g * my)
        })
    }
}

/// Checks a run can refine: columns of one length, a force reading and motion.
fn check_run(r: &StageRun) -> Result<()> {
    let name = r.path.display();
    let n = r.t.len();
    if [r.u.len(), r.f.len(), r.x.len()].iter().any(|&m| m != n) {
        bail!(
            "{name}: columns of different lengths (t_s {n}, voltage_V {}, force_N {}, x_fhps_um {})",
            r.u.len(),
            r.f.len(),
            r.x.len()
        );
    }
    if n < 2 {
        bail!("{name}: a run needs at least two samples");
    }
    if r.f.iter().all(|f| f.abs() < 1e-9) {
        bail!(
            "{name}: column force_N is zero throughout: no force was measured, and the preload \
             scale comes from the force sensor's reading"
        );
    }
    let stroke = span(&r.x);
    if stroke < 1e-3 {
        bail!(
            "{name}: column x_fhps_um moves by {} µm only: the stage output's gain cannot be \
             estimated from a run without motion",
            crate::data::Num(stroke)
        );
    }
    Ok(())
}

/// Predicts every run with the FEM's preload scaled by `s` (and `f_K` as it is).
fn predict_all(
    model: &HostModel,
    fem: &FemMaps,
    runs: &[StageRun],
    s: f64,
) -> Result<Vec<Prediction>> {
    let maps = fem.corrected(1.0, 0.0, s)?;
    runs.par_iter()
        .map(|r| {
            predict::predict(model, &maps, &r.t, &r.u).with_context(|| r.path.display().to_string())
        })
        .collect()
}

/// The names of the runs, for messages.
fn names(runs: &[StageRun]) -> String {
    runs.iter()
        .map(|r| r.path.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Refuses a scale or gain outside [`CORRECTION_RANGE`], naming the runs.
fn in_range(what: &str, v: f64, runs: &[StageRun], hint: &str) -> Result<()> {
    let (lo, hi) = CORRECTION_RANGE;
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        bail!(
            "{}: the estimated {what} is {v:.4}, outside {lo}..{hi}: {hint}",
            names(runs)
        );
    }
    Ok(())
}

/// Estimates the correction of `fem` from measured `runs` of the built stage,
/// with `model` (the actuator; its own `[fem_correction]`, if any, is ignored:
/// the estimate is relative to `fem` as it is).
pub fn estimate(
    model: &HostModel,
    fem: &FemMaps,
    runs: &[StageRun],
    opt: &Options,
) -> Result<Refinement> {
    if runs.is_empty() {
        bail!("refining needs at least one measured run");
    }
    for r in runs {
        check_run(r)?;
    }
    let before = predict_all(model, fem, runs, 1.0)?;
    let (mut s, mut preds) = (1.0, before.clone());
    let mut iterations = 0;
    loop {
        let mut sums = Sums::default();
        for (r, p) in runs.iter().zip(&preds) {
            sums.add(r, p);
        }
        let Some(ratio) = sums.preload_ratio() else {
            bail!("{}: the FEM's preload is zero along the runs", names(runs));
        };
        // The preload predicted is s·f_F: the least-squares scale of f_F.
        let next = s * ratio;
        in_range(
            "preload scale",
            next,
            runs,
            "the measured force_N is not this FEM's preload (another stage, or a force sensor \
             in other units or not zeroed?)",
        )?;
        iterations += 1;
        let settled = (next - s).abs() <= opt.tolerance * s;
        s = next;
        preds = predict_all(model, fem, runs, s)?;
        if settled {
            break;
        }
        if iterations >= opt.max_iterations {
            bail!(
                "{}: the preload scale did not settle in {} rounds (last {s}); the runs may \
                 not suit the model",
                names(runs),
                opt.max_iterations
            );
        }
    }
    let mut sums = Sums::default();
    for (r, p) in runs.iter().zip(&preds) {
        sums.add(r, p);
    }
    let Some((g, b)) = sums.gain_offset() else {
        bail!(
            "{}: the predicted stage output does not move: the stage output's gain cannot be \
             estimated",
            names(runs)
        );
    };
    in_range(
        "stage gain",
        g,
        runs,
        "the measured x_fhps_um is not this FEM's stage output (another stage, or a sensor in \
         other units?)",
    )?;
    let mut fits = Vec::with_capacity(runs.len());
    let mut warnings = Vec::new();
    let (mut all_m, mut all_b, mut all_a) = (Vec::new(), Vec::new(), Vec::new());
    for ((r, p0), p) in runs.iter().zip(&before).zip(&preds) {
        let after: Vec<f64> = p.x_fhps.iter().map(|y| g * y + b).collect();
        all_m.extend_from_slice(&r.x);
        all_b.extend_from_slice(&p0.x_fhps);
        all_a.extend_from_slice(&after);
        let stroke = span(&r.x);
        let rmse = predict::metrics(&after, &r.x).rmse;
        if rmse > UNEXPLAINED_FRACTION * stroke {
            warnings.push(format!(
                "{}: refined, the stage output's RMSE is still {rmse:.3} µm ({:.1} % of its \
                 {stroke:.1} µm stroke): the model does not explain this run (the mechanical \
                 dynamics of a fast drive? another stage?) and the correction may be biased by \
                 it; refine on slow runs and score on others (fpi compare)",
                r.path.display(),
                100.0 * rmse / stroke
            ));
        }
        fits.push(RunFit {
            file: r.path.display().to_string(),
            samples: r.x.len(),
            before: predict::metrics(&p0.x_fhps, &r.x),
            after: predict::metrics(&after, &r.x),
            force_rmse_before_n: predict::metrics(&p0.preload, &r.f).rmse,
            force_rmse_after_n: predict::metrics(&p.preload, &r.f).rmse,
        });
    }
    let (before, after) = (
        predict::metrics(&all_b, &all_m),
        predict::metrics(&all_a, &all_m),
    );
    let correction = FemCorrection {
        stage_gain: g,
        stage_offset_um: b,
        preload_scale: s,
        rmse_before_um: Some(before.rmse),
        rmse_after_um: Some(after.rmse),
        ..FemCorrection::identity()
    };
    correction.validate()?;
    Ok(Refinement {
        correction,
        iterations,
        runs: fits,
        before,
        after,
        warnings,
    })
}

/// `model` with the correction of `fem` estimated from `runs` ([`estimate`]),
/// naming the FEM (its source) and the runs (their paths): what `fpi refine`
/// writes and Python's `Model.refine` returns.
pub fn refine_model(
    model: &HostModel,
    fem: &FemMaps,
    runs: &[StageRun],
) -> Result<(HostModel, Refinement)> {
    let r = estimate(model, fem, runs, &Options::default())?;
    let refined = HostModel {
        fem_correction: Some(FemCorrection {
            fem: fem.source.clone(),
            refined_on: runs.iter().map(|r| r.path.display().to_string()).collect(),
            ..r.correction.clone()
        }),
        ..model.clone()
    };
    Ok((refined, r))
}

/// Largest minus smallest value.
fn span(v: &[f64]) -> f64 {
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    hi - lo
}

/// Whether `run` is one of the runs correction `c` was refined on: the same file
/// (when both paths resolve), else the same file name.
pub fn was_refined_on(c: &FemCorrection, run: &Path) -> bool {
    let canon = run.canonicalize().ok();
    c.refined_on.iter().any(|p| {
        let p = Path::new(p);
        match (p.canonicalize().ok(), &canon) {
            (Some(a), Some(b)) => &a == b,
            _ => p.file_name().is_some() && p.file_name() == run.file_name(),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data;
    use crate::method::model::Kind;
    use piezo_sim::file::{CouplingSection, PiSection};

    /// The paper's FPI with weights of the kind the rig gives.
    fn fpi() -> HostModel {
        let mut m = HostModel::new(
            Kind::Fpi,
            PiSection {
                w0_um_per_v: 0.0626,
                thresholds_v: vec![10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0],
                weights_um_per_v: vec![
                    0.0126, 0.0075, 0.006, 0.0038, 0.0026, 0.0012, 0.0012, 0.0007, 0.0011,
                ],
                input_max_v: 150.0,
            },
        );
        m.coupling.k_f_v_per_n = 0.1;
        m
    }

    /// An efpi model: soft dead zone, compliance, saturation (all through the
    /// preload's reference, which the scale moves).
    fn efpi() -> HostModel {
        let mut m = fpi();
        m.kind = Kind::Efpi;
        m.coupling = CouplingSection {
            offset_v: -0.4,
            k_f_v_per_n: 0.106,
            k_q_v_per_n2: 1.6e-4,
            force_q_n: 75.0,
            compliance_um_per_n: 0.02,
            force_ref_n: None,
        };
        m.dead_zone_softness_v = 1.8;
        m.output = crate::method::model::OutputMap::Saturation {
            beta_per_um: 0.0037,
        };
        m
    }

    fn stage_a() -> FemMaps {
        FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap()
    }

    /// A run of the stage whose true maps are `truth`: a decaying 5 Hz sine, 0–100 V.
    fn synthetic(model: &HostModel, truth: &FemMaps, name: &str) -> StageRun {
        let n = 4000;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 2e-4).collect();
        let u: Vec<f64> = t
            .iter()
            .map(|&t| {
                let a = 50.0 * (1.0 - 0.6 * t / 0.8);
                a - a * (std::f64::consts::TAU * 5.0 * t).cos()
            })
            .collect();
        let p = predict::predict(model, truth, &t, &u).unwrap();
        StageRun {
            path: name.into(),
            t,
            u,
            f: p.preload,
            x: p.x_fhps,
        }
    }

    #[test]
    fn recovers_a_known_gain_offset_and_scale() {
        let fem = stage_a();
        for model in [fpi(), efpi()] {
            for (g, b, s) in [(0.97, 0.05, 0.971), (1.03, -0.2, 1.04), (1.0, 0.0, 1.0)] {
                let truth = fem.corrected(g, b, s).unwrap();
                let run = synthetic(&model, &truth, "synthetic.csv");
                let r = estimate(&model, &fem, &[run], &Options::default()).unwrap();
                let c = &r.correction;
                println!(
                    "{}: truth ({g}, {b}, {s}) estimated ({:.9}, {:.9}, {:.9}) in {} rounds; \
                     RMSE {:.3e} -> {:.3e} um",
                    model.kind,
                    c.stage_gain,
                    c.stage_offset_um,
                    c.preload_scale,
                    r.iterations,
                    r.before.rmse,
                    r.after.rmse
                );
                assert!((c.stage_gain - g).abs() < 1e-9, "{c:?}");
                assert!((c.stage_offset_um - b).abs() < 1e-8, "{c:?}");
                assert!((c.preload_scale - s).abs() < 1e-9, "{c:?}");
                assert!(r.after.rmse < 1e-6, "{:?}", r.after);
                assert!(r.runs[0].force_rmse_after_n < 1e-5, "{:?}", r.runs[0]);
            }
        }
    }

    #[test]
    fn a_correction_applied_predicts_the_distorted_stage() {
        // Estimated on one run, the corrected model predicts another drive of the
        // same distorted stage (the held-out case, without noise).
        let fem = stage_a();
        let model = efpi();
        let truth = fem.corrected(0.975, 0.03, 0.97).unwrap();
        let fit = synthetic(&model, &truth, "fit.csv");
        let r = estimate(&model, &fem, &[fit], &Options::default()).unwrap();
        let mut refined = model.clone();
        refined.fem_correction = Some(r.correction);
        let t: Vec<f64> = (0..3000).map(|k| k as f64 * 2e-4).collect();
        let u: Vec<f64> = t
            .iter()
            .map(|&t| 40.0 - 40.0 * (std::f64::consts::TAU * 15.0 * t).cos())
            .collect();
        let measured = predict::predict(&model, &truth, &t, &u).unwrap().x_fhps;
        let raw = predict::predict(&model, &fem, &t, &u).unwrap().x_fhps;
        let maps = refined.stage_maps(&fem).unwrap();
        let corrected = predict::predict(&refined, &maps, &t, &u).unwrap().x_fhps;
        let (b, a) = (
            predict::metrics(&raw, &measured).rmse,
            predict::metrics(&corrected, &measured).rmse,
        );
        println!("held-out RMSE: FEM as it is {b:.3e} um, refined {a:.3e} um");
        assert!(b > 0.1 && a < 1e-6, "{b} {a}");
    }

    #[test]
    fn runs_that_cannot_refine_are_refused_by_name() {
        let fem = stage_a();
        let model = fpi();
        let mut run = synthetic(&model, &fem, "noforce.csv");
        run.f.iter_mut().for_each(|f| *f = 0.0);
        let e = estimate(&model, &fem, &[run], &Options::default()).unwrap_err();
        assert!(e.to_string().contains("noforce.csv: column force_N"), "{e}");

        let mut run = synthetic(&model, &fem, "short.csv");
        run.x.pop();
        let e = estimate(&model, &fem, &[run], &Options::default()).unwrap_err();
        assert!(
            e.to_string().contains("short.csv: columns of different"),
            "{e}"
        );

        // A force in other units (kN): the scale is refused, not written.
        let mut run = synthetic(&model, &fem, "kn.csv");
        run.f.iter_mut().for_each(|f| *f *= 1e-3);
        let e = estimate(&model, &fem, &[run], &Options::default()).unwrap_err();
        assert!(
            e.to_string()
                .contains("kn.csv: the estimated preload scale"),
            "{e}"
        );
    }

    #[test]
    fn refined_on_matches_the_same_file() {
        let c = FemCorrection {
            refined_on: vec!["data/stage-a/sine_05Hz.csv.gz".into()],
            ..FemCorrection::identity()
        };
        assert!(was_refined_on(&c, Path::new("other/dir/sine_05Hz.csv.gz")));
        assert!(!was_refined_on(
            &c,
            Path::new("data/stage-a/sine_15Hz.csv.gz")
        ));
    }
}
