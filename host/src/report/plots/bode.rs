//! The Bode figures: measured (points) and fitted (lines) magnitude and phase
//! of frequency responses on a logarithmic frequency axis, and their coherence
//! where it was measured (`fpi identify`'s chirps; the board's stepped-sine
//! analyser measures none).

use std::path::Path;

use anyhow::Result;
use nalgebra::Complex;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;

use super::frame::{titled, write_svg};
use super::legend::{draw_legend_row_marked, Mark};
use super::series::{decimate, padded_range};
use super::style::{FONT, LABEL_SIZE, TITLE_SIZE};
use super::{series_color, MAX_POINTS};

/// One response of [`bode()`].
#[derive(Debug, Clone)]
pub struct BodeSeries<'a> {
    /// Its name in the legend.
    pub name: &'a str,
    /// Frequencies of the measured points, Hz.
    pub f_hz: Vec<f64>,
    /// Measured response at `f_hz` (e.g. µm/V).
    pub h: Vec<Complex<f64>>,
    /// Frequencies of the fitted curve, Hz (empty: no fit).
    pub fit_f_hz: Vec<f64>,
    /// Fitted response at `fit_f_hz`.
    pub fit_h: Vec<Complex<f64>>,
    /// Frequencies of the coherence, Hz (empty: not measured).
    pub coherence_f_hz: Vec<f64>,
    /// Magnitude-squared coherence, 0..=1.
    pub coherence: Vec<f64>,
}

/// Least coherence of a fitted point, drawn as a grey line in the coherence panel.
const COHERENCE_LINE: f64 = 0.9;

/// Height of one panel, px (with the title's and the legend's share).
const PANEL_HEIGHT: u32 = 350;

/// Magnitude (dB re 1 unit of `h`) and phase (degrees, unwrapped, each measured
/// series shifted by whole turns onto its fit) against frequency (Hz, log axis),
/// and below them the coherence when any series carries one: 1000 px wide, 350 px
/// per panel. Measured responses are points, fits lines; the legend shows each
/// series as it is drawn. Non-finite and non-positive frequencies are skipped.
pub fn bode(path: &Path, title: &str, series: &[BodeSeries]) -> Result<()> {
    let panels = panels(series);
    let fr = freq_range(series);
    let height = 50 + PANEL_HEIGHT * panels.len() as u32;
    write_svg(path, (1000, height), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        let (legend, area) = area.split_vertically(34);
        draw_legend_row_marked(&legend, &legend_marks(series))?;
        let rows = area.split_evenly((panels.len(), 1));
        for (cell, panel) in rows.iter().zip(&panels) {
            draw_panel(cell, fr, panel)?;
        }
        Ok(())
    })
}

/// One panel's data: per series, (measured points, line).
type PanelData = Vec<(Vec<(f64, f64)>, Vec<(f64, f64)>)>;

/// One panel of the figure.
#[derive(Debug, Clone)]
struct Panel {
    /// Its y axis label.
    label: &'static str,
    /// The coherence panel: y from 0 to 1, the least coherence of a fitted
    /// point marked.
    coherence: bool,
    /// What it draws.
    data: PanelData,
}

/// The panels to draw: magnitude and phase, and the coherence if any series
/// has a finite coherence at a positive frequency (a panel with nothing in it
/// is left out, not drawn empty).
fn panels(series: &[BodeSeries]) -> Vec<Panel> {
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
    let has_coherence = coh.iter().any(|(_, line)| !line.is_empty());
    let mut out = vec![
        Panel {
            label: "magnitude (dB)",
            coherence: false,
            data: mag,
        },
        Panel {
            label: "phase (deg)",
            coherence: false,
            data: phase,
        },
    ];
    if has_coherence {
        out.push(Panel {
            label: "coherence γ²",
            coherence: true,
            data: coh,
        });
    }
    out
}

/// Each series' legend sample, as the magnitude and phase panels draw it: a
/// line for a fit, a dot for measured points, both for both.
fn legend_marks(series: &[BodeSeries]) -> Vec<(String, Mark)> {
    series
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let c = series_color(i);
            let (line, dot) = (c.stroke_width(3), point_style(c));
            let has_fit = !pairs(&s.fit_f_hz, s.fit_h.iter().map(|h| h.norm())).is_empty();
            let has_points = !pairs(&s.f_hz, s.h.iter().map(|h| h.norm())).is_empty();
            let mark = match (has_fit, has_points) {
                (true, true) => Mark::LineAndDot(line, dot),
                (false, true) => Mark::Dot(dot),
                _ => Mark::Line(line),
            };
            (s.name.to_string(), mark)
        })
        .collect()
}

/// How a measured point of colour `c` is drawn.
fn point_style(c: RGBColor) -> ShapeStyle {
    c.mix(0.55).filled()
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

/// One panel: points (measured) and lines (fit, or coherence) of every series.
fn draw_panel(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    fr: (f64, f64),
    panel: &Panel,
) -> Result<()> {
    let visible = |p: &&(f64, f64)| p.0 >= fr.0 && p.0 <= fr.1;
    let ys = panel
        .data
        .iter()
        .flat_map(|(a, b)| a.iter().chain(b).filter(visible).map(|p| p.1));
    let yr = if panel.coherence {
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
        .y_desc(panel.label)
        .label_style((FONT, LABEL_SIZE))
        .axis_desc_style((FONT, LABEL_SIZE + 2))
        .draw()?;
    if panel.coherence {
        let grey = BLACK.mix(0.45).stroke_width(1);
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(fr.0, COHERENCE_LINE), (fr.1, COHERENCE_LINE)],
            grey,
        )))?;
    }
    for (i, (points, line)) in panel.data.iter().enumerate() {
        let c = series_color(i);
        let line: Vec<(f64, f64)> = line.iter().filter(visible).copied().collect();
        chart.draw_series(LineSeries::new(line, c.stroke_width(2)))?;
        let pts = decimate(points, MAX_POINTS / 2);
        chart.draw_series(
            pts.into_iter()
                .filter(|p| visible(&p))
                .map(|p| Circle::new(p, 2, point_style(c))),
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lightly damped mode's response at `f`.
    fn mode(f: &[f64]) -> Vec<Complex<f64>> {
        f.iter()
            .map(|f| {
                let s = Complex::new(0.0, f / 850.0);
                Complex::new(1.0, 0.0) / (s * s + s * 0.06 + 1.0)
            })
            .collect()
    }

    fn grid(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| 20.0 * 200f64.powf(k as f64 / (n - 1) as f64))
            .collect()
    }

    /// Like the board's Bode plots: measured points (no coherence), a fit for
    /// the first series only.
    fn board_like(f: &[f64], fit_f: &[f64]) -> [BodeSeries<'static>; 2] {
        let fit = BodeSeries {
            name: "undamped",
            f_hz: f.to_vec(),
            h: mode(f),
            fit_f_hz: fit_f.to_vec(),
            fit_h: mode(fit_f),
            coherence_f_hz: vec![],
            coherence: vec![],
        };
        let points = BodeSeries {
            name: "damped (IFF)",
            fit_f_hz: vec![],
            fit_h: vec![],
            ..fit.clone()
        };
        [fit, points]
    }

    /// Every panel drawn has something to draw for every series.
    fn no_empty_panel(panels: &[Panel]) {
        for p in panels {
            for (i, (points, line)) in p.data.iter().enumerate() {
                assert!(
                    !points.is_empty() || !line.is_empty(),
                    "the {} panel is empty for series {i}",
                    p.label
                );
            }
        }
    }

    #[test]
    fn without_coherence_there_is_no_empty_coherence_panel() {
        let (f, fit_f) = (grid(40), grid(300));
        let p = panels(&board_like(&f, &fit_f));
        let labels: Vec<&str> = p.iter().map(|p| p.label).collect();
        assert_eq!(labels, ["magnitude (dB)", "phase (deg)"]);
        no_empty_panel(&p);
    }

    #[test]
    fn a_measured_coherence_is_drawn_in_its_panel() {
        let (f, fit_f) = (grid(40), grid(300));
        let [mut a, mut b] = board_like(&f, &fit_f);
        for s in [&mut a, &mut b] {
            s.coherence_f_hz = f.clone();
            s.coherence = f.iter().map(|f| 1.0 - f / 1e5).collect();
        }
        // A NaN coherence (no power at that frequency) is skipped, not fatal.
        b.coherence[3] = f64::NAN;
        let p = panels(&[a, b]);
        assert_eq!(p.len(), 3);
        assert!(p[2].coherence);
        no_empty_panel(&p);
        let (_, line) = &p[2].data[1];
        assert_eq!(line.len(), f.len() - 1);
        assert!(line.iter().all(|&(_, g)| (0.0..=1.0).contains(&g)));
    }

    #[test]
    fn the_legend_shows_each_series_as_it_is_drawn() {
        let (f, fit_f) = (grid(40), grid(300));
        let marks = legend_marks(&board_like(&f, &fit_f));
        assert!(matches!(marks[0].1, Mark::LineAndDot(..)), "{marks:?}");
        assert!(matches!(marks[1].1, Mark::Dot(_)), "{marks:?}");
        let fit_only = BodeSeries {
            name: "fit",
            f_hz: vec![],
            h: vec![],
            fit_f_hz: fit_f.clone(),
            fit_h: mode(&fit_f),
            coherence_f_hz: vec![],
            coherence: vec![],
        };
        assert!(matches!(legend_marks(&[fit_only])[0].1, Mark::Line(_)));
    }
}
