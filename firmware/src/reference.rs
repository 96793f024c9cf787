//! An on-board reference generator: raised cosines with an optional amplitude ramp.
//!
//! `x(k) = center - amplitude(k)·cos(2π·phase(k))`, with a 32-bit phase accumulator
//! (`phase_step = f / f_s · 2^32`) and a 256-interval cosine table generated at
//! build time, so host and board produce bit-identical trajectories. Used for the
//! board's self-test and the emulated demo; a real application streams its own
//! references into the control step instead.

use piezo_fpi::q::Micrometres;

include!(concat!(env!("OUT_DIR"), "/cosine.rs"));

/// cos(2π·phase) for a phase in 2⁻³² turns, `I2F30` raw, linearly interpolated
/// (worst error 7.5·10⁻⁵ of the amplitude).
#[inline]
pub fn cos_turns(phase: u32) -> i32 {
    let k = (phase >> 24) as usize;
    let frac = ((phase >> 8) & 0xFFFF) as i64;
    match (COSINE.get(k), COSINE.get(k + 1)) {
        (Some(&a), Some(&b)) => a + (((b - a) as i64 * frac + (1 << 15)) >> 16) as i32,
        _ => COSINE[0],
    }
}

/// A raised-cosine trajectory (configuration).
///
/// * `center`, `amplitude` — µm, `I16F16`.
/// * `phase_step` — turns per step in 2⁻³² (frequency / sample rate · 2³²).
/// * `amplitude_step` — change of the amplitude per step, µm (`I16F16`; negative
///   for nested minor loops); the amplitude stops at zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RaisedCosine {
    /// Mid-point of the motion, µm.
    pub center: Micrometres,
    /// Initial half-swing, µm.
    pub amplitude: Micrometres,
    /// Phase advance per step, 2⁻³² turns.
    pub phase_step: u32,
    /// Amplitude change per step, µm.
    pub amplitude_step: Micrometres,
}

/// Where a [`RaisedCosine`] is (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Waveform {
    phase: u32,
    amplitude: Micrometres,
}

impl RaisedCosine {
    /// `phase_step` for a frequency (Hz) at a sample rate (Hz); for start-up code.
    pub fn phase_step_for(frequency_hz: f32, sample_rate_hz: f32) -> u32 {
        (frequency_hz / sample_rate_hz * 4_294_967_296.0) as u32
    }

    /// The state at phase 0 (the bottom of the swing).
    pub const fn start(&self) -> Waveform {
        Waveform {
            phase: 0,
            amplitude: self.amplitude,
        }
    }

    /// The next reference, µm.
    #[inline]
    pub fn next(&self, w: &mut Waveform) -> Micrometres {
        let c = cos_turns(w.phase) as i64;
        let swing = ((w.amplitude.to_bits() as i64 * c + (1 << 29)) >> 30) as i32;
        w.phase = w.phase.wrapping_add(self.phase_step);
        let a = w.amplitude.saturating_add(self.amplitude_step);
        w.amplitude = if a < Micrometres::ZERO {
            Micrometres::ZERO
        } else {
            a
        };
        self.center - Micrometres::from_bits(swing)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_table_is_accurate() {
        for k in 0..4096u32 {
            let phase = k.wrapping_mul(1_048_573 * 997);
            let want = (phase as f64 / 4_294_967_296.0 * core::f64::consts::TAU).cos();
            let got = cos_turns(phase) as f64 / (1u64 << 30) as f64;
            assert!((got - want).abs() < 8e-5, "phase {phase}: {got} vs {want}");
        }
    }

    #[test]
    fn raised_cosine_sweeps_between_its_ends() {
        let r = RaisedCosine {
            center: Micrometres::from_num(20),
            amplitude: Micrometres::from_num(18),
            phase_step: RaisedCosine::phase_step_for(5.0, 20_000.0),
            amplitude_step: Micrometres::ZERO,
        };
        let mut w = r.start();
        let xs: [f64; 4000] = core::array::from_fn(|_| r.next(&mut w).to_num::<f64>());
        let lo = xs.iter().cloned().fold(f64::MAX, f64::min);
        let hi = xs.iter().cloned().fold(f64::MIN, f64::max);
        assert!(
            (lo - 2.0).abs() < 1e-3 && (hi - 38.0).abs() < 1e-3,
            "{lo} {hi}"
        );
        assert!((xs[0] - 2.0).abs() < 1e-4);
    }

    #[test]
    fn amplitude_ramp_stops_at_zero() {
        let r = RaisedCosine {
            center: Micrometres::from_num(10),
            amplitude: Micrometres::from_num(1),
            phase_step: 1 << 28,
            amplitude_step: Micrometres::from_num(-0.25),
        };
        let mut w = r.start();
        for _ in 0..10 {
            r.next(&mut w);
        }
        assert_eq!(r.next(&mut w), Micrometres::from_num(10));
    }
}
