//! Data preparation: drawable lines from raw series (split at non-finite points,
//! decimated), value ranges, and points along the lines for the legend placement.

use plotters::prelude::*;

use super::MEASURED_COLOR;

/// One drawable series: finite segments, already decimated.
pub(super) struct Line {
    pub(super) name: String,
    pub(super) color: RGBColor,
    pub(super) measured: bool,
    pub(super) segs: Vec<Vec<(f64, f64)>>,
}

/// The series of a loops-style plot, models first and measured last (on top).
pub(super) fn xy_lines(
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

/// The finite segments of `y` against `x`, sharing `max_points` by length.
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

/// [`split_finite`] for points (a, b).
pub(super) fn finite_segments(pts: impl Iterator<Item = (f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    split_finite(pts, |&(a, b)| a.is_finite() && b.is_finite())
}

/// Splits at the points that are not `finite`; many tiny pieces are joined into
/// one line instead (a NaN every other sample would otherwise make thousands of
/// SVG elements).
pub(super) fn split_finite<T: Copy>(
    pts: impl Iterator<Item = T>,
    finite: impl Fn(&T) -> bool,
) -> Vec<Vec<T>> {
    let mut segs: Vec<Vec<T>> = vec![];
    let mut cur = vec![];
    for p in pts {
        if finite(&p) {
            cur.push(p);
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

/// [`decimate_by`] for points (a, b).
pub(super) fn decimate(pts: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    decimate_by(pts, max, |p| *p)
}

/// Min/max decimation: per bucket, keeps the points of extreme first and second
/// coordinate (in their original order), plus the very first and last points.
pub(super) fn decimate_by<T: Copy>(
    pts: &[T],
    max: usize,
    key: impl Fn(&T) -> (f64, f64),
) -> Vec<T> {
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
        for i in extremes(chunk, &key) {
            let g = c * k + i;
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

/// Indices in `chunk` of the smallest and largest first and second coordinates,
/// sorted (the first one wins ties).
fn extremes<T>(chunk: &[T], key: impl Fn(&T) -> (f64, f64)) -> [usize; 4] {
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
    idx
}

/// Smallest and largest finite value, if any.
pub(super) fn min_max(v: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    v.filter(|x| x.is_finite()).fold(None, |acc, x| match acc {
        None => Some((x, x)),
        Some((lo, hi)) => Some((lo.min(x), hi.max(x))),
    })
}

/// Finite range of the values with `frac` of the span added on each side; all
/// equal values get a widened range, no values give 0..1.
pub(super) fn padded_range(v: impl Iterator<Item = f64>, frac: f64) -> (f64, f64) {
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

/// Points along every line, at most ~0.5 % of the axes apart, for the legend
/// placement.
pub(super) fn densify(lines: &[Line], xr: (f64, f64), yr: (f64, f64)) -> Vec<(f64, f64)> {
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

#[cfg(test)]
mod tests {
    use super::super::MAX_POINTS;
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
    }
}
