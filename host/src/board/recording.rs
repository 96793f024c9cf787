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
use fpi_firmware::control::recorder::{signal, status, Sample};
use piezo_sim::stats::ErrorStats;

use super::client::real;

/// Recorded samples with what they mean.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The board's control rate, Hz (tick → seconds).
    pub rate_hz: f64,
    /// The signals recorded (`fpi_firmware::control::recorder::signal` bits).
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

    /// The columns recorded, in the CSV's order after `t_s`: each signal bit with
    /// its column name.
    fn recorded(&self) -> impl Iterator<Item = (u8, &'static str)> {
        columns_of(self.signals)
    }

    /// The recording by column, as the CSV has them (`t_s` first, in s; then the
    /// signals recorded, in µm, V, N, and `status` as its bits), each value
    /// exactly as the board reported it (the CSV rounds them).
    pub fn columns(&self) -> Vec<(&'static str, Vec<f64>)> {
        let mut out = vec![(
            "t_s",
            self.samples
                .iter()
                .map(|s| s.tick as f64 / self.rate_hz)
                .collect(),
        )];
        for (bit, name) in self.recorded() {
            out.push((name, self.samples.iter().map(|s| value(bit, s)).collect()));
        }
        out
    }

    /// The CSV's header and rows into `w`.
    fn write_rows(&self, w: &mut dyn Write) -> std::io::Result<()> {
        self.write_header(w)?;
        self.write_samples(w, &self.samples)
    }

    /// The CSV's header (its signals', whatever its samples) into `w`.
    pub fn write_header(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let mut head = String::from("t_s");
        for (_, name) in self.recorded() {
            head.push(',');
            head.push_str(name);
        }
        writeln!(w, "{head}")
    }

    /// The CSV's rows of `samples` (recorded with its signals) into `w`: a
    /// recording written as it comes ([`Self::write_header`] first).
    pub fn write_samples(&self, w: &mut dyn Write, samples: &[Sample]) -> std::io::Result<()> {
        for s in samples {
            let mut line = format!("{:.6}", s.tick as f64 / self.rate_hz);
            for (bit, _) in self.recorded() {
                line.push(',');
                line.push_str(&formatted(bit, s));
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    }
}

/// Signal `bit` of `s` as the CSV writes it.
fn formatted(bit: u8, s: &Sample) -> String {
    let v = value(bit, s);
    match bit {
        signal::FORCE => format!("{v:.4}"),
        signal::STATUS => s.status.to_string(),
        signal::TRIGGER => s.lines.to_string(),
        _ => format!("{v:.5}"),
    }
}

/// A recording of every axis of a board of several: each axis's recording,
/// over the same ticks. Its CSV has `t_s`, then each axis's columns named
/// `<signal>@<axis>` (`x_fhps_um@y`).
#[derive(Debug, Clone, Default)]
pub struct AxesRecording {
    /// Each axis's recording, in axis order.
    pub axes: Vec<Recording>,
}

impl AxesRecording {
    /// The recording of `n` axes from `rec`, whose samples interleave them
    /// (each kept tick: one sample per axis, in axis order, as the board
    /// records every axis). A tick that is not whole is dropped and counted.
    pub fn split(rec: &Recording, n: usize) -> Self {
        let mut axes = vec![
            Recording {
                rate_hz: rec.rate_hz,
                signals: rec.signals,
                samples: Vec::with_capacity(rec.samples.len() / n.max(1)),
                dropped: rec.dropped / n.max(1) as u32,
            };
            n
        ];
        let mut rest = rec.samples.as_slice();
        while !rest.is_empty() {
            let same = rest.iter().take_while(|s| s.tick == rest[0].tick).count();
            if same == n {
                for (a, s) in axes.iter_mut().zip(&rest[..n]) {
                    a.samples.push(*s);
                }
            } else {
                for a in &mut axes {
                    a.dropped += 1;
                }
            }
            rest = &rest[same..];
        }
        Self { axes }
    }

    /// The recording by column, as the CSV has them: `t_s`, then each
    /// axis's signals named `<signal>@<axis>`.
    pub fn columns(&self) -> Vec<(String, Vec<f64>)> {
        let mut out = Vec::new();
        for (i, a) in self.axes.iter().enumerate() {
            let name = super::client::axis_name(i as u8);
            for (column, values) in a.columns() {
                if column == "t_s" {
                    if i == 0 {
                        out.push((column.to_string(), values));
                    }
                } else {
                    out.push((format!("{column}@{name}"), values));
                }
            }
        }
        out
    }

    /// Writes the CSV atomically (a failure leaves no partial file and
    /// names `path`).
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        crate::output::write_atomic_with(path, |w| {
            let columns: Vec<String> = self.columns().into_iter().map(|(n, _)| n).collect();
            writeln!(w, "{}", columns.join(","))?;
            let Some(first) = self.axes.first() else {
                return Ok(());
            };
            for (k, s) in first.samples.iter().enumerate() {
                let mut line = format!("{:.6}", f64::from(s.tick) / first.rate_hz);
                for a in &self.axes {
                    let Some(s) = a.samples.get(k) else { continue };
                    for (bit, _) in a.recorded() {
                        line.push(',');
                        line.push_str(&formatted(bit, s));
                    }
                }
                writeln!(w, "{line}")?;
            }
            Ok(())
        })
    }
}

/// The signal bits of the CSV columns named (`voltage_V`, `x_fhps_um`, …; `t_s`
/// is always there and adds none), or the first name that is no column.
pub fn signals_named<'a>(names: impl IntoIterator<Item = &'a str>) -> Result<u8, &'a str> {
    let mut bits = 0;
    for name in names {
        match COLUMNS.iter().find(|(_, n)| *n == name) {
            Some((bit, _)) => bits |= bit,
            None if name == "t_s" => {}
            None => return Err(name),
        }
    }
    Ok(bits)
}

/// The CSV columns a recording may hold after `t_s`, in order.
pub fn column_names() -> impl Iterator<Item = &'static str> {
    COLUMNS.into_iter().map(|(_, n)| n)
}

/// The columns of a recording of `signals`, in the CSV's order after `t_s`:
/// each signal bit with its column name.
pub fn columns_of(signals: u8) -> impl Iterator<Item = (u8, &'static str)> {
    COLUMNS
        .into_iter()
        .filter(move |(bit, _)| signals & bit != 0)
}

/// The signals a recording may hold, by their bit, with their CSV column.
const COLUMNS: [(u8, &str); 8] = [
    (signal::VOLTAGE, "voltage_V"),
    (signal::FORCE, "force_N"),
    (signal::X_REF, "x_ref_um"),
    (signal::X_EST, "x_est_um"),
    (signal::STATUS, "status"),
    (signal::X_TRUE, "x_fhps_um"),
    (signal::X_SENSOR, "x_sensor_um"),
    (signal::TRIGGER, "trigger"),
];

/// The value of signal `bit` in a sample, in µm, V or N (`status`: its bits).
pub fn value(bit: u8, s: &Sample) -> f64 {
    match bit {
        signal::VOLTAGE => real(s.voltage),
        signal::FORCE => real(s.force),
        signal::X_REF => real(s.x_ref),
        signal::X_EST => real(s.x_est),
        signal::STATUS => f64::from(s.status),
        signal::X_TRUE => real(s.x_true),
        signal::TRIGGER => f64::from(s.lines),
        _ => real(s.x_sensor),
    }
}
