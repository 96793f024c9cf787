//! The electromechanical piezostack of the second paper (eqs. 3–5), with the
//! project's hysteresis model inside: a simulator stepped at a fixed sample rate,
//! the plant of the host's rate-dependent (closed-loop) tests.
//!
//! # The paper's equations, as read here
//!
//! Eq. (3), the electrical part: `V_act = (V_in − R·C_m·d33·v) / (R·C·s + 1)`.
//! `V_in` is the amplifier's source voltage, `R` its source (plus lead) resistance,
//! `C` the stack capacitance, `V_act` the voltage across the stack. Multiplied out
//! it is the charge balance of the stack
//!
//! ```text
//! i = (V_in − V_act)/R = C·dV_act/dt + T·v,      T = C_m·d33  (N/V = C/m)
//! ```
//!
//! i.e. the charge `q = C·V_act + T·x`: the direct piezo effect draws the charge
//! `T·x` when the stack moves, and through `R` that lowers `V_act` while the
//! stack extends (the minus sign). The back-coupling is an *electrical damping*
//! `c_e = R·T²` of the mechanical mode (for `R·C·ω ≪ 1`), which a test checks.
//!
//! Eq. (4), the mechanical part: `F_act = V_act·C_m·d33 − F_ext = (m·s² + K_d·s +
//! C_m)·x`: a mass–spring–damper driven by the piezo force minus the external
//! force. `C_m` is a stiffness (N/m, Table 2, and the spring term `C_m·x`), though
//! its symbol reads like a compliance.
//!
//! Eq. (5), "combined": as transcribed, `(V_in − R·C_m·d33·S·x)/(R·C·S + 1) − F_ext
//! = (m·S² + K_d·S + C_m)·x`, it subtracts a force from a voltage. The factor
//! `C_m·d33` of the voltage term is missing (a transcription or typesetting
//! error); eqs. (3) and (4) combine to
//!
//! ```text
//! C_m·d33·(V_in − R·C_m·d33·s·x)/(R·C·s + 1) − F_ext = (m·s² + K_d·s + C_m)·x
//! ```
//!
//! which is what this module integrates. Other points of the transcription:
//! Table 1 calls `V_in` the "voltage developed on the piezostack electrodes",
//! but by eq. (3) that is `V_act` (`V_in` is before `R`); and eq. (14),
//! `I/V = 28.5·10⁻⁶·s`, implies 28.5 µF where the text quotes a 3.4 µF datasheet
//! capacitance. In this model the low-frequency current is
//! `i ≈ (C + T·dy/du)·du/dt`: the clamped capacitance `C` plus the motional part
//! `T·dy/du` (`dy/du` the stroke per volt), so a capacitance identified from the
//! current (eq. 14) is that sum, not `C`.
//!
//! # The hysteresis inside
//!
//! The linear `d33·V_act` of eq. (4) is the free stroke of the stack at the voltage
//! `V_act`. Here it is the project's hysteresis model instead (any
//! [`Model`]: PI, FPI, with creep, soft dead zone, output map):
//! `F_act = C_m·y(V_act) − F_ext`, with `y` the model's extension (µm → m). The
//! model sees the force `preload + F_ext` (its preload-dependent reverse voltage,
//! if it has a coupling) against the reference `preload`; its own compliance must
//! be 0 ([`Electromech::new`] refuses one), since the stiffness `C_m` of the
//! mechanics already carries it. At DC (`v = 0`, `i = 0`, `V_act = V_in`),
//! `x = y(V_in) − F_ext/C_m`: the static stroke is the hysteresis model's. The
//! back-coupling keeps the paper's linear `T = C_m·d33`, with `d33` a parameter
//! (the stack's nominal stroke per volt).
//!
//! # The stage's mechanics and its force sensor
//!
//! The same equations carry a flexure-hinge stage (the emulated board's stage as
//! built, [`crate::stage`]): the stack, of stiffness `k_p` and free stroke `y`,
//! pushes the stage's effective mass `m` (referred to the stack) against the
//! hinge, whose force on the stack is the preload `F_0` plus the load `L(x)`
//! (the FEM's `f_F(x) − f_F(0)`, or a linear spring `k_h·x`):
//!
//! ```text
//! m·ẍ + K_d·ẋ = F_s − F_0 − L(x) − F_ext,      F_s = F_0 + k_p·(y − x)
//! ```
//!
//! `F_s` is the force through the stack: a force sensor in series with it reads
//! it, the preload *plus* the dynamic force `m·ẍ + K_d·ẋ`, so it sees the stage's
//! modes. The hysteresis model sees the same force, so its preload-dependent
//! reverse voltage (the FPI coupling, `k_f`) acts on the free stroke: `y` solves
//! `y = Y(V_act, F_0 + k_p·(y − x))` ([`crate::solve::coupled`] with the stack's
//! [`Spring`]). The coupling softens the stack: small-signal, its stiffness is
//! `k_p/(1 + s·k_f·k_p)` with `s` the local stroke per volt
//! ([`ElectromechParams::effective_stack_stiffness`]). The paper's eq. (4) is
//! the case `L = 0`, `F_0 = 0`, `k_p = C_m`.
//!
//! # Integration
//!
//! Each sample (`1/f_s`) is split into [`ElectromechParams::substeps`] equal
//! substeps `h`. In each, with the input held (zero-order hold):
//!
//! 1. the electrical part exactly (an exponential integrator, stable for any
//!    `h/(R·C)`, also for `R = 0`): `V_act ← V_e + (V_act − V_e)·e^{−h/(R·C)}`,
//!    `V_e = V_in − R·T·v`, with `v` the velocity at the start of the substep;
//! 2. the free stroke: the coupled equation solved with the stack's end at the
//!    substep's midpoint (predicted with the last substep's force), so the
//!    coupling's share of the stiffness is integrated like the trapezoidal rule,
//!    without the energy an explicit force would add to a lightly damped mode;
//!    the model is committed once, there;
//! 3. the mechanics exactly (the zero-order-hold transition matrix of
//!    `m·ẍ + K_d·ẋ + (k_p + k_h)·x`, from the matrix exponential) with the rest of
//!    the force held.
//!
//! Every part is stable; [`Electromech::new`] requires `h·ω_n ≤ 0.5`. The model is
//! generic over the number type: `f64` on the host, `f32` on the emulated board
//! (through `libm`, bit-identical on both).

use crate::fem::Fem;
use crate::model::{Model, State};
use crate::real::Real;
use crate::solve::{coupled, Spring};

/// The parameters of the electromechanical stack (configuration, SI units as the
/// paper's Table 2; the symbols are the paper's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElectromechParams {
    /// Sample rate of [`Electromech::step`], Hz (the board's control rate).
    pub sample_rate_hz: f64,
    /// Substeps per sample (≥ 1; see the module docs).
    pub substeps: u32,
    /// `R`: amplifier source plus lead resistance, Ω (0: an ideal voltage source).
    pub resistance_ohm: f64,
    /// `C`: stack capacitance (clamped), F.
    pub capacitance_f: f64,
    /// `d33`: the stack's nominal stroke per volt in the back-coupling `T =
    /// C_m·d33`, m/V (0: no back-coupling).
    pub d33_m_per_v: f64,
    /// `m`: effective mass (referred to the stack), kg.
    pub mass_kg: f64,
    /// `C_m` (`k_p`): stiffness of the stack, N/m.
    pub stiffness_n_per_m: f64,
    /// `k_h`: the load's stiffness (the hinge's, the slope of `f_F`), N/m (0: the
    /// paper's free stack).
    pub load_stiffness_n_per_m: f64,
    /// `K_d`: viscous damping, N·s/m.
    pub damping_n_s_per_m: f64,
    /// `F_0`: static preload on the stack, N: the hysteresis model's force at rest.
    pub preload_n: f64,
}

impl ElectromechParams {
    /// An 850 Hz, lightly damped (ζ = 0.02) stack at 20 kHz, 4 substeps: 50 N/µm,
    /// 3.4 µF (the paper's datasheet value), a 1 Ω source, `d33` = 0.27 µm/V
    /// (40 µm over 150 V), no preload, no load.
    pub fn stack_850hz() -> Self {
        Self {
            sample_rate_hz: 20_000.0,
            substeps: 4,
            resistance_ohm: 1.0,
            capacitance_f: 3.4e-6,
            d33_m_per_v: 40e-6 / 150.0,
            mass_kg: 1.0,
            stiffness_n_per_m: 50e6,
            load_stiffness_n_per_m: 0.0,
            damping_n_s_per_m: 0.0,
            preload_n: 0.0,
        }
        .with_mode(850.0, 0.02)
    }

    /// The same stiffnesses, with the mass and damping that put the mechanical
    /// mode of `m·ẍ + K_d·ẋ + (C_m + k_h)·x` at `f_hz` with damping ratio `zeta`.
    pub fn with_mode(self, f_hz: f64, zeta: f64) -> Self {
        self.with_mode_at_stiffness(f_hz, zeta, self.stiffness_n_per_m)
    }

    /// The mass and damping that put the mode at `f_hz`, `zeta` for a stack of
    /// effective stiffness `stack_n_per_m` (e.g. softened by the force coupling,
    /// [`effective_stack_stiffness`](Self::effective_stack_stiffness)).
    pub fn with_mode_at_stiffness(self, f_hz: f64, zeta: f64, stack_n_per_m: f64) -> Self {
        let w = 2.0 * core::f64::consts::PI * f_hz;
        let mass_kg = (stack_n_per_m + self.load_stiffness_n_per_m) / (w * w);
        Self {
            mass_kg,
            damping_n_s_per_m: 2.0 * zeta * w * mass_kg,
            ..self
        }
    }

    /// The stack's small-signal stiffness under the force coupling, N/m:
    /// `k_p/(1 + s·k_f·k_p)` for a stroke per volt `s` (µm/V) and a coupling
    /// `k_f` (V/N).
    pub fn effective_stack_stiffness(&self, s_um_per_v: f64, k_f_v_per_n: f64) -> f64 {
        let kp = self.stiffness_n_per_m;
        kp / (1.0 + s_um_per_v * k_f_v_per_n * kp * 1e-6)
    }

    /// `f_n = √((C_m + k_h)/m) / 2π` of the mechanical part, Hz.
    pub fn natural_frequency_hz(&self) -> f64 {
        libm::sqrt(self.total_stiffness() / self.mass_kg) / (2.0 * core::f64::consts::PI)
    }

    /// `ζ = K_d / (2·√((C_m + k_h)·m))` of the mechanical part.
    pub fn damping_ratio(&self) -> f64 {
        self.damping_n_s_per_m / (2.0 * libm::sqrt(self.total_stiffness() * self.mass_kg))
    }

    fn total_stiffness(&self) -> f64 {
        self.stiffness_n_per_m + self.load_stiffness_n_per_m
    }

    /// `T = C_m·d33`, N/V (= C/m): the electromechanical transformer ratio.
    pub fn coupling_n_per_v(&self) -> f64 {
        self.stiffness_n_per_m * self.d33_m_per_v
    }

    /// The electrical damping `R·T²` the back-coupling adds, N·s/m (for `R·C·ω ≪ 1`).
    pub fn electrical_damping_n_s_per_m(&self) -> f64 {
        let t = self.coupling_n_per_v();
        self.resistance_ohm * t * t
    }

    /// The substep `h`, s.
    pub fn substep_s(&self) -> f64 {
        1.0 / (self.sample_rate_hz * self.substeps.max(1) as f64)
    }

    /// Finite and in range: positive rate, mass, stiffness and capacitance,
    /// non-negative resistance, load stiffness, damping and `d33`, at least one
    /// substep, and `h·ω_n ≤ 0.5`.
    pub fn is_valid(&self) -> bool {
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let nonneg = |x: f64| x.is_finite() && x >= 0.0;
        pos(self.sample_rate_hz)
            && pos(self.mass_kg)
            && pos(self.stiffness_n_per_m)
            && pos(self.capacitance_f)
            && nonneg(self.resistance_ohm)
            && nonneg(self.load_stiffness_n_per_m)
            && nonneg(self.damping_n_s_per_m)
            && nonneg(self.d33_m_per_v)
            && self.preload_n.is_finite()
            && self.substeps >= 1
            && self.substep_s() * 2.0 * core::f64::consts::PI * self.natural_frequency_hz() <= 0.5
    }
}

/// One sample of the stack.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElectromechSample<F> {
    /// `V_act`, the voltage across the stack at the end of the sample, V.
    pub stack_voltage_v: F,
    /// The amplifier's current, mean over the sample (charge moved / period), A.
    pub current_a: F,
    /// `x`, the stack's displacement (its end), µm.
    pub displacement_um: F,
    /// `v`, its velocity, µm/s.
    pub velocity_um_per_s: F,
    /// `y(V_act)`, the hysteresis model's free stroke, µm.
    pub free_stroke_um: F,
    /// `F_s = F_0 + k_p·(y − x)`, the force through the stack at the end of the
    /// sample (what a force sensor in series with it reads), N.
    pub stack_force_n: F,
}

/// The simulator (configuration and state), in `f32` or `f64`.
#[derive(Debug, Clone)]
pub struct Electromech<'a, F> {
    p: ElectromechParams,
    model: Model<'a, F>,
    state: State<F>,
    /// The load `L(x) = f_F(x) − f_F(0)` (`None`: the linear `k_h·x`).
    load: Option<Fem<'a, F>>,
    /// Zero-order-hold transition of `[x, v]` (µm, µm/s) over a substep, and the
    /// response to a held force (N).
    phi: [[F; 2]; 2],
    gamma: [F; 2],
    /// `e^{−h/(R·C)}` (0 for `R = 0`).
    decay: F,
    /// `R·T`, V per µm/s; `T`, C/µm; `C`, F.
    rt: F,
    t: F,
    c: F,
    /// `k_p`, `k_h`, N/µm; `F_0`, `F_ext`, N.
    kp: F,
    kh: F,
    f0: F,
    f_ext: F,
    v_act: F,
    x: F,
    v: F,
    y: F,
    /// The force the mechanics was last driven with besides `(k_p + k_h)·x`, N.
    drive: F,
    rate: F,
}

impl<'a, F: Real> Electromech<'a, F> {
    /// A stack at rest (0 V, no motion, the model's state at rest) with hysteresis
    /// `model`, loaded by the preload map `load` (its `f_F(x) − f_F(0)`; `None`:
    /// the linear `k_h·x`); `None` if the parameters are not valid
    /// ([`ElectromechParams::is_valid`]) or the model has a compliance of its own
    /// (the stack's stiffness carries it).
    pub fn new(
        p: ElectromechParams,
        model: Model<'a, F>,
        load: Option<Fem<'a, F>>,
    ) -> Option<Self> {
        if !p.is_valid() || model.compliance() != F::ZERO {
            return None;
        }
        let h = p.substep_s();
        // µm-based units: N/µm, N·s/µm, N·s²/µm.
        let (m, k, d) = (
            p.mass_kg * 1e-6,
            p.total_stiffness() * 1e-6,
            p.damping_n_s_per_m * 1e-6,
        );
        let (phi, gamma) = zoh(m, k, d, h);
        let rc = p.resistance_ohm * p.capacitance_f;
        let decay = if rc > 0.0 { libm::exp(-h / rc) } else { 0.0 };
        let t = p.coupling_n_per_v() * 1e-6;
        let state = model.state(F::of(h));
        let mut s = Self {
            p,
            model,
            state,
            load,
            phi: phi.map(|r| r.map(F::of)),
            gamma: gamma.map(F::of),
            decay: F::of(decay),
            rt: F::of(p.resistance_ohm * t),
            t: F::of(t),
            c: F::of(p.capacitance_f),
            kp: F::of(p.stiffness_n_per_m * 1e-6),
            kh: F::of(p.load_stiffness_n_per_m * 1e-6),
            f0: F::of(p.preload_n),
            f_ext: F::ZERO,
            v_act: F::ZERO,
            x: F::ZERO,
            v: F::ZERO,
            y: F::ZERO,
            drive: F::ZERO,
            rate: F::of(p.sample_rate_hz),
        };
        // At rest: the equilibrium at 0 V (the free stroke there need not be 0),
        // without a start-up transient.
        let (x, y, _) = s.equilibrium(F::ZERO);
        s.x = x;
        s.y = y;
        s.drive = s.kp * y - s.nonlinear_load(x);
        Some(s)
    }

    /// The parameters.
    pub fn params(&self) -> &ElectromechParams {
        &self.p
    }

    /// The position `x` (µm), free stroke `y` (µm) and stack force (N) at rest
    /// under `volts`, found by a few fixed-point passes on the quasi-static balance
    /// `k_p·(y − x) = L(x) + F_ext` (the model not committed).
    fn equilibrium(&self, volts: F) -> (F, F, F) {
        let mut x = self.x;
        let mut y = self.y;
        for _ in 0..60 {
            let spring = Spring {
                force: self.f0,
                stiffness: self.kp,
                at: x,
            };
            y = coupled(&self.model, &self.state, volts, &spring, self.f0, y).x;
            let load = self.load_at(x) + self.f_ext;
            // k_p·(y − x) = L(x): one Newton step in x with L' ≈ k_h.
            let next = x + (self.kp * (y - x) - load) / (self.kp + self.kh);
            if (next - x).abs() <= F::EPSILON * (F::ONE + x.abs()) {
                x = next;
                break;
            }
            x = next;
        }
        (x, y, self.f0 + self.kp * (y - x))
    }

    /// `L(x)`, N.
    fn load_at(&self, x: F) -> F {
        match &self.load {
            Some(fem) => fem.preload_at(x) - fem.rest_preload(),
            None => self.kh * x,
        }
    }

    /// `L(x) − k_h·x`: what the transition matrix does not carry, N.
    fn nonlinear_load(&self, x: F) -> F {
        self.load_at(x) - self.kh * x
    }

    /// Sets the external force `F_ext` (N, pushing the stack back) held from the
    /// next sample on.
    pub fn set_external_force_n(&mut self, f_ext_n: F) {
        self.f_ext = f_ext_n;
    }

    /// `[x, v]` after a substep from `(x, v)` with the force `drive` held.
    #[inline]
    fn advance(&self, x: F, v: F, drive: F) -> (F, F) {
        let f = drive - self.f_ext;
        (
            self.phi[0][0] * x + self.phi[0][1] * v + self.gamma[0] * f,
            self.phi[1][0] * x + self.phi[1][1] * v + self.gamma[1] * f,
        )
    }

    /// One sample with the amplifier's source voltage `u_volts` held over it.
    pub fn step(&mut self, u_volts: F) -> ElectromechSample<F> {
        let q0 = self.c * self.v_act + self.t * self.x;
        let half = F::of(0.5);
        for _ in 0..self.p.substeps {
            // 1. Electrical part, exact for the held source and velocity.
            let v_e = u_volts - self.rt * self.v;
            self.v_act = v_e + (self.v_act - v_e) * self.decay;
            // 2. The free stroke at the substep's midpoint (predicted with the
            //    last drive), committed there.
            let (x_end, _) = self.advance(self.x, self.v, self.drive);
            let mid = half * (self.x + x_end);
            let spring = Spring {
                force: self.f0,
                stiffness: self.kp,
                at: mid,
            };
            let s = coupled(
                &self.model,
                &self.state,
                self.v_act,
                &spring,
                self.f0,
                self.y,
            );
            self.model.commit(&mut self.state, s.uh);
            self.y = s.x;
            // 3. Mechanics, exact for the held force.
            self.drive = self.kp * self.y - self.nonlinear_load(mid);
            (self.x, self.v) = self.advance(self.x, self.v, self.drive);
        }
        let q1 = self.c * self.v_act + self.t * self.x;
        ElectromechSample {
            stack_voltage_v: self.v_act,
            current_a: (q1 - q0) * self.rate,
            displacement_um: self.x,
            velocity_um_per_s: self.v,
            free_stroke_um: self.y,
            stack_force_n: self.f0 + self.kp * (self.y - self.x),
        }
    }

    /// One sample with the external force `f_ext_n` (N) set first.
    pub fn step_with_force(&mut self, u_volts: F, f_ext_n: F) -> ElectromechSample<F> {
        self.set_external_force_n(f_ext_n);
        self.step(u_volts)
    }
}

/// The zero-order-hold discretisation over `h` of `m·ẍ + c·ẋ + k·x = F`: `Φ`
/// and `Γ` with `[x, v]' = Φ·[x, v] + Γ·F`, from the exponential of the augmented
/// matrix `h·[[0, 1, 0], [−k/m, −c/m, 1/m], [0, 0, 0]]` (scaling and squaring,
/// Taylor to 16 terms; any damping).
fn zoh(m: f64, k: f64, c: f64, h: f64) -> ([[f64; 2]; 2], [f64; 2]) {
    let mut a = [
        [0.0, h, 0.0],
        [-k / m * h, -c / m * h, h / m],
        [0.0, 0.0, 0.0],
    ];
    let norm = a
        .iter()
        .map(|r| r.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let mut squarings = 0;
    let mut scale = 1.0;
    while norm * scale > 0.25 && squarings < 60 {
        scale *= 0.5;
        squarings += 1;
    }
    for row in a.iter_mut() {
        for v in row.iter_mut() {
            *v *= scale;
        }
    }
    let mul = |x: &[[f64; 3]; 3], y: &[[f64; 3]; 3]| {
        let mut r = [[0.0; 3]; 3];
        for (i, ri) in r.iter_mut().enumerate() {
            for (j, rij) in ri.iter_mut().enumerate() {
                *rij = (0..3).map(|l| x[i][l] * y[l][j]).sum();
            }
        }
        r
    };
    let mut e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut term = e;
    for n in 1..=16 {
        term = mul(&term, &a);
        for row in term.iter_mut() {
            for v in row.iter_mut() {
                *v /= n as f64;
            }
        }
        for (er, tr) in e.iter_mut().zip(&term) {
            for (ev, tv) in er.iter_mut().zip(tr) {
                *ev += *tv;
            }
        }
    }
    for _ in 0..squarings {
        e = mul(&e, &e);
    }
    ([[e[0][0], e[0][1]], [e[1][0], e[1][1]]], [e[0][2], e[1][2]])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::play::Pi;
    use std::vec::Vec;

    /// A linear stack: `y = w0·u`, µm/V.
    fn linear(w0: f64) -> Model<'static, f64> {
        Model::pi(Pi::new(w0, &[], &[], 150.0).unwrap())
    }

    /// A hysteretic stack (four play operators, 0.27 µm/V on the loading curve's
    /// upper part).
    fn hysteretic() -> Model<'static, f64> {
        Model::pi(
            Pi::new(
                0.12,
                &[10.0, 25.0, 45.0, 70.0],
                &[0.05, 0.04, 0.03, 0.03],
                150.0,
            )
            .unwrap(),
        )
    }

    /// Frequency (Hz) and damping ratio from the ring-down `d` (deviation from the
    /// final value) sampled at `fs`: peaks of |d| refined by a parabola, the mean
    /// half period and the log decrement between the first and the last peak.
    fn ring_down(d: &[f64], fs: f64) -> (f64, f64) {
        let mut peaks = Vec::new();
        for i in 1..d.len() - 1 {
            let (a, b, c) = (d[i - 1].abs(), d[i].abs(), d[i + 1].abs());
            if b > a && b >= c && b > 1e-9 {
                let den = a - 2.0 * b + c;
                let off = if den != 0.0 { 0.5 * (a - c) / den } else { 0.0 };
                peaks.push((i as f64 + off, b - 0.25 * (a - c) * off));
            }
        }
        assert!(peaks.len() > 10, "{} peaks", peaks.len());
        let (first, last) = (peaks[0], peaks[peaks.len() - 1]);
        let halves = (peaks.len() - 1) as f64;
        let f_d = fs / (2.0 * (last.0 - first.0) / halves);
        // ln(A_i/A_{i+1}) per half period = π·ζ/√(1 − ζ²).
        let delta = (first.1 / last.1).ln() / halves / core::f64::consts::PI;
        let zeta = delta / (1.0 + delta * delta).sqrt();
        (f_d / (1.0 - zeta * zeta).sqrt(), zeta)
    }

    fn step_response(p: ElectromechParams, w0: f64, u: f64, n: usize) -> Vec<f64> {
        let mut s = Electromech::new(p, linear(w0), None).unwrap();
        let x: Vec<f64> = (0..n).map(|_| s.step(u).displacement_um).collect();
        let end = w0 * u;
        x.iter().map(|x| x - end).collect()
    }

    #[test]
    fn the_mechanical_mode_rings_at_its_frequency_and_damping() {
        // An ideal source (R = 0): no electrical damping, the mechanics alone.
        let p = ElectromechParams {
            resistance_ohm: 0.0,
            ..ElectromechParams::stack_850hz()
        };
        assert!((p.natural_frequency_hz() - 850.0).abs() < 1e-9);
        assert!((p.damping_ratio() - 0.02).abs() < 1e-12);
        for substeps in [1, 4] {
            let p = ElectromechParams { substeps, ..p };
            let d = step_response(p, 0.27, 100.0, 2_000);
            let (f, zeta) = ring_down(&d, p.sample_rate_hz);
            std::println!("R = 0, {substeps} substeps: ring-down {f:.3} Hz, ζ = {zeta:.5}");
            assert!((f - 850.0).abs() < 0.5, "{f}");
            assert!((zeta - 0.02).abs() < 0.0004, "{zeta}");
        }
    }

    #[test]
    fn the_back_coupling_damps_the_mode_by_r_t_squared() {
        // R = 1 Ω: R·C·ω = 0.018, so the electrical damping is R·T² (with the
        // stack's stroke per volt equal to d33).
        let p = ElectromechParams::stack_850hz();
        let w0 = p.d33_m_per_v * 1e6;
        let d = step_response(p, w0, 100.0, 2_000);
        let (f, zeta) = ring_down(&d, p.sample_rate_hz);
        let crit = 2.0 * (p.stiffness_n_per_m * p.mass_kg).sqrt();
        let want = p.damping_ratio() + p.electrical_damping_n_s_per_m() / crit;
        std::println!("R = 1 Ω: ring-down {f:.3} Hz, ζ = {zeta:.5} (mechanical 0.02 + electrical R·T²: {want:.5})");
        assert!(want > 0.025, "the example has a visible electrical damping");
        assert!((zeta - want).abs() < 0.03 * want, "{zeta} vs {want}");
        assert!((f - 850.0).abs() < 0.01 * 850.0, "{f}");
    }

    #[test]
    fn the_current_is_c_du_dt_at_low_frequency() {
        // 5 Hz, 0–100 V. Without back-coupling the current is C·du/dt; with it,
        // (C + T·w0)·du/dt, the motional part included.
        let base = ElectromechParams {
            resistance_ohm: 10.0,
            ..ElectromechParams::stack_850hz()
        };
        for d33 in [0.0, base.d33_m_per_v] {
            let p = ElectromechParams {
                d33_m_per_v: d33,
                ..base
            };
            let w0 = 0.27;
            let c_eff = p.capacitance_f + p.coupling_n_per_v() * w0 * 1e-6;
            let mut s = Electromech::new(p, linear(w0), None).unwrap();
            let fs = p.sample_rate_hz;
            let u =
                |i: usize| 50.0 - 50.0 * (2.0 * core::f64::consts::PI * 5.0 * i as f64 / fs).cos();
            let (mut err2, mut ref2) = (0.0, 0.0);
            for i in 1..8_000 {
                let i_a = s.step(u(i)).current_a;
                let want = c_eff * (u(i) - u(i - 1)) * fs;
                err2 += (i_a - want) * (i_a - want);
                ref2 += want * want;
            }
            let rel = (err2 / ref2).sqrt();
            std::println!("d33 = {d33:e} m/V: current vs {c_eff:e} F·du/dt, rms error {rel:.2e}");
            assert!(rel < 0.01, "{rel}");
        }
    }

    #[test]
    fn the_static_stroke_is_the_hysteresis_model() {
        // Slow raised-cosine ramps (1 s, no velocity step, so the back-coupling
        // does not make V_act overshoot a turning point) between levels, each held
        // 0.2 s: at the end of each hold the stack sits at the hysteresis model's
        // output for the same sequence of extrema, minus F_ext/C_m.
        let p = ElectromechParams {
            resistance_ohm: 10.0,
            ..ElectromechParams::stack_850hz()
        };
        let f_ext = 5.0;
        let mut s = Electromech::new(p, hysteretic(), None).unwrap();
        s.set_external_force_n(f_ext);
        let model = hysteretic();
        let mut st = model.state(1.0 / p.sample_rate_hz);
        let fs = p.sample_rate_hz;
        let (ramp, hold) = ((1.0 * fs) as usize, (0.2 * fs) as usize);
        let mut from = 0.0;
        for to in [120.0, 30.0, 90.0, 60.0, 150.0, 0.0, 75.0] {
            let mut last = None;
            for i in 1..=ramp + hold {
                let r = i.min(ramp) as f64 / ramp as f64;
                let u = from + (to - from) * 0.5 * (1.0 - (core::f64::consts::PI * r).cos());
                last = Some(s.step(u));
            }
            let want = model.step(&mut st, to, 0.0, 0.0) - f_ext / p.stiffness_n_per_m * 1e6;
            let got = last.unwrap();
            std::println!(
                "{from:>5.1} → {to:>5.1} V: x = {:.6} µm, model {want:.6} µm, V_act {:.6} V",
                got.displacement_um,
                got.stack_voltage_v
            );
            assert!(
                (got.displacement_um - want).abs() < 1e-6,
                "{got:?} vs {want}"
            );
            assert!((got.stack_voltage_v - to).abs() < 1e-9);
            assert!(got.current_a.abs() < 1e-9);
            from = to;
        }
    }

    #[test]
    fn invalid_parameters_and_compliant_models_are_refused() {
        let p = ElectromechParams::stack_850hz();
        assert!(
            Electromech::new(ElectromechParams { mass_kg: 0.0, ..p }, linear(0.27), None).is_none()
        );
        // 20 kHz with one substep is fine for 850 Hz, not for a 5 kHz mode.
        assert!(
            Electromech::new(ElectromechParams { substeps: 1, ..p }, linear(0.27), None).is_some()
        );
        assert!(Electromech::new(
            ElectromechParams {
                substeps: 1,
                ..p.with_mode(5_000.0, 0.02)
            },
            linear(0.27),
            None
        )
        .is_none());
        let mut compliant = linear(0.27);
        compliant.coupling = Some(crate::model::Coupling {
            offset: 0.0,
            k_f: 0.0,
            k_q: 0.0,
            force_q: 0.0,
            compliance: 0.02,
        });
        assert!(Electromech::new(p, compliant, None).is_none());
    }
}
