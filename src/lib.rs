//! Fixed-point Force-dependent Prandtl–Ishlinskii (FPI) hysteresis compensation for
//! preloaded piezo stages: the `no_std` core shared by the STM32 firmware and the
//! host tools.
//!
//! The stack responds to the effective voltage `û = u - k_f·F_p`, where `F_p` is the
//! preload the flexure hinge puts on it; a bank of one-sided play operators maps
//! `û` to stack extension; FEM tables give the preload `f_F(x_pea)` and the stage
//! output `f_K(x_pea)` ("Nonlinearity Characterization of Flexible Hinge
//! Piezoelectric Stages Under Dynamic Preload via a Force-Dependent
//! Prandtl–Ishlinskii Model with a Force-Analyzed Finite Element Method",
//! Actuators 2025, 14(8):411, doi:10.3390/act14080411; cited below as
//! "Actuators 2025"). The control step ([`ControllerConfig::step`])
//! inverts that chain in closed form once per ISR.
//!
//! * No `std`, no allocation, no panic and no division on the control path; every
//!   quantity has a documented Q format ([`q`]) and every model is validated when it
//!   is built (at compile time for the embedded one, [`model`]).
//! * Configuration (weights, thresholds, tables, limits) is separate from state
//!   (operator outputs, last voltage), like `idsp`'s split processors, and every
//!   block has one verb: `config.process(&mut state, x)` ([`process`]).
//! * `defmt` only with the `defmt` feature (derives `Format` on errors and faults).
//!
//! Modules: [`play`] (the OSP operator), [`pi`] (forward PI), [`inverse`] (closed-form
//! inverse PI), [`fpi`] (force coupling), [`table`] (lookup tables), [`limits`],
//! [`control`] (the ISR step and its force channel), [`damping`] (active damping from the
//! force sensor, the stage dynamics a model declares), [`stability`] (the loops as a
//! discrete-time system, and their stability check), [`feedback`] (position feedback), [`io`] (sensor/amplifier traits), [`model`] (the
//! model format and its validator), [`error`] (the error vocabulary).
#![cfg_attr(not(test), no_std)]
#![deny(clippy::panic, clippy::unwrap_used, clippy::expect_used)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used))]

pub mod biquad;
pub mod control;
pub mod damping;
pub mod decoupling;
pub mod error;
pub mod feedback;
pub mod fields;
pub mod fpi;
pub mod governor;
pub mod inverse;
pub mod io;
pub mod lead;
pub mod limits;
pub mod model;
pub mod pi;
pub mod play;
pub mod preview;
pub mod process;
pub mod q;
pub mod stability;
pub mod table;
#[cfg(test)]
pub mod testkit;
pub mod trigger;

pub use control::{
    ControllerConfig, ControllerParts, ControllerState, Fault, ForceSource, Interval, LinearDrive,
    Mode, StepOutput,
};
pub use error::{Field, Invalid, ModelError};
pub use fpi::{Coupling, ForceTerms, Fpi};
pub use inverse::InversePi;
pub use limits::OutputLimits;
pub use pi::PiModel;
pub use play::PlayBank;
pub use table::Table;
