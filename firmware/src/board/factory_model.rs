//! The embedded stage model, generated at build time from `firmware/model/stage-a.toml`
//! (or the file named by the `PIEZO_FPI_MODEL` environment variable at build time).
//!
//! Everything here is `const`/`static`: the PI weights, the inverse computed by the
//! compiler, the FEM tables and the loop limits all live in flash, and an invalid
//! model is a compile error. The same model is also here as an image
//! ([`MODEL_IMAGE`]), the form the board loads, stores and receives. The file itself comes from `fpi export` (see the
//! host crate), which calibrates on the recorded data and resamples the FEM maps
//! onto power-of-two grids.

use fixed::types::I16F16;
use piezo_fpi::control::{
    ControllerConfig, ControllerParts, ForceChannel, ForceSource, Interval, Supervision,
};
#[allow(unused_imports)]
use piezo_fpi::fpi::{Coupling, Creep, Fpi, Identity, Map};
use piezo_fpi::limits::OutputLimits;
use piezo_fpi::pi::PiModel;
#[allow(unused_imports)]
use piezo_fpi::q::{
    CreepRate, Micrometres, Newtons, UmPerNewton, UmPerVolt, Volts, VoltsPerNewton, VoltsPerNewton2,
};
use piezo_fpi::table::{Segment, Table};

include!(concat!(env!("OUT_DIR"), "/model.rs"));

/// The embedded model as an image (`piezo_fpi::model::image`): the board's factory
/// default, loaded into RAM at start-up when no stored model is valid.
pub static MODEL_IMAGE: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/model.image"));
