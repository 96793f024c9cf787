//! The embedded stage model, generated at build time from `src/model/stage-a.toml`
//! (or the file named by the `PIEZO_FPI_MODEL` environment variable at build time).
//!
//! Everything here is `const`/`static`: the PI weights, the inverse computed by the
//! compiler, the FEM tables and the loop limits all live in flash, and an invalid
//! model is a compile error. The file itself comes from `fpi export` (see the
//! host crate), which calibrates on the recorded data and resamples the FEM maps
//! onto power-of-two grids.

use crate::control::{ControllerConfig, ControllerParts, ForceSource, Interval};
#[allow(unused_imports)]
use crate::fpi::{Coupling, Creep, Fpi, Identity, Map};
use crate::limits::OutputLimits;
use crate::pi::PiModel;
#[allow(unused_imports)]
use crate::q::{
    CreepRate, Micrometres, Newtons, UmPerNewton, UmPerVolt, Volts, VoltsPerNewton, VoltsPerNewton2,
};
use crate::table::{Segment, Table};
use fixed::types::I16F16;

include!(concat!(env!("OUT_DIR"), "/model.rs"));
