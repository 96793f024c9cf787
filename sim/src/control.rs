//! The control step in floating point: the reference the fixed-point
//! `piezo_fpi::control` step is measured against, with the same law, written
//! plainly.
//!
//! ```text
//! supervise: force in range, force plausible against f_F(x_pea_est), reference reachable
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
            fault: None,
        }
    }

    fn limit(&self, prev: F, want: F) -> (F, bool) {
        let lo = (prev - self.max_step).max(self.u_min);
        let hi = (prev + self.max_step).min(self.u_max);
        let u = want.clamp_to(lo, hi);
        (u, u != want)
    }

    fn supervise(&self, st: &ControlState<F>, x_ref: F, force: F) -> Option<Fault> {
        let inside = |v: F, r: (F, F)| v >= r.0 && v <= r.1;
        if self.measured && !inside(force, self.force) {
            Some(Fault::ForceOutOfRange)
        } else if self.measured
            && (force - self.f_f.held(st.x_pea_est)).abs() > self.force_tolerance
        {
            Some(Fault::ForceImplausible)
        } else if !inside(x_ref, self.reference) {
            Some(Fault::ReferenceUnreachable)
        } else {
            None
        }
    }

    /// One control step: reference stage position (µm) and force reading (N) in.
    pub fn step(&self, st: &mut ControlState<F>, x_ref: F, force: F) -> StepOut<F> {
        if st.fault.is_none() {
            st.fault = self.supervise(st, x_ref, force);
        }
        if let Some(fault) = st.fault {
            let (voltage, _) = self.limit(st.voltage, self.safe_voltage);
            let f = if self.measured && force >= self.force.0 && force <= self.force.1 {
                force
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
            };
        }
        let x_pea_ref = self.f_k_inv.held(x_ref);
        let f = if self.measured {
            force
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
        }
    }
}
