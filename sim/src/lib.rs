//! The floating-point model of a preloaded piezo stage: the virtual stage the
//! emulated board drives, and the error statistics both worlds compute.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

pub mod stage;
pub mod stats;
