//! The canvas of a 2D figure: the SVG drawing area and a framed chart on it.

use anyhow::Result;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::FrameStyle;

/// A drawing area of the SVG in pixels.
pub(super) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;
/// A 2D chart with f64 axes.
pub(super) type Chart2d<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A 2D chart over `xr` × `yr` in `area`, framed as `st` says.
pub(super) fn frame_chart<'a, 'b>(
    area: &'a Area<'b>,
    st: &FrameStyle,
    xr: (f64, f64),
    yr: (f64, f64),
) -> Result<Chart2d<'a, 'b>> {
    Ok(ChartBuilder::on(area)
        .margin(st.margin)
        .margin_right(st.margin + 14)
        .x_label_area_size(st.x_area)
        .y_label_area_size(st.y_area)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?)
}

/// Pixel size of the plotting area a [`FrameStyle`] leaves in `area`.
pub(super) fn plot_dims(area: &Area, st: &FrameStyle) -> Result<(i32, i32)> {
    let chart = frame_chart(area, st, (0.0, 1.0), (0.0, 1.0))?;
    let (w, h) = chart.plotting_area().dim_in_pixel();
    Ok((w as i32, h as i32))
}
