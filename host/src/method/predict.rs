//! Part III of the method: predicting the stage from its design (first paper,
//! Table 1, Step 4): for every sample of a drive signal, the coupled equation
//! `x_pea = X(u, f_F(x_pea))` solved exactly ([`piezo_sim::solve::coupled`]),
//! the model's memory committed only for the solution, then `x_fhps = f_K(x_pea)`.
//! [`predict`] asks the model's kind ([`ModelKind::predict`]); the kinds evaluated
//! as the float model run [`coupled`].
//!
//! [`ModelKind::predict`]: crate::method::model::ModelKind::predict

use anyhow::{bail, Result};
use piezo_sim::solve::{coupled as solve, WarmStart};
use piezo_sim::stats::ErrorStats;

use crate::data::fem::FemMaps;
use crate::method::limits::AMPLIFIER_MAX_V;
use crate::method::model::HostModel;

pub use crate::method::series::Prediction;

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

/// Predicts the stage for a drive `u(t)`: the coupled solve at every sample, as
/// the model's kind does it. Refuses a drive outside the model's [`input_range`]
/// (the model would clamp it and predict another drive than the one given).
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
    model.kind.predict(model, fem, t, u)
}

/// The float model's prediction ([`HostModel::model`]): Newton on the coupled
/// equation at every sample, warm-started at the previous solution.
pub fn coupled(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let m = model.model();
    let maps = fem.maps();
    let mut st = m.state(dt);
    let f_ref = maps.rest_preload();
    let mut p = Prediction::of_drive(t, u);
    let mut warm = WarmStart::default();
    for &uk in u {
        let s = solve(&m, &st, uk, &maps, f_ref, warm.guess());
        m.commit(&mut st, s.uh);
        warm.push(s.x);
        p.push(&maps, s.x, s.evaluations);
    }
    Ok(p)
}

/// The stage output the model reaches at `u_top` on the loading curve (a slow
/// ramp from rest), µm.
pub fn reachable_top(model: &HostModel, fem: &FemMaps, u_top: f64, dt: f64) -> Result<f64> {
    let n = 2000;
    let t: Vec<f64> = (0..=n).map(|k| k as f64 * dt).collect();
    let u: Vec<f64> = (0..=n).map(|k| u_top * k as f64 / n as f64).collect();
    let p = predict(model, fem, &t, &u)?;
    Ok(p.x_fhps[p.x_fhps.len() - 1])
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
