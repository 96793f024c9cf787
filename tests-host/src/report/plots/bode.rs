//! The Bode figure of `fpi identify`: measured (points) and fitted (lines)
//! magnitude and phase of each chirp's frequency response, and its coherence,
//! on a logarithmic frequency axis.

use std::path::Path;

use anyhow::Result;
use nalgebra::Complex;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;

use super::frame::{titled, write_svg};
use super::legend::LegendEntry;
use super::series::{decimate, padded_range};
use super::style::{FONT, LABEL_SIZE, TITLE_SIZE};
use super::{series_color, MAX_POINTS};

/// One chirp of [`bode()`].
#[derive(Debug, Clone)]
pub struct BodeSeries<'a> {
    /// Its name in the legend.
    pub name: &'a str,
    /// Frequencies of the measured points, Hz.
    pub f_hz: Vec<f64>,
    /// Measured response at `f_hz` (e.g. µm/V).
    pub h: Vec<Complex<f64>>,
    /// Frequencies of the fitted curve, Hz.
    pub fit_f_hz: Vec<f64>,
    /// Fitted response at `fit_f_hz`.
    pub fit_h: Vec<Complex<f64>>,
    /// Frequencies of the coherence, Hz.
    pub coherence_f_hz: Vec<f64>,
    /// Magnitude-squared coherence, 0..=1.
    pub coherence: Vec<f64>,
}

/// Least coherence of a fitted point, drawn as a grey line in the coherence panel.
const COHERENCE_LINE: f64 = 0.9;

/// Three panels, 1000x1100 px: magnitude (dB re 1 unit of `h`), phase (degrees,
/// unwrapped, each measured series shifted by whole turns onto its fit) and
/// coherence, against frequency (Hz, log axis). Non-finite and non-positive
/// frequencies are skipped.
pub fn bode(path: &Path, title: &str, series: &[BodeSeries]) -> Result<()> {
    let panels = panel_data(series);
    let fr = freq_range(series);
    write_svg(path, (1000, 1100), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        let (legend, area) = area.split_vertically(34);
        legend_row(&legend, series)?;
        let rows = area.split_evenly((3, 1));
        let labels = ["magnitude (dB)", "phase (deg)", "coherence γ²"];
        for (k, cell) in rows.iter().enumerate() {
            draw_panel(cell, fr, labels[k], &panels[k], k == 2)?;
        }
        Ok(())
    })
}

/// Per panel, per series: (measured points, fitted line).
type PanelData = Vec<(Vec<(f64, f64)>, Vec<(f64, f64)>)>;

/// Magnitude, phase and coherence as (points, line) per series.
fn panel_data(series: &[BodeSeries]) -> [PanelData; 3] {
    let mut mag = vec![];
    let mut phase = vec![];
    let mut coh = vec![];
    for s in series {
        let db = |h: &Complex<f64>| 20.0 * h.norm().log10();
        let fit_ph = unwrap_deg(&s.fit_h);
        let mut ph = unwrap_deg(&s.h);
        align(&mut ph, &s.f_hz, &fit_ph, &s.fit_f_hz);
        mag.push((
            pairs(&s.f_hz, s.h.iter().map(db)),
            pairs(&s.fit_f_hz, s.fit_h.iter().map(db)),
        ));
        phase.push((
            pairs(&s.f_hz, ph.into_iter()),
            pairs(&s.fit_f_hz, fit_ph.into_iter()),
        ));
        let line = pairs(&s.coherence_f_hz, s.coherence.iter().copied());
        coh.push((vec![], decimate(&line, MAX_POINTS / 2)));
    }
    [mag, phase, coh]
}

/// Finite `(f, y)` pairs with `f > 0`.
fn pairs(f: &[f64], y: impl Iterator<Item = f64>) -> Vec<(f64, f64)> {
    f.iter()
        .copied()
        .zip(y)
        .filter(|(f, y)| *f > 0.0 && f.is_finite() && y.is_finite())
        .collect()
}

/// Phase in degrees, unwrapped along the sequence.
fn unwrap_deg(h: &[Complex<f64>]) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::with_capacity(h.len());
    for z in h {
        let raw = z.arg().to_degrees();
        let v = match out.last() {
            Some(&prev) => raw + 360.0 * ((prev - raw) / 360.0).round(),
            None => raw,
        };
        out.push(v);
    }
    out
}

/// Shifts `ph` (at `f`) by whole turns so its first point lies nearest the fitted
/// phase there.
fn align(ph: &mut [f64], f: &[f64], fit: &[f64], fit_f: &[f64]) {
    let (Some(&p0), Some(&f0)) = (ph.first(), f.first()) else {
        return;
    };
    let k = fit_f.iter().position(|&x| x >= f0).unwrap_or(0);
    let Some(&target) = fit.get(k) else { return };
    let turns = ((target - p0) / 360.0).round();
    ph.iter_mut().for_each(|p| *p += 360.0 * turns);
}

/// The frequency axis: the measured points' span, widened 10 % on a log scale.
fn freq_range(series: &[BodeSeries]) -> (f64, f64) {
    let fs = series
        .iter()
        .flat_map(|s| s.f_hz.iter().chain(&s.fit_f_hz))
        .copied()
        .filter(|f| *f > 0.0 && f.is_finite());
    let (lo, hi) = fs.fold((f64::INFINITY, 0.0f64), |(a, b), f| (a.min(f), b.max(f)));
    if lo.is_finite() && hi > lo {
        (lo / 1.1, hi * 1.1)
    } else {
        (1.0, 10.0)
    }
}

/// One panel: points (measured) and lines (fit) of every series.
fn draw_panel(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    fr: (f64, f64),
    y_label: &str,
    data: &PanelData,
    coherence: bool,
) -> Result<()> {
    let visible = |p: &&(f64, f64)| p.0 >= fr.0 && p.0 <= fr.1;
    let ys = data
        .iter()
        .flat_map(|(a, b)| a.iter().chain(b).filter(visible).map(|p| p.1));
    let yr = if coherence {
        (0.0, 1.02)
    } else {
        padded_range(ys, 0.05)
    };
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .margin_right(24)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((fr.0..fr.1).log_scale(), yr.0..yr.1)?;
    chart
        .configure_mesh()
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(BLACK.mix(0.04))
        .x_desc("frequency (Hz)")
        .y_desc(y_label)
        .label_style((FONT, LABEL_SIZE))
        .axis_desc_style((FONT, LABEL_SIZE + 2))
        .draw()?;
    if coherence {
        let grey = BLACK.mix(0.45).stroke_width(1);
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(fr.0, COHERENCE_LINE), (fr.1, COHERENCE_LINE)],
            grey,
        )))?;
    }
    for (i, (points, line)) in data.iter().enumerate() {
        let c = series_color(i);
        let line: Vec<(f64, f64)> = line.iter().filter(visible).copied().collect();
        chart.draw_series(LineSeries::new(line, c.stroke_width(2)))?;
        let pts = decimate(points, MAX_POINTS / 2);
        chart.draw_series(
            pts.into_iter()
                .filter(|p| visible(&p))
                .map(|p| Circle::new(p, 2, c.mix(0.55).filled())),
        )?;
    }
    Ok(())
}

/// The legend under the title: one entry per series (its colour; points are the
/// measured response, lines the fit).
fn legend_row(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    series: &[BodeSeries],
) -> Result<()> {
    let entries: Vec<LegendEntry> = series
        .iter()
        .enumerate()
        .map(|(i, s)| (s.name.to_string(), series_color(i).stroke_width(3)))
        .collect();
    super::legend::draw_legend_row(area, &entries)
}
