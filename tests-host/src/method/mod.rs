//! The FPI-FFEM method (Actuators 2025, 14(8):411, Table 1) on the host.
//!
//! * [`model`] — the kinds of model and their file (`piezo-fpi-model/1`);
//! * [`calibrate`] (Part I, with [`lsq`]) — identifying a model from
//!   Voltage–Force–Displacement recordings;
//! * [`predict`] (Parts II–III) — the stage from its FEM maps, solving the coupled
//!   equation at every sample; [`compare`] — scoring models against measured runs;
//! * [`invert`] — offline feedforward; [`export`] — the firmware model file;
//! * [`refine`] — correcting a stage's FEM tables from measured runs of it;
//! * [`branch`] — the second paper's branch-polynomial hysteresis (`--kind branch`);
//! * [`lever`] — an analytic stage (the second paper's lever chain) as an FEM table.
//! * [`tune`] — the gains of the board's position loop; [`shaping`] — the
//!   firmware's dynamic compensation from the identified dynamics.

pub mod bench;
pub mod branch;
pub mod calibrate;
pub mod checks;
pub mod compare;
pub mod dynamics;
pub mod export;
pub mod identify;
pub mod invert;
pub mod lever;
pub mod lsq;
pub mod model;
pub mod predict;
pub mod refine;
pub mod shaping;
pub mod tune;
