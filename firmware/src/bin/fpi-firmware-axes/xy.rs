//! The emulated board of 2 axes (`fpi board emulate --axes 2`): the program of
//! `fpi-firmware` (`src/bin/fpi-firmware/app.rs`) on QEMU, each axis of the
//! XY stage as designed on its own virtual analog world
//! (`src/bin/fpi-firmware/qemu_axes.rs`). Built with `--features qemu`.
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The board's axes.
#[cfg(target_os = "none")]
const AXES: usize = 2;

#[cfg(target_os = "none")]
#[macro_use]
#[path = "../fpi-firmware/log.rs"]
mod log;

#[cfg(target_os = "none")]
#[path = "../fpi-firmware/supervisor.rs"]
mod supervisor;

/// The one-axis emulated board: its link, flash and exceptions (its stage and
/// control task are the one-axis board's, unused here).
#[cfg(target_os = "none")]
#[allow(dead_code)]
#[path = "../fpi-firmware/qemu_board.rs"]
mod qemu_board;

#[cfg(target_os = "none")]
#[path = "../fpi-firmware/qemu_axes.rs"]
mod io;

include!("../fpi-firmware/app.rs");
