//! A stage's FEM export (Actuators 2025, 14(8):411, Part II) read from its file: the points of
//! the preload `f_F(x_pea)` and the stage output `f_K(x_pea)`, validated, and the
//! maps through them ([`piezo_sim::fem::Fem`], linear between the points).
//!
//! Reading refuses values no stage has and the firmware cannot hold (beyond
//! ±[`SIGNAL_ABS_MAX`] µm or N), and keeps warnings, each with the number and the
//! line that triggered it, for values that are possible but implausible (a unit
//! slip, a stack under tension, an extreme lever ratio).

use std::path::Path;

use piezo_sim::curve::Curve;
use piezo_sim::fem::Fem;

use piezo_fpi::q::SIGNAL_ABS_MAX;

use crate::data::{self, DataError, Num};

/// Longest plausible stack extension, µm (piezo stacks reach 300 µm at most).
pub const PLAUSIBLE_STACK_UM: f64 = 500.0;
/// Shortest plausible span of stack extension, µm (below: a unit slip, m or mm).
pub const PLAUSIBLE_SPAN_UM: f64 = 0.01;
/// Largest plausible preload, N.
pub const PLAUSIBLE_PRELOAD_N: f64 = 2000.0;
/// Plausible lever ratios of a stage, output over stack travel.
pub const PLAUSIBLE_RATIO: (f64, f64) = (0.01, 100.0);

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
    /// Implausible values found on reading, each naming the file, line and column.
    warnings: Vec<String>,
}

impl FemMaps {
    /// Reads and validates an FEM export (`x_pea_um,preload_N,x_fhps_um`): finite
    /// values within ±[`SIGNAL_ABS_MAX`], strictly increasing `x_pea_um`, strictly
    /// monotone `x_fhps_um`. Implausible values are kept as [`warnings`](Self::warnings).
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let fem = data::read_fem(path)?;
        in_range(&fem)?;
        monotone_output(&fem)?;
        let warnings = plausibility(&fem);
        let mut maps = Self::new(
            fem.path.display().to_string(),
            fem.x_pea,
            fem.preload,
            fem.x_fhps,
        )
        .ok_or_else(|| DataError::file(path, "an FEM table needs at least two points"))?;
        maps.warnings = warnings;
        Ok(maps)
    }

    /// What looked implausible in the file (empty for maps made with [`new`](Self::new)).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
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
            warnings: Vec::new(),
        })
    }

    /// The maps of a built stage that differs from this FEM: new points with stage
    /// output `x_fhps·gain + offset_um` and preload `preload·preload_scale` (the
    /// same stack extensions), checked as a file's points are (within
    /// ±[`SIGNAL_ABS_MAX`], strictly monotone output; a `gain` that is not finite
    /// or not > 0 is refused). The source and the file's warnings are kept.
    pub fn corrected(
        &self,
        gain: f64,
        offset_um: f64,
        preload_scale: f64,
    ) -> Result<Self, DataError> {
        let path = Path::new(&self.source);
        for (what, v) in [("stage gain", gain), ("preload scale", preload_scale)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(DataError::file(
                    path,
                    format!("a {what} of {} (it must be a finite number > 0)", Num(v)),
                ));
            }
        }
        if !offset_um.is_finite() {
            return Err(DataError::file(
                path,
                format!("a stage offset of {} µm is not finite", Num(offset_um)),
            ));
        }
        let fem = data::Fem {
            path: path.to_path_buf(),
            x_pea: self.x_pea.clone(),
            preload: self.preload.iter().map(|f| f * preload_scale).collect(),
            x_fhps: self.x_fhps.iter().map(|y| y * gain + offset_um).collect(),
        };
        in_range(&fem)?;
        monotone_output(&fem)?;
        let mut maps = Self::new(self.source.clone(), fem.x_pea, fem.preload, fem.x_fhps)
            .ok_or_else(|| DataError::file(path, "an FEM table needs at least two points"))?;
        maps.warnings = self.warnings.clone();
        Ok(maps)
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

/// The line of data row `i` (0-based; the header is line 1).
fn line(i: usize) -> u64 {
    i as u64 + 2
}

/// Refuses values beyond ±[`SIGNAL_ABS_MAX`] µm or N: no stage comes near them,
/// the firmware's fixed-point signals cannot hold them, and a prediction through
/// them would be meaningless (e.g. a preload of 1e300 N).
fn in_range(fem: &data::Fem) -> Result<(), DataError> {
    let columns = [
        ("x_pea_um", "µm", &fem.x_pea),
        ("preload_N", "N", &fem.preload),
        ("x_fhps_um", "µm", &fem.x_fhps),
    ];
    for (column, unit, values) in columns {
        if let Some(i) = values.iter().position(|v| v.abs() > SIGNAL_ABS_MAX) {
            return Err(DataError::at(
                &fem.path,
                line(i),
                column,
                format!(
                    "{} {unit} is outside ±{SIGNAL_ABS_MAX} {unit}: no stage comes near it, and \
                     the firmware's fixed-point signals cannot hold it",
                    Num(values[i])
                ),
            ));
        }
    }
    Ok(())
}

/// Refuses a stage output that is not strictly monotone in the stack extension.
fn monotone_output(fem: &data::Fem) -> Result<(), DataError> {
    let up = fem.x_fhps[fem.x_fhps.len() - 1] > fem.x_fhps[0];
    for (i, w) in fem.x_fhps.windows(2).enumerate() {
        if (up && w[1] <= w[0]) || (!up && w[1] >= w[0]) {
            return Err(DataError::at(
                &fem.path,
                line(i + 1),
                "x_fhps_um",
                format!(
                    "{} after {}: the stage output must be strictly monotone in the stack \
                     extension for the inverse kinematics",
                    w[1], w[0]
                ),
            ));
        }
    }
    Ok(())
}

/// The row of the largest value of a column by `key`.
fn arg_max(values: &[f64], key: impl Fn(f64) -> f64) -> usize {
    (0..values.len())
        .max_by(|&a, &b| key(values[a]).total_cmp(&key(values[b])))
        .unwrap_or(0)
}

/// Warnings for possible but implausible values, each with its number and line.
fn plausibility(fem: &data::Fem) -> Vec<String> {
    let at = |i: usize, column: &str, m: String| {
        DataError::at(&fem.path, line(i), column, m).to_string()
    };
    let n = fem.x_pea.len() - 1;
    let (x0, x1) = (fem.x_pea[0], fem.x_pea[n]);
    let mut w = Vec::new();
    let i = arg_max(&fem.x_pea, f64::abs);
    if fem.x_pea[i].abs() > PLAUSIBLE_STACK_UM {
        w.push(at(
            i,
            "x_pea_um",
            format!(
            "{} µm: longer than any piezo stack's stroke (at most ~300 µm); is the column in µm?",
            fem.x_pea[i]
        ),
        ));
    }
    if x1 - x0 < PLAUSIBLE_SPAN_UM {
        w.push(at(n, "x_pea_um", format!(
            "the table spans only {} µm of stack extension: is the column in m or mm instead of µm?",
            x1 - x0
        )));
    }
    if !(x0..=x1).contains(&0.0) {
        w.push(at(
            0,
            "x_pea_um",
            format!(
                "the table covers {x0}..{x1} µm, not 0: the rest preload f_F(0) is extrapolated"
            ),
        ));
    }
    w.extend(preload_warnings(fem, &at));
    let ratio = (fem.x_fhps[n] - fem.x_fhps[0]).abs() / (x1 - x0);
    if !(PLAUSIBLE_RATIO.0..=PLAUSIBLE_RATIO.1).contains(&ratio) {
        w.push(at(
            n,
            "x_fhps_um",
            format!(
                "the stage output moves {ratio:.3e} µm per µm of stack: a lever ratio outside \
             {}..{} (a unit slip?)",
                PLAUSIBLE_RATIO.0, PLAUSIBLE_RATIO.1
            ),
        ));
    }
    w
}

/// Warnings for a preload that pulls the stack or is implausibly large.
fn preload_warnings(fem: &data::Fem, at: &impl Fn(usize, &str, String) -> String) -> Vec<String> {
    let mut w = Vec::new();
    let lo = arg_max(&fem.preload, |v| -v);
    if fem.preload[lo] < 0.0 {
        w.push(at(
            lo,
            "preload_N",
            format!(
                "{} N: the stack is under tension there (a preload presses it: > 0 N)",
                fem.preload[lo]
            ),
        ));
    }
    let hi = arg_max(&fem.preload, |v| v);
    if fem.preload[hi] > PLAUSIBLE_PRELOAD_N {
        w.push(at(
            hi,
            "preload_N",
            format!(
                "{} N: more than the {PLAUSIBLE_PRELOAD_N} N a stage's preload plausibly reaches; \
             is the column in N?",
                fem.preload[hi]
            ),
        ));
    }
    w
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

    #[test]
    fn corrected_maps_scale_the_points() {
        let fem = FemMaps::new(
            "f".into(),
            vec![0.0, 1.0, 3.0],
            vec![10.0, 12.0, 13.0],
            vec![0.0, 5.0, 15.0],
        )
        .unwrap();
        let c = fem.corrected(0.98, 0.25, 0.97).unwrap();
        assert_eq!(c.x_pea(), fem.x_pea());
        assert!((c.preload_at(2.0) - 0.97 * fem.preload_at(2.0)).abs() < 1e-12);
        assert!((c.stage_at(2.0) - (0.98 * fem.stage_at(2.0) + 0.25)).abs() < 1e-12);
        assert!((c.rest_preload() - 9.7).abs() < 1e-12);
        assert_eq!(fem.corrected(1.0, 0.0, 1.0).unwrap(), fem);
        for (g, o, s) in [(0.0, 0.0, 1.0), (1.0, 0.0, f64::NAN), (1.0, 1e12, 1.0)] {
            let e = fem.corrected(g, o, s).unwrap_err().to_string();
            assert!(e.starts_with("f"), "{e}");
        }
    }
}
