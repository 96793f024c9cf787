//! Host side of the piezo FPI project: the recorded datasets, an f64 reference of
//! the fixed-point core, and the tools of the FPI-FFEM method, all on the same
//! `piezo-fpi` core the firmware runs.
//!
//! * [`data`] — reading the datasets (CSV via `csv` + `serde`, gzip), errors with
//!   file, line and column.
//! * [`model_file`] — the firmware model file (shared with the core's `build.rs`).
//! * [`reference`] — the f64 twin of the fixed-point model and control step.

pub mod accuracy;
pub mod calibrate;
pub mod cli;
pub mod compare;
pub mod data;
pub mod demo_chain;
pub mod export;
pub mod fem;
pub mod firmware;
pub mod hmodel;
pub mod invert;
pub mod lsq;
pub mod plots;
pub mod predict;
pub mod report;

/// The firmware model file (shared with the firmware's build).
pub use piezo_sim::file as model_file;
