//! A stage's FEM tables over several stacks: the preload on every stack and the
//! output of every axis, tabulated over the stacks' extensions (a full tensor
//! grid), multilinear between the points.
//!
//! The file (`x_pea_um@x,x_pea_um@y,preload_N@x,preload_N@y,x_fhps_um@x,x_fhps_um@y`,
//! one row per grid point, any order) is what an FEM sweep of a parallel-kinematic
//! stage exports: prescribe every stack's extension, read every stack's reaction
//! and every axis's output. [`FemGrid::design`] writes the XY and XYZ stages'
//! grids from their design (stage A's FEM per axis, the couplings of
//! [`piezo_sim::axes`]).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{bail, Result};
use piezo_sim::axes::{coupling_of, AXIS_NAMES, MAX_AXES};
use piezo_sim::solve::PreloadMap;
use piezo_sim::stage::stage_a;

use crate::data::columns::{axes_in_header, read_named_columns};
use crate::data::fem::FemMaps;
use crate::data::DataError;
use crate::output;

/// A column of the grid file for `axis` (`x_pea_um@y`).
pub fn column(name: &str, axis: usize) -> String {
    format!("{name}@{}", AXIS_NAMES[axis])
}

/// The three quantities of a grid file, per axis.
const QUANTITIES: [&str; 3] = ["x_pea_um", "preload_N", "x_fhps_um"];

/// FEM tables over the extensions of `axes()` stacks.
#[derive(Debug, Clone, PartialEq)]
pub struct FemGrid {
    /// Where the tables came from (a file, or the design's name).
    pub source: String,
    /// Each stack's grid extensions, µm (strictly increasing, at least two).
    knots: Vec<Vec<f64>>,
    /// Preload on each stack at every grid point, N (row-major, axis 0 slowest).
    preload: Vec<Vec<f64>>,
    /// Output of each axis at every grid point, µm.
    output: Vec<Vec<f64>>,
}

impl FemGrid {
    /// Tables from knots and values (row-major, axis 0 slowest); `None` unless
    /// 1..=3 axes, at least two strictly increasing knots each, and one value per
    /// grid point in every table.
    pub fn new(
        source: String,
        knots: Vec<Vec<f64>>,
        preload: Vec<Vec<f64>>,
        output: Vec<Vec<f64>>,
    ) -> Option<Self> {
        let n = knots.len();
        let points: usize = knots.iter().map(Vec::len).product();
        let ok = (1..=MAX_AXES).contains(&n)
            && knots
                .iter()
                .all(|k| k.len() >= 2 && k.windows(2).all(|w| w[0] < w[1]))
            && preload.len() == n
            && output.len() == n
            && preload.iter().chain(&output).all(|t| t.len() == points);
        ok.then_some(Self {
            source,
            knots,
            preload,
            output,
        })
    }

    /// The design of the XY (`axes` 2) or XYZ (3) stage: every axis stage A's FEM
    /// (`stage-a/fem.csv`, the twin's tables) with every `every`-th of its points,
    /// each stack's preload raised by the couplings' N per µm of the other stacks'
    /// extensions, each axis's output by their µm per µm of the other axes'
    /// own outputs ([`piezo_sim::axes::coupling_of`]).
    pub fn design(axes: usize, every: usize) -> Option<Self> {
        if !(2..=MAX_AXES).contains(&axes) || every == 0 {
            return None;
        }
        let p = &stage_a::PARAMS;
        let pick = |v: &[f32]| -> Vec<f64> { v.iter().step_by(every).map(|&x| x as f64).collect() };
        let (x, f, k) = (
            pick(p.fem_x_pea_um),
            pick(p.fem_force_n),
            pick(p.fem_output_um),
        );
        let c = coupling_of(axes);
        let m = x.len();
        let points = m.pow(axes as u32);
        let mut preload = vec![Vec::with_capacity(points); axes];
        let mut output = vec![Vec::with_capacity(points); axes];
        for flat in 0..points {
            let idx = unflatten(flat, axes, m);
            for i in 0..axes {
                let others = (0..axes).filter(|&j| j != i);
                let fi = f[idx[i]]
                    + others
                        .clone()
                        .map(|j| c.preload_n_per_um[i][j] as f64 * x[idx[j]])
                        .sum::<f64>();
                let ki = k[idx[i]]
                    + others
                        .map(|j| c.cross_um_per_um[i][j] as f64 * k[idx[j]])
                        .sum::<f64>();
                preload[i].push(fi);
                output[i].push(ki);
            }
        }
        let name = if axes == 2 { "xy" } else { "xyz" };
        Self::new(
            format!("the {name} stage's design"),
            vec![x; axes],
            preload,
            output,
        )
    }

    /// Stacks (axes) of the grid.
    pub fn axes(&self) -> usize {
        self.knots.len()
    }

    /// Stack `i`'s grid extensions, µm.
    pub fn knots(&self, i: usize) -> &[f64] {
        &self.knots[i]
    }

    /// Grid points.
    pub fn points(&self) -> usize {
        self.preload[0].len()
    }

    /// The preload on stack `i` (N) with the stacks at extensions `x` (µm).
    pub fn preload_at(&self, i: usize, x: &[f64]) -> f64 {
        self.interpolate(&self.preload[i], x)
    }

    /// The output of axis `i` (µm) with the stacks at extensions `x` (µm).
    pub fn output_at(&self, i: usize, x: &[f64]) -> f64 {
        self.interpolate(&self.output[i], x)
    }

    /// The grid of a built stage whose stack `i` and axis `i` differ from this
    /// FEM as a one-axis stage's do ([`FemMaps::corrected`]): the preload on
    /// stack `i` times `preload_scale`, the output of axis `i` times `gain` plus
    /// `offset_um`, everywhere on the grid; the other stacks and axes as they
    /// are. A scale or gain that is not finite and > 0, or an offset that is not
    /// finite, is refused.
    pub fn corrected(
        &self,
        i: usize,
        gain: f64,
        offset_um: f64,
        preload_scale: f64,
    ) -> Result<Self> {
        for (what, v) in [("stage gain", gain), ("preload scale", preload_scale)] {
            if !(v.is_finite() && v > 0.0) {
                bail!(
                    "{}: a {what} of {v} for axis {} (it must be a finite number > 0)",
                    self.source,
                    AXIS_NAMES[i]
                );
            }
        }
        if !offset_um.is_finite() {
            bail!(
                "{}: a stage offset of {offset_um} µm for axis {} is not finite",
                self.source,
                AXIS_NAMES[i]
            );
        }
        let mut out = self.clone();
        for f in &mut out.preload[i] {
            *f *= preload_scale;
        }
        for y in &mut out.output[i] {
            *y = *y * gain + offset_um;
        }
        Ok(out)
    }

    /// Stack `i`'s preload as the other stacks at `x` leave it: the map the
    /// coupled equation of stack `i` solves against.
    pub fn slice<'g>(&'g self, i: usize, x: &[f64]) -> Slice<'g> {
        let mut at = [0.0; MAX_AXES];
        at[..x.len()].copy_from_slice(x);
        Slice {
            grid: self,
            axis: i,
            at,
        }
    }

    /// Axis `i` alone: its FEM tables with every other stack at zero extension
    /// (what an FEM of the axis by itself gives, and a one-axis model uses).
    pub fn alone(&self, i: usize) -> Option<FemMaps> {
        let mut x = vec![0.0; self.axes()];
        let (mut f, mut k) = (Vec::new(), Vec::new());
        for &xi in &self.knots[i] {
            x[i] = xi;
            f.push(self.preload_at(i, &x));
            k.push(self.output_at(i, &x));
        }
        FemMaps::new(
            format!("{} ({} alone)", self.source, AXIS_NAMES[i]),
            self.knots[i].clone(),
            f,
            k,
        )
    }

    /// Multilinear interpolation of `table` at `x`, end cells continued.
    fn interpolate(&self, table: &[f64], x: &[f64]) -> f64 {
        let n = self.axes();
        let mut cell = [(0usize, 0.0f64); MAX_AXES];
        for (i, c) in cell.iter_mut().enumerate().take(n) {
            *c = locate(&self.knots[i], x[i]);
        }
        let mut sum = 0.0;
        for corner in 0..(1usize << n) {
            let (mut flat, mut w) = (0usize, 1.0);
            for (i, &(k, t)) in cell.iter().enumerate().take(n) {
                let up = corner >> i & 1;
                flat = flat * self.knots[i].len() + k + up;
                w *= if up == 1 { t } else { 1.0 - t };
            }
            sum += w * table[flat];
        }
        sum
    }

    /// Reads a grid file; errors name the file, line and column.
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let axes = axes_in_header(path, QUANTITIES[0])?;
        let columns: Vec<String> = QUANTITIES
            .iter()
            .flat_map(|q| (0..axes).map(move |i| column(q, i)))
            .collect();
        let names: Vec<&str> = columns.iter().map(String::as_str).collect();
        let rows = read_named_columns(path, &names)?;
        let ext = |i: usize| &rows.values[i];
        let knots: Vec<Vec<f64>> = (0..axes).map(|i| distinct(ext(i))).collect();
        for (i, k) in knots.iter().enumerate() {
            if k.len() < 2 {
                return Err(DataError::at(
                    path,
                    2,
                    &columns[i],
                    "a grid needs at least two extensions of every stack",
                ));
            }
        }
        let points: usize = knots.iter().map(Vec::len).product();
        let mut slot = vec![usize::MAX; points];
        for r in 0..rows.lines.len() {
            let mut flat = 0;
            for (i, k) in knots.iter().enumerate() {
                flat = flat * k.len() + k.partition_point(|&v| v < ext(i)[r]);
            }
            if slot[flat] != usize::MAX {
                return Err(DataError::at(
                    path,
                    rows.lines[r],
                    &columns[0],
                    format!(
                        "the grid point of line {} appears again: each point once",
                        rows.lines[slot[flat]]
                    ),
                ));
            }
            slot[flat] = r;
        }
        if let Some(missing) = slot.iter().position(|&s| s == usize::MAX) {
            let idx = unflatten_by(missing, &knots);
            let at: Vec<String> = (0..axes)
                .map(|i| format!("{} = {}", columns[i], knots[i][idx[i]]))
                .collect();
            return Err(DataError::file(
                path,
                format!(
                    "not a full grid: no row at {} ({} rows for a grid of {} points)",
                    at.join(", "),
                    rows.lines.len(),
                    knots
                        .iter()
                        .map(|k| k.len().to_string())
                        .collect::<Vec<_>>()
                        .join(" × ")
                ),
            ));
        }
        let table = |q: usize, i: usize| -> Vec<f64> {
            slot.iter().map(|&r| rows.values[q * axes + i][r]).collect()
        };
        let preload = (0..axes).map(|i| table(1, i)).collect();
        let output = (0..axes).map(|i| table(2, i)).collect();
        let grid = Self::new(path.display().to_string(), knots, preload, output)
            .ok_or_else(|| DataError::file(path, "not a grid of 1 to 3 stacks"))?;
        if let Some((flat, i)) = grid.backwards() {
            let line = rows.lines[slot[flat + stride(&grid.knots, i)]];
            return Err(DataError::at(
                path,
                line,
                &column("x_fhps_um", i),
                format!(
                    "is not above the point one step of stack {} before it (line {}): \
                     an axis must move forward with its own stack",
                    AXIS_NAMES[i], rows.lines[slot[flat]]
                ),
            ));
        }
        Ok(grid)
    }

    /// The first point (row-major) and axis `i` from which one step along stack
    /// `i` does not raise output `i` (the inverse kinematics would not exist).
    fn backwards(&self) -> Option<(usize, usize)> {
        (0..self.points()).find_map(|flat| {
            let idx = unflatten_by(flat, &self.knots);
            (0..self.axes()).find_map(|i| {
                let last = idx[i] + 1 == self.knots[i].len();
                let next = flat + stride(&self.knots, i);
                (!last && self.output[i][next] <= self.output[i][flat]).then_some((flat, i))
            })
        })
    }

    /// Writes the grid file (axis 0 slowest), four decimals as `fem.csv` has.
    pub fn write(&self, path: &Path) -> Result<()> {
        let n = self.axes();
        let header: Vec<String> = QUANTITIES
            .iter()
            .flat_map(|q| (0..n).map(move |i| column(q, i)))
            .collect();
        let mut text = header.join(",") + "\n";
        for flat in 0..self.points() {
            let idx = unflatten_by(flat, &self.knots);
            let mut cells: Vec<String> = (0..n)
                .map(|i| format!("{:.3}", self.knots[i][idx[i]]))
                .collect();
            cells.extend((0..n).map(|i| format!("{:.4}", self.preload[i][flat])));
            cells.extend((0..n).map(|i| format!("{:.4}", self.output[i][flat])));
            let _ = writeln!(text, "{}", cells.join(","));
        }
        if path.extension().is_some_and(|e| e == "gz") {
            bail!(
                "{}: write the grid uncompressed (gzip it yourself to keep it)",
                path.display()
            );
        }
        output::write_atomic(path, text.as_bytes())
    }
}

/// Stack `i`'s preload as a map of its own extension, the other stacks fixed
/// ([`FemGrid::slice`]): linear inside each of the grid's cells along stack `i`.
#[derive(Debug, Clone, Copy)]
pub struct Slice<'g> {
    grid: &'g FemGrid,
    axis: usize,
    at: [f64; MAX_AXES],
}

impl PreloadMap<f64> for Slice<'_> {
    fn preload_with_slope(&self, x: f64) -> (f64, f64) {
        let g = self.grid;
        let k = locate(&g.knots[self.axis], x).0;
        let (a, b) = (g.knots[self.axis][k], g.knots[self.axis][k + 1]);
        let mut at = self.at;
        at[self.axis] = a;
        let fa = g.preload_at(self.axis, &at[..g.axes()]);
        at[self.axis] = b;
        let fb = g.preload_at(self.axis, &at[..g.axes()]);
        let slope = (fb - fa) / (b - a);
        (fa + slope * (x - a), slope)
    }
    fn same_segment(&self, a: f64, b: f64) -> bool {
        let k = &self.grid.knots[self.axis];
        locate(k, a).0 == locate(k, b).0
    }
}

/// The cell `[k_j, k_{j+1}]` holding `x` (end cells continued) and `x`'s
/// fraction of it.
fn locate(knots: &[f64], x: f64) -> (usize, f64) {
    let j = knots
        .partition_point(|&k| k <= x)
        .saturating_sub(1)
        .min(knots.len() - 2);
    (j, (x - knots[j]) / (knots[j + 1] - knots[j]))
}

/// The distinct values of a column, sorted.
fn distinct(values: &[f64]) -> Vec<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

/// Grid indices of row-major point `flat` with `m` knots on each of `n` axes.
fn unflatten(mut flat: usize, n: usize, m: usize) -> [usize; MAX_AXES] {
    let mut idx = [0; MAX_AXES];
    for i in (0..n).rev() {
        idx[i] = flat % m;
        flat /= m;
    }
    idx
}

/// Grid indices of row-major point `flat` over `knots`.
fn unflatten_by(mut flat: usize, knots: &[Vec<f64>]) -> [usize; MAX_AXES] {
    let mut idx = [0; MAX_AXES];
    for i in (0..knots.len()).rev() {
        idx[i] = flat % knots[i].len();
        flat /= knots[i].len();
    }
    idx
}

/// The row-major step of one knot along axis `i`.
fn stride(knots: &[Vec<f64>], i: usize) -> usize {
    knots[i + 1..].iter().map(Vec::len).product()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_design_grid_holds_the_couplings_and_each_axis_alone_is_stage_a() {
        let g = FemGrid::design(2, 1).unwrap();
        assert_eq!(g.points(), 49 * 49);
        // Y's preload rises 0.5 N per µm of X's stack; X's output 2 % of Y's.
        let base = g.preload_at(1, &[0.0, 3.0]);
        let pushed = g.preload_at(1, &[4.0, 3.0]);
        assert!((pushed - base - 2.0).abs() < 1e-9, "{pushed} {base}");
        let alone = g.alone(0).unwrap();
        let k = stage_a::PARAMS.fem_output_um;
        let x_at = |x: f64| alone.maps().stage_at(x);
        assert!((x_at(6.0) - k[24] as f64).abs() < 1e-9);
        let with_y = g.output_at(0, &[6.0, 6.0]);
        assert!((with_y - k[24] as f64 * 1.02).abs() < 1e-6, "{with_y}");
    }

    #[test]
    fn interpolation_is_exact_at_the_points_and_linear_in_a_cell() {
        let g = FemGrid::design(3, 4).unwrap();
        let k = g.knots(0).to_vec();
        let at = [k[1], k[2], k[0]];
        let flat = (k.len() + 2) * k.len();
        assert_eq!(g.preload_at(2, &at), g.preload[2][flat]);
        let s = g.slice(1, &[0.7, 0.0, 1.3]);
        let (f0, d0) = s.preload_with_slope(2.1);
        let (f1, d1) = s.preload_with_slope(2.2);
        assert!(s.same_segment(2.1, 2.2));
        assert!((d0 - d1).abs() < 1e-12 && (f1 - f0 - 0.1 * d0).abs() < 1e-9);
    }

    /// A correction of axis 1 scales stack 1's preload and axis 1's output
    /// everywhere, and leaves stack and axis 0 as they are; a gain of 0 or a
    /// non-finite offset is refused, naming the axis.
    #[test]
    fn a_correction_acts_on_its_own_stack_and_axis_only() {
        let g = FemGrid::design(2, 6).unwrap();
        let c = g.corrected(1, 1.03, -0.2, 0.95).unwrap();
        for x in [[0.0, 0.0], [3.1, 7.4], [9.0, 2.0]] {
            assert_eq!(c.preload_at(0, &x), g.preload_at(0, &x));
            assert_eq!(c.output_at(0, &x), g.output_at(0, &x));
            assert!((c.preload_at(1, &x) - 0.95 * g.preload_at(1, &x)).abs() < 1e-12);
            assert!((c.output_at(1, &x) - (1.03 * g.output_at(1, &x) - 0.2)).abs() < 1e-12);
        }
        let e = g.corrected(1, 0.0, 0.0, 1.0).unwrap_err().to_string();
        assert!(e.contains("stage gain of 0 for axis y"), "{e}");
        let e = g.corrected(0, 1.0, f64::NAN, 1.0).unwrap_err().to_string();
        assert!(e.contains("offset of NaN µm for axis x"), "{e}");
    }

    #[test]
    fn a_grid_round_trips_through_its_file() {
        let g = FemGrid::design(2, 6).unwrap();
        let dir = std::env::temp_dir().join(format!("fpi-grid-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("grid.csv");
        g.write(&p).unwrap();
        let back = FemGrid::read(&p).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(back.knots, g.knots);
        for i in 0..2 {
            for (a, b) in back.preload[i].iter().zip(&g.preload[i]) {
                assert!((a - b).abs() <= 5e-5);
            }
        }
    }
}
