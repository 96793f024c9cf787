//! A recording read from a board's data recorder: its samples, in the datasets'
//! units and column names, so `fpi calibrate`, `fpi compare` and the plots take it
//! as they take a recorded dataset.
//!
//! CSV columns: `t_s,voltage_V,force_N,x_ref_um,x_est_um,status` and, where the
//! board knows the stage's true position (the emulated board), `x_fhps_um`, and the
//! position sensor's reading `x_sensor_um`. Only the signals recorded are written
//! (`t_s` always).

use std::io::Write;
use std::path::Path;

use anyhow::Result;
use fpi_firmware::recorder::{signal, status, Sample};
use piezo_sim::stats::ErrorStats;

use super::client::real;

/// Recorded samples with what they mean.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The board's control rate, Hz (tick → seconds).
    pub rate_hz: f64,
    /// The signals recorded (`fpi_firmware::recorder::signal` bits).
    pub signals: u8,
    /// The samples, in tick order.
    pub samples: Vec<Sample>,
    /// Samples the board dropped because its ring was full.
    pub dropped: u32,
}

impl Recording {
    /// Samples with `from <= tick < to`.
    pub fn between(&self, from: u32, to: u32) -> impl Iterator<Item = &Sample> {
        self.samples
            .iter()
            .filter(move |s| s.tick >= from && s.tick < to)
    }

    /// Stage position (true, or else estimated) minus reference over the samples
    /// with `from <= tick < to` that are tracking (no fault, not approaching), µm.
    pub fn tracking(&self, from: u32, to: u32) -> ErrorStats<f64> {
        let mut e = ErrorStats::new();
        for s in self.between(from, to) {
            if s.status & (status::FAULT | status::APPROACHING) == 0 {
                e.add(real(self.position(s)) - real(s.x_ref));
            }
        }
        e
    }

    /// The estimate minus the true position over the same samples, µm.
    pub fn estimate(&self, from: u32, to: u32) -> ErrorStats<f64> {
        let mut e = ErrorStats::new();
        for s in self.between(from, to) {
            if s.status & (status::FAULT | status::APPROACHING) == 0 {
                e.add(real(s.x_est) - real(s.x_true));
            }
        }
        e
    }

    /// The true position if recorded, else the estimate (raw bits).
    fn position(&self, s: &Sample) -> i32 {
        if self.signals & signal::X_TRUE != 0 {
            s.x_true
        } else {
            s.x_est
        }
    }

    /// Writes the CSV (see the module docs) atomically
    /// ([`crate::output::write_atomic_with`]: a failure leaves no partial file and
    /// names `path`).
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        crate::output::write_atomic_with(path, |w| self.write_rows(w))
    }

    /// The CSV's header and rows into `w`.
    fn write_rows(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let cols = [
            (signal::VOLTAGE, "voltage_V"),
            (signal::FORCE, "force_N"),
            (signal::X_REF, "x_ref_um"),
            (signal::X_EST, "x_est_um"),
            (signal::STATUS, "status"),
            (signal::X_TRUE, "x_fhps_um"),
            (signal::X_SENSOR, "x_sensor_um"),
        ];
        let mut head = String::from("t_s");
        for (bit, name) in cols {
            if self.signals & bit != 0 {
                head.push(',');
                head.push_str(name);
            }
        }
        writeln!(w, "{head}")?;
        for s in &self.samples {
            let mut line = format!("{:.6}", s.tick as f64 / self.rate_hz);
            for (bit, _) in cols {
                if self.signals & bit == 0 {
                    continue;
                }
                let v = match bit {
                    signal::VOLTAGE => format!("{:.5}", real(s.voltage)),
                    signal::FORCE => format!("{:.4}", real(s.force)),
                    signal::X_REF => format!("{:.5}", real(s.x_ref)),
                    signal::X_EST => format!("{:.5}", real(s.x_est)),
                    signal::STATUS => s.status.to_string(),
                    signal::X_TRUE => format!("{:.5}", real(s.x_true)),
                    _ => format!("{:.5}", real(s.x_sensor)),
                };
                line.push(',');
                line.push_str(&v);
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    }
}
