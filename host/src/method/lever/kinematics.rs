//! The chain's kinematics (eqs. 8–11): its pose at a stack extension, and the
//! initial angular position of eq. 9 solved from the geometry.

use super::*;

/// The chain's pose at one stack extension (eqs. 8–11).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Lever 1's rotation `atan(x/Rb₁)`, rad.
    pub theta1_rad: f64,
    /// Eq. 8: the arm of lever 2 (tangent length from point 2), mm.
    pub l1_mm: f64,
    /// Eq. 9: lever 2's angle (α₀ included), rad.
    pub alpha34_rad: f64,
    /// Eq. 10: the arm of lever 3 (tangent length from point 4), mm.
    pub l2_mm: f64,
    /// Eq. 11: the output's angle, rad.
    pub alpha_out_rad: f64,
    /// Eq. 11's bracket as transcribed (under its square root), dimensionless.
    pub eq11_radicand: f64,
}

impl Geometry {
    /// Refuses an `R₁₂` that is not the distance of points 1 and 2 (within 1 %).
    pub(super) fn check_r12(&self) -> Result<(), String> {
        let r = self.x12_mm.hypot(self.y12_mm);
        if (self.r12_mm - r).abs() > 0.01 * r {
            return Err(format!(
                "geometry.r12_mm = {}: R₁₂ is the distance of points 1 and 2, but \
                 hypot(x12_mm, y12_mm) = {:.3} mm (more than 1 % apart)",
                Num(self.r12_mm),
                r
            ));
        }
        Ok(())
    }

    /// The pose at stack extension `x_mm` (mm); an error names the keys whose
    /// geometry loses a contact there.
    pub fn pose(&self, x_mm: f64) -> Result<Pose, String> {
        let c = self.rb1_mm.hypot(x_mm);
        let p2x = (self.x12_mm * self.rb1_mm - self.y12_mm * x_mm) / c;
        let p2y = (self.y12_mm * self.rb1_mm + self.x12_mm * x_mm) / c;
        let (dx, dy) = (self.x13_mm - p2x, self.y13_mm - p2y);
        let l1 = tangent(dx, dy, self.rb2_mm).ok_or_else(|| {
            lost(
                x_mm,
                "lever 1's tip (point 2)",
                "lever 2",
                "x13_mm, y13_mm, rb2_mm",
            )
        })?;
        let alpha34 = dy.atan2(dx) - self.rb2_mm.atan2(l1) + self.alpha0_deg.to_radians();
        let ex = self.x35_mm - self.r34_mm * alpha34.sin();
        let ey = self.y35_mm - self.r34_mm * alpha34.cos();
        let l2 = tangent(ex, ey, self.rb3_mm).ok_or_else(|| {
            lost(
                x_mm,
                "lever 2's point 4",
                "lever 3",
                "x35_mm, y35_mm, rb3_mm, r34_mm, alpha0_deg",
            )
        })?;
        Ok(Pose {
            theta1_rad: (x_mm / self.rb1_mm).atan(),
            l1_mm: l1,
            alpha34_rad: alpha34,
            l2_mm: l2,
            alpha_out_rad: ey.atan2(ex) - self.rb3_mm.atan2(l2),
            eq11_radicand: (l2 * ey - self.rb3_mm * ex) / (ex * ex + ey * ey),
        })
    }

    /// Eq. 12's ratio `R₁₂·R₃₄/(Rb₁·L₁·L₂)` at a pose, 1/mm (N at the stack per
    /// N·mm at the output).
    pub fn eq12_ratio_per_mm(&self, pose: &Pose) -> f64 {
        self.r12_mm * self.r34_mm / (self.rb1_mm * pose.l1_mm * pose.l2_mm)
    }

    /// The slope `|dα_out/dx|` of eqs. 8–11 at `x_mm`, rad/mm (central difference).
    pub fn slope_rad_per_mm(&self, x_mm: f64) -> Result<f64, String> {
        let h = 1e-7;
        let (a, b) = (self.pose(x_mm - h)?, self.pose(x_mm + h)?);
        Ok((wrap(b.alpha_out_rad - a.alpha_out_rad) / (2.0 * h)).abs())
    }

    /// Rotations from rest at stack extension `x_um` (µm): lever 1, lever 2 and the
    /// output, degrees, each as a magnitude.
    pub fn strokes_deg(&self, x_um: f64) -> Result<[f64; 3], String> {
        let (p0, p) = (self.pose(0.0)?, self.pose(x_um * 1e-3)?);
        Ok([
            p.theta1_rad.to_degrees().abs(),
            wrap(p.alpha34_rad - p0.alpha34_rad).to_degrees().abs(),
            wrap(p.alpha_out_rad - p0.alpha_out_rad).to_degrees().abs(),
        ])
    }
}

/// The tangent length from a point at `(dx, dy)` from a centre to the circle of
/// radius `r` about it; `None` when the point is inside the circle.
fn tangent(dx: f64, dy: f64, r: f64) -> Option<f64> {
    let s = dx * dx + dy * dy - r * r;
    (s > 0.0).then(|| s.sqrt())
}

/// The message for a contact lost at `x_mm`.
fn lost(x_mm: f64, what: &str, on: &str, keys: &str) -> String {
    format!(
        "at {} µm of stack {what} is inside {on}'s movement radius: no contact \
         (check geometry: {keys})",
        Num(x_mm * 1e3)
    )
}

/// An angle difference wrapped into (−π, π], rad.
pub(super) fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI {
        w - 2.0 * PI
    } else {
        w
    }
}

/// The α₀ (degrees, within `lo_deg..hi_deg`) at which the output turns
/// `stroke_deg` for `stack_um` of stack, by bisection; `None` if the stroke does
/// not cross `stroke_deg` between the ends or a contact is lost.
pub fn solve_alpha0(
    geometry: &Geometry,
    stack_um: f64,
    stroke_deg: f64,
    (lo_deg, hi_deg): (f64, f64),
) -> Option<f64> {
    let f = |a: f64| -> Option<f64> {
        let g = Geometry {
            alpha0_deg: a,
            ..*geometry
        };
        Some(g.strokes_deg(stack_um).ok()?[2] - stroke_deg)
    };
    let (mut lo, mut hi) = (lo_deg, hi_deg);
    let mut f_lo = f(lo)?;
    if f_lo * f(hi)? > 0.0 {
        return None;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        let f_mid = f(mid)?;
        if f_lo * f_mid <= 0.0 {
            hi = mid;
        } else {
            (lo, f_lo) = (mid, f_mid);
        }
    }
    Some(0.5 * (lo + hi))
}
