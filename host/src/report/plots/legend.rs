//! Legends: inside a 2D chart in the corner that hides the fewest data points,
//! or drawn by hand as one row or one framed column in an area of their own.

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::canvas::{plot_dims, Area, Chart2d};
use super::style::{text_style, FrameStyle, FONT, LEGEND_SIZE};

/// One entry of a hand-drawn legend: label and line style.
pub(super) type LegendEntry = (String, ShapeStyle);

/// The sample a hand-drawn legend shows for a series, as the series is drawn:
/// a line, dots, or both (a line through a dot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Mark {
    /// A line in this style.
    Line(ShapeStyle),
    /// A dot in this style.
    Dot(ShapeStyle),
    /// A line (first style) through a dot (second style).
    LineAndDot(ShapeStyle, ShapeStyle),
}

/// Radius of a legend's dot (px): larger than a plotted point's, to be seen.
const DOT_RADIUS: i32 = 4;

/// Gap between the legend box and the plotting area's border (px).
const LEGEND_INSET: i32 = 8;

/// Legend position (pixels in the plotting area) and y range for a chart with
/// frame `st` in `area`, the series `names` and `samples` along the data: see
/// [`place_legend`].
pub(super) fn legend_layout(
    area: &Area,
    st: &FrameStyle,
    names: &[&str],
    samples: &[(f64, f64)],
    xr: (f64, f64),
    yr: (f64, f64),
) -> Result<((i32, i32), (f64, f64))> {
    let plot = plot_dims(area, st)?;
    let boxsz = legend_box(names, LEGEND_SIZE)?;
    Ok(place_legend(samples, xr, yr, plot, boxsz))
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
    let fit = LegendFit {
        samples,
        xr,
        plot: (plot.0.max(1), plot.1.max(1)),
        boxsz,
    };
    let (w, h) = fit.plot;
    let (bw, bh) = boxsz;
    let left = LEGEND_INSET;
    let right = (w - bw - LEGEND_INSET).max(LEGEND_INSET);
    let top = LEGEND_INSET;
    let bottom = (h - bh - LEGEND_INSET).max(LEGEND_INSET);
    let (best, n) = fit.best(
        &[(left, top), (right, top), (right, bottom), (left, bottom)],
        yr,
    );
    if n == 0 {
        return (best, yr);
    }
    let band = (bh + 2 * LEGEND_INSET) as f64;
    if band > 0.6 * h as f64 {
        return (best, yr);
    }
    let hi = yr.0 + (yr.1 - yr.0) * h as f64 / (h as f64 - band);
    let yr2 = (yr.0, hi);
    let (best, _) = fit.best(&[(left, top), (right, top)], yr2);
    (best, yr2)
}

/// The data and sizes [`place_legend`] weighs the legend corners with.
struct LegendFit<'s> {
    samples: &'s [(f64, f64)],
    xr: (f64, f64),
    /// Plotting area size (px).
    plot: (i32, i32),
    /// Legend box size (px).
    boxsz: (i32, i32),
}

impl LegendFit<'_> {
    /// The candidate covering the fewest samples (the first one on ties), and
    /// how many it covers.
    fn best(&self, candidates: &[(i32, i32)], yr: (f64, f64)) -> ((i32, i32), usize) {
        candidates
            .iter()
            .map(|&c| (c, self.covered(c, yr)))
            .min_by_key(|&(_, n)| n)
            .unwrap_or(((LEGEND_INSET, LEGEND_INSET), 0))
    }

    /// How many samples a legend box at `pos` covers (with 4 px around it).
    fn covered(&self, pos: (i32, i32), yr: (f64, f64)) -> usize {
        let (w, h) = self.plot;
        let (bw, bh) = self.boxsz;
        let xr = self.xr;
        let (x0, y0) = (pos.0 as f64 - 4.0, pos.1 as f64 - 4.0);
        let (x1, y1) = (x0 + bw as f64 + 8.0, y0 + bh as f64 + 8.0);
        self.samples
            .iter()
            .filter(|(x, y)| {
                let px = (x - xr.0) / (xr.1 - xr.0) * w as f64;
                let py = (yr.1 - y) / (yr.1 - yr.0) * h as f64;
                px >= x0 && px <= x1 && py >= y0 && py <= y1
            })
            .count()
    }
}

/// Draws plotters' legend of the labelled series of `chart` at `pos`.
pub(super) fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart2d<'a, 'b>,
    pos: (i32, i32),
    size: u32,
) -> Result<()> {
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

/// A one-row legend centred in `area`, each entry's sample a line.
pub(super) fn draw_legend_row(area: &Area, entries: &[LegendEntry]) -> Result<()> {
    let marked: Vec<(String, Mark)> = entries
        .iter()
        .map(|(name, style)| (name.clone(), Mark::Line(*style)))
        .collect();
    draw_legend_row_marked(area, &marked)
}

/// A one-row legend centred in `area`, each entry with its sample.
pub(super) fn draw_legend_row_marked(area: &Area, entries: &[(String, Mark)]) -> Result<()> {
    let font = legend_font();
    let widths: Vec<i32> = entries
        .iter()
        .map(|(name, _)| entry_width(text_width(area, name, &font)))
        .collect();
    let total: i32 = widths.iter().sum();
    let (aw, ah) = area.dim_in_pixel();
    let mut x = ((aw as i32 - total) / 2).max(4);
    let y = ah as i32 / 2;
    for ((name, mark), w) in entries.iter().zip(widths) {
        draw_mark(area, *mark, x, y)?;
        area.draw_text(name, &font, (x + 30, y))?;
        x += w;
    }
    Ok(())
}

/// A legend sample 24 px wide from `(x, y)` (its left middle).
fn draw_mark(area: &Area, mark: Mark, x: i32, y: i32) -> Result<()> {
    let line = |style: ShapeStyle| area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], style));
    let dot = |style: ShapeStyle| area.draw(&Circle::new((x + 12, y), DOT_RADIUS, style));
    match mark {
        Mark::Line(l) => line(l)?,
        Mark::Dot(d) => dot(d)?,
        Mark::LineAndDot(l, d) => {
            line(l)?;
            dot(d)?;
        }
    }
    Ok(())
}

/// A legend column, vertically centred in `area`, in a framed box.
pub(super) fn draw_legend_column(area: &Area, entries: &[LegendEntry]) -> Result<()> {
    let font = legend_font();
    let line_h = 26;
    let text_w = entries
        .iter()
        .map(|(n, _)| text_width(area, n, &font))
        .max()
        .unwrap_or(0);
    let (aw, ah) = area.dim_in_pixel();
    let (bw, bh) = (entry_width(text_w), line_h * entries.len() as i32 + 12);
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

/// Text style of the hand-drawn legends, anchored at the left middle.
fn legend_font() -> TextStyle<'static> {
    text_style(LEGEND_SIZE).pos(Pos::new(HPos::Left, VPos::Center))
}

/// Estimated width of `text` in `font` (0 if it cannot be estimated).
fn text_width(area: &Area, text: &str, font: &TextStyle) -> i32 {
    area.estimate_text_size(text, font)
        .map(|s| s.0)
        .unwrap_or(0) as i32
}

/// Width of a legend entry: line sample, gap and text (with some slack, as real
/// fonts run a little wider than plotters' estimate).
fn entry_width(text_w: i32) -> i32 {
    text_w + text_w / 8 + 30 + 24
}
