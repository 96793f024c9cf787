//! `piezo_fpi.Board`: a board (a serial device, the emulated board on
//! `tcp:HOST:PORT`, or `virtual`, the firmware built for this host and run in
//! this process) through the host library's client (`fpi_host::board::client`),
//! one method per `fpi board` command, each the library's function that
//! `fpi board` runs (`fpi_host::board::commands`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::anyhow;
use fpi_host::board::client::{axis_name, axis_number, real, Client};
use fpi_host::board::commands::{self, BenchSettings, Streamed};
use fpi_host::board::frf::FrfSettings;
use fpi_host::board::live::{Live, SharedClient};
use fpi_host::board::mass;
use fpi_host::board::motion::{self, Until};
use fpi_host::board::raster::{self, RasterSpec};
use fpi_host::board::recording::{column_names, signals_named};
use fpi_host::board::restore::or_restore;
use fpi_host::board::step::StepSettings;
use fpi_host::cli::board::{loadable, Loadable};
use fpi_host::method::export::ExportOptions;
use pyo3::prelude::*;
use pyo3::types::{PyComplex, PyDict};

use crate::arrays::{columns_dict, floats};
use crate::errors::{interrupted, to_py, BoardError, Otherwise};
use crate::recorder::Recorder;

/// The loop settings of an exported model with `fpi board load`'s defaults.
fn export_options(rate: u32, u_max: f64, slew: f64, stroke_voltage: Option<f64>) -> ExportOptions {
    ExportOptions {
        rate_hz: rate,
        u_max,
        slew,
        stroke_voltage,
    }
}

/// A board over its command link. Each method is an `fpi board` command and
/// returns the control tick the board took it on (or what the command reports);
/// a refusal or a fault raises `BoardError` with the board's reason, a bad
/// argument `ValueError` or `TypeError`, a failed link `LinkError`. Lengths are
/// in µm, voltages in V, forces in N, times in s unless a name says otherwise.
/// Use it as a context manager, or call `close()`.
#[pyclass(module = "piezo_fpi")]
pub struct Board {
    client: Arc<Mutex<Option<Client>>>,
    port: String,
    /// A live recording runs (`record_start`).
    live: Arc<AtomicBool>,
    /// The axis its per-axis calls address (0: x; `board.axes["y"]` is the
    /// same board addressing y).
    axis: u8,
}

impl Board {
    /// Runs `f` on the open client with the GIL released.
    pub(crate) fn run<R: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut Client) -> anyhow::Result<R> + Send,
    ) -> PyResult<R> {
        py.detach(|| {
            let mut guard = self
                .client
                .lock()
                .map_err(|_| anyhow!("the link failed in another thread"))?;
            let c = guard
                .as_mut()
                .ok_or_else(|| anyhow!("the link to {} is closed", self.port))?;
            c.on_axis(self.axis)?;
            f(c)
        })
        .map_err(|e| to_py(py, e, Otherwise::Link))
    }

    /// `load` of a file of several axes (`fpi board load` of it): every
    /// axis's model, then the decoupling. Returns `axes` and each axis's
    /// `tick`.
    fn load_axes<'py>(
        &self,
        py: Python<'py>,
        file: &fpi_host::model_file::AxesModel,
        store: bool,
        match_mass: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        if match_mass {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "match_mass measures one axis: load the file of several axes without it",
            ));
        }
        let axes = self.run(py, |c| Ok(usize::from(c.hello().axes)))?;
        if file.models().len() != axes {
            return Err(BoardError::new_err(format!(
                "the model file has {} axes and the board {axes}: a file of several axes loads \
                 onto a board of as many",
                file.models().len()
            )));
        }
        let ticks = self.run(py, |c| {
            let mut ticks = Vec::new();
            fpi_host::board::axes::load(c, file, store, |_, t| ticks.push(t))?;
            Ok(ticks)
        })?;
        let d = PyDict::new(py);
        d.set_item("axes", ticks.len())?;
        d.set_item("tick", ticks)?;
        Ok(d)
    }

    /// `autotune(every_axis=True)`: every axis from `loaded`, then the
    /// coupling, into the file of several axes `out`; the table.
    fn autotune_every_axis(
        &self,
        py: Python<'_>,
        loaded: Loadable,
        design: &fpi_host::method::tune::TuneOptions,
        settings: (
            &fpi_host::board::autotune::Settings,
            &fpi_host::board::decoupling::Settings,
        ),
        store: bool,
        out: &std::path::Path,
    ) -> PyResult<String> {
        use fpi_host::board::axes;
        let tuned = self.run(py, |c| {
            let n = usize::from(c.hello().axes);
            axes::autotune(
                c,
                &loaded.every_axis(n),
                design,
                settings,
                store,
                &mut |f| axes::write(f, out),
                |_| {},
            )
        })?;
        Ok(axes::table(&tuned))
    }

    /// Refuses `what` (a command that uses the recorder itself) while a live
    /// recording runs.
    fn recorder_free(&self, what: &str) -> PyResult<()> {
        if self.live.load(Ordering::Relaxed) {
            return Err(BoardError::new_err(format!(
                "{what} uses the board's recorder, which a live recording holds \
                 (record_start): stop it first"
            )));
        }
        Ok(())
    }
}

/// Polls Python's signal handlers (Ctrl-C) from a loop running without the
/// GIL: true once one raised, its exception kept in `caught`.
fn signalled(caught: &mut Option<PyErr>) -> bool {
    if caught.is_none() {
        if let Err(e) = Python::attach(|py| py.check_signals()) {
            *caught = Some(e);
        }
    }
    caught.is_some()
}

#[pymethods]
impl Board {
    /// Opens the board on `port`: a serial device (`/dev/ttyUSB0`, `COM3`),
    /// `tcp:HOST:PORT` (the emulated board), or `virtual` (the firmware built for
    /// this host, in this process, board time at real time, starting afresh; its
    /// link paced as the UART, or as USB with `virtual:usb`).
    /// Raises `LinkError` if it cannot be opened or the board does not answer.
    #[new]
    fn new(py: Python<'_>, port: &str) -> PyResult<Self> {
        let name = port.to_string();
        let c = py
            .detach(|| commands_open(&name))
            .map_err(|e| to_py(py, e, Otherwise::Link))?;
        Ok(Self {
            client: Arc::new(Mutex::new(Some(c))),
            port: port.to_string(),
            live: Arc::new(AtomicBool::new(false)),
            axis: 0,
        })
    }

    /// The board's runtime settings by key path, a mapping
    /// (`board.settings["stage/0/damping"] = False`; see `Settings`).
    #[getter]
    fn settings(slf: Py<Self>) -> crate::settings::Settings {
        crate::settings::Settings::of(slf)
    }

    /// The port it was opened on.
    #[getter]
    fn port(&self) -> String {
        self.port.clone()
    }

    /// The axis its per-axis calls address: `"x"`, `"y"` or `"z"`.
    #[getter]
    fn axis(&self) -> String {
        axis_name(self.axis)
    }

    /// Each axis of the board by name (`"x"`, `"y"`, `"z"`): the same board
    /// on the same link, its per-axis calls addressing that axis
    /// (`board.axes["y"].step(20.0)`). A board of one axis has `"x"` only.
    #[getter]
    fn axes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let n = self.run(py, |c| Ok(c.hello().axes))?;
        let d = PyDict::new(py);
        for axis in 0..n {
            let view = Self {
                client: Arc::clone(&self.client),
                port: self.port.clone(),
                live: Arc::clone(&self.live),
                axis,
            };
            d.set_item(axis_name(axis), Py::new(py, view)?)?;
        }
        Ok(d)
    }

    /// The control rate, Hz.
    #[getter]
    fn rate_hz(&self, py: Python<'_>) -> PyResult<f64> {
        self.run(py, |c| Ok(c.rate_hz()))
    }

    /// What the board has (`fpi board info`): `board` (`driver`, `emulated`
    /// or `virtual`), `firmware`, `protocol`, `axes`, `front_end`
    /// (`internal` or `precision`), `rate_hz`, `capacity` (operators, creep
    /// terms, table intervals), `buffers` (recorder samples, stream points),
    /// `limits` (`setpoint_min_V`, `setpoint_max_V`, `step_max_V`,
    /// `safe_min_V`, `safe_max_V`), `reset` (why it started), `link` (`usb`
    /// or `uart`: the link it answers on; the emulated board: the one it paces
    /// its own as), `link_bytes_per_s`, `features` (each of `closed_loop`,
    /// `dynamics`, `damping`, `shaping`, `mass_ratio`, `bench`: whether the
    /// board with its running model has it), `commands` (the link commands it
    /// takes) and `settings` (the runtime settings' keys it has).
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let i = self.run(py, fpi_host::board::info::read)?;
        let h = &i.hello;
        let d = PyDict::new(py);
        d.set_item("board", i.kind)?;
        d.set_item("firmware", h.firmware.to_string())?;
        d.set_item("protocol", h.protocol)?;
        d.set_item("axes", h.axes)?;
        d.set_item("front_end", h.front_end.name())?;
        d.set_item("rate_hz", h.rate_hz)?;
        d.set_item("capacity", (h.capacity[0], h.capacity[1], h.capacity[2]))?;
        d.set_item("buffers", (h.buffers[0], h.buffers[1]))?;
        let limits = PyDict::new(py);
        for (name, bits) in [
            "setpoint_min_V",
            "setpoint_max_V",
            "step_max_V",
            "safe_min_V",
            "safe_max_V",
        ]
        .into_iter()
        .zip(h.limits)
        {
            limits.set_item(name, real(bits))?;
        }
        d.set_item("limits", limits)?;
        d.set_item("reset", format!("{:?}", h.reset))?;
        d.set_item("link", h.link.name())?;
        d.set_item("link_bytes_per_s", h.link.bytes_per_s())?;
        let features = PyDict::new(py);
        for (name, on) in i.features.named() {
            features.set_item(name, on)?;
        }
        d.set_item("features", features)?;
        d.set_item("commands", i.commands.clone())?;
        d.set_item("settings", i.settings.clone())?;
        Ok(d)
    }

    /// The board, its model and the loop's state as a dict (`fpi board status`):
    /// `tick`, `time_s`, `state` (`running`, `parked` or `fault`), `fault` (the
    /// reason, or None), `reference_um`, `estimate_um`, `position_sensor_um`,
    /// `setpoint_V`, `force_N`, `amplifier_on`, `source`, `approaching`, `loop`,
    /// `compensated`, `model` (a dict: `crc`, `origin`, `operators`,
    /// `creep_terms`, `stroke_um`, `safe_V`, `feedback`), `stream`, `recorder`,
    /// `link` (counters), `supervision_ms`, `late_ticks`; `axis` (the axis it
    /// describes) and `fault_axis` (the axis whose fault parked every axis,
    /// or None).
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let (h, m, s, k) = self.run(py, |c| {
            Ok((c.hello().clone(), c.model()?, c.status()?, c.counters()?))
        })?;
        let rate = f64::from(h.rate_hz);
        let d = PyDict::new(py);
        d.set_item("axis", axis_name(s.axis))?;
        d.set_item("fault_axis", s.fault_axis.map(axis_name))?;
        d.set_item("tick", s.tick)?;
        d.set_item("time_s", f64::from(s.tick) / rate)?;
        let (state, fault) = match s.fault {
            None => ("running", None),
            Some(f) if f.code == piezo_fpi::control::Fault::Stopped as u8 => ("parked", None),
            Some(f) => (
                "fault",
                Some(
                    piezo_fpi::control::Fault::from_code(f.code)
                        .map_or("unknown fault", |f| f.message()),
                ),
            ),
        };
        d.set_item("state", state)?;
        d.set_item("fault", fault)?;
        d.set_item(
            "fault_tick",
            s.fault.filter(|_| fault.is_some()).map(|f| f.at),
        )?;
        d.set_item("reference_um", real(s.signals[0]))?;
        d.set_item("estimate_um", real(s.signals[1]))?;
        d.set_item("setpoint_V", real(s.signals[2]))?;
        d.set_item("force_N", real(s.signals[3]))?;
        d.set_item("position_sensor_um", real(s.signals[4]))?;
        d.set_item("amplifier_on", s.amplifier_on)?;
        d.set_item("source", format!("{:?}", s.source).to_lowercase())?;
        d.set_item("approaching", s.approaching)?;
        d.set_item(
            "loop",
            match format!("{:?}", s.loop_mode).as_str() {
                "Open" => "open",
                "Closed" => "closed",
                _ => "feedback",
            },
        )?;
        d.set_item("compensated", s.compensated)?;
        d.set_item("damping", s.damping)?;
        d.set_item("shaping", s.shaping)?;
        d.set_item(
            "lead_ratio",
            s.lead_ratio
                .map(|(b, _)| piezo_fpi::q::LeadRatio::from_bits(b).to_num::<f64>()),
        )?;
        d.set_item("lead_applied", s.lead_ratio.map(|(_, a)| a))?;
        d.set_item("supervision_ms", f64::from(s.supervision[0]) / rate * 1e3)?;
        d.set_item("late_ticks", s.overruns)?;
        d.set_item("governed_ticks", s.governed_ticks)?;
        d.set_item("ended_points", s.ended_points)?;
        d.set_item("motion_armed", s.armed[0])?;
        d.set_item("record_armed", s.armed[1])?;
        let model = PyDict::new(py);
        model.set_item("crc", format!("{:08x}", m.crc))?;
        model.set_item("origin", format!("{:?}", m.origin))?;
        model.set_item("operators", m.size[0])?;
        model.set_item("creep_terms", m.size[1])?;
        model.set_item("stroke_um", (real(m.window[0]), real(m.window[1])))?;
        model.set_item("safe_V", real(m.window[2]))?;
        model.set_item("feedback", m.feedback.is_some())?;
        model.set_item("stored_generation", m.stored.map(|(g, _)| g))?;
        d.set_item("model", model)?;
        let stream = PyDict::new(py);
        stream.set_item("queued", s.stream[0])?;
        stream.set_item("free", s.stream[1])?;
        stream.set_item("received", s.stream[2])?;
        stream.set_item("underrun_ticks", s.stream[3])?;
        d.set_item("stream", stream)?;
        let rec = PyDict::new(py);
        rec.set_item("recording", s.recorder[0] == 1)?;
        rec.set_item("kept", s.recorder[1])?;
        rec.set_item("dropped", s.recorder[2])?;
        rec.set_item("waiting", s.recorder[3])?;
        d.set_item("recorder", rec)?;
        let link = PyDict::new(py);
        link.set_item("requests", k.requests)?;
        link.set_item("refused", k.refused)?;
        link.set_item("malformed", k.malformed)?;
        link.set_item("crc_errors", k.crc_errors)?;
        link.set_item("overlong", k.overlong)?;
        link.set_item("other_version", k.version)?;
        link.set_item("unknown", k.unknown)?;
        d.set_item("link", link)?;
        Ok(d)
    }

    /// What `fpi board status` prints, as text.
    fn status_text(&self, py: Python<'_>) -> PyResult<String> {
        self.run(py, fpi_host::cli::board::status_text)
    }

    /// The stage's position, µm: the position sensor's reading when the running
    /// model closes a loop on it, else the model's estimate (PI's `POS?`).
    fn position(&self, py: Python<'_>) -> PyResult<f64> {
        self.run(py, commands::position)
    }

    /// Whether the stage is on target (PI's `ONT?`): running, the reference
    /// standing still, and the position within `tolerance_um` of it.
    #[pyo3(signature = (tolerance_um = commands::ON_TARGET_UM))]
    fn on_target(&self, py: Python<'_>, tolerance_um: f64) -> PyResult<bool> {
        self.run(py, |c| Ok(commands::on_target(c, tolerance_um)?.0))
    }

    /// Waits until the stage is on target (see `on_target`) for up to `timeout`
    /// seconds; the position, µm. Raises `TimeoutError` if it is not, and
    /// `BoardError` if the board faults meanwhile.
    #[pyo3(signature = (timeout = 5.0, tolerance_um = commands::ON_TARGET_UM))]
    fn wait_on_target(&self, py: Python<'_>, timeout: f64, tolerance_um: f64) -> PyResult<f64> {
        let mut caught = None;
        let r = self.run(py, |c| {
            commands::wait_on_target(c, tolerance_um, timeout, || signalled(&mut caught))
        })?;
        if let Some(e) = caught {
            return Err(e);
        }
        r.ok_or_else(|| {
            pyo3::exceptions::PyTimeoutError::new_err(format!(
                "the stage was not on target (within {tolerance_um} µm, the reference held) \
                 within {timeout} s"
            ))
        })
    }

    /// Ramps to `target_um` (µm) at `speed` (µm/s) and holds it (PI's `MOV`);
    /// the tick it started. With `record`, records every tick of the move
    /// (until it holds the target, and 50 ms more) and returns `tick` and the
    /// `recording` (a dict of arrays, as `record` gives, `x_fhps_um` the true
    /// position on the emulated board) once it has ended; a fault meanwhile
    /// raises `BoardError`. Ctrl-C stops the recording (not the move):
    /// `Interrupted`, whose `done` is the recording so far.
    ///
    /// On a board of several axes, `move(x=10.0, y=20.0)` (no `target_um`)
    /// moves each axis named to its target from the same tick (not
    /// recorded).
    #[pyo3(signature = (target_um = None, speed = 1000.0, *, record = false, x = None, y = None, z = None))]
    #[allow(clippy::too_many_arguments)]
    fn r#move<'py>(
        &self,
        py: Python<'py>,
        target_um: Option<f64>,
        speed: f64,
        record: bool,
        x: Option<f64>,
        y: Option<f64>,
        z: Option<f64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let targets = [x, y, z];
        let target_um = match (target_um, targets.iter().any(Option::is_some)) {
            (Some(t), false) => t,
            (None, true) if !record => {
                let t = self.run(py, |c| commands::move_axes(c, targets, speed))?;
                return Ok(t.into_pyobject(py)?.into_any());
            }
            (None, true) => {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "move(x=…, y=…, record=True): recording a move of several axes from \
                     Python is not built yet (`fpi board move --x … --y … --record` records it)",
                ))
            }
            (Some(_), true) => {
                return Err(pyo3::exceptions::PyTypeError::new_err(
                    "move: target_um or x/y/z, not both",
                ))
            }
            (None, false) => {
                return Err(pyo3::exceptions::PyTypeError::new_err(
                    "move: a target: target_um, or x/y/z on a board of several axes",
                ))
            }
        };
        if !record {
            let t = self.run(py, |c| commands::move_to(c, target_um, speed))?;
            return Ok(t.into_pyobject(py)?.into_any());
        }
        self.recorder_free("move(record=True)")?;
        let cmd = commands::move_command(self.axis, target_um, speed)
            .map_err(|e| to_py(py, e, Otherwise::Link))?;
        let mut caught = None;
        let m = self.run(py, |c| {
            let from = real(c.status()?.signals[0]);
            motion::record(
                c,
                "the move",
                motion::move_seconds(from, target_um, speed),
                Until::Rest,
                |c, _| Ok((c.ack(&cmd)?, ())),
                || signalled(&mut caught),
            )
        })?;
        recorded(py, m, caught, "move")
    }

    /// Runs the waveform generator (PI's `WAV`/`WGO`): `shape` `sine`,
    /// `triangle` or `cosine` (a raised cosine from the bottom of the swing),
    /// half-swing `amplitude_um` about `offset_um` (µm), at `freq_hz` (Hz), for
    /// `cycles` periods (0: until the next command). It starts with an approach
    /// to its first point.
    ///
    /// With `record`, records every tick of it (its approach included) for
    /// `seconds` of board time (needed where `cycles` is 0), or until a
    /// finite wave has ended and 50 ms more, and returns `tick` and the
    /// `recording` (as `move` does).
    #[pyo3(signature = (shape = "sine", *, amplitude_um, offset_um, freq_hz, cycles = 0, record = false, seconds = None))]
    #[allow(clippy::too_many_arguments)]
    fn wave<'py>(
        &self,
        py: Python<'py>,
        shape: &str,
        amplitude_um: f64,
        offset_um: f64,
        freq_hz: f64,
        cycles: u32,
        record: bool,
        seconds: Option<f64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        if !record {
            if seconds.is_some() {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "seconds: how long to record; it goes with record=True",
                ));
            }
            let t = self.run(py, |c| {
                commands::wave(c, shape, amplitude_um, offset_um, freq_hz, cycles)
            })?;
            return Ok(t.into_pyobject(py)?.into_any());
        }
        let until = match (seconds, cycles) {
            (Some(s), _) => Until::seconds(s).map_err(|e| to_py(py, e, Otherwise::Link))?,
            (None, 0) => {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "seconds: how long to record a wave that runs until the next command \
                     (cycles 0); or give cycles",
                ))
            }
            (None, _) => Until::Rest,
        };
        self.recorder_free("wave(record=True)")?;
        let mut caught = None;
        let m = self.run(py, |c| {
            let cmd = commands::wave_command(c, shape, amplitude_um, offset_um, freq_hz, cycles)?;
            motion::record(
                c,
                "the wave",
                f64::from(cycles) / freq_hz + 0.1,
                until,
                |c, _| Ok((c.ack(&cmd)?, ())),
                || signalled(&mut caught),
            )
        })?;
        recorded(py, m, caught, "wave")
    }

    /// Streams a trajectory (µm, an array), one point every `interval` control
    /// ticks (20 = 1 kHz at 20 kHz), interpolated on the board; the board
    /// supervises the host meanwhile. Returns `points`, `started_tick` (for a
    /// stream `armed` for the trigger input: the tick it was armed), `armed`,
    /// `underrun_ticks`. Ctrl-C stops it with the board holding (raises
    /// `Interrupted`, whose `done` gives the points sent). With `record`, every
    /// tick of it is recorded (until the board holds its last point, and 50 ms
    /// more) and returned as `recording` (a dict of arrays, as `record` gives).
    #[pyo3(signature = (points_um, interval = 20, *, record = false))]
    fn stream<'py>(
        &self,
        py: Python<'py>,
        points_um: &Bound<'py, PyAny>,
        interval: u16,
        record: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let points = floats(points_um, "points_um")?;
        if record {
            self.recorder_free("stream(record=True)")?;
        }
        let mut caught = None;
        let (r, rec) = self.run(py, |c| {
            if !record {
                let r = commands::stream(c, &points, interval, |_| {}, || signalled(&mut caught))?;
                return Ok((r, None));
            }
            let m = motion::record_stream(c, &points, interval, |_| {}, || signalled(&mut caught))?;
            if let (Some(e), Streamed::Played(_)) = (m.fault, &m.result) {
                return Err(e);
            }
            Ok((m.result, Some(m.recording)))
        })?;
        let d = PyDict::new(py);
        if let Some(rec) = rec {
            d.set_item("recording", columns_dict(py, rec.columns())?)?;
        }
        match r {
            Streamed::Played(r) => {
                d.set_item("points", r.points)?;
                d.set_item("started_tick", r.started)?;
                d.set_item("armed", r.armed)?;
                d.set_item("underrun_ticks", r.underruns)?;
                Ok(d)
            }
            Streamed::Stopped { sent, held_at } => {
                d.set_item("points", sent)?;
                d.set_item("held_at_tick", held_at)?;
                Err(stopped(py, caught, "stream", d.into_any().unbind()))
            }
        }
    }

    /// Records every `decimation`-th control tick for `seconds` of board time
    /// (PI's data recorder, `DRC`/`DRR?`): a dict of numpy arrays with the
    /// recording's CSV columns (`t_s`, `voltage_V`, `force_N`, `x_ref_um`,
    /// `x_est_um`, `status`, `x_fhps_um`, `x_sensor_um`). Ctrl-C stops it early:
    /// the recorder is stopped, the stage left as it was, and `Interrupted` is
    /// raised with what was recorded as its `done`.
    #[pyo3(signature = (seconds, decimation = 20))]
    fn record<'py>(
        &self,
        py: Python<'py>,
        seconds: f64,
        decimation: u16,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.recorder_free("record")?;
        let mut caught = None;
        let r = self.run(py, |c| {
            commands::record(
                c,
                seconds,
                decimation,
                fpi_protocol::record::signal::ALL,
                |_, _| {},
                || signalled(&mut caught),
            )
        })?;
        let d = columns_dict(py, r.recording.columns())?;
        if r.stopped {
            return Err(stopped(py, caught, "record", d.into_any().unbind()));
        }
        if r.recording.dropped > 0 {
            warn(
                py,
                &format!(
                    "the board dropped {} samples (the link could not keep up): raise decimation",
                    r.recording.dropped
                ),
            )?;
        }
        Ok(d)
    }

    /// Starts a live recording (PI's `DRC`, then `DRR?` while motions run):
    /// the board's recorder armed for every `decimation`-th tick and read
    /// continuously by a thread of its own, between the commands this board
    /// object sends meanwhile. Returns a `Recorder`: `read()` gives what came
    /// since the last read, `stop()` the whole recording (with `keep=False`,
    /// only what `read()` had not taken: for a recording that runs for hours).
    /// `signals`: the columns to record (`voltage_V`, `force_N`, `x_ref_um`,
    /// `x_est_um`, `status`, `x_fhps_um`, `x_sensor_um`), every one by default.
    /// A command that keeps the link for long (`stream`, a `wait_on_target`)
    /// holds the reader off meanwhile: at a high rate the board's ring then
    /// drops samples, which the recorder counts and warns of. Raises
    /// `ValueError` for a decimation the link cannot carry, `BoardError` if a
    /// live recording runs already.
    #[pyo3(signature = (*, decimation = 1, signals = None, keep = true))]
    fn record_start(
        &self,
        py: Python<'_>,
        decimation: u16,
        signals: Option<Vec<String>>,
        keep: bool,
    ) -> PyResult<Recorder> {
        let bits = match signals {
            None => fpi_protocol::record::signal::ALL,
            Some(names) => signals_named(names.iter().map(String::as_str)).map_err(|n| {
                pyo3::exceptions::PyValueError::new_err(format!(
                    "signals: {n:?} is no recorded column (they are {})",
                    column_names().collect::<Vec<_>>().join(", ")
                ))
            })?,
        };
        if self.live.swap(true, Ordering::Relaxed) {
            return Err(BoardError::new_err(
                "a live recording runs already on this board: stop it first",
            ));
        }
        let link: Arc<dyn SharedClient> = self.client.clone();
        match py.detach(|| Live::start(link, bits, decimation, keep)) {
            Ok(live) => Ok(Recorder::new(live, self.live.clone())),
            Err(e) => {
                self.live.store(false, Ordering::Relaxed);
                Err(to_py(py, e, Otherwise::Link))
            }
        }
    }

    /// Uploads a model (`fpi board load`): a calibrated model file with the
    /// stage's FEM table `fem` (exported as `fpi export` does, with the loop
    /// settings `rate` Hz, `u_max` V, `slew` V/ms, `stroke_voltage` V), or a
    /// firmware model file, or a file of several axes (every axis's model and
    /// the decoupling of its coupling; returns `axes` and each axis's `tick`).
    /// `store` also keeps it in flash. The stage must be
    /// parked. `match_mass` then measures the stage's mode and starts the
    /// learned mass ratio at what it implies (`fpi board load --match-mass`).
    /// Returns `crc`, `bytes`, `tick` (and `stage_mode_hz`, `mass_ratio`).
    #[pyo3(signature = (model, fem = None, *, store = false, match_mass = false, rate = 20_000, u_max = 150.0, slew = 100.0, stroke_voltage = None))]
    #[allow(clippy::too_many_arguments)]
    fn load<'py>(
        &self,
        py: Python<'py>,
        model: PathBuf,
        fem: Option<PathBuf>,
        store: bool,
        match_mass: bool,
        rate: u32,
        u_max: f64,
        slew: f64,
        stroke_voltage: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        if match_mass {
            self.recorder_free("load(match_mass=True)")?;
        }
        let o = export_options(rate, u_max, slew, stroke_voltage);
        let loaded = py
            .detach(|| loadable(&model, fem.as_deref(), &o))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        let (fw, image) = match loaded {
            Loadable::One(fw, image) => (fw, image),
            Loadable::Axes(file) => return self.load_axes(py, &file, store, match_mass),
        };
        let (tick, crc, matched) = self.run(py, |c| {
            let tick = c.upload(&image, store, |_| {})?;
            let crc = c.model()?.crc;
            let matched = match_mass.then(|| mass::match_mass(c, &fw)).transpose()?;
            Ok((tick, crc, matched))
        })?;
        let d = PyDict::new(py);
        d.set_item("crc", format!("{crc:08x}"))?;
        d.set_item("bytes", image.len())?;
        d.set_item("tick", tick)?;
        if let Some(m) = matched {
            d.set_item("stage_mode_hz", m.stage_hz)?;
            d.set_item("mass_ratio", m.ratio)?;
        }
        Ok(d)
    }

    /// Forgets the stored model and runs the factory default.
    fn factory(&self, py: Python<'_>) -> PyResult<u32> {
        self.run(py, commands::factory)
    }

    /// Parks the stage: ramps to the safe voltage, amplifier off.
    fn safe(&self, py: Python<'_>) -> PyResult<u32> {
        self.run(py, commands::safe)
    }

    /// Clears a latched fault (the stage stays parked until the next motion).
    fn clear_fault(&self, py: Python<'_>) -> PyResult<u32> {
        self.run(py, commands::clear_fault)
    }

    /// Stops the reference where it is (PI's `HLT`/`STP`).
    fn hold(&self, py: Python<'_>) -> PyResult<u32> {
        self.run(py, commands::hold)
    }

    /// Follows the analog reference input (0–3.3 V over the model's stroke).
    fn analog(&self, py: Python<'_>) -> PyResult<u32> {
        self.run(py, commands::analog)
    }

    /// `compensated` (inverse FPI) or `uncompensated` (straight-line) drive.
    fn drive(&self, py: Python<'_>, mode: &str) -> PyResult<u32> {
        self.run(py, |c| commands::drive(c, mode))
    }

    /// Opens or closes the loop without a jump (PI's `SVO`): `open`, `closed`
    /// (feedback on the position sensor with the inverse FPI as feedforward) or
    /// `feedback` (feedback alone); the model needs a `[feedback]` section.
    #[pyo3(name = "loop")]
    fn set_loop(&self, py: Python<'_>, mode: &str) -> PyResult<u32> {
        self.run(py, |c| commands::set_loop(c, mode))
    }

    /// Switches the model's active damping on (`True`/`"on"`) or off.
    fn damping(&self, py: Python<'_>, on: &Bound<'_, PyAny>) -> PyResult<u32> {
        let state = on_off(on, "on")?;
        self.run(py, |c| commands::damping(c, &state))
    }

    /// Switches the model's reference shaping on (`True`/`"on"`) or off.
    fn shaping(&self, py: Python<'_>, on: &Bound<'_, PyAny>) -> PyResult<u32> {
        let state = on_off(on, "on")?;
        self.run(py, |c| commands::shaping(c, &state))
    }

    /// Drives the trigger output: `mode` is `off`, `travel` (a pulse every
    /// `step_um` of travel), `on_target` (high within `band_um` of the
    /// reference), `window` (high inside `low_um`…`high_um`) or `point` (a
    /// pulse at each streamed point); `pulse_ticks` long pulses. Levels not
    /// given stay as the board has them. The tick it took effect.
    #[pyo3(signature = (mode, *, step_um = None, band_um = None, low_um = None, high_um = None, pulse_ticks = None))]
    #[allow(clippy::too_many_arguments)]
    fn trigger(
        &self,
        py: Python<'_>,
        mode: &str,
        step_um: Option<f64>,
        band_um: Option<f64>,
        low_um: Option<f64>,
        high_um: Option<f64>,
        pulse_ticks: Option<u16>,
    ) -> PyResult<u32> {
        use fpi_host::board::trigger;
        let levels = trigger::Levels {
            step_um,
            band_um,
            low_um,
            high_um,
            pulse_ticks,
        };
        self.run(py, |c| {
            let mode = trigger::mode(mode)?;
            trigger::set(c, mode, &levels).map(|(t, _)| t)
        })
    }

    /// What a rising edge on the trigger input starts: `off`, `motion` (a
    /// wave or stream ordered from now on waits for it), `recorder` (a record
    /// order waits for it) or `both`. The tick it took effect.
    fn trigger_in(&self, py: Python<'_>, starts: &str) -> PyResult<u32> {
        use fpi_host::board::trigger;
        self.run(py, |c| trigger::set_input(c, trigger::starts(starts)?))
    }

    /// Parks the stage if the host is silent for `ms` milliseconds while it
    /// drives the stage (0: off).
    fn supervise(&self, py: Python<'_>, ms: u32) -> PyResult<u32> {
        self.run(py, |c| commands::supervise(c, ms))
    }

    /// Resets the board; it starts parked with its stored model. Returns its
    /// new greeting (`info()`).
    fn reset<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.run(py, |c| c.reset().map(|_| ()))?;
        self.info(py)
    }

    /// The emulated board's virtual bench (a real board refuses): `analog_v`
    /// (V on the analog input, 0–3.3), `sensor` and `position_sensor` (`ok`,
    /// `open` or `stuck`), `force_offset_n` (N), `stall_ticks`,
    /// `trigger_in_ticks` (a pulse on the trigger input), `damage_stored`,
    /// `stage` (`nominal`, `built` or a variant TOML file). Returns what was
    /// set, one line each.
    #[pyo3(signature = (*, analog_v = None, sensor = None, force_offset_n = None, stall_ticks = None, damage_stored = false, position_sensor = None, stage = None, trigger_in_ticks = None))]
    #[allow(clippy::too_many_arguments)]
    fn bench(
        &self,
        py: Python<'_>,
        analog_v: Option<f64>,
        sensor: Option<String>,
        force_offset_n: Option<f64>,
        stall_ticks: Option<u16>,
        damage_stored: bool,
        position_sensor: Option<String>,
        stage: Option<String>,
        trigger_in_ticks: Option<u16>,
    ) -> PyResult<Vec<String>> {
        let b = BenchSettings {
            analog_v,
            sensor,
            force_offset_n,
            stall_ticks,
            trigger_in_ticks,
            damage_stored,
            position_sensor,
            stage,
        };
        if b == BenchSettings::default() {
            return Err(pyo3::exceptions::PyTypeError::new_err(
                "bench: nothing to set: analog_v, sensor, force_offset_n, stall_ticks, \
                 trigger_in_ticks, damage_stored, position_sensor or stage",
            ));
        }
        self.run(py, |c| commands::bench(c, &b))
    }

    /// Steps the reference from `from_um` to `to_um` along a raised cosine of
    /// `duration_ms`, records `seconds` of board time (one tick in
    /// `decimation`) and scores the response: `rise_ms`, `overshoot_um`,
    /// `settle_ms` (±0.1 µm), `settle_tol_ms` (±`tol_um`), `final_error_um`,
    /// `governed_ticks` (the ticks the board's reference governor slowed) and
    /// the `recording` (a dict of arrays, as `record` gives).
    #[pyo3(signature = (from_um, to_um, *, seconds = 0.05, tol_um = None, duration_ms = 1.5, decimation = 1))]
    #[allow(clippy::too_many_arguments)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        from_um: f64,
        to_um: f64,
        seconds: f64,
        tol_um: Option<f64>,
        duration_ms: f64,
        decimation: u16,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.recorder_free("step")?;
        let s = StepSettings {
            from_um,
            to_um,
            seconds,
            tol_um,
            duration_ms,
            decimation,
        };
        let (rec, fig) = self.run(py, |c| or_restore(c, |c| fpi_host::board::step::run(c, &s)))?;
        let d = PyDict::new(py);
        d.set_item("rise_ms", fig.rise_ms)?;
        d.set_item("overshoot_um", fig.overshoot_um)?;
        d.set_item("settle_ms", fig.settle_ms)?;
        d.set_item("settle_tol_ms", fig.settle_tol_ms)?;
        d.set_item("final_error_um", fig.final_error_um)?;
        d.set_item("true_position", fig.true_position)?;
        d.set_item("governed_ticks", fig.governed_ticks)?;
        d.set_item("recording", columns_dict(py, rec.columns())?)?;
        Ok(d)
    }

    /// A raster on two axes of a board of several (`fpi board raster`):
    /// both go to their start, then `lines` lines start on the same tick,
    /// axis `fast` (`"x"`, `"y"` or `"z"`) a triangle at `freq_hz` over
    /// `from_um`…`to_um`, axis `slow` a ramp (or a `staircase`) over
    /// `slow_from_um`…`slow_to_um` (by default the same), every axis
    /// recorded. A dict: `fast_rms_pct` and `slow_rms_pct` (the RMS error
    /// over the central 80 % of each line, in % of the fast axis's span),
    /// `on_truth` (scored on the true positions, else the sensors),
    /// `missing` (ticks the board's ring dropped), and under each axis's
    /// name its recording (a dict of arrays: `t_s`, `x_ref_um`, `x_fhps_um`,
    /// `x_sensor_um`, `status`).
    #[pyo3(signature = (fast, slow, *, freq_hz, lines, from_um, to_um, slow_from_um = None, slow_to_um = None, staircase = false))]
    #[allow(clippy::too_many_arguments)]
    fn raster<'py>(
        &self,
        py: Python<'py>,
        fast: &str,
        slow: &str,
        freq_hz: f64,
        lines: u16,
        from_um: f64,
        to_um: f64,
        slow_from_um: Option<f64>,
        slow_to_um: Option<f64>,
        staircase: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.recorder_free("raster")?;
        let axis = |name: &str, arg: &str| {
            axis_number(name).ok_or_else(|| {
                pyo3::exceptions::PyValueError::new_err(format!(
                    "{arg}={name:?}: \"x\", \"y\" or \"z\""
                ))
            })
        };
        let spec = RasterSpec {
            fast: axis(fast, "fast")?,
            slow: axis(slow, "slow")?,
            fast_um: (from_um, to_um),
            slow_um: (slow_from_um.unwrap_or(from_um), slow_to_um.unwrap_or(to_um)),
            freq_hz,
            lines,
            staircase,
        };
        let (m, rec) = self.run(py, |c| or_restore(c, |c| raster::run(c, &spec)))?;
        if let Some(f) = m.fault {
            return Err(to_py(py, f, Otherwise::Link));
        }
        let d = PyDict::new(py);
        if let Some(f) = raster::figures(&spec, &rec) {
            d.set_item("fast_rms_pct", f.fast_rms_pct)?;
            d.set_item("slow_rms_pct", f.slow_rms_pct)?;
            d.set_item("on_truth", f.on_truth)?;
            d.set_item("missing", f.missing)?;
        }
        for (i, a) in rec.axes.iter().enumerate() {
            d.set_item(axis_name(i as u8), columns_dict(py, a.columns())?)?;
        }
        Ok(d)
    }

    /// Measures the frequency response through the board's own lock-in
    /// analyser (`fpi board frf`): `points` log-spaced frequencies from
    /// `from_hz` to `to_hz` (Hz) plus `zoom_points` around the peak, an
    /// excitation of `amplitude_um` about `at_um`. A dict of arrays: `f_hz`,
    /// and the complex responses `x` (command → position sensor, µm/µm),
    /// `force` (N/µm), `dynamic` (N/µm), `x_per_v` (µm/V).
    #[pyo3(signature = (*, from_hz = 20.0, to_hz = 4000.0, points = 40, amplitude_um = 0.1, at_um = 20.0, zoom_points = 12))]
    #[allow(clippy::too_many_arguments)]
    fn frf<'py>(
        &self,
        py: Python<'py>,
        from_hz: f64,
        to_hz: f64,
        points: usize,
        amplitude_um: f64,
        at_um: f64,
        zoom_points: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.recorder_free("frf")?;
        let s = FrfSettings {
            from_hz,
            to_hz,
            points,
            amplitude_um,
            at_um,
            zoom_points,
        };
        let pts = self.run(py, |c| {
            or_restore(c, |c| fpi_host::board::frf::measure(c, &s, |_, _| {}))
        })?;
        let d = columns_dict(py, vec![("f_hz", pts.iter().map(|p| p.f_hz).collect())])?;
        let j = PyComplex::from_doubles(py, 0.0, 1.0);
        let parts: [(&str, Part); 4] = [
            ("x", |p| (p.x.re, p.x.im)),
            ("force", |p| (p.force.re, p.force.im)),
            ("dynamic", |p| (p.dynamic.re, p.dynamic.im)),
            ("x_per_v", |p| (p.x_per_v.re, p.x_per_v.im)),
        ];
        for (name, part) in parts {
            let (re, im): (Vec<f64>, Vec<f64>) = pts.iter().map(part).unzip();
            let c = columns_dict(py, vec![("re", re), ("im", im)])?;
            let z = c
                .get_item("re")?
                .ok_or_else(|| anyhow_py("re"))?
                .add(c.get_item("im")?.ok_or_else(|| anyhow_py("im"))?.mul(&j)?)?;
            d.set_item(name, z)?;
        }
        Ok(d)
    }

    /// Tunes the loops of the model the board runs through the board (`fpi
    /// board autotune`, with its default design and sweep): measures the
    /// response, fits the stage's dynamics, designs damping, PI and
    /// feedforward, refines the feedforward on `trials` trials through the
    /// board (0: as designed), loads the tuned model (also into flash with
    /// `store`) and verifies it with a step. `model` (and `fem` for a calibrated one) is the
    /// model the board runs, as `load` took it; the tuned firmware model is
    /// written to `out`. The design's options are `fpi board autotune`'s:
    /// `damping` (`--no-damping` where false), `target_damping`,
    /// `force_noise_n` (the σ designed for instead of the one measured),
    /// `max_sensitivity`, `bandwidth_hz`. `every_axis` (a board of several
    /// axes; `fpi board autotune` without `--axis`): every axis in turn, then
    /// their coupling (`sensor_crosstalk`: the sensors' calibration, a
    /// fraction), into one file of several axes at `out` that `load` loads
    /// whole. Returns the table `fpi board autotune` prints.
    #[pyo3(signature = (model, out, fem = None, *, trials = fpi_host::board::autotune::TRIALS, store = false, rate = 20_000, u_max = 150.0, slew = 100.0, stroke_voltage = None, damping = true, target_damping = 0.5, force_noise_n = None, max_sensitivity = 1.6, bandwidth_hz = None, every_axis = false, sensor_crosstalk = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn autotune(
        &self,
        py: Python<'_>,
        model: PathBuf,
        out: PathBuf,
        fem: Option<PathBuf>,
        trials: u32,
        store: bool,
        rate: u32,
        u_max: f64,
        slew: f64,
        stroke_voltage: Option<f64>,
        damping: bool,
        target_damping: f64,
        force_noise_n: Option<f64>,
        max_sensitivity: f64,
        bandwidth_hz: Option<f64>,
        every_axis: bool,
        sensor_crosstalk: f64,
    ) -> PyResult<String> {
        use fpi_host::board::autotune;
        use fpi_host::method::tune::TuneOptions;
        self.recorder_free("autotune")?;
        let design = TuneOptions {
            damping,
            target_damping,
            force_noise_n,
            max_sensitivity,
            bandwidth_hz,
            ..TuneOptions::default()
        };
        let o = export_options(rate, u_max, slew, stroke_voltage);
        let loaded = py
            .detach(|| loadable(&model, fem.as_deref(), &o))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        // `out` must take the file before the board is measured; the model is
        // written before it runs for good (if it cannot be, the board is put
        // back to the model it ran).
        let mut inputs = vec![("model", model.as_path())];
        inputs.extend(fem.as_deref().map(|f| ("fem", f)));
        py.detach(|| fpi_host::output::check_outputs(&[("out", out.as_path())], &inputs))
            .map_err(|e| to_py(py, e, Otherwise::Input))?;
        let settings = autotune::Settings {
            trials,
            ..Default::default()
        };
        if every_axis {
            let coupling = fpi_host::board::decoupling::Settings {
                sensor_crosstalk,
                ..Default::default()
            };
            return self.autotune_every_axis(
                py,
                loaded,
                &design,
                (&settings, &coupling),
                store,
                &out,
            );
        }
        let fw = loaded
            .of_axis(self.axis)
            .ok_or_else(|| BoardError::new_err("the file has no model of the addressed axis"))?;
        fpi_host::method::tune::check_options(&fw, &design).map_err(design_error)?;
        let tuned = self.run(py, |c| {
            autotune::run_keeping(
                c,
                &fw,
                &design,
                &settings,
                store,
                &mut |m| autotune::write_model(m, &out),
                |_| {},
            )
        })?;
        Ok(autotune::table(&tuned))
    }

    /// Closes the link (a `virtual` board stops). Further calls raise
    /// `LinkError`.
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        let c = py.detach(|| self.client.lock().map(|mut g| g.take()).ok().flatten());
        py.detach(move || drop(c));
        Ok(())
    }

    /// Whether the link is closed.
    #[getter]
    fn closed(&self) -> bool {
        self.client.lock().map(|g| g.is_none()).unwrap_or(true)
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_exc))]
    fn __exit__(&self, py: Python<'_>, _exc: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }

    fn __repr__(&self) -> String {
        format!(
            "Board({:?}{})",
            self.port,
            if self.closed() { ", closed" } else { "" }
        )
    }
}

/// A design option `fpi_host::method::tune` refused, as a `ValueError` naming
/// the keyword (`--target-damping 2: …` → `target_damping 2: …`).
fn design_error(e: anyhow::Error) -> PyErr {
    let text = format!("{e:#}");
    let named = match text
        .strip_prefix("--")
        .map(|r| r.split_once(' ').unwrap_or((r, "")))
    {
        Some((flag, rest)) => format!("{} {rest}", flag.replace('-', "_")),
        None => text,
    };
    pyo3::exceptions::PyValueError::new_err(named)
}

/// One complex response of a measured frequency, as (real, imaginary).
type Part = fn(&fpi_host::method::tune::frf::FrfPoint) -> (f64, f64);

/// Opens a board as `fpi board --port` does.
fn commands_open(port: &str) -> anyhow::Result<Client> {
    fpi_host::cli::board::open(port)
}

/// `True`/`False` or `"on"`/`"off"` as `"on"`/`"off"`.
fn on_off(v: &Bound<'_, PyAny>, name: &str) -> PyResult<String> {
    if let Ok(b) = v.extract::<bool>() {
        return Ok(if b { "on" } else { "off" }.into());
    }
    v.extract::<String>().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err(format!("{name}: True or False (or \"on\"/\"off\")"))
    })
}

fn anyhow_py(what: &str) -> PyErr {
    pyo3::exceptions::PyRuntimeError::new_err(format!("internal: no column {what}"))
}

/// The exception for a long call that a signal stopped: `Interrupted` carrying
/// `done` for Ctrl-C, else the exception the signal handler raised.
fn stopped(py: Python<'_>, caught: Option<PyErr>, what: &str, done: Py<PyAny>) -> PyErr {
    match caught {
        Some(e) if e.is_instance_of::<pyo3::exceptions::PyKeyboardInterrupt>(py) => interrupted(
            py,
            format!("{what} stopped by Ctrl-C; the board is left in order (see .done)"),
            done,
        ),
        Some(e) => e,
        None => interrupted(py, format!("{what} stopped"), done),
    }
}

/// What a recorded motion returns: `tick` and the `recording`; or the
/// exception for a recording that Ctrl-C stopped (its `done` the recording),
/// a fault the board latched meanwhile, or samples the board dropped.
fn recorded<'py>(
    py: Python<'py>,
    m: motion::Motion<()>,
    caught: Option<PyErr>,
    what: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let rec = columns_dict(py, m.recording.columns())?;
    if m.stopped {
        return Err(stopped(py, caught, what, rec.into_any().unbind()));
    }
    if let Some(e) = m.fault {
        return Err(to_py(py, e, Otherwise::Link));
    }
    if m.recording.dropped > 0 {
        warn(
            py,
            &format!(
                "the board dropped {} samples of the {what}'s recording (the link could not keep up)",
                m.recording.dropped
            ),
        )?;
    }
    let d = PyDict::new(py);
    d.set_item("tick", m.start)?;
    d.set_item("recording", rec)?;
    Ok(d.into_any())
}

/// `warnings.warn(message)`.
pub fn warn(py: Python<'_>, message: &str) -> PyResult<()> {
    py.import("warnings")?.call_method1("warn", (message,))?;
    Ok(())
}
