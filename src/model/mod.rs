//! The model format and its validator.
//!
//! A [`ModelSpec`] is a whole stage model in the core's formats — the PI operators,
//! the force coupling, the static maps and creep terms, the FEM tables, and the
//! loop's limits and supervision settings — borrowed from wherever it lives (flash,
//! a host tool's buffers, a model received over the link). [`validate`] is the one
//! check of a model: it runs exactly the checks the core's constructors run
//! ([`crate::pi::check`], [`crate::inverse::invert`], [`Coupling::check`],
//! [`crate::fpi::creep_slope`], [`Table::new`], [`OutputLimits::new`],
//! [`crate::control::check_settings`]), and locates the first failure by the model
//! file's key ([`Invalid`]). The firmware's build, the host tools and the board's
//! model upload all validate through it, so a model one of them accepts, the others
//! accept too, and a refusal reads the same everywhere.
//!
//! The model *file* (TOML, engineering units) is read and quantised into a
//! `ModelSpec` by the host side (`piezo-sim`'s `file` feature).

pub mod image;
pub mod store;

use fixed::types::I16F16;

use crate::biquad::ShapingSpec;
use crate::control::{check_settings, Supervision};
use crate::damping::{DampingConfig, DampingSpec, DynamicsSpec};
use crate::error::{Field, Invalid, ModelError, TableId, TablePart};
use crate::feedback::{FeedbackConfig, FeedbackSpec};
use crate::fpi::{creep_slope, Coupling, Creep};
use crate::limits::OutputLimits;
use crate::play::Operator;
use crate::q::{
    CreepRate, LeadRatio, Micrometres, UmPerVolt, Volts, VoltsPerUm, MAX_CREEP_TERMS, MAX_OPERATORS,
};
use crate::table::{Segment, Table, INVERSE_TOLERANCE};

/// A lookup table: first knot, spacing `2^shift` raw LSB of the input, intervals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TableSpec<'a> {
    /// First knot (input unit), `I16F16`.
    pub x0: I16F16,
    /// Knot spacing as `log2` of raw LSB (`step_log2 + 16` of the model file).
    pub shift: u32,
    /// The intervals between the knots.
    pub segments: &'a [Segment],
}

impl<'a> TableSpec<'a> {
    /// The spec of a built table (its grid and intervals).
    pub const fn of(t: &Table<'a>) -> Self {
        Self {
            x0: t.x_min(),
            shift: t.shift(),
            segments: t.segments(),
        }
    }

    /// The table, validated ([`Table::new`]).
    pub const fn table(&self) -> Result<Table<'a>, ModelError> {
        Table::new(self.x0, self.shift, self.segments)
    }
}

/// A monotone map and its inverse, both tabulated (see [`crate::fpi::Map`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapSpec<'a> {
    /// `y = map(x)`.
    pub forward: TableSpec<'a>,
    /// `x = map⁻¹(y)`.
    pub inverse: TableSpec<'a>,
}

/// One creep term as stored: its per-sample rate and gain (see [`Creep`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CreepSpec {
    /// `1 - a = 1 - exp(-T_s/τ)`, per sample, `I0F32`.
    pub rate: CreepRate,
    /// `b`, µm/V, `I4F28`.
    pub gain: UmPerVolt,
}

/// A whole stage model in the core's formats (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelSpec<'a> {
    /// Control ISR rate, Hz (100 – 200 000).
    pub rate_hz: u32,
    /// Linear PI weight `w0`, µm/V.
    pub w0: UmPerVolt,
    /// Play operators: thresholds (V) with weights (µm/V).
    pub operators: &'a [Operator<UmPerVolt>],
    /// Input domain `[0, input_max]`, V.
    pub input_max: Volts,
    /// Force coupling and compliance.
    pub coupling: Coupling,
    /// Soft dead zone `g`; `None`: the hard one.
    pub dead_zone: Option<MapSpec<'a>>,
    /// Output saturation `h`; `None`: the identity.
    pub saturation: Option<MapSpec<'a>>,
    /// Creep terms.
    pub creep: &'a [CreepSpec],
    /// Preload `f_F`: stack extension (µm) → force (N).
    pub f_f: TableSpec<'a>,
    /// Kinematics `f_K`: stack extension (µm) → stage output (µm).
    pub f_k: TableSpec<'a>,
    /// Inverse kinematics `f_K⁻¹`: stage output (µm) → stack extension (µm).
    pub f_k_inv: TableSpec<'a>,
    /// Lowest setpoint, V.
    pub u_min: Volts,
    /// Highest setpoint, V.
    pub u_max: Volts,
    /// Largest setpoint change per control step, V.
    pub max_step: Volts,
    /// Supervision and safe state.
    pub supervision: Supervision,
    /// Position feedback (gains, sensor range); `None`: the model has none (the
    /// board then runs open loop only).
    pub feedback: Option<FeedbackSpec>,
    /// Reference shaping (the inverse of the stage's modes, or the feedforward of
    /// the damped stage); `None`: none.
    pub shaping: Option<ShapingSpec>,
    /// The stage's dynamics (its first mode as the loops see it); `None`: not
    /// declared (the board then cannot check its loops or the waveforms against
    /// it).
    pub dynamics: Option<DynamicsSpec>,
    /// Active damping from the force sensor; `None`: none.
    pub damping: Option<DampingSpec>,
    /// The lead's baseline `α_b` (`crate::lead`), in `[1/2, 2)`: the board then
    /// scales the force the shaped reference's motion explains by the stage's
    /// mass over the tuned one's, which it learns; `None`: it learns `α` and
    /// does not apply it. Needs damping and a shaping that runs ahead.
    pub lead_baseline: Option<LeadRatio>,
    /// The oscillation watch's half swing on the tracking error, µm, within
    /// [`WATCH_SWING_MIN`]…[`WATCH_SWING_MAX`]: a swing beyond it ends a
    /// half-cycle (the firmware's `watch` module). Set from the noise the
    /// stage's loops leave at rest (`fpi board autotune` measures it), so that
    /// a quiet stage's unstable loop is counted while it is small; `None`:
    /// [`WATCH_SWING_MAX`]. Needs position feedback.
    pub watch_swing: Option<Micrometres>,
}

/// The least half swing of the oscillation watch (µm, 0.075; `I16F16`): above
/// the residue a healthy loop's step leaves for tens of milliseconds on the
/// emulated stages (up to about 0.05 µm; at 0.04 µm its swings chain into
/// false trips).
pub const WATCH_SWING_MIN: Micrometres =
    Micrometres::from_bits(Field::WatchSwing.decl().bits().0 as i32);
/// The largest, and the default, half swing of the oscillation watch (µm, 0.2;
/// `I16F16`): well above the as-built stage's noise at rest, below the half
/// micrometre where the watch's growing rule starts.
pub const WATCH_SWING_MAX: Micrometres =
    Micrometres::from_bits(Field::WatchSwing.decl().bits().1 as i32);

/// The shape of a valid model: what the firmware's types are built from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Play operators.
    pub operators: usize,
    /// Creep terms.
    pub creep_terms: usize,
    /// A soft dead zone (else the hard one).
    pub dead_zone: bool,
    /// An output saturation (else none).
    pub saturation: bool,
    /// `Y[input_max]` of the PI with this sample's creep, µm (the inverse's input domain).
    pub output_max: Micrometres,
}

/// Lowest control rate a model may ask for, Hz.
pub const MIN_RATE_HZ: u32 = Field::Rate.decl().bits().0 as u32;
/// Highest control rate a model may ask for, Hz.
pub const MAX_RATE_HZ: u32 = Field::Rate.decl().bits().1 as u32;

/// Validates a whole model; the first problem, located by the model file's key.
///
/// The checks, in order: rate; PI (operator count, thresholds, partial sums,
/// ranges); creep terms; the PI with this sample's creep and its closed-form
/// inverse; coupling; dead zone and saturation tables; FEM tables; limits;
/// supervision settings and the force channel; feedback, shaping, stage dynamics
/// and damping; the loops' stability on the declared dynamics
/// ([`crate::stability::check`]). Each is the check the corresponding
/// constructor runs.
pub fn validate(m: &ModelSpec<'_>) -> Result<Shape, Invalid> {
    if m.rate_hz < MIN_RATE_HZ || m.rate_hz > MAX_RATE_HZ {
        return Err(Invalid::at(Field::Rate, ModelError::RateOutOfRange));
    }
    let n = m.operators.len();
    if n > MAX_OPERATORS {
        return Err(Invalid::at(Field::Operators, ModelError::TooManyOperators));
    }
    crate::pi::check(m.w0, m.operators, m.input_max).map_err(locate_pi)?;
    let creep = creep_terms(m.creep)?;
    let w0p =
        creep_slope(m.w0, &creep[..m.creep.len()]).map_err(|e| Invalid::at(Field::CreepGain, e))?;
    let sums = crate::pi::check(w0p, m.operators, m.input_max).map_err(|e| match e {
        // With the creep's share in w0 only the range can fail.
        ModelError::OutputOutOfRange => Invalid::at(Field::CreepGain, e),
        e => locate_pi(e),
    })?;
    let mut inverse = [Operator {
        threshold: I16F16::ZERO,
        weight: VoltsPerUm::ZERO,
    }; MAX_OPERATORS];
    crate::inverse::invert(w0p, m.operators, sums.output_max, &mut inverse[..n])
        .map_err(locate_pi)?;
    m.coupling.check()?;
    let maps = [
        (m.dead_zone, TableId::DeadZone, TableId::DeadZoneInverse),
        (
            m.saturation,
            TableId::Saturation,
            TableId::SaturationInverse,
        ),
    ];
    for (map, forward, inverse) in maps {
        if let Some(map) = map {
            table(&map.forward, forward)?;
            table(&map.inverse, inverse)?;
        }
    }
    let f_f = table(&m.f_f, TableId::FF)?;
    if let Some(k) = f_f.first_rise_below(0) {
        let e = ModelError::PreloadFalls { index: k as u16 };
        return Err(Invalid::at_index(
            Field::Table(TableId::FF, TablePart::Values),
            k,
            e,
        ));
    }
    let f_k = table(&m.f_k, TableId::FK)?;
    if let Some(k) = f_k.first_rise_below(1) {
        let e = ModelError::OutputNotInvertible { index: k as u16 };
        return Err(Invalid::at_index(
            Field::Table(TableId::FK, TablePart::Values),
            k,
            e,
        ));
    }
    let f_k_inv = table(&m.f_k_inv, TableId::FKInv)?;
    if let Some(j) = f_k.first_disagreement(&f_k_inv, INVERSE_TOLERANCE) {
        let e = ModelError::InverseDisagrees { index: j as u16 };
        return Err(Invalid::at_index(
            Field::Table(TableId::FKInv, TablePart::Values),
            j,
            e,
        ));
    }
    let limits = OutputLimits::new(m.u_min, m.u_max, m.max_step).map_err(|e| match e {
        ModelError::NonPositiveSlew => Invalid::at(Field::Slew, e),
        e => Invalid::at(Field::UMin, e),
    })?;
    check_settings(&limits, &f_k_inv, &m.supervision)?;
    check_force_tolerances(m)?;
    if let Some(f) = m.feedback {
        FeedbackConfig::new(f)?;
        check_position_tolerance(&f)?;
    }
    if let Some(s) = m.shaping {
        s.cascade()?;
        s.fir()?;
    }
    if let Some(d) = m.dynamics {
        d.check(m.rate_hz)?;
    }
    if let Some(d) = m.damping {
        DampingConfig::new(d, &m.supervision.channel)?;
        match m.dynamics {
            Some(dy) if dy.force_gain.to_bits() > 0 => {}
            _ => {
                return Err(Invalid::at(
                    Field::DampingGain,
                    ModelError::DampingWithoutDynamics,
                ))
            }
        }
    }
    if let Some(b) = m.lead_baseline {
        check_lead(m, b)?;
    }
    if let Some(h) = m.watch_swing {
        check_watch(m, h)?;
    }
    crate::stability::check(
        m.rate_hz,
        m.dynamics.as_ref(),
        m.supervision.channel.split.to_bits(),
        m.damping.as_ref(),
        m.feedback.as_ref(),
    )?;
    Ok(Shape {
        operators: n,
        creep_terms: m.creep.len(),
        dead_zone: m.dead_zone.is_some(),
        saturation: m.saturation.is_some(),
        output_max: sums.output_max,
    })
}

/// The force checks can trip: the tolerance of the reading against the FEM's
/// preload at most a quarter of the force window's span, the dynamic limit at
/// most the span.
fn check_force_tolerances(m: &ModelSpec<'_>) -> Result<(), Invalid> {
    let s = &m.supervision;
    let span = s.force.hi.to_bits() as i64 - s.force.lo.to_bits() as i64;
    if 4 * s.force_tolerance.to_bits() as i64 > span {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::ToleranceTooWide,
        ));
    }
    if s.channel.dynamic_limit.to_bits() as i64 > span {
        return Err(Invalid::at(
            Field::ForceDynamicLimit,
            ModelError::DynamicLimitBelowTolerance,
        ));
    }
    Ok(())
}

/// The position check can trip: its tolerance at most a quarter of the
/// sensor window's span.
fn check_position_tolerance(f: &FeedbackSpec) -> Result<(), Invalid> {
    let r = f.sensor;
    let span = r.hi.to_bits() as i64 - r.lo.to_bits() as i64;
    if 4 * f.tolerance.to_bits() as i64 > span {
        return Err(Invalid::at(
            Field::PositionTolerance,
            ModelError::ToleranceTooWide,
        ));
    }
    Ok(())
}

/// The lead's baseline: in `[1/2, 2)`, with damping and a preview to scale.
fn check_lead(m: &ModelSpec<'_>, b: LeadRatio) -> Result<(), Invalid> {
    if b < crate::lead::RATIO_MIN {
        return Err(Invalid::at(
            Field::LeadBaseline,
            ModelError::DampingOutOfRange,
        ));
    }
    let previews = matches!(m.shaping, Some(s) if s.preview > 0);
    if m.damping.is_none() || !previews {
        return Err(Invalid::at(
            Field::LeadBaseline,
            ModelError::LeadWithoutPreview,
        ));
    }
    Ok(())
}

/// The watch's half swing: within its range, with a position loop to watch.
fn check_watch(m: &ModelSpec<'_>, h: Micrometres) -> Result<(), Invalid> {
    if h < WATCH_SWING_MIN || h > WATCH_SWING_MAX {
        return Err(Invalid::at(
            Field::WatchSwing,
            ModelError::WatchSwingOutOfRange,
        ));
    }
    if m.feedback.is_none() {
        return Err(Invalid::at(
            Field::WatchSwing,
            ModelError::WatchWithoutFeedback,
        ));
    }
    Ok(())
}

/// The creep terms, each checked by [`Creep::new`].
fn creep_terms(specs: &[CreepSpec]) -> Result<[Creep; MAX_CREEP_TERMS], Invalid> {
    if specs.len() > MAX_CREEP_TERMS {
        return Err(Invalid::at(Field::Creep, ModelError::TooManyCreepTerms));
    }
    let mut out = [Creep::DISABLED; MAX_CREEP_TERMS];
    for (j, (c, o)) in specs.iter().zip(out.iter_mut()).enumerate() {
        *o = Creep::new(c.rate, c.gain).map_err(|e| Invalid::at_index(Field::CreepTau, j, e))?;
    }
    Ok(out)
}

/// A table, validated, its errors located in its part of the model file.
fn table<'a>(t: &TableSpec<'a>, id: TableId) -> Result<Table<'a>, Invalid> {
    t.table().map_err(|e| {
        let part = match e {
            ModelError::TableSpacing => TablePart::StepLog2,
            ModelError::TableSpan if t.x0.to_bits().unsigned_abs() > (4096 << 16) => TablePart::X0,
            _ => TablePart::Values,
        };
        match e.index() {
            Some(i) => Invalid::at_index(Field::Table(id, part), i, e),
            None => Invalid::at(Field::Table(id, part), e),
        }
    })
}

/// Locates an error of [`crate::pi::check`] or [`crate::inverse::invert`]: partial
/// sum `S_j` is `w0` for `j = 0`, else weight `j - 1`; threshold errors name the
/// threshold.
fn locate_pi(e: ModelError) -> Invalid {
    match e {
        ModelError::NonPositiveSlope { index } | ModelError::InverseWeightOutOfRange { index } => {
            if index == 0 {
                Invalid::at(Field::PiW0, e)
            } else {
                Invalid::at_index(Field::PiWeights, index as usize - 1, e)
            }
        }
        ModelError::NegativeThreshold { index }
        | ModelError::ThresholdsNotSorted { index }
        | ModelError::ThresholdBeyondDomain { index } => {
            Invalid::at_index(Field::PiThresholds, index as usize, e)
        }
        ModelError::DomainOutOfRange => Invalid::at(Field::PiInputMax, e),
        ModelError::TooManyOperators => Invalid::at(Field::Operators, e),
        e => Invalid::at(Field::PiWeights, e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{ControllerParts, ForceSource, Interval};
    use crate::q::{coupling, gain, Newtons};
    use crate::testkit;

    fn v<S: crate::q::Signal>(x: f64) -> S {
        crate::testkit::v(x)
    }

    /// The test stage's parts with one creep term.
    struct Owned {
        parts: ControllerParts<'static, 3>,
        creep: Vec<CreepSpec>,
    }

    fn owned() -> Owned {
        Owned {
            parts: testkit::parts(ForceSource::Measured),
            creep: vec![CreepSpec {
                rate: coupling(0.005).unwrap(),
                gain: gain(0.003).unwrap(),
            }],
        }
    }

    fn spec(o: &Owned) -> ModelSpec<'_> {
        testkit::spec(&o.parts, &o.creep)
    }

    fn key(e: Invalid) -> String {
        let mut s = String::new();
        e.write_key(&mut s).unwrap();
        s
    }

    #[test]
    fn a_valid_model_passes_with_its_shape() {
        let o = owned();
        let shape = validate(&spec(&o)).unwrap();
        assert_eq!((shape.operators, shape.creep_terms), (3, 1));
        assert!(!shape.dead_zone && !shape.saturation);
    }

    /// The tables the coupled equation and the inverse rest on: a preload that
    /// falls as the stack extends, an output that stops rising (no inverse), and
    /// an inverse of another map are refused by the table's key and knot.
    #[test]
    fn tables_that_break_the_models_assumptions_are_refused_by_key() {
        let o = owned();
        let base = spec(&o);
        let e = |m: ModelSpec<'_>| {
            let e = validate(&m).unwrap_err();
            (key(e), e.error)
        };
        let falling = testkit::table(0.0, -4, 512, |x| 100.0 - 0.5 * x);
        assert_eq!(
            e(ModelSpec {
                f_f: TableSpec::of(&falling),
                ..base
            }),
            (
                "tables.f_f.values[1]".to_string(),
                ModelError::PreloadFalls { index: 1 }
            )
        );
        let constant = testkit::table(0.0, -4, 512, |_| 20.0);
        assert_eq!(
            e(ModelSpec {
                f_k: TableSpec::of(&constant),
                ..base
            }),
            (
                "tables.f_k.values[1]".to_string(),
                ModelError::OutputNotInvertible { index: 1 }
            )
        );
        let mut flat_end = base.f_k.segments.to_vec();
        flat_end[300] = Segment::new(flat_end[300].start(), I16F16::ZERO);
        for s in &mut flat_end[301..] {
            *s = Segment::new(s.start() - base.f_k.segments[300].rise(), s.rise());
        }
        assert_eq!(
            e(ModelSpec {
                f_k: TableSpec {
                    segments: &flat_end,
                    ..base.f_k
                },
                ..base
            }),
            (
                "tables.f_k.values[301]".to_string(),
                ModelError::OutputNotInvertible { index: 301 }
            )
        );
        let other = testkit::table(0.0, -2, 179, |y| y / 1.5);
        let (k, err) = e(ModelSpec {
            f_k_inv: TableSpec::of(&other),
            ..base
        });
        assert!(k.starts_with("tables.f_k_inv.values["), "{k}");
        assert!(
            matches!(err, ModelError::InverseDisagrees { index } if index > 0),
            "{err:?}"
        );
        // A preload that stays level over part of the stroke is allowed.
        let level = testkit::table(0.0, -4, 512, |x| 60.0 + 4.0 * (x - 10.0).max(0.0));
        assert!(validate(&ModelSpec {
            f_f: TableSpec::of(&level),
            ..base
        })
        .is_ok());
    }

    #[test]
    fn every_failure_names_its_key() {
        let o = owned();
        let base = spec(&o);
        let check = |m: ModelSpec<'_>, want_key: &str, want: ModelError| {
            let e = validate(&m).unwrap_err();
            assert_eq!((key(e).as_str(), e.error), (want_key, want), "{e}");
        };
        let sup = |s: Supervision| ModelSpec {
            supervision: s,
            feedback: None,
            shaping: None,
            dynamics: None,
            damping: None,
            ..base
        };
        check(
            ModelSpec {
                rate_hz: 50,
                ..base
            },
            "controller.rate_hz",
            ModelError::RateOutOfRange,
        );
        let mut ops = base.operators.to_vec();
        ops[1].weight = gain(-0.2).unwrap();
        check(
            ModelSpec {
                operators: &ops,
                ..base
            },
            "pi.weights_um_per_v[1]",
            ModelError::NonPositiveSlope { index: 2 },
        );
        let mut ops = base.operators.to_vec();
        ops.swap(0, 2);
        check(
            ModelSpec {
                operators: &ops,
                ..base
            },
            "pi.thresholds_v[1]",
            ModelError::ThresholdsNotSorted { index: 1 },
        );
        check(
            ModelSpec {
                w0: gain(0.001).unwrap(),
                ..base
            },
            "pi.w0_um_per_v",
            ModelError::InverseWeightOutOfRange { index: 0 },
        );
        let creep = [CreepSpec {
            rate: CreepRate::ZERO,
            gain: gain(0.003).unwrap(),
        }];
        check(
            ModelSpec {
                creep: &creep,
                ..base
            },
            "creep[0].tau_s",
            ModelError::CreepRateOutOfRange,
        );
        check(
            ModelSpec {
                coupling: Coupling {
                    k_q: CreepRate::from_bits(i32::MAX),
                    ..base.coupling
                },
                ..base
            },
            "coupling.k_q_v_per_n2",
            ModelError::CurvatureOutOfRange,
        );
        // The spacing the old file check let through (step_log2 = -16) is refused by name.
        check(
            ModelSpec {
                f_f: TableSpec {
                    shift: 0,
                    ..base.f_f
                },
                ..base
            },
            "tables.f_f.step_log2",
            ModelError::TableSpacing,
        );
        let mut bad = base.f_k.segments.to_vec();
        bad[7] = Segment::new(bad[7].start(), -bad[7].rise());
        check(
            ModelSpec {
                f_k: TableSpec {
                    segments: &bad,
                    ..base.f_k
                },
                ..base
            },
            "tables.f_k.values[8]",
            ModelError::TableNotMonotone { index: 8 },
        );
        check(
            ModelSpec {
                u_min: v(200.0),
                ..base
            },
            "controller.u_min_v",
            ModelError::LimitsInverted,
        );
        check(
            ModelSpec {
                max_step: Volts::ZERO,
                ..base
            },
            "controller.slew_v_per_ms",
            ModelError::NonPositiveSlew,
        );
        let s = base.supervision;
        check(
            sup(Supervision {
                reference: Interval {
                    lo: Micrometres::ZERO,
                    hi: v(500.0),
                },
                ..s
            }),
            "controller.reference_max_um",
            ModelError::ReferenceOutsideTable,
        );
        check(
            sup(Supervision {
                safe_voltage: v(-1.0),
                ..s
            }),
            "controller.safe_voltage_v",
            ModelError::SafeVoltageOutsideLimits,
        );
        check(
            sup(Supervision {
                force_tolerance: Newtons::ZERO,
                ..s
            }),
            "controller.force_tolerance_n",
            ModelError::NonPositiveTolerance,
        );
    }

    /// A check a model could switch off by a setting is refused by the
    /// setting's key: tolerances too wide for their check to trip.
    #[test]
    fn settings_that_would_switch_a_check_off_are_refused_by_key() {
        let o = owned();
        let base = spec(&o);
        let check = |m: ModelSpec<'_>, want_key: &str, want: ModelError| {
            let e = validate(&m).unwrap_err();
            assert_eq!((key(e).as_str(), e.error), (want_key, want), "{e}");
        };
        let s = base.supervision;
        // A force tolerance beyond a quarter of the 20–200 N window (45 N).
        check(
            ModelSpec {
                supervision: Supervision {
                    force_tolerance: v(46.0),
                    channel: crate::control::ForceChannel {
                        dynamic_limit: v(46.0),
                        ..s.channel
                    },
                    ..s
                },
                ..base
            },
            "controller.force_tolerance_n",
            ModelError::ToleranceTooWide,
        );
        // A dynamic limit beyond the force window's 180 N could never trip.
        check(
            ModelSpec {
                supervision: Supervision {
                    channel: crate::control::ForceChannel {
                        dynamic_limit: v(190.0),
                        ..s.channel
                    },
                    ..s
                },
                ..base
            },
            "controller.force_dynamic_limit_n",
            ModelError::DynamicLimitBelowTolerance,
        );
        // A position tolerance beyond a quarter of the −5…30 µm sensor
        // window (8.75 µm).
        let feedback = |tolerance: f64| FeedbackSpec {
            kp: crate::q::LoopGain::from_num(0.5),
            ki: crate::q::LoopGain::from_num(0.01),
            limit: v(5.0),
            sensor: Interval {
                lo: v(-5.0),
                hi: v(30.0),
            },
            tolerance: v(tolerance),
        };
        check(
            ModelSpec {
                feedback: Some(feedback(1000.0)),
                ..base
            },
            "feedback.position_tolerance_um",
            ModelError::ToleranceTooWide,
        );
        check(
            ModelSpec {
                feedback: Some(feedback(9.0)),
                ..base
            },
            "feedback.position_tolerance_um",
            ModelError::ToleranceTooWide,
        );
        assert!(validate(&ModelSpec {
            feedback: Some(feedback(8.5)),
            ..base
        })
        .is_ok());
    }
}
