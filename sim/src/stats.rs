//! Tracking-error statistics, computed the same way on the board and on the host.
//!
//! `micromath`'s `sqrt` is a coarse approximation and `x.sqrt()` silently means
//! std's exact one on the host, so [`sqrt`] calls `micromath` explicitly and polishes
//! the result with Newton steps: both worlds run the same instructions and get the
//! same (correctly rounded to within 1 ulp) result.

use micromath::F32Ext;

/// Square root for `x >= 0` (0 for anything else): micromath's estimate plus three
/// Newton–Raphson steps.
pub fn sqrt(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    let mut r = F32Ext::sqrt(x);
    for _ in 0..3 {
        r = 0.5 * (r + x / r);
    }
    r
}

/// Running count, mean square and largest magnitude of an error signal (µm).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorStats {
    count: u32,
    sum_sq: f32,
    sum_abs: f32,
    max_abs: f32,
}

impl ErrorStats {
    /// No samples yet.
    pub const fn new() -> Self {
        Self {
            count: 0,
            sum_sq: 0.0,
            sum_abs: 0.0,
            max_abs: 0.0,
        }
    }

    /// Adds one error sample.
    pub fn add(&mut self, e: f32) {
        let a = if e < 0.0 { -e } else { e };
        self.count += 1;
        self.sum_sq += e * e;
        self.sum_abs += a;
        if a > self.max_abs {
            self.max_abs = a;
        }
    }

    /// Number of samples.
    pub const fn count(&self) -> u32 {
        self.count
    }

    /// Root-mean-square error (0 without samples).
    pub fn rms(&self) -> f32 {
        if self.count == 0 {
            0.0
        } else {
            sqrt(self.sum_sq / self.count as f32)
        }
    }

    /// Mean absolute error (0 without samples).
    pub fn mae(&self) -> f32 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_abs / self.count as f32
        }
    }

    /// Largest absolute error (the paper's MTE).
    pub const fn max_abs(&self) -> f32 {
        self.max_abs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sqrt_is_accurate() {
        for k in 1..20_000 {
            let x = k as f32 * 0.0137;
            let want = (x as f64).sqrt();
            let got = sqrt(x) as f64;
            assert!(
                (got - want).abs() <= want * 2.0 * f32::EPSILON as f64,
                "{x}: {got} vs {want}"
            );
        }
        assert_eq!(sqrt(0.0), 0.0);
        assert_eq!(sqrt(-1.0), 0.0);
        assert_eq!(sqrt(f32::NAN), 0.0);
    }

    #[test]
    fn stats_accumulate() {
        let mut s = ErrorStats::new();
        for e in [3.0, -4.0] {
            s.add(e);
        }
        assert_eq!(s.count(), 2);
        assert!((s.rms() - 12.5f32.sqrt()).abs() < 1e-6);
        assert_eq!(s.mae(), 3.5);
        assert_eq!(s.max_abs(), 4.0);
    }
}
