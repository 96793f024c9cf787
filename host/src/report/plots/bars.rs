//! Grouped bar charts.

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::canvas::{frame_chart, Area, Chart2d};
use super::frame::{draw_zero_line, no_data, titled, write_svg};
use super::legend::{draw_legend, legend_layout};
use super::series::min_max;
use super::series_color;
use super::style::{
    fmt_sig, text_style, tick_format, DESC_SIZE, FONT, FULL, LABEL_SIZE, LEGEND_SIZE, TITLE_SIZE,
    VALUE_SIZE,
};

/// Width of a group of bars on the x axis (the groups are 1 apart).
const GROUP_W: f64 = 0.8;

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
    let b = Bars::new(groups.len(), series);
    let (lo, hi) = b.value_range();

    write_svg(path, (900, 600), |root| {
        let area = titled(root, title, TITLE_SIZE)?;
        let xr = (-0.5, b.n_groups.max(1) as f64 - 0.5);
        let (legend_pos, yr) = if series.len() > 1 {
            let names: Vec<&str> = series.iter().map(|(n, _)| *n).collect();
            let samples = b.legend_samples((lo, hi));
            let (pos, yr) = legend_layout(&area, &FULL, &names, &samples, xr, (lo, hi))?;
            (Some(pos), yr)
        } else {
            (None, (lo, hi))
        };

        let fy = tick_format(yr, FULL.y_labels);
        let mut chart = frame_chart(&area, &FULL, xr, yr)?;
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

        for j in 0..series.len() {
            b.draw_series(&mut chart, j)?;
        }
        // The zero baseline.
        draw_zero_line(&mut chart, xr, BLACK.stroke_width(1))?;
        if let Some(pos) = legend_pos {
            draw_legend(&mut chart, pos, LEGEND_SIZE)?;
        }
        draw_group_names(root, &chart, groups, yr.0)?;
        if b.n_groups == 0 || series.is_empty() || b.values().next().is_none() {
            no_data(chart.plotting_area())?;
        }
        Ok(())
    })
}

/// The bars of [`bars`]: values and their layout.
struct Bars<'s> {
    series: &'s [(&'s str, Vec<f64>)],
    n_groups: usize,
    /// Width of one bar slot (the bar itself is a little narrower).
    bar_w: f64,
    /// Write the values above the bars.
    show_values: bool,
}

impl<'s> Bars<'s> {
    fn new(n_groups: usize, series: &'s [(&'s str, Vec<f64>)]) -> Self {
        let n_series = series.len();
        Self {
            series,
            n_groups,
            bar_w: GROUP_W / n_series.max(1) as f64,
            show_values: n_groups * n_series <= 40,
        }
    }

    /// Left and right end of the bar of series `j` in group `i`.
    fn bar_x(&self, i: usize, j: usize) -> (f64, f64) {
        let x0 = i as f64 - GROUP_W / 2.0 + j as f64 * self.bar_w;
        (x0 + 0.06 * self.bar_w, x0 + 0.94 * self.bar_w)
    }

    /// (group, value) of the finite values of series `j`.
    fn finite(&self, j: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.series[j]
            .1
            .iter()
            .take(self.n_groups)
            .copied()
            .enumerate()
            .filter(|(_, y)| y.is_finite())
    }

    /// Every finite value drawn.
    fn values(&self) -> impl Iterator<Item = f64> + '_ {
        self.series
            .iter()
            .flat_map(|(_, v)| v.iter().take(self.n_groups).copied())
            .filter(|v| v.is_finite())
    }

    /// The y range: the values and 0, with 12 % of the span of room beyond the
    /// bars (0..1 when there is nothing to show).
    fn value_range(&self) -> (f64, f64) {
        let (lo, hi) = match min_max(self.values()) {
            Some((lo, hi)) => (lo.min(0.0), hi.max(0.0)),
            None => (0.0, 1.0),
        };
        if hi - lo > 0.0 && (hi - lo).is_finite() {
            let span = hi - lo;
            (
                if lo < 0.0 { lo - 0.12 * span } else { 0.0 },
                if hi > 0.0 { hi + 0.12 * span } else { 0.0 },
            )
        } else {
            (0.0, 1.0)
        }
    }

    /// The bars (and value labels) sampled as points for the legend placement,
    /// with `yr` the y range.
    fn legend_samples(&self, yr: (f64, f64)) -> Vec<(f64, f64)> {
        let mut samples = vec![];
        for j in 0..self.series.len() {
            for (i, y) in self.finite(j) {
                let (x0, x1) = self.bar_x(i, j);
                for a in 0..=4 {
                    for b in 0..=20 {
                        let x = x0 + (x1 - x0) * a as f64 / 4.0;
                        let yy = y * b as f64 / 20.0;
                        samples.push((x, yy));
                    }
                }
                // The value label above the bar.
                if self.show_values {
                    let d = 0.07 * (yr.1 - yr.0) * y.signum();
                    samples.push(((x0 + x1) / 2.0, y + d));
                }
            }
        }
        samples
    }

    /// Draws the bars of series `j` (labelled for the legend) and their values.
    fn draw_series(&self, chart: &mut Chart2d, j: usize) -> Result<()> {
        let color = series_color(j);
        let rects: Vec<Rectangle<(f64, f64)>> = self
            .finite(j)
            .map(|(i, y)| {
                let (x0, x1) = self.bar_x(i, j);
                Rectangle::new([(x0, 0.0), (x1, y)], color.filled())
            })
            .collect();
        let anno = chart.draw_series(rects)?;
        anno.label(self.series[j].0)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], color.filled()));
        if self.show_values {
            self.draw_values(chart, j)?;
        }
        Ok(())
    }

    /// Writes the values of series `j` above (below, if negative) its bars.
    fn draw_values(&self, chart: &mut Chart2d, j: usize) -> Result<()> {
        let value_style = text_style(VALUE_SIZE);
        for (i, y) in self.finite(j) {
            let (x0, x1) = self.bar_x(i, j);
            let (vpos, dy) = if y >= 0.0 {
                (VPos::Bottom, -4)
            } else {
                (VPos::Top, 4)
            };
            let st = value_style.pos(Pos::new(HPos::Center, vpos));
            chart.draw_series(std::iter::once(
                EmptyElement::at(((x0 + x1) / 2.0, y)) + Text::new(fmt_sig(y, 3), (0, dy), st),
            ))?;
        }
        Ok(())
    }
}

/// Group names under the x axis at height `y0`, with a tick mark each (absolute
/// pixels in `root`).
fn draw_group_names(root: &Area, chart: &Chart2d, groups: &[String], y0: f64) -> Result<()> {
    let group_style = text_style(DESC_SIZE).pos(Pos::new(HPos::Center, VPos::Top));
    for (i, g) in groups.iter().enumerate() {
        let (x, y) = chart.backend_coord(&(i as f64, y0));
        root.draw(&PathElement::new(vec![(x, y), (x, y + 6)], BLACK))?;
        root.draw_text(g, &group_style, (x, y + 10))?;
    }
    Ok(())
}
