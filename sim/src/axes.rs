//! A stage of up to three axes: one virtual stack and flexure per axis
//! ([`Stage`]), coupled through the flexure as a parallel-kinematic XY(Z)
//! stage's are:
//!
//! * **preload**: each stack's force depends on every stack's extension —
//!   `preload_n_per_um[i][j]` newtons on stack `i` per µm of stack `j`'s
//!   extension, entering stack `i`'s electromechanics as an external force
//!   (pushing it back), so its force sensor reads it and its force-dependent
//!   hysteresis (`u − k_f·F`) responds to it: the first paper's coupled
//!   equation, for several stacks;
//! * **parasitic motion**: each axis's output moves with every other axis —
//!   `cross_um_per_um[i][j]` µm of axis `i` per µm of axis `j`'s own flexure's
//!   output;
//! * **sensor cross-talk**: each position sensor reads `sensor_crosstalk` of
//!   every other axis's output.
//!
//! The couplings act through the stacks' mechanics, so every axis of a coupled
//! stage has a mode ([`Stage::is_dynamic`]); the preload of a quasi-static axis
//! would not move.
//!
//! [`xy_built`] is the XY stage as built: X is stage A as built (mode 850 Hz),
//! Y its own flexure on the same stack (mode 1 000 Hz, ζ 0.025, output gain 1.01
//! where X has 1.03),
//! Y moves 1.5 % of X's output and X 2 % of Y's, each stack's preload rises by
//! 0.5 N per µm of the other's, and each sensor reads 0.2 % of the other axis.
//! [`xyz_built`] adds Z ([`Z_BUILT`], mode 700 Hz) with the weaker couplings of
//! [`XYZ_COUPLING`].
//!
//! As designed, every axis of these stages is stage A's FEM design (the same
//! stack and hinge) with these couplings: the FEM grids of the method for several
//! axes (`fpi axes grid`) are generated from that design.

use crate::stage::{stage_a, Overrides, Stage, StageParams, StageSample};

/// The most axes a stage has.
pub const MAX_AXES: usize = 3;

/// The axes' names, in order: column suffixes (`x_fhps_um@y`), file sections
/// (`[y]`) and command-line values (`--axis y`).
pub const AXIS_NAMES: [&str; MAX_AXES] = ["x", "y", "z"];

/// How the axes of a stage couple (configuration). Indices are axes (0 = x);
/// the diagonals are unused (an axis's own stack and output are its
/// [`StageParams`]').
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coupling {
    /// N on stack `i` per µm of stack `j`'s extension (the flexure's preload
    /// coupling).
    pub preload_n_per_um: [[f32; MAX_AXES]; MAX_AXES],
    /// µm of axis `i`'s output per µm of axis `j`'s own flexure's output
    /// (parasitic motion).
    pub cross_um_per_um: [[f32; MAX_AXES]; MAX_AXES],
    /// Fraction of every other axis's output each position sensor reads.
    pub sensor_crosstalk: f32,
}

impl Coupling {
    /// No coupling: the axes are independent stages.
    pub const NONE: Self = Self {
        preload_n_per_um: [[0.0; MAX_AXES]; MAX_AXES],
        cross_um_per_um: [[0.0; MAX_AXES]; MAX_AXES],
        sensor_crosstalk: 0.0,
    };

    /// Every cross gain and preload coupling times `k` (a variant's
    /// `coupling_scale`); the sensors' cross-talk unchanged.
    pub fn scaled(&self, k: f32) -> Self {
        let times = |m: [[f32; MAX_AXES]; MAX_AXES]| m.map(|row| row.map(|v| v * k));
        Self {
            preload_n_per_um: times(self.preload_n_per_um),
            cross_um_per_um: times(self.cross_um_per_um),
            sensor_crosstalk: self.sensor_crosstalk,
        }
    }
}

/// One axis's sample of a coupled stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisSample {
    /// The axis's stack, as a lone stage reports it (its force includes the
    /// other stacks' preload; its `x_fhps_um` is its own flexure's output alone).
    pub stack: StageSample,
    /// The external force on the stack from the other stacks, N.
    pub coupled_force_n: f32,
    /// The axis's true output, µm: its own flexure's plus the parasitic motion.
    pub x_fhps_um: f32,
}

/// A stage of `N` coupled axes (configuration and state).
#[derive(Debug, Clone)]
pub struct Axes<'a, const N: usize> {
    stages: [Stage<'a>; N],
    coupling: Coupling,
    /// Each stack's extension at the last sample, µm (the coupling acts on the
    /// next one: the flexure's forces follow the stacks' positions).
    extension: [f32; N],
    /// Each axis's true output at the last sample, µm.
    output: [f32; N],
}

impl<'a, const N: usize> Axes<'a, N> {
    /// The stages at rest, coupled; `None` if `N` is not 1..=3, a stage's
    /// parameters describe no model, or a coupled axis has no mode.
    pub fn new(params: &[StageParams<'a>; N], coupling: Coupling, seed: u32) -> Option<Self> {
        if N == 0 || N > MAX_AXES {
            return None;
        }
        let mut stages: heapless::Vec<Stage<'a>, N> = heapless::Vec::new();
        for (i, p) in params.iter().enumerate() {
            let seed = seed.wrapping_add(i as u32 * 0x9E37);
            stages.push(Stage::new(p, seed)?).ok()?;
        }
        let stages: [Stage<'a>; N] = stages.into_array().ok()?;
        if coupling != Coupling::NONE && !stages.iter().all(Stage::is_dynamic) {
            return None;
        }
        Some(Self {
            stages,
            coupling,
            extension: [0.0; N],
            output: [0.0; N],
        })
    }

    /// The axes' stages (their parameters, rest forces, sensors).
    pub fn stages(&self) -> &[Stage<'a>; N] {
        &self.stages
    }

    /// Advances one sample with each axis's amplifier command `u` (V).
    pub fn step(&mut self, u: [f32; N]) -> [AxisSample; N] {
        let c = &self.coupling;
        let forces: [f32; N] = core::array::from_fn(|i| {
            (0..N)
                .filter(|&j| j != i)
                .map(|j| c.preload_n_per_um[i][j] * self.extension[j])
                .sum()
        });
        let stacks: [StageSample; N] =
            core::array::from_fn(|i| self.stages[i].step_loaded(u[i], forces[i]));
        let out: [AxisSample; N] = core::array::from_fn(|i| {
            let parasitic: f32 = (0..N)
                .filter(|&j| j != i)
                .map(|j| c.cross_um_per_um[i][j] * stacks[j].x_fhps_um)
                .sum();
            AxisSample {
                stack: stacks[i],
                coupled_force_n: forces[i],
                x_fhps_um: stacks[i].x_fhps_um + parasitic,
            }
        });
        self.extension = stacks.map(|s| s.x_pea_um);
        self.output = out.map(|s| s.x_fhps_um);
        out
    }

    /// Axis `i`'s position-sensor reading of the last sample's outputs, µm: its
    /// own output, the cross-talk of the others, its noise.
    pub fn sense_position(&mut self, i: usize) -> f32 {
        let others: f32 = (0..N).filter(|&j| j != i).map(|j| self.output[j]).sum();
        let seen = self.output[i] + self.coupling.sensor_crosstalk * others;
        self.stages[i].sense_position(seen)
    }

    /// Axis `i`'s force-sensor reading of `force` (N), with its noise.
    pub fn sense_force(&mut self, i: usize, force: f32) -> f32 {
        self.stages[i].sense_force(force)
    }
}

/// Y of the XY stage as built: stage A's stack on a stiffer flexure (its mode
/// at 1 000 Hz, ζ 0.025), its output gain 1.01 (X has 1.03).
pub const Y_BUILT: StageParams<'static> = StageParams {
    mode_hz: 1000.0,
    mode_damping: 0.025,
    output_gain: 1.01,
    ..stage_a::BUILT
};

/// The XY stage's couplings as built: Y moves 1.5 % of X's output, X 2 % of
/// Y's; each stack's preload rises 0.5 N per µm of the other; each sensor
/// reads 0.2 % of the other axis.
pub const XY_COUPLING: Coupling = Coupling {
    preload_n_per_um: [[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0; MAX_AXES]],
    cross_um_per_um: [[0.0, 0.02, 0.0], [0.015, 0.0, 0.0], [0.0; MAX_AXES]],
    sensor_crosstalk: 0.002,
};

/// The XY stage as built, at rest (both axes have a mode: always `Some`).
pub fn xy_built(seed: u32) -> Option<Axes<'static, 2>> {
    AxesSpec::base("xy-built")?.build(seed)
}

/// Z of the XYZ stage as built: stage A's stack carrying the XY stage (its
/// mode at 700 Hz, ζ 0.03), its output gain 0.98.
pub const Z_BUILT: StageParams<'static> = StageParams {
    mode_hz: 700.0,
    mode_damping: 0.03,
    output_gain: 0.98,
    ..stage_a::BUILT
};

/// The XYZ stage's couplings as built: X and Y as the XY stage's; Z moves
/// 1 % of X's and Y's outputs and they 0.5 % of Z's; Z's preload and the
/// others' couple by 0.2 N per µm; each sensor reads 0.2 % of every other axis.
pub const XYZ_COUPLING: Coupling = Coupling {
    preload_n_per_um: [[0.0, 0.5, 0.2], [0.5, 0.0, 0.2], [0.2, 0.2, 0.0]],
    cross_um_per_um: [[0.0, 0.02, 0.005], [0.015, 0.0, 0.005], [0.01, 0.01, 0.0]],
    sensor_crosstalk: 0.002,
};

/// The XYZ stage as built, at rest (every axis has a mode: always `Some`).
pub fn xyz_built(seed: u32) -> Option<Axes<'static, 3>> {
    AxesSpec::base("xyz-built")?.build(seed)
}

/// The nominal twin of an axis of the XY(Z) stage: stage A's nominal twin
/// ([`stage_a::PARAMS`], what the recorded stage-A runs came from) with the
/// axis's mode (`mode_hz`, ζ) and no position noise — the stage as designed,
/// where only the stacks' own behaviour differs from the FEM design.
pub const fn nominal(mode_hz: f32, mode_damping: f32) -> StageParams<'static> {
    StageParams {
        mode_hz,
        mode_damping,
        ..stage_a::PARAMS
    }
}

/// The XY stage's nominal twin (X 850 Hz, Y 1 000 Hz; the flexure's couplings
/// as built, its sensors without cross-talk).
pub fn xy_nominal(seed: u32) -> Option<Axes<'static, 2>> {
    AxesSpec::base("xy")?.build(seed)
}

/// The XYZ stage's nominal twin (Z 700 Hz).
pub fn xyz_nominal(seed: u32) -> Option<Axes<'static, 3>> {
    AxesSpec::base("xyz")?.build(seed)
}

/// A virtual stage of several axes by name, with changes (configuration): the
/// base (the XY or XYZ twin or prototype), each axis's replaced values, and
/// the couplings' scale and the sensors' cross-talk (a variant file's
/// `coupling_scale` and `sensor_crosstalk`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxesSpec {
    /// Axes, 2 or 3.
    pub axes: usize,
    /// The prototypes (`true`) or the nominal twins.
    pub built: bool,
    /// Each axis's replaced values.
    pub overrides: [Overrides; MAX_AXES],
    /// Multiplies every cross gain and preload coupling of the base.
    pub coupling_scale: f32,
    /// Replaces the sensors' cross-talk (fraction of every other axis).
    pub sensor_crosstalk: Option<f32>,
}

impl AxesSpec {
    /// The bases by name: `xy`, `xyz` (nominal twins), `xy-built`, `xyz-built`.
    pub const BASES: [&'static str; 4] = ["xy", "xyz", "xy-built", "xyz-built"];

    /// The base named `name`, unchanged.
    pub fn base(name: &str) -> Option<Self> {
        let (axes, built) = match name {
            "xy" => (2, false),
            "xyz" => (3, false),
            "xy-built" => (2, true),
            "xyz-built" => (3, true),
            _ => return None,
        };
        Some(Self {
            axes,
            built,
            overrides: [Overrides::default(); MAX_AXES],
            coupling_scale: 1.0,
            sensor_crosstalk: None,
        })
    }

    /// Each axis's parameters (the unused axes' too).
    pub fn params(&self) -> [StageParams<'static>; MAX_AXES] {
        let base = if self.built {
            [stage_a::BUILT, Y_BUILT, Z_BUILT]
        } else {
            [
                nominal(850.0, 0.03),
                nominal(1000.0, 0.025),
                nominal(700.0, 0.03),
            ]
        };
        core::array::from_fn(|i| base[i].with(&self.overrides[i]))
    }

    /// The couplings: the base's, scaled, with the sensors' cross-talk replaced.
    pub fn coupling(&self) -> Coupling {
        let mut c = coupling_of(self.axes).scaled(self.coupling_scale);
        if self.sensor_crosstalk.is_none() && !self.built {
            c.sensor_crosstalk = 0.0;
        }
        if let Some(k) = self.sensor_crosstalk {
            c.sensor_crosstalk = k;
        }
        c
    }

    /// The stage at rest; `None` if `N` is not the spec's axes or an axis has
    /// no model.
    pub fn build<const N: usize>(&self, seed: u32) -> Option<Axes<'static, N>> {
        if N != self.axes {
            return None;
        }
        let p = self.params();
        let params: [StageParams<'static>; N] = core::array::from_fn(|i| p[i]);
        Axes::new(&params, self.coupling(), seed)
    }
}

/// A stage's couplings among its first `n` axes (the others' rows and columns
/// zero): the XY stage's for two, the XYZ stage's for three.
pub fn coupling_of(n: usize) -> Coupling {
    match n {
        2 => XY_COUPLING,
        3 => XYZ_COUPLING,
        _ => Coupling::NONE,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Holds `u` for `ticks` samples; the last one.
    fn hold<const N: usize>(s: &mut Axes<'_, N>, u: [f32; N], ticks: usize) -> [AxisSample; N] {
        let mut last = s.step(u);
        for _ in 1..ticks {
            last = s.step(u);
        }
        last
    }

    #[test]
    fn uncoupled_axes_are_the_lone_stages() {
        let mut xy = Axes::new(&[stage_a::BUILT, Y_BUILT], Coupling::NONE, 7).unwrap();
        let mut x = Stage::new(&stage_a::BUILT, 7).unwrap();
        for k in 0..2000 {
            let u = if k < 1000 { 60.0 } else { 90.0 };
            let s = xy.step([u, 0.0]);
            let lone = x.step(u);
            assert_eq!(s[0].stack, lone, "sample {k}");
            assert_eq!(s[0].x_fhps_um, lone.x_fhps_um);
            assert_eq!(s[1].coupled_force_n, 0.0);
        }
    }

    /// Driving X alone moves Y's output by its cross gain of X's output, raises
    /// Y's preload by 0.5 N per µm of X's stack, and Y's sensor reads its
    /// cross-talk of X.
    #[test]
    fn x_drives_y_through_the_flexure_and_the_sensor() {
        let mut xy = xy_built(3).unwrap();
        let rest = hold(&mut xy, [0.0, 0.0], 4000);
        let moved = hold(&mut xy, [100.0, 0.0], 8000);
        let dx_stack = moved[0].stack.x_pea_um - rest[0].stack.x_pea_um;
        let dx_own = moved[0].stack.x_fhps_um - rest[0].stack.x_fhps_um;
        assert!(dx_stack > 5.0, "{dx_stack}");
        let dy_out = moved[1].x_fhps_um - rest[1].x_fhps_um;
        let dy_stack = moved[1].stack.x_pea_um - rest[1].stack.x_pea_um;
        // Y's own stack gives way a little under the added preload.
        let parasitic = dy_out - (moved[1].stack.x_fhps_um - rest[1].stack.x_fhps_um);
        assert!(
            (parasitic / (0.015 * dx_own) - 1.0).abs() < 0.02,
            "{parasitic} {dx_own}"
        );
        println!(
            "X's stack +{dx_stack:.3} µm, output +{dx_own:.3} µm: Y's output {dy_out:+.4} µm (parasitic {parasitic:+.4}), \
             Y's stack {dy_stack:+.4} µm"
        );
        assert!(dy_stack < 0.0, "{dy_stack}");
        let df = moved[1].coupled_force_n - rest[1].coupled_force_n;
        assert!(
            (df / (0.5 * dx_stack) - 1.0).abs() < 0.01,
            "{df} {dx_stack}"
        );
        // Y's force sensor reads the added preload.
        let dfy = moved[1].stack.force_n - rest[1].stack.force_n;
        assert!((dfy / df - 1.0).abs() < 0.2, "{dfy} {df}");
        let seen = xy.sense_position(1);
        let want = moved[1].x_fhps_um + 0.002 * moved[0].x_fhps_um;
        assert!((seen - want).abs() < 0.02, "{seen} {want}");
    }

    #[test]
    fn a_coupling_needs_mechanics_and_one_to_three_axes() {
        assert!(Axes::new(&[stage_a::PARAMS, Y_BUILT], XY_COUPLING, 1).is_none());
        assert!(Axes::new(&[stage_a::PARAMS, stage_a::PARAMS], Coupling::NONE, 1).is_some());
        let none: [StageParams<'static>; 0] = [];
        assert!(Axes::new(&none, Coupling::NONE, 1).is_none());
        let scaled = XY_COUPLING.scaled(2.0);
        assert_eq!(scaled.cross_um_per_um[1][0], 0.03);
        assert_eq!(scaled.sensor_crosstalk, XY_COUPLING.sensor_crosstalk);
    }
}
