//! The feedforward of the damped stage: the reference shaping `S` that makes the
//! stage follow a fast reference without the lag of its damped mode and of the
//! loop's delay.
//!
//! **Sections** ([`design_time`], without a preview). `S(z) = N(z)/D(z)` in biquad sections: the poles `D` are fixed (a well-damped
//! pair per section at `pole_hz`), the numerator `N` (3 coefficients per
//! section, 5 for two) is found by least squares, with the static gain held to
//! exactly 1 (a heavily weighted row; the quantised sections are then made exact
//! by the core's `with_unit_static_gain`). Two sections split a fourth-order
//! numerator into two quadratics by its roots.
//!
//! **Preview** ([`design_preview`], the default). Where the board's
//! reference runs [`TimeOptions::preview`] ticks ahead of the one the loops
//! track (`piezo_fpi::preview`), the feedforward is sixteen taps on that delay
//! line, so that it inverts the damped stage's lag and delay instead of only
//! shaping them; where the loops damp, the damping leaves out the force the
//! shaped reference's own motion explains (`κ·(S_{k−1} − r_k)`), so that the
//! damped stage's slow high-pass-and-leak response does not trail every step.
//! On the linear model of the stage as built (856 Hz, ζ 0.023), five ticks
//! ahead: the 10 µm, 1.5 ms step overshoots by 0.04 µm and settles within
//! ±0.1 µm in 1.4 ms, the 100 Hz triangle is tracked within 0.04 µm RMS,
//! against 1.7 µm, 4.6 ms and 0.42 µm with the two sections and no preview.
//! Through the board the stage is not the fitted model, and these taps leave
//! about ten times the model's error: `fpi board autotune` then refines them on
//! trials on the stage itself ([`super::trials`]).
//!
//! [`design_time`] fits in the time domain: the position is linear in `N`, so
//! the closed loop (damping, PI and plant, the PI acting on the reference too)
//! is simulated once per numerator coefficient ([`super::simulate`]) on the
//! references the board is judged on — a raised-cosine step of the board's step
//! duration and a 100 Hz triangle — and `N` minimises the squared tracking error
//! over them. (A fit of the frequency response `N ≈ D/P_d` over a band was
//! tried first: it matched the response within 2 % to 400 Hz yet left twice the
//! triangle error, because the error the board is judged on sits at the
//! triangle's corners, where the band's edge decides.)

use anyhow::{anyhow, bail, Result};
use nalgebra::{Complex, DMatrix, DVector};
use piezo_fpi::biquad::COEFF_ABS_MAX;
use piezo_sim::filter::Section;

/// `Σ c_k·z^{−k}`.
fn poly(c: &[f64], z1: Complex<f64>) -> Complex<f64> {
    let mut acc = Complex::new(0.0, 0.0);
    let mut zk = Complex::new(1.0, 0.0);
    for &ck in c {
        acc += zk * ck;
        zk *= z1;
    }
    acc
}

fn convolve(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Two sections from a fourth-order numerator (in `z⁻¹`) and each section's
/// denominator: the numerator's roots paired (complex pairs together, real ones
/// by size), each pair's quadratic scaled to unit static gain with its section.
fn split_quartic(num: &[f64], d1: [f64; 3]) -> Result<Vec<[f64; 5]>> {
    // Roots in z of num[0]·z⁴ + num[1]·z³ + … + num[4].
    let lead = num[0];
    if lead.abs() < 1e-12 {
        bail!("the feedforward's numerator is degenerate");
    }
    let mut comp = DMatrix::<f64>::zeros(4, 4);
    for k in 0..4 {
        comp[(0, k)] = -num[k + 1] / lead;
    }
    for k in 1..4 {
        comp[(k, k - 1)] = 1.0;
    }
    let mut roots: Vec<Complex<f64>> = comp.complex_eigenvalues().iter().copied().collect();
    roots.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    let mut pairs: Vec<[Complex<f64>; 2]> = roots
        .iter()
        .filter(|r| r.im > 1e-9)
        .map(|r| [*r, r.conj()])
        .collect();
    let real: Vec<Complex<f64>> = roots
        .iter()
        .copied()
        .filter(|r| r.im.abs() <= 1e-9)
        .collect();
    for ch in real.chunks(2) {
        if ch.len() == 2 {
            pairs.push([ch[0], ch[1]]);
        }
    }
    if pairs.len() != 2 {
        bail!("the feedforward's numerator does not split into two real sections");
    }
    let dsum: f64 = d1.iter().sum();
    let out = pairs
        .iter()
        .map(|[r1, r2]| {
            // (1 − r1 z⁻¹)(1 − r2 z⁻¹), scaled so that N(1) = D(1).
            let q = [1.0, -(r1 + r2).re, (r1 * r2).re];
            let s = dsum / q.iter().sum::<f64>();
            [q[0] * s, q[1] * s, q[2] * s, d1[1], d1[2]]
        })
        .collect();
    Ok(out)
}

/// The sections as the firmware will run them (quantised), for a check of what
/// the design gives: `S(z)` at each `z⁻¹`.
pub fn response(sections: &[[f64; 5]], z1: Complex<f64>) -> Complex<f64> {
    sections
        .iter()
        .map(|s| poly(&s[..3], z1) / poly(&[1.0, s[3], s[4]], z1))
        .product()
}

/// Quantises the sections to the core's format, exact unit static gain.
pub fn quantise(sections: &[[f64; 5]]) -> Result<Vec<[f64; 5]>> {
    sections
        .iter()
        .map(|s| {
            let sec = Section {
                b: [s[0], s[1], s[2]],
                a: [s[3], s[4]],
            };
            let q = sec
                .quantise()
                .and_then(|q| q.with_unit_static_gain())
                .map_err(|e| anyhow!("a feedforward section: {}", e.message()))?;
            let back = Section::of_quantised(&q);
            Ok([back.b[0], back.b[1], back.b[2], back.a[0], back.a[1]])
        })
        .collect()
}

/// How [`design_time`] designs the feedforward.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeOptions {
    /// The frequency of its poles, Hz.
    pub pole_hz: f64,
    /// Their damping ratio.
    pub pole_damping: f64,
    /// Sections (1 or 2).
    pub sections: usize,
    /// The step it is trained on: its duration, ticks.
    pub step_ticks: usize,
    /// The triangle it is trained on: its frequency, Hz.
    pub triangle_hz: f64,
    /// Weight of the coefficients' size (keeps a reference's corner from being
    /// amplified into a saturating drive), relative to the data.
    pub ridge: f64,
    /// Ticks the shaping runs ahead of the tracked reference (1–7,
    /// `piezo_fpi::preview`: it is then taps on the delay line, and with damping
    /// the damping leaves the shaped reference's own force out); 0: sections
    /// on the tracked reference.
    pub preview: u8,
}

impl Default for TimeOptions {
    fn default() -> Self {
        Self {
            pole_hz: 2500.0,
            pole_damping: 0.8,
            sections: 2,
            step_ticks: 30,
            triangle_hz: 100.0,
            ridge: 1e-6,
            preview: 5,
        }
    }
}

/// A designed feedforward.
#[derive(Debug, Clone, PartialEq)]
pub enum Feedforward {
    /// Sections on the tracked reference (`[b0, b1, b2, a1, a2]` each).
    Sections(Vec<[f64; 5]>),
    /// Taps on the preview's delay line, newest first, `ticks` ahead.
    Preview {
        /// Ticks ahead of the tracked reference.
        ticks: u8,
        /// The taps (quantised, summing to 1 exactly in `I8F24`).
        taps: Vec<f64>,
        /// Trials through the board they were refined on (`super::trials`;
        /// 0: as designed on the model).
        trials: u32,
    },
}

impl Feedforward {
    /// What it is, for people.
    pub fn describe(&self) -> String {
        match self {
            Self::Sections(s) => format!("{} section(s) inverting the damped stage", s.len()),
            Self::Preview {
                ticks,
                taps,
                trials,
            } => {
                let refined = match trials {
                    0 => String::new(),
                    1 => ", refined on a trial through the board".into(),
                    n => format!(", refined on {n} trials through the board"),
                };
                format!(
                    "{} taps {} ticks ahead inverting the damped stage, the damping leaving \
                     the shaped reference's force out{refined}",
                    taps.len(),
                    ticks
                )
            }
        }
    }
}

/// The feedforward for the loops `l` on the plant `p` at `rate_hz` (see the
/// module docs): taps on the preview's line where `o.preview > 0`, else
/// sections.
pub fn design(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    rate_hz: f64,
    o: &TimeOptions,
) -> Result<Feedforward> {
    if o.preview == 0 {
        return design_time(p, l, rate_hz, o).map(Feedforward::Sections);
    }
    design_preview(p, l, rate_hz, o)
}

/// The taps on the preview's line (`o.preview` ticks ahead), fitted like
/// [`design_time`]'s numerators: the position is affine in the taps (the
/// shaped reference `u = Σ h_j·r_{k+n−j}` and, where the loops damp, the lead
/// force `κ·(u_{k−1} − r_k)` the damping leaves out), so least squares over
/// the step and the triangle, with the sum held to 1 exactly (a heavily
/// weighted row, then the rounding put on the largest tap).
pub fn design_preview(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    rate_hz: f64,
    o: &TimeOptions,
) -> Result<Feedforward> {
    use piezo_fpi::preview::TAPS;
    check_preview(o.preview)?;
    let (rows, rhs) = preview_rows(p, l, rate_hz, o);
    let h = fit_taps_within_gain(&rows, &rhs, o.ridge, &[0.0; TAPS], 1.0)?;
    Ok(Feedforward::Preview {
        ticks: o.preview,
        taps: quantise_taps(&h)?,
        trials: 0,
    })
}

/// The least squares [`design_preview`] solves for the taps: a row per tick
/// of the step and the triangle (each tap's response, [`tap_responses`]) and
/// its right-hand side (the reference less the loops' response without
/// taps). `o.preview` must be a preview the board has ([`check_preview`]).
pub fn preview_rows(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    rate_hz: f64,
    o: &TimeOptions,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    use super::simulate::{respond_led, step, triangle};
    use piezo_fpi::preview::TAPS;
    let n = usize::from(o.preview);
    let period = (rate_hz / o.triangle_hz).round() as usize;
    let refs = [
        step(1.0, o.step_ticks, 2 * TAPS, 8 * o.step_ticks),
        triangle(1.0, period, 3),
    ];
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut rhs: Vec<f64> = Vec::new();
    for r in &refs {
        let zeros = vec![0.0; r.len()];
        let y0 = respond_led(p, l, r, &zeros, &lead_force(p, l, &zeros, r), true);
        let basis = tap_responses(p, l, n, r);
        for k in 0..r.len() {
            rows.push(basis.iter().map(|b| b[k]).collect());
            rhs.push(r[k] - y0[k]);
        }
    }
    (rows, rhs)
}

/// Ridges tried, each ten times the last, before taps within the board's gain
/// are given up on.
const RIDGE_RAISES: u32 = 8;

/// The taps `base + c` for the least squares `c` of [`fit_with_sum`], with
/// their gain `Σ |h_j|` within the board's `TAPS_GAIN_MAX`
/// (`piezo_fpi::preview`, which refuses more): where the fit on a plant
/// with little to invert (a mode damped to ζ 0.45, no force gain) wants
/// more, the ridge is raised tenfold until it does not — a weaker inverse,
/// never a model the board refuses.
pub fn fit_taps_within_gain(
    rows: &[Vec<f64>],
    rhs: &[f64],
    ridge: f64,
    base: &[f64],
    sum: f64,
) -> Result<Vec<f64>> {
    let limit = taps_gain_max();
    let mut r = ridge.max(1e-12);
    for _ in 0..=RIDGE_RAISES {
        let c = fit_with_sum(rows, rhs, r, sum)?;
        let h: Vec<f64> = base.iter().zip(&c).map(|(b, d)| b + d).collect();
        if taps_gain(&h) <= limit {
            return Ok(h);
        }
        r *= 10.0;
    }
    bail!(
        "the feedforward's taps amplify the reference more than the board's {limit:.0} times \
         (the sum of their magnitudes) even with a ridge of {r:.0e}: the fitted plant has \
         nothing a preview can invert; tune without the feedforward (--no-feedforward)"
    )
}

/// `Σ |h_j|`: how many times the taps can amplify the reference.
pub fn taps_gain(h: &[f64]) -> f64 {
    h.iter().map(|t| t.abs()).sum()
}

/// The board's bound on [`taps_gain`] (`piezo_fpi::preview::TAPS_GAIN_MAX`),
/// less the rounding to `I8F24` of every tap.
fn taps_gain_max() -> f64 {
    piezo_fpi::preview::TAPS_GAIN_MAX as f64 - 1e-6
}

/// A preview of `ticks` the board has: 1 to `PREVIEW_MAX`.
pub fn check_preview(ticks: u8) -> Result<()> {
    use piezo_fpi::preview::PREVIEW_MAX;
    if !(1..=PREVIEW_MAX).contains(&ticks) {
        bail!("a preview of {ticks} ticks: 1 to {PREVIEW_MAX}");
    }
    Ok(())
}

/// The force the damping leaves out (N, per tick): `κ·(u_{k−1} − r_k)` for the
/// shaped reference `u` and the tracked one `r`, where the loops damp; zeros
/// where they do not.
fn lead_force(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    u: &[f64],
    r: &[f64],
) -> Vec<f64> {
    let kappa = if l.damps() { p.force_gain } else { 0.0 };
    (0..r.len())
        .map(|k| kappa * (if k > 0 { u[k - 1] } else { 0.0 } - r[k]))
        .collect()
}

/// The loops' response (from rest, µm) to each tap of the preview's line alone,
/// for the reference `r` (µm from its first value, per tick) `n` ticks ahead:
/// tap `j` feeds `r_{k+n−j}` (held at the ends) forward, with the lead force it
/// brings. The position is affine in the taps, so these are the columns of
/// every least squares on them.
pub fn tap_responses(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    n: usize,
    r: &[f64],
) -> Vec<Vec<f64>> {
    use super::simulate::respond_led;
    use piezo_fpi::preview::TAPS;
    let zeros = vec![0.0; r.len()];
    (0..TAPS)
        .map(|j| {
            let u: Vec<f64> = (0..r.len())
                .map(|k| r[(k + n).saturating_sub(j).min(r.len() - 1)])
                .collect();
            respond_led(p, l, &zeros, &u, &lead_force(p, l, &u, &zeros), true)
        })
        .collect()
}

/// The least-squares solution `c` of `rows·c ≈ rhs` with a ridge of `ridge`
/// (relative to the data) on each coefficient and `Σ c = sum` held (a row
/// weighted a thousandfold).
pub fn fit_with_sum(rows: &[Vec<f64>], rhs: &[f64], ridge: f64, sum: f64) -> Result<Vec<f64>> {
    let nb = rows.first().map_or(0, Vec::len);
    let m = rows.len() + nb + 1;
    let mut a = DMatrix::<f64>::zeros(m, nb);
    let mut b = DVector::<f64>::zeros(m);
    let scale: f64 = rows.iter().flatten().map(|v| v * v).sum::<f64>() / nb as f64;
    for (i, (row, y)) in rows.iter().zip(rhs).enumerate() {
        for (k, v) in row.iter().enumerate() {
            a[(i, k)] = *v;
        }
        b[i] = *y;
    }
    let lam = (ridge * scale).sqrt();
    let big = 1e3 * scale.sqrt();
    for k in 0..nb {
        a[(rows.len() + k, k)] = lam;
        a[(m - 1, k)] = big;
    }
    b[m - 1] = big * sum;
    let c = a
        .svd(true, true)
        .solve(&b, 1e-14)
        .map_err(|e| anyhow!("the feedforward's least squares failed: {e}"))?;
    Ok(c.iter().copied().collect())
}

/// Taps in `I8F24`, their sum exactly 1 (the rounding on the largest tap).
pub fn quantise_taps(h: &[f64]) -> Result<Vec<f64>> {
    use piezo_fpi::biquad::COEFF_FRAC;
    let one = f64::from(1u32 << COEFF_FRAC);
    if let Some(t) = h
        .iter()
        .find(|t| !t.is_finite() || t.abs() >= COEFF_ABS_MAX)
    {
        bail!("a feedforward tap of {t:.2} is beyond the board's range ±{COEFF_ABS_MAX:.0}");
    }
    if taps_gain(h) > taps_gain_max() {
        bail!(
            "the feedforward's taps amplify the reference {:.1} times (the sum of their \
             magnitudes): the board takes at most {}",
            taps_gain(h),
            piezo_fpi::preview::TAPS_GAIN_MAX
        );
    }
    let mut raw: Vec<i64> = h.iter().map(|t| (t * one).round() as i64).collect();
    let (big, _) = raw
        .iter()
        .enumerate()
        .max_by_key(|(_, v)| v.abs())
        .ok_or_else(|| anyhow!("a feedforward without taps"))?;
    raw[big] += (1i64 << COEFF_FRAC) - raw.iter().sum::<i64>();
    Ok(raw.iter().map(|v| *v as f64 / one).collect())
}

/// The feedforward sections for the loops `l` on the plant `p` at `rate_hz`,
/// fitted in the time domain (see the module docs); quantised, unit static gain.
pub fn design_time(
    p: &piezo_fpi::stability::Plant,
    l: &piezo_fpi::stability::Laws,
    rate_hz: f64,
    o: &TimeOptions,
) -> Result<Vec<[f64; 5]>> {
    use super::simulate::{filter, respond, step, triangle};
    if !(1..=2).contains(&o.sections) {
        bail!("a feedforward of {} sections: 1 or 2", o.sections);
    }
    let t = 1.0 / rate_hz;
    let w = std::f64::consts::TAU * o.pole_hz;
    let zeta = o.pole_damping;
    let zp = (Complex::new(-zeta * w, w * (1.0 - zeta * zeta).max(0.0).sqrt()) * t).exp();
    let d1 = [1.0, -2.0 * zp.re, zp.norm_sqr()];
    let den = if o.sections == 1 {
        d1.to_vec()
    } else {
        convolve(&d1, &d1)
    };
    let nb = 2 * o.sections + 1;
    // The training references and their weights.
    let period = (rate_hz / o.triangle_hz).round() as usize;
    let refs = [
        (step(1.0, o.step_ticks, 10, 8 * o.step_ticks), 1.0),
        (triangle(1.0, period, 3), 1.0),
    ];
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut rhs: Vec<f64> = Vec::new();
    for (r, wgt) in &refs {
        let zeros = vec![0.0; r.len()];
        let y0 = respond(p, l, r, &zeros, true);
        let basis: Vec<Vec<f64>> = (0..nb)
            .map(|k| {
                let mut b = vec![0.0; k + 1];
                b[k] = 1.0;
                let u = filter(&b, &den, r);
                respond(p, l, &zeros, &u, true)
            })
            .collect();
        for n in 0..r.len() {
            rows.push(basis.iter().map(|b| b[n] * wgt).collect());
            rhs.push((r[n] - y0[n]) * wgt);
        }
    }
    // N(1) = D(1): unit static gain.
    let num = fit_with_sum(&rows, &rhs, o.ridge, den.iter().sum::<f64>())?;
    let sections = if o.sections == 1 {
        vec![[num[0], num[1], num[2], d1[1], d1[2]]]
    } else {
        split_quartic(&num, d1)?
    };
    for (k, s) in sections.iter().enumerate() {
        if let Some(c) = s.iter().find(|c| c.abs() > COEFF_ABS_MAX) {
            bail!(
                "feedforward section {k}: coefficient {c:.2} beyond the board's range ±{COEFF_ABS_MAX:.0}"
            );
        }
    }
    quantise(&sections)
}
