//! The stage's identified linear dynamics (`DYN.toml`, written by `fpi identify`):
//! the one home of the dynamics model. It reads, validates and writes the file,
//! evaluates the transfer function, and runs it, normalised to unit DC gain and
//! discretised at a drive's sample rate, after the rate-independent FPI
//! prediction (the Hammerstein structure of `fpi predict --dynamics`).
//!
//! The file's contract (other tools rely on these keys):
//!
//! ```toml
//! natural_frequency_hz = [851.3]     # one per identified mode, lowest first, Hz
//! damping_ratio = [0.021]            # one per mode, > 0
//! capacitance_uf = 2.1               # eq. 14, i = C·du/dt, µF
//! dc_gain_um_per_v = 0.33            # the transfer function's DC gain, µm/V
//! [transfer_function]                # voltage → x_fhps_um, µm/V, s in rad/s
//! numerator = [1.0e7]                # highest power of s first
//! denominator = [1.0, 112.0, 2.9e7]  # highest power first, stable
//! ```
//!
//! Optional tables: `[voltage_gain]` (eq. 13, the static gain against the drive's
//! span) and `[fit]` (provenance and fit quality).
//!
//! **Why Hammerstein (hysteresis, then dynamics), not Wiener.** The hysteresis is
//! the stack's (its polarisation against the field it is given); the mode is the
//! stage's mass on its hinges, moved by what the stack does. So the linear
//! dynamics act on the stack's output. Put before the hysteresis, the mode would
//! amplify the *voltage* near resonance and the play operators would see reversals
//! the stack never sees. The amplifier's lag, which does act on the voltage, is a
//! pole well above the drives' band, and a linear lag commutes with the
//! nearly-linear small-signal hysteresis; it is kept in the same linear block.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use nalgebra::{Complex, DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::data::toml_file::{self, TomlFile};

mod transfer;
use transfer::describe_modes;
pub use transfer::{horner, modes_of, real_poles_of, roots, uniform_step, Discrete};

/// Format tag of the file.
pub const FORMAT: &str = "fpi-dynamics/1";

/// Largest file [`Dynamics::read`] takes, bytes.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Most poles a transfer function may have (the identification fits at most 7).
pub const MAX_ORDER: usize = 12;

/// A mode listed in the file matches a pole pair of the denominator when both its
/// natural frequency and its damping ratio agree within this relative tolerance.
pub const MODE_TOLERANCE: f64 = 1e-3;

/// The identified dynamics of one stage (`DYN.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dynamics {
    /// Format tag, [`FORMAT`].
    #[serde(default = "format_tag")]
    pub format: String,
    /// Natural frequencies of the modes (complex pole pairs), lowest first, Hz.
    pub natural_frequency_hz: Vec<f64>,
    /// Damping ratios of the modes, in the order of `natural_frequency_hz`.
    pub damping_ratio: Vec<f64>,
    /// Stack capacitance of the capacitive current model (eq. 14), µF.
    pub capacitance_uf: f64,
    /// DC gain of `transfer_function`, µm/V.
    pub dc_gain_um_per_v: f64,
    /// Real poles (e.g. the amplifier's lag) as corner frequencies, Hz (provenance:
    /// the denominator holds them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub real_pole_hz: Vec<f64>,
    /// Voltage → stage output, µm/V.
    pub transfer_function: TransferFunction,
    /// Static gain against the drive's span (eq. 13).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voltage_gain: Option<VoltageGain>,
    /// How the file was made and how well it fits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitInfo>,
}

fn format_tag() -> String {
    FORMAT.to_string()
}

/// A continuous-time rational transfer function in `s` (rad/s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransferFunction {
    /// Numerator coefficients, highest power of `s` first.
    pub numerator: Vec<f64>,
    /// Denominator coefficients, highest power of `s` first.
    pub denominator: Vec<f64>,
}

/// Eq. 13: the static gain of the stage against the drive's span.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VoltageGain {
    /// Drive span (peak to peak) of each chirp, V.
    pub span_v: Vec<f64>,
    /// Static gain measured on each chirp, µm/V.
    pub gain_um_per_v: Vec<f64>,
    /// `gain(V) = c0 + c1·V + c2·V²` (lowest power first; as many terms as the
    /// chirps allow, at most three), µm/V with V the span in volts.
    pub coefficients: Vec<f64>,
}

impl VoltageGain {
    /// The fitted gain at drive span `span_v` (V), µm/V.
    pub fn at(&self, span_v: f64) -> f64 {
        self.coefficients
            .iter()
            .rev()
            .fold(0.0, |acc, c| acc * span_v + c)
    }
}

/// Provenance and fit quality of an identification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitInfo {
    /// The chirps identified from.
    pub files: Vec<String>,
    /// Frequency band of the fitted points, Hz.
    pub band_hz: [f64; 2],
    /// Frequency points fitted.
    pub points: usize,
    /// The order criterion, in words.
    pub criterion: String,
    /// Modes and real poles of the chosen structure.
    pub modes: usize,
    /// Real poles of the chosen structure (the amplifier lag).
    pub real_poles: usize,
    /// Weighted RMS relative output error of the chosen model (the criterion's
    /// value).
    pub rms_relative_error: f64,
    /// Akaike's criterion of the chosen model (for comparison only).
    pub aic: f64,
    /// Weighted RMS relative error of the capacitive current model.
    pub current_rms_relative_error: f64,
}

impl Dynamics {
    /// Reads and validates a dynamics file; errors name the file and the key.
    pub fn read(path: &Path) -> Result<Self> {
        toml_file::read(path)
    }

    /// A dynamics file from its text; `name` names it in errors.
    pub fn parse(text: &str, name: &str) -> Result<Self> {
        toml_file::parse(text, name)
    }

    /// Writes the file atomically after [`validate`](Self::validate).
    pub fn write(&self, path: &Path) -> Result<()> {
        toml_file::write(self, path)
    }

    /// Checks every key; the error names the key and its value.
    pub fn validate(&self) -> Result<()> {
        self.check_format()?;
        let tf = &self.transfer_function;
        check_poly("transfer_function.denominator", &tf.denominator)?;
        check_poly("transfer_function.numerator", &tf.numerator)?;
        if tf.numerator.len() > tf.denominator.len() {
            bail!(
                "transfer_function.numerator: degree {} above the denominator's {} (not proper)",
                tf.numerator.len() - 1,
                tf.denominator.len() - 1
            );
        }
        let poles = tf.poles();
        if let Some(p) = poles.iter().find(|p| p.re >= 0.0 || p.re.is_nan()) {
            bail!(
                "transfer_function.denominator: unstable, pole {:.6e}{:+.6e}j rad/s",
                p.re,
                p.im
            );
        }
        positive("capacitance_uf", self.capacitance_uf)?;
        self.check_gain()?;
        self.check_modes(&poles)?;
        for (i, &f) in self.real_pole_hz.iter().enumerate() {
            positive(&format!("real_pole_hz[{i}]"), f)?;
        }
        if let Some(g) = &self.voltage_gain {
            g.validate()?;
        }
        Ok(())
    }

    /// `dc_gain_um_per_v`: finite, non-zero, and the transfer function's.
    fn check_gain(&self) -> Result<()> {
        let g = self.dc_gain_um_per_v;
        if !g.is_finite() || g == 0.0 {
            bail!("dc_gain_um_per_v = {g}: must be finite and non-zero");
        }
        let tf = self.transfer_function.dc_gain();
        if (tf - g).abs() > 1e-6 * g.abs() {
            bail!("dc_gain_um_per_v = {g}: the transfer function's DC gain is {tf}");
        }
        Ok(())
    }

    /// The listed modes: as many frequencies as damping ratios, each positive,
    /// lowest first, and each a pole pair of the denominator.
    fn check_modes(&self, poles: &[Complex<f64>]) -> Result<()> {
        let (f, z) = (&self.natural_frequency_hz, &self.damping_ratio);
        if f.len() != z.len() {
            bail!(
                "damping_ratio: {} values for {} natural_frequency_hz",
                z.len(),
                f.len()
            );
        }
        for (i, (&fi, &zi)) in f.iter().zip(z).enumerate() {
            positive(&format!("natural_frequency_hz[{i}]"), fi)?;
            positive(&format!("damping_ratio[{i}]"), zi)?;
            if i > 0 && fi < f[i - 1] {
                bail!(
                    "natural_frequency_hz[{i}] = {fi}: below the previous mode's {} Hz \
                     (lowest first)",
                    f[i - 1]
                );
            }
            let found = modes_of(poles).iter().any(|&(fm, zm)| {
                (fm - fi).abs() <= MODE_TOLERANCE * fi && (zm - zi).abs() <= MODE_TOLERANCE * zi
            });
            if !found {
                bail!(
                    "natural_frequency_hz[{i}] = {fi}, damping_ratio[{i}] = {zi}: no pole pair \
                     of transfer_function.denominator has them (its modes: {})",
                    describe_modes(&modes_of(poles))
                );
            }
        }
        Ok(())
    }

    /// The transfer function's response at `f_hz`, µm/V.
    pub fn response(&self, f_hz: f64) -> Complex<f64> {
        self.transfer_function
            .at(Complex::new(0.0, 2.0 * std::f64::consts::PI * f_hz))
    }

    /// The dynamics with unit DC gain, discretised for sample interval `dt_s`
    /// ([`Discrete::tustin`]).
    pub fn discretise(&self, dt_s: f64) -> Result<Discrete> {
        let prewarp = self.natural_frequency_hz.first().copied();
        Discrete::tustin(&self.transfer_function.unit_dc(), dt_s, prewarp)
    }

    /// The Hammerstein step: the rate-independent stage output `x` (µm, sampled
    /// every `dt_s`) through the unit-DC-gain dynamics, starting at rest at `x[0]`.
    ///
    /// The dynamics keep their low-frequency delay (about 80 µs on stage A, the
    /// amplifier's lag). The rate-independent model was calibrated on rig
    /// recordings made through the same amplifier, and its hysteresis absorbed
    /// part of that delay as a phase: on slow drives the two together lag the
    /// stage slightly (see the book's `docs/src/measured-figures.md`), on fast
    /// ones the delay is what the stage does.
    pub fn apply(&self, x: &[f64], dt_s: f64) -> Result<Vec<f64>> {
        Ok(self.discretise(dt_s)?.filter(x))
    }
}

impl VoltageGain {
    fn validate(&self) -> Result<()> {
        if self.span_v.len() != self.gain_um_per_v.len() {
            bail!(
                "voltage_gain.gain_um_per_v: {} values for {} span_v",
                self.gain_um_per_v.len(),
                self.span_v.len()
            );
        }
        if self.coefficients.is_empty() || self.coefficients.len() > 3 {
            bail!(
                "voltage_gain.coefficients: {} values (1 to 3)",
                self.coefficients.len()
            );
        }
        let all = [
            ("span_v", &self.span_v),
            ("gain_um_per_v", &self.gain_um_per_v),
            ("coefficients", &self.coefficients),
        ];
        for (key, v) in all {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                bail!("voltage_gain.{key}[{i}] = {}: not a finite number", v[i]);
            }
        }
        Ok(())
    }
}

/// `key = v` must be finite and > 0.
fn positive(key: &str, v: f64) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        bail!("{key} = {v}: must be a finite number > 0");
    }
    Ok(())
}

/// A polynomial key: 1..=[`MAX_ORDER`]+1 finite coefficients, the first non-zero.
fn check_poly(key: &str, c: &[f64]) -> Result<()> {
    if c.is_empty() || c.len() > MAX_ORDER + 1 {
        bail!(
            "{key}: {} coefficients (1 to {} expected)",
            c.len(),
            MAX_ORDER + 1
        );
    }
    if let Some(i) = c.iter().position(|x| !x.is_finite()) {
        bail!("{key}[{i}] = {}: not a finite number", c[i]);
    }
    if c[0] == 0.0 {
        bail!("{key}[0] = 0: the leading coefficient must be non-zero");
    }
    Ok(())
}

impl TomlFile for Dynamics {
    const WHAT: &'static str = "dynamics file";
    const MAX_BYTES: u64 = MAX_FILE_BYTES;
    const FORMAT: &'static str = FORMAT;
    fn format(&self) -> &str {
        &self.format
    }
    fn check(&self) -> Result<()> {
        self.validate()
    }
    fn header(&self) -> String {
        "# Stage dynamics identified by `fpi identify` (voltage -> x_fhps_um).\n\
         # transfer_function: s in rad/s, highest power first, µm/V.\n"
            .to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn second_order(f: f64, z: f64, k: f64) -> TransferFunction {
        let w = 2.0 * std::f64::consts::PI * f;
        TransferFunction {
            numerator: vec![k * w * w],
            denominator: vec![1.0, 2.0 * z * w, w * w],
        }
    }

    #[test]
    fn roots_of_a_lightly_damped_mode() {
        let tf = second_order(850.0, 0.02, 0.3);
        let m = modes_of(&tf.poles());
        assert_eq!(m.len(), 1);
        assert!((m[0].0 - 850.0).abs() < 1e-6 && (m[0].1 - 0.02).abs() < 1e-9);
    }

    #[test]
    fn tustin_keeps_the_dc_gain_and_the_mode() {
        let tf = second_order(850.0, 0.02, 0.3).unit_dc();
        let d = Discrete::tustin(&tf, 5e-5, Some(850.0)).unwrap();
        let y = d.filter(&vec![2.0; 100]);
        assert!(y.iter().all(|v| (v - 2.0).abs() < 1e-12), "{y:?}");
        // A step rings at the mode: the first peak after about half a period.
        let mut u = vec![0.0; 4000];
        u[1..].iter_mut().for_each(|v| *v = 1.0);
        let y = d.filter(&u);
        let peak = (1..200).max_by(|&a, &b| y[a].total_cmp(&y[b])).unwrap();
        let t_peak = peak as f64 * 5e-5;
        assert!((t_peak - 0.5 / 850.0).abs() < 1e-4, "{t_peak}");
        assert!((y[3999] - 1.0).abs() < 1e-3);
    }

    #[test]
    fn uniform_steps() {
        assert_eq!(uniform_step(&[0.0, 0.5, 1.0]), Ok(0.5));
        assert!(uniform_step(&[0.0, 0.5, 1.5, 2.0]).is_err());
    }
}
