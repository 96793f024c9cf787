//! Trials through the board: the references the feedforward is judged on, run
//! with the loops closed and recorded at every tick on the position sensor —
//! what autotune refines the feedforward's taps on
//! ([`crate::method::tune::trials`]).
//!
//! Each trial starts from rest (50 ms held), so that the loops' response is the
//! response from rest the refinement models:
//!
//! * the 10 → 20 µm step, a 1.5 ms raised cosine, 30 ms recorded;
//! * the 100 Hz triangle over 5–35 µm, three periods from its start at 20 µm
//!   going up, 5 ms after its end recorded.

use anyhow::{bail, Result};
use fpi_protocol::record::signal;
use fpi_protocol::Shape;

use super::client::{real, Client};
use super::closed_loop::{TRIANGLE_HZ, WAVE_UM};
use super::follow::{no_fault, Capture, Follow};
use super::step::StepSettings;
use crate::method::tune::trials::Trial;

/// What a trial records: the tracked reference, the position sensor, the status.
pub const SIGNALS: u8 = signal::X_REF | signal::X_SENSOR | signal::STATUS;

/// Periods of the triangle a trial runs.
pub const TRIANGLE_PERIODS: u32 = 3;

/// Ticks recorded before the reference moves.
const PRE_ROLL: u32 = 20;

/// Runs `go` (which starts the reference moving, and says on which tick) from
/// rest at `start_um`, and records [`SIGNALS`] at every tick for `seconds`
/// after it; the trial, from [`PRE_ROLL`] ticks before.
fn record(
    c: &mut Client,
    what: &str,
    start_um: f64,
    seconds: f64,
    go: impl FnOnce(&mut Client) -> Result<u32>,
) -> Result<Trial> {
    let mut f = Follow::new(c, SIGNALS);
    f.rest_at(start_um, what)?;
    let ticks = f.ticks(seconds);
    let cap = Capture {
        what,
        decimation: 1,
        seconds,
        hint: "a trial records every tick; or autotune with --trials 0",
    };
    let from = f.capture(&cap, go, |s, from| {
        no_fault(s, what)?;
        Ok(s.tick >= from + ticks)
    })?;
    let to = from + ticks;
    let s: Vec<_> = f
        .rec
        .samples
        .iter()
        .filter(|s| s.tick + PRE_ROLL >= from && s.tick < to)
        .collect();
    if s.first().is_none_or(|s| s.tick + PRE_ROLL != from)
        || s.windows(2).any(|w| w[1].tick != w[0].tick + 1)
    {
        bail!("{what}: the recording has gaps");
    }
    Trial::new(
        s.iter().map(|s| real(s.x_ref)).collect(),
        s.iter().map(|s| real(s.x_sensor)).collect(),
    )
}

/// The trials, on a board holding with its loops closed: the step, then the
/// triangle.
pub fn run(c: &mut Client) -> Result<Vec<Trial>> {
    let s = StepSettings::default();
    let step = record(c, "the trial's step", s.from_um, 0.03, |c| {
        c.step(s.to_um, s.duration_ms)
    })?;
    let seconds = f64::from(TRIANGLE_PERIODS) / TRIANGLE_HZ + 0.005;
    let triangle = record(c, "the trial's triangle", WAVE_UM.0, seconds, |c| {
        c.wave(
            Shape::Triangle,
            WAVE_UM.1,
            WAVE_UM.0,
            TRIANGLE_HZ,
            TRIANGLE_PERIODS,
        )
    })?;
    // The wave ends where it began, holding.
    Follow::new(c, 0).until_rest("the trial's triangle")?;
    Ok(vec![step, triangle])
}
