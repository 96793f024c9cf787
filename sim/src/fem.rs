//! The FFEM maps of a stage (Actuators 2025, 14(8):411, Part II): the preload the flexure hinge
//! puts on the stack, `f_F(x_pea)`, and the stage output, `f_K(x_pea)`, linear
//! between the FEM's points, with the inverse kinematics `f_K⁻¹`.

use crate::curve::Curve;
use crate::real::Real;

/// Piecewise-linear FEM maps over the stack extension (both curves share the
/// FEM's points).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fem<'a, F> {
    /// `f_F`: stack extension (µm) → preload (N).
    pub preload: Curve<'a, F>,
    /// `f_K`: stack extension (µm) → stage output (µm), strictly monotone.
    pub output: Curve<'a, F>,
    /// The built stage's preload relative to the FEM's (1 for the FEM itself; the
    /// virtual stage's prototype differs from its design).
    pub preload_scale: F,
}

impl<'a, F: Real> Fem<'a, F> {
    /// Maps through the FEM's points: extensions `x_pea` (increasing), preloads and
    /// stage outputs; `None` for fewer than two points or columns of different
    /// lengths.
    pub fn new(x_pea: &'a [F], preload: &'a [F], x_fhps: &'a [F]) -> Option<Self> {
        Some(Self {
            preload: Curve::points(x_pea, preload)?,
            output: Curve::points(x_pea, x_fhps)?,
            preload_scale: F::ONE,
        })
    }

    /// `f_F(x_pea)` (N) and its slope (N/µm) in one lookup.
    #[inline]
    pub fn preload_with_slope(&self, x_pea: F) -> (F, F) {
        let (f, s) = self.preload.with_slope(x_pea);
        (self.preload_scale * f, self.preload_scale * s)
    }
    /// `f_F(x_pea)`, N.
    pub fn preload_at(&self, x_pea: F) -> F {
        self.preload_with_slope(x_pea).0
    }
    /// `f_K(x_pea)`, µm.
    pub fn stage_at(&self, x_pea: F) -> F {
        self.output.eval(x_pea)
    }
    /// `f_K⁻¹(x_fhps)`, µm.
    pub fn stack_for(&self, x_fhps: F) -> F {
        self.output.solve(x_fhps)
    }
    /// Whether two extensions fall in the same linear segment of the maps.
    #[inline]
    pub fn same_segment(&self, a: F, b: F) -> bool {
        self.preload.same_segment(a, b)
    }
    /// The assembly preload `f_F(0)`, N.
    pub fn rest_preload(&self) -> F {
        self.preload_at(F::ZERO)
    }
    /// Largest stack extension the FEM covers, µm.
    pub fn x_pea_max(&self) -> F {
        self.preload.x_max()
    }
}
