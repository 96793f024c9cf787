//! Drawing helpers shared by the figures: the SVG file itself, titles, 2D chart
//! frames and the loops-style line plot drawn in them.

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::canvas::{frame_chart, Area, Chart2d};
use super::legend::{draw_legend, legend_layout};
use super::series::{densify, padded_range, Line};
use super::style::{
    text_style, tick_format, FrameStyle, DASH_SENTINEL, DASH_SENTINEL_SVG, DASH_SVG, DESC_SIZE,
    FONT, LEGEND_SIZE,
};
use super::MEASURED_COLOR;

/// A loops-style line plot: what [`draw_xy`] draws.
pub(super) struct XyPlot<'s> {
    pub(super) x_label: &'s str,
    pub(super) y_label: &'s str,
    pub(super) lines: &'s [Line],
    /// Draw a line at y = 0 and keep 0 in the y range.
    pub(super) zero_line: bool,
    /// Draw a legend (when more than one line is drawn).
    pub(super) legend: bool,
    pub(super) style: &'s FrameStyle,
}

/// Draws `p` in `area`: frame, grid, lines (measured dashed), legend.
pub(super) fn draw_xy(area: &Area, p: &XyPlot) -> Result<()> {
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
    let (legend_pos, yr) = if p.legend && drawn.len() > 1 {
        let names: Vec<&str> = drawn.iter().map(|l| l.name.as_str()).collect();
        let samples = densify(p.lines, xr, yr);
        let (pos, yr) = legend_layout(area, st, &names, &samples, xr, yr)?;
        (Some(pos), yr)
    } else {
        (None, yr)
    };

    let mut chart = frame_chart(area, st, xr, yr)?;
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
        draw_zero_line(&mut chart, xr, BLACK.mix(0.6).stroke_width(1))?;
    }
    for line in &drawn {
        draw_line(&mut chart, line)?;
    }
    if let Some(pos) = legend_pos {
        draw_legend(&mut chart, pos, LEGEND_SIZE)?;
    }
    if !has_data {
        no_data(chart.plotting_area())?;
    }
    Ok(())
}

/// Draws the segments of `line` (an isolated point as a dot) and labels the
/// first one for the legend.
fn draw_line(chart: &mut Chart2d, line: &Line) -> Result<()> {
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
    Ok(())
}

/// Draws a horizontal line at y = 0 across `xr`.
pub(super) fn draw_zero_line(chart: &mut Chart2d, xr: (f64, f64), style: ShapeStyle) -> Result<()> {
    chart.draw_series(std::iter::once(PathElement::new(
        vec![(xr.0, 0.0), (xr.1, 0.0)],
        style,
    )))?;
    Ok(())
}

/// Renders into a string, applies the measured-line dash, writes `path` atomically
/// ([`crate::output::write_atomic`]: its folder is created, a failure leaves no
/// partial file).
pub(super) fn write_svg(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area) -> Result<()>,
) -> Result<()> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    let svg = buf.replace(DASH_SENTINEL_SVG, DASH_SVG);
    crate::output::write_atomic(path, svg.as_bytes())
}

/// Draws a title at the top of `area` and returns the rest.
pub(super) fn titled<'a>(area: &Area<'a>, title: &str, size: u32) -> Result<Area<'a>> {
    if title.is_empty() {
        return Ok(area.clone());
    }
    Ok(area.titled(title, (FONT, size))?)
}

/// Writes "no data" in grey in the middle of `area`.
pub(super) fn no_data<CT: CoordTranslate>(area: &DrawingArea<SVGBackend, CT>) -> Result<()> {
    let area = area.strip_coord_spec();
    let (w, h) = area.dim_in_pixel();
    let grey = BLACK.mix(0.5);
    let st = text_style(DESC_SIZE)
        .color(&grey)
        .pos(Pos::new(HPos::Center, VPos::Center));
    area.draw_text("no data", &st, (w as i32 / 2, h as i32 / 2))?;
    Ok(())
}
