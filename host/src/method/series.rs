//! The time series the model kinds take and give: a recording prepared for
//! calibration, a predicted run and an inverted trajectory.

use piezo_sim::fem::Fem;
use piezo_sim::stats::ErrorStats;

use crate::method::sections::FileFit;

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

/// The output-error figures of a recording's window.
pub fn file_fit(d: &CalibData, e: &ErrorStats<f64>) -> FileFit {
    FileFit {
        file: d.name.clone(),
        samples: e.count() as usize,
        rmse_um: e.rms(),
        mte_um: e.max_abs(),
    }
}

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

/// An inverted trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Inversion {
    /// Time, s.
    pub t: Vec<f64>,
    /// Voltage to apply, V.
    pub u: Vec<f64>,
    /// Target samples outside the reachable stroke (clamped to it).
    pub clamped_targets: usize,
    /// Samples whose voltage hit the amplifier's range.
    pub clamped_voltage: usize,
    /// The reachable stroke, µm of stage output.
    pub reachable: (f64, f64),
}
