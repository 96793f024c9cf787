//! `piezo_fpi.Emulator`: the emulated board (`fpi board emulate`): QEMU's
//! `netduinoplus2` running the firmware, its link on a TCP port
//! (`fpi_host::board::emulator`).

use std::sync::Mutex;

use fpi_host::board::emulator::Emulator as Qemu;
use pyo3::prelude::*;

use crate::errors::{to_py, Otherwise};

/// Whether `qemu-system-arm` is there to run the emulated board
/// (`$QEMU_SYSTEM_ARM` or on `PATH`).
#[pyfunction]
pub fn qemu_available() -> bool {
    fpi_host::board::qemu().is_ok()
}

/// The emulated board (`fpi board emulate`): runs the firmware for the
/// emulated STM32F405 on QEMU — the ELF `firmware` (as `fpi board emulate
/// --firmware`), else one built with cargo in the source tree this package was
/// built from (an installed package without that tree needs `firmware`) —
/// its link on `listen` (`HOST:PORT`; a free loopback port if None), paced as `link` (`"usb"` or `"uart"`), converting
/// with the analog front end `frontend` (`"internal"`: the STM32's 12-bit
/// converters; `"precision"`: AD7606 and AD5791, as `--frontend`). `port` is
/// what `Board` opens. Use it as a context manager, or call `close()` (which
/// stops QEMU).
#[pyclass(module = "piezo_fpi")]
pub struct Emulator {
    qemu: Mutex<Option<Qemu>>,
    port: String,
}

#[pymethods]
impl Emulator {
    #[new]
    #[pyo3(signature = (listen = None, link = "usb", frontend = "internal", firmware = None, axes = 1))]
    fn new(
        py: Python<'_>,
        listen: Option<String>,
        link: &str,
        frontend: &str,
        firmware: Option<std::path::PathBuf>,
        axes: u8,
    ) -> PyResult<Self> {
        let Some(link) = fpi_host::board::client::link_kind(link) else {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "link={link:?}: \"usb\" or \"uart\""
            )));
        };
        let Some(front) = fpi_protocol::FrontEndKind::from_name(frontend) else {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "frontend={frontend:?}: \"internal\" or \"precision\""
            )));
        };
        let q = py
            .detach(|| Qemu::start_board(firmware.as_deref(), axes, listen.as_deref(), link, front))
            .map_err(|e| to_py(py, e, Otherwise::Link))?;
        let port = q.port().to_string();
        Ok(Self {
            qemu: Mutex::new(Some(q)),
            port,
        })
    }

    /// The port to open: `tcp:HOST:PORT`.
    #[getter]
    fn port(&self) -> String {
        self.port.clone()
    }

    /// What the firmware and QEMU printed so far.
    fn output(&self) -> String {
        self.qemu
            .lock()
            .ok()
            .and_then(|g| g.as_ref().map(Qemu::output))
            .unwrap_or_default()
    }

    /// Stops QEMU.
    fn close(&self, py: Python<'_>) {
        let q = self.qemu.lock().ok().and_then(|mut g| g.take());
        py.detach(move || drop(q));
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_exc))]
    fn __exit__(&self, py: Python<'_>, _exc: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        self.close(py);
        false
    }

    fn __repr__(&self) -> String {
        format!("Emulator(port={:?})", self.port)
    }
}
