//! A stage's FEM export (Actuators 2025, 14(8):411, Part II) read from its file: the points of
//! the preload `f_F(x_pea)` and the stage output `f_K(x_pea)`, validated, and the
//! maps through them ([`piezo_sim::fem::Fem`], linear between the points).

use std::path::Path;

use piezo_sim::curve::Curve;
use piezo_sim::fem::Fem;

use crate::data::{self, DataError};

/// An FEM export's points and the maps through them.
#[derive(Debug, Clone, PartialEq)]
pub struct FemMaps {
    /// Where the points came from.
    pub source: String,
    /// Stack extension at the points, µm (strictly increasing).
    x_pea: Vec<f64>,
    /// Preload at the points, N.
    preload: Vec<f64>,
    /// Stage output at the points, µm (strictly monotone).
    x_fhps: Vec<f64>,
    /// The points' spacing when it is uniform (FEM sweeps usually are): lookups
    /// are then an index computation instead of a search.
    uniform_step: Option<f64>,
}

impl FemMaps {
    /// Reads and validates an FEM export (`x_pea_um,preload_N,x_fhps_um`): finite
    /// values, strictly increasing `x_pea_um`, strictly monotone `x_fhps_um`.
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let fem = data::read_fem(path)?;
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
        Self::new(
            fem.path.display().to_string(),
            fem.x_pea,
            fem.preload,
            fem.x_fhps,
        )
        .ok_or_else(|| DataError::file(path, "an FEM table needs at least two points"))
    }

    /// Maps through points (`x_pea` strictly increasing); `None` for fewer than
    /// two points or columns of different lengths.
    pub fn new(
        source: String,
        x_pea: Vec<f64>,
        preload: Vec<f64>,
        x_fhps: Vec<f64>,
    ) -> Option<Self> {
        Curve::points(&x_pea, &x_fhps)?;
        let uniform_step = Curve::points(&x_pea, &preload)?.uniform_step();
        Some(Self {
            source,
            x_pea,
            preload,
            x_fhps,
            uniform_step,
        })
    }

    /// The stack extensions of the FEM's points, µm.
    pub fn x_pea(&self) -> &[f64] {
        &self.x_pea
    }

    /// The maps (borrowing the points).
    #[inline]
    pub fn maps<'a>(&'a self) -> Fem<'a, f64> {
        let curve = |ys: &'a [f64]| -> Option<Curve<'a, f64>> {
            self.uniform_step
                .and_then(|h| Curve::uniform(self.x_pea[0], h, ys))
                .or_else(|| Curve::points(&self.x_pea, ys))
        };
        match (curve(&self.preload), curve(&self.x_fhps)) {
            (Some(preload), Some(output)) => Fem {
                preload,
                output,
                preload_scale: 1.0,
            },
            // `new` checked: at least two points, columns of one length.
            _ => unreachable!("FemMaps::new checked the points"),
        }
    }

    /// `f_F(x_pea)` (N) and its slope (N/µm) in one lookup.
    pub fn preload_with_slope(&self, x_pea: f64) -> (f64, f64) {
        self.maps().preload_with_slope(x_pea)
    }
    /// `f_F(x_pea)`, N.
    pub fn preload_at(&self, x_pea: f64) -> f64 {
        self.maps().preload_at(x_pea)
    }
    /// `f_K(x_pea)`, µm.
    pub fn stage_at(&self, x_pea: f64) -> f64 {
        self.maps().stage_at(x_pea)
    }
    /// `f_K⁻¹(x_fhps)`, µm.
    pub fn stack_for(&self, x_fhps: f64) -> f64 {
        self.maps().stack_for(x_fhps)
    }
    /// The assembly preload `f_F(0)`, N.
    pub fn rest_preload(&self) -> f64 {
        self.maps().rest_preload()
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
    fn uniform_and_uneven_points_give_the_same_maps() {
        let even = FemMaps::new(
            "u".into(),
            vec![0.0, 0.5, 1.0],
            vec![1.0, 2.0, 4.0],
            vec![0.0, 1.0, 2.0],
        )
        .unwrap();
        assert_eq!(even.uniform_step, Some(0.5));
        assert_eq!(even.preload_with_slope(0.75), (3.0, 4.0));
        let uneven = FemMaps::new(
            "t".into(),
            vec![0.0, 1.0, 3.0],
            vec![10.0, 12.0, 13.0],
            vec![0.0, 5.0, 15.0],
        )
        .unwrap();
        assert_eq!(uneven.uniform_step, None);
        assert_eq!(uneven.preload_with_slope(2.0), (12.5, 0.5));
        assert_eq!(uneven.stack_for(10.0), 2.0);
        assert_eq!(uneven.stage_at(uneven.stack_for(7.5)), 7.5);
    }
}
