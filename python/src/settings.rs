//! `Board.settings`: the board's runtime settings as a mapping by key path
//! (`board.settings["stage/0/damping"] = False`), each get and set the host
//! library's (`fpi_host::board::settings`, the client's `setting` and
//! `set_setting`), values converted through JSON, as they cross the link.

use fpi_host::board::settings;
use pyo3::exceptions::PyKeyError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::board::Board;

/// The board's runtime settings by key path, a mapping: `settings[key]` reads
/// one, `settings[key] = value` changes it as its named method would (with the
/// board's checks: a refusal raises `BoardError`), `keys()` lists them and
/// `dict(settings)`-style `to_dict()` reads every one (`None` where the
/// running model has no such section). A key may use slashes or dots
/// (`"stage/0/loop_mode"`, `"stage.0.loop_mode"`); a key that is no setting
/// raises `KeyError`. The book's reference lists every key with its values.
#[pyclass(module = "piezo_fpi")]
pub struct Settings {
    board: Py<Board>,
}

impl Settings {
    pub fn of(board: Py<Board>) -> Self {
        Self { board }
    }
}

/// The board's key path for `key`, or `KeyError` naming the settings.
fn path(key: &str) -> PyResult<String> {
    settings::path(key).map_err(|e| PyKeyError::new_err(e.to_string()))
}

#[pymethods]
impl Settings {
    fn __getitem__<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        let p = path(key)?;
        let text = self.board.borrow(py).run(py, |c| c.setting(&p))?;
        py.import("json")?.call_method1("loads", (text,))
    }

    fn __setitem__(&self, py: Python<'_>, key: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = path(key)?;
        let text: String = py
            .import("json")?
            .call_method1("dumps", (value,))?
            .extract()?;
        self.board
            .borrow(py)
            .run(py, |c| c.set_setting(&p, &text))
            .map(|_| ())
    }

    fn __contains__(&self, key: &str) -> bool {
        settings::path(key).is_ok()
    }

    fn __len__(&self) -> usize {
        settings::leaves().len()
    }

    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.keys().into_pyobject(py)?.call_method0("__iter__")
    }

    /// Every key, in the tree's order (`stage/0/loop_mode`, …).
    fn keys(&self) -> Vec<String> {
        settings::leaves()
            .into_iter()
            .map(|l| l.path[1..].to_string())
            .collect()
    }

    /// Every setting's value by key (`None` where the running model has no
    /// such section).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let all = self.board.borrow(py).run(py, settings::read_all)?;
        let json = py.import("json")?;
        let d = PyDict::new(py);
        for (p, v) in all {
            let v = match v {
                Some(t) => json.call_method1("loads", (t,))?,
                None => py.None().into_bound(py),
            };
            d.set_item(&p[1..], v)?;
        }
        Ok(d)
    }

    /// One setting's declaration: its `doc`, `range` (the values it takes),
    /// `unit` and `default`.
    fn describe<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyDict>> {
        let p = path(key)?;
        let leaf = settings::leaves().into_iter().find(|l| l.path == p);
        let d = PyDict::new(py);
        if let Some(l) = leaf {
            d.set_item("doc", l.doc)?;
            d.set_item("range", l.range)?;
            d.set_item("unit", l.unit)?;
            d.set_item("default", l.default)?;
        }
        Ok(d)
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!("Settings({})", self.to_dict(py)?.repr()?))
    }
}
