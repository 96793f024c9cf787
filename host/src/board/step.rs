//! `fpi board step`: a step through the board, recorded and scored — rise
//! time, overshoot, settling to ±0.1 µm and to a tolerance — on the stage's
//! true position where the board knows it (the emulated board), else on the
//! position sensor.
//!
//! The step is the board's raised-cosine step ([`Command::Step`](fpi_protocol::Command::Step)): the
//! reference goes from `A` to `B` along half a cosine lasting `duration_ms`
//! (zero speed at both ends, so it does not kick the mode), then holds. Every
//! figure is timed from the tick the step starts.

use anyhow::{bail, Result};
use fpi_firmware::control::recorder::signal;

use super::client::{real, Client};
use super::follow::{no_fault, Capture, Follow};
use super::recording::Recording;

/// What a step records.
pub const SIGNALS: u8 =
    signal::X_REF | signal::VOLTAGE | signal::X_TRUE | signal::X_SENSOR | signal::STATUS;

/// The settling band of the targets, µm.
pub const SETTLE_UM: f64 = 0.1;

/// The step to make.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepSettings {
    /// From, µm.
    pub from_um: f64,
    /// To, µm.
    pub to_um: f64,
    /// Board time recorded from the step's start, s.
    pub seconds: f64,
    /// A second settling band, µm.
    pub tol_um: Option<f64>,
    /// The raised cosine's duration, ms.
    pub duration_ms: f64,
    /// Ticks per recorded sample.
    pub decimation: u16,
}

impl Default for StepSettings {
    fn default() -> Self {
        Self {
            from_um: 10.0,
            to_um: 20.0,
            seconds: 0.05,
            tol_um: None,
            duration_ms: 1.5,
            decimation: 1,
        }
    }
}

/// A step's figures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepFigures {
    /// 10–90 % rise time, ms.
    pub rise_ms: f64,
    /// Largest excursion beyond the target, µm.
    pub overshoot_um: f64,
    /// Time from the step's start until the position stays within ±0.1 µm of
    /// the target, ms (`None`: not within the record).
    pub settle_ms: Option<f64>,
    /// The same for `tol_um`.
    pub settle_tol_ms: Option<f64>,
    /// Mean offset from the target over the record's last fifth, µm.
    pub final_error_um: f64,
    /// Whether the figures are on the true position (else the sensor's).
    pub true_position: bool,
    /// Recorded ticks in which the board's reference governor departed from
    /// the step (it asked for more than the stage can take within its stroke
    /// and its force room): the step the stage made was slower.
    pub governed_ticks: usize,
}

/// Scores the recorded step `a → b` started at tick `from` (see [`StepFigures`]).
pub fn figures(rec: &Recording, from: u32, (a, b): (f64, f64), tol_um: Option<f64>) -> StepFigures {
    let true_position = rec.signals & signal::X_TRUE != 0
        && rec
            .samples
            .iter()
            .any(|s| s.x_true != fpi_firmware::control::recorder::NO_TRUE_POSITION);
    let pts: Vec<(f64, f64)> = rec
        .samples
        .iter()
        .filter(|s| s.tick >= from)
        .map(|s| {
            let x = if true_position { s.x_true } else { s.x_sensor };
            ((s.tick - from) as f64 / rec.rate_hz * 1e3, real(x))
        })
        .collect();
    let sign = if b >= a { 1.0 } else { -1.0 };
    let first = |level: f64| {
        pts.iter()
            .find(|(_, x)| sign * (x - level) >= 0.0)
            .map(|p| p.0)
    };
    let rise_ms = match (first(a + 0.1 * (b - a)), first(a + 0.9 * (b - a))) {
        (Some(t1), Some(t9)) => t9 - t1,
        _ => f64::NAN,
    };
    let overshoot_um = pts.iter().map(|p| sign * (p.1 - b)).fold(0.0, f64::max);
    let settle = |band: f64| match pts.iter().rposition(|(_, x)| (x - b).abs() > band) {
        None => pts.first().map(|p| p.0),
        Some(i) => pts.get(i + 1).map(|p| p.0),
    };
    let end = pts.last().map_or(0.0, |p| p.0);
    let tail: Vec<f64> = pts
        .iter()
        .filter(|p| p.0 >= 0.8 * end)
        .map(|p| p.1 - b)
        .collect();
    StepFigures {
        rise_ms,
        overshoot_um,
        settle_ms: settle(SETTLE_UM),
        settle_tol_ms: tol_um.and_then(settle),
        final_error_um: tail.iter().sum::<f64>() / tail.len().max(1) as f64,
        true_position,
        governed_ticks: rec
            .samples
            .iter()
            .filter(|s| s.status & fpi_firmware::control::recorder::status::GOVERNED != 0)
            .count(),
    }
}

/// Makes the step `s` on the board `c` in whatever loop it runs: moves to
/// `from_um`, rests 50 ms, records, steps; the recording from the step's start
/// and its figures. The board is left holding at `to_um`.
pub fn run(c: &mut Client, s: &StepSettings) -> Result<(Recording, StepFigures)> {
    if !(s.seconds > 0.0 && s.seconds <= 10.0) {
        bail!("--seconds {}: in (0, 10]", s.seconds);
    }
    if let Some(t) = s.tol_um {
        if !(t > 0.0 && t.is_finite()) {
            bail!("--tol {t}: a band > 0 µm");
        }
    }
    let mut f = Follow::new(c, SIGNALS);
    f.rest_at(s.from_um, "the approach")?;
    let ticks = f.ticks(s.seconds);
    let cap = Capture {
        what: "the step",
        decimation: s.decimation,
        seconds: s.seconds,
        hint: "shorten --seconds or raise --decimation",
    };
    let from = f.capture(
        &cap,
        |c| c.step(s.to_um, s.duration_ms),
        |st, from| {
            no_fault(st, "the step")?;
            Ok(st.tick >= from + ticks)
        },
    )?;
    f.rec
        .samples
        .retain(|x| x.tick >= from && x.tick < from + ticks);
    let fig = figures(&f.rec, from, (s.from_um, s.to_um), s.tol_um);
    Ok((f.rec, fig))
}

/// The figures as a table row: rise, overshoot, settling.
pub fn describe(fig: &StepFigures, tol_um: Option<f64>) -> String {
    let ms = |v: Option<f64>| v.map_or("not within the record".into(), |v| format!("{v:.2} ms"));
    let mut t = format!(
        "rise (10–90 %) {:.2} ms, overshoot {:.3} µm, settles within ±{SETTLE_UM} µm after {}",
        fig.rise_ms,
        fig.overshoot_um,
        ms(fig.settle_ms)
    );
    if let Some(tol) = tol_um {
        t.push_str(&format!(
            ", within ±{tol} µm after {}",
            ms(fig.settle_tol_ms)
        ));
    }
    t.push_str(&format!(
        "; final error {:+.3} µm ({})",
        fig.final_error_um,
        if fig.true_position {
            "true position"
        } else {
            "position sensor"
        }
    ));
    if fig.governed_ticks > 0 {
        t.push_str(&format!(
            "; the board's reference governor slowed {} ticks of it (the stage cannot take \
             that step so fast within its stroke and force room)",
            fig.governed_ticks
        ));
    }
    t
}
