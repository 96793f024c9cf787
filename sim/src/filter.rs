//! Design of the dynamic compensator the core runs as a fixed-point biquad cascade
//! ([`piezo_fpi::biquad`]), its quantisation, and its `f64` reference.
//!
//! Both designs are the ratio of two second-order polynomials with the same
//! natural frequency `ω = 2π·f`:
//!
//! ```text
//! H(s) = (s² + 2ζ_num·ω·s + ω²) / (s² + 2ζ_den·ω·s + ω²)        |H(0)| = 1, |H(jω)| = ζ_num/ζ_den
//! ```
//!
//! * **notch** ([`notch`]): `ζ_den` sets the width (a full notch, `ζ_num = 0`, is
//!   3 dB down at `f·(√(1+ζ²) ± ζ)`, a −3 dB bandwidth of `2ζ·f`), and the depth is
//!   the gain at `f`, `ζ_num/ζ_den` (0: a full notch);
//! * **stable model inverse** ([`mode_inverse`]): `ζ_num = ζ` of the plant's mode
//!   (its poles become the filter's zeros and cancel the mode), `ζ_den = ζ_d`, the
//!   damping the compensated stage should have (e.g. 0.7). The filter is proper,
//!   stable and minimum phase for `ζ ≥ 0`, `ζ_d > 0`; its gain at `f` is `ζ/ζ_d`
//!   (the plant's resonant peak `1/(2ζ)` becomes `1/(2ζ_d)`).
//!
//! Discretisation at the board's rate `f_s` is the bilinear (Tustin) transform with
//! pre-warping at `f`: `s = K·(1 − z⁻¹)/(1 + z⁻¹)` with `K = ω / tan(ω/(2 f_s))`, so
//! the digital filter's gain at `f` is exactly the analog one, and its DC gain is
//! exactly 1. `f64` only (`libm` for `tan`, `sin`, `cos`: the same on the host and
//! without `std`).

use piezo_fpi::biquad::{Biquad, BiquadError, Cascade, Coefficient};

/// One second-order section in `f64`, `a0 = 1`:
/// `H(z) = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    /// `[b0, b1, b2]`.
    pub b: [f64; 3],
    /// `[a1, a2]`.
    pub a: [f64; 2],
}

impl Section {
    /// The identity.
    pub const IDENTITY: Self = Self {
        b: [1.0, 0.0, 0.0],
        a: [0.0, 0.0],
    };

    /// The bilinear transform of the analog section
    /// `(n[0]·s² + n[1]·s + n[2]) / (d[0]·s² + d[1]·s + d[2])` at `fs_hz`, pre-warped
    /// at `f_warp_hz` (`0 < f_warp_hz < fs_hz/2`); `None` for a warp frequency
    /// outside that range, a non-finite result or a zero `a0`.
    pub fn bilinear(n: [f64; 3], d: [f64; 3], f_warp_hz: f64, fs_hz: f64) -> Option<Self> {
        if !(f_warp_hz > 0.0 && fs_hz > 0.0 && f_warp_hz < 0.5 * fs_hz) {
            return None;
        }
        let w = 2.0 * core::f64::consts::PI * f_warp_hz;
        let k = w / libm::tan(w / (2.0 * fs_hz));
        let z = |p: [f64; 3]| {
            let (p2, p1, p0) = (p[0] * k * k, p[1] * k, p[2]);
            [p2 + p1 + p0, 2.0 * (p0 - p2), p2 - p1 + p0]
        };
        let (b, a) = (z(n), z(d));
        if a[0] == 0.0 {
            return None;
        }
        let s = Self {
            b: [b[0] / a[0], b[1] / a[0], b[2] / a[0]],
            a: [a[1] / a[0], a[2] / a[0]],
        };
        s.b.iter().chain(&s.a).all(|c| c.is_finite()).then_some(s)
    }

    /// The complex response `(re, im)` at `f_hz` for a sample rate `fs_hz`.
    pub fn response(&self, f_hz: f64, fs_hz: f64) -> (f64, f64) {
        let th = 2.0 * core::f64::consts::PI * f_hz / fs_hz;
        let (c1, s1) = (libm::cos(th), -libm::sin(th));
        let (c2, s2) = (libm::cos(2.0 * th), -libm::sin(2.0 * th));
        let (nr, ni) = (
            self.b[0] + self.b[1] * c1 + self.b[2] * c2,
            self.b[1] * s1 + self.b[2] * s2,
        );
        let (dr, di) = (
            1.0 + self.a[0] * c1 + self.a[1] * c2,
            self.a[0] * s1 + self.a[1] * s2,
        );
        let m = dr * dr + di * di;
        ((nr * dr + ni * di) / m, (ni * dr - nr * di) / m)
    }

    /// `|H|` at `f_hz` for a sample rate `fs_hz`.
    pub fn gain(&self, f_hz: f64, fs_hz: f64) -> f64 {
        let (re, im) = self.response(f_hz, fs_hz);
        libm::sqrt(re * re + im * im)
    }

    /// The DC gain `Σb / (1 + a1 + a2)`.
    pub fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }

    /// The section in the core's format ([`Biquad`]: `I8F24` coefficients, limits
    /// ±4096), each coefficient rounded to nearest. If the design has unity DC gain
    /// (within 10⁻⁹, as both designs here), `b1` absorbs the rounding so that the
    /// quantised section's DC gain is exactly 1 (`Σb = 1 + a1 + a2` in the raw
    /// integers). Refused ([`BiquadError`], never a panic) if a coefficient is not
    /// finite or outside ±2, or the quantised poles are not stable.
    pub fn quantise(&self) -> Result<Biquad, BiquadError> {
        let q = Biquad::from_f64(self.b, self.a)?;
        let dc = self.dc_gain();
        if (dc - 1.0).abs().partial_cmp(&1e-9) != Some(core::cmp::Ordering::Less) {
            return Ok(q);
        }
        q.with_unit_static_gain()
    }

    /// The coefficients of a quantised section, back in `f64` (exact).
    pub fn of_quantised(q: &Biquad) -> Self {
        let f = |c: Coefficient| c.to_num::<f64>();
        let ([b0, b1, b2], [a1, a2]) = (q.b(), q.a());
        Self {
            b: [f(b0), f(b1), f(b2)],
            a: [f(a1), f(a2)],
        }
    }
}

/// `(s² + 2ζ_num·ω·s + ω²)/(s² + 2ζ_den·ω·s + ω²)` at `f_hz`, Tustin pre-warped at
/// `f_hz`, sample rate `fs_hz`; `None` unless `0 < f_hz < fs_hz/2`, `ζ_num ≥ 0` and
/// `ζ_den > 0` (finite).
pub fn resonance_ratio(f_hz: f64, zeta_num: f64, zeta_den: f64, fs_hz: f64) -> Option<Section> {
    if !(zeta_num >= 0.0 && zeta_den > 0.0 && zeta_num.is_finite() && zeta_den.is_finite()) {
        return None;
    }
    let w = 2.0 * core::f64::consts::PI * f_hz;
    Section::bilinear(
        [1.0, 2.0 * zeta_num * w, w * w],
        [1.0, 2.0 * zeta_den * w, w * w],
        f_hz,
        fs_hz,
    )
}

/// A notch at `f_hz`: width `zeta` (the poles' damping ratio; a full notch has a
/// −3 dB bandwidth of `2·zeta·f_hz`) and `depth`, the linear gain at `f_hz`
/// (`0 ≤ depth`, 0 for a full notch; e.g. 0.1 for −20 dB); unity DC gain.
pub fn notch(f_hz: f64, zeta: f64, depth: f64, fs_hz: f64) -> Option<Section> {
    resonance_ratio(f_hz, depth * zeta, zeta, fs_hz)
}

/// The stable inverse of a mode at `f_hz` with damping ratio `zeta`, placing the
/// compensated mode at the damping `zeta_d` (e.g. 0.7): the zeros cancel the
/// mode's poles; unity DC gain, gain `zeta/zeta_d` at `f_hz`.
pub fn mode_inverse(f_hz: f64, zeta: f64, zeta_d: f64, fs_hz: f64) -> Option<Section> {
    resonance_ratio(f_hz, zeta, zeta_d, fs_hz)
}

/// Quantises every section ([`Section::quantise`]) into a core [`Cascade`]; the
/// first refusal, with the section's index.
pub fn quantise_cascade<const M: usize>(
    sections: &[Section; M],
) -> Result<Cascade<M>, (usize, BiquadError)> {
    let mut out = [Biquad::IDENTITY; M];
    for (i, (o, s)) in out.iter_mut().zip(sections).enumerate() {
        *o = s.quantise().map_err(|e| (i, e))?;
    }
    Ok(Cascade::new(out))
}

/// The `f64` reference of a section (direct form I, no rounding, no saturation):
/// configuration and state together.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// The coefficients.
    pub section: Section,
    x: [f64; 2],
    y: [f64; 2],
}

impl Reference {
    /// At rest.
    pub fn new(section: Section) -> Self {
        Self {
            section,
            x: [0.0; 2],
            y: [0.0; 2],
        }
    }

    /// Settled on the constant `v` (a unity-DC-gain section).
    pub fn settled(section: Section, v: f64) -> Self {
        Self {
            section,
            x: [v; 2],
            y: [v; 2],
        }
    }

    /// One sample.
    pub fn update(&mut self, x: f64) -> f64 {
        let Section { b, a } = self.section;
        let y =
            b[0] * x + b[1] * self.x[0] + b[2] * self.x[1] - a[0] * self.y[0] - a[1] * self.y[1];
        self.x = [x, self.x[0]];
        self.y = [y, self.y[0]];
        y
    }
}

/// Runs `x` through references of `sections` in order (one sample).
pub fn cascade_update(refs: &mut [Reference], x: f64) -> f64 {
    refs.iter_mut().fold(x, |u, r| r.update(u))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fixed::types::I16F16;
    use piezo_fpi::process::SplitProcess;

    const FS: f64 = 20_000.0;

    /// A linear chirp from `f0` to `f1` Hz over `n` samples, `offset ± amp`.
    fn chirp(n: usize, f0: f64, f1: f64, offset: f64, amp: f64) -> impl Iterator<Item = f64> {
        let t_end = n as f64 / FS;
        (0..n).map(move |i| {
            let t = i as f64 / FS;
            let ph = 2.0 * core::f64::consts::PI * (f0 * t + 0.5 * (f1 - f0) / t_end * t * t);
            offset + amp * libm::sin(ph)
        })
    }

    fn sections() -> [Section; 2] {
        [
            mode_inverse(850.0, 0.02, 0.7, FS).unwrap(),
            notch(2_600.0, 0.1, 0.05, FS).unwrap(),
        ]
    }

    #[test]
    fn designs_have_unity_dc_gain_and_the_analog_gain_at_f() {
        let inv = mode_inverse(850.0, 0.02, 0.7, FS).unwrap();
        assert!((inv.dc_gain() - 1.0).abs() < 1e-12);
        assert!((inv.gain(850.0, FS) - 0.02 / 0.7).abs() < 1e-12);
        let n = notch(850.0, 0.1, 0.05, FS).unwrap();
        assert!((n.dc_gain() - 1.0).abs() < 1e-12);
        assert!((n.gain(850.0, FS) - 0.05).abs() < 1e-12);
        // The response is flat far from f (2 % at a decade below).
        assert!((n.gain(85.0, FS) - 1.0).abs() < 0.02);
        assert!(mode_inverse(850.0, 0.02, 0.0, FS).is_none());
        assert!(mode_inverse(12_000.0, 0.02, 0.7, FS).is_none());
    }

    #[test]
    fn quantised_sections_keep_exact_unity_dc_gain() {
        for s in sections() {
            let q = s.quantise().unwrap();
            assert_eq!(q.dc_gain(), 1.0);
        }
        let c = quantise_cascade(&sections()).unwrap();
        let mut st = c.initial_state();
        let x = I16F16::from_num(75.123_456);
        let mut y = I16F16::ZERO;
        for _ in 0..20_000 {
            y = c.process(&mut st, x);
        }
        assert_eq!(y, x, "fixed-point cascade settles exactly on a constant");
    }

    #[test]
    fn out_of_format_designs_are_refused() {
        // A resonance ratio with large numerator damping near Nyquist, scaled
        // beyond the I8F24 range (±128).
        let mut s = resonance_ratio(7_000.0, 3.0, 0.3, FS).unwrap();
        s.b = s.b.map(|b| b * 64.0);
        assert!(s.b[0] > 128.0, "{s:?}");
        assert_eq!(
            s.quantise(),
            Err(BiquadError::CoefficientOutOfRange { index: 0 })
        );
        let bad = Section {
            b: [1.0, 0.0, 0.0],
            a: [-1.99, 1.0],
        };
        assert_eq!(bad.quantise(), Err(BiquadError::Unstable));
        assert_eq!(
            quantise_cascade(&[Section::IDENTITY, bad]).err(),
            Some((1, BiquadError::Unstable))
        );
    }

    /// The bound of the fixed-point cascade against the f64 reference with the same
    /// (quantised) coefficients on the same (quantised) input, in output LSB
    /// (2⁻¹⁶ V = 15.3 µV): each section's output is the exact one rounded (±½ LSB);
    /// the first section's rounding passes through the second (gain ≤ 1.1 here).
    const CHIRP_BOUND_LSB: f64 = 1.25;

    #[test]
    fn fixed_point_cascade_matches_the_f64_reference_on_a_chirp() {
        let c = quantise_cascade(&sections()).unwrap();
        let mut st = c.initial_state();
        let mut refs = c
            .sections()
            .map(|q| Reference::new(Section::of_quantised(&q)));
        let mut design = sections().map(Reference::new);
        let (mut worst, mut worst_design) = (0.0f64, 0.0f64);
        let lsb = 1.0 / 65_536.0;
        for x in chirp(100_000, 10.0, 5_000.0, 75.0, 20.0) {
            let xq = I16F16::from_num(x);
            let y = c.process(&mut st, xq).to_num::<f64>();
            let r = cascade_update(&mut refs, xq.to_num::<f64>());
            let d = cascade_update(&mut design, xq.to_num::<f64>());
            worst = worst.max((y - r).abs() / lsb);
            worst_design = worst_design.max((y - d).abs() / lsb);
        }
        std::println!(
            "chirp 10 Hz-5 kHz, 75 ± 20 V: fixed vs f64 reference (same coefficients) {worst:.2} LSB, vs the unquantised design {worst_design:.2} LSB"
        );
        assert!(worst <= CHIRP_BOUND_LSB, "{worst} LSB");
        assert!(worst_design <= 2.0 * CHIRP_BOUND_LSB, "{worst_design} LSB");
    }

    /// The amplitude of `y` at `f` (Hz), by correlation over whole periods.
    fn amplitude(y: &[f64], f: f64) -> f64 {
        let (mut c, mut s) = (0.0, 0.0);
        for (i, v) in y.iter().enumerate() {
            let th = 2.0 * core::f64::consts::PI * f * i as f64 / FS;
            c += v * libm::cos(th);
            s += v * libm::sin(th);
        }
        2.0 * libm::sqrt(c * c + s * s) / y.len() as f64
    }

    #[test]
    fn fixed_point_notch_attenuates_as_designed_at_f() {
        // 800 Hz: exactly 25 samples a period.
        let (f, depth) = (800.0, 0.05);
        let q = notch(f, 0.1, depth, FS).unwrap().quantise().unwrap();
        let mut st = piezo_fpi::biquad::BiquadState::settled(I16F16::from_num(75.0));
        let mut out = std::vec::Vec::new();
        for i in 0..40_000 {
            let x = 75.0 + 50.0 * libm::sin(2.0 * core::f64::consts::PI * f * i as f64 / FS);
            let y = q.process(&mut st, I16F16::from_num(x)).to_num::<f64>();
            if i >= 20_000 {
                out.push(y - 75.0);
            }
        }
        let gain = amplitude(&out, f) / 50.0;
        std::println!("notch at {f} Hz: designed {depth}, fixed point {gain:.6}");
        assert!((gain - depth).abs() < 1e-4, "{gain}");
    }
}
