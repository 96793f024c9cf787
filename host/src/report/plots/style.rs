//! Look of the figures: fonts, sizes, colours, chart frame styles and the
//! formatting of numbers on axes and in labels.

use plotters::prelude::*;

use super::PALETTE;

pub(super) const FONT: &str = "sans-serif";
/// Colour of the highlighted path of [`surface()`](super::surface()).
pub(super) const PATH_COLOR: RGBColor = PALETTE[1];
pub(super) const TITLE_SIZE: u32 = 28;
pub(super) const PANEL_TITLE_SIZE: u32 = 21;
pub(super) const DESC_SIZE: u32 = 21;
pub(super) const LABEL_SIZE: u32 = 17;
pub(super) const LEGEND_SIZE: u32 = 17;
pub(super) const VALUE_SIZE: u32 = 15;
/// Stand-in colour of the measured series: replaced in the SVG text by black
/// with a dash pattern (plotters' own dashes make one element per dash).
pub(super) const DASH_SENTINEL: RGBColor = RGBColor(1, 2, 3);
pub(super) const DASH_SENTINEL_SVG: &str = "stroke=\"#010203\"";
pub(super) const DASH_SVG: &str = "stroke=\"#000000\" stroke-dasharray=\"7,4\"";

/// Sizes of a 2D chart frame.
pub(super) struct FrameStyle {
    pub(super) margin: u32,
    pub(super) x_area: u32,
    pub(super) y_area: u32,
    pub(super) label: u32,
    pub(super) desc: u32,
    pub(super) x_labels: usize,
    pub(super) y_labels: usize,
}

/// Frame of a figure with a single chart.
pub(super) const FULL: FrameStyle = FrameStyle {
    margin: 12,
    x_area: 56,
    y_area: 84,
    label: LABEL_SIZE,
    desc: DESC_SIZE,
    x_labels: 10,
    y_labels: 8,
};

/// Frame of one panel of a multi-panel figure.
pub(super) const SMALL: FrameStyle = FrameStyle {
    margin: 8,
    x_area: 46,
    y_area: 68,
    label: 15,
    desc: 17,
    x_labels: 6,
    y_labels: 6,
};

/// Black text in [`FONT`] at `size`.
pub(super) fn text_style(size: u32) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).color(&BLACK)
}

/// Colour at `t` in 0..=1 along a dark-violet → green ramp (viridis-like, without
/// the pale yellow end that vanishes on white).
pub(super) fn ramp_color(t: f64) -> RGBColor {
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
pub(super) fn tick_format(range: (f64, f64), n: usize) -> impl Fn(&f64) -> String {
    let step = tick_step((range.1 - range.0).abs(), n);
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

/// The tick step plotters picks for `span` with at most `n` ticks: the smallest
/// 1, 2 or 5 × 10^k giving no more than `n` ticks.
fn tick_step(span: f64, n: usize) -> f64 {
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
    step
}

fn round_to(v: f64, d: usize) -> f64 {
    let p = 10f64.powi(d as i32);
    (v * p).round() / p
}

/// `v` with `sig` significant digits, without trailing zeros.
pub(super) fn fmt_sig(v: f64, sig: usize) -> String {
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
    fn significant_digits() {
        assert_eq!(fmt_sig(12.345, 3), "12.3");
        assert_eq!(fmt_sig(0.5, 3), "0.5");
        assert_eq!(fmt_sig(1234.0, 3), "1234");
    }
}
