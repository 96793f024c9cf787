//! The f64 reference of the fixed-point core: the same model, the same control
//! law, written plainly (eq. (3) with both min and max, closed-form inverse in
//! f64 from the unquantised weights, linear interpolation in f64), so the tests
//! can measure what fixed point costs.

use crate::model_file::{FirmwareModel, TableSection};

/// A PI model in f64: `Y[u] = w0·u + Σ w_i G_{r_i}[u]`, inputs clamped to `[0, input_max]`.
#[derive(Debug, Clone, PartialEq)]
pub struct PiF64 {
    /// Linear weight.
    pub w0: f64,
    /// Thresholds (sorted).
    pub r: Vec<f64>,
    /// Weights.
    pub w: Vec<f64>,
    /// Input domain upper end.
    pub input_max: f64,
}

/// Operator outputs and last input of an f64 bank.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BankF64 {
    /// Operator outputs.
    pub y: Vec<f64>,
    /// Last input.
    pub last: f64,
}

impl BankF64 {
    /// A bank of `n` operators at rest.
    pub fn new(n: usize) -> Self {
        Self {
            y: vec![0.0; n],
            last: 0.0,
        }
    }
}

impl PiF64 {
    /// One sample of eq. (3)–(4).
    pub fn apply(&self, bank: &mut BankF64, u: f64) -> f64 {
        let u = u.clamp(0.0, self.input_max);
        let mut x = self.w0 * u;
        for ((y, r), w) in bank.y.iter_mut().zip(&self.r).zip(&self.w) {
            *y = (u - r).max(u.min(*y));
            x += w * *y;
        }
        bank.last = u;
        x
    }

    /// `Y[input_max]` on the loading curve.
    pub fn output_max(&self) -> f64 {
        let u = self.input_max;
        self.w0 * u
            + self
                .r
                .iter()
                .zip(&self.w)
                .map(|(r, w)| w * (u - r).max(0.0))
                .sum::<f64>()
    }

    /// The closed-form inverse (also a PI model).
    pub fn inverse(&self) -> PiF64 {
        let mut s_prev = self.w0;
        let mut sum_wr = 0.0;
        let (mut r, mut w) = (Vec::new(), Vec::new());
        for (rj, wj) in self.r.iter().zip(&self.w) {
            let s = s_prev + wj;
            sum_wr += wj * rj;
            r.push(s * rj - sum_wr);
            w.push(-wj / (s * s_prev));
            s_prev = s;
        }
        PiF64 {
            w0: 1.0 / self.w0,
            r,
            w,
            input_max: self.output_max(),
        }
    }

    /// The inverse bank's state that matches a forward bank.
    pub fn resync(&self, fwd: &BankF64, inv: &mut BankF64) {
        let mut s: f64 = self.w0 + self.w.iter().sum::<f64>();
        let mut tail = 0.0;
        for j in (0..self.w.len()).rev() {
            let y = fwd.y[j];
            inv.y[j] = s * y + tail;
            tail += self.w[j] * y;
            s -= self.w[j];
        }
        inv.last = (self.w0 * fwd.last + tail).clamp(0.0, self.output_max());
    }
}

/// An FPI model in f64.
#[derive(Debug, Clone, PartialEq)]
pub struct FpiF64 {
    /// Forward PI.
    pub pi: PiF64,
    /// Its inverse.
    pub inv: PiF64,
    /// Force–voltage coupling, V/N.
    pub k_f: f64,
    /// Compliance, µm/N.
    pub compliance: f64,
    /// Reference force, N.
    pub force_ref: f64,
}

impl FpiF64 {
    /// The model from its parts.
    pub fn new(pi: PiF64, k_f: f64, compliance: f64, force_ref: f64) -> Self {
        let inv = pi.inverse();
        Self {
            pi,
            inv,
            k_f,
            compliance,
            force_ref,
        }
    }

    /// Forward FPI: voltage and force → stack extension.
    pub fn forward(&self, bank: &mut BankF64, u: f64, force: f64) -> f64 {
        self.pi.apply(bank, u - self.k_f * force) - self.compliance * (force - self.force_ref)
    }

    /// Inverse FPI: stack extension and force → voltage.
    pub fn inverse(&self, bank: &mut BankF64, x: f64, force: f64) -> f64 {
        let y = (x + self.compliance * (force - self.force_ref)).clamp(0.0, self.inv.input_max);
        self.inv.apply(bank, y) + self.k_f * force
    }
}

/// A lookup table in f64 (the model file's knots, the core's grid).
pub type TableF64 = TableSection;

/// The faults of the f64 controller (same order as the core's checks).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultF64 {
    /// Force outside the sensor range.
    ForceOutOfRange,
    /// Force disagrees with `f_F`.
    ForceImplausible,
    /// Reference outside the stroke.
    ReferenceUnreachable,
}

/// The control step in f64.
#[derive(Debug, Clone, PartialEq)]
pub struct ControllerF64 {
    /// The model.
    pub fpi: FpiF64,
    /// `f_F`.
    pub f_f: TableF64,
    /// `f_K`.
    pub f_k: TableF64,
    /// `f_K⁻¹`.
    pub f_k_inv: TableF64,
    /// Voltage range.
    pub u_min: f64,
    /// Voltage range.
    pub u_max: f64,
    /// Largest change per step, V.
    pub max_step: f64,
    /// Reachable references, µm.
    pub reference: (f64, f64),
    /// Plausible forces, N.
    pub force: (f64, f64),
    /// Tolerated `|F - f_F(x_pea_est)|`, N.
    pub force_tolerance: f64,
    /// Safe voltage, V.
    pub safe_voltage: f64,
    /// Force from the sensor (`true`) or from `f_F` of the reference.
    pub measured: bool,
}

/// State of the f64 controller.
#[derive(Debug, Clone, PartialEq)]
pub struct StateF64 {
    /// Inverse bank.
    pub inverse: BankF64,
    /// Forward bank.
    pub forward: BankF64,
    /// Last voltage.
    pub voltage: f64,
    /// Last estimate.
    pub x_pea_est: f64,
    /// Latched fault.
    pub fault: Option<FaultF64>,
}

/// One step's results in f64.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutF64 {
    /// Setpoint, V.
    pub voltage: f64,
    /// Stack extension asked for, µm.
    pub x_pea_ref: f64,
    /// Virtual sensor, µm.
    pub x_pea_est: f64,
    /// Limited.
    pub limited: bool,
    /// Fault.
    pub fault: Option<FaultF64>,
}

impl ControllerF64 {
    /// The controller a firmware model file describes.
    pub fn from_model(m: &FirmwareModel) -> Self {
        let pi = PiF64 {
            w0: m.pi.w0_um_per_v,
            r: m.pi.thresholds_v.clone(),
            w: m.pi.weights_um_per_v.clone(),
            input_max: m.pi.input_max_v,
        };
        let c = &m.coupling;
        let k = &m.controller;
        Self {
            fpi: FpiF64::new(pi, c.k_f_v_per_n, c.compliance_um_per_n, c.force_ref_n),
            f_f: m.tables.f_f.clone(),
            f_k: m.tables.f_k.clone(),
            f_k_inv: m.tables.f_k_inv.clone(),
            u_min: k.u_min_v,
            u_max: k.u_max_v,
            max_step: k.slew_v_per_ms * 1e3 / k.rate_hz as f64,
            reference: (k.reference_min_um, k.reference_max_um),
            force: (k.force_min_n, k.force_max_n),
            force_tolerance: k.force_tolerance_n,
            safe_voltage: k.safe_voltage_v,
            measured: k.force_source == "measured",
        }
    }

    /// A fresh state.
    pub fn initial_state(&self) -> StateF64 {
        let n = self.fpi.pi.r.len();
        StateF64 {
            inverse: BankF64::new(n),
            forward: BankF64::new(n),
            voltage: self.safe_voltage,
            x_pea_est: 0.0,
            fault: None,
        }
    }

    fn limit(&self, prev: f64, want: f64) -> (f64, bool) {
        let lo = (prev - self.max_step).max(self.u_min);
        let hi = (prev + self.max_step).min(self.u_max);
        let u = want.clamp(lo, hi);
        (u, u != want)
    }

    /// One control step, the f64 twin of `ControllerConfig::step`.
    pub fn step(&self, st: &mut StateF64, x_ref: f64, force: f64) -> OutF64 {
        if st.fault.is_none() {
            let in_range = |v: f64, r: (f64, f64)| v >= r.0 && v <= r.1;
            st.fault = if self.measured && !in_range(force, self.force) {
                Some(FaultF64::ForceOutOfRange)
            } else if self.measured
                && (force - self.f_f.eval(st.x_pea_est)).abs() > self.force_tolerance
            {
                Some(FaultF64::ForceImplausible)
            } else if !in_range(x_ref, self.reference) {
                Some(FaultF64::ReferenceUnreachable)
            } else {
                None
            };
        }
        if let Some(fault) = st.fault {
            let (voltage, _) = self.limit(st.voltage, self.safe_voltage);
            let f = if self.measured && force >= self.force.0 && force <= self.force.1 {
                force
            } else {
                self.f_f.eval(st.x_pea_est)
            };
            let x = self.fpi.forward(&mut st.forward, voltage, f);
            st.voltage = voltage;
            st.x_pea_est = x;
            return OutF64 {
                voltage,
                x_pea_ref: x,
                x_pea_est: x,
                limited: true,
                fault: Some(fault),
            };
        }
        let x_pea_ref = self.f_k_inv.eval(x_ref);
        let f = if self.measured {
            force
        } else {
            self.f_f.eval(x_pea_ref)
        };
        let want = self.fpi.inverse(&mut st.inverse, x_pea_ref, f);
        let (voltage, limited) = self.limit(st.voltage, want);
        let x_pea_est = self.fpi.forward(&mut st.forward, voltage, f);
        if limited {
            self.fpi.pi.resync(&st.forward, &mut st.inverse);
        }
        st.voltage = voltage;
        st.x_pea_est = x_pea_est;
        OutF64 {
            voltage,
            x_pea_ref,
            x_pea_est,
            limited,
            fault: None,
        }
    }
}
