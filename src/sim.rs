//! A virtual flexure-hinge piezo stage: what the emulated board drives instead of hardware.
//!
//! QEMU models no DAC and no analog world, so the `qemu` build of the firmware
//! closes its loop through this model, stepped in thread mode between control
//! interrupts (outside the ISR's budget). It is deliberately *not* the
//! controller's model: a denser PI bank (24 operators), a first-order amplifier
//! lag, a mild output saturation, a prototype whose hinge preload differs from
//! the FEM by a few percent, and a noisy, quantised force sensor.
//!
//! Plain `f32` arithmetic without transcendental functions, so the host and the
//! Cortex-M4F compute bit-identical trajectories (IEEE single precision, no fused
//! operations): the host test suite predicts the emulator's figures exactly.
//!
//! Each step solves the coupled equation of seed 000, Table 1, step 4a,
//! `x = h(Y[v - k_f·F(x)]) - c·(F(x) - F(0))` with `F = force_scale·f_F`, by
//! bisection (the right-hand side is non-increasing in `x`), committing the
//! operator state only for the solution, then `x_fhps = f_K(x)`.

/// Parameters of a virtual stage (configuration). Units in the names.
#[derive(Debug, Clone, Copy)]
pub struct StageParams<'a> {
    /// Linear PI weight, µm/V.
    pub w0_um_per_v: f32,
    /// Play-operator thresholds, V (sorted).
    pub thresholds_v: &'a [f32],
    /// Play-operator weights, µm/V (same length).
    pub weights_um_per_v: &'a [f32],
    /// Force–voltage coupling, V/N.
    pub k_f_v_per_n: f32,
    /// Stack compliance, µm/N.
    pub compliance_um_per_n: f32,
    /// Output saturation `h(y) = y / (1 + y / s)`, µm (`f32::INFINITY` for none).
    pub saturation_um: f32,
    /// Amplifier lag per step: `v += alpha·(u - v)` (1 for none).
    pub amplifier_alpha: f32,
    /// Knot spacing of the FEM maps in stack extension, µm (first knot at 0).
    pub fem_step_um: f32,
    /// FEM preload at the knots, N.
    pub fem_force_n: &'a [f32],
    /// FEM stage output at the knots, µm.
    pub fem_output_um: &'a [f32],
    /// Built prototype's preload relative to the FEM's (e.g. 0.97).
    pub force_scale: f32,
    /// Standard deviation of the force sensor's noise, N.
    pub force_noise_n: f32,
}

/// State of a virtual stage with `M` play operators.
#[derive(Debug, Clone, Copy)]
pub struct Stage<const M: usize> {
    y: [f32; M],
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

impl<const M: usize> Stage<M> {
    /// A stage at rest (0 V, operators at rest), with a noise seed.
    pub const fn new(seed: u32) -> Self {
        Self {
            y: [0.0; M],
            voltage: 0.0,
            x_pea: 0.0,
            rng: if seed == 0 { 0x9E37_79B9 } else { seed },
        }
    }

    fn pi(p: &StageParams<'_>, y: &mut [f32; M], u: f32) -> f32 {
        let mut x = p.w0_um_per_v * u;
        for ((yi, &r), &w) in y.iter_mut().zip(p.thresholds_v).zip(p.weights_um_per_v) {
            let held = if *yi < u { *yi } else { u };
            let dragged = u - r;
            *yi = if dragged > held { dragged } else { held };
            x += w * *yi;
        }
        x
    }

    /// Preload the built prototype puts on the stack at extension `x` (µm), N.
    pub fn preload(p: &StageParams<'_>, x: f32) -> f32 {
        p.force_scale * interp(p.fem_step_um, p.fem_force_n, x)
    }

    /// Advances one sample with amplifier command `u` (V).
    pub fn step(&mut self, p: &StageParams<'_>, u: f32) -> StageSample {
        self.voltage += p.amplifier_alpha * (u - self.voltage);
        let v = self.voltage;
        let f0 = Self::preload(p, 0.0);
        let sat = |y: f32| y / (1.0 + y / p.saturation_um);
        // g(x) = h(Y[v - k_f F(x)]) - c (F(x) - F0) - x is decreasing in x.
        let residual = |x: f32, y: &mut [f32; M]| {
            let f = Self::preload(p, x);
            let uh = v - p.k_f_v_per_n * f;
            let uh = if uh > 0.0 { uh } else { 0.0 };
            sat(Self::pi(p, y, uh)) - p.compliance_um_per_n * (f - f0) - x
        };
        let (mut lo, mut hi) = (self.x_pea - 1.0, self.x_pea + 1.0);
        while residual(lo, &mut self.y.clone()) < 0.0 {
            lo -= 4.0;
        }
        while residual(hi, &mut self.y.clone()) > 0.0 {
            hi += 4.0;
        }
        for _ in 0..26 {
            let mid = 0.5 * (lo + hi);
            if residual(mid, &mut self.y.clone()) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let x = 0.5 * (lo + hi);
        residual(x, &mut self.y); // commit the operator state for the solution
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

/// The virtual twin of stage A used by the emulated board.
///
/// Hysteresis: 24 one-sided play operators fitted (NNLS, `k_f` = 0.1 V/N,
/// c = 0.02 µm/N) on all `pea-rig/` recordings; maps: `stage-a/fem.csv` with the
/// prototype's preload 3 % below the FEM's (the recorded stage rests at 60 N where
/// the FEM says 61.8 N); amplifier lag 50 µs at 20 kHz; 0.15 N force noise.
pub mod stage_a {
    use super::StageParams;

    /// Play operators of the twin.
    pub const OPERATORS: usize = 24;

    const THRESHOLDS: [f32; OPERATORS] = [
        4.0, 8.0, 12.0, 16.0, 20.0, 24.0, 28.0, 32.0, 36.0, 40.0, 44.0, 48.0, 52.0, 56.0, 60.0,
        64.0, 68.0, 72.0, 76.0, 80.0, 84.0, 88.0, 92.0, 96.0,
    ];
    const WEIGHTS: [f32; OPERATORS] = [
        0.0,
        0.0,
        0.009_189_9,
        0.000_852_6,
        0.006_438_7,
        0.003_136_4,
        0.001_808,
        0.002_717_7,
        0.0,
        0.001_831_2,
        0.0,
        0.0,
        0.003_601_7,
        0.0,
        0.001_697_8,
        0.0,
        0.0,
        0.0,
        0.000_240_7,
        0.0,
        0.014_131,
        0.0,
        0.0,
        0.0,
    ];
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
        w0_um_per_v: 0.065_865_46,
        thresholds_v: &THRESHOLDS,
        weights_um_per_v: &WEIGHTS,
        k_f_v_per_n: 0.1,
        compliance_um_per_n: 0.02,
        saturation_um: 400.0,
        amplifier_alpha: 0.632_120_56,
        fem_step_um: 0.25,
        fem_force_n: &FEM_FORCE,
        fem_output_um: &FEM_OUTPUT,
        force_scale: 0.971,
        force_noise_n: 0.15,
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rest_state_and_dead_zone() {
        let p = stage_a::PARAMS;
        let mut s = Stage::<{ stage_a::OPERATORS }>::new(1);
        let r = s.step(&p, 0.0);
        assert!(r.x_pea_um.abs() < 1e-6);
        assert!((r.force_n - 60.0).abs() < 0.01, "{}", r.force_n);
        // k_f F = 6 V: 5 V does not move the stack.
        for _ in 0..50 {
            s.step(&p, 5.0);
        }
        assert!(s.step(&p, 5.0).x_pea_um.abs() < 1e-5);
    }

    #[test]
    fn full_stroke_matches_the_recorded_stage() {
        // The recorded stage reaches about 40.4 um at 100 V.
        let p = stage_a::PARAMS;
        let mut s = Stage::<{ stage_a::OPERATORS }>::new(1);
        let mut top = 0.0;
        for k in 0..=2000 {
            top = s.step(&p, 100.0 * k as f32 / 2000.0).x_fhps_um;
        }
        assert!((top - 40.4).abs() < 1.0, "{top}");
    }

    #[test]
    fn sensor_noise_has_the_configured_spread() {
        let p = stage_a::PARAMS;
        let mut s = Stage::<4>::new(7);
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
