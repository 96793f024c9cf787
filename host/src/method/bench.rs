//! How calibration scales: seconds and peak resident memory on millions of
//! samples, built by repeating the pea-rig recordings (`fpi bench` reports it).
//!
//! The peak is the process's `VmHWM` (Linux, `/proc/self/status`), reset before
//! each kind through `/proc/self/clear_refs`; elsewhere it is unknown.
//!
//! Last, how `fpi calibrate --rig ONE.csv` reads one file of as many samples
//! ([`single_file`], in this process; calibrating it too is optional).

use std::fmt;
use std::io::{BufWriter, Write};
use std::path::Path;
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
    /// The same samples as one CSV file, read as `fpi calibrate` reads it (not
    /// calibrated: see [`single_file`]).
    pub file: FileRun,
}

/// `fpi calibrate --rig ONE.csv` in this process, on one file: its reading, and
/// optionally its calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct FileRun {
    /// Rows of the file.
    pub samples: usize,
    /// Size of the file, bytes.
    pub file_bytes: u64,
    /// Seconds to read it (`calibrate::load`, as `fpi calibrate` reads).
    pub read_seconds: f64,
    /// Resident memory before reading, bytes; `None`: unknown.
    pub rss_before_bytes: Option<u64>,
    /// Peak resident memory while reading, bytes; `None`: unknown.
    pub read_peak_rss_bytes: Option<u64>,
    /// The default kind (efpi) calibrated on it, if asked: its seconds and
    /// processor time exclude the reading; its peak is the peak since before
    /// reading (that of the whole `fpi calibrate`).
    pub calibrated: Option<KindRun>,
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
        let r = &self.file;
        writeln!(
            f,
            "calibration_one_file_read: {} samples in one CSV of {:.0} MB read in {:.2} s, peak resident {} (before {})",
            r.samples,
            r.file_bytes as f64 / 1e6,
            r.read_seconds,
            mib(r.read_peak_rss_bytes),
            mib(r.rss_before_bytes),
        )?;
        if let Some(c) = &r.calibrated {
            writeln!(
                f,
                "calibration_one_file kind={}: {:.2} s after reading (processor {}), peak resident {} (data {}), RMSE {:.4} µm, {} warning(s)",
                c.kind,
                c.seconds,
                c.cpu_seconds
                    .map_or_else(|| "unknown".to_string(), |c| format!("{c:.2} s")),
                mib(c.peak_rss_bytes),
                mib(c.rss_before_bytes),
                c.rmse_um,
                c.warnings.len()
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
/// [`rig_data`]) and measures each: seconds and peak resident memory; then
/// writes the same number of samples as one file and measures reading it
/// ([`single_file`], without calibrating).
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
    let samples = data.iter().map(|d| d.u.len()).sum();
    let recordings = data.len();
    // Not to count in the single file's peak.
    drop(data);
    let dir = std::env::temp_dir().join(format!("fpi-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    // Reading only: calibrating one long recording would take about as long again
    // as everything above (tests/scaling.rs does it).
    let file = single_file(samples, &dir, false);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(Scaling {
        samples,
        recordings,
        repeats,
        build_seconds,
        threads: rayon::current_num_threads(),
        runs,
        file: file?,
    })
}

/// Writes `samples` rows of the pea-rig recordings, one after the other and
/// repeated, as one `t_s,voltage_V,force_N,displacement_um` file in `dir` (time
/// strictly increasing), then reads it as `fpi calibrate --rig FILE` does and,
/// if `calibrate`, calibrates the default kind (efpi) on it, measuring each.
/// The file is left in `dir`.
pub fn single_file(samples: usize, dir: &Path, calibrate: bool) -> Result<FileRun> {
    let path = dir.join(format!("rig-{samples}.csv"));
    {
        let rigs = data::datasets_in("pea-rig")
            .iter()
            .map(|p| data::read_rig(p))
            .collect::<Result<Vec<_>, _>>()?;
        if rigs.iter().all(|r| r.t.is_empty()) {
            bail!("no pea-rig samples");
        }
        let mut w = BufWriter::with_capacity(1 << 20, std::fs::File::create(&path)?);
        writeln!(w, "t_s,voltage_V,force_N,displacement_um")?;
        let rows = rigs
            .iter()
            .cycle()
            .flat_map(|r| (0..r.t.len()).map(move |k| (r.u[k], r.f[k], r.x[k])));
        for (k, (u, f, x)) in rows.take(samples).enumerate() {
            // 5 kHz, as the recordings.
            writeln!(w, "{:.4},{u},{f},{x}", k as f64 * 2e-4)?;
        }
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    }
    let file_bytes = std::fs::metadata(&path)?.len();
    reset_peak();
    let rss_before_bytes = status_bytes("VmRSS:");
    let t = Instant::now();
    let rig = calibrate::load(&[&path], None)?;
    let read_seconds = t.elapsed().as_secs_f64();
    let read_peak_rss_bytes = status_bytes("VmHWM:");
    let calibrated = if calibrate {
        let kind = Kind::Efpi;
        let rss_before_bytes = status_bytes("VmRSS:");
        let cpu = cpu_seconds();
        let t = Instant::now();
        let m = calibrate::calibrate(&rig, &Options::for_kind(kind))?;
        let seconds = t.elapsed().as_secs_f64();
        Some(KindRun {
            kind,
            seconds,
            cpu_seconds: cpu.zip(cpu_seconds()).map(|(a, b)| b - a),
            rss_before_bytes,
            peak_rss_bytes: status_bytes("VmHWM:"),
            rmse_um: m.calibration.rmse_um,
            warnings: m.calibration.warnings,
        })
    } else {
        None
    };
    Ok(FileRun {
        samples: rig.iter().map(|d| d.u.len()).sum(),
        file_bytes,
        read_seconds,
        rss_before_bytes,
        read_peak_rss_bytes,
        calibrated,
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
