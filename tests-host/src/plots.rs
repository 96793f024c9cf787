//! Publication-quality SVG figures for the report (hysteresis loops, error curves,
//! the 3D loop family of Fig. 12, grouped bars and multi-panel loop figures).
//!
//! Every function writes one SVG file (parent directories are created), white
//! background, a title, axis labels with units and a legend when more than one
//! series is drawn. Colours are consistent across figures: measured data are always
//! black ([`MEASURED_COLOR`], drawn last and dashed so that a model lying on top of
//! them stays visible), and the other series take [`series_color`]`(0)`,
//! [`series_color`]`(1)`, … in order.
//!
//! Inputs are never trusted: NaN/infinite values are skipped (a line is broken at
//! them), empty series are ignored, `x`/`y` slices of different lengths are
//! truncated to the shorter one, all-equal values get a widened axis range, and
//! long series (more than [`MAX_POINTS`] points) are decimated for drawing with a
//! shape-preserving min/max scheme so every SVG stays well below 1 MB.

#![deny(missing_docs)]

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Colour of measured data in every figure.
pub const MEASURED_COLOR: RGBColor = RGBColor(0, 0, 0);

/// Fixed palette of the non-measured series, in order (Okabe–Ito, colour-blind
/// safe, without black and yellow, plus brown). After these, colours come from
/// plotters' `Palette99`.
pub const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),   // blue
    RGBColor(213, 94, 0),    // vermillion
    RGBColor(0, 158, 115),   // bluish green
    RGBColor(204, 121, 167), // reddish purple
    RGBColor(230, 159, 0),   // orange
    RGBColor(86, 180, 233),  // sky blue
    RGBColor(140, 86, 75),   // brown
];

/// Most points drawn per series; longer series are decimated (min/max per bucket,
/// first and last points always kept).
pub const MAX_POINTS: usize = 4000;

/// Colour of the `i`-th non-measured series ([`PALETTE`], then `Palette99`).
pub fn series_color(i: usize) -> RGBColor {
    if i < PALETTE.len() {
        PALETTE[i]
    } else {
        let c = Palette99::pick(i - PALETTE.len()).to_rgba();
        RGBColor(c.0, c.1, c.2)
    }
}

/// One panel of [`loop_panels`]: a loops-style plot with its own title.
#[derive(Debug, Clone)]
pub struct Panel<'a> {
    /// Panel title (e.g. "25 N").
    pub title: String,
    /// Abscissa shared by the measured data and the series (e.g. voltage in V).
    pub x: &'a [f64],
    /// Measured ordinate, drawn black (dashed, on top).
    pub measured: Option<&'a [f64]>,
    /// Model ordinates: (name, values). Colours are assigned by name across all
    /// panels, so one model has the same colour in every panel.
    pub series: Vec<(&'a str, &'a [f64])>,
}

// ---------------------------------------------------------------------------
// Public figures
// ---------------------------------------------------------------------------

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
    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        draw_xy(
            &area,
            &XyPlot {
                x_label,
                y_label,
                lines: &lines,
                zero_line: false,
                legend: true,
                style: &FULL,
            },
        )
    })
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
    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        draw_xy(
            &area,
            &XyPlot {
                x_label: "time (s)",
                y_label,
                lines: &lines,
                zero_line: true,
                legend: true,
                style: &FULL,
            },
        )
    })
}

/// The paper's Fig. 12: a family of hysteresis loops x(u) at constant preloads
/// drawn in 3D as (voltage u, preload F, extension x), and a highlighted path
/// (u(t), F(t), x(t)) crossing them (the predicted loop in the stage, where the
/// preload changes with the extension). 900x600 px, the legend in a column on the
/// right of the cube.
///
/// `family`: (preload in N, points (u, x)) per loop, coloured from dark to light
/// with increasing preload (one legend entry per loop up to 8 loops, else the
/// first and last). `path3d`: (u, F, x) points, drawn thick in vermillion.
/// Projection: yaw 0.6, pitch 0.3; the vertical axis is the extension.
pub fn surface(
    path: &Path,
    title: &str,
    family: &[(f64, Vec<(f64, f64)>)],
    path3d: &[(f64, f64, f64)],
) -> Result<()> {
    // Loops as (u, x, F) segments: plotters' 3D y axis is the vertical one. Loops
    // without a finite preload or without drawable points are left out.
    let n_loops = family.len();
    let per_line = (40_000 / (n_loops + 1)).clamp(200, MAX_POINTS);
    let drawable: Vec<(f64, Vec<Line3>)> = family
        .iter()
        .filter(|(f, _)| f.is_finite())
        .map(|(f, pts)| {
            let segs: Vec<Line3> = finite_segments(pts.iter().copied())
                .into_iter()
                .filter(|s| s.len() > 1)
                .map(|s| {
                    decimate(&s, per_line)
                        .into_iter()
                        .map(|(u, x)| (u, x, *f))
                        .collect()
                })
                .collect();
            (*f, segs)
        })
        .filter(|(_, segs)| !segs.is_empty())
        .collect();
    // Colour by preload: dark for the lowest, light for the highest.
    let (f_lo, f_hi) = min_max(drawable.iter().map(|(f, _)| *f)).unwrap_or((0.0, 1.0));
    let loops3: Vec<(f64, RGBColor, Vec<Line3>)> = drawable
        .into_iter()
        .map(|(f, segs)| {
            let t = if f_hi > f_lo {
                (f - f_lo) / (f_hi - f_lo)
            } else {
                0.0
            };
            (f, ramp_color(t), segs)
        })
        .collect();
    let path_segs: Vec<Line3> = {
        // Split at non-finite points, decimate on (u, x) with F carried along.
        let mut segs = vec![];
        let mut cur: Vec<(f64, f64, f64)> = vec![];
        for &(u, f, x) in path3d {
            if u.is_finite() && f.is_finite() && x.is_finite() {
                cur.push((u, x, f));
            } else if !cur.is_empty() {
                segs.push(std::mem::take(&mut cur));
            }
        }
        if !cur.is_empty() {
            segs.push(cur);
        }
        if segs.len() > 200 {
            segs = vec![segs.concat()];
        }
        segs.into_iter()
            .filter(|s| s.len() > 1)
            .map(|s| decimate_by(&s, MAX_POINTS, |p| (p.0, p.1)))
            .collect()
    };

    let all = || {
        loops3
            .iter()
            .flat_map(|(_, _, s)| s.iter().flatten())
            .chain(path_segs.iter().flatten())
    };
    let ur = padded_range(all().map(|p| p.0), 0.02);
    let xr = padded_range(all().map(|p| p.1), 0.02);
    let fr = padded_range(all().map(|p| p.2), 0.02);

    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        // The cube on the left, the legend in a column on the right.
        let mut entries: Vec<(String, ShapeStyle)> = vec![];
        if loops3.len() <= 8 {
            for (f, color, _) in &loops3 {
                entries.push((format!("F = {} N", fmt_sig(*f, 3)), color.stroke_width(2)));
            }
        } else if let (Some(first), Some(last)) = (loops3.first(), loops3.last()) {
            entries.push((
                format!("F = {} N", fmt_sig(first.0, 3)),
                first.1.stroke_width(2),
            ));
            entries.push(("…".into(), TRANSPARENT.stroke_width(2)));
            entries.push((
                format!("F = {} N", fmt_sig(last.0, 3)),
                last.1.stroke_width(2),
            ));
        }
        if !path_segs.is_empty() {
            entries.push(("loop in the stage".into(), PATH_COLOR.stroke_width(3)));
        }
        let (cube_area, legend_area) = if entries.len() > 1 {
            let (w, _) = area.dim_in_pixel();
            let (a, b) = area.split_horizontally(w as i32 - 215);
            (a, Some(b))
        } else {
            (area.clone(), None)
        };
        let mut chart = ChartBuilder::on(&cube_area)
            .margin(0)
            .margin_left(60)
            .margin_top(6)
            .margin_bottom(44)
            .build_cartesian_3d(ur.0..ur.1, xr.0..xr.1, fr.0..fr.1)?;
        chart.with_projection(|mut pb| {
            pb.yaw = 0.6;
            pb.pitch = 0.3;
            pb.scale = 0.9;
            pb.into_matrix()
        });
        let (fu, fx, ff) = (tick_format(ur, 6), tick_format(xr, 6), tick_format(fr, 6));
        chart
            .configure_axes()
            .tick_size(6)
            .label_style((FONT, LABEL_SIZE - 2))
            .light_grid_style(BLACK.mix(0.06))
            .bold_grid_style(BLACK.mix(0.18))
            .axis_panel_style(BLACK.mix(0.04))
            .max_light_lines(2)
            .x_labels(6)
            .y_labels(6)
            .z_labels(6)
            .x_formatter(&fu)
            .y_formatter(&fx)
            .z_formatter(&ff)
            .draw()?;

        for (_, color, segs) in &loops3 {
            for seg in segs {
                chart.draw_series(LineSeries::new(seg.iter().copied(), color.stroke_width(2)))?;
            }
        }
        for seg in &path_segs {
            chart.draw_series(LineSeries::new(
                seg.iter().copied(),
                PATH_COLOR.stroke_width(3),
            ))?;
        }
        if let Some(legend_area) = legend_area {
            draw_legend_column(&legend_area, &entries)?;
        }

        // Axis titles (plotters draws no 3D axis descriptions), next to the edge
        // carrying each axis' ticks: the lowest edge on screen for the horizontal
        // axes, the leftmost one for the vertical axis; offset perpendicularly to
        // the edge, away from the cube centre.
        let coord = chart.plotting_area().as_coord_spec().clone();
        let px = |u: f64, x: f64, f: f64| coord.translate(&(u, x, f));
        let centre = px(
            (ur.0 + ur.1) / 2.0,
            (xr.0 + xr.1) / 2.0,
            (fr.0 + fr.1) / 2.0,
        );
        let mid = |e: &((i32, i32), (i32, i32))| {
            (
                (e.0 .0 + e.1 .0) as f64 / 2.0,
                (e.0 .1 + e.1 .1) as f64 / 2.0,
            )
        };
        let corners =
            |a: (f64, f64), b: (f64, f64)| [(a.0, b.0), (a.0, b.1), (a.1, b.0), (a.1, b.1)];
        let lowest = |edges: Vec<((i32, i32), (i32, i32))>| {
            edges
                .into_iter()
                .max_by(|a, b| mid(a).1.total_cmp(&mid(b).1))
                .unwrap_or(((0, 0), (0, 0)))
        };
        let u_edge = lowest(
            corners(xr, fr)
                .iter()
                .map(|&(x, f)| (px(ur.0, x, f), px(ur.1, x, f)))
                .collect(),
        );
        let f_edge = lowest(
            corners(ur, xr)
                .iter()
                .map(|&(u, x)| (px(u, x, fr.0), px(u, x, fr.1)))
                .collect(),
        );
        let x_edge = corners(ur, fr)
            .iter()
            .map(|&(u, f)| (px(u, xr.0, f), px(u, xr.1, f)))
            .min_by(|a, b| mid(a).0.total_cmp(&mid(b).0))
            .unwrap_or(((0, 0), (0, 0)));
        let style = TextStyle::from((FONT, DESC_SIZE).into_font()).color(&BLACK);
        let put = |edge: ((i32, i32), (i32, i32)), text: &str, dist: f64, vertical: bool| {
            let m = mid(&edge);
            let (ex, ey) = (
                (edge.1 .0 - edge.0 .0) as f64,
                (edge.1 .1 - edge.0 .1) as f64,
            );
            let n = ex.hypot(ey).max(1.0);
            let (mut nx, mut ny) = (-ey / n, ex / n);
            if nx * (m.0 - centre.0 as f64) + ny * (m.1 - centre.1 as f64) < 0.0 {
                (nx, ny) = (-nx, -ny);
            }
            let pos = (
                (m.0 + nx * dist).round() as i32,
                (m.1 + ny * dist).round() as i32,
            );
            let st = style.pos(Pos::new(HPos::Center, VPos::Center));
            let st = if vertical {
                st.transform(FontTransform::Rotate270)
            } else {
                st
            };
            root.draw_text(text, &st, pos)
        };
        put(u_edge, "voltage (V)", 48.0, false)?;
        put(f_edge, "preload (N)", 62.0, false)?;
        put(x_edge, "stack extension (µm)", 62.0, true)?;
        if loops3.is_empty() && path_segs.is_empty() {
            no_data(&cube_area)?;
        }
        Ok(())
    })
}

/// Grouped bar chart: for each group (e.g. "25 N", "50 N", ...) one bar per
/// series (e.g. "PI", "FPI"), with the value written above each bar when there
/// are at most 40 bars. 900x600 px.
///
/// `series[j].1[i]` is the value of series `j` in group `i`; missing or non-finite
/// values leave a gap.
pub fn bars(
    path: &Path,
    title: &str,
    y_label: &str,
    groups: &[String],
    series: &[(&str, Vec<f64>)],
) -> Result<()> {
    let n_groups = groups.len();
    let n_series = series.len();
    let values = || {
        series
            .iter()
            .flat_map(|(_, v)| v.iter().take(n_groups).copied())
            .filter(|v| v.is_finite())
    };
    let (lo, hi) = match min_max(values()) {
        Some((lo, hi)) => (lo.min(0.0), hi.max(0.0)),
        None => (0.0, 1.0),
    };
    let (lo, hi) = if hi - lo > 0.0 && (hi - lo).is_finite() {
        let span = hi - lo;
        (
            if lo < 0.0 { lo - 0.12 * span } else { 0.0 },
            if hi > 0.0 { hi + 0.12 * span } else { 0.0 },
        )
    } else {
        (0.0, 1.0)
    };
    let group_w = 0.8;
    let bar_w = group_w / n_series.max(1) as f64;
    let bar_x = |i: usize, j: usize| {
        let x0 = i as f64 - group_w / 2.0 + j as f64 * bar_w;
        (x0 + 0.06 * bar_w, x0 + 0.94 * bar_w)
    };
    let show_values = n_groups * n_series <= 40;

    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        let xr = (-0.5, n_groups.max(1) as f64 - 0.5);
        let names: Vec<&str> = series.iter().map(|(n, _)| *n).collect();
        let legend = n_series > 1;
        // Bars sampled as points for the legend placement.
        let mut samples = vec![];
        for (j, (_, v)) in series.iter().enumerate() {
            for (i, &y) in v.iter().take(n_groups).enumerate() {
                if !y.is_finite() {
                    continue;
                }
                let (x0, x1) = bar_x(i, j);
                for a in 0..=4 {
                    for b in 0..=20 {
                        let x = x0 + (x1 - x0) * a as f64 / 4.0;
                        let yy = y * b as f64 / 20.0;
                        samples.push((x, yy));
                    }
                }
                // The value label above the bar.
                if show_values {
                    let d = 0.07 * (hi - lo) * y.signum();
                    samples.push(((x0 + x1) / 2.0, y + d));
                }
            }
        }
        let (legend_pos, yr) = if legend {
            let plot = plot_dims(&area, &FULL)?;
            let boxsz = legend_box(&names, LEGEND_SIZE)?;
            let (pos, yr) = place_legend(&samples, xr, (lo, hi), plot, boxsz);
            (Some(pos), yr)
        } else {
            (None, (lo, hi))
        };

        let fy = tick_format(yr, FULL.y_labels);
        let mut chart = ChartBuilder::on(&area)
            .margin(FULL.margin)
            .margin_right(FULL.margin + 14)
            .x_label_area_size(FULL.x_area)
            .y_label_area_size(FULL.y_area)
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_labels(FULL.y_labels)
            .y_label_formatter(&fy)
            .bold_line_style(BLACK.mix(0.12))
            .light_line_style(TRANSPARENT)
            .y_desc(y_label)
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .draw()?;

        let value_style = TextStyle::from((FONT, VALUE_SIZE).into_font()).color(&BLACK);
        for (j, (name, v)) in series.iter().enumerate() {
            let color = series_color(j);
            let rects: Vec<Rectangle<(f64, f64)>> = v
                .iter()
                .take(n_groups)
                .enumerate()
                .filter(|(_, y)| y.is_finite())
                .map(|(i, &y)| {
                    let (x0, x1) = bar_x(i, j);
                    Rectangle::new([(x0, 0.0), (x1, y)], color.filled())
                })
                .collect();
            let anno = chart.draw_series(rects)?;
            anno.label(*name).legend(move |(x, y)| {
                Rectangle::new([(x, y - 6), (x + 20, y + 6)], color.filled())
            });
            if show_values {
                for (i, &y) in v.iter().take(n_groups).enumerate() {
                    if !y.is_finite() {
                        continue;
                    }
                    let (x0, x1) = bar_x(i, j);
                    let (vpos, dy) = if y >= 0.0 {
                        (VPos::Bottom, -4)
                    } else {
                        (VPos::Top, 4)
                    };
                    let st = value_style.pos(Pos::new(HPos::Center, vpos));
                    chart.draw_series(std::iter::once(
                        EmptyElement::at(((x0 + x1) / 2.0, y))
                            + Text::new(fmt_sig(y, 3), (0, dy), st),
                    ))?;
                }
            }
        }
        // The zero baseline.
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(xr.0, 0.0), (xr.1, 0.0)],
            BLACK.stroke_width(1),
        )))?;
        if let Some(pos) = legend_pos {
            draw_legend(&mut chart, pos, LEGEND_SIZE)?;
        }
        // Group names under the x axis, with a tick mark each (absolute pixels).
        let group_style = TextStyle::from((FONT, DESC_SIZE).into_font())
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Top));
        for (i, g) in groups.iter().enumerate() {
            let (x, y) = chart.backend_coord(&(i as f64, yr.0));
            root.draw(&PathElement::new(vec![(x, y), (x, y + 6)], BLACK))?;
            root.draw_text(g, &group_style, (x, y + 10))?;
        }
        if n_groups == 0 || n_series == 0 || values().next().is_none() {
            no_data(chart.plotting_area())?;
        }
        Ok(())
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
    // Colours by series name, in order of first appearance.
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
    let color_of = |name: &str| series_color(names.iter().position(|n| *n == name).unwrap_or(0));
    let n = panels.len();
    let (rows, cols) = match n {
        0 | 1 => (1, 1),
        2 => (1, 2),
        3 => (1, 3),
        4 => (2, 2),
        _ => (n.div_ceil(3), 3),
    };
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

    write_svg(path, (1200, height), |root| {
        let mut area = titled(root, title, TITLE_SIZE)?;
        // Shared legend: one row under the title.
        let mut entries: Vec<(String, ShapeStyle, bool)> = vec![];
        if has_measured {
            entries.push(("measured".into(), DASH_SENTINEL.stroke_width(2), true));
        }
        for (i, name) in names.iter().enumerate() {
            entries.push((name.to_string(), series_color(i).stroke_width(2), false));
        }
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

// ---------------------------------------------------------------------------
// Layout constants
// ---------------------------------------------------------------------------

const FONT: &str = "sans-serif";
/// Colour of the highlighted path of [`surface`].
const PATH_COLOR: RGBColor = PALETTE[1];
const TITLE_SIZE: u32 = 28;
const PANEL_TITLE_SIZE: u32 = 21;
const DESC_SIZE: u32 = 21;
const LABEL_SIZE: u32 = 17;
const LEGEND_SIZE: u32 = 17;
const VALUE_SIZE: u32 = 15;
/// Stand-in colour of the measured series: replaced in the SVG text by black
/// with a dash pattern (plotters' own dashes make one element per dash).
const DASH_SENTINEL: RGBColor = RGBColor(1, 2, 3);
const DASH_SENTINEL_SVG: &str = "stroke=\"#010203\"";
const DASH_SVG: &str = "stroke=\"#000000\" stroke-dasharray=\"7,4\"";

/// Sizes of a 2D chart frame.
struct FrameStyle {
    margin: u32,
    x_area: u32,
    y_area: u32,
    label: u32,
    desc: u32,
    x_labels: usize,
    y_labels: usize,
}

const FULL: FrameStyle = FrameStyle {
    margin: 12,
    x_area: 56,
    y_area: 84,
    label: LABEL_SIZE,
    desc: DESC_SIZE,
    x_labels: 10,
    y_labels: 8,
};

const SMALL: FrameStyle = FrameStyle {
    margin: 8,
    x_area: 46,
    y_area: 68,
    label: 15,
    desc: 17,
    x_labels: 6,
    y_labels: 6,
};

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;
/// A polyline in plotters' 3D coordinates (u, x, F).
type Line3 = Vec<(f64, f64, f64)>;
type Chart2d<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

// ---------------------------------------------------------------------------
// 2D line plots
// ---------------------------------------------------------------------------

/// One drawable series: finite segments, already decimated.
struct Line {
    name: String,
    color: RGBColor,
    measured: bool,
    segs: Vec<Vec<(f64, f64)>>,
}

struct XyPlot<'s> {
    x_label: &'s str,
    y_label: &'s str,
    lines: &'s [Line],
    zero_line: bool,
    legend: bool,
    style: &'s FrameStyle,
}

/// The series of a loops-style plot, models first and measured last (on top).
fn xy_lines(
    x: &[f64],
    measured: Option<&[f64]>,
    series: &[(&str, &[f64])],
    color: impl Fn(usize, &str) -> RGBColor,
    max_points: usize,
) -> Vec<Line> {
    // Budget of ~48 000 points per figure, but at least 500 per series.
    let n_lines = series.len() + usize::from(measured.is_some());
    let max_points = max_points.min((48_000 / n_lines.max(1)).max(500));
    let mut lines: Vec<Line> = series
        .iter()
        .enumerate()
        .map(|(i, (name, y))| Line {
            name: name.to_string(),
            color: color(i, name),
            measured: false,
            segs: xy_segments(x, y, max_points),
        })
        .collect();
    if let Some(y) = measured {
        lines.push(Line {
            name: "measured".into(),
            color: MEASURED_COLOR,
            measured: true,
            segs: xy_segments(x, y, max_points),
        });
    }
    lines
}

fn xy_segments(x: &[f64], y: &[f64], max_points: usize) -> Vec<Vec<(f64, f64)>> {
    let segs = finite_segments(x.iter().copied().zip(y.iter().copied()));
    let total: usize = segs.iter().map(Vec::len).sum();
    segs.into_iter()
        .map(|s| {
            let share = (max_points as f64 * s.len() as f64 / total.max(1) as f64).ceil() as usize;
            decimate(&s, share.max(8))
        })
        .collect()
}

/// Splits at non-finite points; many tiny pieces are joined into one line instead
/// (a NaN every other sample would otherwise make thousands of SVG elements).
fn finite_segments(pts: impl Iterator<Item = (f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    let mut segs: Vec<Vec<(f64, f64)>> = vec![];
    let mut cur = vec![];
    for (a, b) in pts {
        if a.is_finite() && b.is_finite() {
            cur.push((a, b));
        } else if !cur.is_empty() {
            segs.push(std::mem::take(&mut cur));
        }
    }
    if !cur.is_empty() {
        segs.push(cur);
    }
    if segs.len() > 200 {
        segs = vec![segs.concat()];
    }
    segs
}

fn decimate(pts: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    decimate_by(pts, max, |p| *p)
}

/// Min/max decimation: per bucket, keeps the points of extreme first and second
/// coordinate (in their original order), plus the very first and last points.
fn decimate_by<T: Copy>(pts: &[T], max: usize, key: impl Fn(&T) -> (f64, f64)) -> Vec<T> {
    let max = max.max(8);
    if pts.len() <= max {
        return pts.to_vec();
    }
    let buckets = (max - 2) / 4;
    let k = pts.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(max);
    out.push(pts[0]);
    let mut last_idx = 0;
    for (c, chunk) in pts.chunks(k).enumerate() {
        let base = c * k;
        let mut idx = [0usize; 4];
        let mut val = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for (i, p) in chunk.iter().enumerate() {
            let (a, b) = key(p);
            if a < val[0] {
                (val[0], idx[0]) = (a, i);
            }
            if a > val[1] {
                (val[1], idx[1]) = (a, i);
            }
            if b < val[2] {
                (val[2], idx[2]) = (b, i);
            }
            if b > val[3] {
                (val[3], idx[3]) = (b, i);
            }
        }
        idx.sort_unstable();
        for i in idx {
            let g = base + i;
            if g > last_idx {
                out.push(pts[g]);
                last_idx = g;
            }
        }
    }
    if last_idx != pts.len() - 1 {
        out.push(pts[pts.len() - 1]);
    }
    out
}

fn draw_xy(area: &Area, p: &XyPlot) -> Result<()> {
    let st = p.style;
    let pts = || p.lines.iter().flat_map(|l| l.segs.iter().flatten());
    let has_data = pts().next().is_some();
    let xr = padded_range(pts().map(|q| q.0), 0.02);
    let ys = pts().map(|q| q.1);
    let yr = if p.zero_line {
        padded_range(ys.chain(std::iter::once(0.0)), 0.05)
    } else {
        padded_range(ys, 0.05)
    };

    let drawn: Vec<&Line> = p.lines.iter().filter(|l| !l.segs.is_empty()).collect();
    let legend = p.legend && drawn.len() > 1;
    let (legend_pos, yr) = if legend {
        let plot = plot_dims(area, st)?;
        let names: Vec<&str> = drawn.iter().map(|l| l.name.as_str()).collect();
        let boxsz = legend_box(&names, LEGEND_SIZE)?;
        let samples = densify(p.lines, xr, yr);
        let (pos, yr) = place_legend(&samples, xr, yr, plot, boxsz);
        (Some(pos), yr)
    } else {
        (None, yr)
    };

    let mut chart = ChartBuilder::on(area)
        .margin(st.margin)
        .margin_right(st.margin + 14)
        .x_label_area_size(st.x_area)
        .y_label_area_size(st.y_area)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    let (fx, fy) = (tick_format(xr, st.x_labels), tick_format(yr, st.y_labels));
    chart
        .configure_mesh()
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(BLACK.mix(0.04))
        .max_light_lines(4)
        .x_labels(st.x_labels)
        .y_labels(st.y_labels)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_desc(p.x_label)
        .y_desc(p.y_label)
        .label_style((FONT, st.label))
        .axis_desc_style((FONT, st.desc))
        .draw()?;

    if p.zero_line && yr.0 <= 0.0 && yr.1 >= 0.0 {
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(xr.0, 0.0), (xr.1, 0.0)],
            BLACK.mix(0.6).stroke_width(1),
        )))?;
    }
    for line in &drawn {
        let style = if line.measured {
            DASH_SENTINEL.stroke_width(2)
        } else {
            line.color.stroke_width(2)
        };
        for (j, seg) in line.segs.iter().enumerate() {
            let anno = if let [p] = seg.as_slice() {
                // An isolated point: a dot, or it would not show at all.
                let dot = if line.measured {
                    MEASURED_COLOR
                } else {
                    line.color
                };
                chart.draw_series(std::iter::once(Circle::new(*p, 2, dot.filled())))?
            } else {
                chart.draw_series(LineSeries::new(seg.iter().copied(), style))?
            };
            if j == 0 {
                anno.label(line.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 22, y)], style));
            }
        }
    }
    if let Some(pos) = legend_pos {
        draw_legend(&mut chart, pos, LEGEND_SIZE)?;
    }
    if !has_data {
        no_data(chart.plotting_area())?;
    }
    Ok(())
}

/// Points along every line, at most ~0.5 % of the axes apart, for the legend
/// placement.
fn densify(lines: &[Line], xr: (f64, f64), yr: (f64, f64)) -> Vec<(f64, f64)> {
    let (sx, sy) = (xr.1 - xr.0, yr.1 - yr.0);
    let mut out = vec![];
    for seg in lines.iter().flat_map(|l| &l.segs) {
        for w in seg.windows(2) {
            let (a, b) = (w[0], w[1]);
            let d = ((b.0 - a.0) / sx).hypot((b.1 - a.1) / sy);
            let n = ((d / 0.005).ceil() as usize).clamp(1, 200);
            for k in 0..n {
                let t = k as f64 / n as f64;
                out.push((a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t));
            }
        }
        if let Some(&l) = seg.last() {
            out.push(l);
        }
    }
    out
}

/// Pixel size of the plotting area a [`FrameStyle`] leaves in `area`.
fn plot_dims(area: &Area, st: &FrameStyle) -> Result<(i32, i32)> {
    let chart = ChartBuilder::on(area)
        .margin(st.margin)
        .margin_right(st.margin + 14)
        .x_label_area_size(st.x_area)
        .y_label_area_size(st.y_area)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)?;
    let (w, h) = chart.plotting_area().dim_in_pixel();
    Ok((w as i32, h as i32))
}

/// Legend box size as plotters lays it out (legend area 30 px, margin 10 px).
fn legend_box(names: &[&str], size: u32) -> Result<(i32, i32)> {
    let mut text = MultiLineText::<(i32, i32), &str>::new((0, 0), (FONT, size));
    for n in names {
        text.push_line(*n);
    }
    let (w, h) = text
        .estimate_dimension()
        .map_err(|e| anyhow!("legend layout: {e:?}"))?;
    // Real fonts run a little wider than plotters' estimate: keep some slack.
    Ok((w + w / 8 + 30 + 20, h + 20))
}

const LEGEND_INSET: i32 = 8;

/// Picks the legend corner that covers the fewest data points; if every corner
/// covers some, raises the top of the y range to make a free band for it.
/// Returns the legend position (pixels in the plotting area) and the y range.
fn place_legend(
    samples: &[(f64, f64)],
    xr: (f64, f64),
    yr: (f64, f64),
    plot: (i32, i32),
    boxsz: (i32, i32),
) -> ((i32, i32), (f64, f64)) {
    let (w, h) = (plot.0.max(1), plot.1.max(1));
    let (bw, bh) = boxsz;
    let left = LEGEND_INSET;
    let right = (w - bw - LEGEND_INSET).max(LEGEND_INSET);
    let top = LEGEND_INSET;
    let bottom = (h - bh - LEGEND_INSET).max(LEGEND_INSET);
    let candidates = [(left, top), (right, top), (right, bottom), (left, bottom)];
    let count = |pos: (i32, i32), yr: (f64, f64)| {
        let (x0, y0) = (pos.0 as f64 - 4.0, pos.1 as f64 - 4.0);
        let (x1, y1) = (x0 + bw as f64 + 8.0, y0 + bh as f64 + 8.0);
        samples
            .iter()
            .filter(|(x, y)| {
                let px = (x - xr.0) / (xr.1 - xr.0) * w as f64;
                let py = (yr.1 - y) / (yr.1 - yr.0) * h as f64;
                px >= x0 && px <= x1 && py >= y0 && py <= y1
            })
            .count()
    };
    let (best, n) = candidates
        .iter()
        .map(|&c| (c, count(c, yr)))
        .min_by_key(|&(_, n)| n)
        .unwrap_or(((left, top), 0));
    if n == 0 {
        return (best, yr);
    }
    let band = (bh + 2 * LEGEND_INSET) as f64;
    if band > 0.6 * h as f64 {
        return (best, yr);
    }
    let hi = yr.0 + (yr.1 - yr.0) * h as f64 / (h as f64 - band);
    let yr2 = (yr.0, hi);
    let (best, _) = [(left, top), (right, top)]
        .iter()
        .map(|&c| (c, count(c, yr2)))
        .min_by_key(|&(_, n)| n)
        .unwrap_or(((left, top), 0));
    (best, yr2)
}

fn draw_legend<'a, 'b: 'a>(chart: &mut Chart2d<'a, 'b>, pos: (i32, i32), size: u32) -> Result<()> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::Coordinate(pos.0, pos.1))
        .label_font((FONT, size))
        .legend_area_size(30)
        .margin(10)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

/// A one-row legend centred in `area`: (label, line style, measured?).
fn draw_legend_row(area: &Area, entries: &[(String, ShapeStyle, bool)]) -> Result<()> {
    let font = TextStyle::from((FONT, LEGEND_SIZE).into_font())
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let widths: Vec<i32> = entries
        .iter()
        .map(|(name, _, _)| {
            let (w, _) = area.estimate_text_size(name, &font).unwrap_or((0, 0));
            w as i32 + w as i32 / 8 + 30 + 24
        })
        .collect();
    let total: i32 = widths.iter().sum();
    let (aw, ah) = area.dim_in_pixel();
    let mut x = ((aw as i32 - total) / 2).max(4);
    let y = ah as i32 / 2;
    for ((name, style, _), w) in entries.iter().zip(widths) {
        area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], *style))?;
        area.draw_text(name, &font, (x + 30, y))?;
        x += w;
    }
    Ok(())
}

/// A legend column, vertically centred in `area`, in a framed box.
fn draw_legend_column(area: &Area, entries: &[(String, ShapeStyle)]) -> Result<()> {
    let font = TextStyle::from((FONT, LEGEND_SIZE).into_font())
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let line_h = 26;
    let text_w = entries
        .iter()
        .map(|(n, _)| area.estimate_text_size(n, &font).map(|s| s.0).unwrap_or(0) as i32)
        .max()
        .unwrap_or(0);
    let (aw, ah) = area.dim_in_pixel();
    let (bw, bh) = (
        text_w + text_w / 8 + 30 + 24,
        line_h * entries.len() as i32 + 12,
    );
    let x0 = ((aw as i32 - bw) / 2).max(2);
    let y0 = ((ah as i32 - bh) / 2).max(2);
    area.draw(&Rectangle::new(
        [(x0, y0), (x0 + bw, y0 + bh)],
        BLACK.mix(0.4).stroke_width(1),
    ))?;
    for (k, (name, style)) in entries.iter().enumerate() {
        let y = y0 + 6 + line_h * k as i32 + line_h / 2;
        area.draw(&PathElement::new(vec![(x0 + 10, y), (x0 + 34, y)], *style))?;
        area.draw_text(name, &font, (x0 + 42, y))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Shared helpers
// ---------------------------------------------------------------------------

/// Renders into a string, applies the measured-line dash, writes `path`.
fn write_svg(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area) -> Result<()>) -> Result<()> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    let svg = buf.replace(DASH_SENTINEL_SVG, DASH_SVG);
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating directory {}", dir.display()))?;
    }
    std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))
}

/// Draws a title at the top of `area` and returns the rest.
fn titled<'a>(area: &Area<'a>, title: &str, size: u32) -> Result<Area<'a>> {
    if title.is_empty() {
        return Ok(area.clone());
    }
    Ok(area.titled(title, (FONT, size))?)
}

fn no_data<CT: CoordTranslate>(area: &DrawingArea<SVGBackend, CT>) -> Result<()> {
    let area = area.strip_coord_spec();
    let (w, h) = area.dim_in_pixel();
    let grey = BLACK.mix(0.5);
    let st = TextStyle::from((FONT, DESC_SIZE).into_font())
        .color(&grey)
        .pos(Pos::new(HPos::Center, VPos::Center));
    area.draw_text("no data", &st, (w as i32 / 2, h as i32 / 2))?;
    Ok(())
}

fn min_max(v: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    v.filter(|x| x.is_finite()).fold(None, |acc, x| match acc {
        None => Some((x, x)),
        Some((lo, hi)) => Some((lo.min(x), hi.max(x))),
    })
}

/// Finite range of the values with `frac` of the span added on each side; all
/// equal values get a widened range, no values give 0..1.
fn padded_range(v: impl Iterator<Item = f64>, frac: f64) -> (f64, f64) {
    let Some((lo, hi)) = min_max(v) else {
        return (0.0, 1.0);
    };
    let span = hi - lo;
    if !span.is_finite() {
        return (lo.max(-f64::MAX / 4.0), hi.min(f64::MAX / 4.0));
    }
    if span <= 1e-12 * lo.abs().max(hi.abs()) || span == 0.0 {
        let w = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        return (lo - w, hi + w);
    }
    (lo - frac * span, hi + frac * span)
}

/// Colour at `t` in 0..=1 along a dark-violet → green ramp (viridis-like, without
/// the pale yellow end that vanishes on white).
fn ramp_color(t: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (53.0, 183.0, 121.0),
        (144.0, 200.0, 50.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let s = t * (STOPS.len() - 1) as f64;
    let k = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - k as f64;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    let mix = |x: f64, y: f64| (x + (y - x) * f).round().clamp(0.0, 255.0) as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Tick label formatter for an axis over `range` with at most `n` ticks: the
/// decimals of plotters' tick step (1, 2 or 5 × 10^k), the same for every tick.
fn tick_format(range: (f64, f64), n: usize) -> impl Fn(&f64) -> String {
    let span = (range.1 - range.0).abs();
    let mut step = if span > 0.0 && span.is_finite() {
        let raw = span / n.max(2) as f64;
        10f64.powf(raw.log10().floor())
    } else {
        1.0
    };
    for _ in 0..40 {
        if (span / step).floor() + 1.0 <= n as f64 || !step.is_finite() {
            break;
        }
        let e = 10f64.powf(step.log10().floor());
        let m = (step / e).round();
        step = if m < 1.5 {
            2.0 * e
        } else if m < 3.5 {
            5.0 * e
        } else {
            10.0 * e
        };
    }
    let big = range.0.abs().max(range.1.abs());
    let scientific = big >= 1e7 || (step < 1e-5 && step > 0.0);
    let decimals = if step > 0.0 && step.is_finite() {
        (-(step.log10() + 1e-9).floor()).max(0.0) as usize
    } else {
        0
    };
    move |v: &f64| {
        if scientific {
            return format!("{v:.2e}");
        }
        // More decimals only if plotters picked a finer step than estimated.
        let mut d = decimals;
        while d < decimals + 3 && (v - round_to(*v, d)).abs() > step * 1e-3 {
            d += 1;
        }
        let s = format!("{v:.d$}");
        if s.trim_start_matches('-')
            .chars()
            .all(|c| c == '0' || c == '.')
        {
            s.trim_start_matches('-').to_string()
        } else {
            s
        }
    }
}

fn round_to(v: f64, d: usize) -> f64 {
    let p = 10f64.powi(d as i32);
    (v * p).round() / p
}

/// `v` with `sig` significant digits, without trailing zeros.
fn fmt_sig(v: f64, sig: usize) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".into();
    }
    let mag = v.abs().log10().floor() as i32;
    if !(-4..=6).contains(&mag) {
        return format!("{:.*e}", sig.saturating_sub(1), v);
    }
    let decimals = (sig as i32 - 1 - mag).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_keeps_ends_and_bound() {
        let pts: Vec<(f64, f64)> = (0..70_000)
            .map(|i| (i as f64, (i as f64 * 0.01).sin()))
            .collect();
        let d = decimate(&pts, MAX_POINTS);
        assert!(d.len() <= MAX_POINTS);
        assert_eq!(d[0], pts[0]);
        assert_eq!(*d.last().unwrap(), *pts.last().unwrap());
        let (lo, hi) = min_max(d.iter().map(|p| p.1)).unwrap();
        assert!(lo < -0.999 && hi > 0.999);
    }

    #[test]
    fn ranges() {
        assert_eq!(padded_range([].into_iter(), 0.1), (0.0, 1.0));
        assert_eq!(padded_range([f64::NAN].into_iter(), 0.1), (0.0, 1.0));
        assert_eq!(padded_range([0.0, 0.0].into_iter(), 0.1), (-1.0, 1.0));
        let (lo, hi) = padded_range([5.0, 5.0].into_iter(), 0.1);
        assert!(lo < 5.0 && hi > 5.0);
        assert_eq!(fmt_sig(12.345, 3), "12.3");
        assert_eq!(fmt_sig(0.5, 3), "0.5");
        assert_eq!(fmt_sig(1234.0, 3), "1234");
    }
}
