//! A board's loops made ready to be scored: closed at mid-stroke and warmed up
//! by slow sines, over which the force channel learns the stage's preload map
//! (its offset and scale) — before autotune's trials and verification, and
//! before each drive of the closed-loop comparison.

use anyhow::Result;
use fpi_protocol::{Command, LoopMode, Shape};

use super::client::Client;
use super::follow::{no_fault, Follow};

/// Slow sines of the warm-up: 5 Hz over 5–35 µm, this many.
pub const WARM_UP_CYCLES: u32 = 10;

/// [`WARM_UP_CYCLES`] slow sines, 5–35 µm at 5 Hz, with the loops as they are.
/// A fault latched before (the board then refuses the sines) is named with its
/// tick.
pub fn warm_up(c: &mut Client) -> Result<()> {
    if let Err(e) = c.wave(Shape::Sine, 15.0, 20.0, 5.0, WARM_UP_CYCLES) {
        let status = c.status()?;
        no_fault(
            &status,
            "what ran before the warm-up (the board refused its sines)",
        )?;
        return Err(e);
    }
    Follow::new(c, 0).until_rest("the warm-up")?;
    Ok(())
}

/// Where the loops are closed: mid-stroke, µm.
pub const MID_UM: f64 = 20.0;

/// Moves to mid-stroke ([`MID_UM`]), closes the loop and warms up.
pub fn close_and_warm_up(c: &mut Client) -> Result<()> {
    c.move_to(MID_UM, 1000.0)?;
    Follow::new(c, 0).until_hold()?;
    c.ack(&Command::Loop {
        axis: c.axis(),
        mode: LoopMode::Closed,
    })?;
    warm_up(c)
}
