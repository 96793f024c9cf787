//! The firmware model file (TOML, engineering units): what `fpi export` writes,
//! `firmware/build.rs` embeds, and (through the core's format) the board accepts.
//!
//! Every value is an engineering value (V, µm, N, µm/V, V/N, µm/N); tables are
//! sampled on uniform grids with a power-of-two spacing `2^step_log2` in the input
//! unit. Reading a file checks it in two steps, with errors that name the file and
//! the key:
//!
//! 1. [`FirmwareModel::quantize`] — every value fits its Q format (the core's
//!    `q` module): `pi.thresholds_v[3] = 5000: not a finite value within ±4096`;
//! 2. the core's validator, [`piezo_fpi::model::validate`] — the one check of a
//!    model, which the board's model upload runs too:
//!    `tables.f_f.step_log2 = -16: table knot spacing outside …`.
//!
//! [`FirmwareModel::float_model`] and [`FirmwareModel::controller`] give the same
//! model in floating point, the reference the fixed-point core is measured against.

use std::fmt::Write as _;
use std::string::{String, ToString};
use std::vec::Vec;

use fixed::types::I16F16;
use piezo_fpi::biquad::{ShapingSpec, COEFF_ABS_MAX, COEFF_FRAC, SHAPING_SECTIONS};
use piezo_fpi::control::{ForceChannel, ForceSource, Interval, Supervision, DEFAULT_SPLIT_HZ};
use piezo_fpi::damping::{DampingSpec, DynamicsSpec};
use piezo_fpi::error::{Field, Invalid, ModelError, TableId, TablePart};
use piezo_fpi::feedback::FeedbackSpec;
use piezo_fpi::fpi::Coupling as FixedCoupling;
use piezo_fpi::model::{validate, CreepSpec, MapSpec, ModelSpec, Shape, TableSpec};
use piezo_fpi::play::Operator;
use piezo_fpi::preview::{PREVIEW_MAX, TAPS};
use piezo_fpi::q::{self, CreepRate, LoopGain, UmPerVolt, VoltsPerNewton};
use piezo_fpi::table::Segment;
use serde::{Deserialize, Serialize};

use crate::control::Controller;
use crate::curve::Curve;
use crate::maps::TableMap;
use crate::model::{lag_rate, Coupling, Creep, DeadZone, Model, Output};
use crate::play::Pi;
use crate::quote::toml_error;

/// The default dynamic force limit, in force tolerances
/// (`controller.force_dynamic_limit_n`).
pub const DYNAMIC_LIMIT_FACTOR: f64 = 4.0;

/// The `format` string this schema reads and writes.
pub const FORMAT: &str = "piezo-fpi-firmware/1";

/// A whole firmware model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FirmwareModel {
    /// Always [`FORMAT`].
    pub format: String,
    /// Where the numbers came from.
    pub provenance: Provenance,
    /// The forward PI model of the stack.
    pub pi: PiSection,
    /// The FPI force coupling.
    pub coupling: CouplingSection,
    /// The soft dead zone `û = g(u - U_p(F))`; absent: the hard one, `max(·, 0)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dead_zone: Option<MapSection>,
    /// The output saturation `z = h(Y)`; absent: the identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation: Option<MapSection>,
    /// Creep: first-order lags of the effective voltage, added to `Y`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub creep: Vec<CreepSection>,
    /// The control loop: rate, limits, fault thresholds.
    pub controller: ControllerSection,
    /// FEM-derived lookup tables.
    pub tables: Tables,
    /// Position feedback on a stage-position sensor (`fpi tune`); absent: the
    /// board runs open loop only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feedback: Option<FeedbackSection>,
    /// Reference shaping: the stable inverse of the stage's lightly damped modes,
    /// run on the reference before the inverse FPI (`fpi export --dynamics`);
    /// absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shaping: Option<ShapingSection>,
    /// The stage's dynamics as the loops see them (`fpi tune`, `fpi board
    /// autotune`): what the board checks its loops and waveforms against; absent:
    /// not declared.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dynamics: Option<DynamicsSection>,
    /// Active damping of the first mode from the force sensor (`fpi tune`, `fpi
    /// board autotune`); absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<DampingSection>,
}

/// The stage's first mode as the loops see it from the command (µm in, the
/// position sensor and the force channel's dynamic part out).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DynamicsSection {
    /// Natural frequency of the first mode, small-signal, undamped, Hz.
    pub mode_hz: f64,
    /// Its damping ratio (0–0.5).
    pub damping_ratio: f64,
    /// The amplifier's and sensors' lag as a real pole, Hz (absent: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lag_hz: Option<f64>,
    /// κ: the dynamic force per µm of command well above the mode, N/µm (absent:
    /// not measured; active damping needs it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_gain_n_per_um: Option<f64>,
    /// Where the numbers came from.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl DynamicsSection {
    fn quantize(&self) -> Result<DynamicsSpec, String> {
        let mhz = |key: &str, v: f64| -> Result<u32, String> {
            if v.is_finite() && v > 0.0 && v < 4.0e6 {
                Ok((v * 1000.0).round() as u32)
            } else {
                Err(format!("{key} = {v}: not a positive frequency below 4 MHz"))
            }
        };
        let ratio = |key: &str, v: f64| {
            q::quantize(v, q::COUPLING_FRAC, q::COUPLING_ABS_MAX)
                .map(CreepRate::from_bits)
                .ok_or_else(|| format!("{key} = {v}: not a finite value within ±0.5 (I0F32)"))
        };
        Ok(DynamicsSpec {
            mode_mhz: mhz("dynamics.mode_hz", self.mode_hz)?,
            damping: ratio("dynamics.damping_ratio", self.damping_ratio)?,
            lag_mhz: self
                .lag_hz
                .map(|v| mhz("dynamics.lag_hz", v))
                .transpose()?
                .unwrap_or(0),
            force_gain: signal(
                "dynamics.force_gain_n_per_um",
                self.force_gain_n_per_um.unwrap_or(0.0),
            )?,
        })
    }
}

/// Active damping: integral force feedback on the force channel's dynamic part,
/// in a band (`C(s) ≈ g·s/((s + ω_h)(s + ω_l))`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingSection {
    /// IFF gain: µm of command per N·s of dynamic force.
    pub gain_um_per_n_s: f64,
    /// Corner of the high-pass below which the law stops integrating, Hz (> 0).
    pub highpass_hz: f64,
    /// Corner of the integrator's leak, Hz (> 0).
    pub leak_hz: f64,
    /// Largest correction the damping adds to the command, µm.
    pub limit_um: f64,
    /// How the gains were chosen (what the tuning assumed and the margins it got).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl DampingSection {
    fn quantize(&self, rate_hz: u32) -> Result<DampingSpec, String> {
        let fs = rate_hz.max(1) as f64;
        let g = self.gain_um_per_n_s / fs;
        let gain = q::quantize(g, q::LOOP_GAIN_FRAC, 127.9)
            .map(LoopGain::from_bits)
            .ok_or_else(|| {
                format!(
                    "damping.gain_um_per_n_s = {}: not a finite value within ±128 µm/N per tick (I8F24)",
                    self.gain_um_per_n_s
                )
            })?;
        Ok(DampingSpec {
            gain,
            highpass: rate_per_tick("damping.highpass_hz", self.highpass_hz, fs)?,
            leak: rate_per_tick("damping.leak_hz", self.leak_hz, fs)?,
            limit: signal("damping.limit_um", self.limit_um)?,
        })
    }
}

/// `1 − e^{−2π·f/f_s}` in `I0F32` for a corner `f` (Hz, ≥ 0) at `f_s`; errors
/// name `key`.
fn rate_per_tick(key: &str, f_hz: f64, fs: f64) -> Result<CreepRate, String> {
    if !(f_hz.is_finite() && f_hz >= 0.0 && f_hz * 64.0 <= fs) {
        return Err(format!(
            "{key} = {f_hz}: not a corner between 0 and f_s/64 = {} Hz",
            fs / 64.0
        ));
    }
    let a = -(-2.0 * std::f64::consts::PI * f_hz / fs).exp_m1();
    q::quantize(a, q::COUPLING_FRAC, q::COUPLING_ABS_MAX)
        .map(CreepRate::from_bits)
        .ok_or_else(|| format!("{key} = {f_hz}: does not fit its Q format"))
}

fn is_zero(v: &u8) -> bool {
    *v == 0
}

/// The reference-shaping filter: up to two second-order sections at the control
/// rate, `y = b0·x + b1·x₁ + b2·x₂ − a1·y₁ − a2·y₂`, each of static gain 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapingSection {
    /// `[b0, b1, b2, a1, a2]` of each section (at most two), dimensionless.
    pub sections: Vec<[f64; 5]>,
    /// Ticks the shaping runs ahead of the reference the loops track (0–7; 0:
    /// none): it is then `taps` on the preview's delay line, not sections (see
    /// `piezo_fpi::preview`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub preview_ticks: u8,
    /// The taps on the delay line, newest first (at most 8, summing to 1),
    /// with `preview_ticks > 0`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub taps: Vec<f64>,
    /// What the filter cancels (the modes, the damping it leaves).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl ShapingSection {
    /// The sections in the core's format (`I8F24`), the missing ones the identity.
    fn quantize(&self) -> Result<ShapingSpec, String> {
        if self.sections.len() > SHAPING_SECTIONS {
            return Err(format!(
                "shaping.sections has {} sections: the board runs at most {SHAPING_SECTIONS}",
                self.sections.len()
            ));
        }
        if self.preview_ticks > PREVIEW_MAX {
            return Err(format!(
                "shaping.preview_ticks = {}: the board looks ahead at most {PREVIEW_MAX} ticks",
                self.preview_ticks
            ));
        }
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
                format!("shaping.taps[{j}] = {v}: not a finite value within ±128 (I8F24)")
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
                        "shaping.sections[{i}][{j}] = {v}: not a finite value within ±128 (I8F24)"
                    )
                })?;
            }
        }
        Ok(out)
    }
}

/// Position-feedback settings: the PI law's gains and the sensor's supervision.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeedbackSection {
    /// Proportional gain, µm per µm of error (0–16).
    pub kp: f64,
    /// Integral gain, per second (`ki_per_s / rate_hz` per tick, 0–1 per tick).
    pub ki_per_s: f64,
    /// Largest correction the feedback adds to the reference, µm.
    pub limit_um: f64,
    /// Lowest plausible position reading, µm.
    pub position_min_um: f64,
    /// Highest plausible position reading, µm.
    pub position_max_um: f64,
    /// Largest tolerated `|x_sensor − f_K(x̂_pea)|`, µm.
    pub position_tolerance_um: f64,
    /// How the gains were chosen (what `fpi tune` assumed and the margins it got).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub notes: String,
}

impl FeedbackSection {
    /// The settings in the core's formats at `rate_hz` (ranges only; the core's
    /// validator checks the rest).
    fn quantize(&self, rate_hz: u32) -> Result<FeedbackSpec, String> {
        let loop_gain = |key: &str, v: f64| {
            q::quantize(v, q::LOOP_GAIN_FRAC, 127.9)
                .map(LoopGain::from_bits)
                .ok_or_else(|| format!("{key} = {v}: not a finite value within ±128 (I8F24)"))
        };
        Ok(FeedbackSpec {
            kp: loop_gain("feedback.kp", self.kp)?,
            ki: loop_gain(
                "feedback.ki_per_s (per control step)",
                self.ki_per_s / rate_hz.max(1) as f64,
            )?,
            limit: signal("feedback.limit_um", self.limit_um)?,
            sensor: Interval {
                lo: signal("feedback.position_min_um", self.position_min_um)?,
                hi: signal("feedback.position_max_um", self.position_max_um)?,
            },
            tolerance: signal("feedback.position_tolerance_um", self.position_tolerance_um)?,
        })
    }
}

/// Provenance of a model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The calibrated model it was exported from.
    pub model: String,
    /// The FEM table the maps came from.
    pub fem: String,
    /// Tool and version that wrote it.
    pub created_by: String,
    /// Free text: calibration data, fit metrics.
    pub notes: String,
}

/// `Y[u] = w0·u + Σ w_i G_{r_i}[u]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PiSection {
    /// Linear weight, µm/V (> 0).
    pub w0_um_per_v: f64,
    /// Thresholds, V, non-decreasing, in `[0, input_max_v]`.
    pub thresholds_v: Vec<f64>,
    /// Weights, µm/V; partial sums with `w0` positive.
    pub weights_um_per_v: Vec<f64>,
    /// Input domain `[0, input_max_v]`, V.
    pub input_max_v: f64,
}

/// `U_p(F) = k0 + k_f·F + k_q·(F - F_q)²`, `x = h(Y[g(u - U_p)]) - c·(F - F_ref)`
/// (also the coupling of the host tools' calibrated models, which have no `F_ref`:
/// that belongs to a stage).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct CouplingSection {
    /// Constant part `k0` of the preload offset, V.
    #[serde(default)]
    pub offset_v: f64,
    /// Force–voltage coupling, V/N.
    pub k_f_v_per_n: f64,
    /// Curvature `k_q` of the preload offset, V/N².
    #[serde(default)]
    pub k_q_v_per_n2: f64,
    /// Centre `F_q` of the curvature term, N.
    #[serde(default)]
    pub force_q_n: f64,
    /// Stack compliance, µm/N (0 for the paper's FPI).
    #[serde(default)]
    pub compliance_um_per_n: f64,
    /// Force at zero extension, N: the stage's rest preload (a firmware model
    /// needs it; a calibrated actuator model has none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_ref_n: Option<f64>,
}

/// A monotone map and its inverse, both tabulated (see the core's `fpi::Map`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapSection {
    /// `y = map(x)`.
    pub forward: TableSection,
    /// `x = map⁻¹(y)`.
    pub inverse: TableSection,
}

/// One creep term: `m ← m + (1 - exp(-T_s/τ))·(û - m)`, contributing `b·m` to `Y`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepSection {
    /// Time constant `τ`, s.
    pub tau_s: f64,
    /// Gain `b`, µm/V.
    pub gain_um_per_v: f64,
}

/// Control-loop settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// ISR rate, Hz.
    pub rate_hz: u32,
    /// Lowest amplifier setpoint, V.
    pub u_min_v: f64,
    /// Highest amplifier setpoint, V.
    pub u_max_v: f64,
    /// Largest setpoint slew, V/ms.
    pub slew_v_per_ms: f64,
    /// Lowest reachable reference, µm of stage output.
    pub reference_min_um: f64,
    /// Highest reachable reference, µm of stage output.
    pub reference_max_um: f64,
    /// Lowest plausible force reading, N.
    pub force_min_n: f64,
    /// Highest plausible force reading, N.
    pub force_max_n: f64,
    /// Largest tolerated `|F - f_F(x_pea_est)|`, N.
    pub force_tolerance_n: f64,
    /// Safe-state voltage, V.
    pub safe_voltage_v: f64,
    /// `"measured"` (force sensor) or `"predicted"` (`f_F` of the reference).
    pub force_source: String,
    /// The amplifier's output current limit, mA: with `capacitance_uf` it bounds
    /// the slew to `I_max / C` (second paper, eq. 14).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub current_limit_ma: Option<f64>,
    /// The stack's capacitance, µF (`fpi identify`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capacitance_uf: Option<f64>,
    /// Corner of the force channel's split, Hz: below it the FPI uses the measured
    /// force, above it the FEM's preload (the dynamic part goes to the damping).
    /// Absent: 10 Hz; 0: no split (the reading as it is).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_split_hz: Option<f64>,
    /// Largest tolerated `|F − f_F(x_pea_est)|` at once (the dynamic force
    /// included), N; the slow part is held to `force_tolerance_n`. Absent:
    /// [`DYNAMIC_LIMIT_FACTOR`] times the tolerance (a stage's first mode, rung by a
    /// fast move, swings the force by tens of newtons).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_dynamic_limit_n: Option<f64>,
}

impl ControllerSection {
    /// The slew the loop enforces, V/ms: `slew_v_per_ms`, or `I_max / C` (mA/µF =
    /// V/ms) where the amplifier's current limit and the stack's capacitance are
    /// given and it is lower. An `I_max` or `C` that is not positive and finite is
    /// refused, naming its key.
    pub fn slew_limit_v_per_ms(&self) -> Result<f64, String> {
        match (self.current_limit_ma, self.capacitance_uf) {
            (None, None) => Ok(self.slew_v_per_ms),
            (Some(i), Some(c)) => {
                if !(i > 0.0 && i.is_finite()) {
                    return Err(format!(
                        "controller.current_limit_ma = {i}: not a positive current"
                    ));
                }
                if !(c > 0.0 && c.is_finite()) {
                    return Err(format!(
                        "controller.capacitance_uf = {c}: not a positive capacitance"
                    ));
                }
                Ok(self.slew_v_per_ms.min(i / c))
            }
            _ => Err(
                "controller.current_limit_ma and controller.capacitance_uf go together \
                 (the slew limit I_max / C needs both)"
                    .to_string(),
            ),
        }
    }

    /// The slew the loop enforces ([`slew_limit_v_per_ms`](Self::slew_limit_v_per_ms))
    /// per control step at `rate_hz`, V.
    pub fn slew_per_step_v(&self) -> Result<f64, String> {
        Ok(self.slew_limit_v_per_ms()? * 1e3 / self.rate_hz as f64)
    }
}

/// The three FEM-derived maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tables {
    /// Preload, N, vs stack extension, µm.
    pub f_f: TableSection,
    /// Stage output, µm, vs stack extension, µm.
    pub f_k: TableSection,
    /// Stack extension, µm, vs stage output, µm.
    pub f_k_inv: TableSection,
}

/// A monotone function sampled at `x0 + k·2^step_log2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableSection {
    /// First knot, input unit.
    pub x0: f64,
    /// Knot spacing is `2^step_log2` input units; `-15..=0`.
    pub step_log2: i32,
    /// Values at the knots, output unit.
    pub values: Vec<f64>,
}

/// A table quantised to the core's format (owns what a [`TableSpec`] borrows).
#[derive(Debug, Clone, PartialEq)]
pub struct QuantizedTable {
    /// First knot, `I16F16`.
    pub x0: I16F16,
    /// Spacing as `log2` of raw LSB.
    pub shift: u32,
    /// The intervals.
    pub segments: Vec<Segment>,
}

impl QuantizedTable {
    /// The borrowed form.
    pub fn spec(&self) -> TableSpec<'_> {
        TableSpec {
            x0: self.x0,
            shift: self.shift,
            segments: &self.segments,
        }
    }
}

/// A model quantised to the core's formats: owns the arrays a [`ModelSpec`]
/// borrows, and lends them with [`spec`](Self::spec).
#[derive(Debug, Clone, PartialEq)]
pub struct Quantized {
    /// Everything but the arrays (which are empty here).
    base: ModelSpec<'static>,
    operators: Vec<Operator<UmPerVolt>>,
    creep: Vec<CreepSpec>,
    dead_zone: Option<[QuantizedTable; 2]>,
    saturation: Option<[QuantizedTable; 2]>,
    tables: [QuantizedTable; 3],
}

impl Quantized {
    /// The model in the core's format, for [`validate`] and the firmware's types.
    pub fn spec(&self) -> ModelSpec<'_> {
        fn map(m: &Option<[QuantizedTable; 2]>) -> Option<MapSpec<'_>> {
            m.as_ref().map(|[f, i]| MapSpec {
                forward: f.spec(),
                inverse: i.spec(),
            })
        }
        let [f_f, f_k, f_k_inv] = &self.tables;
        ModelSpec {
            operators: &self.operators,
            creep: &self.creep,
            dead_zone: map(&self.dead_zone),
            saturation: map(&self.saturation),
            f_f: f_f.spec(),
            f_k: f_k.spec(),
            f_k_inv: f_k_inv.spec(),
            ..self.base
        }
    }
}

fn signal(key: &str, v: f64) -> Result<I16F16, String> {
    q::signal(v).ok_or_else(|| {
        format!(
            "{key} = {v}: not a finite value within ±{} (I16F16 signal range)",
            q::SIGNAL_ABS_MAX
        )
    })
}

fn gain(key: &str, v: f64) -> Result<UmPerVolt, String> {
    q::gain(v).ok_or_else(|| {
        format!(
            "{key} = {v}: not a finite value within ±{} (I4F28 gain range)",
            q::GAIN_ABS_MAX
        )
    })
}

fn coupling(key: &str, v: f64) -> Result<VoltsPerNewton, String> {
    q::coupling(v).ok_or_else(|| {
        format!(
            "{key} = {v}: not a finite value within ±{} (I0F32 coupling range)",
            q::COUPLING_ABS_MAX
        )
    })
}

impl PiSection {
    /// The operators in the core's formats.
    fn operators(&self) -> Result<Vec<Operator<UmPerVolt>>, String> {
        if self.weights_um_per_v.len() != self.thresholds_v.len() {
            return Err(format!(
                "pi.weights_um_per_v has {} values but pi.thresholds_v has {}",
                self.weights_um_per_v.len(),
                self.thresholds_v.len()
            ));
        }
        self.thresholds_v
            .iter()
            .zip(&self.weights_um_per_v)
            .enumerate()
            .map(|(i, (&r, &w))| {
                Ok(Operator {
                    threshold: signal(&format!("pi.thresholds_v[{i}]"), r)?,
                    weight: gain(&format!("pi.weights_um_per_v[{i}]"), w)?,
                })
            })
            .collect()
    }
}

impl CouplingSection {
    /// The coupling in the core's formats (a firmware model needs `force_ref_n`).
    fn quantize(&self) -> Result<FixedCoupling, String> {
        let force_ref = self
            .force_ref_n
            .ok_or("coupling.force_ref_n: missing (the stage's force at zero extension, N)")?;
        Ok(FixedCoupling {
            offset: signal("coupling.offset_v", self.offset_v)?,
            k_f: coupling("coupling.k_f_v_per_n", self.k_f_v_per_n)?,
            k_q: coupling("coupling.k_q_v_per_n2", self.k_q_v_per_n2)?,
            force_q: signal("coupling.force_q_n", self.force_q_n)?,
            compliance: coupling("coupling.compliance_um_per_n", self.compliance_um_per_n)?,
            force_ref: signal("coupling.force_ref_n", force_ref)?,
        })
    }
}

impl ControllerSection {
    /// The supervision settings in the core's formats.
    fn supervision(&self) -> Result<Supervision, String> {
        let force_source = match self.force_source.as_str() {
            "measured" => ForceSource::Measured,
            "predicted" => ForceSource::Predicted,
            other => {
                return Err(format!(
                    "controller.force_source = {}: expected \"measured\" or \"predicted\"",
                    crate::quote::Quoted(other)
                ))
            }
        };
        let interval = |lo_key: &str, lo, hi_key: &str, hi| -> Result<Interval, String> {
            Ok(Interval {
                lo: signal(lo_key, lo)?,
                hi: signal(hi_key, hi)?,
            })
        };
        // The default corner, or f_s/64 at a rate too low for it (the validator
        // then names the rate).
        let split_hz = self
            .force_split_hz
            .unwrap_or((DEFAULT_SPLIT_HZ as f64).min(self.rate_hz as f64 / 64.0));
        let channel = ForceChannel {
            split: rate_per_tick("controller.force_split_hz", split_hz, self.rate_hz as f64)?,
            dynamic_limit: match self.force_dynamic_limit_n {
                Some(v) => signal("controller.force_dynamic_limit_n", v)?,
                None => signal(
                    "controller.force_tolerance_n (times the default dynamic-limit factor)",
                    DYNAMIC_LIMIT_FACTOR * self.force_tolerance_n,
                )?,
            },
        };
        Ok(Supervision {
            channel,
            reference: interval(
                "controller.reference_min_um",
                self.reference_min_um,
                "controller.reference_max_um",
                self.reference_max_um,
            )?,
            force: interval(
                "controller.force_min_n",
                self.force_min_n,
                "controller.force_max_n",
                self.force_max_n,
            )?,
            force_tolerance: signal("controller.force_tolerance_n", self.force_tolerance_n)?,
            safe_voltage: signal("controller.safe_voltage_v", self.safe_voltage_v)?,
            force_source,
        })
    }
}

/// A tabulated map and its inverse in the core's format.
fn quantize_map(name: &str, m: &Option<MapSection>) -> Result<Option<[QuantizedTable; 2]>, String> {
    m.as_ref()
        .map(|m| {
            Ok([
                quantize_table(&format!("{name}.forward"), &m.forward)?,
                quantize_table(&format!("{name}.inverse"), &m.inverse)?,
            ])
        })
        .transpose()
}

fn quantize_table(key: &str, t: &TableSection) -> Result<QuantizedTable, String> {
    let values = t
        .values
        .iter()
        .enumerate()
        .map(|(i, &v)| signal(&format!("{key}.values[{i}]"), v))
        .collect::<Result<Vec<_>, _>>()?;
    let segments = values
        .windows(2)
        .map(|w| Segment::from_bits(w[0].to_bits(), w[1].to_bits() - w[0].to_bits()))
        .collect();
    Ok(QuantizedTable {
        x0: signal(&format!("{key}.x0"), t.x0)?,
        // Out-of-range spacings are passed on for the validator to name.
        shift: (t.step_log2 + q::SIGNAL_FRAC as i32).clamp(0, 32) as u32,
        segments,
    })
}

impl TableSection {
    /// Knot spacing in input units.
    pub fn step(&self) -> f64 {
        2f64.powi(self.step_log2)
    }
    /// Last knot, input unit.
    pub fn x_max(&self) -> f64 {
        self.x0 + self.step() * (self.values.len().saturating_sub(1)) as f64
    }
    /// The table as a curve (ends held, like the core's table); `None` for fewer
    /// than two knots.
    pub fn curve(&self) -> Option<Curve<'_, f64>> {
        Curve::uniform(self.x0, self.step(), &self.values)
    }
}

impl MapSection {
    /// The map and its inverse as curves.
    pub fn table_map(&self) -> Option<TableMap<'_, f64>> {
        Some(TableMap {
            forward: self.forward.curve()?,
            inverse: self.inverse.curve()?,
        })
    }
}

impl FirmwareModel {
    /// Parses and checks a model file ([`check`](Self::check)); errors name the file
    /// and the key.
    pub fn parse(text: &str, file: &str) -> Result<Self, String> {
        let model: FirmwareModel =
            toml::from_str(text).map_err(|e| toml_error(file, "firmware model file", text, &e))?;
        model.check().map_err(|e| format!("{file}: {e}"))?;
        Ok(model)
    }

    /// The file's text (what `fpi export` writes), with a header comment.
    pub fn to_toml(&self) -> Result<String, String> {
        let body = toml::to_string(self).map_err(|e| e.to_string())?;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "# Firmware model: FPI parameters, FEM tables and loop settings for the\n\
             # no_std core. Written by `fpi export`; build.rs quantises it to the Q formats.\n\
             # Units are in the key names. Regenerate rather than edit by hand.\n"
        );
        out.push_str(&body);
        Ok(out)
    }

    /// Quantises the model and validates it with the core's validator; the
    /// quantised model and its shape, or the first problem, naming its key.
    pub fn check(&self) -> Result<(Quantized, Shape), String> {
        let q = self.quantize()?;
        let shape = validate(&q.spec()).map_err(|e| self.describe(e))?;
        Ok((q, shape))
    }

    /// The model as an image (`piezo_fpi::model::image`): checked, quantised and
    /// encoded — what the firmware embeds as its factory default and what the
    /// host uploads to a board.
    pub fn image(&self) -> Result<Vec<u8>, String> {
        let (q, _) = self.check()?;
        let spec = q.spec();
        let mut out = vec![0; piezo_fpi::model::image::encoded_len(&spec)];
        piezo_fpi::model::image::encode(&spec, &mut out).map_err(|e| e.to_string())?;
        Ok(out)
    }

    /// Every value in its Q format (the values' ranges only; [`check`](Self::check)
    /// validates the model).
    pub fn quantize(&self) -> Result<Quantized, String> {
        if self.format != FORMAT {
            return Err(format!(
                "format = {}: expected {FORMAT:?}",
                crate::quote::Quoted(&self.format)
            ));
        }
        let empty = TableSpec {
            x0: I16F16::ZERO,
            shift: 0,
            segments: &[],
        };
        let k = &self.controller;
        Ok(Quantized {
            base: ModelSpec {
                rate_hz: k.rate_hz,
                w0: gain("pi.w0_um_per_v", self.pi.w0_um_per_v)?,
                operators: &[],
                input_max: signal("pi.input_max_v", self.pi.input_max_v)?,
                coupling: self.coupling.quantize()?,
                dead_zone: None,
                saturation: None,
                creep: &[],
                f_f: empty,
                f_k: empty,
                f_k_inv: empty,
                u_min: signal("controller.u_min_v", k.u_min_v)?,
                u_max: signal("controller.u_max_v", k.u_max_v)?,
                max_step: signal(
                    "controller.slew_v_per_ms (per control step)",
                    k.slew_per_step_v()?,
                )?,
                supervision: k.supervision()?,
                feedback: self
                    .feedback
                    .as_ref()
                    .map(|f| f.quantize(k.rate_hz))
                    .transpose()?,
                shaping: self
                    .shaping
                    .as_ref()
                    .map(ShapingSection::quantize)
                    .transpose()?,
                dynamics: self
                    .dynamics
                    .as_ref()
                    .map(DynamicsSection::quantize)
                    .transpose()?,
                damping: self
                    .damping
                    .as_ref()
                    .map(|d| d.quantize(k.rate_hz))
                    .transpose()?,
            },
            operators: self.pi.operators()?,
            creep: self.creep_terms()?,
            dead_zone: quantize_map("dead_zone", &self.dead_zone)?,
            saturation: quantize_map("saturation", &self.saturation)?,
            tables: [
                quantize_table("tables.f_f", &self.tables.f_f)?,
                quantize_table("tables.f_k", &self.tables.f_k)?,
                quantize_table("tables.f_k_inv", &self.tables.f_k_inv)?,
            ],
        })
    }

    /// The creep terms at the control rate (a rate outside `(0, 0.5)` is passed
    /// on as 0, which the validator refuses by name).
    fn creep_terms(&self) -> Result<Vec<CreepSpec>, String> {
        let dt = 1.0 / self.controller.rate_hz as f64;
        self.creep
            .iter()
            .enumerate()
            .map(|(j, cr)| {
                let r = lag_rate(dt, cr.tau_s);
                let rate = if r > 0.0 && r < 0.5 {
                    coupling(&format!("creep[{j}].tau_s"), r)?
                } else {
                    CreepRate::ZERO
                };
                Ok(CreepSpec {
                    rate,
                    gain: gain(&format!("creep[{j}].gain_um_per_v"), cr.gain_um_per_v)?,
                })
            })
            .collect()
    }

    fn table(&self, id: TableId) -> Option<&TableSection> {
        fn map(m: &Option<MapSection>, inverse: bool) -> Option<&TableSection> {
            m.as_ref()
                .map(|m| if inverse { &m.inverse } else { &m.forward })
        }
        match id {
            TableId::FF => Some(&self.tables.f_f),
            TableId::FK => Some(&self.tables.f_k),
            TableId::FKInv => Some(&self.tables.f_k_inv),
            TableId::DeadZone => map(&self.dead_zone, false),
            TableId::DeadZoneInverse => map(&self.dead_zone, true),
            TableId::Saturation => map(&self.saturation, false),
            TableId::SaturationInverse => map(&self.saturation, true),
        }
    }

    /// The file's value at a located field, when it is one number.
    pub fn value_at(&self, field: Field, index: Option<u16>) -> Option<f64> {
        let i = index.map(usize::from);
        let at = |v: &Vec<f64>| i.and_then(|i| v.get(i).copied());
        let (p, c, k) = (&self.pi, &self.coupling, &self.controller);
        match field {
            Field::PiW0 => Some(p.w0_um_per_v),
            Field::PiThresholds => at(&p.thresholds_v),
            Field::PiWeights => at(&p.weights_um_per_v),
            Field::PiInputMax => Some(p.input_max_v),
            Field::CouplingOffset => Some(c.offset_v),
            Field::CouplingKf => Some(c.k_f_v_per_n),
            Field::CouplingKq => Some(c.k_q_v_per_n2),
            Field::CouplingForceQ => Some(c.force_q_n),
            Field::CouplingCompliance => Some(c.compliance_um_per_n),
            Field::CouplingForceRef => c.force_ref_n,
            Field::CreepTau => i.and_then(|i| self.creep.get(i)).map(|c| c.tau_s),
            Field::CreepGain => i.and_then(|i| self.creep.get(i)).map(|c| c.gain_um_per_v),
            Field::Table(id, part) => {
                let t = self.table(id)?;
                match part {
                    TablePart::X0 => Some(t.x0),
                    TablePart::StepLog2 => Some(t.step_log2 as f64),
                    TablePart::Values => at(&t.values),
                }
            }
            Field::Rate => Some(k.rate_hz as f64),
            Field::UMin => Some(k.u_min_v),
            Field::UMax => Some(k.u_max_v),
            Field::Slew => Some(k.slew_v_per_ms),
            Field::ReferenceMin => Some(k.reference_min_um),
            Field::ReferenceMax => Some(k.reference_max_um),
            Field::ForceMin => Some(k.force_min_n),
            Field::ForceMax => Some(k.force_max_n),
            Field::ForceTolerance => Some(k.force_tolerance_n),
            Field::SafeVoltage => Some(k.safe_voltage_v),
            Field::FeedbackKp => self.feedback.as_ref().map(|f| f.kp),
            Field::FeedbackKi => self.feedback.as_ref().map(|f| f.ki_per_s),
            Field::FeedbackLimit => self.feedback.as_ref().map(|f| f.limit_um),
            Field::PositionMin => self.feedback.as_ref().map(|f| f.position_min_um),
            Field::PositionMax => self.feedback.as_ref().map(|f| f.position_max_um),
            Field::PositionTolerance => self.feedback.as_ref().map(|f| f.position_tolerance_um),
            Field::Shaping | Field::Preview => None,
            Field::ForceSplit => Some(
                k.force_split_hz
                    .unwrap_or((DEFAULT_SPLIT_HZ as f64).min(k.rate_hz as f64 / 64.0)),
            ),
            Field::ForceDynamicLimit => Some(
                k.force_dynamic_limit_n
                    .unwrap_or(DYNAMIC_LIMIT_FACTOR * k.force_tolerance_n),
            ),
            Field::DynamicsModeHz => self.dynamics.as_ref().map(|d| d.mode_hz),
            Field::DynamicsDamping => self.dynamics.as_ref().map(|d| d.damping_ratio),
            Field::DynamicsLagHz => self.dynamics.as_ref().and_then(|d| d.lag_hz),
            Field::DynamicsForceGain => self.dynamics.as_ref().and_then(|d| d.force_gain_n_per_um),
            Field::DampingGain => self.damping.as_ref().map(|d| d.gain_um_per_n_s),
            Field::DampingLeak => self.damping.as_ref().map(|d| d.leak_hz),
            Field::DampingHighpass => self.damping.as_ref().map(|d| d.highpass_hz),
            Field::DampingLimit => self.damping.as_ref().map(|d| d.limit_um),
            Field::Operators | Field::Creep | Field::ForceSource | Field::Model => None,
        }
    }

    /// A validator's error as the file's user reads it: the key, the value there,
    /// the problem, and for a partial sum or a table what it is compared with.
    pub fn describe(&self, e: Invalid) -> String {
        let mut s = String::new();
        let _ = e.write_key(&mut s);
        if let Some(v) = self.value_at(e.field, e.index) {
            let _ = write!(s, " = {v}");
        }
        let _ = write!(s, ": {}", e.error.message());
        match (e.error, e.field) {
            (ModelError::NonPositiveSlope { index }, _) => {
                let p = &self.pi;
                let sum: f64 =
                    p.w0_um_per_v + p.weights_um_per_v.iter().take(index as usize).sum::<f64>();
                let _ = write!(s, " (S_{index} = w0 + w_1 + … = {sum})");
            }
            (ModelError::TableNotMonotone { index }, Field::Table(id, _))
            | (ModelError::TableTooSteep { index }, Field::Table(id, _))
            | (ModelError::PreloadFalls { index }, Field::Table(id, _))
            | (ModelError::OutputNotInvertible { index }, Field::Table(id, _)) => {
                if let Some(prev) = self
                    .table(id)
                    .and_then(|t| t.values.get((index as usize).wrapping_sub(1)))
                {
                    let _ = write!(s, " (previous knot {prev})");
                }
            }
            (ModelError::ReferenceOutsideTable, _) => {
                let t = &self.tables.f_k_inv;
                let _ = write!(s, " ({}..{} µm)", t.x0, t.x_max());
            }
            _ => {}
        }
        s
    }

    /// The model in floating point with its tabulated maps (the reference of the
    /// fixed-point core); `None` if the file does not describe one.
    pub fn float_model(&self) -> Option<Model<'_, f64>> {
        let p = &self.pi;
        let c = &self.coupling;
        let mut creep = heapless::Vec::new();
        for cr in &self.creep {
            creep
                .push(Creep {
                    tau_s: cr.tau_s,
                    gain: cr.gain_um_per_v,
                })
                .ok()?;
        }
        Some(Model {
            pi: Pi::new(
                p.w0_um_per_v,
                &p.thresholds_v,
                &p.weights_um_per_v,
                p.input_max_v,
            )?,
            ldpi: None,
            coupling: Some(Coupling {
                offset: c.offset_v,
                k_f: c.k_f_v_per_n,
                k_q: c.k_q_v_per_n2,
                force_q: c.force_q_n,
                compliance: c.compliance_um_per_n,
            }),
            dead_zone: match &self.dead_zone {
                Some(m) => DeadZone::Table(m.table_map()?),
                None => DeadZone::Hard,
            },
            output: match &self.saturation {
                Some(m) => Output::Table(m.table_map()?),
                None => Output::Map(crate::maps::OutputMap::Identity),
            },
            offset: 0.0,
            creep,
        })
    }

    /// The force channel's split rate (the quantised one, so both sides filter
    /// alike) and dynamic limit, N.
    fn supervision_f64(&self) -> (f64, f64) {
        match self.controller.supervision() {
            Ok(s) => (
                s.channel.split.to_num::<f64>(),
                s.channel.dynamic_limit.to_num::<f64>(),
            ),
            Err(_) => (
                0.0,
                DYNAMIC_LIMIT_FACTOR * self.controller.force_tolerance_n,
            ),
        }
    }

    /// The control step in floating point with this model's settings.
    pub fn controller(&self) -> Option<Controller<'_, f64>> {
        let k = &self.controller;
        let t = &self.tables;
        Some(Controller {
            model: self.float_model()?,
            f_f: t.f_f.curve()?,
            f_k: t.f_k.curve()?,
            f_k_inv: t.f_k_inv.curve()?,
            u_min: k.u_min_v,
            u_max: k.u_max_v,
            max_step: k.slew_per_step_v().ok()?,
            reference: (k.reference_min_um, k.reference_max_um),
            force: (k.force_min_n, k.force_max_n),
            force_tolerance: k.force_tolerance_n,
            safe_voltage: k.safe_voltage_v,
            measured: k.force_source == "measured",
            split: self.supervision_f64().0,
            dynamic_limit: self.supervision_f64().1,
            force_ref: self.coupling.force_ref_n?,
            dt: 1.0 / k.rate_hz as f64,
        })
    }
}
