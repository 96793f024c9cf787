//! Scoring models against measured stage runs (Actuators 2025, 14(8):411, Table 4 and
//! Figs. 14–16).

use anyhow::{Context, Result};
use rayon::prelude::*;

use crate::data::fem::FemMaps;
use crate::data::StageRun;
use crate::method::model::HostModel;
use crate::method::predict::{self, Metrics, Prediction};

/// One model's prediction of one run.
#[derive(Debug, Clone)]
pub struct Scored {
    /// The prediction.
    pub prediction: Prediction,
    /// Its error against the measured stage output.
    pub metrics: Metrics,
}

/// Every model on every run.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// Model names (file stems) and models, the first being the baseline.
    pub models: Vec<(String, HostModel)>,
    /// The measured runs.
    pub runs: Vec<StageRun>,
    /// `scores[run][model]`.
    pub scores: Vec<Vec<Scored>>,
    /// The runs' names in the report and its plots' file names (file names,
    /// made unique by [`unique_names`]).
    pub run_names: Vec<String>,
}

/// Names made unique: the first of equal names keeps it, the next get `-2`, `-3`,
/// … before the extension (skipping names already taken), so that two inputs
/// named alike do not share their plots.
pub fn unique_names(names: &[String]) -> Vec<String> {
    let mut taken: std::collections::HashSet<String> = names.iter().cloned().collect();
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::with_capacity(names.len());
    for (i, name) in names.iter().enumerate() {
        if seen.insert(name.as_str()) {
            out.push(name.clone());
            continue;
        }
        let (stem, ext) = split_extension(name);
        let renamed = (2..=names.len() + 1)
            .map(|k| format!("{stem}-{k}{ext}"))
            .find(|n| !taken.contains(n))
            .unwrap_or_else(|| format!("{stem}-input{}{ext}", i + 1));
        taken.insert(renamed.clone());
        out.push(renamed);
    }
    out
}

/// Prints a note for every input renamed by [`unique_names`] (`what`: "run",
/// "model").
pub fn note_renamed(what: &str, paths: &[&std::path::Path], names: &[String], unique: &[String]) {
    for ((p, a), b) in paths.iter().zip(names).zip(unique) {
        if a != b {
            eprintln!(
                "note: another {what} is also named {a:?}: {} is {b:?} in the report",
                p.display()
            );
        }
    }
}

/// `("run", ".csv")` from `"run.csv"`; `("model", "")` from `"model"`.
fn split_extension(name: &str) -> (&str, &str) {
    match name.rfind('.') {
        Some(i) if i > 0 => name.split_at(i),
        _ => (name, ""),
    }
}

/// A run's name: its file name without `.gz`.
pub fn run_file_name(path: &std::path::Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().trim_end_matches(".gz").to_string())
        .unwrap_or_default()
}

impl Comparison {
    /// Predicts every run with every model (runs in parallel), each model with the
    /// stage maps it runs with ([`HostModel::stage_maps`]: `fem`, corrected by the
    /// model's `[fem_correction]` if it has one).
    pub fn run(fem: &FemMaps, runs: &[StageRun], models: &[(String, HostModel)]) -> Result<Self> {
        let maps = models
            .iter()
            .map(|(name, m)| m.stage_maps(fem).with_context(|| format!("model {name}")))
            .collect::<Result<Vec<_>>>()?;
        let scores = runs
            .par_iter()
            .map(|r| {
                models
                    .iter()
                    .zip(&maps)
                    .map(|((_, m), fem)| {
                        let prediction = predict::predict(m, fem, &r.t, &r.u)?;
                        let metrics = predict::metrics(&prediction.x_fhps, &r.x);
                        Ok(Scored {
                            prediction,
                            metrics,
                        })
                    })
                    .collect::<Result<Vec<_>>>()
            })
            .collect::<Result<Vec<_>>>()?;
        let names: Vec<String> = runs.iter().map(|r| run_file_name(&r.path)).collect();
        let run_names = unique_names(&names);
        let paths: Vec<&std::path::Path> = runs.iter().map(|r| r.path.as_path()).collect();
        note_renamed("run", &paths, &names, &run_names);
        Ok(Self {
            models: models.to_vec(),
            runs: runs.to_vec(),
            scores,
            run_names,
        })
    }

    /// MAE reduction of model `m` against the first model on run `r`, %.
    pub fn reduction(&self, r: usize, m: usize) -> f64 {
        let base = self.scores[r][0].metrics.mae;
        100.0 * (base - self.scores[r][m].metrics.mae) / base
    }

    /// Whether model `m` was refined on run `r` (`fpi refine`): its score there is
    /// in-sample.
    pub fn refined_on(&self, r: usize, m: usize) -> bool {
        self.models[m]
            .1
            .fem_correction
            .as_ref()
            .is_some_and(|c| crate::method::refine::was_refined_on(c, &self.runs[r].path))
    }

    /// The cells of model `m`'s row on run `r` that compare it: its MAE reduction
    /// against the first model (`(baseline)` for the first) and, where its score is
    /// in-sample, the note saying so. The terminal table and the report show the
    /// same.
    pub fn row_cells(&self, r: usize, m: usize) -> (String, Option<&'static str>) {
        let reduction = if m == 0 {
            "(baseline)".to_string()
        } else {
            format!("{:.1} %", self.reduction(r, m))
        };
        let note = self
            .refined_on(r, m)
            .then_some("(refined on this run: in-sample)");
        (reduction, note)
    }

    /// The runs no model was refined on: where refined models are scored fairly.
    pub fn held_out(&self) -> Vec<usize> {
        (0..self.runs.len())
            .filter(|&r| (0..self.models.len()).all(|m| !self.refined_on(r, m)))
            .collect()
    }

    /// The run's name (its file name, made unique among the runs).
    pub fn run_name(&self, r: usize) -> String {
        self.run_names
            .get(r)
            .cloned()
            .unwrap_or_else(|| run_file_name(&self.runs[r].path))
    }
}

impl Comparison {
    /// Adds, for every model, its prediction followed by the identified dynamics
    /// `d` (the Hammerstein structure of [`crate::method::dynamics`]) as another
    /// model named `NAME+dyn`, scored on every run. Each run must be sampled
    /// uniformly.
    pub fn add_dynamics(&mut self, d: &crate::method::dynamics::Dynamics) -> Result<()> {
        let base = self.models.len();
        for m in 0..base {
            let (name, model) = self.models[m].clone();
            for (r, run) in self.runs.iter().enumerate() {
                let dt = crate::method::dynamics::uniform_step(&run.t).map_err(|(k, ..)| {
                    anyhow::anyhow!(
                        "{}:{}: column t_s: not uniformly sampled (the dynamics need it)",
                        run.path.display(),
                        k + 3
                    )
                })?;
                let mut prediction = self.scores[r][m].prediction.clone();
                prediction.x_fhps = d.apply(&prediction.x_fhps, dt)?;
                let metrics = predict::metrics(&prediction.x_fhps, &run.x);
                self.scores[r].push(Scored {
                    prediction,
                    metrics,
                });
            }
            self.models.push((format!("{name}+dyn"), model));
        }
        Ok(())
    }
}

/// Prints the comparison table (MAE, RMSE, MTE, MAE reduction vs the first model).
pub fn print_table(c: &Comparison) {
    for (r, _) in c.runs.iter().enumerate() {
        println!("{}:", c.run_name(r));
        println!(
            "  {:<28} {:<10} {:>9} {:>9} {:>9} {:>16}",
            "model", "method", "MAE µm", "RMSE µm", "MTE µm", "MAE reduction"
        );
        for (m, (name, model)) in c.models.iter().enumerate() {
            let s = &c.scores[r][m].metrics;
            let (red, note) = c.row_cells(r, m);
            let note = note.map_or(String::new(), |n| format!("  {n}"));
            println!(
                "  {:<28} {:<10} {:>9.3} {:>9.3} {:>9.3} {:>16}{note}",
                name,
                model.kind.method(),
                s.mae,
                s.rmse,
                s.mte,
                red
            );
        }
    }
    print_held_out(c);
}

/// When a model carries a `[fem_correction]`: each model's mean MAE and RMSE over
/// the runs no model was refined on (the fair comparison of refined models).
fn print_held_out(c: &Comparison) {
    for line in held_out_summary(c) {
        println!("{line}");
    }
}

/// The lines of `print_held_out` (none when no model carries a correction): the
/// terminal and the report show the same.
pub fn held_out_summary(c: &Comparison) -> Vec<String> {
    if c.models.iter().all(|(_, m)| m.fem_correction.is_none()) {
        return Vec::new();
    }
    let held = c.held_out();
    if held.is_empty() {
        let refined: Vec<&str> = c
            .models
            .iter()
            .filter(|(_, m)| m.fem_correction.is_some())
            .map(|(n, _)| n.as_str())
            .collect();
        return vec![format!(
            "held-out runs: none (every run was refined on by {}); give runs not refined on \
             to score the refinement",
            refined.join(", ")
        )];
    }
    let names: Vec<String> = held.iter().map(|&r| c.run_name(r)).collect();
    let mut lines = vec![
        format!(
            "held-out runs (no model was refined on them): {}",
            names.join(", ")
        ),
        format!(
            "  {:<28} {:<10} {:>9} {:>9}",
            "model", "method", "MAE µm", "RMSE µm"
        ),
    ];
    for (m, (name, model)) in c.models.iter().enumerate() {
        let mean = |f: fn(&Metrics) -> f64| {
            held.iter()
                .map(|&r| f(&c.scores[r][m].metrics))
                .sum::<f64>()
                / held.len() as f64
        };
        let tag = match &model.fem_correction {
            Some(k) => format!(
                "  FEM refined: gain {:.4}, offset {:.3} µm, preload ×{:.4}",
                k.stage_gain, k.stage_offset_um, k.preload_scale
            ),
            None => "  FEM as it is".to_string(),
        };
        lines.push(format!(
            "  {:<28} {:<10} {:>9.3} {:>9.3}{tag}",
            name,
            model.kind.method(),
            mean(|s| s.mae),
            mean(|s| s.rmse)
        ));
    }
    lines
}
