//! The FFEM maps of a stage (seed 000, Part II): preload `f_F(x_pea)` and stage
//! output `f_K(x_pea)`, linear between the FEM's points, and the inverse
//! kinematics `f_K⁻¹` (exact: the inverse of a strictly monotone piecewise-linear map).

use std::path::Path;

use crate::data::{self, DataError, Fem};

/// Piecewise-linear maps through the points of an FEM export.
#[derive(Debug, Clone, PartialEq)]
pub struct FemMaps {
    /// Where the points came from.
    pub source: String,
    /// Stack extension at the points, µm (strictly increasing).
    pub x_pea: Vec<f64>,
    /// Preload at the points, N.
    pub preload: Vec<f64>,
    /// Stage output at the points, µm (strictly monotone).
    pub x_fhps: Vec<f64>,
    /// The points' spacing when it is uniform (FEM sweeps usually are): lookups
    /// are then an index computation instead of a search.
    pub uniform_step: Option<f64>,
}

/// Linear interpolation on sorted knots `xs`; beyond the ends, the end segments'
/// lines continue (a predicted extension may leave the FEM's range slightly).
pub fn interp(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    let n = xs.len();
    let k = match xs.partition_point(|v| *v <= x) {
        0 => 0,
        p if p >= n => n - 2,
        p => p - 1,
    };
    let t = (x - xs[k]) / (xs[k + 1] - xs[k]);
    ys[k] + t * (ys[k + 1] - ys[k])
}

/// Slope of [`interp`] at `x` (the right-hand slope at knots).
pub fn slope(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    let n = xs.len();
    let k = match xs.partition_point(|v| *v <= x) {
        0 => 0,
        p if p >= n => n - 2,
        p => p - 1,
    };
    (ys[k + 1] - ys[k]) / (xs[k + 1] - xs[k])
}

impl FemMaps {
    /// Reads and validates an FEM export (`x_pea_um,preload_N,x_fhps_um`): finite
    /// values, strictly increasing `x_pea_um`, strictly monotone `x_fhps_um`.
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let fem = data::read_fem(path)?;
        Self::from_fem(fem)
    }

    /// Validates parsed FEM points.
    pub fn from_fem(fem: Fem) -> Result<Self, DataError> {
        let up = fem.x_fhps[fem.x_fhps.len() - 1] > fem.x_fhps[0];
        for (i, w) in fem.x_fhps.windows(2).enumerate() {
            if (up && w[1] <= w[0]) || (!up && w[1] >= w[0]) {
                return Err(DataError::at(
                    &fem.path,
                    i as u64 + 3,
                    "x_fhps_um",
                    format!(
                        "{} after {}: the stage output must be strictly monotone in the stack \
                         extension for the inverse kinematics",
                        w[1], w[0]
                    ),
                ));
            }
        }
        Ok(Self::new(
            fem.path.display().to_string(),
            fem.x_pea,
            fem.preload,
            fem.x_fhps,
        ))
    }

    /// Maps from points (`x_pea` strictly increasing, at least two).
    pub fn new(source: String, x_pea: Vec<f64>, preload: Vec<f64>, x_fhps: Vec<f64>) -> Self {
        let n = x_pea.len();
        let step = (x_pea[n - 1] - x_pea[0]) / (n - 1) as f64;
        let uniform = x_pea
            .iter()
            .enumerate()
            .all(|(k, x)| (x - (x_pea[0] + k as f64 * step)).abs() <= 1e-9 * step);
        Self {
            source,
            x_pea,
            preload,
            x_fhps,
            uniform_step: uniform.then_some(step),
        }
    }

    /// The segment index for `x` (end segments extended).
    #[inline]
    fn segment(&self, x: f64) -> usize {
        let n = self.x_pea.len();
        match self.uniform_step {
            Some(h) => {
                let k = ((x - self.x_pea[0]) / h).floor();
                if k < 0.0 {
                    0
                } else {
                    (k as usize).min(n - 2)
                }
            }
            None => match self.x_pea.partition_point(|v| *v <= x) {
                0 => 0,
                p if p >= n => n - 2,
                p => p - 1,
            },
        }
    }

    /// Whether two extensions fall in the same linear segment of the maps.
    #[inline]
    pub fn same_segment(&self, a: f64, b: f64) -> bool {
        let k = self.segment(a);
        k == self.segment(b)
            && (k == 0 || b >= self.x_pea[k])
            && (k + 2 == self.x_pea.len() || b < self.x_pea[k + 1])
            && (k == 0 || a >= self.x_pea[k])
            && (k + 2 == self.x_pea.len() || a < self.x_pea[k + 1])
    }

    /// `f_F(x_pea)` (N) and its slope (N/µm) in one lookup.
    #[inline]
    pub fn preload_with_slope(&self, x_pea: f64) -> (f64, f64) {
        let k = self.segment(x_pea);
        let (x0, x1) = (self.x_pea[k], self.x_pea[k + 1]);
        let (f0, f1) = (self.preload[k], self.preload[k + 1]);
        let s = (f1 - f0) / (x1 - x0);
        (f0 + s * (x_pea - x0), s)
    }

    /// `f_F(x_pea)`, N.
    pub fn preload_at(&self, x_pea: f64) -> f64 {
        self.preload_with_slope(x_pea).0
    }
    /// `f_F'(x_pea)`, N/µm.
    pub fn preload_slope(&self, x_pea: f64) -> f64 {
        self.preload_with_slope(x_pea).1
    }
    /// `f_K(x_pea)`, µm.
    pub fn stage_at(&self, x_pea: f64) -> f64 {
        interp(&self.x_pea, &self.x_fhps, x_pea)
    }
    /// `f_K⁻¹(x_fhps)`, µm.
    pub fn stack_for(&self, x_fhps: f64) -> f64 {
        if self.x_fhps[0] < self.x_fhps[self.x_fhps.len() - 1] {
            interp(&self.x_fhps, &self.x_pea, x_fhps)
        } else {
            let xs: Vec<f64> = self.x_fhps.iter().rev().copied().collect();
            let ys: Vec<f64> = self.x_pea.iter().rev().copied().collect();
            interp(&xs, &ys, x_fhps)
        }
    }
    /// The assembly preload `f_F(0)`, N.
    pub fn rest_preload(&self) -> f64 {
        self.preload_at(0.0)
    }
    /// Largest stack extension the FEM covers, µm.
    pub fn x_pea_max(&self) -> f64 {
        self.x_pea[self.x_pea.len() - 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_extrapolates_and_inverts() {
        let xs = [0.0, 1.0, 3.0];
        let ys = [10.0, 12.0, 13.0];
        assert_eq!(interp(&xs, &ys, 0.5), 11.0);
        assert_eq!(interp(&xs, &ys, 2.0), 12.5);
        assert_eq!(interp(&xs, &ys, -1.0), 8.0);
        assert_eq!(interp(&xs, &ys, 5.0), 14.0);
        assert_eq!(slope(&xs, &ys, 1.0), 0.5);
        let m = FemMaps::new("t".into(), xs.to_vec(), ys.to_vec(), vec![0.0, 5.0, 15.0]);
        assert_eq!(m.uniform_step, None);
        assert_eq!(m.preload_with_slope(2.0), (12.5, 0.5));
        let u = FemMaps::new(
            "u".into(),
            vec![0.0, 0.5, 1.0],
            vec![1.0, 2.0, 4.0],
            vec![0.0, 1.0, 2.0],
        );
        assert_eq!(u.uniform_step, Some(0.5));
        assert_eq!(u.preload_with_slope(0.75), (3.0, 4.0));
        assert_eq!(u.preload_with_slope(-1.0), (-1.0, 2.0));
        assert_eq!(m.stack_for(10.0), 2.0);
        assert_eq!(m.stage_at(m.stack_for(7.5)), 7.5);
    }
}
