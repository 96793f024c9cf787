//! The waveform generator: sine, triangle and raised cosine from a 32-bit phase
//! accumulator, a given number of cycles or continuously.
//!
//! `x(k) = offset + amplitude·s(φ(k))`, `φ(k) = k·phase_step` in 2⁻³² turns
//! (`phase_step = f / f_s · 2³²`), with `s` one of:
//!
//! | shape | `s(φ)` | starts at | first motion |
//! |---|---|---|---|
//! | sine | `sin 2πφ` | `offset` | upward, at full speed |
//! | triangle | 1 − 4·\|φ − ¼\| folded | `offset` | upward, constant speed |
//! | raised cosine | `−cos 2πφ` | `offset − amplitude` | upward, from rest |
//!
//! `s` comes from a 256-interval cosine table generated at build time, linearly
//! interpolated (worst error 7.5·10⁻⁵ of the amplitude), so host and board produce
//! bit-identical trajectories. A finite wave ends after its last full cycle, where
//! it is back at its start value: the reference then holds there, without a jump.

use piezo_fpi::q::Micrometres;

use crate::control::cosine::cos_turns;

pub use fpi_protocol::Shape;

/// `s(φ)` of `shape` for a phase in 2⁻³² turns, `I2F30` raw in `[−1, 1]`.
#[inline]
pub fn shape_at(shape: Shape, phase: u32) -> i32 {
    match shape {
        Shape::Sine => cos_turns(phase.wrapping_sub(1 << 30)),
        Shape::Triangle => {
            // Shifted by a quarter turn: p = 2³¹ is the top, p = 0 the bottom.
            let p = phase.wrapping_add(1 << 30) as i64;
            ((1i64 << 30) - (p - (1i64 << 31)).abs()) as i32
        }
        Shape::RaisedCosine => -cos_turns(phase),
    }
}

/// A periodic reference (configuration).
///
/// * `offset`, `amplitude` — µm, `I16F16`; the wave spans `offset ± amplitude`.
/// * `phase_step` — turns per tick in 2⁻³² ([`Wave::phase_step_for`]).
/// * `cycles` — full periods to run; 0 runs until another source is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wave {
    /// Shape.
    pub shape: Shape,
    /// Mid-point of the motion, µm.
    pub offset: Micrometres,
    /// Half-swing, µm (not negative).
    pub amplitude: Micrometres,
    /// Phase advance per tick, 2⁻³² turns.
    pub phase_step: u32,
    /// Periods to run; 0: continuous.
    pub cycles: u32,
}

/// Where a [`Wave`] is (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WavePhase {
    phase: u32,
    cycles_done: u32,
    finished: bool,
}

impl WavePhase {
    /// The wave has run all its cycles.
    pub const fn finished(&self) -> bool {
        self.finished
    }
}

impl Wave {
    /// `phase_step` for a frequency in mHz at a control rate in Hz, rounded to
    /// nearest; integer arithmetic, so host and board agree exactly.
    pub const fn phase_step_for(freq_mhz: u32, rate_hz: u32) -> u32 {
        let den = rate_hz as u64 * 1000;
        if den == 0 {
            return 0;
        }
        let step = (((freq_mhz as u64) << 32) + den / 2) / den;
        if step > u32::MAX as u64 {
            u32::MAX
        } else {
            step as u32
        }
    }

    /// The value at a phase, µm.
    #[inline]
    pub fn value_at(&self, phase: u32) -> Micrometres {
        let s = shape_at(self.shape, phase) as i64;
        let swing = ((self.amplitude.to_bits() as i64 * s + (1 << 29)) >> 30) as i32;
        Micrometres::from_bits(self.offset.to_bits().wrapping_add(swing))
    }

    /// The first value (phase 0), where a transition must lead the reference.
    pub fn start_value(&self) -> Micrometres {
        self.value_at(0)
    }

    /// The next reference, µm; after the last cycle, the start value.
    #[inline]
    pub fn next(&self, w: &mut WavePhase) -> Micrometres {
        if w.finished {
            return self.value_at(0);
        }
        let x = self.value_at(w.phase);
        let (phase, wrapped) = w.phase.overflowing_add(self.phase_step);
        w.phase = phase;
        if wrapped {
            w.cycles_done = w.cycles_done.wrapping_add(1);
            if self.cycles != 0 && w.cycles_done >= self.cycles {
                w.finished = true;
            }
        }
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wave(shape: Shape, cycles: u32) -> Wave {
        Wave {
            shape,
            offset: Micrometres::from_num(20),
            amplitude: Micrometres::from_num(15),
            phase_step: Wave::phase_step_for(15_000, 20_000),
            cycles,
        }
    }

    #[test]
    fn phase_step_is_rounded_integer_arithmetic() {
        assert_eq!(
            Wave::phase_step_for(5_000, 20_000),
            1_073_742 /* 2³²/4000 rounded */
        );
        let exact = 15.0 / 20_000.0 * 4_294_967_296.0;
        let got = Wave::phase_step_for(15_000, 20_000) as f64;
        assert!((got - exact).abs() <= 0.5);
        assert_eq!(Wave::phase_step_for(1, 0), 0);
    }

    #[test]
    fn each_shape_matches_its_formula_and_starts_where_documented() {
        use core::f64::consts::TAU;
        for (shape, f) in [
            (Shape::Sine, (|p: f64| (TAU * p).sin()) as fn(f64) -> f64),
            (Shape::Triangle, |p: f64| {
                let q = (p + 0.25).rem_euclid(1.0);
                1.0 - 4.0 * (q - 0.5).abs()
            }),
            (Shape::RaisedCosine, |p: f64| -(TAU * p).cos()),
        ] {
            let w = wave(shape, 0);
            for k in 0..1000u32 {
                let phase = k.wrapping_mul(4_294_967);
                let want = 20.0 + 15.0 * f(phase as f64 / 4_294_967_296.0);
                let got = w.value_at(phase).to_num::<f64>();
                assert!(
                    (got - want).abs() < 2e-3,
                    "{shape:?} at {phase}: {got} vs {want}"
                );
            }
        }
        assert_eq!(
            wave(Shape::Sine, 0).start_value(),
            Micrometres::from_num(20)
        );
        assert_eq!(
            wave(Shape::Triangle, 0).start_value(),
            Micrometres::from_num(20)
        );
        assert_eq!(
            wave(Shape::RaisedCosine, 0).start_value(),
            Micrometres::from_num(5)
        );
    }

    #[test]
    fn a_finite_wave_runs_its_cycles_then_holds_its_start_value() {
        for shape in [Shape::Sine, Shape::Triangle, Shape::RaisedCosine] {
            let w = wave(shape, 3);
            let mut p = WavePhase::default();
            let period: f64 = 20_000.0 / 15.0;
            // The third wrap of the phase ends the wave.
            let ticks = ((3u64 << 32).div_ceil(w.phase_step as u64)) as usize;
            let mut last = w.next(&mut p);
            for _ in 1..ticks {
                assert!(!p.finished());
                let x = w.next(&mut p);
                let speed = (x - last).abs().to_num::<f64>();
                // Fastest slope: the sine's, 2π·15 µm per period.
                let top = core::f64::consts::TAU * 15.0 / period;
                assert!(speed < top * 1.01 + 1e-4, "{shape:?}: jump {speed}");
                last = x;
            }
            assert!(p.finished(), "{shape:?}");
            let end = w.next(&mut p);
            assert_eq!(end, w.start_value());
            assert!(
                (end - last).abs() < Micrometres::from_num(0.2),
                "{shape:?}: no jump at the end"
            );
        }
        let mut p = WavePhase::default();
        let w = wave(Shape::Sine, 0);
        for _ in 0..100_000 {
            w.next(&mut p);
        }
        assert!(!p.finished(), "continuous");
    }
}
