//! The transfer function's arithmetic: its modes and real poles, evaluation and
//! roots of its polynomials, and its discretisation for the step a sampled run
//! is simulated with ([`Discrete`]).

use super::*;

/// `(natural frequency Hz, damping ratio)` of the complex pole pairs among
/// `poles` (those with positive imaginary part), lowest frequency first.
pub fn modes_of(poles: &[Complex<f64>]) -> Vec<(f64, f64)> {
    let mut m: Vec<(f64, f64)> = poles
        .iter()
        .filter(|p| p.im > 1e-9 * p.norm())
        .map(|p| (p.norm() / (2.0 * std::f64::consts::PI), -p.re / p.norm()))
        .collect();
    m.sort_by(|a, b| a.0.total_cmp(&b.0));
    m
}

/// Corner frequencies of the real poles among `poles`, Hz, lowest first.
pub fn real_poles_of(poles: &[Complex<f64>]) -> Vec<f64> {
    let mut r: Vec<f64> = poles
        .iter()
        .filter(|p| p.im.abs() <= 1e-9 * p.norm())
        .map(|p| p.norm() / (2.0 * std::f64::consts::PI))
        .collect();
    r.sort_by(f64::total_cmp);
    r
}

/// `"851.3 Hz ζ 0.0210, …"`, or `"none"`.
pub(super) fn describe_modes(m: &[(f64, f64)]) -> String {
    if m.is_empty() {
        return "none".into();
    }
    m.iter()
        .map(|(f, z)| format!("{f:.4} Hz ζ {z:.5}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl TransferFunction {
    /// `N(s)/D(s)` at complex `s` (rad/s).
    pub fn at(&self, s: Complex<f64>) -> Complex<f64> {
        horner(&self.numerator, s) / horner(&self.denominator, s)
    }

    /// `N(0)/D(0)`.
    pub fn dc_gain(&self) -> f64 {
        self.numerator.last().copied().unwrap_or(0.0)
            / self.denominator.last().copied().unwrap_or(f64::NAN)
    }

    /// The same transfer function scaled to unit DC gain.
    pub fn unit_dc(&self) -> TransferFunction {
        let g = self.dc_gain();
        TransferFunction {
            numerator: self.numerator.iter().map(|c| c / g).collect(),
            denominator: self.denominator.clone(),
        }
    }

    /// The poles, rad/s (roots of the denominator).
    pub fn poles(&self) -> Vec<Complex<f64>> {
        roots(&self.denominator)
    }
}

/// A polynomial (highest power first) at complex `s`.
pub fn horner(c: &[f64], s: Complex<f64>) -> Complex<f64> {
    c.iter().fold(Complex::new(0.0, 0.0), |acc, &k| acc * s + k)
}

/// Roots of a polynomial (highest power first): the eigenvalues of its companion
/// matrix, computed on the polynomial in `s/ω` with `ω = |c_n/c_0|^(1/n)` so that
/// the coefficients of high-frequency modes stay well scaled.
pub fn roots(c: &[f64]) -> Vec<Complex<f64>> {
    let c: Vec<f64> = c.iter().copied().skip_while(|&x| x == 0.0).collect();
    let n = c.len().saturating_sub(1);
    if n == 0 {
        return Vec::new();
    }
    let zeros_at_origin = c.iter().rev().take_while(|&&x| x == 0.0).count();
    let c = &c[..c.len() - zeros_at_origin];
    let m = c.len() - 1;
    let mut out = vec![Complex::new(0.0, 0.0); zeros_at_origin];
    if m == 0 {
        return out;
    }
    let w = (c[m] / c[0]).abs().powf(1.0 / m as f64);
    // Monic in s' = s/w: coefficient of s'^k over the leading one.
    let monic: Vec<f64> = (0..=m).map(|i| c[i] / c[0] / w.powi(i as i32)).collect();
    let mut comp = DMatrix::<f64>::zeros(m, m);
    for j in 0..m {
        comp[(0, j)] = -monic[j + 1];
    }
    for i in 1..m {
        comp[(i, i - 1)] = 1.0;
    }
    out.extend(comp.complex_eigenvalues().iter().map(|z| z * w));
    out
}

/// A discrete linear system in state space, run sample by sample: the
/// trapezoidal (Tustin) form `(kI − A)·x[n+1] = (kI + A)·x[n] + B·(u[n+1] + u[n])`,
/// `y[n] = C·x[n] + D·u[n]`, of a continuous system in time scaled by `ω0`.
#[derive(Debug, Clone)]
pub struct Discrete {
    /// `(kI − A)⁻¹(kI + A)`.
    p: DMatrix<f64>,
    /// `(kI − A)⁻¹B`.
    q: DVector<f64>,
    c: DVector<f64>,
    d: f64,
    /// Equilibrium state per unit of a constant input, `−A⁻¹B`.
    rest: DVector<f64>,
}

impl Discrete {
    /// Discretises `tf` (which must be stable) for sample interval `dt_s` with the
    /// bilinear transform, pre-warped at `prewarp_hz` when that lies below 0.45 of
    /// the sample rate (the discrete model then has the mode exactly there).
    pub fn tustin(tf: &TransferFunction, dt_s: f64, prewarp_hz: Option<f64>) -> Result<Self> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            bail!("sample interval {dt_s} s: must be > 0");
        }
        let two_pi = 2.0 * std::f64::consts::PI;
        let nyquist = 0.5 / dt_s;
        let k_rad = match prewarp_hz {
            Some(f) if f > 0.0 && f < 0.9 * nyquist => {
                let w = two_pi * f;
                w / (0.5 * w * dt_s).tan()
            }
            _ => 2.0 / dt_s,
        };
        let (a, b, c, d, w0) = canonical(tf)?;
        let n = a.nrows();
        let k = k_rad / w0;
        let eye = DMatrix::<f64>::identity(n, n);
        let m = (&eye * k - &a)
            .try_inverse()
            .ok_or_else(|| anyhow!("the dynamics cannot be discretised at {dt_s} s"))?;
        let rest = if n == 0 {
            DVector::zeros(0)
        } else {
            -a.clone()
                .try_inverse()
                .ok_or_else(|| anyhow!("the dynamics have a pole at 0"))?
                * &b
        };
        Ok(Self {
            p: &m * (&eye * k + &a),
            q: &m * &b,
            c,
            d,
            rest,
        })
    }

    /// Runs the system over `u`, starting at rest at `u[0]` (the state of a
    /// constant `u[0]` held for ever).
    pub fn filter(&self, u: &[f64]) -> Vec<f64> {
        let Some(&u0) = u.first() else {
            return Vec::new();
        };
        let mut x = &self.rest * u0;
        let mut prev = u0;
        let mut next = DVector::zeros(x.len());
        u.iter()
            .map(|&uk| {
                self.p.mul_to(&x, &mut next);
                next.axpy(prev + uk, &self.q, 1.0);
                std::mem::swap(&mut x, &mut next);
                prev = uk;
                self.c.dot(&x) + self.d * uk
            })
            .collect()
    }
}

/// A continuous state-space model `(A, B, C, D)` in the scaled variable
/// `s' = s/ω0`, and `ω0` (rad/s).
type Scaled = (DMatrix<f64>, DVector<f64>, DVector<f64>, f64, f64);

/// Controllable canonical form `(A, B, C, D)` of `tf` in the scaled variable
/// `s' = s/ω0`, and `ω0` (rad/s; the geometric mean of the poles' magnitudes).
fn canonical(tf: &TransferFunction) -> Result<Scaled> {
    let den = &tf.denominator;
    let n = den.len().saturating_sub(1);
    if den.is_empty() || den[0] == 0.0 || tf.numerator.len() > den.len() {
        bail!("the transfer function is not proper");
    }
    let w0 = if n == 0 {
        1.0
    } else {
        (den[n] / den[0]).abs().powf(1.0 / n as f64).max(1e-300)
    };
    // Ascending coefficients in s', the denominator monic.
    let scale = |c: &[f64]| -> Vec<f64> {
        let deg = c.len() - 1;
        (0..=deg)
            .map(|i| c[deg - i] * w0.powi(i as i32) / (den[0] * w0.powi(n as i32)))
            .collect()
    };
    let a_asc = scale(den);
    let mut b_asc = scale(&tf.numerator);
    b_asc.resize(n + 1, 0.0);
    let d = b_asc[n];
    let mut a = DMatrix::<f64>::zeros(n, n);
    for i in 0..n.saturating_sub(1) {
        a[(i, i + 1)] = 1.0;
    }
    for j in 0..n {
        a[(n - 1, j)] = -a_asc[j];
    }
    let mut b = DVector::<f64>::zeros(n);
    if n > 0 {
        b[n - 1] = 1.0;
    }
    let c = DVector::from_iterator(n, (0..n).map(|i| b_asc[i] - d * a_asc[i]));
    Ok((a, b, c, d, w0))
}

/// The sample interval of a uniformly sampled time column `t` (s): the mean step;
/// refuses a column whose steps differ from it by more than 1 %, naming the
/// 0-based index of the first such step.
pub fn uniform_step(t: &[f64]) -> std::result::Result<f64, (usize, f64, f64)> {
    if t.len() < 2 {
        return Err((0, f64::NAN, f64::NAN));
    }
    let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    match t
        .windows(2)
        .position(|w| ((w[1] - w[0]) - dt).abs() > 0.01 * dt)
    {
        Some(k) => Err((k, t[k + 1] - t[k], dt)),
        None => Ok(dt),
    }
}
