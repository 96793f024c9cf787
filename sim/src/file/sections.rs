//! The FPI model's sections of the firmware model file (the PI bank, the
//! coupling, the maps, creep, the controller's settings, the tables) and their
//! quantisation into the core's formats.

use std::fmt;

use fixed::types::I16F16;
use piezo_fpi::control::{ForceChannel, ForceSource, Interval, Supervision, DEFAULT_SPLIT_HZ};
use piezo_fpi::fields::{Field, Range, TableId, TablePart};
use piezo_fpi::fpi::Coupling as FixedCoupling;
use piezo_fpi::model::{CreepSpec, MapSpec, ModelSpec, TableSpec};
use piezo_fpi::play::Operator;
use piezo_fpi::q::{self, CreepRate, Newtons, Signal, UmPerVolt, Volts, VoltsPerNewton};
use piezo_fpi::table::Segment;
use serde::{Deserialize, Serialize};

use super::DYNAMIC_LIMIT_FACTOR;
use crate::curve::Curve;
use crate::maps::TableMap;
use crate::quote::Num;

/// Provenance of a model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PiSection {
    /// Declared as [`Field::PiW0`](piezo_fpi::fields::Field::PiW0).
    pub w0_um_per_v: f64,
    /// Declared as [`Field::PiThresholds`](piezo_fpi::fields::Field::PiThresholds).
    pub thresholds_v: Vec<f64>,
    /// Declared as [`Field::PiWeights`](piezo_fpi::fields::Field::PiWeights).
    pub weights_um_per_v: Vec<f64>,
    /// Declared as [`Field::PiInputMax`](piezo_fpi::fields::Field::PiInputMax).
    pub input_max_v: f64,
}

/// `U_p(F) = k0 + k_f·F + k_q·(F - F_q)²`, `x = h(Y[g(u - U_p)]) - c·(F - F_ref)`
/// (also the coupling of the host tools' calibrated models, which have no `F_ref`:
/// that belongs to a stage).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CouplingSection {
    /// Declared as [`Field::CouplingOffset`](piezo_fpi::fields::Field::CouplingOffset).
    #[serde(default)]
    pub offset_v: f64,
    /// Declared as [`Field::CouplingKf`](piezo_fpi::fields::Field::CouplingKf).
    pub k_f_v_per_n: f64,
    /// Declared as [`Field::CouplingKq`](piezo_fpi::fields::Field::CouplingKq).
    #[serde(default)]
    pub k_q_v_per_n2: f64,
    /// Declared as [`Field::CouplingForceQ`](piezo_fpi::fields::Field::CouplingForceQ).
    #[serde(default)]
    pub force_q_n: f64,
    /// Declared as [`Field::CouplingCompliance`](piezo_fpi::fields::Field::CouplingCompliance).
    #[serde(default)]
    pub compliance_um_per_n: f64,
    /// Declared as [`Field::CouplingForceRef`](piezo_fpi::fields::Field::CouplingForceRef).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_ref_n: Option<f64>,
}

/// A monotone map and its inverse, both tabulated (see the core's `fpi::Map`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MapSection {
    /// `y = map(x)`.
    pub forward: TableSection,
    /// `x = map⁻¹(y)`.
    pub inverse: TableSection,
}

/// One creep term: `m ← m + (1 - exp(-T_s/τ))·(û - m)`, contributing `b·m` to `Y`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CreepSection {
    /// Declared as [`Field::CreepTau`](piezo_fpi::fields::Field::CreepTau).
    pub tau_s: f64,
    /// Declared as [`Field::CreepGain`](piezo_fpi::fields::Field::CreepGain).
    pub gain_um_per_v: f64,
}

/// Control-loop settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// Declared as [`Field::Rate`](piezo_fpi::fields::Field::Rate).
    pub rate_hz: u32,
    /// Declared as [`Field::UMin`](piezo_fpi::fields::Field::UMin).
    pub u_min_v: f64,
    /// Declared as [`Field::UMax`](piezo_fpi::fields::Field::UMax).
    pub u_max_v: f64,
    /// Declared as [`Field::Slew`](piezo_fpi::fields::Field::Slew).
    pub slew_v_per_ms: f64,
    /// Declared as [`Field::ReferenceMin`](piezo_fpi::fields::Field::ReferenceMin).
    pub reference_min_um: f64,
    /// Declared as [`Field::ReferenceMax`](piezo_fpi::fields::Field::ReferenceMax).
    pub reference_max_um: f64,
    /// Declared as [`Field::ForceMin`](piezo_fpi::fields::Field::ForceMin).
    pub force_min_n: f64,
    /// Declared as [`Field::ForceMax`](piezo_fpi::fields::Field::ForceMax).
    pub force_max_n: f64,
    /// Declared as [`Field::ForceTolerance`](piezo_fpi::fields::Field::ForceTolerance).
    pub force_tolerance_n: f64,
    /// Declared as [`Field::SafeVoltage`](piezo_fpi::fields::Field::SafeVoltage).
    pub safe_voltage_v: f64,
    /// Declared as [`Field::ForceSource`](piezo_fpi::fields::Field::ForceSource).
    pub force_source: String,
    /// Declared as [`Field::CurrentLimit`](piezo_fpi::fields::Field::CurrentLimit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub current_limit_ma: Option<f64>,
    /// Declared as [`Field::Capacitance`](piezo_fpi::fields::Field::Capacitance).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capacitance_uf: Option<f64>,
    /// Declared as [`Field::ForceSplit`](piezo_fpi::fields::Field::ForceSplit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_split_hz: Option<f64>,
    /// Declared as [`Field::ForceDynamicLimit`](piezo_fpi::fields::Field::ForceDynamicLimit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_dynamic_limit_n: Option<f64>,
}

impl ControllerSection {
    /// The force channel's split corner, Hz: the file's, else the default
    /// corner, or f_s/64 at a rate too low for it (the validator then names the
    /// rate).
    pub fn split_hz(&self) -> f64 {
        self.force_split_hz
            .unwrap_or((DEFAULT_SPLIT_HZ as f64).min(self.rate_hz as f64 / 64.0))
    }

    /// The dynamic force limit, N: the file's, else
    /// [`DYNAMIC_LIMIT_FACTOR`] times the tolerance.
    pub fn dynamic_limit_n(&self) -> f64 {
        self.force_dynamic_limit_n
            .unwrap_or(DYNAMIC_LIMIT_FACTOR * self.force_tolerance_n)
    }

    /// The slew the loop enforces, V/ms: `slew_v_per_ms`, or `I_max / C` (mA/µF =
    /// V/ms) where the amplifier's current limit and the stack's capacitance are
    /// given and it is lower. An `I_max` or `C` that is not positive and finite is
    /// refused, naming its key (a huge current limit limits nothing; a huge
    /// capacitance, a slew below the smallest step, is refused by
    /// `max_step`).
    pub fn slew_limit_v_per_ms(&self) -> Result<f64, String> {
        match (self.current_limit_ma, self.capacitance_uf) {
            (None, None) => Ok(self.slew_v_per_ms),
            (Some(i), Some(c)) => {
                if !(i > 0.0 && i.is_finite()) {
                    return Err(format!(
                        "controller.current_limit_ma = {}: not a positive finite current, mA",
                        Num(i)
                    ));
                }
                if !(c > 0.0 && c.is_finite()) {
                    return Err(format!(
                        "controller.capacitance_uf = {}: not a positive finite capacitance, µF",
                        Num(c)
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

    /// The slew per control step ([`slew_per_step_v`](Self::slew_per_step_v)) in
    /// its format, `I16F16` V. A slew whose step does not fit is named by its key,
    /// as the file gives it, with the range in V/ms at the file's rate; a current
    /// limit over a capacitance whose slew is below the smallest step, by both
    /// keys. (At a rate outside the validator's range, 0: the validator names the
    /// rate.)
    pub(super) fn max_step(&self) -> Result<Volts, String> {
        if !(100..=200_000).contains(&self.rate_hz) {
            return Ok(Volts::ZERO);
        }
        let rate = self.rate_hz as f64;
        let per_ms = |v_per_step: f64| Num(v_per_step * rate / 1e3);
        if q::signal(self.slew_v_per_ms * 1e3 / rate).is_none() {
            return Err(format!(
                "controller.slew_v_per_ms = {}: not a finite value within ±{} V/ms (±{} V per \
                 control step at controller.rate_hz = {}, I16F16)",
                Num(self.slew_v_per_ms),
                per_ms(q::SIGNAL_ABS_MAX),
                q::SIGNAL_ABS_MAX,
                self.rate_hz
            ));
        }
        let step = q::signal(self.slew_per_step_v()?).map_or(Volts::ZERO, Volts::from_raw);
        match (self.current_limit_ma, self.capacitance_uf) {
            (Some(i), Some(c)) if step <= Volts::ZERO && self.slew_v_per_ms > 0.0 => Err(format!(
                "controller.current_limit_ma = {} over controller.capacitance_uf = {}: a \
                     slew of {} V/ms, below the smallest the loop holds ({} V/ms, 2^-16 V per \
                     control step at controller.rate_hz = {})",
                Num(i),
                Num(c),
                Num(i / c),
                per_ms(Volts::DELTA.to_num::<f64>()),
                self.rate_hz
            )),
            _ => Ok(step),
        }
    }
}

/// The three FEM-derived maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TableSection {
    /// Declared as [`TablePart::X0`](piezo_fpi::fields::TablePart) (unit, format, range, doc).
    pub x0: f64,
    /// Declared as [`TablePart::StepLog2`](piezo_fpi::fields::TablePart) (unit, format, range, doc).
    pub step_log2: i32,
    /// Declared as [`TablePart::Values`](piezo_fpi::fields::TablePart) (unit, format, range, doc).
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
    pub(super) base: ModelSpec<'static>,
    pub(super) operators: Vec<Operator<UmPerVolt>>,
    pub(super) creep: Vec<CreepSpec>,
    pub(super) dead_zone: Option<[QuantizedTable; 2]>,
    pub(super) saturation: Option<[QuantizedTable; 2]>,
    pub(super) tables: [QuantizedTable; 3],
}

impl Quantized {
    /// The model in the core's format, for [`validate`](piezo_fpi::model::validate) and the firmware's types.
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

/// `1 − e^{−2π·f/f_s}` in `I0F32` for a corner `f` (Hz, ≥ 0) at `f_s`; errors
/// name `key`.
pub(super) fn rate_per_tick(
    key: impl fmt::Display,
    f_hz: f64,
    fs: f64,
) -> Result<CreepRate, String> {
    if !(f_hz.is_finite() && f_hz >= 0.0 && f_hz * 64.0 <= fs) {
        return Err(format!(
            "{key} = {}: not a corner between 0 and f_s/64 = {} Hz (controller.rate_hz = {})",
            Num(f_hz),
            Num(fs / 64.0),
            Num(fs)
        ));
    }
    let a = -(-2.0 * std::f64::consts::PI * f_hz / fs).exp_m1();
    q::quantize(a, q::COUPLING_FRAC, q::COUPLING_ABS_MAX)
        .map(CreepRate::from_bits)
        .ok_or_else(|| {
            format!(
                "{key} = {}: its rate per control tick does not fit I0F32",
                Num(f_hz)
            )
        })
}

/// `v` as a signal in the unit its key names (V, µm, N; or bare `I16F16`).
pub(super) fn signal<S: Signal>(key: impl fmt::Display, v: f64) -> Result<S, String> {
    q::signal(v)
        .map(|x| S::from_bits(x.to_bits()))
        .ok_or_else(|| {
            format!(
                "{key} = {}: not a finite value within ±{} (I16F16 signal range)",
                Num(v),
                q::SIGNAL_ABS_MAX
            )
        })
}

pub(super) fn gain(key: impl fmt::Display, v: f64) -> Result<UmPerVolt, String> {
    q::gain(v).ok_or_else(|| {
        format!(
            "{key} = {}: not a finite value within ±{} (I4F28 gain range)",
            Num(v),
            q::GAIN_ABS_MAX
        )
    })
}

pub(super) fn coupling(key: impl fmt::Display, v: f64) -> Result<VoltsPerNewton, String> {
    q::coupling(v).ok_or_else(|| {
        format!(
            "{key} = {}: not a finite value within ±{} (I0F32 coupling range)",
            Num(v),
            q::COUPLING_ABS_MAX
        )
    })
}

impl PiSection {
    /// The operators in the core's formats.
    pub(super) fn operators(&self) -> Result<Vec<Operator<UmPerVolt>>, String> {
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
                    threshold: signal(Field::PiThresholds.at(i), r)?,
                    weight: gain(Field::PiWeights.at(i), w)?,
                })
            })
            .collect()
    }
}

impl CouplingSection {
    /// The coupling in the core's formats (a firmware model needs `force_ref_n`).
    pub(super) fn quantize(&self) -> Result<FixedCoupling, String> {
        let force_ref = self
            .force_ref_n
            .ok_or("coupling.force_ref_n: missing (the stage's force at zero extension, N)")?;
        Ok(FixedCoupling {
            offset: signal(Field::CouplingOffset, self.offset_v)?,
            k_f: coupling(Field::CouplingKf, self.k_f_v_per_n)?,
            k_q: coupling(Field::CouplingKq, self.k_q_v_per_n2)?,
            force_q: signal(Field::CouplingForceQ, self.force_q_n)?,
            compliance: coupling(Field::CouplingCompliance, self.compliance_um_per_n)?,
            force_ref: signal(Field::CouplingForceRef, force_ref)?,
        })
    }
}

impl ControllerSection {
    /// The supervision settings in the core's formats.
    pub(super) fn supervision(&self) -> Result<Supervision, String> {
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
        fn interval<S: Signal>(
            lo_key: Field,
            lo: f64,
            hi_key: Field,
            hi: f64,
        ) -> Result<Interval<S>, String> {
            Ok(Interval {
                lo: signal(lo_key, lo)?,
                hi: signal(hi_key, hi)?,
            })
        }
        let channel = ForceChannel {
            split: rate_per_tick(Field::ForceSplit, self.split_hz(), self.rate_hz as f64)?,
            dynamic_limit: match self.force_dynamic_limit_n {
                Some(v) => signal(Field::ForceDynamicLimit, v)?,
                None => {
                    signal::<Newtons>(Field::ForceTolerance, self.force_tolerance_n)?;
                    q::signal(self.dynamic_limit_n())
                        .map(Newtons::from_raw)
                        .ok_or_else(|| {
                            format!(
                            "controller.force_tolerance_n = {}: {DYNAMIC_LIMIT_FACTOR} times it, \
                             the default controller.force_dynamic_limit_n, is not within ±{} N \
                             (I16F16 signal range): give controller.force_dynamic_limit_n",
                            Num(self.force_tolerance_n),
                            q::SIGNAL_ABS_MAX
                        )
                        })?
                }
            },
        };
        Ok(Supervision {
            channel,
            reference: interval(
                Field::ReferenceMin,
                self.reference_min_um,
                Field::ReferenceMax,
                self.reference_max_um,
            )?,
            force: interval(
                Field::ForceMin,
                self.force_min_n,
                Field::ForceMax,
                self.force_max_n,
            )?,
            force_tolerance: signal(Field::ForceTolerance, self.force_tolerance_n)?,
            safe_voltage: signal(Field::SafeVoltage, self.safe_voltage_v)?,
            force_source,
        })
    }
}

/// A tabulated map and its inverse in the core's format.
pub(super) fn quantize_map(
    [forward, inverse]: [TableId; 2],
    m: &Option<MapSection>,
) -> Result<Option<[QuantizedTable; 2]>, String> {
    m.as_ref()
        .map(|m| {
            Ok([
                quantize_table(forward, &m.forward)?,
                quantize_table(inverse, &m.inverse)?,
            ])
        })
        .transpose()
}

pub(super) fn quantize_table(id: TableId, t: &TableSection) -> Result<QuantizedTable, String> {
    let values = t
        .values
        .iter()
        .enumerate()
        .map(|(i, &v)| signal::<I16F16>(Field::Table(id, TablePart::Values).at(i), v))
        .collect::<Result<Vec<_>, _>>()?;
    let segments = values
        .windows(2)
        .map(|w| Segment::from_bits(w[0].to_bits(), w[1].to_bits() - w[0].to_bits()))
        .collect();
    Ok(QuantizedTable {
        x0: signal(Field::Table(id, TablePart::X0), t.x0)?,
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

/// `v` if it lies within its key's declared range (`piezo_fpi::fields`), else
/// the error naming the key, the value and the range: `[lo, hi]`, or `[lo, hi)`
/// where `hi` itself is beyond the stored format (a ratio of `I2F30` below 2).
pub(super) fn within(field: Field, v: f64) -> Result<f64, String> {
    let d = field.decl();
    let Range::Within(lo, hi) = d.range else {
        return Ok(v);
    };
    let open = d.q.frac > 0 && d.bits().1 > i64::from(i32::MAX);
    let inside = v >= lo && if open { v < hi } else { v <= hi };
    if inside {
        return Ok(v);
    }
    let unit = if d.unit.is_empty() {
        String::new()
    } else {
        format!(" {}", d.unit)
    };
    Err(format!(
        "{field} = {}: not within [{}, {}{}{unit} ({})",
        Num(v),
        Num(lo),
        Num(hi),
        if open { ")" } else { "]" },
        d.q.name
    ))
}
