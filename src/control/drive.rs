//! How the voltage is chosen: the inverse FPI or the straight-line drive.

use crate::q::{
    narrow_inv_gain, InvGainAcc, Micrometres, Volts, VoltsPerUm, INV_GAIN_FRAC, SIGNAL_ABS_MAX_BITS,
};

/// Which law computes the voltage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Inverse FPI compensation ([`ControllerConfig::step`](super::ControllerConfig::step)).
    Compensated,
    /// The straight-line baseline ([`ControllerConfig::step_uncompensated`](super::ControllerConfig::step_uncompensated)).
    Uncompensated(LinearDrive),
}

/// The uncompensated baseline: a straight line from the reference to the voltage,
/// `u = offset + gain·x_ref`, as an amplifier driven without a hysteresis model would be.
///
/// * `gain` — V/µm, `I10F22`; `offset` — V, `I16F16`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinearDrive {
    /// Slope, V/µm.
    pub gain: VoltsPerUm,
    /// Voltage at zero reference, V.
    pub offset: Volts,
}

impl LinearDrive {
    /// The line through `(x_lo, u_lo)` and `(x_hi, u_hi)`; for host tools and start-up code.
    pub fn through(x_lo: f64, u_lo: f64, x_hi: f64, u_hi: f64) -> Option<Self> {
        let g = (u_hi - u_lo) / (x_hi - x_lo);
        let gain = crate::q::quantize(g, crate::q::INV_GAIN_FRAC, crate::q::INV_GAIN_ABS_MAX)?;
        Some(Self {
            gain: VoltsPerUm::from_bits(gain),
            offset: Volts::from_raw(crate::q::signal(u_lo - g * x_lo)?),
        })
    }

    /// The voltage for a reference (before the limits), V.
    #[inline]
    pub fn voltage(&self, x_ref: Micrometres) -> Volts {
        // Saturate the product at the signal range before narrowing it.
        let lim = (SIGNAL_ABS_MAX_BITS as i64) << INV_GAIN_FRAC;
        let acc = self.gain.wide_mul(x_ref.raw()).to_bits().max(-lim).min(lim);
        narrow_inv_gain(InvGainAcc::from_bits(acc)).saturating_add(self.offset)
    }

    /// The reference whose voltage is `voltage`, `(u − offset) / gain`, µm,
    /// saturated to the signal range; `None` for a zero gain. One division: for a
    /// switch of control law (bumpless transfer), not for every tick.
    pub fn reference_for(&self, voltage: Volts) -> Option<Micrometres> {
        let num = ((voltage.to_bits() as i64) - (self.offset.to_bits() as i64)) << INV_GAIN_FRAC;
        let x = num.checked_div(self.gain.to_bits() as i64)?;
        let lim = SIGNAL_ABS_MAX_BITS as i64;
        Some(Micrometres::from_bits(x.max(-lim).min(lim) as i32))
    }
}
