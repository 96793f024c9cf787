//! A virtual flexure-hinge piezo stage: what the emulated board drives instead of hardware.
//!
//! QEMU models no DAC and no analog world, so the `qemu` build of the firmware
//! closes its loop through this model, stepped in thread mode between control
//! interrupts (outside the ISR's budget). It is the best description of stage A
//! the recorded data support, plus what the firmware's model leaves out:
//!
//! * the stack: the extended FPI structure identified on `pea-rig/` (preload
//!   offset with curvature, soft dead zone, output saturation, four creep lags,
//!   compliance) evaluated in floating point with the analytic functions, not
//!   tables;
//! * an amplifier lag (first order, 0.09 ms: the small-signal lag seen in the
//!   chirp recordings' current) that the firmware does not compensate;
//! * a built prototype whose hinge preload is 3 % below the FEM's (the recorded
//!   stage rests at 60 N where the FEM says 61.8 N);
//! * a noisy force sensor (0.15 N).
//!
//! Plain `f32` with `micromath`'s `exp`/`ln` and [`crate::stats::sqrt`] called
//! explicitly, so the host and the Cortex-M4F run the same instructions and get
//! bit-identical trajectories: the host test suite predicts the emulator's
//! figures exactly.
//!
//! Each step solves the coupled equation of seed 000, Table 1, step 4a,
//! `x = h(Y[g(v - U_p(F(x)))]) - c·(F(x) - F(0))` with `F = force_scale·f_F`, by
//! bisection (the right-hand side is non-increasing in `x`), committing the
//! operator and creep states only for the solution, then `x_fhps = f_K(x)`.

use micromath::F32Ext;

/// Most creep lags a virtual stage may have.
pub const MAX_CREEP: usize = 8;

/// Parameters of a virtual stage (configuration). Units in the names.
#[derive(Debug, Clone, Copy)]
pub struct StageParams<'a> {
    /// Linear PI weight, µm/V.
    pub w0_um_per_v: f32,
    /// Play-operator thresholds, V (sorted).
    pub thresholds_v: &'a [f32],
    /// Play-operator weights, µm/V (same length).
    pub weights_um_per_v: &'a [f32],
    /// Preload offset `U_p(F) = offset + k_f·F + k_q·(F - F_q)²`: the constant, V.
    pub offset_v: f32,
    /// … its slope, V/N.
    pub k_f_v_per_n: f32,
    /// … its curvature, V/N².
    pub k_q_v_per_n2: f32,
    /// … and the curvature's centre, N.
    pub force_q_n: f32,
    /// Softness of the dead zone `g(e) = s·ln(1 + exp(e/s))`, V (0: hard, `max(e, 0)`).
    pub softness_v: f32,
    /// Output saturation `z + β·z² = Y`, 1/µm (0: none).
    pub saturation_per_um: f32,
    /// Creep time constants, s.
    pub creep_tau_s: &'a [f32],
    /// Creep gains, µm/V (same length).
    pub creep_gain_um_per_v: &'a [f32],
    /// Stack compliance, µm/N.
    pub compliance_um_per_n: f32,
    /// Amplifier lag, s (0: none).
    pub amplifier_tau_s: f32,
    /// Step rate, Hz.
    pub sample_rate_hz: f32,
    /// Knot spacing of the FEM maps in stack extension, µm (first knot at 0).
    pub fem_step_um: f32,
    /// FEM preload at the knots, N.
    pub fem_force_n: &'a [f32],
    /// FEM stage output at the knots, µm.
    pub fem_output_um: &'a [f32],
    /// Built prototype's preload relative to the FEM's (e.g. 0.971).
    pub force_scale: f32,
    /// Standard deviation of the force sensor's noise, N.
    pub force_noise_n: f32,
}

/// State of a virtual stage with `M` play operators.
#[derive(Debug, Clone, Copy)]
pub struct Stage<const M: usize> {
    y: [f32; M],
    creep: [f32; MAX_CREEP],
    creep_rate: [f32; MAX_CREEP],
    amplifier_alpha: f32,
    voltage: f32,
    x_pea: f32,
    rng: u32,
}

/// One step of the virtual stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageSample {
    /// Voltage at the stack (after the amplifier lag), V.
    pub voltage_v: f32,
    /// Stack extension, µm.
    pub x_pea_um: f32,
    /// Preload on the stack, N (noise-free).
    pub force_n: f32,
    /// Stage output, µm (what a capacitive sensor would read, noise-free).
    pub x_fhps_um: f32,
}

/// Linear interpolation on a uniform grid starting at 0, holding the ends.
fn interp(step: f32, ys: &[f32], x: f32) -> f32 {
    let t = x / step;
    if t.is_nan() || t <= 0.0 {
        return ys.first().copied().unwrap_or(0.0);
    }
    let k = t as usize;
    match (ys.get(k), ys.get(k + 1)) {
        (Some(&a), Some(&b)) => a + (b - a) * (t - k as f32),
        _ => ys.last().copied().unwrap_or(0.0),
    }
}

/// `1 - exp(-1/(rate·τ))`: the per-step rate of a first-order lag (1 for τ = 0).
fn lag_rate(tau_s: f32, rate_hz: f32) -> f32 {
    if tau_s <= 0.0 {
        1.0
    } else {
        1.0 - F32Ext::exp(-1.0 / (rate_hz * tau_s))
    }
}

impl<const M: usize> Stage<M> {
    /// A stage at rest (0 V, operators and lags at rest), with a noise seed.
    pub fn new(p: &StageParams<'_>, seed: u32) -> Self {
        let mut creep_rate = [0.0; MAX_CREEP];
        for (r, &tau) in creep_rate.iter_mut().zip(p.creep_tau_s) {
            *r = lag_rate(tau, p.sample_rate_hz);
        }
        Self {
            y: [0.0; M],
            creep: [0.0; MAX_CREEP],
            creep_rate,
            amplifier_alpha: lag_rate(p.amplifier_tau_s, p.sample_rate_hz),
            voltage: 0.0,
            x_pea: 0.0,
            rng: if seed == 0 { 0x9E37_79B9 } else { seed },
        }
    }

    /// The soft (or hard) dead zone.
    fn dead_zone(p: &StageParams<'_>, e: f32) -> f32 {
        let s = p.softness_v;
        if s <= 0.0 {
            return if e > 0.0 { e } else { 0.0 };
        }
        let t = e / s;
        if t > 20.0 {
            e
        } else if t < -20.0 {
            s * F32Ext::exp(t)
        } else {
            s * F32Ext::ln(1.0 + F32Ext::exp(t))
        }
    }

    /// Preload the built prototype puts on the stack at extension `x` (µm), N.
    pub fn preload(p: &StageParams<'_>, x: f32) -> f32 {
        p.force_scale * interp(p.fem_step_um, p.fem_force_n, x)
    }

    /// Stack extension for voltage `v` at extension guess `x`, advancing the
    /// given operator and creep states (the caller decides whether to keep them).
    fn extension(
        &self,
        p: &StageParams<'_>,
        y: &mut [f32; M],
        creep: &mut [f32; MAX_CREEP],
        v: f32,
        x: f32,
    ) -> f32 {
        let f = Self::preload(p, x);
        let d = f - p.force_q_n;
        let offset = p.offset_v + p.k_f_v_per_n * f + p.k_q_v_per_n2 * d * d;
        let uh = Self::dead_zone(p, v - offset);
        let mut out = p.w0_um_per_v * uh;
        for ((yi, &r), &w) in y.iter_mut().zip(p.thresholds_v).zip(p.weights_um_per_v) {
            let held = if *yi < uh { *yi } else { uh };
            let dragged = uh - r;
            *yi = if dragged > held { dragged } else { held };
            out += w * *yi;
        }
        for ((m, &rate), &b) in creep
            .iter_mut()
            .zip(&self.creep_rate)
            .zip(p.creep_gain_um_per_v)
        {
            *m += rate * (uh - *m);
            out += b * *m;
        }
        let beta = p.saturation_per_um;
        let z = if beta > 0.0 && out > 0.0 {
            2.0 * out / (1.0 + crate::stats::sqrt(1.0 + 4.0 * beta * out))
        } else {
            out
        };
        z - p.compliance_um_per_n * (f - Self::preload(p, 0.0))
    }

    /// Advances one sample with amplifier command `u` (V).
    pub fn step(&mut self, p: &StageParams<'_>, u: f32) -> StageSample {
        self.voltage += self.amplifier_alpha * (u - self.voltage);
        let v = self.voltage;
        // g(x) = extension(x) - x is decreasing in x: bisect on a bracket around
        // the last solution.
        let residual = |s: &Self, x: f32| {
            let (mut y, mut c) = (s.y, s.creep);
            s.extension(p, &mut y, &mut c, v, x) - x
        };
        let (mut lo, mut hi) = (self.x_pea - 1.0, self.x_pea + 1.0);
        while residual(self, lo) < 0.0 {
            lo -= 4.0;
        }
        while residual(self, hi) > 0.0 {
            hi += 4.0;
        }
        for _ in 0..26 {
            let mid = 0.5 * (lo + hi);
            if residual(self, mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let x = 0.5 * (lo + hi);
        // Commit the operator and creep states for the solution.
        let (mut y, mut c) = (self.y, self.creep);
        self.extension(p, &mut y, &mut c, v, x);
        self.y = y;
        self.creep = c;
        self.x_pea = x;
        StageSample {
            voltage_v: v,
            x_pea_um: x,
            force_n: Self::preload(p, x),
            x_fhps_um: interp(p.fem_step_um, p.fem_output_um, x),
        }
    }

    /// A force-sensor reading of `force` (N): adds zero-mean noise of the configured
    /// standard deviation (sum of four uniforms, deterministic xorshift generator).
    pub fn sense_force(&mut self, p: &StageParams<'_>, force: f32) -> f32 {
        let mut s = 0.0;
        for _ in 0..4 {
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 17;
            self.rng ^= self.rng << 5;
            s += (self.rng >> 8) as f32 / 16_777_216.0 - 0.5;
        }
        // Four uniforms on [-0.5, 0.5) have variance 1/3.
        force + s * 1.732_050_8 * p.force_noise_n
    }
}

/// The virtual twin of stage A used by the emulated board, at 20 kHz.
///
/// Stack: the extended FPI structure identified on all `pea-rig/` recordings
/// (10 operators, 0–90 V; research fit "M2", see the README); maps:
/// `stage-a/fem.csv` with the prototype's preload 2.9 % below the FEM's;
/// amplifier lag 0.09 ms; 0.15 N force noise.
pub mod stage_a {
    use super::StageParams;

    /// Play operators of the twin.
    pub const OPERATORS: usize = 9;

    const THRESHOLDS: [f32; OPERATORS] = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0];
    const WEIGHTS: [f32; OPERATORS] = [
        0.012_608_085,
        0.007_466_546,
        0.005_975_463,
        0.003_753_661,
        0.002_584_105,
        0.001_225_93,
        0.001_244_621,
        0.000_658_104,
        0.001_145_867,
    ];
    const CREEP_TAU: [f32; 4] = [0.01, 0.03, 0.3, 3.0];
    const CREEP_GAIN: [f32; 4] = [0.002_854_712, 0.000_501_681, 0.001_204_947, 0.000_263_809];
    const FEM_FORCE: [f32; 49] = [
        61.8, 62.8332, 63.8729, 64.919, 65.9715, 67.0305, 68.0959, 69.1677, 70.246, 71.3307,
        72.4219, 73.5195, 74.6235, 75.734, 76.8509, 77.9742, 79.104, 80.2402, 81.3829, 82.532,
        83.6875, 84.8495, 86.0179, 87.1927, 88.374, 89.5617, 90.7559, 91.9565, 93.1635, 94.377,
        95.5969, 96.8232, 98.056, 99.2952, 100.5409, 101.793, 103.0515, 104.3165, 105.5879,
        106.8657, 108.15, 109.4407, 110.7379, 112.0415, 113.3515, 114.668, 115.9909, 117.3202,
        118.656,
    ];
    const FEM_OUTPUT: [f32; 49] = [
        0.0, 1.4331, 2.8616, 4.2853, 5.7044, 7.1187, 8.5284, 9.9334, 11.3336, 12.7291, 14.12,
        15.5061, 16.8876, 18.2644, 19.6364, 21.0038, 22.3664, 23.7243, 25.0776, 26.4261, 27.77,
        29.1091, 30.4436, 31.7734, 33.0984, 34.4188, 35.7344, 37.0453, 38.3516, 39.6531, 40.95,
        42.2422, 43.5296, 44.8123, 46.0904, 47.3638, 48.6324, 49.8964, 51.1556, 52.4101, 53.66,
        54.9051, 56.1456, 57.3813, 58.6124, 59.8387, 61.0604, 62.2773, 63.4896,
    ];

    /// The twin's parameters at a 20 kHz step.
    pub const PARAMS: StageParams<'static> = StageParams {
        w0_um_per_v: 0.062_582_01,
        thresholds_v: &THRESHOLDS,
        weights_um_per_v: &WEIGHTS,
        offset_v: -0.442_02,
        k_f_v_per_n: 0.106,
        k_q_v_per_n2: 0.000_165_53,
        force_q_n: 75.0,
        softness_v: 1.8355,
        saturation_per_um: 0.003_725_144,
        creep_tau_s: &CREEP_TAU,
        creep_gain_um_per_v: &CREEP_GAIN,
        compliance_um_per_n: 0.02,
        amplifier_tau_s: 0.000_09,
        sample_rate_hz: 20_000.0,
        fem_step_um: 0.25,
        fem_force_n: &FEM_FORCE,
        fem_output_um: &FEM_OUTPUT,
        force_scale: 60.0 / 61.8,
        force_noise_n: 0.15,
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage() -> Stage<{ stage_a::OPERATORS }> {
        Stage::new(&stage_a::PARAMS, 1)
    }

    #[test]
    fn rest_state_and_dead_zone() {
        let p = stage_a::PARAMS;
        let mut s = stage();
        let r = s.step(&p, 0.0);
        // The soft dead zone leaves 0.06 V of drive at 0 V: 4 nm of stack.
        assert!(r.x_pea_um.abs() < 0.01, "{}", r.x_pea_um);
        assert!((r.force_n - 60.0).abs() < 0.05, "{}", r.force_n);
        // U_p(60 N) ≈ 5.9 V: 2 V barely moves the stack (the soft dead zone's foot),
        // 12 V does.
        for _ in 0..200 {
            s.step(&p, 2.0);
        }
        assert!(s.step(&p, 2.0).x_pea_um < 0.03);
        for _ in 0..200 {
            s.step(&p, 12.0);
        }
        assert!(s.step(&p, 12.0).x_pea_um > 0.3);
    }

    #[test]
    fn full_stroke_matches_the_recorded_stage() {
        // The recorded stage reaches about 40.4 um at 100 V.
        let p = stage_a::PARAMS;
        let mut s = stage();
        let mut top = 0.0;
        for k in 0..=2000 {
            top = s.step(&p, 100.0 * k as f32 / 2000.0).x_fhps_um;
        }
        assert!((top - 40.4).abs() < 1.0, "{top}");
    }

    #[test]
    fn sensor_noise_has_the_configured_spread() {
        let p = stage_a::PARAMS;
        let mut s = stage();
        let n = 20_000;
        let (mut m1, mut m2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let e = (s.sense_force(&p, 60.0) - 60.0) as f64;
            m1 += e;
            m2 += e * e;
        }
        let sd = (m2 / n as f64 - (m1 / n as f64).powi(2)).sqrt();
        assert!((sd - 0.15).abs() < 0.01, "{sd}");
    }
}
