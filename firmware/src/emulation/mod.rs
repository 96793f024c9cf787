//! The emulated board: what the QEMU board (`src/bin/fpi-firmware/qemu_board.rs`)
//! and the host's twin run instead of the analog world.
//!
//! * [`virtual_io`] — the emulated board's virtual sensor, DAC, enable line and
//!   analog input, the ISR's side of the virtual stage;
//! * with the `sim` feature, `virtual_bench` — the virtual bench: the virtual
//!   stage stepped after every tick and its fault injection, which the host also
//!   runs as its twin;
//! * with the `sim` feature, `virtual_axes` — a virtual stage of several
//!   axes behind one link per axis, stepped after every tick.

#[cfg(all(test, feature = "sim"))]
pub(crate) mod link_host;
#[cfg(feature = "sim")]
pub mod virtual_axes;
#[cfg(feature = "sim")]
pub mod virtual_bench;
pub mod virtual_io;
