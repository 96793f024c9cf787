//! The host side of the piezo FPI project, in layers (each uses only those above it):
//!
//! * [`data`] — the recorded datasets and the stage's FEM export, read with errors
//!   that name the file, the line and the column; where the project's files are.
//! * [`method`] — the FPI-FFEM method (Actuators 2025, 14(8):411, Table 1): the model
//!   kinds, one file each ([`method::kinds`]), and the calibrated model's file
//!   ([`method::model`]), calibration, the coupled prediction, comparison, offline
//!   inversion, the export of a firmware model and the board's limits. The models
//!   are evaluated by the project's float model (`piezo-sim`).
//! * [`report`] — the Markdown report, its SVG plots, and `fpi demo`, the whole
//!   chain on the project's datasets.
//! * [`board`] — the firmware from the host: building it for the Cortex-M4,
//!   running it on the emulated board (QEMU), and measuring the fixed-point core
//!   against its f64 reference ([`board::accuracy`]).
//! * [`cli`] — the `fpi` commands (the binaries only parse arguments).

pub mod board;
pub mod cli;
pub mod data;
pub mod method;
pub mod output;
pub mod report;

/// The firmware model file (shared with the firmware's build).
pub use piezo_sim::file as model_file;
