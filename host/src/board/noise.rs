//! The noise at rest, measured through the board: the force sensor's, which
//! the active damping feeds back into the stack and so turns into motion, and
//! the swing that motion and the position sensor's own noise leave in the
//! tracking error, which the loop watch sees.
//!
//! On the emulated stage as built (σ 0.15 N) the loops tuned for ζ 0.5 move
//! the stage 0.02 µm RMS at rest, mostly near 310 Hz; at σ 0.5 N, 0.07 µm; at
//! σ 0.8 N, 0.10 µm, and the loop watch (`firmware/src/control/watch.rs`), which
//! counts swings beyond ±0.2 µm, took that motion for an oscillation after
//! 1.3 s at rest (after 30 ms at σ 0.9 N; nothing in 3 s at σ 0.7 N). So
//! autotune measures the noise before it tunes, prints it, designs the
//! damping for it (`crate::method::tune::NOISE_BUDGET_UM`), and names it
//! where the watch trips nevertheless ([`explain`]: the loops were designed
//! for a quieter sensor than the one measured).
//!
//! With the loops tuned, autotune then measures the swing the watch sees on
//! the tracking error at rest ([`tracking_swing`]) and sets the watch's half
//! swing from it (`crate::method::tune::watch_swing_um`).

use anyhow::{bail, Error, Result};
use fpi_protocol::record::signal;
use fpi_protocol::Command;
use piezo_fpi::control::Fault;

use super::client::{real, Client};
use super::follow::{no_fault, Follow};
use super::warm::close_and_warm_up;
use crate::method::tune::NOISE_BUDGET_UM;

/// Ticks between the samples measured (a recording every link carries).
pub const DECIMATION: u16 = 10;
/// Samples measured (0.2 s at 20 kHz).
pub const SAMPLES: u32 = 400;

/// σ of the force reading at rest, N, with the loops as they are: from the
/// differences of samples [`DECIMATION`] ticks apart (white noise's σ·√2; a
/// stage at rest adds nothing measurable over half a millisecond).
pub fn force_noise(c: &mut Client) -> Result<f64> {
    let mut f = Follow::new(c, signal::FORCE);
    f.record(DECIMATION)?;
    f.rec.samples.clear();
    let t0 = f.c.status()?.tick;
    f.until_tick(t0 + u32::from(DECIMATION) * SAMPLES)?;
    f.c.ack(&Command::RecordStop)?;
    f.drain()?;
    let x: Vec<f64> = f.rec.samples.iter().map(|s| real(s.force)).collect();
    if x.len() < 2 * SAMPLES as usize / 3 {
        bail!(
            "the force at rest: {} samples of the {SAMPLES} recorded reached the host",
            x.len()
        );
    }
    let squares: f64 = x.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum();
    Ok((squares / (2.0 * (x.len() - 1) as f64)).sqrt())
}

/// Ticks of the tracking error recorded at rest (0.1 s at 20 kHz).
pub const SWING_TICKS: u32 = 2000;
/// Ticks the watch's low-pass takes to settle, left out of the RMS.
const SWING_SETTLE: u32 = 200;

/// The RMS of the swing the loop watch sees on the tracking error at rest
/// with the loops the board runs closed at 20 µm, µm: `x_ref − x_sensor` less
/// its one-pole low-pass (the watch's `MEAN_SHIFT`, about 100 Hz), recorded at
/// every tick for [`SWING_TICKS`]. The force sensor's noise the damping feeds
/// back and the position sensor's own both count. The board is left parked.
pub fn tracking_swing(c: &mut Client) -> Result<f64> {
    close_and_warm_up(c)?;
    let mut f = Follow::new(c, signal::X_SENSOR | signal::X_REF);
    f.record(1)?;
    f.rec.samples.clear();
    let t0 = f.c.status()?.tick;
    f.until_tick(t0 + SWING_TICKS)?;
    f.c.ack(&Command::RecordStop)?;
    f.drain()?;
    no_fault(&f.c.status()?, "the tracking error at rest")?;
    let mut e: Vec<(u32, f64)> = f
        .rec
        .samples
        .iter()
        .filter(|s| s.tick >= t0)
        .map(|s| (s.tick, real(s.x_ref) - real(s.x_sensor)))
        .collect();
    e.sort_by_key(|p| p.0);
    if e.len() < 2 * SWING_TICKS as usize / 3 {
        bail!(
            "the tracking error at rest: {} samples of the {SWING_TICKS} recorded reached the host",
            e.len()
        );
    }
    let alpha = 1.0 / f64::from(1u32 << fpi_firmware::control::watch::MEAN_SHIFT);
    let (mut mean, mut sum, mut n) = (e[0].1, 0.0, 0usize);
    for &(tick, x) in &e {
        let hp = x - mean;
        mean += alpha * hp;
        if tick >= t0 + SWING_SETTLE {
            sum += hp * hp;
            n += 1;
        }
    }
    c.park()?;
    Ok((sum / n.max(1) as f64).sqrt())
}

/// The oscillation watch's half swing on the tracking error of the model
/// the board runs, µm, where the model sets one below the default 0.2 µm
/// (autotune sets it from its stage's swing at rest: a noisier board's noise
/// alone may trip it); `None` otherwise or where the model cannot be read.
pub fn model_watch_swing(c: &mut Client) -> Option<f64> {
    let image = c.read_model().ok()?;
    let mut store = Box::new(fpi_firmware::board::capacity::Store::new());
    store
        .load(&image, &fpi_firmware::board::capacity::BOARD)
        .ok()?;
    store
        .spec()
        .watch_swing
        .filter(|&h| h < piezo_fpi::model::WATCH_SWING_MAX)
        .map(|h| h.to_num::<f64>())
}

/// What to say beside an `Oscillation` fault on a model whose watch swing is
/// `swing_um` (µm, [`model_watch_swing`]).
pub fn watch_hint(swing_um: f64) -> String {
    format!(
        "the model's loop watch counts swings beyond ±{swing_um:.3} µm (autotune set it from \
         its stage's noise at rest): if the stage rests quietly and this board's sensors are \
         noisier, their noise alone trips it — autotune on this board, or set \
         feedback.watch_swing_um = 0.2 in the model's file"
    )
}

/// What to say beside an `Oscillation` fault on a model with active damping:
/// the damping turns the force sensor's noise into motion, by as much as its
/// design allowed for the sensor autotune measured, more on a noisier one.
pub const DAMPING_HINT: &str = "the model's damping was designed for the force sensor its \
     tuning measured: a noisier sensor's noise, which the damping turns into motion, may be \
     what the loop watch took for an oscillation — autotune on this board (it designs the \
     damping for the noise it measures), or run without it (`fpi board damping off`)";

/// `e`, with the likely cause, where the board latched `Oscillation` and the
/// loops move the stage `motion_um` (µm RMS) at rest with the noise measured,
/// `noise_n` (N σ), more than the budget they are designed for
/// ([`crate::method::tune::NOISE_BUDGET_UM`]).
pub fn explain(c: &mut Client, e: Error, noise_n: f64, motion_um: f64) -> Error {
    let oscillation = c
        .status()
        .ok()
        .and_then(|s| s.fault)
        .is_some_and(|f| f.code == Fault::Oscillation as u8);
    if oscillation && motion_um > NOISE_BUDGET_UM {
        e.context(format!(
            "the force sensor reads σ {noise_n:.2} N of noise at rest, which the damping \
             designed turns into {motion_um:.3} µm RMS of motion (budget \
             {NOISE_BUDGET_UM:.2} µm): the loop watch takes it for an oscillation; let \
             autotune design for the noise it measures (no --force-noise-n), or tune with a \
             lower --target-damping or --no-damping"
        ))
    } else {
        e
    }
}
