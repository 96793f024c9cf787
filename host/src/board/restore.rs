//! Leaving the board as it was found: what a command that changes the loops
//! (or the model) on its way captures before it starts, and puts back when it
//! fails midway (`fpi board autotune`, `step`, `frf`, `load --match-mass`).
//!
//! The stage is parked first (a model is loaded, and the loops switched,
//! only at rest), then the model the board ran is loaded again if it runs
//! another (into RAM only: the flash keeps what it holds), then the damping,
//! the shaping and the loop mode are set as they were. A fault the board
//! latched meanwhile stays latched: it says why the command failed.

use anyhow::Result;
use fpi_protocol::{Command, LoopMode};

use super::client::Client;

/// What a board ran before a command changed it (see the module docs).
#[derive(Debug, Clone)]
pub struct Before {
    loop_mode: LoopMode,
    damping: Option<bool>,
    shaping: Option<bool>,
    /// The model's CRC and image, where the command may load another.
    model: Option<(u32, Vec<u8>)>,
}

impl Before {
    /// The loop mode, damping and shaping `c` runs now.
    pub fn capture(c: &mut Client) -> Result<Self> {
        let s = c.status()?;
        Ok(Self {
            loop_mode: s.loop_mode,
            damping: s.damping,
            shaping: s.shaping,
            model: None,
        })
    }

    /// And the model it runs, whose image is `image` (read back or known to
    /// be the one running).
    pub fn with_model(mut self, c: &mut Client, image: Vec<u8>) -> Result<Self> {
        self.model = Some((c.model()?.crc, image));
        Ok(self)
    }

    /// Parks `c` and puts back what it ran (see the module docs).
    pub fn restore(&self, c: &mut Client) -> Result<()> {
        c.park()?;
        if let Some((crc, image)) = &self.model {
            if c.model()?.crc != *crc {
                c.upload(image, false, |_| {})?;
            }
        }
        if let Some(on) = self.damping {
            c.damping(on)?;
        }
        if let Some(on) = self.shaping {
            c.shaping(on)?;
        }
        c.ack(&Command::Loop {
            axis: c.axis(),
            mode: self.loop_mode,
        })?;
        Ok(())
    }

    /// Runs `f` on `c`; where it fails, restores `c` ([`Self::restore`])
    /// before returning its error (with the restoration's own failure, if
    /// that fails too).
    pub fn on_failure<T>(
        &self,
        c: &mut Client,
        f: impl FnOnce(&mut Client) -> Result<T>,
    ) -> Result<T> {
        f(c).map_err(|e| match self.restore(c) {
            Ok(()) => e,
            Err(r) => e.context(format!(
                "the board could not be put back as it was after this failure ({r:#}; check it \
                 with `fpi board status`)"
            )),
        })
    }
}

/// Runs the command `f` on `c`, which changes the loops on its way; where it
/// fails, `c` is parked and its loops put back as they were.
pub fn or_restore<T>(c: &mut Client, f: impl FnOnce(&mut Client) -> Result<T>) -> Result<T> {
    Before::capture(c)?.on_failure(c, f)
}
