//! The 2D line figures: hysteresis loops, curves against time and grids of
//! loop panels.

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;

use super::frame::{draw_xy, no_data, titled, write_svg, XyPlot};
use super::legend::{draw_legend_row, LegendEntry};
use super::series::{xy_lines, Line};
use super::style::{DASH_SENTINEL, FULL, PANEL_TITLE_SIZE, SMALL, TITLE_SIZE};
use super::{series_color, Panel, MAX_POINTS};

/// Hysteresis loops: `y` against `x` for the measured data and each model (e.g.
/// stage output µm vs voltage V). 900x600 px.
///
/// `measured` and every series are paired point by point with `x`.
pub fn loops(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    x: &[f64],
    measured: Option<&[f64]>,
    series: &[(&str, &[f64])],
) -> Result<()> {
    let lines = xy_lines(x, measured, series, |i, _| series_color(i), MAX_POINTS);
    single_plot(path, title, x_label, y_label, &lines, false)
}

/// Curves against time (e.g. prediction error in µm vs time in s), one per series,
/// with a zero line (the y range always includes 0). The x axis is labelled
/// "time (s)". 900x600 px.
pub fn curves(
    path: &Path,
    title: &str,
    y_label: &str,
    t: &[f64],
    series: &[(&str, &[f64])],
) -> Result<()> {
    let lines = xy_lines(t, None, series, |i, _| series_color(i), MAX_POINTS);
    single_plot(path, title, "time (s)", y_label, &lines, true)
}

/// One full-size line plot with a legend under a title, 900x600 px.
fn single_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    lines: &[Line],
    zero_line: bool,
) -> Result<()> {
    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        draw_xy(
            &area,
            &XyPlot {
                x_label,
                y_label,
                lines,
                zero_line,
                legend: true,
                style: &FULL,
            },
        )
    })
}

/// Several small loops-style panels in one SVG (1200x800 px): a grid of up to 3
/// columns (1: 1x1, 2: 2x1, 3: 3x1, 4: 2x2, 5-6: 3x2, more: 3 columns and as many
/// rows as needed, the figure growing 400 px per extra row), each with its own
/// title and the same axis labels, and one legend shared by all panels under the
/// figure title.
pub fn loop_panels(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    panels: &[Panel],
) -> Result<()> {
    let (names, has_measured) = series_names(panels);
    let color_of = |name: &str| series_color(names.iter().position(|n| *n == name).unwrap_or(0));
    let n = panels.len();
    let (rows, cols) = grid_shape(n);
    let height = 800 + 400 * rows.saturating_sub(2) as u32;
    let per_line = (MAX_POINTS / 2).max(MAX_POINTS * 4 / (n.max(1) * 3));
    let panel_lines: Vec<Vec<Line>> = panels
        .iter()
        .map(|p| {
            xy_lines(
                p.x,
                p.measured,
                &p.series,
                |_, name| color_of(name),
                per_line.min(MAX_POINTS),
            )
        })
        .collect();
    let entries = shared_legend(&names, has_measured);

    write_svg(path, (1200, height), |root| {
        let mut area = titled(root, title, TITLE_SIZE)?;
        // Shared legend: one row under the title.
        if entries.len() > 1 {
            let (legend_area, rest) = area.split_vertically(30);
            draw_legend_row(&legend_area, &entries)?;
            area = rest;
        }
        if panels.is_empty() {
            return no_data(&area);
        }
        let cells = area.split_evenly((rows, cols));
        for (cell, (p, lines)) in cells.iter().zip(panels.iter().zip(&panel_lines)) {
            let cell = titled(cell, &p.title, PANEL_TITLE_SIZE)?;
            draw_xy(
                &cell,
                &XyPlot {
                    x_label,
                    y_label,
                    lines,
                    zero_line: false,
                    legend: false,
                    style: &SMALL,
                },
            )?;
        }
        Ok(())
    })
}

/// The model names of all panels, in order of first appearance (their colours
/// follow this order), and whether any panel has measured data.
fn series_names<'a>(panels: &[Panel<'a>]) -> (Vec<&'a str>, bool) {
    let mut names: Vec<&str> = vec![];
    let mut has_measured = false;
    for p in panels {
        has_measured |= p.measured.is_some();
        for (n, _) in &p.series {
            if !names.contains(n) {
                names.push(n);
            }
        }
    }
    (names, has_measured)
}

/// (rows, columns) of the panel grid for `n` panels.
fn grid_shape(n: usize) -> (usize, usize) {
    match n {
        0 | 1 => (1, 1),
        2 => (1, 2),
        3 => (1, 3),
        4 => (2, 2),
        _ => (n.div_ceil(3), 3),
    }
}

/// Entries of the legend shared by all panels: measured first, then the models.
fn shared_legend(names: &[&str], has_measured: bool) -> Vec<LegendEntry> {
    let mut entries: Vec<LegendEntry> = vec![];
    if has_measured {
        entries.push(("measured".into(), DASH_SENTINEL.stroke_width(2)));
    }
    for (i, name) in names.iter().enumerate() {
        entries.push((name.to_string(), series_color(i).stroke_width(2)));
    }
    entries
}
