//! Error statistics: the one implementation of the figures every report gives
//! (MAE, RMSE, largest error), on the board in `f32` and on the host in `f64`.

use crate::real::Real;

/// Running count, mean square, mean absolute and largest magnitude of an error
/// signal.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorStats<F> {
    count: u32,
    sum_sq: F,
    sum_abs: F,
    max_abs: F,
}

impl<F: Real> ErrorStats<F> {
    /// No samples yet.
    pub fn new() -> Self {
        Self {
            count: 0,
            sum_sq: F::ZERO,
            sum_abs: F::ZERO,
            max_abs: F::ZERO,
        }
    }

    /// Adds one error sample.
    #[inline]
    pub fn add(&mut self, e: F) {
        let a = e.abs();
        self.count += 1;
        self.sum_sq += e * e;
        self.sum_abs += a;
        if a > self.max_abs {
            self.max_abs = a;
        }
    }

    /// The statistics of `a - b`, sample by sample (the shorter length).
    pub fn of_difference(a: &[F], b: &[F]) -> Self {
        let mut s = Self::new();
        for (x, y) in a.iter().zip(b) {
            s.add(*x - *y);
        }
        s
    }

    /// Number of samples.
    pub const fn count(&self) -> u32 {
        self.count
    }

    /// Root-mean-square error (0 without samples).
    pub fn rms(&self) -> F {
        if self.count == 0 {
            F::ZERO
        } else {
            (self.sum_sq / F::of_count(self.count as usize)).sqrt()
        }
    }

    /// Mean absolute error (0 without samples).
    pub fn mae(&self) -> F {
        if self.count == 0 {
            F::ZERO
        } else {
            self.sum_abs / F::of_count(self.count as usize)
        }
    }

    /// Largest absolute error (the paper's MTE).
    pub fn max_abs(&self) -> F {
        self.max_abs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_accumulate() {
        let mut s = ErrorStats::<f32>::new();
        for e in [3.0, -4.0] {
            s.add(e);
        }
        assert_eq!(s.count(), 2);
        assert!((s.rms() - 12.5f32.sqrt()).abs() < 1e-6);
        assert_eq!(s.mae(), 3.5);
        assert_eq!(s.max_abs(), 4.0);
        let d = ErrorStats::of_difference(&[1.0f64, 2.0], &[1.5, 2.0]);
        assert_eq!((d.count(), d.max_abs()), (2, 0.5));
    }
}
