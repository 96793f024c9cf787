//! Recordings of the virtual XY and XYZ stages: as built
//! ([`piezo_sim::axes::xy_built`], [`xyz_built`](piezo_sim::axes::xyz_built)),
//! and their nominal twins ([`piezo_sim::axes::xy_nominal`], [`xyz_nominal`](piezo_sim::axes::xyz_nominal): only the stacks
//! differ from the FEM design, so a prediction's error is the model's and the
//! couplings'): what the several-axis method is scored on. Each axis's drive goes straight
//! to its amplifier (open loop, no board), at the virtual stage's 20 kHz.

use anyhow::{bail, Result};
use piezo_sim::axes::{Axes, AxesSpec, AXIS_NAMES};
use piezo_sim::stage::stage_a;

use crate::method::axes::grid::column;

/// The virtual stage's sample period, s.
pub fn sample_period_s() -> f64 {
    1.0 / stage_a::BUILT.sample_rate_hz as f64
}

/// A recording of every axis of a virtual stage.
#[derive(Debug, Clone, PartialEq)]
pub struct AxesRecording {
    /// Time, s.
    pub t: Vec<f64>,
    /// Per axis: drive (V), force-sensor reading (N), stack extension (µm), true
    /// output (µm) and position-sensor reading (µm).
    pub axes: Vec<[Vec<f64>; 5]>,
}

/// The recording's columns per axis, in [`AxesRecording::axes`]' order.
pub const COLUMNS: [&str; 5] = [
    "voltage_V",
    "force_N",
    "x_pea_um",
    "x_fhps_um",
    "x_sensed_um",
];

impl AxesRecording {
    /// The header and columns of the recording's file.
    pub fn columns(&self) -> (Vec<String>, Vec<&[f64]>) {
        let mut names = vec!["t_s".to_string()];
        let mut cols: Vec<&[f64]> = vec![&self.t];
        for (i, a) in self.axes.iter().enumerate() {
            for (name, c) in COLUMNS.iter().zip(a) {
                names.push(column(name, i));
                cols.push(c);
            }
        }
        (names, cols)
    }
}

/// Records `stage` (a nominal twin, a stage as built, or a variant of one:
/// [`AxesSpec`]) under drives `u` (one per axis,
/// V, at [`sample_period_s`]), from rest; `seed` seeds the sensors' noise.
pub fn record(stage: &AxesSpec, u: &[Vec<f64>], seed: u32) -> Result<AxesRecording> {
    if u.len() != stage.axes {
        bail!(
            "the stage has {} axes; the drive has {} (voltage_V@x, @y[, @z])",
            stage.axes,
            u.len()
        );
    }
    Ok(match stage.axes {
        2 => run(stage.build::<2>(seed), u),
        _ => run(stage.build::<3>(seed), u),
    })
}

fn run<const N: usize>(stage: Option<Axes<'static, N>>, u: &[Vec<f64>]) -> AxesRecording {
    // The built stages are always Some (every axis has a mode).
    let Some(mut s) = stage else {
        return AxesRecording {
            t: Vec::new(),
            axes: Vec::new(),
        };
    };
    let samples = u[0].len();
    let mut r = AxesRecording {
        t: (0..samples).map(|k| k as f64 * sample_period_s()).collect(),
        axes: vec![Default::default(); N],
    };
    let drives = (0..samples).map(|k| -> [f64; N] { core::array::from_fn(|i| u[i][k]) });
    for uk in drives {
        let out = s.step(uk.map(|v| v as f32));
        for (i, o) in out.iter().enumerate() {
            let force = s.sense_force(i, o.stack.force_n);
            let sensed = s.sense_position(i);
            let values = [
                uk[i],
                force as f64,
                o.stack.x_pea_um as f64,
                o.x_fhps_um as f64,
                sensed as f64,
            ];
            for (c, v) in r.axes[i].iter_mut().zip(values) {
                c.push(v);
            }
        }
    }
    r
}

/// A drive of every axis at [`sample_period_s`] for `seconds`: axis `i` a raised
/// cosine of 0–100 V at `hz[i]`, or, where `hz[i]` is 0, a half-cosine rise to
/// 50 V in 50 ms, then held. Time (s) and each axis's voltage (V).
pub fn raised_sines(hz: &[f64], seconds: f64) -> (Vec<f64>, Vec<Vec<f64>>) {
    use std::f64::consts::PI;
    let samples = (seconds / sample_period_s()).round() as usize;
    let t: Vec<f64> = (0..samples).map(|k| k as f64 * sample_period_s()).collect();
    let u = hz
        .iter()
        .map(|&f| {
            t.iter()
                .map(|&t| {
                    if f > 0.0 {
                        50.0 - 50.0 * (2.0 * PI * f * t).cos()
                    } else {
                        25.0 * (1.0 - (PI * (t / 0.05).min(1.0)).cos())
                    }
                })
                .collect()
        })
        .collect();
    (t, u)
}

/// The axis names of `n` axes, for messages (`x, y`).
pub fn names(n: usize) -> String {
    AXIS_NAMES[..n].join(", ")
}
