//! The FPI-FFEM method (Actuators 2025, 14(8):411, Table 1) on the host.
//!
//! * [`model`] — the kinds of model and their file (`piezo-fpi-model/1`);
//! * [`calibrate`] (Part I, with [`lsq`]) — identifying a model from
//!   Voltage–Force–Displacement recordings;
//! * [`predict`] (Parts II–III) — the stage from its FEM maps, solving the coupled
//!   equation at every sample; [`compare`] — scoring models against measured runs;
//! * [`invert`] — offline feedforward; [`export`] — the firmware model file;
//! * [`refine`] — correcting a stage's FEM tables from measured runs of it.

pub mod bench;
pub mod calibrate;
pub mod checks;
pub mod compare;
pub mod export;
pub mod invert;
pub mod lsq;
pub mod model;
pub mod predict;
pub mod refine;
