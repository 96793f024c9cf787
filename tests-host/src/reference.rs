//! The f64 reference of the fixed-point core: the same model, the same control
//! law, written plainly (eq. (3) with both min and max, closed-form inverse in
//! f64 from the unquantised weights, linear interpolation in f64), so the tests
//! can measure what fixed point costs.

use crate::model_file::{FirmwareModel, MapSection, TableSection};

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

/// An FPI model in f64, with the core's extensions (see `piezo_fpi::fpi`).
#[derive(Debug, Clone, PartialEq)]
pub struct FpiF64 {
    /// Forward PI.
    pub pi: PiF64,
    /// `PI'`: the PI with this sample's creep in `w0`.
    pub pi_prime: PiF64,
    /// The inverse of `PI'`.
    pub inv: PiF64,
    /// Constant part of the preload offset, V.
    pub offset: f64,
    /// Force–voltage coupling, V/N.
    pub k_f: f64,
    /// Curvature of the preload offset, V/N².
    pub k_q: f64,
    /// Its centre, N.
    pub force_q: f64,
    /// Compliance, µm/N.
    pub compliance: f64,
    /// Reference force, N.
    pub force_ref: f64,
    /// Soft dead zone (tables), if any.
    pub dead_zone: Option<MapSection>,
    /// Output saturation (tables), if any.
    pub saturation: Option<MapSection>,
    /// Creep terms: (1 - a, b).
    pub creep: Vec<(f64, f64)>,
}

impl FpiF64 {
    /// The paper's FPI with compliance: `x = Y[max(u - k_f F, 0)] - c (F - F_ref)`.
    pub fn new(pi: PiF64, k_f: f64, compliance: f64, force_ref: f64) -> Self {
        Self::extended(
            pi,
            0.0,
            k_f,
            0.0,
            0.0,
            compliance,
            force_ref,
            None,
            None,
            Vec::new(),
        )
    }

    /// The extended model.
    #[allow(clippy::too_many_arguments)]
    pub fn extended(
        pi: PiF64,
        offset: f64,
        k_f: f64,
        k_q: f64,
        force_q: f64,
        compliance: f64,
        force_ref: f64,
        dead_zone: Option<MapSection>,
        saturation: Option<MapSection>,
        creep: Vec<(f64, f64)>,
    ) -> Self {
        let mut pi_prime = pi.clone();
        pi_prime.w0 += creep.iter().map(|(r, b)| b * r).sum::<f64>();
        let inv = pi_prime.inverse();
        Self {
            pi,
            pi_prime,
            inv,
            offset,
            k_f,
            k_q,
            force_q,
            compliance,
            force_ref,
            dead_zone,
            saturation,
            creep,
        }
    }

    /// The preload offset `U_p(F)`, V.
    pub fn preload_offset(&self, force: f64) -> f64 {
        let d = (force - self.force_q).clamp(-1024.0, 1024.0);
        self.offset + self.k_f * force + self.k_q * d * d
    }

    /// Forward model: voltage and force → stack extension; advances the bank and
    /// the creep memories.
    pub fn forward(&self, bank: &mut BankF64, creep: &mut [f64], u: f64, force: f64) -> f64 {
        let e = u - self.preload_offset(force);
        let uh = match &self.dead_zone {
            Some(g) => g.apply(e),
            None => e,
        }
        .clamp(0.0, self.pi.input_max);
        let mut y = self.pi.apply(bank, uh);
        for (m, (r, b)) in creep.iter_mut().zip(&self.creep) {
            *m += r * (uh - *m);
            y += b * *m;
        }
        let z = match &self.saturation {
            Some(h) => h.apply(y),
            None => y,
        };
        z - self.compliance * (force - self.force_ref)
    }

    /// Inverse model: stack extension and force → voltage; reads the creep memories.
    pub fn inverse(&self, bank: &mut BankF64, creep: &[f64], x: f64, force: f64) -> f64 {
        self.inverse_checked(bank, creep, x, force).0
    }

    /// [`inverse`](Self::inverse), and whether the effective voltage asked for lies
    /// in the foot of the soft dead zone (below its inverse table).
    pub fn inverse_checked(
        &self,
        bank: &mut BankF64,
        creep: &[f64],
        x: f64,
        force: f64,
    ) -> (f64, bool) {
        let z = x + self.compliance * (force - self.force_ref);
        let mut v = match &self.saturation {
            Some(h) => h.invert(z),
            None => z,
        };
        for (m, (r, b)) in creep.iter().zip(&self.creep) {
            v -= b * (1.0 - r) * m;
        }
        let uh = self.inv.apply(bank, v);
        let (e, foot) = match &self.dead_zone {
            Some(g) => (g.invert(uh), uh < g.inverse.x0),
            None => (uh, false),
        };
        (self.preload_offset(force) + e, foot)
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
    /// Creep memories, V.
    pub creep: Vec<f64>,
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
        let creep = m
            .creep
            .iter()
            .map(|cr| (cr.rate(k.rate_hz as f64), cr.gain_um_per_v))
            .collect();
        Self {
            fpi: FpiF64::extended(
                pi,
                c.offset_v,
                c.k_f_v_per_n,
                c.k_q_v_per_n2,
                c.force_q_n,
                c.compliance_um_per_n,
                c.force_ref_n,
                m.dead_zone.clone(),
                m.saturation.clone(),
                creep,
            ),
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
            creep: vec![0.0; self.fpi.creep.len()],
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
            let x = self.fpi.forward(&mut st.forward, &mut st.creep, voltage, f);
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
        let (want, foot) = self
            .fpi
            .inverse_checked(&mut st.inverse, &st.creep, x_pea_ref, f);
        let (voltage, limited) = self.limit(st.voltage, want);
        let x_pea_est = self.fpi.forward(&mut st.forward, &mut st.creep, voltage, f);
        if limited || foot {
            self.fpi.pi_prime.resync(&st.forward, &mut st.inverse);
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
