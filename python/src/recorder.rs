//! `piezo_fpi.Recorder`: a live recording (`Board.record_start`), read while
//! the board runs other commands (`fpi_host::board::live`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::anyhow;
use fpi_host::board::live::{Counts, Live};
use fpi_host::board::recording::Recording;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::columns_dict;
use crate::board::warn;
use crate::errors::{to_py, Otherwise};

/// A recording that runs while the board takes other commands
/// (`Board.record_start`): PI's data recorder as a script uses it — arm,
/// start a motion, read meanwhile, stop. `read()` returns what came since the
/// last read, `stop()` the whole recording; both as `Board.record` gives it (a
/// dict of numpy arrays, `t_s` from the board's tick). Every sample carries its
/// tick, so a loss is never silent: `gaps`, `missing` (samples the gaps miss)
/// and `dropped` (samples the board's ring dropped) count it, and a read or a
/// stop that finds a new loss warns. While it runs, the board's commands that
/// use the recorder themselves (`record`, `step`, `frf`, `autotune`,
/// `load(match_mass=True)`, a motion's `record=True`) raise `BoardError`. Use
/// it as a context manager, or call `stop()`.
#[pyclass(module = "piezo_fpi")]
pub struct Recorder {
    live: Mutex<Option<Live>>,
    /// The board's flag that a live recording runs.
    busy: Arc<AtomicBool>,
    /// The counts at the last read or stop.
    last: Mutex<Counts>,
    /// The counts whose losses were last warned of.
    reported: Mutex<Counts>,
}

impl Recorder {
    /// A recorder over `live`, clearing `busy` when it stops.
    pub fn new(live: Live, busy: Arc<AtomicBool>) -> Self {
        Self {
            live: Mutex::new(Some(live)),
            busy,
            last: Mutex::new(Counts::default()),
            reported: Mutex::new(Counts::default()),
        }
    }

    /// Keeps the counts `c` and warns once for losses not reported yet.
    fn report(&self, py: Python<'_>, c: Counts) -> PyResult<()> {
        if let Ok(mut l) = self.last.lock() {
            *l = c;
        }
        let mut r = self
            .reported
            .lock()
            .map_err(|_| anyhow_err("the recorder failed in another thread"))?;
        if (c.gaps, c.missing, c.dropped) != (r.gaps, r.missing, r.dropped) {
            *r = c;
            warn(
                py,
                &format!("the live recording lost samples: {}", c.losses()),
            )?;
        }
        Ok(())
    }

    fn counts(&self) -> Counts {
        self.live
            .lock()
            .ok()
            .and_then(|g| g.as_ref().map(Live::counts))
            .unwrap_or_else(|| self.last.lock().map(|r| *r).unwrap_or_default())
    }
}

fn anyhow_err(m: &str) -> PyErr {
    pyo3::exceptions::PyRuntimeError::new_err(m.to_string())
}

#[pymethods]
impl Recorder {
    /// What came since the last read: a dict of numpy arrays (empty arrays
    /// where nothing came yet), the columns recorded. Raises `LinkError` if
    /// the link failed meanwhile, `BoardError` once stopped.
    fn read<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let (block, rate, signals) = py
            .detach(|| {
                let g = self
                    .live
                    .lock()
                    .map_err(|_| anyhow!("the recorder failed in another thread"))?;
                let live = g
                    .as_ref()
                    .ok_or_else(|| anyhow!("the live recording was stopped"))?;
                Ok((live.read()?, live.rate_hz, live.signals))
            })
            .map_err(|e| to_py(py, e, Otherwise::Link))?;
        self.report(py, block.counts)?;
        let rec = Recording {
            rate_hz: rate,
            signals,
            samples: block.samples,
            dropped: 0,
        };
        columns_dict(py, rec.columns())
    }

    /// Stops the recorder and returns the whole recording (what `read()` took
    /// included) as a dict of numpy arrays. Raises `BoardError` if it was
    /// stopped already.
    fn stop<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let live = self
            .live
            .lock()
            .map_err(|_| anyhow_err("the recorder failed in another thread"))?
            .take();
        let Some(live) = live else {
            return Err(crate::errors::BoardError::new_err(
                "the live recording was stopped already",
            ));
        };
        let r = py.detach(|| live.stop());
        self.busy.store(false, Ordering::Relaxed);
        let (rec, counts) = r.map_err(|e| to_py(py, e, Otherwise::Link))?;
        self.report(py, counts)?;
        columns_dict(py, rec.columns())
    }

    /// Whether it still records (not stopped, and its reader running).
    #[getter]
    fn running(&self) -> bool {
        self.live
            .lock()
            .map(|g| g.as_ref().is_some_and(Live::running))
            .unwrap_or(false)
    }

    /// The tick the board took the recording's start on (its first sample is
    /// the next recorded one).
    #[getter]
    fn start_tick(&self) -> Option<u32> {
        self.live
            .lock()
            .ok()
            .and_then(|g| g.as_ref().map(|l| l.start))
    }

    /// Samples received so far.
    #[getter]
    fn samples(&self) -> u64 {
        self.counts().samples
    }

    /// Places where a sample did not follow the one before by the decimation.
    #[getter]
    fn gaps(&self) -> u32 {
        self.counts().gaps
    }

    /// Samples the gaps miss.
    #[getter]
    fn missing(&self) -> u64 {
        self.counts().missing
    }

    /// Samples the board's ring dropped (the link could not keep up, or a
    /// command held it too long).
    #[getter]
    fn dropped(&self) -> u32 {
        self.counts().dropped
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// Stops it if it still runs (the recording is dropped: call `stop()`
    /// inside the block to keep it).
    #[pyo3(signature = (*_exc))]
    fn __exit__(&self, py: Python<'_>, _exc: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        let live = self.live.lock().ok().and_then(|mut g| g.take());
        if let Some(live) = live {
            let r = py.detach(|| live.stop());
            self.busy.store(false, Ordering::Relaxed);
            r.map_err(|e| to_py(py, e, Otherwise::Link))?;
        }
        Ok(false)
    }

    fn __repr__(&self) -> String {
        let c = self.counts();
        format!(
            "Recorder({}, {} samples, {} gaps, {} dropped)",
            if self.running() { "running" } else { "stopped" },
            c.samples,
            c.gaps,
            c.dropped
        )
    }
}

/// A recorder dropped while running stops the board's recorder (its
/// recording is lost) and frees the board for the commands that record.
impl Drop for Recorder {
    fn drop(&mut self) {
        if let Ok(mut g) = self.live.lock() {
            drop(g.take());
        }
        self.busy.store(false, Ordering::Relaxed);
    }
}
