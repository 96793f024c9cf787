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

mod params;
pub use params::{Geometry, LeverParams, Load, OutputArm, Reflection};
mod kinematics;
use kinematics::wrap;
pub use kinematics::{solve_alpha0, Pose};

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
