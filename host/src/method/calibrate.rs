//! Part I of the method: identifying a model from Voltage–Force–Displacement
//! recordings (Actuators 2025, 14(8):411, Table 1, Step 1): the recordings read
//! ([`load`]) and checked ([`crate::method::checks`]), the model fitted as its
//! kind does it ([`ModelKind::calibrate`]; the kinds built on play operators on
//! the least squares of [`crate::method::fit`]), and a model scored on recordings,
//! in its fitted rows ([`score`]) and beyond them ([`held_out`]).
//!
//! [`ModelKind::calibrate`]: crate::method::model::ModelKind::calibrate

use std::path::Path;

use anyhow::{bail, Context, Result};
use piezo_sim::stats::ErrorStats;
use rayon::prelude::*;

use crate::data;
use crate::method::checks;
use crate::method::kinds;
use crate::method::model::{FileFit, HostModel, Kind};
use crate::method::series::file_fit;

pub use crate::method::model::Options;
pub use crate::method::series::CalibData;

/// Reads calibration recordings: `t_s,voltage_V,force_N,displacement_um` CSV (gz
/// allowed), or the micromanipulator's `.dat` (column 1 volts, column 5 µm, 200 Hz,
/// no force). `rows` (1-based, inclusive) restricts fitting to a window of a single
/// recording; the operators still see the whole history from the first row, and
/// the extension is zeroed at the window's first row.
pub fn load(paths: &[impl AsRef<Path>], rows: Option<(usize, usize)>) -> Result<Vec<CalibData>> {
    load_each(paths, rows, |p, name| {
        if name.ends_with(".dat") {
            let m = data::read_micromanipulator(p)?;
            prepare(name, 1.0 / 200.0, &m.u, None, &m.sensor, rows)
        } else {
            let r = data::read_rig(p)?;
            from_columns(name, &r.t, &r.u, Some(&r.f), &r.x, rows)
        }
        .with_context(|| p.display().to_string())
    })
}

/// Reads one stack's columns of recordings of a stage of several axes
/// (`fpi axes record`: `t_s`, `voltage_V@y`, `force_N@y`, `x_pea_um@y` for
/// `axis` 1): each stack calibrated in its stage, under the preload the other
/// stacks put on it. `rows` as in [`load`]; each recording is named
/// `file@axis` in reports.
pub fn load_stack(
    paths: &[impl AsRef<Path>],
    axis: usize,
    rows: Option<(usize, usize)>,
) -> Result<Vec<CalibData>> {
    use crate::data::columns::read_named_columns;
    use crate::method::axes::grid::column;
    let names = [
        "t_s".to_string(),
        column("voltage_V", axis),
        column("force_N", axis),
        column("x_pea_um", axis),
    ];
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    load_each(paths, rows, |p, name| {
        let c = read_named_columns(p, &names)?;
        data::strictly_increasing(p, "t_s", &c.values[0])?;
        let name = format!("{name}@{}", piezo_sim::axes::AXIS_NAMES[axis]);
        let v = &c.values;
        from_columns(&name, &v[0], &v[1], Some(&v[2]), &v[3], rows)
            .with_context(|| p.display().to_string())
    })
}

/// What [`load`] and [`load_stack`] share: `rows` for one recording only,
/// each file read by `read` (its path and its name without `.gz`; its errors
/// name the file), and at least one recording.
fn load_each<P: AsRef<Path>>(
    paths: &[P],
    rows: Option<(usize, usize)>,
    read: impl Fn(&Path, &str) -> Result<CalibData>,
) -> Result<Vec<CalibData>> {
    if rows.is_some() && paths.len() != 1 {
        bail!(
            "--rows selects a window of one recording; {} were given",
            paths.len()
        );
    }
    let mut out = Vec::new();
    for p in paths {
        let p = p.as_ref();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().trim_end_matches(".gz").to_string())
            .unwrap_or_default();
        out.push(read(p, &name)?);
    }
    if out.is_empty() {
        bail!("no calibration recordings given");
    }
    Ok(out)
}

/// One recording for calibration from its columns (the CSV's `t_s`, s;
/// `voltage_V`, V; `force_N`, N, `None` for a recording without force; and the
/// extension, µm, zeroed here at the first fitted row), named `name` in reports;
/// `rows` as in [`load`]. The checks of [`load`]: at least two samples, columns
/// of one length, `rows` within the recording, values within the fixed-point
/// range. The sample period is the median time step.
pub fn from_columns(
    name: &str,
    t: &[f64],
    u: &[f64],
    f: Option<&[f64]>,
    x: &[f64],
    rows: Option<(usize, usize)>,
) -> Result<CalibData> {
    let n = u.len();
    if t.len() != n || x.len() != n || f.is_some_and(|f| f.len() != n) {
        bail!(
            "columns of different lengths (t_s {}, voltage_V {n}, force_N {}, \
             displacement {})",
            t.len(),
            f.map_or("none".into(), |f| f.len().to_string()),
            x.len()
        );
    }
    let dt = median_step(t).with_context(|| "needs at least two samples".to_string())?;
    prepare(name, dt, u, f, x, rows)
}

/// [`from_columns`] with the sample period `dt` (s) given.
fn prepare(
    name: &str,
    dt: f64,
    u: &[f64],
    f: Option<&[f64]>,
    x: &[f64],
    rows: Option<(usize, usize)>,
) -> Result<CalibData> {
    let n = u.len();
    let fit = match rows {
        Some((a, b)) => {
            if a < 1 || b < a || b > n {
                bail!("--rows {a}-{b} is outside the recording's {n} rows");
            }
            (a - 1, b)
        }
        None => (0, n),
    };
    let has_force = f.is_some();
    let f = f.map_or_else(|| vec![0.0; n], <[f64]>::to_vec);
    let mut d = CalibData {
        name: name.to_string(),
        dt,
        u: u.to_vec(),
        f0: f[fit.0],
        f,
        x: x.to_vec(),
        fit,
        has_force,
    };
    // Values beyond the fixed-point range, as the recording has them.
    checks::ranges(&d)?;
    // Zero the extension at the first fitted sample (the recordings are zeroed at t = 0).
    let x0 = d.x[fit.0];
    d.x.iter_mut().for_each(|v| *v -= x0);
    Ok(d)
}

/// The options of a calibration as `fpi calibrate` settles them: `kind`, or the
/// default for the recordings ([`kinds::default_for`], with a note when it
/// falls back), `operators` and `compliance` if given (compliance only for the
/// kinds that take one), `rows` long enough for the operators
/// ([`min_fit_rows`]), and an offset for recordings without force (no force
/// channel, or a force column of zeros). The options and the note.
pub fn settle(
    data: &[CalibData],
    kind: Option<Kind>,
    operators: Option<usize>,
    compliance: Option<f64>,
    rows: Option<(usize, usize)>,
) -> Result<(Options, Option<String>)> {
    // A force column of zeros is a recording without force written in the rig's
    // columns (e.g. the micromanipulator's cycle cut to a CSV): it is fitted as
    // the recording itself would be, with an offset.
    let has_force = data
        .iter()
        .all(|d| d.has_force && d.f.iter().any(|&f| f != 0.0));
    let (kind, note) = match kind {
        Some(k) => (k, None),
        None => kinds::default_for(data),
    };
    let mut opt = Options::for_kind(kind);
    if let Some(n) = operators {
        opt.operators = n;
    }
    if let Some(c) = compliance {
        if !kind.takes_compliance() {
            let takers: Vec<&str> = kinds::ALL
                .iter()
                .filter(|k| k.takes_compliance())
                .map(|k| k.name())
                .collect();
            bail!("--compliance applies to {} models only", takers.join(", "));
        }
        opt.compliance = c;
    }
    if let Some((a, b)) = rows {
        let (n, need) = (
            b.saturating_sub(a).saturating_add(1),
            min_fit_rows(opt.operators),
        );
        if n < need {
            bail!(
                "--rows {a}-{b}: {n} rows; a {kind} fit of {} operators needs at least {need}",
                opt.operators
            );
        }
    }
    if !has_force {
        opt.offset = true;
    }
    Ok((opt, note))
}

/// Fewest rows `--rows` may select: a fit of even one operator needs a handful of
/// samples of motion (and [`min_fit_rows`] asks more of larger models).
pub const MIN_FIT_ROWS: usize = 20;

/// Fewest rows a fit of `operators` play operators takes: [`MIN_FIT_ROWS`], and
/// at least two per operator.
pub fn min_fit_rows(operators: usize) -> usize {
    MIN_FIT_ROWS.max(2 * operators)
}

fn median_step(t: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// Calibrates a model on recordings: checks them for its kind
/// ([`checks::check`]), fits it as its kind does, and refuses a fit that fails
/// its own plausibility ([`plausible`]).
pub fn calibrate(data: &[CalibData], opt: &Options) -> Result<HostModel> {
    let warnings = checks::check(data, opt.kind)?;
    if opt.operators < 1 || opt.operators > 32 {
        bail!("--operators {}: must be 1..=32", opt.operators);
    }
    let m = opt.kind.calibrate(data, opt, warnings)?;
    if let Err(e) = m.validate() {
        bail!(
            "the recordings give no valid {} model: {}; nothing is written (the fitted \
             model fails its check: {e:#})",
            m.kind,
            why_no_model(&m, data)
        );
    }
    plausible(&m, data)?;
    Ok(m)
}

/// Why `data` gave the model `m` that fails its check, in terms of the
/// recordings: a voltage that does not move, a displacement that does not move
/// or does not rise with the voltage, or one that does not rise with it at the
/// bottom of the drive (which leaves the model no slope at rest, `w0`).
fn why_no_model(m: &HostModel, data: &[CalibData]) -> String {
    use crate::data::Num;
    let round = |v: f64| Num((v * 1000.0).round() / 1000.0);
    for d in data {
        let (u, x) = (&d.u[d.fit.0..d.fit.1], &d.x[d.fit.0..d.fit.1]);
        let span = |v: &[f64]| {
            let (lo, hi) = v
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            (lo, hi - lo)
        };
        let ((u_lo, u_span), (_, x_span)) = (span(u), span(x));
        let name = &d.name;
        if u_span <= 1e-9 {
            return format!(
                "the voltage of {name} does not change over its fitted rows ({} V throughout)",
                round(u_lo)
            );
        }
        if x_span <= 1e-9 {
            return format!(
                "the displacement of {name} does not change over its fitted rows while the \
                 voltage spans {} V",
                round(u_span)
            );
        }
        let all = slope(u, x, |_| true);
        if all.is_nan() || all <= 0.0 {
            return format!(
                "the displacement of {name} does not rise with the voltage over its fitted \
                 rows (a straight line through them goes {} µm/V): a sensor that reads lower \
                 as the stage extends needs its sign flipped",
                round(all)
            );
        }
        // The bottom tenth of the drive, where the voltage rises.
        let top = u_lo + 0.1 * u_span;
        let rising = |k: usize| k > 0 && u[k] > u[k - 1] && u[k] <= top;
        let bottom = slope(u, x, rising);
        if m.pi.w0_um_per_v <= 0.0 && bottom.is_finite() && bottom <= 0.1 * all {
            return format!(
                "at the bottom of the drive ({}–{} V) the displacement of {name} rises by {} \
                 µm/V where the voltage rises, against {} µm/V over the whole drive: the \
                 model gets no slope at rest (w0) and so no inverse; a recording that moves \
                 from its lowest voltage on can give one",
                round(u_lo),
                round(top),
                round(bottom),
                round(all)
            );
        }
    }
    if m.pi.w0_um_per_v <= 0.0 {
        return format!(
            "the fit gives the displacement's immediate rise with the voltage to other terms \
             than the slope at rest (w0 = {}), so the model has no inverse; more rows or fewer \
             operators (--operators) can give one",
            Num(m.pi.w0_um_per_v)
        );
    }
    format!(
        "the recordings ({}) give no {} model within its limits",
        data.iter()
            .map(|d| d.name.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        m.kind
    )
}

/// The least-squares slope of `x` on `u` over the samples `k` that `take`.
fn slope(u: &[f64], x: &[f64], take: impl Fn(usize) -> bool) -> f64 {
    let ks: Vec<usize> = (0..u.len()).filter(|&k| take(k)).collect();
    let n = ks.len() as f64;
    let (mu, mx) = ks
        .iter()
        .fold((0.0, 0.0), |(a, b), &k| (a + u[k] / n, b + x[k] / n));
    let (sux, suu) = ks.iter().fold((0.0, 0.0), |(a, b), &k| {
        (a + (u[k] - mu) * (x[k] - mx), b + (u[k] - mu) * (u[k] - mu))
    });
    sux / suu
}

/// The largest share of the recordings' motion a fit's RMSE may reach: a fit
/// that explains the motion leaves a few percent of it (the rig: 0.1–2 %).
pub const PLAUSIBLE_RMSE_SHARE: f64 = 0.5;

/// Refuses a fit whose RMSE reaches [`PLAUSIBLE_RMSE_SHARE`] of the motion the
/// recordings span in their fitted rows: it explains none of it (e.g. a stack
/// compliance far from any stack's), and a prediction from it would be as wrong.
pub fn plausible(m: &HostModel, data: &[CalibData]) -> Result<()> {
    let span = data
        .iter()
        .map(|d| {
            let x = &d.x[d.fit.0..d.fit.1];
            let (lo, hi) = x
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            hi - lo
        })
        .fold(0.0, f64::max);
    let rmse = m.calibration.rmse_um;
    if span > 0.0 && (rmse.is_nan() || rmse >= PLAUSIBLE_RMSE_SHARE * span) {
        let share = rmse / span;
        let share = if share >= 1.0 {
            format!("{} times", crate::data::Num((share * 10.0).round() / 10.0))
        } else {
            format!("{:.0} % of", 100.0 * share)
        };
        bail!(
            "the fitted {} model is implausible: its RMSE {} µm is {share} the {} µm the \
             recordings span (a fit that explains the motion leaves a few percent); nothing is \
             written{}",
            m.kind,
            crate::data::Num(rmse),
            crate::data::Num(span),
            if m.kind.takes_compliance() {
                format!(
                    " (its stack compliance is {} µm/N; stacks: 0.005–0.1 µm/N)",
                    crate::data::Num(m.coupling.compliance_um_per_n)
                )
            } else {
                String::new()
            }
        );
    }
    Ok(())
}

/// The model's stack extension over a recording, driven by its voltage with its
/// measured force, µm.
pub fn simulate(model: &HostModel, d: &CalibData) -> Vec<f64> {
    model.kind.simulate(model, d)
}

/// Scores a model on recordings by simulating it with the measured force
/// (output error), per file, over the fitted rows.
pub fn score(model: &HostModel, data: &[CalibData]) -> Vec<FileFit> {
    data.par_iter()
        .map(|d| {
            let window = d.fit.0..d.fit.1;
            let e = ErrorStats::of_difference(&simulate(model, d)[window.clone()], &d.x[window]);
            file_fit(d, &e)
        })
        .collect()
}

/// Samples in each window of the rows beyond a fitted window that `fpi calibrate
/// --rows` and the demo score ([`held_out`]).
pub const HELD_OUT_WINDOW: usize = 1000;

/// How a model predicts a window of a recording beyond its fitted rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// The window's rows, 1-based, inclusive.
    pub rows: (usize, usize),
    /// RMSE of the prediction with the window's mean error removed, µm.
    pub rmse_um: f64,
    /// The mean error removed (the recording's drift and the model's offset
    /// there), µm.
    pub offset_um: f64,
}

/// The prediction of a recording's rows outside its fitted ones (`d.fit`), in
/// windows of `len` samples: the model runs over the whole recording from its
/// first row, as it was fitted, and each window is scored with its own mean error
/// (the recording's drift) removed. The windows tile the rows before the fitted
/// ones from the first row, and those after them from the next row; the last of
/// each part may be shorter.
pub fn held_out(model: &HostModel, d: &CalibData, len: usize) -> Vec<Window> {
    let x = simulate(model, d);
    let len = len.max(1);
    let parts = [(0, d.fit.0), (d.fit.1, d.u.len())];
    parts
        .into_iter()
        .flat_map(|(a, b)| (a..b).step_by(len).map(move |k| (k, (k + len).min(b))))
        .map(|(a, b)| {
            let (sim, measured) = (&x[a..b], &d.x[a..b]);
            let offset =
                sim.iter().zip(measured).map(|(s, m)| s - m).sum::<f64>() / sim.len() as f64;
            let mut e = ErrorStats::new();
            for (s, m) in sim.iter().zip(measured) {
                e.add(s - m - offset);
            }
            Window {
                rows: (a + 1, b),
                rmse_um: e.rms(),
                offset_um: offset,
            }
        })
        .collect()
}

/// [`held_out`]'s windows of `d` in one line: their RMSE before and after the
/// fitted rows.
pub fn held_out_summary(d: &CalibData, windows: &[Window]) -> String {
    let list = |before: bool| {
        let v: Vec<String> = windows
            .iter()
            .filter(|w| (w.rows.1 <= d.fit.0) == before)
            .map(|w| format!("{:.3}", w.rmse_um))
            .collect();
        if v.is_empty() {
            "none".to_string()
        } else {
            v.join(", ")
        }
    };
    let len = windows.first().map_or(0, |w| w.rows.1 + 1 - w.rows.0);
    format!(
        "{len}-sample windows beyond the fitted rows {}-{}, each with its mean error removed: \
         RMSE {} µm before them, {} µm after",
        d.fit.0 + 1,
        d.fit.1,
        list(true),
        list(false)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::method::model::Kind;
    use crate::model_file::PiSection;

    /// A recording whose fitted rows span `span_um`.
    fn spanning(span_um: f64) -> CalibData {
        let x: Vec<f64> = (0..100).map(|k| span_um * k as f64 / 99.0).collect();
        CalibData {
            name: "r.csv".into(),
            dt: 1e-3,
            u: x.iter().map(|v| 10.0 * v).collect(),
            f: vec![50.0; 100],
            x,
            f0: 50.0,
            fit: (0, 100),
            has_force: true,
        }
    }

    fn fitted(kind: Kind, rmse_um: f64, compliance: f64) -> HostModel {
        let mut m = HostModel::new(
            kind,
            PiSection {
                w0_um_per_v: 0.1,
                thresholds_v: vec![10.0],
                weights_um_per_v: vec![0.01],
                input_max_v: 150.0,
            },
        );
        m.calibration.rmse_um = rmse_um;
        m.coupling.compliance_um_per_n = compliance;
        m
    }

    /// The fit `--compliance 1e9` gave (RMSE 7·10⁷ µm on a 40 µm motion) is
    /// refused with the share of the motion it misses; an ordinary fit passes.
    #[test]
    fn a_fit_that_misses_the_motion_is_refused() {
        let d = [spanning(40.0)];
        let e = plausible(&fitted(Kind::Efpi, 7.2e7, 0.45), &d).unwrap_err();
        let e = format!("{e:#}");
        assert!(
            e.starts_with("the fitted efpi model is implausible: its RMSE 72000000 µm is")
                && e.contains("1800000 times the 40 µm the recordings span")
                && e.contains("its stack compliance is 0.45 µm/N"),
            "{e}"
        );
        assert!(plausible(&fitted(Kind::Efpi, 0.2, 0.02), &d).is_ok());
        assert!(plausible(&fitted(Kind::Pi, 25.0, 0.0), &d).is_err());
        // No motion at all: nothing to compare with (the model's own checks
        // refuse a model that cannot move).
        assert!(plausible(&fitted(Kind::Pi, 1.0, 0.0), &[spanning(0.0)]).is_ok());
    }

    /// A fit that fails its check is explained by the recording: one that does
    /// not rise with the voltage, one that does not move at the bottom of the
    /// drive (no slope at rest), one whose voltage does not move.
    #[test]
    fn a_fit_without_a_valid_model_is_explained_by_the_data() {
        let mut m = fitted(Kind::Pi, 0.1, 0.0);
        m.pi.w0_um_per_v = 0.0;
        let mut d = spanning(40.0);
        let why = why_no_model(&m, &[d.clone()]);
        assert!(why.contains("the fit gives"), "{why}");
        d.x.iter_mut().for_each(|x| *x = -*x);
        let why = why_no_model(&m, &[d.clone()]);
        assert!(
            why.starts_with(
                "the displacement of r.csv does not rise with the voltage over its \
                 fitted rows (a straight line through them goes -0.1 µm/V)"
            ),
            "{why}"
        );
        // Up and down 0–100 V; the displacement moves from 20 V on only.
        d.u = (0..100)
            .map(|k| 100.0 - (k as f64 - 50.0).abs() * 2.0)
            .collect();
        d.x = d.u.iter().map(|u| (u - 20.0).max(0.0) * 0.1).collect();
        let why = why_no_model(&m, &[d.clone()]);
        assert!(
            why.starts_with(
                "at the bottom of the drive (0–10 V) the displacement of r.csv rises \
                 by 0 µm/V where the voltage rises, against 0.09 µm/V over the whole drive"
            ),
            "{why}"
        );
        d.u = vec![5.0; 100];
        let why = why_no_model(&m, &[d]);
        assert_eq!(
            why,
            "the voltage of r.csv does not change over its fitted rows (5 V throughout)"
        );
    }
}
