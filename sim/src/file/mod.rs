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
use piezo_fpi::error::{Field, Invalid, ModelError, TableId};
use piezo_fpi::model::{validate, CreepSpec, ModelSpec, Shape, TableSpec};
use piezo_fpi::q::CreepRate;
use serde::{Deserialize, Serialize};

use crate::control::Controller;
use crate::model::{lag_rate, Coupling, Creep, DeadZone, Model, Output};
use crate::play::Pi;
use crate::quote::{toml_error, Num};

/// The default dynamic force limit, in force tolerances
/// (`controller.force_dynamic_limit_n`).
pub const DYNAMIC_LIMIT_FACTOR: f64 = 4.0;

/// The `format` string this schema reads and writes.
pub const FORMAT: &str = "piezo-fpi-firmware/1";

/// A whole firmware model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FirmwareModel {
    /// Always `piezo-fpi-firmware/1` ([`FORMAT`]): the format this schema reads and writes.
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

pub mod axes;
mod loops;
mod sections;

use sections::{gain, quantize_map, quantize_table, signal};

pub use axes::{AxesModel, CouplingTable, AXES_FORMAT};
pub use loops::{DampingSection, DynamicsSection, FeedbackSection, ShapingSection};
pub use sections::{
    ControllerSection, CouplingSection, CreepSection, MapSection, PiSection, Provenance, Quantized,
    QuantizedTable, TableSection, Tables,
};

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
                w0: gain(Field::PiW0, self.pi.w0_um_per_v)?,
                operators: &[],
                input_max: signal(Field::PiInputMax, self.pi.input_max_v)?,
                coupling: self.coupling.quantize()?,
                dead_zone: None,
                saturation: None,
                creep: &[],
                f_f: empty,
                f_k: empty,
                f_k_inv: empty,
                u_min: signal(Field::UMin, k.u_min_v)?,
                u_max: signal(Field::UMax, k.u_max_v)?,
                max_step: k.max_step()?,
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
                lead_baseline: self
                    .damping
                    .as_ref()
                    .map(DampingSection::lead)
                    .transpose()?
                    .flatten(),
                watch_swing: self
                    .feedback
                    .as_ref()
                    .map(FeedbackSection::watch_swing)
                    .transpose()?
                    .flatten(),
            },
            operators: self.pi.operators()?,
            creep: self.creep_terms()?,
            dead_zone: quantize_map(
                [TableId::DeadZone, TableId::DeadZoneInverse],
                &self.dead_zone,
            )?,
            saturation: quantize_map(
                [TableId::Saturation, TableId::SaturationInverse],
                &self.saturation,
            )?,
            tables: [
                quantize_table(TableId::FF, &self.tables.f_f)?,
                quantize_table(TableId::FK, &self.tables.f_k)?,
                quantize_table(TableId::FKInv, &self.tables.f_k_inv)?,
            ],
        })
    }

    /// The creep terms at the control rate: a time constant that is not a
    /// positive finite number, or too long for its rate's format, is named here;
    /// one too short (a rate of 0.5 or more per tick) is passed on as 0, which
    /// the validator refuses by name.
    fn creep_terms(&self) -> Result<Vec<CreepSpec>, String> {
        let dt = 1.0 / self.controller.rate_hz as f64;
        self.creep
            .iter()
            .enumerate()
            .map(|(j, cr)| {
                let key = Field::CreepTau.at(j);
                if !(cr.tau_s.is_finite() && cr.tau_s > 0.0) {
                    return Err(format!(
                        "{key} = {}: not a positive finite time constant, s",
                        Num(cr.tau_s)
                    ));
                }
                let r = lag_rate(dt, cr.tau_s);
                let rate = if r > 0.0 && r < 0.5 {
                    piezo_fpi::q::coupling(r)
                        .filter(|q| *q > CreepRate::ZERO)
                        .ok_or_else(|| {
                            format!(
                                "{key} = {}: longer than its rate per control tick holds \
                                 (I0F32: at most about {} s at controller.rate_hz = {})",
                                Num(cr.tau_s),
                                Num((dt * 2f64.powi(32)).round()),
                                self.controller.rate_hz
                            )
                        })?
                } else {
                    CreepRate::ZERO
                };
                Ok(CreepSpec {
                    rate,
                    gain: gain(Field::CreepGain.at(j), cr.gain_um_per_v)?,
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

    /// The file's value at a located field, when it is one number: looked up by
    /// the field's declared key (`piezo_fpi::fields`), so no key is spelled
    /// here; a key the file leaves out reads as its default where the reader
    /// gives it one (the force channel's split and dynamic limit).
    pub fn value_at(&self, field: Field, index: Option<u16>) -> Option<f64> {
        match field {
            Field::ForceSplit => return Some(self.controller.split_hz()),
            Field::ForceDynamicLimit => return Some(self.controller.dynamic_limit_n()),
            Field::Operators | Field::Creep | Field::Model => return None,
            _ => {}
        }
        let tree = toml::Value::try_from(self).ok()?;
        // `creep[].tau_s`: the index goes into the array of tables.
        let path = field.to_string();
        let mut at = &tree;
        for part in path.split('.') {
            at = match part.strip_suffix("[]") {
                Some(array) => at.get(array)?.get(usize::from(index?))?,
                None => at.get(part)?,
            };
        }
        let at = match (at, index) {
            (toml::Value::Array(a), Some(i)) if !path.contains("[]") => a.get(usize::from(i))?,
            (v, _) => v,
        };
        match at {
            toml::Value::Float(v) => Some(*v),
            toml::Value::Integer(v) => Some(*v as f64),
            _ => None,
        }
    }

    /// The rule a validator's error `e` says the value breaks, with the file's
    /// values it is checked against where the core's message is general (the
    /// stage's dynamics: one error for all of their ranges).
    fn rule(&self, e: Invalid) -> String {
        let rate = self.controller.rate_hz;
        match (e.error, e.field, &self.dynamics) {
            (ModelError::DampingOutOfRange, Field::DynamicsLagHz, Some(d)) => format!(
                "must be above dynamics.mode_hz = {} (the lag's corner lies above the mode; \
                 no lag: leave lag_hz out)",
                Num(d.mode_hz)
            ),
            (ModelError::DampingOutOfRange, Field::DynamicsModeHz, _) => format!(
                "the mode must lie from 1 Hz up to below the Nyquist frequency, {} Hz at \
                 controller.rate_hz = {rate}",
                Num(rate as f64 / 2.0)
            ),
            (ModelError::DampingOutOfRange, Field::DynamicsDamping, _) => {
                "the damping ratio must lie within (0, 0.5)".to_string()
            }
            (ModelError::DampingOutOfRange, Field::DynamicsForceGain, _) => {
                "κ, the dynamic force per µm of command, must not be negative".to_string()
            }
            _ => e.error.message().to_string(),
        }
    }

    /// A validator's error as the file's user reads it: the key, the value there,
    /// the problem, and for a partial sum or a table what it is compared with.
    pub fn describe(&self, e: Invalid) -> String {
        let mut s = String::new();
        let _ = e.write_key(&mut s);
        if let Some(v) = self.value_at(e.field, e.index) {
            let _ = write!(s, " = {}", Num(v));
        }
        let _ = write!(s, ": {}", self.rule(e));
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
                    let _ = write!(s, " (previous knot {})", Num(*prev));
                }
            }
            (ModelError::LimitsInverted, lower) => {
                let upper = match lower {
                    Field::UMin => Some(Field::UMax),
                    Field::ReferenceMin => Some(Field::ReferenceMax),
                    Field::ForceMin => Some(Field::ForceMax),
                    Field::PositionMin => Some(Field::PositionMax),
                    _ => None,
                };
                if let Some((f, v)) = upper.and_then(|f| Some((f, self.value_at(f, None)?))) {
                    let _ = write!(s, " ({} = {})", f.key(), Num(v));
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
            Err(_) => (0.0, self.controller.dynamic_limit_n()),
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
