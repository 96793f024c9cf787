//! `piezo_fpi.Model` and `piezo_fpi.calibrate`: the method's calibrated model
//! (`fpi_host::method::model::HostModel`), calibrated from arrays
//! (`fpi_host::method::calibrate`, as `fpi calibrate` does from files), and its
//! prediction (`fpi predict`) and inversion (`fpi invert`) of arrays;
//! `piezo_fpi.predict_axes`: every axis of a stage of several stacks
//! (`fpi axes predict`), and `piezo_fpi.refine_axes`: its grid corrected for
//! the built stage (`fpi axes refine`).

use std::path::{Path, PathBuf};

use fpi_host::data::fem::FemMaps;
use fpi_host::method::calibrate as method;
use fpi_host::method::model::{HostModel, Kind};
use fpi_host::method::{invert, predict};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{column, columns_dict, floats, required};
use crate::board::warn;
use crate::errors::{to_py, Otherwise};

/// A calibrated model (the file `fpi calibrate` writes). Lengths in µm,
/// voltages in V, forces in N, times in s.
#[pyclass(module = "piezo_fpi", frozen)]
pub struct Model {
    inner: HostModel,
}

/// A finite array of `name`, increasing if `increasing`.
fn finite(name: &str, v: &[f64], increasing: bool) -> PyResult<()> {
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{name}[{k}] = {}: not a finite number",
            v[k]
        )));
    }
    if increasing {
        if let Some(k) = v.windows(2).position(|w| w[1] <= w[0]) {
            return Err(PyValueError::new_err(format!(
                "{name}[{}] = {} does not increase (previous {})",
                k + 1,
                v[k + 1],
                v[k]
            )));
        }
    }
    Ok(())
}

/// The stage maps for `model` from the FEM table `fem` (`fpi predict --fem`):
/// the table read, its plausibility warnings given as Python warnings, and the
/// model's `[fem_correction]` applied.
fn stage_maps(py: Python<'_>, model: &HostModel, fem: &Path) -> PyResult<FemMaps> {
    let maps = py
        .detach(|| FemMaps::read(fem).map_err(anyhow::Error::from))
        .map_err(|e| to_py(py, e, Otherwise::Input))?;
    for w in maps.warnings() {
        warn(py, w)?;
    }
    model
        .stage_maps(&maps)
        .map_err(|e| to_py(py, e, Otherwise::Input))
}

#[pymethods]
impl Model {
    /// Reads a model file (`fpi calibrate`'s).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py
            .detach(|| HostModel::read(&path))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        Ok(Self { inner })
    }

    /// Writes the model file (atomically, as `fpi calibrate` writes it).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.write(&path))
            .map_err(|e| to_py(py, e, Otherwise::Input))
    }

    /// The model kind (`efpi`, `fpi`, `pi`, `ldpi`, `epi`, `gpi`, `branch`).
    #[getter]
    fn kind(&self) -> String {
        self.inner.kind.name().to_string()
    }

    /// RMSE of the fit over all fitted samples, µm.
    #[getter]
    fn rmse_um(&self) -> f64 {
        self.inner.calibration.rmse_um
    }

    /// Largest error of the fit over all fitted samples, µm.
    #[getter]
    fn mte_um(&self) -> f64 {
        self.inner.calibration.mte_um
    }

    /// Each recording's fit: a list of dicts `file`, `samples`, `rmse_um`,
    /// `mte_um`.
    #[getter]
    fn per_file<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.inner
            .calibration
            .per_file
            .iter()
            .map(|f| {
                let d = PyDict::new(py);
                d.set_item("file", &f.file)?;
                d.set_item("samples", f.samples)?;
                d.set_item("rmse_um", f.rmse_um)?;
                d.set_item("mte_um", f.mte_um)?;
                Ok(d)
            })
            .collect()
    }

    /// What looked suspicious in the calibration data.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.calibration.warnings.clone()
    }

    /// The correction of the stage's FEM tables the model carries (`fpi
    /// refine`, `fpi axes refine`), or `None`: `stage_gain`, `stage_offset_um`
    /// (µm), `preload_scale`, the `fem` it was refined against and the runs it
    /// was `refined_on`.
    #[getter]
    fn fem_correction<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(c) = &self.inner.fem_correction else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("stage_gain", c.stage_gain)?;
        d.set_item("stage_offset_um", c.stage_offset_um)?;
        d.set_item("preload_scale", c.preload_scale)?;
        d.set_item("fem", &c.fem)?;
        d.set_item("refined_on", c.refined_on.clone())?;
        Ok(Some(d))
    }

    /// Predicts the stage for the drive `voltage_V(t_s)` (V, s) with the stage's
    /// FEM table `fem` (`fpi predict`): a dict of arrays with its columns
    /// `t_s`, `voltage_V`, `x_pea_um` (stack extension), `preload_N`,
    /// `x_fhps_um` (stage output).
    #[pyo3(signature = (*, fem, t_s, voltage_V))]
    #[allow(non_snake_case)]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        fem: PathBuf,
        t_s: &Bound<'py, PyAny>,
        voltage_V: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (t, u) = (floats(t_s, "t_s")?, floats(voltage_V, "voltage_V")?);
        finite("t_s", &t, true)?;
        finite("voltage_V", &u, false)?;
        if t.len() != u.len() {
            return Err(PyValueError::new_err(format!(
                "t_s has {} samples, voltage_V {}",
                t.len(),
                u.len()
            )));
        }
        let m = &self.inner;
        if let Some((k, v)) = predict::outside_range(m, &u) {
            let (lo, hi) = predict::input_range(m);
            return Err(PyValueError::new_err(format!(
                "voltage_V[{k}] = {v} V is outside the model's input range {lo}..{hi} V; the \
                 model would clamp it"
            )));
        }
        let maps = stage_maps(py, m, &fem)?;
        let p = py
            .detach(|| predict::predict(m, &maps, &t, &u))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        columns_dict(
            py,
            vec![
                ("t_s", p.t),
                ("voltage_V", p.u),
                ("x_pea_um", p.x_pea),
                ("preload_N", p.preload),
                ("x_fhps_um", p.x_fhps),
            ],
        )
    }

    /// The model with the correction of the stage's FEM table `fem` estimated
    /// from measured `runs` of the built stage (`fpi refine`): each a dict of
    /// arrays `t_s` (s), `voltage_V` (V), `force_N` (N), `x_fhps_um` (µm), as a
    /// board recording has them; `names` name the runs in the model (default
    /// `runs[k]`). The table is used as it is (the model's own correction, if
    /// any, is estimated anew).
    #[pyo3(signature = (*, fem, runs, names = None))]
    fn refine(
        &self,
        py: Python<'_>,
        fem: PathBuf,
        runs: Vec<Bound<'_, PyAny>>,
        names: Option<Vec<String>>,
    ) -> PyResult<Model> {
        let names = run_names(runs.len(), names)?;
        let m = &self.inner;
        let mut data = Vec::with_capacity(runs.len());
        for (k, (run, name)) in runs.iter().zip(names).enumerate() {
            let what = format!("runs[{k}]");
            let d = run_dict(run, &what, "t_s, voltage_V, force_N, x_fhps_um")?;
            let col = |key: &str, increasing: bool| finite_column(d, key, &what, increasing);
            let (t, u, f, x) = (
                col("t_s", true)?,
                col("voltage_V", false)?,
                col("force_N", false)?,
                col("x_fhps_um", false)?,
            );
            if let Some((i, v)) = predict::outside_range(m, &u) {
                let (lo, hi) = predict::input_range(m);
                return Err(PyValueError::new_err(format!(
                    "{what}[\"voltage_V\"][{i}] = {v} V is outside the model's input range \
                     {lo}..{hi} V; the model would clamp it"
                )));
            }
            data.push(fpi_host::data::StageRun {
                path: name.into(),
                t,
                u,
                f,
                x,
            });
        }
        let maps = py
            .detach(|| FemMaps::read(&fem).map_err(anyhow::Error::from))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        for w in maps.warnings() {
            warn(py, w)?;
        }
        let (refined, r) = py
            .detach(|| fpi_host::method::refine::refine_model(m, &maps, &data))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        for w in &r.warnings {
            warn(py, w)?;
        }
        Ok(Model { inner: refined })
    }

    /// The voltage that makes the stage follow `x_fhps_um(t_s)` (µm, s) with the
    /// stage's FEM table `fem` (`fpi invert`), within 0..`u_max` V: a dict of
    /// arrays `t_s`, `voltage_V`. Targets outside the reachable stroke are
    /// clamped, with a warning.
    #[pyo3(signature = (*, fem, t_s, x_fhps_um, u_max = 150.0))]
    fn invert<'py>(
        &self,
        py: Python<'py>,
        fem: PathBuf,
        t_s: &Bound<'py, PyAny>,
        x_fhps_um: &Bound<'py, PyAny>,
        u_max: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (t, x) = (floats(t_s, "t_s")?, floats(x_fhps_um, "x_fhps_um")?);
        finite("t_s", &t, true)?;
        finite("x_fhps_um", &x, false)?;
        if t.len() != x.len() {
            return Err(PyValueError::new_err(format!(
                "t_s has {} samples, x_fhps_um {}",
                t.len(),
                x.len()
            )));
        }
        let m = &self.inner;
        let maps = stage_maps(py, m, &fem)?;
        let inv = py
            .detach(|| invert::invert(m, &maps, &t, &x, u_max))
            .map_err(|e| match to_py(py, e, Otherwise::Input) {
                e if e.is_instance_of::<PyValueError>(py) => {
                    PyValueError::new_err(e.to_string().replace("--u-max", "u_max"))
                }
                e => e,
            })?;
        if inv.clamped_targets > 0 {
            warn(
                py,
                &format!(
                    "{} of {} target samples lie outside the reachable stroke {:.3}..{:.3} µm \
                     and were clamped to it",
                    inv.clamped_targets,
                    t.len(),
                    inv.reachable.0,
                    inv.reachable.1
                ),
            )?;
        }
        if inv.clamped_voltage > 0 {
            warn(
                py,
                &format!(
                    "{} samples needed a voltage outside 0..{u_max} V and were clamped",
                    inv.clamped_voltage
                ),
            )?;
        }
        columns_dict(py, vec![("t_s", inv.t), ("voltage_V", inv.u)])
    }

    fn __repr__(&self) -> String {
        format!(
            "Model(kind={:?}, rmse_um={:.4}, files={:?})",
            self.inner.kind.name(),
            self.inner.calibration.rmse_um,
            self.inner.calibration.files
        )
    }
}

/// The names of `runs` recordings: `names` where given (one per run), else
/// `runs[k]`; no runs, or a count of names other than the runs', refused.
fn run_names(runs: usize, names: Option<Vec<String>>) -> PyResult<Vec<String>> {
    if runs == 0 {
        return Err(PyValueError::new_err("runs: no recordings given"));
    }
    match names {
        Some(n) if n.len() != runs => Err(PyValueError::new_err(format!(
            "names: {} names for {runs} runs",
            n.len()
        ))),
        Some(n) => Ok(n),
        None => Ok((0..runs).map(|k| format!("runs[{k}]")).collect()),
    }
}

/// Run `what` (`runs[k]`) as a dict of arrays; `columns` says which, for the
/// error.
fn run_dict<'a, 'py>(
    run: &'a Bound<'py, PyAny>,
    what: &str,
    columns: &str,
) -> PyResult<&'a Bound<'py, PyDict>> {
    run.cast::<PyDict>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{what}: a dict of arrays ({columns}), not {}",
            run.get_type()
        ))
    })
}

/// Column `key` of run `what`, which must be there, finite (and increasing if
/// `increasing`).
fn finite_column(
    d: &Bound<'_, PyDict>,
    key: &str,
    what: &str,
    increasing: bool,
) -> PyResult<Vec<f64>> {
    let v = required(d, key, what)?;
    finite(&format!("{what}[{key:?}]"), &v, increasing)?;
    Ok(v)
}

/// The recording `run` (a dict of arrays, `runs[k]`) for calibration: `t_s`,
/// `voltage_V`, `force_N` if it has one, and the displacement, µm:
/// `displacement_um` (a preload rig's stack extension) or else `x_fhps_um` (a
/// stage's output, as a board recording has it).
fn run_data(
    run: &Bound<'_, PyAny>,
    k: usize,
    name: &str,
    rows: Option<(usize, usize)>,
) -> PyResult<method::CalibData> {
    let what = format!("runs[{k}]");
    let d = run_dict(run, &what, "t_s, voltage_V, force_N, displacement_um")?;
    let t = required(d, "t_s", &what)?;
    let u = required(d, "voltage_V", &what)?;
    let f = column(d, "force_N", &what)?;
    let x = match column(d, "displacement_um", &what)? {
        Some(x) => x,
        None => column(d, "x_fhps_um", &what)?.ok_or_else(|| {
            PyValueError::new_err(format!(
                "{what}: no displacement: a column displacement_um (a rig's) or x_fhps_um (a \
                 stage's or a board recording's)"
            ))
        })?,
    };
    let short = Path::new(name)
        .file_name()
        .map(|n| n.to_string_lossy().trim_end_matches(".gz").to_string())
        .unwrap_or_else(|| name.to_string());
    method::from_columns(&short, &t, &u, f.as_deref(), &x, rows)
        .map_err(|e| PyValueError::new_err(format!("{what} ({name}): {e:#}")))
}

/// Calibrates a model on recordings (`fpi calibrate`): `runs` is a list of
/// dicts of arrays with the datasets' columns (`t_s` s, `voltage_V` V,
/// `force_N` N, and `displacement_um` µm or `x_fhps_um` µm; a board recording
/// works as it is). `kind` as `fpi calibrate --kind` (default: efpi, or epi
/// without force); `operators`, `compliance` (µm/N), `rows` (1-based,
/// inclusive, one recording only) likewise. `names` name the recordings in the
/// model file (default `runs[k]`).
#[pyfunction]
#[pyo3(signature = (runs, kind = None, *, operators = None, compliance = None, rows = None, names = None))]
pub fn calibrate(
    py: Python<'_>,
    runs: &Bound<'_, PyAny>,
    kind: Option<&str>,
    operators: Option<usize>,
    compliance: Option<f64>,
    rows: Option<(usize, usize)>,
    names: Option<Vec<String>>,
) -> PyResult<Model> {
    let runs: Vec<Bound<'_, PyAny>> = runs
        .try_iter()
        .map_err(|_| PyTypeError::new_err("runs: a list of dicts of arrays"))?
        .collect::<PyResult<_>>()?;
    let names = run_names(runs.len(), names)?;
    if rows.is_some() && runs.len() != 1 {
        return Err(PyValueError::new_err(format!(
            "rows selects a window of one recording; {} were given",
            runs.len()
        )));
    }
    let kind = kind
        .map(Kind::parse)
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("kind: {e:#}")))?;
    let data = runs
        .iter()
        .zip(&names)
        .enumerate()
        .map(|(k, (r, n))| run_data(r, k, n, rows))
        .collect::<PyResult<Vec<_>>>()?;
    let fix = |e: anyhow::Error| {
        let text = format!("{e:#}")
            .replace("--compliance", "compliance")
            .replace("--operators", "operators")
            .replace("--rows", "rows");
        PyValueError::new_err(text)
    };
    let (opt, note) = method::settle(&data, kind, operators, compliance, rows).map_err(fix)?;
    if let Some(note) = note {
        warn(py, &note)?;
    }
    let mut m = py.detach(|| method::calibrate(&data, &opt)).map_err(fix)?;
    m.calibration.rows = rows.map(|(a, b)| [a, b]);
    m.calibration.files = names;
    for w in &m.calibration.warnings {
        warn(py, w)?;
    }
    Ok(Model { inner: m })
}

/// Every axis of a stage of several stacks predicted from its FEM grid `grid`
/// (`fpi axes predict`): `models` one for every stack or one per stack in axis
/// order (a model refined by `fpi axes refine` brings its axis's correction of
/// the grid), `voltages` one drive per axis (V) at times `t_s` (s); coupled, or
/// each axis alone (`independent`). A dict of arrays: `t_s`, then per axis
/// `voltage_V@x`, `x_pea_um@x`, `preload_N@x`, `x_fhps_um@x`, ….
#[pyfunction]
#[pyo3(signature = (models, *, grid, t_s, voltages, independent = false))]
pub fn predict_axes<'py>(
    py: Python<'py>,
    models: Vec<PyRef<'py, Model>>,
    grid: PathBuf,
    t_s: &Bound<'py, PyAny>,
    voltages: Vec<Bound<'py, PyAny>>,
    independent: bool,
) -> PyResult<Bound<'py, PyDict>> {
    use fpi_host::method::axes::{grid::FemGrid, predict as axes};
    let t = floats(t_s, "t_s")?;
    finite("t_s", &t, true)?;
    let u = voltages
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let name = format!("voltages[{i}]");
            let u = floats(v, &name)?;
            finite(&name, &u, false)?;
            Ok(u)
        })
        .collect::<PyResult<Vec<_>>>()?;
    let g = py
        .detach(|| FemGrid::read(&grid).map_err(anyhow::Error::from))
        .map_err(|e| to_py(py, e, Otherwise::Input))?;
    let of = axes::model_of_each_stack(models.len(), g.axes(), "models")
        .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let chosen: Vec<&HostModel> = of.iter().map(|&k| &models[k].inner).collect();
    let names: Vec<String> = of.iter().map(|k| format!("models[{k}]")).collect();
    let p = py
        .detach(|| axes::run(&chosen, &names, &g, &t, &u, independent))
        .map_err(|e| to_py(py, e, Otherwise::Input))?;
    let columns = p.columns();
    columns_dict(
        py,
        columns
            .iter()
            .map(|(n, v)| (n.as_str(), v.to_vec()))
            .collect(),
    )
}

/// Corrects a stage's FEM grid for the built stage, axis by axis (`fpi axes
/// refine`): `models` one for every stack or one per stack in axis order,
/// `runs` measured runs of the built stage, each a dict of arrays with `t_s`
/// (s) and per axis `voltage_V@x` (V), `force_N@x` (N) and `x_fhps_um@x` (µm),
/// as `predict_axes` and `fpi axes record` name them; `names` name the runs in
/// the models (default `runs[k]`). Each stack's model with its axis's
/// `[fem_correction]`, in axis order (`predict_axes` applies it).
#[pyfunction]
#[pyo3(signature = (models, *, grid, runs, names = None))]
pub fn refine_axes(
    py: Python<'_>,
    models: Vec<PyRef<'_, Model>>,
    grid: PathBuf,
    runs: Vec<Bound<'_, PyAny>>,
    names: Option<Vec<String>>,
) -> PyResult<Vec<Model>> {
    use fpi_host::method::axes::grid::{column as named, FemGrid};
    use fpi_host::method::axes::{predict as axes, refine};
    let names = run_names(runs.len(), names)?;
    let g = py
        .detach(|| FemGrid::read(&grid).map_err(anyhow::Error::from))
        .map_err(|e| to_py(py, e, Otherwise::Input))?;
    let of = axes::model_of_each_stack(models.len(), g.axes(), "models")
        .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let chosen: Vec<&HostModel> = of.iter().map(|&k| &models[k].inner).collect();
    let model_names: Vec<String> = of.iter().map(|k| format!("models[{k}]")).collect();
    let mut data = Vec::with_capacity(runs.len());
    for (k, (run, name)) in runs.iter().zip(names).enumerate() {
        let what = format!("runs[{k}]");
        let d = run_dict(run, &what, "t_s, voltage_V@x, force_N@x, x_fhps_um@x, …")?;
        let t = finite_column(d, "t_s", &what, true)?;
        let per_axis = |q: &str| -> PyResult<Vec<Vec<f64>>> {
            (0..g.axes())
                .map(|i| finite_column(d, &named(q, i), &what, false))
                .collect()
        };
        data.push(refine::AxesRun {
            name,
            t,
            u: per_axis("voltage_V")?,
            f: per_axis("force_N")?,
            x: per_axis("x_fhps_um")?,
        });
    }
    let (refined, r) = py
        .detach(|| refine::refine_models(&chosen, &model_names, &g, &data))
        .map_err(|e| to_py(py, e, Otherwise::Input))?;
    for w in &r.warnings {
        warn(py, w)?;
    }
    Ok(refined.into_iter().map(|inner| Model { inner }).collect())
}
