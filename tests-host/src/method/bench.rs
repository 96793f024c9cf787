//! How calibration scales: seconds and peak resident memory on millions of
//! samples, built by repeating the pea-rig recordings (`fpi bench` reports it).
//!
//! The peak is the process's `VmHWM` (Linux, `/proc/self/status`), reset before
//! each kind through `/proc/self/clear_refs`; elsewhere it is unknown.

use std::fmt;
use std::time::Instant;

use anyhow::{bail, Result};

use crate::data;
use crate::method::calibrate::{self, CalibData, Options};
use crate::method::model::Kind;

/// The samples of the scaling benchmark (the 5 million).
pub const SAMPLES: usize = 5_000_000;

/// One kind calibrated on the benchmark's data.
#[derive(Debug, Clone, PartialEq)]
pub struct KindRun {
    /// The kind.
    pub kind: Kind,
    /// Wall-clock time of `calibrate::calibrate`, s.
    pub seconds: f64,
    /// Processor time the process spent in it (all threads), s; `None`: unknown.
    pub cpu_seconds: Option<f64>,
    /// Resident memory before the calibration (the data), bytes; `None`: unknown.
    pub rss_before_bytes: Option<u64>,
    /// Peak resident memory during the calibration, bytes; `None`: unknown.
    pub peak_rss_bytes: Option<u64>,
    /// The calibrated model's output RMSE over all samples, µm.
    pub rmse_um: f64,
    /// The calibration's warnings.
    pub warnings: Vec<String>,
}

/// The benchmark's figures.
#[derive(Debug, Clone, PartialEq)]
pub struct Scaling {
    /// Samples calibrated on.
    pub samples: usize,
    /// Recordings they form.
    pub recordings: usize,
    /// Times each pea-rig recording was repeated.
    pub repeats: usize,
    /// Seconds to read the recordings and build the data.
    pub build_seconds: f64,
    /// Rayon threads.
    pub threads: usize,
    /// Per kind: the default kind (efpi), then fpi.
    pub runs: Vec<KindRun>,
}

/// Mebibytes, or "unknown".
fn mib(bytes: Option<u64>) -> String {
    bytes.map_or_else(
        || "unknown".to_string(),
        |b| format!("{:.0} MiB", b as f64 / 1048576.0),
    )
}

impl fmt::Display for Scaling {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "calibration scaling: {} samples ({} pea-rig recordings, each repeated {}×), built in {:.2} s, {} threads",
            self.samples, self.recordings, self.repeats, self.build_seconds, self.threads
        )?;
        for r in &self.runs {
            writeln!(
                f,
                "calibration_scaling kind={}: {:.2} s (processor {}), peak resident {} (data {}), RMSE {:.4} µm, {} warning(s)",
                r.kind,
                r.seconds,
                r.cpu_seconds
                    .map_or_else(|| "unknown".to_string(), |c| format!("{c:.2} s")),
                mib(r.peak_rss_bytes),
                mib(r.rss_before_bytes),
                r.rmse_um,
                r.warnings.len()
            )?;
        }
        Ok(())
    }
}

/// About `samples` samples: each pea-rig recording concatenated with itself until
/// the set holds at least `samples` (21 recordings, each repeated alike). Returns
/// the recordings and the repeat count.
pub fn rig_data(samples: usize) -> Result<(Vec<CalibData>, usize)> {
    let rig = calibrate::load(&data::datasets_in("pea-rig"), None)?;
    let base: usize = rig.iter().map(|d| d.u.len()).sum();
    if base == 0 {
        bail!("no pea-rig samples");
    }
    let repeats = samples.div_ceil(base).max(1);
    Ok((rig.iter().map(|d| repeat(d, repeats)).collect(), repeats))
}

/// A recording concatenated with itself `times` times (each copy starts at rest,
/// as the recording does).
fn repeat(d: &CalibData, times: usize) -> CalibData {
    let cat = |v: &[f64]| {
        let mut out = Vec::with_capacity(v.len() * times);
        (0..times).for_each(|_| out.extend_from_slice(v));
        out
    };
    let n = d.u.len() * times;
    CalibData {
        name: format!("{}×{times}", d.name),
        u: cat(&d.u),
        f: cat(&d.f),
        x: cat(&d.x),
        fit: (0, n),
        ..d.clone()
    }
}

/// Calibrates the default kind (efpi) and fpi on about `samples` samples (see
/// [`rig_data`]) and measures each: seconds and peak resident memory.
pub fn scaling(samples: usize) -> Result<Scaling> {
    let t0 = Instant::now();
    let (data, repeats) = rig_data(samples)?;
    let build_seconds = t0.elapsed().as_secs_f64();
    let mut runs = Vec::new();
    for kind in [Kind::Efpi, Kind::Fpi] {
        reset_peak();
        let rss_before_bytes = status_bytes("VmRSS:");
        let cpu = cpu_seconds();
        let t = Instant::now();
        let m = calibrate::calibrate(&data, &Options::for_kind(kind))?;
        let seconds = t.elapsed().as_secs_f64();
        let cpu_seconds = cpu.zip(cpu_seconds()).map(|(a, b)| b - a);
        runs.push(KindRun {
            kind,
            seconds,
            cpu_seconds,
            rss_before_bytes,
            peak_rss_bytes: status_bytes("VmHWM:"),
            rmse_um: m.calibration.rmse_um,
            warnings: m.calibration.warnings,
        });
    }
    Ok(Scaling {
        samples: data.iter().map(|d| d.u.len()).sum(),
        recordings: data.len(),
        repeats,
        build_seconds,
        threads: rayon::current_num_threads(),
        runs,
    })
}

/// Processor time of the process so far (user and system, all threads), s;
/// `None` where unknown.
fn cpu_seconds() -> Option<f64> {
    #[cfg(unix)]
    {
        // SAFETY: `rusage` is plain data, all zeros is a valid value, and
        // `getrusage` only writes the struct we own.
        let mut r: libc::rusage = unsafe { std::mem::zeroed() };
        if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut r) } != 0 {
            return None;
        }
        let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
        Some(secs(r.ru_utime) + secs(r.ru_stime))
    }
    #[cfg(not(unix))]
    {
        None
    }
}

/// Resets the process's peak resident memory to its current one (Linux ≥ 4.0;
/// elsewhere, or if refused, the peak stays the process's).
fn reset_peak() {
    #[cfg(target_os = "linux")]
    {
        let _ = std::fs::write("/proc/self/clear_refs", "5");
    }
}

/// A `kB` line of `/proc/self/status` (`VmHWM:`, `VmRSS:`), bytes; `None` where
/// there is no such file.
fn status_bytes(key: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = line[key.len()..]
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}
