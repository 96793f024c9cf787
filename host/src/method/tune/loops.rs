//! The loops of the board on a family of plants, in the frequency domain and as
//! state matrices: the core's discrete-time model ([`piezo_fpi::stability`]), so
//! what the tuner designs is what the validator checks and the board runs.
//!
//! Per plant, on a frequency grid `z = e^{jωT}`:
//!
//! ```text
//! P_x(z) = [0 1 0]·(zI − Φ)⁻¹·Γ            command → position sensor (one tick of delay)
//! P_r(z) = κ·[1 −1 0]·(zI − Φ)⁻¹·Γ         command → force residual
//! H(z)   = (1 − a)(1 − z⁻¹)/(1 − (1 − a)z⁻¹)       the split's high-pass (r_d = H·r)
//! G(z)   = (b0 + b1·z⁻¹ + b2·z⁻²)/(1 + a1·z⁻¹ + a2·z⁻²)   the damping's section
//! C(z)   = kp + ki·z⁻¹/(1 − z⁻¹)                    the PI
//! L_d    = G·H·P_r,   P_d = P_x/(1 + L_d),   L = C·P_d
//! ```

use nalgebra::{Complex, DMatrix, Matrix3, Vector3};
use piezo_fpi::damping::DynamicsSpec;
use piezo_fpi::stability::{decays, Laws, Plant};

/// One member of the plant family: the mode scaled, its damping replaced, the
/// gain scaled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Variant {
    /// Mode frequency relative to the nominal.
    pub mode_scale: f64,
    /// Damping ratio (`None`: the nominal).
    pub zeta: Option<f64>,
    /// Loop gain relative to the nominal.
    pub gain: f64,
}

impl Variant {
    /// The nominal plant.
    pub const NOMINAL: Self = Self {
        mode_scale: 1.0,
        zeta: None,
        gain: 1.0,
    };
}

/// A plant's responses on the grid.
#[derive(Debug, Clone)]
pub struct Responses {
    /// The variant.
    pub variant: Variant,
    /// The plant.
    pub plant: Plant,
    px: Vec<Complex<f64>>,
    pr: Vec<Complex<f64>>,
}

/// The family of plants the loops must hold on, and the frequency grid.
#[derive(Debug, Clone)]
pub struct Family {
    /// Frequencies, Hz.
    pub f_hz: Vec<f64>,
    /// `z⁻¹` at each.
    z1: Vec<Complex<f64>>,
    /// The control rate, Hz.
    fs: f64,
    /// The plants, nominal first.
    pub plants: Vec<Responses>,
}

impl Family {
    /// The family of `d` at `rate_hz` over `variants` (the nominal is added first),
    /// on a logarithmic grid from 1 Hz to just below Nyquist.
    pub fn new(d: &DynamicsSpec, rate_hz: u32, variants: &[Variant]) -> Self {
        let fs = rate_hz as f64;
        let (lo, hi, n) = (1.0_f64, 0.499 * fs, 700);
        let f_hz: Vec<f64> = (0..n)
            .map(|k| lo * (hi / lo).powf(k as f64 / (n - 1) as f64))
            .collect();
        let z1 = f_hz
            .iter()
            .map(|f| Complex::from_polar(1.0, -std::f64::consts::TAU * f / fs))
            .collect::<Vec<_>>();
        let mut all = vec![Variant::NOMINAL];
        all.extend(variants.iter().filter(|v| **v != Variant::NOMINAL));
        let plants = all
            .into_iter()
            .map(|v| {
                let plant = Plant::new(d, rate_hz, v.mode_scale, v.zeta, v.gain);
                let (px, pr) = responses(&plant, &z1);
                Responses {
                    variant: v,
                    plant,
                    px,
                    pr,
                }
            })
            .collect();
        Self {
            f_hz,
            z1,
            fs,
            plants,
        }
    }

    /// The nominal plant.
    pub fn nominal(&self) -> &Responses {
        &self.plants[0]
    }

    /// `L_d` of the damping loop on plant `p` at grid point `i`.
    pub fn damping_loop(&self, p: &Responses, i: usize, l: &Laws) -> Complex<f64> {
        damping_at(l, self.z1[i], p.pr[i])
    }

    /// The damped plant `P_d = P_x/(1 + L_d)` at grid point `i`.
    pub fn damped(&self, p: &Responses, i: usize, l: &Laws) -> Complex<f64> {
        p.px[i] / (Complex::new(1.0, 0.0) + self.damping_loop(p, i, l))
    }

    /// The PI `C(z)` at grid point `i`.
    pub fn pi(&self, i: usize, l: &Laws) -> Complex<f64> {
        pi_at(l, self.z1[i])
    }

    /// The position loop `L = C·P_d` at grid point `i`.
    pub fn position_loop(&self, p: &Responses, i: usize, l: &Laws) -> Complex<f64> {
        position_at(l, self.z1[i], p.px[i], p.pr[i])
    }

    /// Whether every plant of the family is stable under `l`, with the margin the
    /// validator asks for.
    pub fn all_stable(&self, l: &Laws) -> bool {
        self.plants.iter().all(|p| decays(&p.plant.closed_loop(l)))
    }

    /// The sensitivity peak `max |1/(1 + L)|` of the position loop over the family.
    pub fn sensitivity_peak(&self, l: &Laws) -> f64 {
        self.plants
            .iter()
            .map(|p| {
                (0..self.f_hz.len())
                    .map(|i| 1.0 / (Complex::new(1.0, 0.0) + self.position_loop(p, i, l)).norm())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max)
    }

    /// The smallest damping ratio of the oscillatory closed-loop poles above
    /// 5 Hz, over the family: the damping the mode gets, and that of any
    /// oscillation the loops make in its place or below it (a band-pass damping
    /// law adds a pole pair of its own).
    pub fn mode_damping(&self, d: &DynamicsSpec, rate_hz: u32, l: &Laws) -> f64 {
        let fs = rate_hz as f64;
        self.plants
            .iter()
            .map(|p| {
                let fm = d.mode_hz() * p.variant.mode_scale;
                let a = p.plant.closed_loop(l);
                let m = DMatrix::from_fn(a.len(), a.len(), |i, j| a[i][j]);
                m.complex_eigenvalues()
                    .iter()
                    .filter(|z| z.im > 1e-9)
                    .map(|z| {
                        let s = z.ln() * fs;
                        (s.im / std::f64::consts::TAU, -s.re / s.norm())
                    })
                    .filter(|(f, _)| *f > 5.0 && fm > 0.0)
                    .map(|(_, zeta)| zeta)
                    .fold(1.0, f64::min)
            })
            .fold(1.0, f64::min)
    }

    /// Gain crossover of the nominal position loop (first `|L| ≤ 1`), Hz.
    pub fn crossover_hz(&self, l: &Laws) -> f64 {
        let p = self.nominal();
        (0..self.f_hz.len())
            .find(|&i| self.position_loop(p, i, l).norm() <= 1.0)
            .map_or(0.0, |i| self.f_hz[i])
    }

    /// Gain margin (dB) and phase margin (degrees) of the nominal position loop
    /// ([`margins`]).
    pub fn margins(&self, l: &Laws) -> (f64, f64) {
        let p = &self.nominal().plant;
        margins(&self.f_hz, self.fs, |z1| {
            let (px, pr) = responses(p, &[z1]);
            position_at(l, z1, px[0], pr[0])
        })
    }

    /// The same for the damping loop `L_d` alone (broken at the damping's output).
    pub fn damping_margins(&self, l: &Laws) -> (f64, f64) {
        let p = &self.nominal().plant;
        margins(&self.f_hz, self.fs, |z1| {
            let (_, pr) = responses(p, &[z1]);
            damping_at(l, z1, pr[0])
        })
    }

    /// The −3 dB bandwidth of the nominal feedback loop's complementary
    /// sensitivity `T = L/(1 + L)`, Hz.
    pub fn feedback_bandwidth_hz(&self, l: &Laws) -> f64 {
        let p = self.nominal();
        let lim = std::f64::consts::FRAC_1_SQRT_2;
        (0..self.f_hz.len())
            .find(|&i| {
                let lp = self.position_loop(p, i, l);
                (lp / (Complex::new(1.0, 0.0) + lp)).norm() < lim
            })
            .map_or(self.f_hz[self.f_hz.len() - 1], |i| self.f_hz[i])
    }

    /// The RMS motion of the nominal stage at rest (µm) that white noise of
    /// `sigma_n` N RMS a sample on the force sensor drives through the loops:
    /// the noise enters the damping as a force residual would, so
    ///
    /// ```text
    /// T_n = −P_x·G·H / ((1 + L_d)·(1 + L))        force noise → position
    /// x_rms² = σ²·(2/f_s)·∫₀^{f_s/2} |T_n|² df
    /// ```
    ///
    /// on a linear grid of 4 000 points (2.5 Hz apart at 20 kHz: the damped
    /// mode's peak spans many of them). Without damping the noise does not
    /// reach the stage: 0.
    pub fn noise_motion_um(&self, l: &Laws, sigma_n: f64) -> f64 {
        if !l.damps() {
            return 0.0;
        }
        let n = 4000;
        let df = 0.5 * self.fs / n as f64;
        let z1: Vec<Complex<f64>> = (0..n)
            .map(|k| {
                Complex::from_polar(
                    1.0,
                    -std::f64::consts::TAU * (k as f64 + 0.5) * df / self.fs,
                )
            })
            .collect();
        let (px, pr) = responses(&self.nominal().plant, &z1);
        let one = Complex::new(1.0, 0.0);
        let power: f64 = (0..n)
            .map(|k| {
                let gh = damping_at(l, z1[k], one);
                let damped = one + gh * pr[k];
                let position = pi_at(l, z1[k]) * px[k] / damped;
                (px[k] * gh / (damped * (one + position))).norm_sqr() * df
            })
            .sum();
        sigma_n * (2.0 / self.fs * power).sqrt()
    }

    /// `z⁻¹` on the grid (for the feedforward's design).
    pub fn z1(&self) -> &[Complex<f64>] {
        &self.z1
    }
}

/// `L_d`, the damping loop, at `z⁻¹ = z1` with the plant's force response `pr`
/// there: the damping section through the force channel's high-pass.
fn damping_at(l: &Laws, z1: Complex<f64>, pr: Complex<f64>) -> Complex<f64> {
    let one = Complex::new(1.0, 0.0);
    if !l.damps() {
        return Complex::new(0.0, 0.0);
    }
    let h = if l.split > 0.0 {
        (one - z1) * (1.0 - l.split) / (one - z1 * (1.0 - l.split))
    } else {
        Complex::new(0.0, 0.0)
    };
    let [b0, b1, b2, a1, a2] = l.damping;
    let g = (z1 * (z1 * b2 + b1) + b0) / (z1 * (z1 * a2 + a1) + 1.0);
    g * h * pr
}

/// The PI `C(z)` at `z⁻¹ = z1`.
fn pi_at(l: &Laws, z1: Complex<f64>) -> Complex<f64> {
    Complex::new(l.kp, 0.0) + z1 * l.ki / (Complex::new(1.0, 0.0) - z1)
}

/// The position loop `L = C·P_x/(1 + L_d)` at `z⁻¹ = z1`.
fn position_at(l: &Laws, z1: Complex<f64>, px: Complex<f64>, pr: Complex<f64>) -> Complex<f64> {
    pi_at(l, z1) * px / (Complex::new(1.0, 0.0) + damping_at(l, z1, pr))
}

/// The margins of a loop `L(z⁻¹)` at control rate `fs`, the classical way but
/// over every crossing, not only the first: the gain margin is the least
/// `−20·log₁₀|L|` where `L` crosses the negative real axis (its phase through
/// ±180°, Nyquist included, where `L` is real), the phase margin the least
/// `180° − |∠L|` where `|L|` crosses 1 (∞ where there is no such crossing).
/// Crossings are found on the increasing grid `f_hz` and then located by
/// bisection on `L` itself: a lightly damped mode turns `L` through half a
/// circle within a few grid points, where interpolating between them misplaced
/// the crossing by up to 4 dB.
pub fn margins(f_hz: &[f64], fs: f64, l: impl Fn(Complex<f64>) -> Complex<f64>) -> (f64, f64) {
    let at = |f: f64| l(Complex::from_polar(1.0, -std::f64::consts::TAU * f / fs));
    // The frequency in (a, b) where `side` changes, by bisection.
    let locate = |(mut a, mut b): (f64, f64), side: &dyn Fn(Complex<f64>) -> bool| {
        let s_a = side(at(a));
        for _ in 0..60 {
            let m = 0.5 * (a + b);
            if side(at(m)) == s_a {
                a = m;
            } else {
                b = m;
            }
        }
        at(0.5 * (a + b))
    };
    let (mut gm, mut pm) = (f64::INFINITY, f64::INFINITY);
    let mut prev: Option<(f64, Complex<f64>)> = None;
    let mut grid: Vec<f64> = f_hz.to_vec();
    grid.push(0.5 * fs);
    for f in grid {
        let v = at(f);
        if let Some((fp, p)) = prev {
            if p.im.signum() != v.im.signum() && (p.im != 0.0 || v.im != 0.0) {
                let c = locate((fp, f), &|x: Complex<f64>| x.im >= 0.0);
                if c.re < 0.0 {
                    gm = gm.min(-20.0 * (-c.re).log10());
                }
            }
            if (p.norm() - 1.0).signum() != (v.norm() - 1.0).signum() {
                let c = locate((fp, f), &|x: Complex<f64>| x.norm() >= 1.0);
                pm = pm.min(180.0 - c.arg().to_degrees().abs());
            }
        }
        prev = Some((f, v));
    }
    // At Nyquist `L` is real: a negative value is a crossing of its own.
    let n = at(0.5 * fs);
    if n.re < 0.0 && n.im.abs() <= 1e-9 * n.norm().max(1e-300) {
        gm = gm.min(-20.0 * (-n.re).log10());
    }
    (gm, pm)
}

/// The plant's responses at each `z⁻¹` of `z1`: command → position sensor and
/// command → force residual.
pub fn responses(p: &Plant, z1: &[Complex<f64>]) -> (Vec<Complex<f64>>, Vec<Complex<f64>>) {
    let phi = Matrix3::from_fn(|i, j| Complex::new(p.phi[i][j], 0.0));
    let gamma = Vector3::from_fn(|i, _| Complex::new(p.gamma[i], 0.0));
    let mut px = Vec::with_capacity(z1.len());
    let mut pr = Vec::with_capacity(z1.len());
    for &zi in z1 {
        let z = Complex::new(1.0, 0.0) / zi;
        let m = Matrix3::from_diagonal_element(z) - phi;
        let s = m.try_inverse().map_or(Vector3::zeros(), |inv| inv * gamma);
        px.push(s[1]);
        pr.push((s[0] - s[1]) * p.force_gain);
    }
    (px, pr)
}
