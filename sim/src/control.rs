//! The control step in floating point: the reference the fixed-point
//! `piezo_fpi::control` step is measured against, with the same law, written
//! plainly.
//!
//! ```text
//! force channel: r = F − f_F(x_pea_est), p = r_0 + b·Δ (Δ = f_F(x_pea_est) − f_F(x_0)),
//!                r_s ← r_s + a·(r − p − r_s), r_0 ← r_0 + 2⁻¹¹·r_s, b ← b + 2⁻¹⁸·r_s·Δ,
//!                F_ff = f_F(x_pea_est) + p + r_s
//! supervise: force in range, r_s within the tolerance, r within the dynamic limit, reference reachable
//! x_pea_ref = f_K⁻¹(x_ref)
//! u         = inverse model at x_pea_ref under the force          (closed form)
//! u_out     = limits(u)                                            (range and slew)
//! x_pea_est = forward model at u_out                               (virtual sensor)
//! ```
//!
//! The tables are held at their ends and the maps are tabulated, as in the
//! firmware; a fault ramps the output to the safe voltage at the slew limit.

use piezo_fpi::control::Fault;

use crate::curve::Curve;
use crate::model::{Model, State};
use crate::play::{Bank, Pi};
use crate::real::Real;

/// The settings of the control step (configuration).
#[derive(Debug, Clone, PartialEq)]
pub struct Controller<'a, F> {
    /// The model.
    pub model: Model<'a, F>,
    /// `f_F`: stack extension (µm) → force (N).
    pub f_f: Curve<'a, F>,
    /// `f_K`: stack extension (µm) → stage output (µm).
    pub f_k: Curve<'a, F>,
    /// `f_K⁻¹`: stage output (µm) → stack extension (µm).
    pub f_k_inv: Curve<'a, F>,
    /// Lowest setpoint, V.
    pub u_min: F,
    /// Highest setpoint, V.
    pub u_max: F,
    /// Largest change per step, V.
    pub max_step: F,
    /// Reachable references, µm.
    pub reference: (F, F),
    /// Plausible forces, N.
    pub force: (F, F),
    /// Tolerated `|F - f_F(x_pea_est)|`, N.
    pub force_tolerance: F,
    /// Safe voltage, V.
    pub safe_voltage: F,
    /// Force from the sensor (`true`) or from `f_F` of the reference.
    pub measured: bool,
    /// The force channel's split rate per step (0: the reading as it is).
    pub split: F,
    /// Tolerated `|F - f_F(x_pea_est)|` at once, N.
    pub dynamic_limit: F,
    /// The compliance term's reference force `F_ref`, N.
    pub force_ref: F,
    /// Control period, s.
    pub dt: F,
}

/// State of the control step.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlState<F> {
    /// The inverse bank.
    pub inverse: Bank<F>,
    /// The forward model's memory (operators, creep).
    pub model: State<F>,
    /// The inverse of the PI with this sample's creep.
    pub inverse_pi: Pi<F>,
    /// Last voltage, V.
    pub voltage: F,
    /// Last estimated stack extension, µm.
    pub x_pea_est: F,
    /// The slow part of the force residual beyond the learned map, N.
    pub force_slow: F,
    /// The preload map's learned offset, N.
    pub force_offset: F,
    /// The residual at the tare, N.
    pub force_tare_offset: F,
    /// The learned scale error of the preload map.
    pub force_scale: F,
    /// Latched fault.
    pub fault: Option<Fault>,
}

/// One step's results.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOut<F> {
    /// Setpoint, V.
    pub voltage: F,
    /// Stack extension asked for, µm.
    pub x_pea_ref: F,
    /// Virtual sensor, µm.
    pub x_pea_est: F,
    /// The limits changed the voltage.
    pub limited: bool,
    /// Latched fault.
    pub fault: Option<Fault>,
    /// The force the model used (the force channel's feedforward), N.
    pub force: F,
    /// The force channel's dynamic part, N.
    pub dynamic: F,
}

impl<F: Real> Controller<'_, F> {
    /// A fresh state at the safe voltage, all operators at rest.
    pub fn initial_state(&self) -> ControlState<F> {
        let model = self.model.state(self.dt);
        let inverse_pi = self.model.inverse_pi(&model);
        ControlState {
            inverse: inverse_pi.at_rest(),
            model,
            inverse_pi,
            voltage: self.safe_voltage,
            x_pea_est: F::ZERO,
            force_slow: F::ZERO,
            force_offset: F::ZERO,
            force_tare_offset: F::ZERO,
            force_scale: F::ZERO,
            fault: None,
        }
    }

    /// Takes `force` (N) as the compliance reference and settles the force
    /// channel on the residual at rest (the fixed-point `tare`).
    pub fn tare(&mut self, st: &mut ControlState<F>, force: F) {
        self.force_ref = force;
        st.force_tare_offset = force - self.f_f.held(st.x_pea_est);
        st.force_offset = st.force_tare_offset;
        st.force_slow = F::ZERO;
        st.force_scale = F::ZERO;
    }

    /// The force channel: the feedforward force and the dynamic part from the
    /// reading, the slow part advanced (for a reading in range).
    fn sense(&self, st: &mut ControlState<F>, force: F) -> (F, F, bool) {
        let model = self.f_f.held(st.x_pea_est);
        if !self.measured {
            return (model, F::ZERO, true);
        }
        let in_range = force >= self.force.0 && force <= self.force.1;
        let r = force - model;
        let slow = if self.split == F::ZERO {
            r
        } else {
            // The learned map: the offset at the tare and the scale error (used
            // to 2⁻³², as the fixed-point channel keeps it).
            let delta = model - (self.force_ref - st.force_tare_offset);
            let q = F::of(4294967296.0); // 2³²
            let b = (st.force_scale * q).floor() / q;
            let learned = st.force_offset + b * delta;
            if in_range {
                st.force_slow += self.split * (r - learned - st.force_slow);
                if st.fault.is_none() {
                    st.force_offset += F::of(1.0 / 2048.0) * st.force_slow; // 2⁻¹¹
                    let mu = F::of(1.0 / 262144.0); // 2⁻¹⁸
                    let lim = F::of(0.25);
                    // The step's factors held as the fixed-point channel holds
                    // them (±32 N and ±2048 N).
                    let rs = st.force_slow.clamp_to(F::of(-32.0), F::of(32.0));
                    let d = delta.clamp_to(F::of(-2048.0), F::of(2048.0));
                    st.force_scale = (st.force_scale + mu * rs * d).clamp_to(-lim, lim);
                }
            }
            learned + st.force_slow
        };
        if st.fault.is_none() {
            if !in_range {
                st.fault = Some(Fault::ForceOutOfRange);
            } else if slow.abs() > self.force_tolerance || r.abs() > self.dynamic_limit {
                st.fault = Some(Fault::ForceImplausible);
            }
        }
        let dynamic = if in_range { r - slow } else { F::ZERO };
        (model + slow, dynamic, in_range)
    }

    fn limit(&self, prev: F, want: F) -> (F, bool) {
        let lo = (prev - self.max_step).max(self.u_min);
        let hi = (prev + self.max_step).min(self.u_max);
        let u = want.clamp_to(lo, hi);
        (u, u != want)
    }

    /// One control step: reference stage position (µm) and force reading (N) in.
    pub fn step(&self, st: &mut ControlState<F>, x_ref: F, force: F) -> StepOut<F> {
        let (ff, dynamic, in_range) = self.sense(st, force);
        if st.fault.is_none() && !(x_ref >= self.reference.0 && x_ref <= self.reference.1) {
            st.fault = Some(Fault::ReferenceUnreachable);
        }
        if let Some(fault) = st.fault {
            let (voltage, _) = self.limit(st.voltage, self.safe_voltage);
            let f = if self.measured && in_range {
                ff
            } else {
                self.f_f.held(st.x_pea_est)
            };
            let x = self.model.step(&mut st.model, voltage, f, self.force_ref);
            st.voltage = voltage;
            st.x_pea_est = x;
            return StepOut {
                voltage,
                x_pea_ref: x,
                x_pea_est: x,
                limited: true,
                fault: Some(fault),
                force: f,
                dynamic,
            };
        }
        let x_pea_ref = self.f_k_inv.held(x_ref);
        let f = if self.measured {
            ff
        } else {
            self.f_f.held(x_pea_ref)
        };
        let (want, foot) = self.model.inverse(
            &st.inverse_pi,
            &mut st.inverse,
            &st.model,
            x_pea_ref,
            f,
            self.force_ref,
        );
        let (voltage, limited) = self.limit(st.voltage, want);
        let x_pea_est = self.model.step(&mut st.model, voltage, f, self.force_ref);
        if limited || foot {
            self.model
                .prime(&st.model)
                .resync(&st.model.bank, &mut st.inverse);
        }
        st.voltage = voltage;
        st.x_pea_est = x_pea_est;
        StepOut {
            voltage,
            x_pea_ref,
            x_pea_est,
            limited,
            fault: None,
            force: f,
            dynamic,
        }
    }
}
