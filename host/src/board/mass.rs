//! A tuning matched to the stage it is loaded on, before its first step:
//! `fpi board load TUNED.toml --match-mass`.
//!
//! The damping leaves out the force the shaped reference's motion explains at
//! the *tuned* stage's mass, and the board learns the ratio of the stage's mass
//! to that one, `β`, from its steps (`piezo_fpi::lead`). It starts at 1, so
//! the first step on a heavier stage (a payload, a mode that moved from 856 to
//! 700 Hz) is made with the wrong mass: it overshoots by about 1 µm and rings
//! for 4–7 ms (book, `docs/src/mass-ratio.md`, *Why the first step on a
//! heavier stage misses*).
//!
//! Here the host measures the stage's mode through the board — the loops open,
//! damping and shaping off, a sweep of 0.05 µm around the model's mode
//! ([`sweep`]) — and starts `β` at `(f_model/f_stage)²`: the mass ratio at the
//! model's stiffness, as a payload changes it. The board learns on from there.

use anyhow::{bail, Context, Result};
use fpi_protocol::Command;
use piezo_sim::file::FirmwareModel;

use super::autotune::bare;
use super::client::Client;
use super::commands::BadArgument;
use super::frf::{self, FrfSettings};
use super::restore::Before;
use crate::method::tune::frf::FrfPoint;

/// What the match measured and set.
#[derive(Debug, Clone)]
pub struct MassMatch {
    /// The model's mode, Hz.
    pub model_hz: f64,
    /// The stage's, Hz (the peak of the command → position response).
    pub stage_hz: f64,
    /// `β` started at, `(model_hz/stage_hz)²`.
    pub ratio: f64,
    /// The sweep.
    pub points: Vec<FrfPoint>,
}

/// The match's stimulus, µm: half the analyser's usual 0.1 µm. Only the
/// peak's frequency is wanted, and a stage whose mode is lower and less damped
/// than the model's answers a stimulus near its mode with the whole gain of
/// that mode: on a stage at 700 Hz and ζ 0.015, 0.1 µm at the mode swings it
/// by 3.6 µm and its force by 26 N, half the sensor window's room below the
/// preload at 20 µm (71.5 N against 15 N), and above the mode 0.1 µm asks more
/// acceleration than the reference governor lets through, whose braking then
/// rings that mode further. At 0.05 µm neither happens and the peak is as
/// sharp.
pub const AMPLITUDE_UM: f64 = 0.05;

/// The sweep around a model's mode at `mode_hz`: ten frequencies over
/// 0.7–1.45 times it (a mode anywhere in the ±20 % the tuning is designed for,
/// and beyond), then eight within ±15 % of the highest, [`AMPLITUDE_UM`] at
/// 20 µm.
pub fn sweep(mode_hz: f64) -> FrfSettings {
    FrfSettings {
        from_hz: 0.7 * mode_hz,
        to_hz: 1.45 * mode_hz,
        points: 10,
        amplitude_um: AMPLITUDE_UM,
        at_um: 20.0,
        zoom_points: 8,
    }
}

/// The peak of `|x|` over `points` (sorted by frequency), Hz: the highest
/// point refined by the parabola through it and its neighbours in `ln f`
/// (`None` where the highest is at either end: no peak inside the sweep).
pub fn peak_hz(points: &[FrfPoint]) -> Option<f64> {
    let i = (0..points.len()).max_by(|&a, &b| points[a].x.norm().total_cmp(&points[b].x.norm()))?;
    if i == 0 || i + 1 >= points.len() {
        return None;
    }
    let [a, b, c] = [i - 1, i, i + 1].map(|k| (points[k].f_hz.ln(), points[k].x.norm()));
    // The vertex of the parabola through three points.
    let (d1, d2) = (b.0 - a.0, b.0 - c.0);
    let (e1, e2) = (b.1 - a.1, b.1 - c.1);
    let den = d1 * e2 - d2 * e1;
    let shift = if den != 0.0 {
        0.5 * (d1 * d1 * e2 - d2 * d2 * e1) / den
    } else {
        0.0
    };
    Some((b.0 - shift.clamp(-d1.abs(), d2.abs())).exp())
}

/// Measures the stage's mode on the board `c`, which runs `fw` (a tuning
/// with the lead's baseline, as autotune writes it), and starts the board's
/// learned mass ratio at what it implies; leaves the loop, damping and shaping
/// as they were and the stage parked. Refuses a model without the lead, and a
/// mode outside the sweep or a ratio outside `[1/2, 2)`.
pub fn match_mass(c: &mut Client, fw: &FirmwareModel) -> Result<MassMatch> {
    let model_hz = match (&fw.dynamics, &fw.damping) {
        (Some(d), Some(dm)) if dm.lead_baseline.is_some() => d.mode_hz,
        // Refused before anything moves; named as the caller spells it.
        _ => {
            return Err(BadArgument {
                name: "match_mass",
                cli: "--match-mass",
                message: "--match-mass: the model has no learned mass ratio to start (it needs \
                          [dynamics] and [damping] with lead_baseline: a model from `fpi board \
                          autotune`)"
                    .into(),
            }
            .into())
        }
    };
    let before = Before::capture(c)?;
    let sweep = sweep(model_hz);
    let measured = bare(c).and_then(|()| frf::measure(c, &sweep, |_, _| {}));
    // Parked, and the loops as they were, whether the sweep went through or not.
    before.restore(c)?;
    let points = measured.context("--match-mass: measuring the stage's mode")?;
    let Some(stage_hz) = peak_hz(&points) else {
        bail!(
            "--match-mass: no peak between {:.0} and {:.0} Hz around the model's mode at \
             {model_hz:.0} Hz: the stage is not the one this tuning is for (run `fpi board \
             autotune` on it)",
            sweep.from_hz,
            sweep.to_hz
        );
    };
    let ratio = (model_hz / stage_hz).powi(2);
    if !(0.5..2.0).contains(&ratio) {
        bail!(
            "--match-mass: the stage's mode at {stage_hz:.0} Hz makes a mass ratio of \
             {ratio:.2} to the model's ({model_hz:.0} Hz), outside [0.5, 2)"
        );
    }
    c.ack(&Command::LeadRatio {
        axis: c.axis(),
        ratio: piezo_fpi::q::LeadRatio::from_num(ratio).to_bits(),
    })?;
    Ok(MassMatch {
        model_hz,
        stage_hz,
        ratio,
        points,
    })
}

/// What the match found, one line.
pub fn describe(m: &MassMatch) -> String {
    format!(
        "the stage's mode: {:.1} Hz (the model's {:.1} Hz): its mass ratio {:.3} set; the board \
         learns on from it",
        m.stage_hz, m.model_hz, m.ratio
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Complex;

    fn point(f_hz: f64, x: f64) -> FrfPoint {
        FrfPoint {
            f_hz,
            x: Complex::new(x, 0.0),
            force: Complex::new(0.0, 0.0),
            dynamic: Complex::new(0.0, 0.0),
            x_per_v: Complex::new(0.0, 0.0),
            excitation_um: 0.1,
            ticks: 0,
        }
    }

    #[test]
    fn the_peak_is_the_parabolas_vertex_in_ln_f() {
        // A parabola in ln f with its vertex at 700 Hz, sampled off-centre.
        let f0: f64 = 700.0;
        let pts: Vec<FrfPoint> = [600.0, 660.0, 720.0, 790.0]
            .iter()
            .map(|&f: &f64| point(f, 10.0 - 50.0 * (f.ln() - f0.ln()).powi(2)))
            .collect();
        let p = peak_hz(&pts).unwrap();
        assert!((p - f0).abs() < 1e-6, "{p}");
    }

    #[test]
    fn no_peak_inside_the_sweep_is_none() {
        let rising: Vec<FrfPoint> = (1..6).map(|k| point(100.0 * k as f64, k as f64)).collect();
        assert_eq!(peak_hz(&rising), None);
        assert_eq!(peak_hz(&[]), None);
    }
}
