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

/// An emulated board in one thread: its control period run on demand (the
/// link handler runs one whenever it waits, [`crate::link::handler::Board`]).
/// The one-axis board ([`virtual_bench::Virtual`]) and the board of several
/// axes ([`virtual_axes::VirtualAxes`]) are one.
#[cfg(feature = "sim")]
pub trait Emulated<const N: usize>: crate::link::handler::Board<N> {
    /// One control period: the bench, the control tick, the stage, the
    /// recorder.
    fn period(&mut self);
    /// The number of the next tick.
    fn next_tick(&self) -> u32;
}
