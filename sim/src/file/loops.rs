//! The loops' sections of the firmware model file: the stage's dynamics, the
//! active damping, the reference shaping and the position feedback.

use piezo_fpi::biquad::{ShapingSpec, COEFF_ABS_MAX, COEFF_FRAC, SHAPING_SECTIONS};
use piezo_fpi::control::Interval;
use piezo_fpi::damping::{DampingSpec, DynamicsSpec};
use piezo_fpi::feedback::FeedbackSpec;
use piezo_fpi::fields::Field;
use piezo_fpi::preview::TAPS;
use piezo_fpi::q::{self, CreepRate, LeadRatio, LoopGain, Micrometres};
use serde::{Deserialize, Serialize};

use super::sections::{rate_per_tick, signal, within};
use crate::quote::Num;

/// The stage's first mode as the loops see it from the command (µm in, the
/// position sensor and the force channel's dynamic part out).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DynamicsSection {
    /// Declared as [`Field::DynamicsModeHz`](piezo_fpi::fields::Field::DynamicsModeHz).
    pub mode_hz: f64,
    /// Declared as [`Field::DynamicsDamping`](piezo_fpi::fields::Field::DynamicsDamping).
    pub damping_ratio: f64,
    /// Declared as [`Field::DynamicsLagHz`](piezo_fpi::fields::Field::DynamicsLagHz).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lag_hz: Option<f64>,
    /// Declared as [`Field::DynamicsForceGain`](piezo_fpi::fields::Field::DynamicsForceGain).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_gain_n_per_um: Option<f64>,
    /// Where the numbers came from.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl DynamicsSection {
    pub(super) fn quantize(&self) -> Result<DynamicsSpec, String> {
        let mhz = |key: Field, v: f64| -> Result<u32, String> {
            if v.is_finite() && v > 0.0 && v < 4.0e6 {
                Ok((v * 1000.0).round() as u32)
            } else {
                Err(format!(
                    "{key} = {}: not a positive frequency below 4 MHz",
                    Num(v)
                ))
            }
        };
        let ratio = |key: Field, v: f64| {
            q::quantize(v, q::COUPLING_FRAC, q::COUPLING_ABS_MAX)
                .map(CreepRate::from_bits)
                .ok_or_else(|| {
                    format!("{key} = {}: not a finite value within ±0.5 (I0F32)", Num(v))
                })
        };
        Ok(DynamicsSpec {
            mode_mhz: mhz(Field::DynamicsModeHz, self.mode_hz)?,
            damping: ratio(Field::DynamicsDamping, self.damping_ratio)?,
            lag_mhz: self
                .lag_hz
                .map(|v| mhz(Field::DynamicsLagHz, v))
                .transpose()?
                .unwrap_or(0),
            force_gain: signal(
                Field::DynamicsForceGain,
                self.force_gain_n_per_um.unwrap_or(0.0),
            )?,
        })
    }
}

/// Active damping: integral force feedback on the force channel's dynamic part,
/// in a band (`C(s) ≈ g·s/((s + ω_h)(s + ω_l))`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DampingSection {
    /// Declared as [`Field::DampingGain`](piezo_fpi::fields::Field::DampingGain).
    pub gain_um_per_n_s: f64,
    /// Declared as [`Field::DampingHighpass`](piezo_fpi::fields::Field::DampingHighpass).
    pub highpass_hz: f64,
    /// Declared as [`Field::DampingLeak`](piezo_fpi::fields::Field::DampingLeak).
    pub leak_hz: f64,
    /// Declared as [`Field::DampingLimit`](piezo_fpi::fields::Field::DampingLimit).
    pub limit_um: f64,
    /// Declared as [`Field::LeadBaseline`](piezo_fpi::fields::Field::LeadBaseline).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lead_baseline: Option<f64>,
    /// How the gains were chosen (what the tuning assumed and the margins it got).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl DampingSection {
    pub(super) fn quantize(&self, rate_hz: u32) -> Result<DampingSpec, String> {
        let fs = rate_hz.max(1) as f64;
        let g = self.gain_um_per_n_s / fs;
        let gain = q::quantize(g, q::LOOP_GAIN_FRAC, 127.9)
            .map(LoopGain::from_bits)
            .ok_or_else(|| {
                format!(
                    "damping.gain_um_per_n_s = {}: not a finite value within ±{} µm/(N·s) \
                     (±128 µm/N per control tick at controller.rate_hz = {rate_hz}, I8F24)",
                    Num(self.gain_um_per_n_s),
                    Num(128.0 * fs)
                )
            })?;
        Ok(DampingSpec {
            gain,
            highpass: rate_per_tick(Field::DampingHighpass, self.highpass_hz, fs)?,
            leak: rate_per_tick(Field::DampingLeak, self.leak_hz, fs)?,
            limit: signal(Field::DampingLimit, self.limit_um)?,
        })
    }

    /// The lead's baseline in its format, `I2F30`, if the section has one.
    pub(super) fn lead(&self) -> Result<Option<LeadRatio>, String> {
        self.lead_baseline
            .map(|b| within(Field::LeadBaseline, b).map(LeadRatio::from_num))
            .transpose()
    }
}

fn is_zero(v: &u8) -> bool {
    *v == 0
}

/// The reference-shaping filter: up to two second-order sections at the control
/// rate, `y = b0·x + b1·x₁ + b2·x₂ − a1·y₁ − a2·y₂`, each of static gain 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ShapingSection {
    /// Declared as [`Field::Shaping`](piezo_fpi::fields::Field::Shaping).
    pub sections: Vec<[f64; 5]>,
    /// Declared as [`Field::PreviewTicks`](piezo_fpi::fields::Field::PreviewTicks).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub preview_ticks: u8,
    /// Declared as [`Field::Preview`](piezo_fpi::fields::Field::Preview).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub taps: Vec<f64>,
    /// What the filter cancels (the modes, the damping it leaves).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl ShapingSection {
    /// The sections in the core's format (`I8F24`), the missing ones the identity.
    pub(super) fn quantize(&self) -> Result<ShapingSpec, String> {
        if self.sections.len() > SHAPING_SECTIONS {
            return Err(format!(
                "shaping.sections has {} sections: the board runs at most {SHAPING_SECTIONS}",
                self.sections.len()
            ));
        }
        within(Field::PreviewTicks, f64::from(self.preview_ticks))?;
        let mut out = ShapingSpec {
            preview: self.preview_ticks,
            ..ShapingSpec::IDENTITY
        };
        match (self.preview_ticks, self.sections.is_empty(), self.taps.len()) {
            (0, _, 0) => {}
            (0, _, _) => return Err("shaping.taps: taps run with preview_ticks > 0".into()),
            (_, false, _) => {
                return Err(
                    "shaping.sections: a shaping that runs ahead (preview_ticks > 0) is its taps, not sections"
                        .into(),
                )
            }
            (_, true, n) if n > TAPS => {
                return Err(format!(
                    "shaping.taps has {n} taps: the board runs at most {TAPS}"
                ))
            }
            _ => {}
        }
        for (j, (&v, o)) in self.taps.iter().zip(out.taps.iter_mut()).enumerate() {
            *o = q::quantize(v, COEFF_FRAC, COEFF_ABS_MAX).ok_or_else(|| {
                format!(
                    "shaping.taps[{j}] = {}: not a finite value within ±128 (I8F24)",
                    Num(v)
                )
            })?;
        }
        for (i, (s, o)) in self
            .sections
            .iter()
            .zip(out.sections.iter_mut())
            .enumerate()
        {
            for (j, (&v, o)) in s.iter().zip(o.iter_mut()).enumerate() {
                *o = q::quantize(v, COEFF_FRAC, COEFF_ABS_MAX).ok_or_else(|| {
                    format!(
                        "shaping.sections[{i}][{j}] = {}: not a finite value within ±128 (I8F24)",
                        Num(v)
                    )
                })?;
            }
        }
        Ok(out)
    }
}

/// Position-feedback settings: the PI law's gains and the sensor's supervision.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FeedbackSection {
    /// Declared as [`Field::FeedbackKp`](piezo_fpi::fields::Field::FeedbackKp).
    pub kp: f64,
    /// Declared as [`Field::FeedbackKi`](piezo_fpi::fields::Field::FeedbackKi).
    pub ki_per_s: f64,
    /// Declared as [`Field::FeedbackLimit`](piezo_fpi::fields::Field::FeedbackLimit).
    pub limit_um: f64,
    /// Declared as [`Field::PositionMin`](piezo_fpi::fields::Field::PositionMin).
    pub position_min_um: f64,
    /// Declared as [`Field::PositionMax`](piezo_fpi::fields::Field::PositionMax).
    pub position_max_um: f64,
    /// Declared as [`Field::PositionTolerance`](piezo_fpi::fields::Field::PositionTolerance).
    pub position_tolerance_um: f64,
    /// Declared as [`Field::WatchSwing`](piezo_fpi::fields::Field::WatchSwing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub watch_swing_um: Option<f64>,
    /// How the gains were chosen (what `fpi tune` assumed and the margins it got).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl FeedbackSection {
    /// The settings in the core's formats at `rate_hz` (ranges only; the core's
    /// validator checks the rest).
    pub(super) fn quantize(&self, rate_hz: u32) -> Result<FeedbackSpec, String> {
        let fs = rate_hz.max(1) as f64;
        let loop_gain = |v: f64| q::quantize(v, q::LOOP_GAIN_FRAC, 127.9).map(LoopGain::from_bits);
        Ok(FeedbackSpec {
            kp: loop_gain(self.kp).ok_or_else(|| {
                format!(
                    "feedback.kp = {}: not a finite value within ±128 (I8F24)",
                    Num(self.kp)
                )
            })?,
            ki: loop_gain(self.ki_per_s / fs).ok_or_else(|| {
                format!(
                    "feedback.ki_per_s = {}: not a finite value within ±{} /s (±128 per control \
                     tick at controller.rate_hz = {rate_hz}, I8F24)",
                    Num(self.ki_per_s),
                    Num(128.0 * fs)
                )
            })?,
            limit: signal(Field::FeedbackLimit, self.limit_um)?,
            sensor: Interval {
                lo: signal(Field::PositionMin, self.position_min_um)?,
                hi: signal(Field::PositionMax, self.position_max_um)?,
            },
            tolerance: signal(Field::PositionTolerance, self.position_tolerance_um)?,
        })
    }

    /// The watch's half swing in its format, `I16F16` µm, if the section has one.
    pub(super) fn watch_swing(&self) -> Result<Option<Micrometres>, String> {
        self.watch_swing_um
            .map(|h| signal(Field::WatchSwing, h))
            .transpose()
    }
}
