//! Plausibility checks of calibration recordings: the one place that decides
//! whether data can be calibrated at all (errors) and what in it looks like a
//! unit slip or a recording gone wrong (warnings, kept in the model's
//! `calibration.warnings` and printed by `fpi calibrate`). Every message names
//! the file, the column and the number that triggered it.
//!
//! Errors, where the result would be meaningless:
//!
//! * a value beyond ±[`SIGNAL_ABS_MAX`] (4096 V, N or µm), the largest signal the
//!   fixed-point core handles: such a cell (1e308, or millivolts) overflows the fit;
//! * no voltage variation, or no displacement variation, over the fitted rows;
//! * a force-dependent kind (fpi, efpi, ldpi, branch) on recordings without a
//!   force channel, or whose force is constant: `k_f` (the force slopes, for ldpi)
//!   cannot be identified ([`force_unusable`]; `fpi calibrate` falls back from the
//!   default efpi to epi instead).
//!
//! Warnings: a nearly constant voltage (span below [`MIN_VOLTAGE_SPAN_V`]) or
//! force (below [`MIN_FORCE_SPAN_N`] or [`MIN_FORCE_SPAN_REL`] of its mean, for the
//! force kinds), voltages beyond the amplifier's [`AMPLIFIER_MAX_V`] or below
//! [`MIN_VOLTAGE_V`], forces below [`MIN_FORCE_N`], displacement spans beyond
//! [`MAX_DISPLACEMENT_SPAN_UM`] or below [`MIN_DISPLACEMENT_SPAN_UM`], and a pi
//! model (identified at one preload) over recordings at very different preloads.
//!
//! Rows are counted from 1 over a file's data rows (the header not counted), as
//! `--rows` counts them.

use anyhow::{bail, Result};
use piezo_fpi::q::SIGNAL_ABS_MAX;

use crate::method::limits::AMPLIFIER_MAX_V;
use crate::method::model::Kind;
use crate::method::series::CalibData;

/// Voltages below this, V, are not an amplifier's output (a sign or offset slip).
pub const MIN_VOLTAGE_V: f64 = -5.0;
/// A recording whose voltage spans less than this, V, barely moves the operators.
pub const MIN_VOLTAGE_SPAN_V: f64 = 1.0;
/// Forces below this, N, are a tension: the preload is a compression, positive.
pub const MIN_FORCE_N: f64 = -5.0;
/// A force spanning less than this over all recordings, N, barely identifies `k_f`.
pub const MIN_FORCE_SPAN_N: f64 = 1.0;
/// … or less than this fraction of its mean magnitude.
pub const MIN_FORCE_SPAN_REL: f64 = 0.02;
/// A piezo stack's extension spans at most about this, µm.
pub const MAX_DISPLACEMENT_SPAN_UM: f64 = 500.0;
/// Below this span, µm, a recording hardly shows motion.
pub const MIN_DISPLACEMENT_SPAN_UM: f64 = 0.01;
/// Mean preloads of a pi model's recordings further apart than this, N, are
/// different operating points (the paper identifies PI at one preload).
pub const PI_PRELOAD_SPREAD_N: f64 = 10.0;

/// A span this small relative to the channel's magnitude (at least 1) is no
/// variation at all.
const CONSTANT_REL: f64 = 1e-9;

/// A recording's channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Channel {
    Voltage,
    Force,
    Displacement,
}

impl Channel {
    fn values(self, d: &CalibData) -> &[f64] {
        match self {
            Channel::Voltage => &d.u,
            Channel::Force => &d.f,
            Channel::Displacement => &d.x,
        }
    }

    /// The column's name in the recording's file.
    fn column(self, d: &CalibData) -> &'static str {
        let dat = d.name.ends_with(".dat");
        match (self, dat) {
            (Channel::Voltage, false) => "voltage_V",
            (Channel::Force, false) => "force_N",
            (Channel::Displacement, false) => "displacement_um",
            (Channel::Voltage, true) => "column 1 (V)",
            (Channel::Force, true) => "force (none)",
            (Channel::Displacement, true) => "column 5 (µm)",
        }
    }

    fn unit(self) -> &'static str {
        match self {
            Channel::Voltage => "V",
            Channel::Force => "N",
            Channel::Displacement => "µm",
        }
    }
}

/// The smallest and largest value of a series and their indices.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Extremes {
    lo: f64,
    lo_at: usize,
    hi: f64,
    hi_at: usize,
}

impl Extremes {
    /// `None` for an empty series; a NaN counts as the largest value.
    fn of(v: &[f64]) -> Option<Self> {
        let first = *v.first()?;
        let mut e = Extremes {
            lo: first,
            lo_at: 0,
            hi: first,
            hi_at: 0,
        };
        for (k, &x) in v.iter().enumerate() {
            if x < e.lo {
                e.lo = x;
                e.lo_at = k;
            }
            if x > e.hi || (x.is_nan() && !e.hi.is_nan()) {
                e.hi = x;
                e.hi_at = k;
            }
        }
        Some(e)
    }

    fn span(&self) -> f64 {
        self.hi - self.lo
    }

    /// The two series' extremes together (indices are then meaningless).
    fn merge(self, o: Self) -> Self {
        Extremes {
            lo: self.lo.min(o.lo),
            lo_at: 0,
            hi: self.hi.max(o.hi),
            hi_at: 0,
        }
    }

    /// Whether the span is no variation at all.
    fn constant(&self) -> bool {
        self.span() <= CONSTANT_REL * self.lo.abs().max(self.hi.abs()).max(1.0)
    }
}

/// A number for a message: plain where readable, scientific where huge or tiny.
fn num(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:.3e}")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".to_string()
        } else {
            s.to_string()
        }
    }
}

/// Refuses a series with a value beyond ±[`SIGNAL_ABS_MAX`] (or not finite):
/// `file`, `column`, the value and its row in the message. [`super::calibrate::load`]
/// runs it on the values as read ([`ranges`]), [`check`] again on the prepared data.
pub fn signal_range(file: &str, column: &str, values: &[f64], unit: &str) -> Result<()> {
    let Some((k, v)) = values
        .iter()
        .enumerate()
        .find(|(_, v)| !v.is_finite() || v.abs() > SIGNAL_ABS_MAX)
    else {
        return Ok(());
    };
    let why = if v.abs() < 1e7 {
        "a unit slip"
    } else {
        "a corrupt cell"
    };
    bail!(
        "{file}: {column} = {} {unit} at row {}: beyond ±{SIGNAL_ABS_MAX} {unit}, the largest \
         signal the fit and the firmware's fixed point handle ({why}?)",
        num(*v),
        k + 1
    )
}

/// [`signal_range`] on every channel of a recording.
pub fn ranges(d: &CalibData) -> Result<()> {
    for ch in [Channel::Voltage, Channel::Force, Channel::Displacement] {
        if ch == Channel::Force && !d.has_force {
            continue;
        }
        signal_range(&d.name, ch.column(d), ch.values(d), ch.unit())?;
    }
    Ok(())
}

/// Why a recording set cannot identify a force coupling: a recording without a
/// force channel, or a force that is constant over every fitted row. `None`
/// when the force varies.
pub fn force_unusable(data: &[CalibData]) -> Option<String> {
    if let Some(d) = data.iter().find(|d| !d.has_force) {
        return Some(format!("{}: the recording has no force channel", d.name));
    }
    let e = fitted_extremes(data, Channel::Force)?;
    e.constant().then(|| {
        format!(
            "force_N is constant ({} N in every fitted row of {})",
            num(e.lo),
            files(data)
        )
    })
}

/// "file.csv" or "the 3 files".
fn files(data: &[CalibData]) -> String {
    match data {
        [d] => d.name.clone(),
        _ => format!("the {} files", data.len()),
    }
}

/// A channel's extremes over the fitted rows of every recording.
fn fitted_extremes(data: &[CalibData], ch: Channel) -> Option<Extremes> {
    data.iter()
        .filter_map(|d| Extremes::of(&ch.values(d)[d.fit.0..d.fit.1]))
        .reduce(Extremes::merge)
}

/// Checks recordings before calibrating a `kind`: an error where the result
/// would be meaningless, else the warnings (empty when everything looks
/// plausible).
pub fn check(data: &[CalibData], kind: Kind) -> Result<Vec<String>> {
    use Channel::*;
    if data.is_empty() {
        bail!("no calibration recordings given");
    }
    for d in data {
        ranges(d)?;
        if d.fit.0 >= d.fit.1 || d.fit.1 > d.u.len() {
            bail!(
                "{}: no rows to fit (rows {}-{} of {})",
                d.name,
                d.fit.0 + 1,
                d.fit.1,
                d.u.len()
            );
        }
    }
    for ch in [Voltage, Displacement] {
        let e = fitted_extremes(data, ch).expect("every recording has fitted rows");
        if e.constant() {
            let what = if ch == Voltage {
                "the drive never changes: there is nothing to fit"
            } else {
                "the stage never moves: there is nothing to fit"
            };
            bail!(
                "{} is constant ({} {} in every fitted row of {}): {what}",
                ch.column(&data[0]),
                num(e.lo),
                ch.unit(),
                files(data)
            );
        }
    }
    if kind.uses_force() {
        if let Some(why) = force_unusable(data) {
            bail!(
                "{why}: {} cannot be identified; calibrate epi, gpi or pi, or record at several \
                 preloads",
                kind.force_part()
            );
        }
    }
    let mut w = Vec::new();
    for d in data {
        warn_recording(d, kind, &mut w);
    }
    if kind.uses_force() {
        let e = fitted_extremes(data, Force).expect("every recording has fitted rows");
        let mean = mean_force(data);
        let least = MIN_FORCE_SPAN_N.max(MIN_FORCE_SPAN_REL * mean.abs());
        if e.span() < least {
            w.push(format!(
                "force_N spans only {} N ({}–{} N) over the fitted rows of {}: nearly constant \
                 (less than {} N), so k_f is poorly identified (kilonewtons? record at several \
                 preloads)",
                num(e.span()),
                num(e.lo),
                num(e.hi),
                files(data),
                num(least)
            ));
        }
    }
    if kind.one_preload() && data.iter().all(|d| d.has_force) {
        let means: Vec<f64> = data
            .iter()
            .map(|d| {
                let f = &d.f[d.fit.0..d.fit.1];
                f.iter().sum::<f64>() / f.len() as f64
            })
            .collect();
        let lo = means.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = means.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if hi - lo > PI_PRELOAD_SPREAD_N {
            w.push(format!(
                "force_N: a {kind} model ignores force, and these recordings span mean \
                 preloads {lo:.0}–{hi:.0} N; the paper identifies PI at one preload (the rig \
                 preload nearest the stage's f_F(0))"
            ));
        }
    }
    Ok(w)
}

/// The mean force over every fitted row, N.
fn mean_force(data: &[CalibData]) -> f64 {
    let (s, c) = data
        .iter()
        .flat_map(|d| d.f[d.fit.0..d.fit.1].iter())
        .fold((0.0, 0usize), |(s, c), f| (s + f, c + 1));
    s / c.max(1) as f64
}

/// One recording's warnings: voltage range and span, force sign (force kinds),
/// displacement span.
fn warn_recording(d: &CalibData, kind: Kind, w: &mut Vec<String>) {
    use Channel::*;
    let name = &d.name;
    let fitted = |ch: Channel| Extremes::of(&ch.values(d)[d.fit.0..d.fit.1]);
    let all = |ch: Channel| Extremes::of(ch.values(d));
    if let Some(e) = all(Voltage) {
        let col = Voltage.column(d);
        if e.hi > AMPLIFIER_MAX_V {
            w.push(format!(
                "{name}: {col} reaches {} V at row {}, beyond the amplifier's 0–{AMPLIFIER_MAX_V} V \
                 (millivolts?)",
                num(e.hi),
                e.hi_at + 1
            ));
        }
        if e.lo < MIN_VOLTAGE_V {
            w.push(format!(
                "{name}: {col} goes down to {} V at row {}, below {MIN_VOLTAGE_V} V: an amplifier \
                 drives 0–{AMPLIFIER_MAX_V} V (millivolts? a sign or offset slip?)",
                num(e.lo),
                e.lo_at + 1
            ));
        }
    }
    if let Some(e) = fitted(Voltage) {
        if e.span() < MIN_VOLTAGE_SPAN_V {
            w.push(format!(
                "{name}: {} spans only {} V ({}–{} V) in the fitted rows: nearly constant (less \
                 than {MIN_VOLTAGE_SPAN_V} V), the operators barely move",
                Voltage.column(d),
                num(e.span()),
                num(e.lo),
                num(e.hi)
            ));
        }
    }
    if kind.uses_force() && d.has_force {
        if let Some(e) = all(Force) {
            if e.lo < MIN_FORCE_N {
                w.push(format!(
                    "{name}: {} goes down to {} N at row {}: a preload is a compression, \
                     positive here (a sign slip?)",
                    Force.column(d),
                    num(e.lo),
                    e.lo_at + 1
                ));
            }
        }
    }
    if let Some(e) = fitted(Displacement) {
        let col = Displacement.column(d);
        if e.span() > MAX_DISPLACEMENT_SPAN_UM {
            w.push(format!(
                "{name}: {col} spans {} µm in the fitted rows, implausible for a piezo stack \
                 (more than {MAX_DISPLACEMENT_SPAN_UM} µm; nanometres?)",
                num(e.span())
            ));
        } else if e.span() < MIN_DISPLACEMENT_SPAN_UM {
            w.push(format!(
                "{name}: {col} spans only {} µm in the fitted rows: hardly any motion (less than \
                 {MIN_DISPLACEMENT_SPAN_UM} µm; millimetres? a disconnected sensor?)",
                num(e.span())
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plausible recording: a 0–100 V triangle, 50–60 N, 0–8 µm.
    fn rec(name: &str) -> CalibData {
        let n = 400;
        let u: Vec<f64> = (0..n)
            .map(|k| 100.0 * (1.0 - (2.0 * k as f64 / n as f64 - 1.0).abs()))
            .collect();
        let x: Vec<f64> = u.iter().map(|u| 0.08 * u).collect();
        let f: Vec<f64> = x.iter().map(|x| 50.0 + 1.25 * x).collect();
        CalibData {
            name: name.into(),
            dt: 1e-3,
            f0: f[0],
            u,
            f,
            x,
            fit: (0, n),
            has_force: true,
        }
    }

    fn two() -> Vec<CalibData> {
        let mut b = rec("b.csv");
        b.f.iter_mut().for_each(|f| *f += 50.0);
        vec![rec("a.csv"), b]
    }

    fn err(data: &[CalibData], kind: Kind) -> String {
        format!("{:#}", check(data, kind).unwrap_err())
    }

    fn warnings(data: &[CalibData], kind: Kind) -> Vec<String> {
        check(data, kind).unwrap()
    }

    #[test]
    fn plausible_data_passes_silently() {
        for kind in [Kind::Pi, Kind::Gpi, Kind::Fpi, Kind::Efpi, Kind::Ldpi] {
            assert_eq!(warnings(&[rec("a.csv")], kind), Vec::<String>::new());
        }
        assert!(warnings(&two(), Kind::Efpi).is_empty());
    }

    #[test]
    fn a_huge_cell_is_refused_with_file_column_row_and_value() {
        let mut d = two();
        d[1].f[7] = 1e308;
        let e = err(&d, Kind::Gpi);
        assert!(
            e.contains("b.csv: force_N = 1.000e308 N at row 8: beyond ±4096"),
            "{e}"
        );
        let mut d = two();
        d[0].x[3] = -5000.0;
        let e = err(&d, Kind::Pi);
        assert!(
            e.contains("a.csv: displacement_um = -5000 µm at row 4") && e.contains("unit slip"),
            "{e}"
        );
        let e = signal_range("m.dat", "column 1 (V)", &[1.0, f64::NAN], "V").unwrap_err();
        assert!(e.to_string().contains("row 2"), "{e}");
    }

    #[test]
    fn no_voltage_or_displacement_variation_is_refused() {
        let mut d = two();
        for r in &mut d {
            r.u.iter_mut().for_each(|u| *u = 42.0);
        }
        let e = err(&d, Kind::Gpi);
        assert!(
            e.contains("voltage_V is constant (42 V in every fitted row of the 2 files)"),
            "{e}"
        );
        let mut d = two();
        for r in &mut d {
            r.x.iter_mut().for_each(|x| *x = 0.0);
        }
        let e = err(&d, Kind::Pi);
        assert!(e.contains("displacement_um is constant (0 µm"), "{e}");
    }

    #[test]
    fn a_constant_or_absent_force_cannot_identify_k_f() {
        let mut d = two();
        for r in &mut d {
            r.f.iter_mut().for_each(|f| *f = 50.0);
        }
        for kind in [Kind::Fpi, Kind::Efpi] {
            let e = err(&d, kind);
            assert!(
                e.contains("force_N is constant (50 N in every fitted row of the 2 files)")
                    && e.contains(&format!(
                        "k_f, the force coupling of the {kind} model, cannot be identified"
                    )),
                "{e}"
            );
        }
        assert!(err(&d, Kind::Ldpi).contains("the force slopes of the ldpi model's weights cannot"));
        assert!(warnings(&d, Kind::Gpi).is_empty());
        assert!(force_unusable(&d).is_some());
        let mut d = two();
        d[1].has_force = false;
        assert!(err(&d, Kind::Fpi).contains("b.csv: the recording has no force channel"));
        assert!(force_unusable(&two()).is_none());
    }

    #[test]
    fn a_nearly_constant_force_warns() {
        // Kilonewtons: 0.05–0.06.
        let mut d = rec("kn.csv");
        d.f.iter_mut().for_each(|f| *f /= 1000.0);
        let w = warnings(&[d], Kind::Fpi);
        assert!(
            w.len() == 1 && w[0].starts_with("force_N spans only 0.01 N (0.05–0.06 N)"),
            "{w:?}"
        );
        // Not for the kinds that ignore force.
        let mut d = rec("kn.csv");
        d.f.iter_mut().for_each(|f| *f /= 1000.0);
        assert!(warnings(&[d], Kind::Gpi).is_empty());
    }

    #[test]
    fn voltages_outside_the_amplifier_or_nearly_constant_warn() {
        let mut d = rec("mv.csv");
        d.u.iter_mut().for_each(|u| *u *= 10.0);
        let w = warnings(&[d], Kind::Gpi);
        assert!(
            w.len() == 1 && w[0].starts_with("mv.csv: voltage_V reaches 1000 V at row 201"),
            "{w:?}"
        );
        let mut d = rec("neg.csv");
        d.u[5] = -12.0;
        let w = warnings(&[d], Kind::Pi);
        assert!(
            w.len() == 1 && w[0].starts_with("neg.csv: voltage_V goes down to -12 V at row 6"),
            "{w:?}"
        );
        let mut d = rec("flat.csv");
        d.u.iter_mut().for_each(|u| *u = 50.0 + *u * 1e-3);
        let w = warnings(&[d, rec("a.csv")], Kind::Gpi);
        assert!(
            w.len() == 1 && w[0].starts_with("flat.csv: voltage_V spans only 0.1 V (50–50.1 V)"),
            "{w:?}"
        );
    }

    #[test]
    fn a_negative_force_warns_for_the_force_kinds() {
        let mut d = rec("t.csv");
        d.f[9] = -30.0;
        let w = warnings(&[d.clone()], Kind::Efpi);
        assert!(
            w.len() == 1 && w[0].starts_with("t.csv: force_N goes down to -30 N at row 10"),
            "{w:?}"
        );
        assert!(warnings(&[d], Kind::Gpi).is_empty());
    }

    #[test]
    fn implausible_displacement_spans_warn() {
        let mut d = rec("nm.csv");
        d.x.iter_mut().for_each(|x| *x *= 100.0);
        let w = warnings(&[d], Kind::Gpi);
        assert!(
            w.len() == 1 && w[0].starts_with("nm.csv: displacement_um spans 800 µm"),
            "{w:?}"
        );
        let mut d = rec("mm.csv");
        d.x.iter_mut().for_each(|x| *x *= 1e-3);
        let w = warnings(&[d], Kind::Gpi);
        assert!(
            w.len() == 1 && w[0].starts_with("mm.csv: displacement_um spans only 0.008 µm"),
            "{w:?}"
        );
    }

    #[test]
    fn a_pi_model_over_spread_preloads_warns() {
        let w = warnings(&two(), Kind::Pi);
        assert!(
            w.len() == 1 && w[0].contains("span mean preloads 55–105 N"),
            "{w:?}"
        );
    }

    #[test]
    fn only_the_fitted_rows_count_for_spans() {
        let mut d = rec("w.csv");
        d.fit = (0, 2);
        let w = warnings(&[d], Kind::Gpi);
        assert!(
            w.iter().any(|w| w.contains("voltage_V spans only 0.5 V")),
            "{w:?}"
        );
    }

    #[test]
    fn numbers_read_well() {
        assert_eq!(num(1e308), "1.000e308");
        assert_eq!(num(42.0), "42");
        assert_eq!(num(0.0), "0");
        assert_eq!(num(-12.5), "-12.5");
        assert_eq!(num(0.0084), "0.0084");
    }
}
