//! `fpi scope`: opens the board, picks what to stream and serves the page
//! ([`crate::scope`]) until stopped.

use std::sync::{Arc, Mutex};

use anyhow::Result;

use super::board::{catch_ctrl_c, open, signals_arg, stop_asked};
use crate::board::budget::Budget;
use crate::scope::{self, Options};

/// `fpi scope --port PORT --listen HOST:PORT [--signals …] [--decimation N]`.
pub fn run(port: &str, listen: &str, signals: &[String], decimation: Option<u16>) -> Result<()> {
    catch_ctrl_c()?;
    let signals = signals_arg(signals)?;
    let c = open(port)?;
    let decimation = match decimation {
        Some(d) => d,
        None => Budget::continuous_decimation(c.hello(), signals),
    };
    let board = c.name().to_string();
    let bound = scope::bind(
        Arc::new(Mutex::new(c)),
        &board,
        listen,
        Options {
            signals,
            decimation,
        },
    )?;
    println!(
        "scope of {board} at {} ({} at every {decimation}. tick); Ctrl-C ends",
        bound.url(),
        scope::channels(signals)
            .iter()
            .map(|(n, _)| *n)
            .collect::<Vec<_>>()
            .join(", ")
    );
    let t = bound.run(&stop_asked)?;
    println!("{}", scope::closing(&t));
    Ok(())
}
