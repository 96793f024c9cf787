//! The host library's errors as Python exceptions: a refusal or a fault of the
//! board is a `BoardError` carrying the board's reason, an argument the host
//! refuses a `ValueError` naming it, a link that fails a `LinkError`, and a
//! Ctrl-C that stopped a long call an `Interrupted` (a `KeyboardInterrupt`)
//! carrying what was done.

use fpi_host::board::client::{refusal, Faulted};
use fpi_host::board::commands::bad_argument;
use fpi_host::data::DataError;
use pyo3::exceptions::{PyFileNotFoundError, PyKeyboardInterrupt, PyOSError, PyValueError};
use pyo3::prelude::*;

pyo3::create_exception!(
    piezo_fpi,
    BoardError,
    pyo3::exceptions::PyException,
    "The board refused a command, or took it and faulted on it. `reason` is the \
     board's reason (e.g. \"target 45.000 µm outside the stroke 0.000–39.921 µm\"), \
     `code` the refusal's kind (or \"Fault\")."
);
pyo3::create_exception!(
    piezo_fpi,
    LinkError,
    pyo3::exceptions::PyConnectionError,
    "The link to the board failed: it could not be opened, closed, or the board \
     stopped answering."
);
pyo3::create_exception!(
    piezo_fpi,
    Interrupted,
    PyKeyboardInterrupt,
    "Ctrl-C stopped `Board.record` or `Board.stream`: the board was left in order \
     (the recorder stopped; a stream ended with the board holding). `done` holds \
     what was done: the partial recording, or the points sent."
);

/// What failed, when an error is none of the typed ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Otherwise {
    /// Talking to the board: a `LinkError`.
    Link,
    /// Reading or checking the caller's input (files, arrays): a `ValueError`,
    /// or an `OSError` where a file could not be read.
    Input,
}

/// The Python exception for `e`.
pub fn to_py(py: Python<'_>, e: anyhow::Error, otherwise: Otherwise) -> PyErr {
    if let Some(b) = bad_argument(&e) {
        return PyValueError::new_err(b.python_message());
    }
    let text = format!("{e:#}");
    if let Some(r) = refusal(&e) {
        return board_error(py, text, &r.reason, &format!("{:?}", r.code));
    }
    if let Some(f) = e.downcast_ref::<Faulted>() {
        return board_error(py, text, f.reason, "Fault");
    }
    let io = e.chain().find_map(|c| c.downcast_ref::<std::io::Error>());
    // The host's readers say which file they could not read, not why: a file
    // that is not there is Python's `FileNotFoundError`.
    let missing = e
        .chain()
        .find_map(|c| c.downcast_ref::<DataError>())
        .is_some_and(|d| d.line.is_none() && !d.file.exists());
    if otherwise == Otherwise::Input && missing {
        return PyFileNotFoundError::new_err(text);
    }
    match (otherwise, io) {
        (Otherwise::Link, _) => LinkError::new_err(text),
        (Otherwise::Input, Some(io)) if io.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(text)
        }
        (Otherwise::Input, Some(_)) => PyOSError::new_err(text),
        (Otherwise::Input, None) => PyValueError::new_err(text),
    }
}

fn board_error(py: Python<'_>, text: String, reason: &str, code: &str) -> PyErr {
    let err = BoardError::new_err(text);
    let v = err.value(py);
    // Setting attributes on a fresh exception instance does not fail.
    let _ = v.setattr("reason", reason);
    let _ = v.setattr("code", code);
    err
}

/// An `Interrupted` carrying `done`.
pub fn interrupted(py: Python<'_>, message: String, done: Py<PyAny>) -> PyErr {
    let err = Interrupted::new_err(message);
    let _ = err.value(py).setattr("done", done);
    err
}
