//! The axes' decoupling of a board of several (`piezo_fpi::decoupling`): the
//! input matrix, the output matrix and the stacks' preload coupling, sent as
//! the link carries them ([`Command::Decoupling`]).

use anyhow::Result;
use fpi_protocol::Command;
use piezo_fpi::decoupling::Decoupling;

use super::client::Client;

/// The axes a decoupling spans on the link (x, y, z).
pub const MAX_AXES: usize = fpi_protocol::MAX_AXES as usize;

/// The command that sets `d` (its entries' fixed-point bits).
pub fn command(d: &Decoupling<MAX_AXES>) -> Command<'static> {
    Command::Decoupling {
        input: d.input.rows().map(|r| r.map(|e| e.to_bits())),
        output: d.output.rows().map(|r| r.map(|e| e.to_bits())),
        preload: d.preload.rows().map(|r| r.map(|k| k.to_bits())),
    }
}

/// Sets `d` on the board `c` (every axis parked); the tick it took effect.
pub fn set(c: &mut Client, d: &Decoupling<MAX_AXES>) -> Result<u32> {
    c.order(&command(d))
}
