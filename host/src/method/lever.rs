//! An analytic stage: the three-stage lever of Levy & Shapiro (Actuators 2022, the
//! second paper; §3.3, eqs. 8–12, Table 5) as a source of the stage maps `f_K` and
//! `f_F`, written in the FEM export's format `x_pea_um,preload_N,x_fhps_um`
//! ([`crate::data::fem`]), so that `fpi predict`, `fpi compare` and `fpi export`
//! take it where they take an FEM table (`fpi lever … --out fem.csv`).
//!
//! # The chain (eqs. 8–11), lengths in mm, stack extension `x` in mm
//!
//! * Lever 1 turns about point 1 by `θ₁ = atan(x/Rb₁)`: the stack pushes it at the
//!   radius `Rb₁`. Eq. 8 rotates point 2 (`X₁₂, Y₁₂`) by `θ₁`
//!   (`cos θ₁ = Rb₁/√(Rb₁²+x²)`, `sin θ₁ = x/√(Rb₁²+x²)`). `D = P₃ − P₂`, and
//!   `L₁ = √(|D|² − Rb₂²)` is the length of the tangent from point 2 to the circle
//!   of radius `Rb₂` about point 3: lever 2's face, on which lever 1's tip rides.
//! * Eq. 9: `α₃₄ = asin((L₁·D_y − Rb₂·D_x)/|D|²) + α₀`, the direction of that
//!   tangent (lever 2's face) plus the initial angular position `α₀`.
//! * Eq. 10: point 4 at `R₃₄·(sin α₃₄, cos α₃₄)` from point 3, `E = P₅ − P₄`, and
//!   `L₂ = √(|E|² − Rb₃²)`, the tangent from point 4 to lever 3's face about point 5.
//! * Eq. 11: `α_out`, the direction of lever 3's face, the same construction.
//!
//! # Load reflection (eq. 12)
//!
//! `F = T·R₁₂·R₃₄/(Rb₁·L₁·L₂)`: a torque `T` (N·mm) at the output axis reaches the
//! stack as a force (N). The ratio (1/mm) is the small-angle lever ratio
//! `dα_out/dx`; by virtual work the exact one is the slope of eqs. 8–11, which
//! [`Reflection::VirtualWork`] uses instead. The preload written is
//! `f_F(x) = stack_preload_N + (torque_Nmm + stiffness_Nmm_per_rad·θ_out(x))·ratio(x)`:
//! the stack's own assembly preload plus a constant torque and a torsional spring
//! at the output. The paper names two loads but gives no values: the defaults
//! (30 N, 2 N·mm, 2 N·mm/rad) are illustrative, chosen near stage A's preloads.
//!
//! # Where the transcription disagrees with the paper's stated strokes, and the reading chosen
//!
//! The paper states 50 µm of stack → 1.5° (lever 1) → 20° (lever 2) → 40° (output).
//! Taken literally the transcribed equations do not give that:
//!
//! 1. Eq. 8 writes `Y₁₂·h₀ + X₁₂·x` where the rotation needs `Y₁₂·Rb₁ + X₁₂·x`;
//!    `h₀` is defined nowhere. Read as `h₀ = Rb₁` (the only value that leaves point
//!    2 at `(X₁₂, Y₁₂)` at rest, where Table 5's `R₁₂ = 61.81 = |(X₁₂, Y₁₂)|`).
//!    Lever 1 then turns 1.432° for 50 µm: the stated 1.5° within 4.5 %.
//! 2. Eq. 11 as transcribed puts a square root over the sine. Its radicand is
//!    negative at rest (−0.846 with `α₀ = 0`), so it has no real angle at all. Eq. 9
//!    is the same tangent construction without the root: read without it.
//! 3. Lever 2 turns 12.12° for 50 µm whatever `α₀` is (eqs. 8–9 do not involve it),
//!    not the stated 1.5° → 20°; no reading of the transcription changes that.
//! 4. `α₀` is an input of eqs. 9–11 "the initial angular position \[deg\]" with no
//!    value given. With `α₀ = 0` the output turns only 5.39° for 50 µm. The stated
//!    40° needs point 4 to pass close to lever 3's pivot, which `α₀` sets: 40° is
//!    reached at `α₀ = 65.20°` and at `α₀ = 80.97°`. The default is **80.9678°**
//!    ([`TABLE5_ALPHA0_DEG`], solved by [`solve_alpha0`]): on that branch eq. 12's
//!    ratio agrees with the slope of eqs. 8–11 (within 0.3 % at 50 µm, 59 % high
//!    at rest), while on the other it is 1.2–5.8× the slope over 0–50 µm and the
//!    output saturates (it turns back at 77.5 µm). The 40° is therefore *fitted* through `α₀`; what
//!    eqs. 8–11 predict independently is the 1.43° of lever 1 and the 12.1° of lever 2.
//! 5. Eqs. 9–11 use `asin`, which folds at ±90°; the angles are computed as
//!    `atan2(D_y, D_x) − atan2(Rb₂, L₁)` (and likewise for eq. 11), equal to the
//!    `asin` form on its principal branch and continuous beyond it.
//! 6. Eq. 10 places point 4 at `(sin α₃₄, cos α₃₄)`, i.e. at `90° − α₃₄` from the x
//!    axis, so lever 2's arm turns against its face's direction of eq. 9: a mirror
//!    (or a frame of Fig. 7 that the text does not give). Kept as transcribed;
//!    with `(cos, sin)` the stroke is ≈ 5° for most `α₀` too.
//!
//! # Output units
//!
//! The paper's output is an angle; the table's column is `x_fhps_um`. The column
//! holds the output axis's rotation from rest, `θ_out(x) = s·(α_out(x) − α_out(0))`
//! with the sign `s` that makes it increase with the stack extension (α_out
//! decreases in the transcription's convention), either
//! * [`OutputUnit::Arc`] (default): as the arc length in µm at the radius
//!   `[output] radius_mm` (default 1 mm, where µm of arc = mrad of rotation:
//!   40° = 698.1 µm), or
//! * [`OutputUnit::Deg`]: in degrees (the column keeps its name `x_fhps_um`, since
//!   the FEM reader requires it; `fpi lever` prints a note).
//!
//! # The parameter file
//!
//! A TOML file with the sections `[geometry]` (Table 5's keys `x12_mm` … `rb3_mm`
//! and `alpha0_deg`), `[output]` (`radius_mm`) and `[load]` (`stack_preload_N`,
//! `torque_Nmm`, `stiffness_Nmm_per_rad`, `reflection = "eq12" | "virtual-work"`).
//! Every key is optional (defaults: Table 5 and the above); an unknown key, a value
//! of the wrong type or out of range is refused naming the file and the key.

use std::f64::consts::PI;
use std::path::Path;

use anyhow::{anyhow, Result};
use serde::Deserialize;

use crate::data::fem::{FemMaps, PLAUSIBLE_STACK_UM};
use crate::data::Num;
use crate::output;
use piezo_fpi::q::SIGNAL_ABS_MAX;

/// The paper's stated stack stroke, µm.
pub const PAPER_STACK_UM: f64 = 50.0;
/// The paper's stated rotations at [`PAPER_STACK_UM`]: lever 1, lever 2, output, degrees.
pub const PAPER_STAGES_DEG: [f64; 3] = [1.5, 20.0, 40.0];
/// The default `α₀`, degrees: the output turns 40° for 50 µm (module doc, item 4).
pub const TABLE5_ALPHA0_DEG: f64 = 80.9678;
/// Default number of table points: 0.125 µm (a power of two) apart over 50 µm, so
/// `fpi export` resamples `f_K` and `f_F` exactly, and `f_K⁻¹` of the arc output
/// (698 µm) within its 1e-4 µm error limit and 4000 knots (101 points do not).
pub const DEFAULT_POINTS: usize = 401;
/// Most table points `fpi lever` writes.
pub const MAX_POINTS: usize = 10_001;
/// Decimals the table is written with (as the other commands' CSVs).
const DECIMALS: i32 = 6;

/// Table 5's dimensions (all mm) and the initial angular position of eq. 9.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Geometry {
    /// X₁₂: points 1 → 2, horizontal, mm.
    pub x12_mm: f64,
    /// Y₁₂: points 1 → 2, vertical, mm.
    pub y12_mm: f64,
    /// R₁₂: distance of points 1 and 2, mm (eq. 12; must match `hypot(X₁₂, Y₁₂)`).
    pub r12_mm: f64,
    /// Rb₁: movement radius of lever 1 (where the stack pushes it), mm.
    pub rb1_mm: f64,
    /// X₁₃: points 1 → 3, horizontal, mm.
    pub x13_mm: f64,
    /// Y₁₃: points 1 → 3, vertical, mm.
    pub y13_mm: f64,
    /// Rb₂: movement radius of lever 2 (its face's offset from point 3), mm.
    pub rb2_mm: f64,
    /// R₃₄: distance of points 3 and 4, mm.
    pub r34_mm: f64,
    /// X₃₅: points 3 → 5, horizontal, mm.
    pub x35_mm: f64,
    /// Y₃₅: points 3 → 5, vertical, mm.
    pub y35_mm: f64,
    /// Rb₃: movement radius of lever 3, mm.
    pub rb3_mm: f64,
    /// α₀: initial angular position of eq. 9, degrees (not given by the paper).
    pub alpha0_deg: f64,
}

impl Default for Geometry {
    fn default() -> Self {
        Self {
            x12_mm: 60.43,
            y12_mm: 13.0,
            r12_mm: 61.81,
            rb1_mm: 2.0,
            x13_mm: 65.31,
            y13_mm: 20.50,
            rb2_mm: 4.36,
            r34_mm: 30.0,
            x35_mm: 36.0,
            y35_mm: 0.044,
            rb3_mm: 4.48,
            alpha0_deg: TABLE5_ALPHA0_DEG,
        }
    }
}

/// The output axis's arm, for the arc-length column.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputArm {
    /// Radius at which the output's arc length is written, mm.
    pub radius_mm: f64,
}

impl Default for OutputArm {
    fn default() -> Self {
        Self { radius_mm: 1.0 }
    }
}

/// How the output load reaches the stack.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum Reflection {
    /// Eq. 12: the ratio `R₁₂·R₃₄/(Rb₁·L₁·L₂)`.
    #[default]
    #[serde(rename = "eq12")]
    Eq12,
    /// Virtual work: the slope `|dα_out/dx|` of eqs. 8–11.
    #[serde(rename = "virtual-work")]
    VirtualWork,
}

impl Reflection {
    /// The name the parameter file uses.
    pub fn name(self) -> &'static str {
        match self {
            Self::Eq12 => "eq. 12",
            Self::VirtualWork => "virtual-work",
        }
    }
}

/// The load on the stage: the stack's own preload and the load at the output.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Load {
    /// The stack's assembly preload with no output load, N.
    #[serde(rename = "stack_preload_N")]
    pub stack_preload_n: f64,
    /// Constant external torque at the output axis, N·mm.
    #[serde(rename = "torque_Nmm")]
    pub torque_nmm: f64,
    /// Torsional stiffness of an external spring at the output, N·mm/rad.
    #[serde(rename = "stiffness_Nmm_per_rad")]
    pub stiffness_nmm_per_rad: f64,
    /// How the load reaches the stack (eq. 12 by default).
    pub reflection: Reflection,
}

impl Default for Load {
    fn default() -> Self {
        Self {
            stack_preload_n: 30.0,
            torque_nmm: 2.0,
            stiffness_nmm_per_rad: 2.0,
            reflection: Reflection::Eq12,
        }
    }
}

/// A lever stage's parameters (the `--params` file).
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LeverParams {
    /// Table 5 and α₀.
    pub geometry: Geometry,
    /// The output arm of the arc-length column.
    pub output: OutputArm,
    /// The load.
    pub load: Load,
}

/// What a key's value must be.
#[derive(Clone, Copy)]
enum Rule {
    /// Any finite number.
    Finite,
    /// A finite number > 0.
    Positive,
    /// A finite number ≥ 0.
    NonNegative,
}

impl LeverParams {
    /// Reads and validates a parameter file; errors name the file and the key.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow!("{}: cannot read: {e}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parameters from the text of a file named `name` (for messages).
    pub fn parse(text: &str, name: &str) -> Result<Self> {
        let p: Self = toml::from_str(text).map_err(|e| {
            anyhow!(piezo_sim::quote::toml_error(
                name,
                "lever parameter file",
                text,
                &e
            ))
        })?;
        p.validate().map_err(|e| anyhow!("{name}: {e}"))?;
        Ok(p)
    }

    /// The keys and their values, with the rule each follows.
    fn keys(&self) -> [(&'static str, f64, Rule); 16] {
        let (g, l) = (&self.geometry, &self.load);
        use Rule::*;
        [
            ("geometry.x12_mm", g.x12_mm, Finite),
            ("geometry.y12_mm", g.y12_mm, Finite),
            ("geometry.r12_mm", g.r12_mm, Positive),
            ("geometry.rb1_mm", g.rb1_mm, Positive),
            ("geometry.x13_mm", g.x13_mm, Finite),
            ("geometry.y13_mm", g.y13_mm, Finite),
            ("geometry.rb2_mm", g.rb2_mm, Positive),
            ("geometry.r34_mm", g.r34_mm, Positive),
            ("geometry.x35_mm", g.x35_mm, Finite),
            ("geometry.y35_mm", g.y35_mm, Finite),
            ("geometry.rb3_mm", g.rb3_mm, Positive),
            ("geometry.alpha0_deg", g.alpha0_deg, Finite),
            ("output.radius_mm", self.output.radius_mm, Positive),
            ("load.stack_preload_N", l.stack_preload_n, Finite),
            ("load.torque_Nmm", l.torque_nmm, Finite),
            (
                "load.stiffness_Nmm_per_rad",
                l.stiffness_nmm_per_rad,
                NonNegative,
            ),
        ]
    }

    /// Checks every value; the error starts with the key (`geometry.rb1_mm = -2: …`).
    pub fn validate(&self) -> Result<(), String> {
        for (key, v, rule) in self.keys() {
            let why = match rule {
                Rule::Finite if !v.is_finite() => "must be a finite number",
                Rule::Positive if !(v.is_finite() && v > 0.0) => "must be a finite number > 0",
                Rule::NonNegative if !(v.is_finite() && v >= 0.0) => "must be a finite number ≥ 0",
                _ => continue,
            };
            return Err(format!("{key} = {}: {why}", Num(v)));
        }
        if self.geometry.alpha0_deg.abs() > 360.0 {
            let a = self.geometry.alpha0_deg;
            return Err(format!(
                "geometry.alpha0_deg = {}: an angle within ±360°",
                Num(a)
            ));
        }
        self.geometry.check_r12()?;
        self.geometry.pose(0.0).map(|_| ())
    }
}

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
    fn check_r12(&self) -> Result<(), String> {
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
fn wrap(a: f64) -> f64 {
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

/// What the `x_fhps_um` column holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum OutputUnit {
    /// The output's arc length at `[output] radius_mm`, µm.
    #[default]
    Arc,
    /// The output's rotation, degrees.
    Deg,
}

/// The analytic stage table and what went into it.
#[derive(Debug, Clone, PartialEq)]
pub struct LeverTable {
    /// Stack extension, µm (uniform from 0).
    pub x_pea_um: Vec<f64>,
    /// `f_F`: the preload on the stack, N.
    pub preload_n: Vec<f64>,
    /// `f_K`: the output, µm of arc or degrees ([`OutputUnit`]).
    pub x_fhps: Vec<f64>,
    /// The output's rotation from rest, degrees (increasing).
    pub output_deg: Vec<f64>,
    /// The reflection ratio used for the preload, 1/mm.
    pub ratio_per_mm: Vec<f64>,
}

/// `v` rounded as the table is written.
fn rounded(v: f64) -> f64 {
    let s = 10f64.powi(DECIMALS);
    (v * s).round() / s
}

/// The stage table over `0..=stroke_um` of stack in `points` points.
pub fn table(
    p: &LeverParams,
    stroke_um: f64,
    points: usize,
    unit: OutputUnit,
) -> Result<LeverTable, String> {
    check_grid(stroke_um, points)?;
    let g = &p.geometry;
    let x_pea_um: Vec<f64> = (0..points)
        .map(|i| rounded(stroke_um * i as f64 / (points - 1) as f64))
        .collect();
    let poses = x_pea_um
        .iter()
        .map(|x| g.pose(x * 1e-3))
        .collect::<Result<Vec<_>, _>>()?;
    let rotation = unwrapped_rotation(&poses);
    let output_deg: Vec<f64> = rotation.iter().map(|r| r.to_degrees()).collect();
    let x_fhps: Vec<f64> = match unit {
        OutputUnit::Arc => rotation
            .iter()
            .map(|r| rounded(r * p.output.radius_mm * 1e3))
            .collect(),
        OutputUnit::Deg => output_deg.iter().map(|d| rounded(*d)).collect(),
    };
    check_monotone(&x_pea_um, &x_fhps, g)?;
    let ratio_per_mm = reflection_ratios(p, &x_pea_um, &poses)?;
    let preload_n: Vec<f64> = rotation
        .iter()
        .zip(&ratio_per_mm)
        .map(|(r, k)| {
            let torque = p.load.torque_nmm + p.load.stiffness_nmm_per_rad * r;
            rounded(p.load.stack_preload_n + torque * k)
        })
        .collect();
    check_range(p, &x_fhps, &preload_n)?;
    Ok(LeverTable {
        x_pea_um,
        preload_n,
        x_fhps,
        output_deg,
        ratio_per_mm,
    })
}

/// Refuses outputs or preloads the FEM reader would refuse (beyond
/// ±[`SIGNAL_ABS_MAX`] µm or N), naming the keys that set them.
fn check_range(p: &LeverParams, x_fhps: &[f64], preload_n: &[f64]) -> Result<(), String> {
    let top = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let (y, f) = (top(x_fhps), top(preload_n));
    if y > SIGNAL_ABS_MAX {
        return Err(format!(
            "the output reaches {} (output.radius_mm = {}), beyond the ±{SIGNAL_ABS_MAX} an \
             FEM table holds: a smaller output.radius_mm or --output deg",
            Num(y),
            Num(p.output.radius_mm)
        ));
    }
    if f > SIGNAL_ABS_MAX {
        return Err(format!(
            "the preload reaches {} N, beyond the ±{SIGNAL_ABS_MAX} N an FEM table holds \
             (load.stack_preload_N, load.torque_Nmm, load.stiffness_Nmm_per_rad)",
            Num(f)
        ));
    }
    Ok(())
}

/// Refuses a stroke or a count of points the table cannot be written with.
fn check_grid(stroke_um: f64, points: usize) -> Result<(), String> {
    if !(stroke_um.is_finite() && stroke_um > 0.0 && stroke_um <= PLAUSIBLE_STACK_UM) {
        return Err(format!(
            "--stroke-um {}: a stack stroke > 0 and ≤ {PLAUSIBLE_STACK_UM} µm",
            Num(stroke_um)
        ));
    }
    if !(2..=MAX_POINTS).contains(&points) {
        return Err(format!("--points {points}: 2..={MAX_POINTS} points"));
    }
    let step = stroke_um / (points - 1) as f64;
    if step < 1e-3 {
        return Err(format!(
            "--points {points} over --stroke-um {}: steps of {} µm, below the 0.001 µm \
             the table resolves",
            Num(stroke_um),
            Num(step)
        ));
    }
    Ok(())
}

/// The output's rotation from rest at each pose, rad, unwrapped and signed to
/// increase with the stack extension (the sign of the whole stroke).
fn unwrapped_rotation(poses: &[Pose]) -> Vec<f64> {
    let mut rot = Vec::with_capacity(poses.len());
    let mut acc = 0.0;
    rot.push(0.0);
    for w in poses.windows(2) {
        acc += wrap(w[1].alpha_out_rad - w[0].alpha_out_rad);
        rot.push(acc);
    }
    let sign = if acc < 0.0 { -1.0 } else { 1.0 };
    // `+ 0.0` turns the rest's −0 into 0.
    rot.iter().map(|r| sign * r + 0.0).collect()
}

/// Refuses an output that is not strictly increasing (as written).
fn check_monotone(x_pea_um: &[f64], x_fhps: &[f64], g: &Geometry) -> Result<(), String> {
    match x_fhps.windows(2).position(|w| w[1] <= w[0]) {
        None => Ok(()),
        Some(i) => Err(format!(
            "the output turns back (or stalls) at {} µm of stack: f_K is not strictly \
             monotone over --stroke-um {} with geometry.alpha0_deg = {} (the \
             inverse kinematics needs it); lower --stroke-um or change the geometry",
            Num(x_pea_um[i]),
            Num(x_pea_um[x_pea_um.len() - 1]),
            Num(g.alpha0_deg)
        )),
    }
}

/// The reflection ratio at each point, 1/mm.
fn reflection_ratios(
    p: &LeverParams,
    x_pea_um: &[f64],
    poses: &[Pose],
) -> Result<Vec<f64>, String> {
    let g = &p.geometry;
    match p.load.reflection {
        Reflection::Eq12 => Ok(poses.iter().map(|q| g.eq12_ratio_per_mm(q)).collect()),
        Reflection::VirtualWork => x_pea_um
            .iter()
            .map(|x| g.slope_rad_per_mm(x * 1e-3))
            .collect(),
    }
}

/// Writes the table `x_pea_um,preload_N,x_fhps_um` atomically.
pub fn write(path: &Path, t: &LeverTable) -> Result<()> {
    output::write_atomic_with(path, |w| {
        writeln!(w, "x_pea_um,preload_N,x_fhps_um")?;
        for i in 0..t.x_pea_um.len() {
            writeln!(
                w,
                "{:.6},{:.6},{:.6}",
                t.x_pea_um[i], t.preload_n[i], t.x_fhps[i]
            )?;
        }
        Ok(())
    })
}

/// `fpi lever`: the table from `params` (Table 5 if `None`) into `out`, read back
/// through the FEM reader; prints the strokes against the paper's.
pub fn command(
    params: Option<&Path>,
    out: &Path,
    points: usize,
    stroke_um: f64,
    unit: OutputUnit,
) -> Result<()> {
    if let Some(p) = params {
        output::not_an_input("--out", out, &[("--params", p)])?;
    }
    output::prepare(out)?;
    check_grid(stroke_um, points).map_err(|e| anyhow!(e))?;
    let p = match params {
        Some(path) => LeverParams::read(path)?,
        None => LeverParams::default(),
    };
    let name = params.map_or("Table 5 (built in)".to_string(), |p| {
        p.display().to_string()
    });
    let t = table(&p, stroke_um, points, unit).map_err(|e| anyhow!("{name}: {e}"))?;
    write(out, &t)?;
    let back = FemMaps::read(out)?;
    for w in back.warnings() {
        eprintln!("warning: {w}");
    }
    print_summary(&p, &name, &t, unit, stroke_um)?;
    println!(
        "written to {} and read back through the FEM reader: {} points, {} warning(s)",
        out.display(),
        back.x_pea().len(),
        back.warnings().len()
    );
    Ok(())
}

/// Prints the strokes, the paper's figures and the table's ranges.
fn print_summary(
    p: &LeverParams,
    name: &str,
    t: &LeverTable,
    unit: OutputUnit,
    stroke_um: f64,
) -> Result<()> {
    let g = &p.geometry;
    let n = t.x_pea_um.len() - 1;
    println!(
        "lever chain ({name}, α₀ = {}°): {} points over 0..{} µm of stack",
        Num(g.alpha0_deg),
        n + 1,
        Num(stroke_um)
    );
    let at = |x: f64| g.strokes_deg(x).map_err(|e| anyhow!("{name}: {e}"));
    let [s1, s2, s3] = at(stroke_um)?;
    println!(
        "  at {} µm: lever 1 {s1:.3}°, lever 2 {s2:.3}°, output {s3:.3}°",
        Num(stroke_um)
    );
    let [p1, p2, p3] = at(PAPER_STACK_UM)?;
    let [q1, q2, q3] = PAPER_STAGES_DEG;
    println!(
        "  at the paper's {PAPER_STACK_UM} µm: lever 1 {p1:.3}° (paper {q1}°), lever 2 \
         {p2:.3}° (paper {q2}°), output {p3:.3}° (paper {q3}°)"
    );
    let what = match unit {
        OutputUnit::Arc => format!("µm of arc at {} mm", Num(p.output.radius_mm)),
        OutputUnit::Deg => "degrees (the column keeps its name x_fhps_um)".to_string(),
    };
    println!(
        "  f_K: {:.3} .. {:.3} ({what}); f_F: {:.3} .. {:.3} N ({} ratio {:.3} .. {:.3} 1/mm)",
        t.x_fhps[0],
        t.x_fhps[n],
        t.preload_n[0],
        t.preload_n[n],
        p.load.reflection.name(),
        t.ratio_per_mm[0],
        t.ratio_per_mm[n]
    );
    if unit == OutputUnit::Deg {
        println!(
            "note: --output deg: column x_fhps_um holds the output's rotation in degrees, not µm"
        );
    }
    Ok(())
}
