//! Piecewise-linear curves through knots: the one float interpolator.
//!
//! A [`Curve`] holds its knots as borrowed slices (flash on the board, a host
//! tool's buffers), on a uniform grid (an index computation) or at arbitrary
//! increasing abscissae (a search). Two rules for beyond the ends:
//! [`eval`](Curve::eval) continues the end segments (FEM maps: a predicted
//! extension may leave the FEM's range slightly), [`held`](Curve::held) holds the
//! end values (the rule of the core's fixed-point tables).

use crate::real::Real;

/// Where the knots are.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Grid<'a, F> {
    /// `x_k = x0 + k·step`.
    Uniform { x0: F, step: F },
    /// Increasing abscissae.
    Points(&'a [F]),
}

/// A piecewise-linear curve through at least two knots.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Curve<'a, F> {
    grid: Grid<'a, F>,
    ys: &'a [F],
}

impl<'a, F: Real> Curve<'a, F> {
    /// Knots at `x0 + k·step` (`step > 0`) with values `ys`; `None` for fewer
    /// than two knots.
    pub fn uniform(x0: F, step: F, ys: &'a [F]) -> Option<Self> {
        (ys.len() >= 2 && step > F::ZERO).then_some(Self {
            grid: Grid::Uniform { x0, step },
            ys,
        })
    }

    /// Knots at increasing `xs` with values `ys`; a uniform grid (to 10⁻⁹ of its
    /// step) is recognised and looked up by index. `None` for fewer than two knots
    /// or slices of different lengths.
    pub fn points(xs: &'a [F], ys: &'a [F]) -> Option<Self> {
        let n = xs.len();
        if n < 2 || ys.len() != n {
            return None;
        }
        let step = (xs[n - 1] - xs[0]) / F::of_count(n - 1);
        let uniform = xs
            .iter()
            .enumerate()
            .all(|(k, &x)| (x - (xs[0] + F::of_count(k) * step)).abs() <= F::of(1e-9) * step);
        Some(Self {
            grid: if uniform && step > F::ZERO {
                Grid::Uniform { x0: xs[0], step }
            } else {
                Grid::Points(xs)
            },
            ys,
        })
    }

    /// The knot spacing, if the knots are on a uniform grid.
    pub fn uniform_step(&self) -> Option<F> {
        match self.grid {
            Grid::Uniform { step, .. } => Some(step),
            Grid::Points(_) => None,
        }
    }

    /// Number of knots.
    pub fn len(&self) -> usize {
        self.ys.len()
    }

    /// Never: a curve has at least two knots.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Abscissa of knot `k`.
    #[inline]
    pub fn x(&self, k: usize) -> F {
        match self.grid {
            Grid::Uniform { x0, step } => x0 + F::of_count(k) * step,
            Grid::Points(xs) => xs[k],
        }
    }

    /// The values at the knots.
    pub fn values(&self) -> &'a [F] {
        self.ys
    }

    /// First abscissa.
    pub fn x_min(&self) -> F {
        self.x(0)
    }

    /// Last abscissa.
    pub fn x_max(&self) -> F {
        self.x(self.len() - 1)
    }

    /// Value at the last knot.
    pub fn last(&self) -> F {
        self.ys[self.len() - 1]
    }

    /// The segment `[x_k, x_{k+1}]` for `x`, end segments extended (`k` in
    /// `0..=n-2`; NaN gives 0).
    #[inline]
    pub fn segment(&self, x: F) -> usize {
        let n = self.len();
        match self.grid {
            Grid::Uniform { x0, step } => {
                let k = ((x - x0) / step).floor();
                if k >= F::of_count(n - 2) {
                    n - 2
                } else if k > F::ZERO {
                    k.to_index()
                } else {
                    0
                }
            }
            Grid::Points(xs) => match xs.partition_point(|v| *v <= x) {
                0 => 0,
                p if p >= n => n - 2,
                p => p - 1,
            },
        }
    }

    /// Value and slope at `x` in segment `k`.
    #[inline]
    fn on(&self, k: usize, x: F) -> (F, F) {
        let (x0, x1) = (self.x(k), self.x(k + 1));
        let (y0, y1) = (self.ys[k], self.ys[k + 1]);
        let s = (y1 - y0) / (x1 - x0);
        (y0 + s * (x - x0), s)
    }

    /// The value at `x`, end segments continued beyond the ends.
    #[inline]
    pub fn eval(&self, x: F) -> F {
        self.on(self.segment(x), x).0
    }

    /// The value at `x` and the slope of its segment (right-hand at knots).
    #[inline]
    pub fn with_slope(&self, x: F) -> (F, F) {
        self.on(self.segment(x), x)
    }

    /// The value at `x`, the end values held beyond the ends (NaN: the first).
    #[inline]
    pub fn held(&self, x: F) -> F {
        if x > self.x_min() {
            if x >= self.x_max() {
                self.last()
            } else {
                self.eval(x)
            }
        } else {
            self.ys[0] // at or below the first knot, or NaN
        }
    }

    /// Whether `a` and `b` lie in the same segment (so the curve is one line
    /// between them).
    #[inline]
    pub fn same_segment(&self, a: F, b: F) -> bool {
        let k = self.segment(a);
        let n = self.len();
        let inside = |x: F| (k == 0 || x >= self.x(k)) && (k + 2 == n || x < self.x(k + 1));
        k == self.segment(b) && inside(a) && inside(b)
    }

    /// The `x` at which a strictly monotone curve takes the value `y`, end
    /// segments continued.
    pub fn solve(&self, y: F) -> F {
        let n = self.len();
        let rising = self.ys[n - 1] > self.ys[0];
        let k = match self
            .ys
            .partition_point(|v| if rising { *v <= y } else { *v >= y })
        {
            0 => 0,
            p if p >= n => n - 2,
            p => p - 1,
        };
        let (x0, x1) = (self.x(k), self.x(k + 1));
        let (y0, y1) = (self.ys[k], self.ys[k + 1]);
        x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_extends_holds_and_solves() {
        let xs = [0.0, 1.0, 3.0];
        let ys = [10.0, 12.0, 13.0];
        let c = Curve::points(&xs, &ys).unwrap();
        assert_eq!(c.eval(0.5), 11.0);
        assert_eq!(c.eval(2.0), 12.5);
        assert_eq!(c.eval(-1.0), 8.0);
        assert_eq!(c.eval(5.0), 14.0);
        assert_eq!(c.held(-1.0), 10.0);
        assert_eq!(c.held(5.0), 13.0);
        assert_eq!(c.with_slope(1.0), (12.0, 0.5));
        assert_eq!(c.solve(12.5), 2.0);
        assert!(c.same_segment(1.5, 2.9) && !c.same_segment(0.5, 1.5));
        let u = Curve::points(&[0.0, 0.5, 1.0], &[1.0, 2.0, 4.0]).unwrap();
        assert_eq!(u.with_slope(0.75), (3.0, 4.0));
        assert_eq!(u.with_slope(-1.0), (-1.0, 2.0));
        let down = Curve::uniform(0.0, 1.0, &[5.0, 3.0, 2.0]).unwrap();
        assert_eq!(down.solve(2.5), 1.5);
        assert_eq!(down.held(f64::NAN), 5.0);
    }
}
