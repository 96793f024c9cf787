//! The force sensor's noise at rest, measured through the board: what the
//! active damping feeds back into the stack and so turns into motion.
//!
//! On the emulated stage as built (σ 0.15 N) the tuned loops move the stage
//! 0.02–0.03 µm RMS at rest, mostly near 310 Hz; at σ 0.5 N, 0.07 µm; at
//! σ 1 N, 0.14 µm, and the loop watch (`firmware/src/watch.rs`), which counts
//! swings beyond ±0.2 µm, takes that motion for an oscillation: `fpi board
//! autotune` with the default damping latched `Oscillation` during its first
//! trial or warm-up (two runs), where `--target-damping 0.2` or
//! `--no-damping` tuned the same stage (one run each; 0.3 tripped). Autotune
//! measures the noise before it tunes, prints it, and names it where the
//! watch trips ([`explain`]).

use anyhow::{bail, Error, Result};
use fpi_protocol::record::signal;
use fpi_protocol::Command;
use piezo_fpi::control::Fault;

use super::client::{real, Client};
use super::follow::Follow;

/// The force noise above which a tripped loop watch is likely the damping's
/// own noise-driven motion, N (σ): a third of the way from the stage as
/// built's 0.15 N to the 1 N that tripped it.
pub const NOISY_FORCE_N: f64 = 0.5;
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

/// `e`, with the likely cause, where the board latched `Oscillation` and the
/// force sensor's noise `noise_n` (N) is above [`NOISY_FORCE_N`].
pub fn explain(c: &mut Client, e: Error, noise_n: f64) -> Error {
    let oscillation = c
        .status()
        .ok()
        .and_then(|s| s.fault)
        .is_some_and(|f| f.code == Fault::Oscillation as u8);
    if oscillation && noise_n > NOISY_FORCE_N {
        e.context(format!(
            "the force sensor reads σ {noise_n:.2} N of noise at rest (above {NOISY_FORCE_N} N): \
             the damping turns it into motion the loop watch takes for an oscillation; \
             tune with a lower --target-damping (0.2 tuned σ 1 N on the emulated stage) \
             or --no-damping"
        ))
    } else {
        e
    }
}
