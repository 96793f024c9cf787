//! Least squares with non-negativity constraints, for calibrating PI weights.
//!
//! Calibration problems are tall (10⁵ samples, 10–40 unknowns). They are reduced
//! to their normal equations, accumulated row by row (in parallel per file, then
//! merged), factored with a Cholesky decomposition (`nalgebra`) after scaling
//! every column to unit norm, and the Lawson–Hanson NNLS (`nnls` crate) runs on
//! the small triangular factor: `‖A x − b‖² = ‖R x − d‖² + const` with
//! `RᵀR = AᵀA`, `Rᵀd = Aᵀb`. Unconstrained unknowns enter NNLS as a pair of
//! columns `(r, −r)`.

use anyhow::{bail, Result};
use nalgebra::{DMatrix, DVector};
use ndarray::{Array1, Array2};

/// Accumulated normal equations of a weighted least-squares problem.
#[derive(Debug, Clone, PartialEq)]
pub struct Normal {
    n: usize,
    /// `AᵀWA`, row-major, full.
    ata: Vec<f64>,
    /// `AᵀWb`.
    atb: Vec<f64>,
    /// `bᵀWb`.
    btb: f64,
    /// Rows added.
    rows: usize,
}

impl Normal {
    /// No rows yet, `n` unknowns.
    pub fn new(n: usize) -> Self {
        Self {
            n,
            ata: vec![0.0; n * n],
            atb: vec![0.0; n],
            btb: 0.0,
            rows: 0,
        }
    }

    /// Unknowns.
    pub fn unknowns(&self) -> usize {
        self.n
    }

    /// Rows added.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Adds one equation `row · x ≈ target` with weight `w`.
    #[inline]
    pub fn add(&mut self, row: &[f64], target: f64, w: f64) {
        debug_assert_eq!(row.len(), self.n);
        for (i, &ri) in row.iter().enumerate() {
            let wi = w * ri;
            if wi == 0.0 {
                continue;
            }
            let line = &mut self.ata[i * self.n..(i + 1) * self.n];
            // Upper triangle only; mirrored in `symmetric`.
            for (a, &rj) in line[i..].iter_mut().zip(&row[i..]) {
                *a += wi * rj;
            }
            self.atb[i] += wi * target;
        }
        self.btb += w * target * target;
        self.rows += 1;
    }

    /// Adds another accumulation of the same shape.
    pub fn merge(&mut self, other: &Normal) {
        for (a, b) in self.ata.iter_mut().zip(&other.ata) {
            *a += b;
        }
        for (a, b) in self.atb.iter_mut().zip(&other.atb) {
            *a += b;
        }
        self.btb += other.btb;
        self.rows += other.rows;
    }

    fn symmetric(&self) -> DMatrix<f64> {
        let n = self.n;
        DMatrix::from_fn(n, n, |i, j| {
            let (a, b) = if i <= j { (i, j) } else { (j, i) };
            self.ata[a * n + b]
        })
    }

    /// Minimises `‖W^½(A x − b)‖` subject to `x_j ≥ 0` where `nonneg[j]`; returns
    /// `x` and the residual sum of squares.
    pub fn solve(&self, nonneg: &[bool]) -> Result<(Vec<f64>, f64)> {
        let n = self.n;
        if n == 0 || self.rows == 0 {
            bail!("least squares without unknowns or without data");
        }
        // Unit-norm column scaling; columns that are identically zero stay at 0.
        let g = self.symmetric();
        let scale: Vec<f64> = (0..n)
            .map(|i| {
                let d = g[(i, i)];
                if d > 0.0 {
                    1.0 / d.sqrt()
                } else {
                    0.0
                }
            })
            .collect();
        let gs = DMatrix::from_fn(n, n, |i, j| g[(i, j)] * scale[i] * scale[j]);
        let bs = DVector::from_fn(n, |i, _| self.atb[i] * scale[i]);
        // A tiny ridge keeps near-collinear operator columns factorable.
        let ridge = 1e-12;
        let gr = &gs + DMatrix::identity(n, n) * ridge;
        let Some(chol) = gr.cholesky() else {
            bail!("the least-squares problem is singular");
        };
        let l = chol.l(); // G = L Lᵀ, R = Lᵀ
        let d = l
            .solve_lower_triangular(&bs)
            .unwrap_or_else(|| DVector::zeros(n));
        // Columns of R, with a negated copy for every free unknown.
        let free: Vec<usize> = (0..n).filter(|&j| !nonneg[j]).collect();
        let cols = n + free.len();
        let mut r = Array2::<f64>::zeros((n, cols));
        for i in 0..n {
            for j in 0..n {
                r[(i, j)] = l[(j, i)];
            }
            for (k, &j) in free.iter().enumerate() {
                r[(i, n + k)] = -l[(j, i)];
            }
        }
        let dv = Array1::from_iter(d.iter().copied());
        let (z, _) = nnls::nnls(r.view(), dv.view());
        let mut x: Vec<f64> = (0..n).map(|j| z[j] * scale[j]).collect();
        for (k, &j) in free.iter().enumerate() {
            x[j] -= z[n + k] * scale[j];
        }
        // Residual from the normal equations: bᵀb − 2 xᵀAᵀb + xᵀAᵀA x.
        let xv = DVector::from_vec(x.clone());
        let atb = DVector::from_vec(self.atb.clone());
        let rss = (self.btb - 2.0 * xv.dot(&atb) + (g * &xv).dot(&xv)).max(0.0);
        Ok((x, rss))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_non_negative_solution() {
        // y = 2 a + 0 b + 3 c, with b's best unconstrained coefficient negative.
        let mut ne = Normal::new(3);
        for k in 0..200 {
            let t = k as f64 * 0.05;
            let row = [t.sin(), t.cos() + 0.1 * t, 1.0];
            let y = 2.0 * row[0] - 0.3 * row[1] + 3.0;
            ne.add(&row, y, 1.0);
        }
        let (x, _) = ne.solve(&[true, false, true]).unwrap();
        assert!(
            (x[0] - 2.0).abs() < 1e-9 && (x[1] + 0.3).abs() < 1e-9 && (x[2] - 3.0).abs() < 1e-9,
            "{x:?}"
        );
        let (x, rss) = ne.solve(&[true, true, true]).unwrap();
        assert!(x.iter().all(|v| *v >= 0.0) && rss > 0.0, "{x:?}");
    }
}
