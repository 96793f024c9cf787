//! `piezo_fpi`: the piezo FPI host tools from Python. A thin binding over the
//! host library (`fpi_host`): the board over its command link ([`board`]), the
//! emulated board ([`emulator`]), and the method's calibration, prediction and
//! inversion ([`model`]). Every check, command and computation is the host
//! library's, as `fpi` runs it; this crate converts arguments and results
//! ([`arrays`]) and errors ([`errors`]), and releases the GIL while the Rust code
//! works.

#![forbid(unsafe_code)]

mod arrays;
mod board;
mod emulator;
mod errors;
mod model;
mod recorder;
mod settings;

use pyo3::prelude::*;

/// The module `piezo_fpi`.
#[pymodule]
fn piezo_fpi(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("BoardError", py.get_type::<errors::BoardError>())?;
    m.add("LinkError", py.get_type::<errors::LinkError>())?;
    m.add("Interrupted", py.get_type::<errors::Interrupted>())?;
    m.add_class::<board::Board>()?;
    m.add_class::<recorder::Recorder>()?;
    m.add_class::<settings::Settings>()?;
    m.add_class::<emulator::Emulator>()?;
    m.add_class::<model::Model>()?;
    m.add_function(wrap_pyfunction!(model::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(model::predict_axes, m)?)?;
    m.add_function(wrap_pyfunction!(model::refine_axes, m)?)?;
    m.add_function(wrap_pyfunction!(emulator::qemu_available, m)?)?;
    Ok(())
}
