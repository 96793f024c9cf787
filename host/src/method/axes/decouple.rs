//! The board's decoupling from a stage's FEM grid: the output matrix that takes
//! the flexure's parasitic motion out of the commands
//! ([`piezo_fpi::decoupling`]), before autotune measures the stage as built.
//!
//! The grid's cross gain `C[i][j]` is µm of axis `i`'s output per µm of axis
//! `j`'s own output: the slope of axis `i`'s output along stack `j`'s
//! extension over the slope of axis `j`'s, at the middle of the grid (central
//! differences over a tenth of each stack's span). The board's commands are µm
//! of each axis's own output, so its output matrix is `(I + C)⁻¹`. The
//! preload coupling `K[i][j]` is the slope of stack `i`'s preload along stack
//! `j`'s extension, N/µm, the same way. The grid knows nothing of the
//! position sensors: the input matrix stays the identity.

use anyhow::{bail, Result};
use piezo_fpi::decoupling::{Decoupling, Matrix, Preload};
use piezo_sim::axes::{AXIS_NAMES, MAX_AXES};

use crate::method::axes::grid::FemGrid;

/// The middle of every stack's span and a tenth of it, µm.
fn middle(grid: &FemGrid) -> (Vec<f64>, Vec<f64>) {
    (0..grid.axes())
        .map(|j| {
            let k = grid.knots(j);
            let (lo, hi) = (k[0], k[k.len() - 1]);
            ((lo + hi) / 2.0, (hi - lo) / 20.0)
        })
        .unzip()
}

/// The slope of `f` along stack `j`'s extension about `mid` (central
/// difference over `h[j]`).
fn slope(f: impl Fn(&[f64]) -> f64, mid: &[f64], h: &[f64], j: usize) -> f64 {
    let (mut up, mut down) = (mid.to_vec(), mid.to_vec());
    up[j] += h[j];
    down[j] -= h[j];
    (f(&up) - f(&down)) / (2.0 * h[j])
}

/// An `n × n` table of `f(i, j)` off the diagonal, 0 on it.
fn off_diagonal(n: usize, f: impl Fn(usize, usize) -> f64) -> Vec<Vec<f64>> {
    (0..n)
        .map(|i| (0..n).map(|j| if i == j { 0.0 } else { f(i, j) }).collect())
        .collect()
}

/// A table of the grid's axes as the board's three-axis one (the axes the
/// grid lacks uncoupled).
fn padded(t: &[Vec<f64>]) -> [[f64; MAX_AXES]; MAX_AXES] {
    let mut out = [[0.0; MAX_AXES]; MAX_AXES];
    for (row, t) in out.iter_mut().zip(t) {
        row[..t.len()].copy_from_slice(t);
    }
    out
}

/// The grid's cross gains about the middle of every stack's span,
/// `[i][j]` (µm of axis `i` per µm of axis `j`'s own output; the diagonal 0).
pub fn cross_gains(grid: &FemGrid) -> Vec<Vec<f64>> {
    let (mid, h) = middle(grid);
    let s = |i: usize, j: usize| slope(|x| grid.output_at(i, x), &mid, &h, j);
    off_diagonal(grid.axes(), |i, j| s(i, j) / s(j, j))
}

/// The grid's preload coupling about the middle of every stack's span,
/// `[i][j]` (N on stack `i` per µm of stack `j`'s extension; the diagonal 0).
pub fn preload_coupling(grid: &FemGrid) -> Vec<Vec<f64>> {
    let (mid, h) = middle(grid);
    off_diagonal(grid.axes(), |i, j| {
        slope(|x| grid.preload_at(i, x), &mid, &h, j)
    })
}

/// The board's decoupling for the grid's stage: the output matrix
/// `(I + C)⁻¹` of its cross gains, its preload coupling, the input matrix
/// the identity; refused,
/// naming the grid and the entry, where the board would refuse it (a
/// coupling beyond its range) or an axis does not move with its own stack.
pub fn decoupling(grid: &FemGrid) -> Result<Decoupling<MAX_AXES>> {
    let c = cross_gains(grid);
    let n = c.len();
    for (j, name) in AXIS_NAMES.iter().enumerate().take(n) {
        let k = grid.knots(j);
        let (lo, hi) = (vec![k[0]; n], vec![k[k.len() - 1]; n]);
        let rise = grid.output_at(j, &hi) - grid.output_at(j, &lo);
        if rise.is_nan() || rise <= 0.0 {
            bail!(
                "{}: axis {name}'s output does not rise with its own stack: no cross gain is defined",
                grid.source
            );
        }
    }
    let output = Matrix::undoing(padded(&c)).map_err(|e| {
        anyhow::anyhow!(
            "{}: the output matrix (I + C)⁻¹ is not one the board takes: {e}",
            grid.source
        )
    })?;
    let preload = Preload::from_f64(padded(&preload_coupling(grid))).map_err(|e| {
        anyhow::anyhow!(
            "{}: the preload coupling is not one the board takes: {e}",
            grid.source
        )
    })?;
    Ok(Decoupling {
        input: Matrix::IDENTITY,
        output,
        preload,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use piezo_sim::axes::coupling_of;

    /// The design's grid carries the couplings of `piezo_sim::axes`: the
    /// cross gains and the preload coupling read back from it are theirs,
    /// and the output matrix undoes the gains.
    #[test]
    fn the_designs_cross_gains_are_the_couplings_it_was_made_with() {
        for axes in [2, 3] {
            let grid = FemGrid::design(axes, 4).unwrap();
            let c = cross_gains(&grid);
            let want = coupling_of(axes).cross_um_per_um;
            for (i, (row, want)) in c.iter().zip(want).enumerate() {
                for (j, (&got, &w)) in row.iter().zip(&want).enumerate() {
                    let w = if i == j { 0.0 } else { f64::from(w) };
                    assert!(
                        (got - w).abs() < 1e-6,
                        "{axes} axes [{i}][{j}]: {got} vs {w}"
                    );
                }
            }
            let k = preload_coupling(&grid);
            let want = coupling_of(axes).preload_n_per_um;
            for (i, (row, want)) in k.iter().zip(want).enumerate() {
                for (j, (&got, &w)) in row.iter().zip(&want).enumerate() {
                    let w = if i == j { 0.0 } else { f64::from(w) };
                    assert!(
                        (got - w).abs() < 1e-6,
                        "{axes} axes K[{i}][{j}]: {got} vs {w}"
                    );
                }
            }
            let d = decoupling(&grid).unwrap();
            assert!(d.input.is_identity());
            assert!(!d.preload.is_none());
            let m = d.output.rows().map(|r| r.map(|e| e.to_num::<f64>()));
            // (I + C)·M = I.
            let eye = |i: usize, j: usize| f64::from(u8::from(i == j));
            for (i, row) in c.iter().enumerate() {
                for (j, want) in (0..axes).map(|j| (j, eye(i, j))) {
                    let p: f64 = row
                        .iter()
                        .zip(&m)
                        .enumerate()
                        .map(|(k, (ck, mk))| (eye(i, k) + ck) * mk[j])
                        .sum();
                    assert!((p - want).abs() < 1e-8, "{axes} axes [{i}][{j}]: {p}");
                }
            }
        }
    }
}
