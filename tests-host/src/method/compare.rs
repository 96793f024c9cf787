//! Scoring models against measured stage runs (Actuators 2025, 14(8):411, Table 4 and
//! Figs. 14–16).

use anyhow::Result;
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
}

impl Comparison {
    /// Predicts every run with every model (runs in parallel).
    pub fn run(fem: &FemMaps, runs: &[StageRun], models: &[(String, HostModel)]) -> Result<Self> {
        let scores = runs
            .par_iter()
            .map(|r| {
                models
                    .iter()
                    .map(|(_, m)| {
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
        Ok(Self {
            models: models.to_vec(),
            runs: runs.to_vec(),
            scores,
        })
    }

    /// MAE reduction of model `m` against the first model on run `r`, %.
    pub fn reduction(&self, r: usize, m: usize) -> f64 {
        let base = self.scores[r][0].metrics.mae;
        100.0 * (base - self.scores[r][m].metrics.mae) / base
    }

    /// The run's file name.
    pub fn run_name(&self, r: usize) -> String {
        self.runs[r]
            .path
            .file_name()
            .map(|n| n.to_string_lossy().trim_end_matches(".gz").to_string())
            .unwrap_or_default()
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
            let red = if m == 0 {
                "(baseline)".to_string()
            } else {
                format!("{:.1} %", c.reduction(r, m))
            };
            println!(
                "  {:<28} {:<10} {:>9.3} {:>9.3} {:>9.3} {:>16}",
                name,
                model.kind.method(),
                s.mae,
                s.rmse,
                s.mte,
                red
            );
        }
    }
}
