//! Dynamic compensation for the firmware: from the identified dynamics
//! (`fpi identify`, [`super::dynamics`]) to the firmware model's reference-shaping
//! filter and its slew limit (`fpi export --dynamics`).
//!
//! The stage is a Hammerstein chain — hysteresis, then linear dynamics — so its
//! inverse runs the other way round: the reference first goes through the inverse
//! of the dynamics' lightly damped modes, then through the inverse FPI. Each mode
//! (up to two, lowest first) gets the section
//! `(s² + 2ζω s + ω²)·(ω_d/ω)² / (s² + 2ζ_d ω_d s + ω_d²)`: its zeros cancel the
//! mode's poles and leave a pair at `ω_d` (the mode's frequency by default) damped at
//! `ζ_d` (0.7), of unit static gain, discretised at the control rate by Tustin
//! pre-warped at the mode. The price is lag: the compensated pair delays a ramp by
//! `2ζ_d/ω_d` (0.26 ms at 850 Hz with `ω_d = ω`, the default: 1.7 µm on a 100 Hz
//! triangle over 32 µm). A faster pair lags less but asks for a sharper drive and
//! larger coefficients: at 850 Hz and 20 kHz, `ω_d = 1.5 ω` already needs
//! coefficients beyond the firmware's `I2F30` range (±2) and is refused. The amplifier's lag (the identified real pole) is left
//! alone: inverting it would ask for more slew than the amplifier has.
//!
//! With the amplifier's current limit `I_max` the stack's capacitance `C` (eq.
//! 14) bounds the slew to `I_max / C`; the model carries both
//! (`controller.current_limit_ma`, `controller.capacitance_uf`) and the firmware
//! enforces the lower of that and the slew setting per tick.

use anyhow::{anyhow, bail, Result};
use piezo_fpi::biquad::SHAPING_SECTIONS;
use piezo_sim::file::{FirmwareModel, ShapingSection};
use piezo_sim::filter::Section;

use super::dynamics::Dynamics;

/// Default damping of the compensated modes.
pub const DAMPING: f64 = 0.7;
/// Default `ω_d / ω`.
pub const SPEED_UP: f64 = 1.0;

/// `(s² + 2ζω s + ω²)·(ω_d/ω)² / (s² + 2ζ_d ω_d s + ω_d²)` at `fs_hz`, Tustin
/// pre-warped at the mode: unit static gain, the mode's poles cancelled, a pair
/// at `ω_d = speed_up·ω` damped at `ζ_d` in their place.
fn mode_inverse(f_hz: f64, zeta: f64, zeta_d: f64, speed_up: f64, fs_hz: f64) -> Option<Section> {
    let w = 2.0 * std::f64::consts::PI * f_hz;
    let wd = speed_up * w;
    let g = (wd / w).powi(2);
    if speed_up.is_nan() || speed_up < 1.0 || wd >= std::f64::consts::PI * fs_hz {
        return None;
    }
    Section::bilinear(
        [g, g * 2.0 * zeta * w, g * w * w],
        [1.0, 2.0 * zeta_d * wd, wd * wd],
        f_hz,
        fs_hz,
    )
}

/// What the shaping is asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapingOptions {
    /// Damping ratio the compensated modes get.
    pub damping: f64,
    /// How much faster than the mode the compensated pair is (`ω_d / ω`, ≥ 1):
    /// faster leaves less lag on a ramp, at the price of a sharper drive.
    pub speed_up: f64,
    /// The amplifier's current limit, mA (`None`: no slew bound from it).
    pub current_limit_ma: Option<f64>,
}

impl Default for ShapingOptions {
    fn default() -> Self {
        Self {
            damping: DAMPING,
            speed_up: SPEED_UP,
            current_limit_ma: None,
        }
    }
}

/// `fw` with the shaping filter for `d`'s modes and, with a current limit, the
/// capacitance for the slew bound; checked by the core's validator.
pub fn with_dynamics(
    fw: &FirmwareModel,
    d: &Dynamics,
    o: &ShapingOptions,
) -> Result<FirmwareModel> {
    if !(o.damping > 0.0 && o.damping <= 2.0) {
        bail!("--damping {}: a damping ratio in (0, 2]", o.damping);
    }
    if !(o.speed_up >= 1.0 && o.speed_up <= 8.0) {
        bail!("--speed-up {}: between 1 and 8", o.speed_up);
    }
    let rate = fw.controller.rate_hz as f64;
    let mut sections = Vec::new();
    let mut cancelled = Vec::new();
    for (&f, &z) in d.natural_frequency_hz.iter().zip(&d.damping_ratio) {
        if sections.len() == SHAPING_SECTIONS || z >= o.damping || f >= 0.45 * rate {
            continue;
        }
        let s = mode_inverse(f, z, o.damping, o.speed_up, rate)
            .ok_or_else(|| anyhow!("the mode at {f} Hz (ζ {z}) has no inverse at {rate} Hz"))?;
        let q = s.quantise().map_err(|e| {
            anyhow!(
                "the mode at {f} Hz: {} (a faster pair needs larger coefficients: try a \
                     smaller --speed-up)",
                e.message()
            )
        })?;
        let s = Section::of_quantised(&q);
        sections.push([s.b[0], s.b[1], s.b[2], s.a[0], s.a[1]]);
        cancelled.push(format!("{f:.1} Hz (ζ {z:.4})"));
    }
    let mut out = fw.clone();
    out.shaping = (!sections.is_empty()).then(|| ShapingSection {
        sections,
        preview_ticks: 0,
        taps: Vec::new(),
        notes: format!(
            "fpi export --dynamics: the inverse of the mode(s) at {} leaving a pair {}× faster \
             at ζ = {} (Tustin at {rate} Hz, pre-warped at each mode)",
            cancelled.join(", "),
            o.speed_up,
            o.damping
        ),
    });
    if let Some(i) = o.current_limit_ma {
        if !(i > 0.0 && i.is_finite()) {
            bail!("--current-limit-ma {i}: a positive current");
        }
        out.controller.current_limit_ma = Some(i);
        out.controller.capacitance_uf = Some(d.capacitance_uf);
    }
    out.check().map_err(anyhow::Error::msg)?;
    Ok(out)
}

/// The shaping's group delay at low frequency, ms: `Σ 2ζ_d/ω_d − 2ζ/ω` over the
/// modes [`with_dynamics`] cancels (what a slow ramp lags by).
pub fn delay_ms(d: &Dynamics, o: &ShapingOptions, rate_hz: f64) -> f64 {
    d.natural_frequency_hz
        .iter()
        .zip(&d.damping_ratio)
        .filter(|(&f, &z)| z < o.damping && f < 0.45 * rate_hz)
        .take(SHAPING_SECTIONS)
        .map(|(&f, &z)| {
            let w = 2.0 * std::f64::consts::PI * f;
            1e3 * (2.0 * o.damping / (o.speed_up * w) - 2.0 * z / w)
        })
        .sum()
}

/// One line on what [`with_dynamics`] added, for the terminal.
pub fn describe(fw: &FirmwareModel) -> String {
    let mut s = match &fw.shaping {
        Some(sh) => format!("reference shaping: {}", sh.notes),
        None => "reference shaping: none (no lightly damped mode below the control rate)".into(),
    };
    let k = &fw.controller;
    if let (Some(i), Some(c)) = (k.current_limit_ma, k.capacitance_uf) {
        let slew = k.slew_limit_v_per_ms().unwrap_or(k.slew_v_per_ms);
        s.push_str(&format!(
            "; slew limit {slew:.2} V/ms (I_max {i} mA / C {c:.4} µF = {:.2} V/ms, setting {} V/ms)",
            i / c,
            k.slew_v_per_ms
        ));
    }
    s
}
