//! The rational fit of the pooled points (steps 2 and 3 of [`super`]): the
//! structures, equation error with Sanathanan–Koerner re-weighting, the output
//! error's Gauss–Newton and the candidates of every structure.

use super::*;

/// A frequency point to fit: `s = jω/ω0`, response, weight.
#[derive(Debug, Clone, Copy)]
pub struct Point {
    /// Scaled Laplace variable `jω/ω0`.
    pub s: Complex<f64>,
    /// Measured response (normalised to unit static gain).
    pub h: Complex<f64>,
    /// Coherence `γ²`.
    pub coherence: f64,
}

impl Point {
    /// The fit weight `γ²/|H|²`.
    fn weight(&self) -> f64 {
        self.coherence / self.h.norm_sqr()
    }
}

/// A model structure: modes (complex pole pairs) and real poles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Structure {
    /// Second-order modes.
    pub modes: usize,
    /// Real poles (0 or 1: the amplifier's lag).
    pub lag: usize,
}

impl Structure {
    /// Denominator degree.
    pub fn na(&self) -> usize {
        2 * self.modes + self.lag
    }
    /// Numerator degree: zeros between the modes, and one with the real pole
    /// (so that it can stand for a delay, as a first-order Padé term).
    pub fn nb(&self) -> usize {
        (2 * self.modes).saturating_sub(2) + self.lag
    }
    /// Free parameters (the denominator is monic).
    pub fn parameters(&self) -> usize {
        self.nb() + 1 + self.na()
    }
}

/// A rational model in the scaled variable: `B(s')/A(s')`, ascending
/// coefficients, `A` monic.
#[derive(Debug, Clone, PartialEq)]
pub struct Rational {
    /// Numerator, ascending powers of `s'`.
    pub b: Vec<f64>,
    /// Denominator, ascending powers of `s'`, last = 1.
    pub a: Vec<f64>,
}

/// A polynomial with ascending coefficients at `s`.
fn poly_asc(c: &[f64], s: Complex<f64>) -> Complex<f64> {
    c.iter()
        .rev()
        .fold(Complex::new(0.0, 0.0), |acc, &k| acc * s + k)
}

impl Rational {
    /// `B(s)/A(s)`.
    pub fn at(&self, s: Complex<f64>) -> Complex<f64> {
        poly_asc(&self.b, s) / poly_asc(&self.a, s)
    }

    /// The transfer function in `s` (rad/s) for scale `w0` (rad/s), highest power
    /// first, the denominator monic.
    pub fn unscaled(&self, w0: f64) -> TransferFunction {
        let na = self.a.len() - 1;
        let up = |c: &[f64]| -> Vec<f64> {
            (0..c.len())
                .rev()
                .map(|i| c[i] * w0.powi((na - i) as i32))
                .collect()
        };
        let mut numerator = up(&self.b);
        while numerator.len() > 1 && numerator[0] == 0.0 {
            numerator.remove(0);
        }
        TransferFunction {
            numerator,
            denominator: up(&self.a),
        }
    }

    /// Whether every root of `A` lies in the open left half-plane.
    fn stable(&self) -> bool {
        let desc: Vec<f64> = self.a.iter().rev().copied().collect();
        dynamics::roots(&desc).iter().all(|p| p.re < 0.0)
    }
}

/// Weighted sum of squared output errors `Σ w|H − B/A|²`.
pub fn cost(r: &Rational, pts: &[Point]) -> f64 {
    pts.iter()
        .map(|p| p.weight() * (p.h - r.at(p.s)).norm_sqr())
        .sum()
}

/// Equation-error fit (`invfreqs`), then Sanathanan–Koerner re-weighting; unstable
/// roots reflected.
pub fn equation_error(pts: &[Point], st: Structure) -> Option<Rational> {
    let mut r = ee_solve(pts, st, None)?;
    for _ in 0..6 {
        r = ee_solve(pts, st, Some(&r.a)).unwrap_or(r);
    }
    Some(stabilise(r))
}

/// One linear least-squares solve of `Σ w/|A_prev|² · |H·A − B|²`.
fn ee_solve(pts: &[Point], st: Structure, prev: Option<&[f64]>) -> Option<Rational> {
    let (na, nb) = (st.na(), st.nb());
    let cols = nb + 1 + na;
    let mut m = DMatrix::<f64>::zeros(2 * pts.len(), cols);
    let mut rhs = DVector::<f64>::zeros(2 * pts.len());
    for (k, p) in pts.iter().enumerate() {
        let sk = prev.map_or(1.0, |a| poly_asc(a, p.s).norm());
        let w = p.weight().sqrt() / sk;
        let mut row = Vec::with_capacity(cols);
        row.extend((0..=nb).map(|i| -p.s.powu(i as u32) * w));
        row.extend((0..na).map(|i| p.h * p.s.powu(i as u32) * w));
        let r = -p.h * p.s.powu(na as u32) * w;
        for (j, v) in row.iter().enumerate() {
            m[(2 * k, j)] = v.re;
            m[(2 * k + 1, j)] = v.im;
        }
        rhs[2 * k] = r.re;
        rhs[2 * k + 1] = r.im;
    }
    let theta = solve_scaled(m, &rhs)?;
    Some(from_theta(&theta, st))
}

/// Least-squares solution of `m·θ = rhs` with the columns scaled to unit norm.
pub(super) fn solve_scaled(mut m: DMatrix<f64>, rhs: &DVector<f64>) -> Option<DVector<f64>> {
    let norms: Vec<f64> = m
        .column_iter()
        .map(|c| c.norm().max(f64::MIN_POSITIVE))
        .collect();
    for (j, n) in norms.iter().enumerate() {
        m.column_mut(j).scale_mut(1.0 / n);
    }
    let x = m.svd(true, true).solve(rhs, 1e-13).ok()?;
    let x = DVector::from_iterator(x.len(), x.iter().zip(&norms).map(|(v, n)| v / n));
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// `θ = [b_0..b_nb, a_0..a_{na−1}]` as a model.
fn from_theta(theta: &DVector<f64>, st: Structure) -> Rational {
    let nb = st.nb();
    let b = theta.rows(0, nb + 1).iter().copied().collect();
    let mut a: Vec<f64> = theta.rows(nb + 1, st.na()).iter().copied().collect();
    a.push(1.0);
    Rational { b, a }
}

/// The parameter vector of a model.
fn to_theta(r: &Rational) -> DVector<f64> {
    let na = r.a.len() - 1;
    DVector::from_iterator(r.b.len() + na, r.b.iter().chain(&r.a[..na]).copied())
}

/// The model with the roots of `A` in the right half-plane reflected into the
/// left one (the gain at `s = 0` kept).
fn stabilise(r: Rational) -> Rational {
    if r.stable() || r.a.len() < 2 {
        return r;
    }
    let desc: Vec<f64> = r.a.iter().rev().copied().collect();
    let roots: Vec<Complex<f64>> = dynamics::roots(&desc)
        .into_iter()
        .map(|p| Complex::new(-p.re.abs().max(1e-6 * p.norm()), p.im))
        .collect();
    let a = poly_from_roots(&roots);
    let scale = a[0] / r.a[0];
    let b = if scale.is_finite() {
        r.b.iter().map(|c| c * scale).collect()
    } else {
        r.b
    };
    Rational { b, a }
}

/// The monic polynomial (ascending) with these roots (conjugates paired).
pub(super) fn poly_from_roots(roots: &[Complex<f64>]) -> Vec<f64> {
    let mut c = vec![Complex::new(1.0, 0.0)];
    for &z in roots {
        let mut next = vec![Complex::new(0.0, 0.0); c.len() + 1];
        for (i, &k) in c.iter().enumerate() {
            next[i + 1] += k;
            next[i] -= k * z;
        }
        c = next;
    }
    c.iter().map(|z| z.re).collect()
}

/// Levenberg–Marquardt on the output error from `start` (which must be stable);
/// steps that make `A` unstable are refused.
pub fn output_error(pts: &[Point], st: Structure, start: Rational) -> Rational {
    let mut best = start;
    let mut c = cost(&best, pts);
    let mut lambda = 1e-3;
    for _ in 0..300 {
        let (j, r) = jacobian(&best, pts);
        let jt = j.transpose();
        let jtj = &jt * &j;
        let g = &jt * &r;
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj.clone();
            for i in 0..a.nrows() {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-300);
            }
            let Some(step) = a.lu().solve(&(-&g)) else {
                lambda *= 10.0;
                continue;
            };
            let cand = from_theta(&(to_theta(&best) + step), st);
            let cc = cost(&cand, pts);
            if cc.is_finite() && cc < c && cand.stable() {
                let done = (c - cc) < 1e-12 * c;
                best = cand;
                c = cc;
                lambda = (lambda / 3.0).max(1e-12);
                improved = !done;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    best
}

/// Residuals `√w·(H − B/A)` (re, im stacked) and their Jacobian in `θ`.
fn jacobian(r: &Rational, pts: &[Point]) -> (DMatrix<f64>, DVector<f64>) {
    let (nb, na) = (r.b.len() - 1, r.a.len() - 1);
    let mut j = DMatrix::<f64>::zeros(2 * pts.len(), nb + 1 + na);
    let mut res = DVector::<f64>::zeros(2 * pts.len());
    for (k, p) in pts.iter().enumerate() {
        let w = p.weight().sqrt();
        let (bv, av) = (poly_asc(&r.b, p.s), poly_asc(&r.a, p.s));
        let e = (p.h - bv / av) * w;
        res[2 * k] = e.re;
        res[2 * k + 1] = e.im;
        for i in 0..=nb {
            let d = -p.s.powu(i as u32) / av * w;
            j[(2 * k, i)] = d.re;
            j[(2 * k + 1, i)] = d.im;
        }
        for i in 0..na {
            let d = bv * p.s.powu(i as u32) / (av * av) * w;
            j[(2 * k, nb + 1 + i)] = d.re;
            j[(2 * k + 1, nb + 1 + i)] = d.im;
        }
    }
    (j, res)
}

/// One fitted structure and its scores.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// The structure.
    pub structure: Structure,
    /// The fitted model (scaled variable).
    pub model: Rational,
    /// Weighted RMS relative error `√(Σγ²|H − G|²/|H|² / Σγ²)`.
    pub rms: f64,
    /// Akaike's criterion `2N·ln(SSE/2N) + 2p` (N complex points).
    pub aic: f64,
}

/// Fits one structure: equation error, then output error.
pub fn fit(pts: &[Point], st: Structure) -> Option<Candidate> {
    let start = equation_error(pts, st)?;
    if !start.stable() {
        return None;
    }
    let model = output_error(pts, st, start);
    let sse = cost(&model, pts);
    let n2 = 2.0 * pts.len() as f64;
    let wsum: f64 = pts.iter().map(|p| p.coherence).sum();
    Some(Candidate {
        structure: st,
        rms: (sse / wsum).sqrt(),
        aic: n2 * (sse / n2).ln() + 2.0 * st.parameters() as f64,
        model,
    })
}

/// Every structure of [`CRITERION`], fitted (those that fail to fit left out).
pub fn candidates(pts: &[Point]) -> Vec<Candidate> {
    let mut out = vec![];
    for modes in 0..=3 {
        for lag in 0..=1 {
            let st = Structure { modes, lag };
            if st.parameters() * 2 < pts.len() {
                out.extend(fit(pts, st));
            }
        }
    }
    out
}
