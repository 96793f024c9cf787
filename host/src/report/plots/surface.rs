//! The paper's Fig. 12: a family of hysteresis loops at constant preloads and a
//! path crossing them, drawn in a 3D cube.

use std::path::Path;

use anyhow::Result;
use plotters::coord::cartesian::Cartesian3d;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::canvas::Area;
use super::frame::{no_data, titled, write_svg};
use super::legend::{draw_legend_column, LegendEntry};
use super::series::{decimate, decimate_by, finite_segments, min_max, padded_range, split_finite};
use super::style::{
    fmt_sig, ramp_color, text_style, tick_format, DESC_SIZE, FONT, LABEL_SIZE, PATH_COLOR,
    TITLE_SIZE,
};
use super::MAX_POINTS;

/// A polyline in plotters' 3D coordinates (u, x, F).
type Line3 = Vec<(f64, f64, f64)>;
/// Projection of plotters' 3D coordinates (u, x, F) to pixels.
type Coord3 = Cartesian3d<RangedCoordf64, RangedCoordf64, RangedCoordf64>;
/// An edge of the cube on screen: its two ends in pixels.
type Edge = ((i32, i32), (i32, i32));

/// One loop of the family, ready to draw.
struct Loop3 {
    /// Preload (N).
    preload: f64,
    color: RGBColor,
    segs: Vec<Line3>,
}

/// Axis ranges of the cube: voltage u, extension x, preload F.
struct Ranges3 {
    u: (f64, f64),
    x: (f64, f64),
    f: (f64, f64),
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
    let loops3 = loop_family(family);
    let path_segs = path_segments(path3d);
    let all = || {
        loops3
            .iter()
            .flat_map(|l| l.segs.iter().flatten())
            .chain(path_segs.iter().flatten())
    };
    let ranges = Ranges3 {
        u: padded_range(all().map(|p| p.0), 0.02),
        x: padded_range(all().map(|p| p.1), 0.02),
        f: padded_range(all().map(|p| p.2), 0.02),
    };
    let entries = legend_entries(&loops3, !path_segs.is_empty());

    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        // The cube on the left, the legend in a column on the right.
        let (cube_area, legend_area) = if entries.len() > 1 {
            let (w, _) = area.dim_in_pixel();
            let (a, b) = area.split_horizontally(w as i32 - 215);
            (a, Some(b))
        } else {
            (area.clone(), None)
        };
        let coord = draw_cube(&cube_area, &ranges, &loops3, &path_segs)?;
        if let Some(legend_area) = legend_area {
            draw_legend_column(&legend_area, &entries)?;
        }
        draw_axis_titles(root, &coord, &ranges)?;
        if loops3.is_empty() && path_segs.is_empty() {
            no_data(&cube_area)?;
        }
        Ok(())
    })
}

/// The loops as (u, x, F) segments (plotters' 3D y axis is the vertical one),
/// coloured by preload: dark for the lowest, light for the highest. Loops without
/// a finite preload or without drawable points are left out.
fn loop_family(family: &[(f64, Vec<(f64, f64)>)]) -> Vec<Loop3> {
    let per_line = (40_000 / (family.len() + 1)).clamp(200, MAX_POINTS);
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
    let (f_lo, f_hi) = min_max(drawable.iter().map(|(f, _)| *f)).unwrap_or((0.0, 1.0));
    drawable
        .into_iter()
        .map(|(preload, segs)| {
            let t = if f_hi > f_lo {
                (preload - f_lo) / (f_hi - f_lo)
            } else {
                0.0
            };
            Loop3 {
                preload,
                color: ramp_color(t),
                segs,
            }
        })
        .collect()
}

/// The highlighted path as (u, x, F) segments: split at non-finite points,
/// decimated on (u, x) with F carried along.
fn path_segments(path3d: &[(f64, f64, f64)]) -> Vec<Line3> {
    let finite = |p: &(f64, f64, f64)| p.0.is_finite() && p.1.is_finite() && p.2.is_finite();
    split_finite(path3d.iter().map(|&(u, f, x)| (u, x, f)), finite)
        .into_iter()
        .filter(|s| s.len() > 1)
        .map(|s| decimate_by(&s, MAX_POINTS, |p| (p.0, p.1)))
        .collect()
}

/// Legend entries: one per loop up to 8 loops, else the first and the last; then
/// the path, if any.
fn legend_entries(loops3: &[Loop3], has_path: bool) -> Vec<LegendEntry> {
    let entry = |l: &Loop3| {
        (
            format!("F = {} N", fmt_sig(l.preload, 3)),
            l.color.stroke_width(2),
        )
    };
    let mut entries: Vec<LegendEntry> = vec![];
    if loops3.len() <= 8 {
        entries.extend(loops3.iter().map(entry));
    } else if let (Some(first), Some(last)) = (loops3.first(), loops3.last()) {
        entries.push(entry(first));
        entries.push(("…".into(), TRANSPARENT.stroke_width(2)));
        entries.push(entry(last));
    }
    if has_path {
        entries.push(("loop in the stage".into(), PATH_COLOR.stroke_width(3)));
    }
    entries
}

/// Draws the cube (axes, grid, ticks), the loops and the path in `area`;
/// returns the projection used.
fn draw_cube(area: &Area, r: &Ranges3, loops3: &[Loop3], path_segs: &[Line3]) -> Result<Coord3> {
    let mut chart = ChartBuilder::on(area)
        .margin(0)
        .margin_left(60)
        .margin_top(6)
        .margin_bottom(44)
        .build_cartesian_3d(r.u.0..r.u.1, r.x.0..r.x.1, r.f.0..r.f.1)?;
    chart.with_projection(|mut pb| {
        pb.yaw = 0.6;
        pb.pitch = 0.3;
        pb.scale = 0.9;
        pb.into_matrix()
    });
    let (fu, fx, ff) = (
        tick_format(r.u, 6),
        tick_format(r.x, 6),
        tick_format(r.f, 6),
    );
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
    let loop_lines = loops3
        .iter()
        .flat_map(|l| l.segs.iter().map(|s| (s, l.color.stroke_width(2))));
    let path_lines = path_segs.iter().map(|s| (s, PATH_COLOR.stroke_width(3)));
    for (seg, style) in loop_lines.chain(path_lines) {
        chart.draw_series(LineSeries::new(seg.iter().copied(), style))?;
    }
    Ok(chart.plotting_area().as_coord_spec().clone())
}

/// Axis titles (plotters draws no 3D axis descriptions), next to the edge
/// carrying each axis' ticks: the lowest edge on screen for the horizontal axes,
/// the leftmost one for the vertical axis; offset perpendicularly to the edge,
/// away from the cube centre.
fn draw_axis_titles(root: &Area, coord: &Coord3, r: &Ranges3) -> Result<()> {
    let px = |u: f64, x: f64, f: f64| coord.translate(&(u, x, f));
    let centre = px(
        (r.u.0 + r.u.1) / 2.0,
        (r.x.0 + r.x.1) / 2.0,
        (r.f.0 + r.f.1) / 2.0,
    );
    let lowest = |edges: Vec<Edge>| {
        edges
            .into_iter()
            .max_by(|a, b| mid(a).1.total_cmp(&mid(b).1))
            .unwrap_or(((0, 0), (0, 0)))
    };
    let u_edge = lowest(
        corners(r.x, r.f)
            .iter()
            .map(|&(x, f)| (px(r.u.0, x, f), px(r.u.1, x, f)))
            .collect(),
    );
    let f_edge = lowest(
        corners(r.u, r.x)
            .iter()
            .map(|&(u, x)| (px(u, x, r.f.0), px(u, x, r.f.1)))
            .collect(),
    );
    let x_edge = corners(r.u, r.f)
        .iter()
        .map(|&(u, f)| (px(u, r.x.0, f), px(u, r.x.1, f)))
        .min_by(|a, b| mid(a).0.total_cmp(&mid(b).0))
        .unwrap_or(((0, 0), (0, 0)));
    let put =
        |edge, text, dist, vertical| draw_edge_title(root, centre, edge, text, dist, vertical);
    put(u_edge, "voltage (V)", 48.0, false)?;
    put(f_edge, "preload (N)", 62.0, false)?;
    put(x_edge, "stack extension (µm)", 62.0, true)
}

/// Midpoint of an edge on screen.
fn mid(e: &Edge) -> (f64, f64) {
    (
        (e.0 .0 + e.1 .0) as f64 / 2.0,
        (e.0 .1 + e.1 .1) as f64 / 2.0,
    )
}

/// The four combinations of the ends of two ranges.
fn corners(a: (f64, f64), b: (f64, f64)) -> [(f64, f64); 4] {
    [(a.0, b.0), (a.0, b.1), (a.1, b.0), (a.1, b.1)]
}

/// Writes `text` centred `dist` px from the middle of `edge`, perpendicular to
/// it and away from `centre`; rotated to run upwards if `vertical`.
fn draw_edge_title(
    root: &Area,
    centre: (i32, i32),
    edge: Edge,
    text: &str,
    dist: f64,
    vertical: bool,
) -> Result<()> {
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
    let st = text_style(DESC_SIZE).pos(Pos::new(HPos::Center, VPos::Center));
    let st = if vertical {
        st.transform(FontTransform::Rotate270)
    } else {
        st
    };
    root.draw_text(text, &st, pos)?;
    Ok(())
}
