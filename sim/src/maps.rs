//! The static monotone maps of the chain, analytic and tabulated: the dead zone
//! `g` before the operators and the output map `h` after them.

use crate::curve::Curve;
use crate::real::Real;

/// The soft dead zone `g(e) = s·ln(1 + e^{e/s})` and its slope; the hard one,
/// `max(e, 0)`, for `s <= 0`.
#[inline]
pub fn dead_zone<F: Real>(s: F, e: F) -> (F, F) {
    if s <= F::ZERO {
        return if e > F::ZERO {
            (e, F::ONE)
        } else {
            (F::ZERO, F::ZERO)
        };
    }
    let t = e / s;
    if t > F::of(36.0) {
        (e, F::ONE)
    } else {
        let ex = t.exp();
        (s * ex.ln_1p(), ex / (F::ONE + ex))
    }
}

/// The inverse of [`dead_zone`] for a positive effective voltage `û`:
/// `e = s·ln(e^{û/s} - 1)` (`û` itself for the hard one).
pub fn dead_zone_inverse<F: Real>(s: F, uh: F) -> F {
    if s <= F::ZERO {
        return uh;
    }
    let t = uh / s;
    if t > F::of(36.0) {
        uh
    } else if t <= F::of(1e-300) {
        F::of(-700.0) * s
    } else {
        s * t.exp_m1().ln()
    }
}

/// An analytic map after the PI (`z = h(Y)`), invertible in closed form.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(tag = "map", rename_all = "lowercase", deny_unknown_fields)
)]
pub enum OutputMap<F> {
    /// `z = Y`.
    #[default]
    Identity,
    /// Saturation: `z + β·z² = Y` (β > 0 flattens the top).
    Saturation {
        /// β, 1/µm.
        beta_per_um: F,
    },
    /// `z = Y + γ·Y²`.
    Quadratic {
        /// γ, 1/µm.
        gamma_per_um: F,
    },
}

impl<F: Real> OutputMap<F> {
    /// `z = h(Y)` and `dz/dY`.
    #[inline]
    pub fn apply(self, y: F) -> (F, F) {
        let two = F::of(2.0);
        match self {
            OutputMap::Identity => (y, F::ONE),
            OutputMap::Saturation { beta_per_um: b } => {
                if b == F::ZERO {
                    return (y, F::ONE);
                }
                let d = F::ONE + F::of(4.0) * b * y;
                if d <= F::ZERO {
                    return (-F::ONE / (two * b), F::ZERO);
                }
                let z = two * y / (F::ONE + d.sqrt());
                (z, F::ONE / (F::ONE + two * b * z))
            }
            OutputMap::Quadratic { gamma_per_um: g } => (y + g * y * y, F::ONE + two * g * y),
        }
    }

    /// `d²z/dY²` where the slope is `dz` (as [`apply`](Self::apply) returns it).
    pub fn curvature(self, dz: F) -> F {
        match self {
            OutputMap::Identity => F::ZERO,
            // z + βz² = Y: dz/dY = 1/(1 + 2βz), d²z/dY² = −2β·(dz/dY)³.
            OutputMap::Saturation { beta_per_um: b } => -F::of(2.0) * b * dz * dz * dz,
            OutputMap::Quadratic { gamma_per_um: g } => F::of(2.0) * g,
        }
    }

    /// `Y = h⁻¹(z)`.
    pub fn invert(self, z: F) -> F {
        match self {
            OutputMap::Identity => z,
            OutputMap::Saturation { beta_per_um: b } => z + b * z * z,
            OutputMap::Quadratic { gamma_per_um: g } => {
                if g == F::ZERO {
                    z
                } else {
                    let d = (F::ONE + F::of(4.0) * g * z).max(F::ZERO);
                    (d.sqrt() - F::ONE) / (F::of(2.0) * g)
                }
            }
        }
    }

    /// Whether the map is the identity.
    pub fn is_identity(self) -> bool {
        match self {
            OutputMap::Identity => true,
            OutputMap::Saturation { beta_per_um } => beta_per_um == F::ZERO,
            OutputMap::Quadratic { gamma_per_um } => gamma_per_um == F::ZERO,
        }
    }
}

impl core::fmt::Display for OutputMap<f64> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            OutputMap::Identity => write!(f, "none (x = Y)"),
            OutputMap::Saturation { beta_per_um } => {
                write!(f, "x + {beta_per_um:.3e}/µm·x² = Y")
            }
            OutputMap::Quadratic { gamma_per_um } => {
                write!(f, "x = Y + {gamma_per_um:.3e}/µm·Y²")
            }
        }
    }
}

/// A monotone map and its inverse as tables (the firmware's form of `g` and `h`):
/// below the first knot the first value is held, beyond the last the map
/// continues with slope one — the rule of the core's `fpi::Map`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableMap<'a, F> {
    /// `y = map(x)`.
    pub forward: Curve<'a, F>,
    /// `x = map⁻¹(y)`.
    pub inverse: Curve<'a, F>,
}

impl<F: Real> TableMap<'_, F> {
    fn through(t: &Curve<'_, F>, x: F) -> F {
        if x > t.x_max() {
            t.last() + (x - t.x_max())
        } else {
            t.held(x)
        }
    }
    /// `map(x)`.
    pub fn apply(&self, x: F) -> F {
        Self::through(&self.forward, x)
    }
    /// `map⁻¹(y)`.
    pub fn invert(&self, y: F) -> F {
        Self::through(&self.inverse, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_maps_and_the_dead_zone_invert() {
        for map in [
            OutputMap::Saturation { beta_per_um: 0.004 },
            OutputMap::Quadratic {
                gamma_per_um: -0.0014,
            },
            OutputMap::Identity,
        ] {
            for y in [0.0, 1.0, 7.5, 14.0] {
                let (z, _) = map.apply(y);
                assert!((map.invert(z) - y).abs() < 1e-12, "{map:?} {y}");
            }
        }
        assert!((dead_zone_inverse(1.8, dead_zone(1.8, -3.0).0) + 3.0).abs() < 1e-9);
        assert_eq!(dead_zone(0.0, -1.0), (0.0, 0.0));
    }
}
