//! Part III of the method: predicting the stage from its design (first paper,
//! Table 1, Step 4): for every sample of a drive signal, the coupled equation
//! `x_pea = X(u, f_F(x_pea))` solved exactly ([`piezo_sim::solve::coupled`]),
//! the model's memory committed only for the solution, then `x_fhps = f_K(x_pea)`.

use anyhow::{bail, Result};
use piezo_sim::fem::Fem;
use piezo_sim::solve::{coupled, WarmStart};
use piezo_sim::stats::ErrorStats;

use crate::data::fem::FemMaps;
use crate::method::export::AMPLIFIER_MAX_V;
use crate::method::model::HostModel;

/// A predicted run.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// Time, s.
    pub t: Vec<f64>,
    /// Drive voltage, V.
    pub u: Vec<f64>,
    /// Stack extension, µm.
    pub x_pea: Vec<f64>,
    /// Preload on the stack, N.
    pub preload: Vec<f64>,
    /// Stage output, µm.
    pub x_fhps: Vec<f64>,
    /// Model evaluations of the solver, total.
    pub iterations: usize,
}

impl Prediction {
    /// An empty prediction of the drive `u` (V) at times `t` (s).
    pub fn of_drive(t: &[f64], u: &[f64]) -> Self {
        let n = u.len();
        Self {
            t: t.to_vec(),
            u: u.to_vec(),
            x_pea: Vec::with_capacity(n),
            preload: Vec::with_capacity(n),
            x_fhps: Vec::with_capacity(n),
            iterations: 0,
        }
    }

    /// Appends a sample's solution `x_pea` (µm), found in `evaluations` model
    /// evaluations: its preload and stage output from the stage's `maps`.
    pub fn push(&mut self, maps: &Fem<'_, f64>, x_pea: f64, evaluations: usize) {
        self.iterations += evaluations;
        self.x_pea.push(x_pea);
        self.preload.push(maps.preload_at(x_pea));
        self.x_fhps.push(maps.stage_at(x_pea));
    }
}

/// The drive voltages a model takes, V: its input range `0..=pi.input_max_v`
/// ([`HostModel::input_max_v`]), and no more than the board's amplifier span
/// ([`AMPLIFIER_MAX_V`]).
pub fn input_range(model: &HostModel) -> (f64, f64) {
    (0.0, model.input_max_v().min(AMPLIFIER_MAX_V))
}

/// The first drive sample outside [`input_range`]: its index and voltage, V.
pub fn outside_range(model: &HostModel, u: &[f64]) -> Option<(usize, f64)> {
    let (lo, hi) = input_range(model);
    u.iter()
        .position(|v| !(lo..=hi).contains(v))
        .map(|k| (k, u[k]))
}

/// Predicts the stage for a drive `u(t)`: the coupled solve at every sample.
/// Refuses a drive outside the model's [`input_range`] (the model would clamp it
/// and predict another drive than the one given).
pub fn predict(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
    if t.len() != u.len() || t.len() < 2 {
        bail!("a drive needs at least two samples of time and voltage");
    }
    if let Some((k, v)) = outside_range(model, u) {
        let (lo, hi) = input_range(model);
        bail!(
            "drive sample {}: {v} V is outside the model's input range {lo}..{hi} V",
            k + 1
        );
    }
    if model.kind == crate::method::model::Kind::Branch {
        return crate::method::branch::predict(model, fem, t, u);
    }
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let m = model.model();
    let maps = fem.maps();
    let mut st = m.state(dt);
    let f_ref = maps.rest_preload();
    let mut p = Prediction::of_drive(t, u);
    let mut warm = WarmStart::default();
    for &uk in u {
        let s = coupled(&m, &st, uk, &maps, f_ref, warm.guess());
        m.commit(&mut st, s.uh);
        warm.push(s.x);
        p.push(&maps, s.x, s.evaluations);
    }
    Ok(p)
}

/// Error figures of a prediction against a measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    /// Mean absolute error, µm.
    pub mae: f64,
    /// Root-mean-square error, µm.
    pub rmse: f64,
    /// Largest absolute error (MTE), µm.
    pub mte: f64,
}

/// MAE, RMSE and MTE of `predicted − measured`.
pub fn metrics(predicted: &[f64], measured: &[f64]) -> Metrics {
    let s = ErrorStats::of_difference(predicted, measured);
    Metrics {
        mae: s.mae(),
        rmse: s.rms(),
        mte: s.max_abs(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data;
    use crate::method::calibrate::{self, Options};
    use crate::method::model::Kind;

    /// Bisection on the coupled equation: slow, but obviously right.
    fn bisect(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Vec<f64> {
        let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
        let model = model.model();
        let mut st = model.state(dt);
        let f_ref = fem.rest_preload();
        u.iter()
            .map(|&uk| {
                let (mut lo, mut hi) = (-20.0, 40.0);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    let (f, df) = fem.preload_with_slope(mid);
                    if model.peek(&st, uk, f, df, f_ref).x > mid {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let x = 0.5 * (lo + hi);
                let (f, df) = fem.preload_with_slope(x);
                let p = model.peek(&st, uk, f, df, f_ref);
                model.commit(&mut st, p.uh);
                x
            })
            .collect()
    }

    #[test]
    fn newton_solve_equals_bisection_for_every_kind() {
        let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
        let rig = calibrate::load(&data::datasets_in("pea-rig")[6..9], None).unwrap();
        let run = data::read_stage(&data::dataset("stage-a/sine_15Hz.csv")).unwrap();
        for kind in [Kind::Pi, Kind::Ldpi, Kind::Fpi, Kind::Efpi] {
            let m = calibrate::calibrate(&rig, &Options::for_kind(kind)).unwrap();
            let fast = predict(&m, &fem, &run.t, &run.u).unwrap();
            let slow = bisect(&m, &fem, &run.t, &run.u);
            let worst = fast
                .x_pea
                .iter()
                .zip(&slow)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            println!(
                "{kind}: worst |Newton - bisection| {worst:.2e} um, {:.2} evaluations/sample",
                fast.iterations as f64 / run.t.len() as f64
            );
            assert!(worst < 1e-12, "{kind}: {worst} um");
            assert!(
                fast.iterations < 5 * run.t.len(),
                "{kind}: {} iterations",
                fast.iterations
            );
        }
    }
}
