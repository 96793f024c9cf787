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

mod bars;
mod bode;
mod canvas;
mod frame;
mod legend;
mod series;
mod style;
mod surface;
mod xy;

use plotters::prelude::*;

pub use bars::bars;
pub use bode::{bode, BodeSeries};
pub use surface::surface;
pub use xy::{curves, loop_panels, loops};

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
