//! The floating-point model of a preloaded piezo stage, generic over `f32`/`f64`:
//!
//! * [`play`] — the one-sided play operator and the PI model with its closed-form
//!   inverse; [`maps`] — the dead zone and the output maps; [`curve`] — the one
//!   piecewise-linear interpolator; [`model`] — the actuator model every kind of
//!   the host tools is a configuration of; [`fem`] — the FEM maps of a stage;
//!   [`solve`] — the coupled equation of the FPI-FFEM method; [`stats`] — the error
//!   figures;
//! * in `f64`, the reference the fixed-point core is measured against, and the
//!   models the host tools calibrate, predict and invert with;
//! * in `f32`, [`stage`] — the virtual stage the emulated board drives; [`axes`] —
//!   stages of two or three axes coupled through their flexure.
//!
//! `no_std`; the `file` feature (host) adds the firmware model file (`file`)
//! and what an error quotes of a file's text (`quote`).
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![deny(clippy::unwrap_used, clippy::expect_used)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used))]

#[cfg(feature = "std")]
extern crate std;

pub mod axes;
pub mod control;
pub mod curve;
pub mod electromech;
pub mod fem;
#[cfg(feature = "file")]
pub mod file;
pub mod filter;
pub mod maps;
pub mod model;
pub mod play;
#[cfg(feature = "file")]
pub mod quote;
pub mod real;
pub mod solve;
pub mod stage;
pub mod stats;

pub use real::Real;
