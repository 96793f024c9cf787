//! The FPI-FFEM method (Actuators 2025, 14(8):411, Table 1) on the host.
//!
//! * [`model`] — a calibrated model and its file (`piezo-fpi-model/1`), and what
//!   a model kind does ([`model::ModelKind`]); [`kinds`] — the kinds, one file
//!   each; [`sections`] — the model file's sections;
//! * [`calibrate`] (Part I, with [`fit`] and [`lsq`]) — identifying a model from
//!   Voltage–Force–Displacement recordings, checked by [`checks`];
//! * [`predict`] (Parts II–III) — the stage from its FEM maps, solving the coupled
//!   equation at every sample; [`compare`] — scoring models against measured runs;
//! * [`invert`] — offline feedforward; [`export`] — the firmware model file;
//!   [`limits`] — what the board and its amplifier allow;
//! * [`refine`] — correcting a stage's FEM tables from measured runs of it;
//! * [`lever`] — an analytic stage (the second paper's lever chain) as an FEM table;
//! * [`identify`] and [`dynamics`] — the stage's linear dynamics;
//! * [`tune`] — the gains of the board's position loop; [`shaping`] — the
//!   firmware's dynamic compensation from the identified dynamics.

pub mod axes;
pub mod bench;
pub mod calibrate;
pub mod checks;
pub mod compare;
pub mod dynamics;
pub mod export;
pub mod fit;
pub mod identify;
pub mod invert;
pub mod keys;
pub mod kinds;
pub mod lever;
pub mod limits;
pub mod lsq;
pub mod model;
pub mod predict;
pub mod refine;
pub mod sections;
pub mod series;
pub mod shaping;
pub mod tune;
