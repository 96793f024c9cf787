//! Numbers between Python and the host library: sequences of floats in (any
//! one-dimensional array-like, through `numpy.asarray`), dictionaries of numpy
//! arrays out (the columns of a CSV the CLI would write).

use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// `obj` as a vector of floats: anything `numpy.asarray(obj, float)` turns into a
/// one-dimensional array. A `TypeError` names the argument `name` otherwise.
pub fn floats(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<f64>> {
    let np = obj.py().import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj, "float64"))
        .map_err(|e| PyTypeError::new_err(format!("{name}: not an array of numbers ({e})")))?;
    let ndim: usize = arr.getattr("ndim")?.extract()?;
    if ndim != 1 {
        return Err(PyTypeError::new_err(format!(
            "{name}: a one-dimensional array of numbers, not one of {ndim} dimensions"
        )));
    }
    let a: PyReadonlyArray1<'_, f64> = arr.extract()?;
    Ok(a.as_array().to_vec())
}

/// Column `key` of a dictionary of arrays (a dataset or a recording) as floats,
/// if it has one; `what` names the dictionary in errors.
pub fn column(d: &Bound<'_, PyDict>, key: &str, what: &str) -> PyResult<Option<Vec<f64>>> {
    match d.get_item(key)? {
        None => Ok(None),
        Some(v) => floats(&v, &format!("{what}[{key:?}]")).map(Some),
    }
}

/// Column `key` that must be there.
pub fn required(d: &Bound<'_, PyDict>, key: &str, what: &str) -> PyResult<Vec<f64>> {
    column(d, key, what)?.ok_or_else(|| {
        let keys: Vec<String> = d.keys().iter().map(|k| k.to_string()).collect();
        PyValueError::new_err(format!(
            "{what}: no column {key:?} (it has {})",
            keys.join(", ")
        ))
    })
}

/// Columns as a dictionary of numpy arrays, in order.
pub fn columns_dict<'py>(
    py: Python<'py>,
    columns: Vec<(&str, Vec<f64>)>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, values) in columns {
        d.set_item(name, values.into_pyarray(py))?;
    }
    Ok(d)
}
