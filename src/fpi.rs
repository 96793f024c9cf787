//! The Force-dependent Prandtl–Ishlinskii model (seed 000, eqs. 5–7), with stack compliance.
//!
//! The stack responds to the effective voltage `û = u - k_f·F`: the preload `F`
//! induces a reverse voltage `k_f·F` across the ceramic. Its extension is
//!
//! ```text
//! x_pea = Y[max(û, 0)] - c·(F - F_ref)
//! ```
//!
//! * **Dead zone (`û < 0`).** One-sided play operators are defined for a unipolar
//!   input. While the applied voltage has not overcome the preload's reverse
//!   voltage the stack does not extend, so `û` is clamped at 0 before it reaches
//!   the bank: the operators see "no drive" and stay at rest. This is what the
//!   recorded data show: the stack starts to move at `u ≈ k_f·F` (2.5 V at 25 N,
//!   15 V at 150 N), and a higher preload both widens the dead zone and shortens
//!   the stroke.
//! * **Compliance (`c`, µm/N).** The stack is a spring (datasheet ≈ 50 N/µm, so
//!   `c ≈ 0.02 µm/N`): a rising hinge force compresses it. `F_ref` is the force at
//!   which displacement is zeroed (the assembly preload). Set `c = 0` for the
//!   paper's FPI model.
//!
//! The inverse is explicit because the force is measured (or predicted from the
//! reference through `f_F`): `u = PI⁻¹[x_pea + c·(F - F_ref)] + k_f·F`.

use crate::error::ModelError;
use crate::inverse::InversePi;
use crate::pi::PiModel;
use crate::play::PlayBank;
use crate::q::{
    coupling_mul, Micrometres, Newtons, UmPerNewton, Volts, VoltsPerNewton, SIGNAL_ABS_MAX_BITS,
};

/// The force coupling of an FPI model.
///
/// * `k_f` — force–voltage coupling, V/N, `I0F32`.
/// * `compliance` — `c`, µm/N, `I0F32` (0 for the paper's model).
/// * `force_ref` — `F_ref`, N, `I16F16`: force at which the extension is zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Coupling {
    /// Force–voltage coupling `k_f`, V/N.
    pub k_f: VoltsPerNewton,
    /// Stack compliance `c`, µm/N.
    pub compliance: UmPerNewton,
    /// Reference force `F_ref`, N.
    pub force_ref: Newtons,
}

/// A calibrated FPI model: forward PI, its closed-form inverse, and the coupling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fpi<const N: usize> {
    pi: PiModel<N>,
    inverse: InversePi<N>,
    coupling: Coupling,
}

/// The force terms of one sample, computed once and shared by inverse and forward.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceTerms {
    /// Reverse voltage `k_f·F`, V.
    pub reverse_voltage: Volts,
    /// Compression `c·(F - F_ref)`, µm.
    pub compression: Micrometres,
}

impl<const N: usize> Fpi<N> {
    /// Builds the model and its inverse; `const` so the firmware's model is checked
    /// when it is compiled.
    pub const fn new(pi: PiModel<N>, coupling: Coupling) -> Result<Self, ModelError> {
        let inverse = match InversePi::from_forward(&pi) {
            Ok(i) => i,
            Err(e) => return Err(e),
        };
        let fr = coupling.force_ref.to_bits();
        if fr > SIGNAL_ABS_MAX_BITS || fr < -SIGNAL_ABS_MAX_BITS {
            return Err(ModelError::NotRepresentable);
        }
        Ok(Self {
            pi,
            inverse,
            coupling,
        })
    }

    /// `k_f·F` and `c·(F - F_ref)` for a force `F` (N), each rounded once.
    #[inline(always)]
    pub fn force_terms(&self, force: Newtons) -> ForceTerms {
        ForceTerms {
            reverse_voltage: coupling_mul(self.coupling.k_f, force),
            compression: coupling_mul(
                self.coupling.compliance,
                force.saturating_sub(self.coupling.force_ref),
            ),
        }
    }

    /// Forward FPI: applied voltage `u` (V) under force terms `t` → stack extension (µm).
    /// Advances the forward bank.
    #[inline(always)]
    pub fn forward(&self, bank: &mut PlayBank<N>, u: Volts, t: ForceTerms) -> Micrometres {
        // `PiModel::apply` clamps û to [0, input_max]: the dead zone.
        self.pi.apply(bank, u.saturating_sub(t.reverse_voltage)) - t.compression
    }

    /// Inverse FPI: desired stack extension `x_pea` (µm) under force terms `t` → the
    /// voltage (V) to apply. Advances the inverse bank.
    ///
    /// `x_pea + c·(F - F_ref)` is clamped to the PI output range, so the result lies
    /// in `[k_f·F, input_max + k_f·F]`; the caller applies the actuator limits.
    #[inline(always)]
    pub fn inverse(&self, bank: &mut PlayBank<N>, x_pea: Micrometres, t: ForceTerms) -> Volts {
        self.inverse.apply(bank, x_pea + t.compression) + t.reverse_voltage
    }

    /// Realigns the inverse bank with the forward bank (see [`InversePi::resync`]).
    #[inline]
    pub fn resync(&self, forward: &PlayBank<N>, inverse: &mut PlayBank<N>) {
        self.inverse.resync(&self.pi, forward, inverse);
    }

    /// The forward PI model.
    pub const fn pi(&self) -> &PiModel<N> {
        &self.pi
    }
    /// Its closed-form inverse.
    pub const fn inverse_pi(&self) -> &InversePi<N> {
        &self.inverse
    }
    /// The force coupling.
    pub const fn coupling(&self) -> &Coupling {
        &self.coupling
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::q::{coupling, signal};

    fn model(c: f64) -> Fpi<3> {
        let pi =
            PiModel::from_f64(0.064, &[10.0, 30.0, 60.0], &[0.01, 0.008, 0.004], 150.0).unwrap();
        let coupling = Coupling {
            k_f: coupling(0.1).unwrap(),
            compliance: coupling(c).unwrap(),
            force_ref: signal(60.0).unwrap(),
        };
        Fpi::new(pi, coupling).unwrap()
    }

    #[test]
    fn dead_zone_holds_the_stack_until_u_exceeds_kf_f() {
        let m = model(0.0);
        let mut bank = PlayBank::new();
        let t = m.force_terms(Newtons::from_num(100));
        // k_f F = 10 V: below it nothing moves.
        for u in [0.0, 4.0, 9.99] {
            assert_eq!(
                m.forward(&mut bank, Volts::from_num(u), t),
                Micrometres::ZERO
            );
        }
        let x = m.forward(&mut bank, Volts::from_num(20), t).to_num::<f64>();
        assert!((x - 0.64).abs() < 1e-4, "{x}");
    }

    #[test]
    fn compliance_compresses_under_extra_force() {
        let m = model(0.02);
        let mut bank = PlayBank::new();
        let t = m.force_terms(Newtons::from_num(80));
        let x = m.forward(&mut bank, Volts::from_num(8), t).to_num::<f64>();
        // In the dead zone (k_f F = 8 V): only the 20 N extra load compresses it.
        assert!((x + 0.4).abs() < 1e-4, "{x}");
    }

    #[test]
    fn inverse_then_forward_returns_the_target() {
        let m = model(0.02);
        let (mut fb, mut ib) = (PlayBank::new(), PlayBank::new());
        for (x, f) in [
            (2.0, 70.0),
            (6.5, 90.0),
            (3.2, 75.0),
            (5.0, 84.0),
            (0.5, 62.0),
        ] {
            let t = m.force_terms(Newtons::from_num(f));
            let u = m.inverse(&mut ib, Micrometres::from_num(x), t);
            let back = m.forward(&mut fb, u, t).to_num::<f64>();
            assert!((back - x).abs() < 1e-4, "x={x}: {back}");
        }
    }
}
