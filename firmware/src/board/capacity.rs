//! What the driver board's hardware allows and what it has room for: the limits a
//! model may narrow but never widen, and the capacity of the model it runs.
//!
//! * Control rate 20 kHz (SysTick on both boards).
//! * Amplifier and safe voltage: the board definition's
//!   ([`crate::board::definition::AMPLIFIER`]).
//! * Capacity: 10 play operators, 4 creep terms, 3 072 table intervals (24 KiB of
//!   RAM per model; the board holds two, the running one and the one it receives).

use piezo_fpi::model::image;
use piezo_fpi::model::store::{Board, ModelStore, RuntimeController};
use piezo_fpi::q::Micrometres;

/// Play operators a model may have.
pub const OPERATORS: usize = 10;
/// Creep terms a model may have.
pub const CREEP_TERMS: usize = 4;
/// Table intervals a model may have, all tables together.
pub const TABLE_INTERVALS: usize = 3072;
/// Bytes of the largest model image (the room to receive one).
pub const IMAGE_BYTES: usize = image::max_len(OPERATORS, CREEP_TERMS, TABLE_INTERVALS);

/// The most axes a board drives (x, y, z): the size of a decoupling order's
/// matrices.
pub const MAX_AXES: usize = 3;

/// Recorder ring: samples (28 bytes each, 14 KiB).
pub const RECORDER_SAMPLES: usize = 512;
/// Streamed points buffered on the board.
pub const STREAM_POINTS: usize = 1024;
/// Speed of the approach to a new source's entry point: 0.05 µm per tick (1 mm/s
/// at 20 kHz; a 40 µm stroke in 40 ms).
pub const APPROACH_STEP: Micrometres = Micrometres::from_bits(3277);

pub use crate::board::definition::RATE_HZ;

/// The board: its rate and hardware limits.
pub const BOARD: Board = Board {
    rate_hz: RATE_HZ,
    limits: crate::board::definition::AMPLIFIER,
};

/// A model in the board's RAM.
pub type Store = ModelStore<OPERATORS, CREEP_TERMS, TABLE_INTERVALS>;

/// The control step's configuration for a model in the board's RAM.
pub type Controller<'a> = RuntimeController<'a, OPERATORS, CREEP_TERMS>;
