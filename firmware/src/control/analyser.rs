//! The board's frequency-response analyser: a sine added to the command, and the
//! signals correlated with it in the control ISR (a lock-in amplifier), so that
//! a frequency response is measured on the board itself, at any link speed.
//!
//! For one frequency `f` the ISR adds `e = A·sin φ` to the command (µm, after the
//! loop's laws, so it meets whatever loops run: open, damped, closed), `φ`
//! advancing `2³²·f/f_s` per tick. After `settle` periods it sums, over
//! `cycles` periods, each signal `s` times `sin φ` and `cos φ`:
//!
//! ```text
//! S_s = Σ ((s − s₀)·sin φ) >> 16,  C_s = Σ ((s − s₀)·cos φ) >> 16     s in I16F16 bits, sin/cos in I2F30
//! ```
//!
//! with `s₀` the signal at the correlation's first tick: the signals' large
//! steady values (20 µm of position, 70 N of preload) would otherwise leak into
//! the sums through the window's fraction of a period (a 0.1 µm excitation
//! under a 20 µm position: a leak of the excitation's own size at 300 Hz).
//!
//! for the position sensor (µm), the force reading (N), the force channel's
//! dynamic part (N), the setpoint (V) and the excitation itself. The host divides
//! the signals' phasors `S + jC` by the excitation's: the responses from the
//! command to each signal, and from the setpoint to the sensors.
//!
//! Each difference is clamped to ±2²⁷ (±2048 µm, N or V: beyond any stage), each
//! product is then at most 2²⁷·2³⁰ = 2⁵⁷, 2⁴¹ after the shift; at most 2²¹ ticks
//! are summed (`MAX_TICKS`), so no sum leaves 2⁶². The excitation starts at
//! `φ = 0` (a zero) and stops after whole periods, near zero again: it does not
//! kick the stage. Constant time per tick, no division, no panic.

use piezo_fpi::q::Micrometres;

use crate::control::cosine::cos_turns;

/// Signals correlated, in order: position sensor, force, dynamic force,
/// setpoint, excitation.
pub const SIGNALS: usize = 5;
/// Largest difference from the first correlated value, `I16F16` bits (2048).
const DIFF_MAX: i64 = 1 << 27;
/// Most ticks an analysis may correlate (105 s at 20 kHz).
pub const MAX_TICKS: u32 = 1 << 21;

/// One analysis, as the link task orders it (checked there).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnalyseOrder {
    /// The frequency, mHz (reported back).
    pub freq_mhz: u32,
    /// Phase advance per tick, 2⁻³² turns.
    pub phase_step: u32,
    /// Excitation amplitude, µm.
    pub amplitude: Micrometres,
    /// Ticks before the correlation.
    pub settle_ticks: u32,
    /// Ticks correlated (≤ [`MAX_TICKS`]).
    pub measure_ticks: u32,
}

/// What an analysis found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnalysisSums {
    /// The frequency, mHz.
    pub freq_mhz: u32,
    /// Ticks correlated.
    pub ticks: u32,
    /// `[Σ s·sin, Σ s·cos]` per signal (see the module docs).
    pub sums: [[i64; 2]; SIGNALS],
    /// A fault latched while it ran.
    pub faulted: bool,
    /// Correlated ticks in which the reference governor departed from the
    /// stimulus asked (the stage could not take it there): the response is
    /// then the one to a stimulus that was not the sine.
    pub governed: u32,
}

/// The analyser (state): idle, or running one order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Analyser {
    order: Option<AnalyseOrder>,
    phase: u32,
    tick: u32,
    sums: [[i64; 2]; SIGNALS],
    base: [i32; SIGNALS],
    faulted: bool,
    governed: u32,
}

impl Analyser {
    /// Idle.
    pub const fn new() -> Self {
        Self {
            order: None,
            phase: 0,
            tick: 0,
            sums: [[0; 2]; SIGNALS],
            base: [0; SIGNALS],
            faulted: false,
            governed: 0,
        }
    }

    /// Starts `o` from phase 0.
    pub fn start(&mut self, o: AnalyseOrder) {
        *self = Self {
            order: Some(o),
            ..Self::new()
        };
    }

    /// Whether an analysis runs.
    pub const fn running(&self) -> bool {
        self.order.is_some()
    }

    /// Stops a running analysis (a fault, a new source).
    pub fn abort(&mut self) {
        self.order = None;
    }

    /// This tick's excitation, µm (0 when idle).
    #[inline]
    pub fn excitation(&self) -> Micrometres {
        match &self.order {
            Some(o) => {
                let s = sin_turns(self.phase) as i64;
                Micrometres::from_bits(
                    ((o.amplitude.to_bits() as i64 * s + (1 << 29)) >> 30) as i32,
                )
            }
            None => Micrometres::ZERO,
        }
    }

    /// Takes this tick's signals (`I16F16` bits, in [`SIGNALS`] order),
    /// whether a fault is latched and whether the governor departed from the
    /// stimulus; advances the phase; the result once the last period has been
    /// correlated (the analyser is then idle).
    #[inline]
    pub fn take(
        &mut self,
        signals: [i32; SIGNALS],
        fault: bool,
        governed: bool,
    ) -> Option<AnalysisSums> {
        let o = self.order?;
        self.faulted |= fault;
        if self.tick == o.settle_ticks {
            self.base = signals;
        }
        if self.tick >= o.settle_ticks {
            self.governed += governed as u32;
            let (s, c) = (sin_turns(self.phase) as i64, cos_turns(self.phase) as i64);
            for ((acc, v), b) in self.sums.iter_mut().zip(signals).zip(self.base) {
                let v = (v as i64 - b as i64).clamp(-DIFF_MAX, DIFF_MAX);
                acc[0] += (v * s) >> 16;
                acc[1] += (v * c) >> 16;
            }
        }
        self.phase = self.phase.wrapping_add(o.phase_step);
        self.tick += 1;
        if self.tick < o.settle_ticks.saturating_add(o.measure_ticks) && !fault {
            return None;
        }
        self.order = None;
        Some(AnalysisSums {
            freq_mhz: o.freq_mhz,
            ticks: self.tick.saturating_sub(o.settle_ticks),
            sums: self.sums,
            faulted: self.faulted,
            governed: self.governed,
        })
    }
}

/// `sin 2πφ` for a phase in 2⁻³² turns, `I2F30` raw.
#[inline]
fn sin_turns(phase: u32) -> i32 {
    cos_turns(phase.wrapping_sub(1 << 30))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::reference::wave::Wave;

    /// A signal `a·sin(φ − θ)` (lagging by `θ`) correlates to the phasor
    /// `a·e^{−jθ}` times the excitation's: the response's gain `a/A`, phase `−θ`.
    #[test]
    fn the_lock_in_recovers_amplitude_and_phase() {
        let mut an = Analyser::new();
        let step = Wave::phase_step_for(500_000, 20_000);
        an.start(AnalyseOrder {
            freq_mhz: 500_000,
            phase_step: step,
            amplitude: Micrometres::from_num(0.5),
            settle_ticks: 80,
            measure_ticks: 400,
        });
        let theta = 0.7f64;
        let mut k = 0u32;
        let result = loop {
            let e = an.excitation().to_num::<f64>();
            let phi = (k as f64) * step as f64 / 4_294_967_296.0 * core::f64::consts::TAU;
            let x = 2.0 * (phi - theta).sin();
            let bits = |v: f64| Micrometres::from_num(v).to_bits();
            if let Some(r) = an.take([bits(x), 0, 0, 0, bits(e)], false, false) {
                break r;
            }
            k += 1;
        };
        assert_eq!(result.ticks, 400);
        assert!(!result.faulted && !an.running());
        let ph = |s: [i64; 2]| (s[0] as f64, s[1] as f64);
        let (xs, xc) = ph(result.sums[0]);
        let (es, ec) = ph(result.sums[4]);
        // Phasors S + jC; the response is their ratio.
        let (num_re, num_im) = (xs, xc);
        let (den_re, den_im) = (es, ec);
        let d = den_re * den_re + den_im * den_im;
        let re = (num_re * den_re + num_im * den_im) / d;
        let im = (num_im * den_re - num_re * den_im) / d;
        let gain = re.hypot(im);
        let phase = im.atan2(re);
        assert!((gain - 4.0).abs() < 0.01, "{gain}");
        assert!((phase + theta).abs() < 0.01, "{phase}");
    }

    #[test]
    fn a_fault_ends_the_analysis_marked_void() {
        let mut an = Analyser::new();
        an.start(AnalyseOrder {
            freq_mhz: 100_000,
            phase_step: Wave::phase_step_for(100_000, 20_000),
            amplitude: Micrometres::from_num(0.5),
            settle_ticks: 10,
            measure_ticks: 1000,
        });
        assert_eq!(an.take([0; SIGNALS], false, false), None);
        let r = an.take([0; SIGNALS], true, false).unwrap();
        assert!(r.faulted && !an.running());
        assert_eq!(an.excitation(), Micrometres::ZERO);
    }
}
