//! Branch-polynomial hysteresis (`--kind branch`): the hysteresis model of the
//! second paper (seed 001, eqs. 6–7 and Table 3), made continuous at reversals,
//! with a memory of reversal points, its least-squares fit on the rig recordings
//! and its coupled prediction of a stage.
//!
//! # The paper's equations and our reading
//!
//! The paper describes the voltage–displacement curve by two polynomials, one per
//! direction of the voltage, in the distance from the last turning voltage:
//!
//! ```text
//! (6) Hist_up(v, v_min) = P_up1·Δ³ + P_up2·Δ² + P_up3·Δ + P_up4 + B_up1·v_min² + B_up2·v_min + B_up3,   Δ = v − v_min ≥ 0
//! (7) Hist_dn(v, v_max) = P_dn1·Δ⁴ + P_dn2·Δ³ + P_dn3·Δ² + P_dn4·Δ + P_dn5 − B_dn1·v_max² + B_dn2·v_max + B_dn3,   Δ = v − v_max ≤ 0
//! ```
//!
//! The constant of each branch, `P_up4 + B_up(v_min)` and `P_dn5 + B_dn(v_max)`, is
//! where the branch starts: a fitted quadratic of the turning *voltage*. With
//! Table 3's values as transcribed, eq. 7 is continuous with eq. 6 nowhere: at a
//! reversal at 100 V after an ascent from 0 V, eq. 6 ends at 75.4 and eq. 7 starts
//! at 512.2. Reading the printed `− B_dn1·v_max²` as `+ B_dn1·v_max²` (a lost
//! sign; `B_dn1` is itself negative), the two meet at the paper's major loop only:
//! at `v_max` = 120 V eq. 6 ends at 121.3 and eq. 7 starts at 123.0, and eq. 7
//! ends at −0.1 at 0 V where eq. 6 started at 1.9; at `v_max` = 100 V the jump
//! is 83 (of a 75 span), and an ascent from `v_min` = 60 V on the 0–120 V loop
//! starts 49 below the point it turns at (`tests/branch.rs` holds these
//! figures). So the `B` terms are a fit of the major loop's turning points, not a
//! rule that keeps the output continuous at any reversal.
//!
//! **Our reading** keeps the paper's structure (one polynomial per direction, of
//! degree 3 up and 4 down, in the distance from the last turning voltage) and
//! replaces the fitted constant by the output the model had at the turning point:
//!
//! ```text
//! ascending  from the last minimum (v_m, y_m):  y = y_m + Σ a_k·(v − v_m)^k  (+ closure)
//! descending from the last maximum (v_M, y_M):  y = y_M + Σ d_k·(v − v_M)^k  (+ closure)
//! ```
//!
//! so each branch starts exactly at its turning point's output: the curve is
//! continuous at every reversal by construction (`tests/branch.rs` checks it on
//! random drives). The paper's constant `P_up4` and `P_dn5` vanish (a branch
//! starts where the last one ended), and so do the `B` polynomials.
//!
//! # Memory of reversal points
//!
//! `branch.memory` selects how minor loops are handled:
//!
//! * `"stack"` (the default): a stack of turning points with **wiping-out**, as
//!   in a Preisach model. A branch starting at the last turning point aims at the
//!   one before it (of the other direction), and a linear term in `Δ` makes it
//!   arrive there exactly (**closure**: a minor loop closes on its starting
//!   point): `y = y_o + P(Δ) + (Δ/Δ_t)·(y_t − y_o − P(Δ_t))`. When the voltage
//!   passes that earlier turning point, both points are removed and the model
//!   continues on the outer branch it left (**wiping-out**), continuously, since
//!   that outer branch passed through the removed point. The bottom of the stack
//!   is the rest state `(0 V, offset_um)`, never removed (the effective voltage is
//!   clamped at 0), so every descent to 0 V closes the major loop. Costs: memory
//!   grows with the depth of nested loops (at most [`MAX_TURNS`] points, the
//!   outermost pair dropped beyond that), each sample is amortised O(1) (a point
//!   is pushed once and removed once), and the model stays linear in its
//!   coefficients, so the fit is exact least squares. Noise near an extremum only
//!   makes tiny loops that are closed and wiped out again.
//! * `"last"`: the paper's memory, the last turning point only. O(1) memory and
//!   time, but minor loops do not close: a decaying or nested drive drifts, and
//!   every jitter of the input (force-sensor noise in the effective voltage)
//!   restarts a branch.
//!
//! # How the force enters
//!
//! Through the same effective voltage as the paper's FPI, `û = clamp(u − k_f·F,
//! 0, input_max_v)` with `k_f` in `coupling.k_f_v_per_n`, and the branches drive
//! on `û`. On the rig, where the preload runs from 25 to 150 N, a force-free model
//! cannot fit every preload at once; with `û`, `fpi predict` and `fpi compare`
//! solve the same coupled equation `x_pea = Y[u − k_f·f_F(x_pea)]` as for the FPI
//! (bracketed Newton, here on a model that is polynomial between turning points).
//!
//! # Fit
//!
//! Given `k_f`, the turning voltages depend on the input only, and every output is
//! a linear function of the coefficients and of the rest offset (a turning
//! point's output is itself such a function): the model's output is `Xθ` exactly,
//! where each row of `X` is run through the same memory with vectors in place of
//! numbers. So the coefficients are an output-error least-squares fit (normal
//! equations on columns scaled to the voltage span, solved by SVD with
//! `nalgebra`), and `k_f` is found by golden section on that fit's RMSE, as for
//! the FPI.
//!
//! The firmware does not run this model: `fpi export` refuses it.

use std::ops::{Add, Mul, Sub};

use anyhow::{bail, Context, Result};
use nalgebra::{DMatrix, DVector, SVector};
use piezo_sim::fem::Fem;
use piezo_sim::stats::ErrorStats;
use rayon::prelude::*;

use crate::data::fem::FemMaps;
use crate::method::fit::{golden, voltage_span};
use crate::method::model::{
    is_no_pi, no_pi, BranchSection, Calibration, HostModel, Kind, Memory, ModelKind, Options,
    OutputMap,
};
use crate::method::sections::{finite, pooled_rmse, MAX_DEGREE};
use crate::method::series::{file_fit, CalibData, Inversion, Prediction};

mod calibrate;
use calibrate::calibrate;

/// The `branch` kind.
pub struct Branch;

#[allow(non_upper_case_globals)]
impl Kind {
    /// `branch`.
    pub const Branch: Kind = Kind::of(&Branch);
}

impl ModelKind for Branch {
    fn name(&self) -> &'static str {
        "branch"
    }
    fn method(&self) -> &'static str {
        "BPH-FFEM"
    }
    fn uses_force(&self) -> bool {
        true
    }
    fn coupled(&self) -> bool {
        false
    }
    fn options(&self) -> Options {
        Options::common(Kind::Branch)
    }
    fn calibrate(
        &self,
        data: &[CalibData],
        opt: &Options,
        warnings: Vec<String>,
    ) -> Result<HostModel> {
        calibrate(data, opt, warnings)
    }
    /// Its `[branch]` section, `k_f` ≥ 0 and the rest offset, and none of the other
    /// kinds' parts.
    fn validate(&self, m: &HostModel) -> Result<()> {
        let Some(b) = &m.branch else {
            bail!("kind = \"branch\" needs a [branch] section");
        };
        b.validate()?;
        if !is_no_pi(&m.pi) {
            bail!("pi: a branch model has no PI part (leave the [pi] section out)");
        }
        let c = &m.coupling;
        let k_f = c.k_f_v_per_n;
        if !(k_f.is_finite() && k_f >= 0.0) {
            bail!("coupling.k_f_v_per_n = {k_f}: must be a finite value ≥ 0 V/N");
        }
        for (key, v) in [
            ("coupling.offset_v", c.offset_v),
            ("coupling.k_q_v_per_n2", c.k_q_v_per_n2),
            ("coupling.force_q_n", c.force_q_n),
            ("coupling.compliance_um_per_n", c.compliance_um_per_n),
            ("dead_zone_softness_v", m.dead_zone_softness_v),
        ] {
            if v != 0.0 {
                bail!("{key} = {v}: a branch model uses only coupling.k_f_v_per_n (must be 0)");
            }
        }
        finite("offset_um", m.offset_um)?;
        if m.output != OutputMap::Identity {
            bail!("output: a branch model has no output map");
        }
        if m.ldpi.is_some() || !m.creep.is_empty() {
            bail!("ldpi, creep: a branch model has neither section");
        }
        Ok(())
    }
    fn simulate(&self, m: &HostModel, d: &CalibData) -> Vec<f64> {
        match BranchModel::of(m) {
            Ok(b) => b.simulate(d),
            Err(_) => vec![f64::NAN; d.u.len()],
        }
    }
    fn predict(&self, m: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
        predict(m, fem, t, u)
    }
    fn invert(
        &self,
        _: &HostModel,
        _: &FemMaps,
        _: &[f64],
        _: &[f64],
        _: f64,
    ) -> Result<Inversion> {
        bail!(
            "a branch model has no closed-form inverse: invert with a pi, fpi or efpi model \
             (the inverse PI is what the firmware runs)"
        )
    }
    fn export(&self, _: &HostModel) -> Result<()> {
        bail!("it has no play operators (the firmware runs the closed-form inverse PI)")
    }
    fn structure(&self, m: &HostModel) -> String {
        match &m.branch {
            Some(b) => format!(
                "branch polynomials of degree {} (ascending) and {} (descending)",
                b.ascending_um_per_vk.len(),
                b.descending_um_per_vk.len()
            ),
            None => "no [branch] section".into(),
        }
    }
    fn parameters(&self, m: &HostModel) -> Option<String> {
        Some(format!(
            "k_f {:.5} V/N (û = u − k_f·F)",
            m.coupling.k_f_v_per_n
        ))
    }
}

/// Most turning points the stack memory keeps, the rest state included.
pub const MAX_TURNS: usize = 1024;

/// Model evaluations of one coupled solve, at most.
const MAX_SOLVE_EVALUATIONS: usize = 200;

/// `Σ c_k·d^(k+1)` (Horner).
fn poly(c: &[f64], d: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ck| (acc + ck) * d)
}

/// `d/dd Σ c_k·d^(k+1)`.
fn dpoly(c: &[f64], d: f64) -> f64 {
    c.iter()
        .enumerate()
        .rev()
        .fold(0.0, |acc, (k, &ck)| acc * d + (k + 1) as f64 * ck)
}

/// What a turning point's output can be: a number (the model) or a row of the
/// least squares (the output as a linear function of the coefficients).
pub trait Linear: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<f64, Output = Self> {}
impl<T: Copy + Add<Output = T> + Sub<Output = T> + Mul<f64, Output = T>> Linear for T {}

/// A turning point: effective voltage (V) and output (µm, or its row).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Turn<T> {
    v: f64,
    y: T,
}

/// The model's memory: the turning points (the rest state first), the direction
/// of the current branch and the last sample.
#[derive(Debug, Clone, PartialEq)]
pub struct BranchState<T> {
    turns: Vec<Turn<T>>,
    rising: bool,
    last: Turn<T>,
}

impl<T: Linear> BranchState<T> {
    /// At rest: `(0 V, rest)`, about to rise.
    pub fn at_rest(rest: T) -> Self {
        let p = Turn { v: 0.0, y: rest };
        Self {
            turns: vec![p],
            rising: true,
            last: p,
        }
    }

    /// Turning points remembered, the rest state included.
    pub fn depth(&self) -> usize {
        self.turns.len()
    }

    /// Advances to effective voltage `v` (≥ 0 V) and returns the output. `shape`
    /// gives the branch polynomial `P(rising, Δ)`.
    pub fn advance(&mut self, v: f64, memory: Memory, shape: &impl Fn(bool, f64) -> T) -> T {
        if v == self.last.v {
            return self.last.y;
        }
        let rising = v > self.last.v;
        if rising != self.rising {
            self.turn(memory);
            self.rising = rising;
        }
        if memory == Memory::Stack {
            self.wipe(v);
        }
        let (o, t) = self.ends();
        let y = value(o, t, self.rising, v, shape);
        self.last = Turn { v, y };
        y
    }

    /// The last sample becomes a turning point.
    fn turn(&mut self, memory: Memory) {
        match memory {
            Memory::Stack => {
                self.turns.push(self.last);
                if self.turns.len() > MAX_TURNS {
                    // Forget the outermost loop (the rest state stays).
                    self.turns.drain(1..3);
                }
            }
            Memory::Last => {
                self.turns.clear();
                self.turns.push(self.last);
            }
        }
    }

    /// Removes the inner loops `v` has passed (the rest state stays).
    fn wipe(&mut self, v: f64) {
        while self.turns.len() >= 3 {
            let t = self.turns[self.turns.len() - 2];
            let passed = if self.rising { v > t.v } else { v < t.v };
            if !passed {
                break;
            }
            self.turns.truncate(self.turns.len() - 2);
        }
    }

    /// The current branch's origin, and the turning point it closes on (stack
    /// memory; none for the first ascent and for the last-point memory).
    fn ends(&self) -> (Turn<T>, Option<Turn<T>>) {
        let n = self.turns.len();
        let o = self.turns[n - 1];
        let t = (n >= 2)
            .then(|| self.turns[n - 2])
            .filter(|t| t.v != o.v && (t.v > o.v) == self.rising);
        (o, t)
    }
}

/// The output on the branch from `o` closing on `t` at effective voltage `v`.
fn value<T: Linear>(
    o: Turn<T>,
    t: Option<Turn<T>>,
    rising: bool,
    v: f64,
    shape: &impl Fn(bool, f64) -> T,
) -> T {
    let d = v - o.v;
    let y = o.y + shape(rising, d);
    match t {
        Some(t) => {
            let dm = t.v - o.v;
            y + (t.y - o.y - shape(rising, dm)) * (d / dm)
        }
        None => y,
    }
}

/// A branch model ready to evaluate (from a [`HostModel`] of kind branch).
#[derive(Debug, Clone, PartialEq)]
pub struct BranchModel {
    /// Force coupling `k_f`, V/N.
    pub k_f: f64,
    /// Output at rest, µm.
    pub rest_um: f64,
    /// The section.
    pub section: BranchSection,
}

impl BranchModel {
    /// The branch model of `m`; an error if `m` is not one.
    pub fn of(m: &HostModel) -> Result<Self> {
        let Some(section) = m.branch.clone().filter(|_| m.kind == Kind::Branch) else {
            bail!(
                "a {} model is not a branch model (kind = \"branch\" with a [branch] section)",
                m.kind
            );
        };
        Ok(Self {
            k_f: m.coupling.k_f_v_per_n,
            rest_um: m.offset_um,
            section,
        })
    }

    /// The effective voltage `clamp(u − k_f·F, 0, input_max_v)`, V.
    pub fn effective(&self, u: f64, force: f64) -> f64 {
        (u - self.k_f * force).clamp(0.0, self.section.input_max_v)
    }

    /// `P(rising, Δ)`, µm.
    fn shape(&self) -> impl Fn(bool, f64) -> f64 + '_ {
        let s = &self.section;
        move |rising, d| {
            let c = if rising {
                &s.ascending_um_per_vk
            } else {
                &s.descending_um_per_vk
            };
            poly(c, d)
        }
    }

    /// A state at rest.
    pub fn state(&self) -> BranchState<f64> {
        BranchState::at_rest(self.rest_um)
    }

    /// Advances by one sample of voltage `u` (V) under force `force` (N); the
    /// stack extension, µm.
    pub fn step(&self, st: &mut BranchState<f64>, u: f64, force: f64) -> f64 {
        self.advance(st, self.effective(u, force))
    }

    /// Advances to effective voltage `v`, V; the extension, µm.
    pub fn advance(&self, st: &mut BranchState<f64>, v: f64) -> f64 {
        st.advance(v, self.section.memory, &self.shape())
    }

    /// The extension at effective voltage `v` (µm) and its slope (µm/V) on the
    /// branch `v` lies on, without committing.
    pub fn peek(&self, st: &BranchState<f64>, v: f64) -> (f64, f64) {
        let mut s = st.clone();
        let y = self.advance(&mut s, v);
        let (o, t) = s.ends();
        let c = if s.rising {
            &self.section.ascending_um_per_vk
        } else {
            &self.section.descending_um_per_vk
        };
        let mut slope = dpoly(c, v - o.v);
        if let Some(t) = t {
            let dm = t.v - o.v;
            slope += (t.y - o.y - poly(c, dm)) / dm;
        }
        (y, slope)
    }

    /// The extension over a recording driven by its voltage and measured force, µm.
    pub fn simulate(&self, d: &CalibData) -> Vec<f64> {
        let mut st = self.state();
        (0..d.u.len())
            .map(|k| self.step(&mut st, d.u[k], d.f[k]))
            .collect()
    }
}

/// Solves `x = Y[clamp(u − k_f·f_F(x))]` for one sample from `guess` (µm):
/// Newton's method kept inside the bracket the sign of `φ(x) = Y − x` gives
/// (bisection where a step leaves it). `φ` is continuous (the branches are), so
/// the bracket always holds a root. Returns the extension and the evaluations.
fn solve(
    b: &BranchModel,
    st: &BranchState<f64>,
    u: f64,
    fem: &Fem<'_, f64>,
    guess: f64,
) -> (f64, usize) {
    let phi = |x: f64| {
        let (f, df) = fem.preload_with_slope(x);
        let e = u - b.k_f * f;
        let v = e.clamp(0.0, b.section.input_max_v);
        let (y, dy) = b.peek(st, v);
        let dv = if v == e { -b.k_f * df } else { 0.0 };
        (y - x, dy * dv - 1.0)
    };
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let mut x = guess;
    for it in 1..=MAX_SOLVE_EVALUATIONS {
        let (p, dp) = phi(x);
        if p == 0.0 || hi - lo < 1e-13 * (1.0 + x.abs()) {
            return (x, it);
        }
        if p > 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let mut next = x - p / dp;
        if !(next > lo && next < hi && next.is_finite()) {
            next = match (lo.is_finite(), hi.is_finite()) {
                (true, true) => 0.5 * (lo + hi),
                (true, false) => x + 2.0 * p.abs().max(1.0),
                (false, true) => x - 2.0 * p.abs().max(1.0),
                (false, false) => x,
            };
        }
        if (next - x).abs() <= 1e-13 * (1.0 + x.abs()) {
            return (next, it);
        }
        x = next;
    }
    (x, MAX_SOLVE_EVALUATIONS)
}

/// Predicts the stage for a drive: the coupled solve at every sample, the memory
/// advanced at the solution, `x_fhps = f_K(x_pea)` (see [`crate::method::predict`]).
fn predict(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
    let b = BranchModel::of(model)?;
    let maps = fem.maps();
    let mut st = b.state();
    let mut p = Prediction::of_drive(t, u);
    let mut guess = b.rest_um;
    for &uk in u {
        let (x, evals) = solve(&b, &st, uk, &maps, guess);
        let f = maps.preload_at(x);
        b.advance(&mut st, b.effective(uk, f));
        guess = x;
        p.push(&maps, x, evals);
    }
    Ok(p)
}


