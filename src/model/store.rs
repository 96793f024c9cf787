//! A model held in RAM: loaded from an image, checked against the board, and run
//! by the control step as a [`RuntimeController`].
//!
//! A board has room for at most `N` play operators, `C` creep terms and `S` table
//! intervals (its capacity, set when the firmware is built) and hardware limits it
//! cannot exceed ([`Board`]). [`ModelStore::load`] reads an image
//! ([`super::image`]), refuses one that does not fit the capacity or widens a
//! hardware limit, and runs the validator ([`super::validate`]). A model with fewer
//! operators than `N` is padded with operators of zero weight at the top of the
//! input domain, which contribute nothing (bit for bit); its creep terms are run
//! as many as it has.

use fixed::types::I16F16;

use super::image::{
    Reader, FLAG_DAMPING, FLAG_DEAD_ZONE, FLAG_DYNAMICS, FLAG_FEEDBACK, FLAG_LEAD, FLAG_PREDICTED,
    FLAG_PREVIEW, FLAG_SATURATION, FLAG_SHAPING, FLAG_WATCH,
};
use super::{validate, CreepSpec, MapSpec, ModelSpec, Shape, TableSpec};
use crate::biquad::{ShapingSpec, SHAPING_SECTIONS};
use crate::control::{
    ControllerConfig, ControllerParts, ForceChannel, ForceSource, Interval, Supervision,
};
use crate::damping::{DampingSpec, DynamicsSpec};
use crate::error::{Field, Invalid, ModelError, TableId, TablePart};
use crate::feedback::FeedbackSpec;
use crate::fpi::{Coupling, Creep, Fpi, Map};
use crate::limits::OutputLimits;
use crate::pi::PiModel;
use crate::play::Operator;
use crate::q::{
    CreepRate, LeadRatio, LoopGain, Micrometres, Newtons, NewtonsPerUm, UmPerVolt, Volts,
};
use crate::table::{Segment, Table};

/// The control step's configuration for a model received at run time: `N`
/// operators (padded), up to `C` creep terms, and dead zone and saturation
/// chosen at run time.
pub type RuntimeController<'a, const N: usize, const C: usize> =
    ControllerConfig<'a, N, C, Option<Map<'a>>, Option<Map<'a>>>;

/// What the board's hardware allows: a model may narrow these, never widen them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HardwareLimits {
    /// Lowest amplifier setpoint, V.
    pub u_min: Volts,
    /// Highest amplifier setpoint, V.
    pub u_max: Volts,
    /// Largest setpoint change per control step, V (the amplifier's current into the
    /// stack's capacitance).
    pub max_step: Volts,
    /// The window the safe voltage must lie in (the stack's safe voltages), V.
    pub safe: Interval<Volts>,
    /// The position channel's rails, µm: a broken wire reads one, so a
    /// model's sensor window must lie strictly inside them.
    pub position: Interval<Micrometres>,
    /// The force channel's rails, N: likewise for the force window.
    pub force: Interval<Newtons>,
}

/// The board a model must fit: its control rate and hardware limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Board {
    /// The control ISR's rate, Hz.
    pub rate_hz: u32,
    /// What the hardware allows.
    pub limits: HardwareLimits,
}

/// Whether a window `w` lies strictly inside the `rails` (a broken wire reads a
/// rail); `lo` or `hi` names the end that does not.
fn rails<T: PartialOrd>(
    w: Interval<T>,
    rails: Interval<T>,
    lo: Field,
    hi: Field,
) -> Result<(), Invalid> {
    if w.lo <= rails.lo {
        Err(Invalid::at(lo, ModelError::OutsideRails))
    } else if w.hi >= rails.hi {
        Err(Invalid::at(hi, ModelError::OutsideRails))
    } else {
        Ok(())
    }
}

impl Board {
    /// Checks that a model runs at this board's rate and stays inside its hardware
    /// limits; the first limit it would widen, by key.
    pub fn check(&self, m: &ModelSpec<'_>) -> Result<(), Invalid> {
        let h = &self.limits;
        let widens = |field| Err(Invalid::at(field, ModelError::WidensHardwareLimit));
        if m.rate_hz != self.rate_hz {
            return Err(Invalid::at(Field::Rate, ModelError::RateMismatch));
        }
        if m.u_min < h.u_min {
            return widens(Field::UMin);
        }
        if m.u_max > h.u_max {
            return widens(Field::UMax);
        }
        if m.max_step > h.max_step {
            return widens(Field::Slew);
        }
        let s = m.supervision.safe_voltage;
        if s < h.safe.lo || s > h.safe.hi {
            return widens(Field::SafeVoltage);
        }
        rails(
            m.supervision.force,
            h.force,
            Field::ForceMin,
            Field::ForceMax,
        )?;
        if let Some(f) = m.feedback {
            rails(f.sensor, h.position, Field::PositionMin, Field::PositionMax)?;
        }
        Ok(())
    }
}

/// Where a table lies in the store's pool of intervals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Span {
    x0: I16F16,
    shift: u32,
    start: usize,
    len: usize,
}

const NO_SPAN: Span = Span {
    x0: I16F16::ZERO,
    shift: 0,
    start: 0,
    len: 0,
};

/// A model in RAM with room for `N` operators, `C` creep terms and `S` table
/// intervals (configuration, loaded at start-up or when the board receives one).
#[derive(Debug, Clone)]
pub struct ModelStore<const N: usize, const C: usize, const S: usize> {
    /// The scalars; the arrays are lent by [`spec`](Self::spec).
    base: Scalars,
    operators: [Operator<UmPerVolt>; N],
    n: usize,
    creep: [CreepSpec; C],
    c: usize,
    pool: [Segment; S],
    /// f_F, f_K, f_K⁻¹, dead zone (map, inverse), saturation (map, inverse).
    spans: [Span; 7],
    loaded: bool,
}

const ORDER: [TableId; 7] = [
    TableId::FF,
    TableId::FK,
    TableId::FKInv,
    TableId::DeadZone,
    TableId::DeadZoneInverse,
    TableId::Saturation,
    TableId::SaturationInverse,
];

impl<const N: usize, const C: usize, const S: usize> Default for ModelStore<N, C, S> {
    fn default() -> Self {
        Self::new()
    }
}

/// A model's scalars as a store keeps them: all zero before an image is read,
/// so an empty store is all zero bytes (a board's stores go to `.bss` and cost no
/// flash for their initial value).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Scalars {
    rate_hz: u32,
    w0: UmPerVolt,
    input_max: Volts,
    coupling: Coupling,
    u_min: Volts,
    u_max: Volts,
    max_step: Volts,
    supervision: Supervision,
    dead_zone: bool,
    saturation: bool,
    feedback: FeedbackSpec,
    has_feedback: bool,
    shaping: ShapingSpec,
    has_shaping: bool,
    dynamics: DynamicsSpec,
    has_dynamics: bool,
    damping: DampingSpec,
    has_damping: bool,
    lead_baseline: LeadRatio,
    has_lead: bool,
    watch_swing: Micrometres,
    has_watch: bool,
}

const NO_SCALARS: Scalars = Scalars {
    rate_hz: 0,
    w0: UmPerVolt::ZERO,
    input_max: Volts::ZERO,
    coupling: Coupling::paper(crate::q::VoltsPerNewton::ZERO),
    u_min: Volts::ZERO,
    u_max: Volts::ZERO,
    max_step: Volts::ZERO,
    supervision: Supervision {
        reference: Interval {
            lo: Micrometres::ZERO,
            hi: Micrometres::ZERO,
        },
        force: Interval {
            lo: Newtons::ZERO,
            hi: Newtons::ZERO,
        },
        force_tolerance: Newtons::ZERO,
        safe_voltage: Volts::ZERO,
        force_source: ForceSource::Measured,
        channel: ForceChannel {
            split: CreepRate::ZERO,
            dynamic_limit: Newtons::ZERO,
        },
    },
    dead_zone: false,
    saturation: false,
    feedback: FeedbackSpec {
        kp: LoopGain::ZERO,
        ki: LoopGain::ZERO,
        limit: Micrometres::ZERO,
        sensor: Interval {
            lo: Micrometres::ZERO,
            hi: Micrometres::ZERO,
        },
        tolerance: Micrometres::ZERO,
    },
    has_feedback: false,
    shaping: ShapingSpec {
        sections: [[0; 5]; SHAPING_SECTIONS],
        preview: 0,
        taps: [0; crate::preview::TAPS],
    },
    has_shaping: false,
    dynamics: DynamicsSpec {
        mode_mhz: 0,
        damping: CreepRate::ZERO,
        lag_mhz: 0,
        force_gain: NewtonsPerUm::ZERO,
    },
    has_dynamics: false,
    damping: DampingSpec {
        gain: LoopGain::ZERO,
        highpass: CreepRate::ZERO,
        leak: CreepRate::ZERO,
        limit: Micrometres::ZERO,
    },
    has_damping: false,
    lead_baseline: LeadRatio::ZERO,
    has_lead: false,
    watch_swing: Micrometres::ZERO,
    has_watch: false,
};

impl<const N: usize, const C: usize, const S: usize> ModelStore<N, C, S> {
    /// An empty store (no model). All its bytes are zero, so a board's stores
    /// cost no flash for their initial value (they go to `.bss`).
    pub const fn new() -> Self {
        Self {
            base: NO_SCALARS,
            operators: [Operator {
                threshold: I16F16::ZERO,
                weight: UmPerVolt::ZERO,
            }; N],
            n: 0,
            creep: [CreepSpec {
                rate: CreepRate::ZERO,
                gain: UmPerVolt::ZERO,
            }; C],
            c: 0,
            pool: [Segment::from_bits(0, 0); S],
            spans: [NO_SPAN; 7],
            loaded: false,
        }
    }

    /// Whether the store holds a valid model.
    pub const fn is_loaded(&self) -> bool {
        self.loaded
    }

    /// The model, borrowing the store's arrays (empty before a model is loaded).
    pub fn spec(&self) -> ModelSpec<'_> {
        let b = &self.base;
        let table = |k: usize| {
            let s = self.spans[k];
            TableSpec {
                x0: s.x0,
                shift: s.shift,
                segments: self.pool.get(s.start..s.start + s.len).unwrap_or(&[]),
            }
        };
        let map = |k: usize, present: bool| {
            present.then(|| MapSpec {
                forward: table(k),
                inverse: table(k + 1),
            })
        };
        ModelSpec {
            rate_hz: b.rate_hz,
            w0: b.w0,
            operators: self.operators.get(..self.n).unwrap_or(&[]),
            input_max: b.input_max,
            coupling: b.coupling,
            dead_zone: map(3, b.dead_zone),
            saturation: map(5, b.saturation),
            creep: self.creep.get(..self.c).unwrap_or(&[]),
            f_f: table(0),
            f_k: table(1),
            f_k_inv: table(2),
            u_min: b.u_min,
            u_max: b.u_max,
            max_step: b.max_step,
            supervision: b.supervision,
            feedback: b.has_feedback.then_some(b.feedback),
            shaping: b.has_shaping.then_some(b.shaping),
            dynamics: b.has_dynamics.then_some(b.dynamics),
            damping: b.has_damping.then_some(b.damping),
            lead_baseline: b.has_lead.then_some(b.lead_baseline),
            watch_swing: b.has_watch.then_some(b.watch_swing),
        }
    }

    /// Reads an image into the store, checks it against the board and validates
    /// it; its shape. On any error the store is left empty (a board keeps running
    /// the model in its other store).
    pub fn load(&mut self, image: &[u8], board: &Board) -> Result<Shape, Invalid> {
        self.loaded = false;
        self.read(image)?;
        let spec = self.spec();
        board.check(&spec)?;
        let shape = validate(&spec)?;
        self.loaded = true;
        Ok(shape)
    }

    fn read(&mut self, image: &[u8]) -> Result<(), Invalid> {
        let mut r = Reader::new(image)?;
        let over = |field| Invalid::at(field, ModelError::OverCapacity);
        let b = &mut self.base;
        b.rate_hz = r.u32()?;
        b.w0 = UmPerVolt::from_bits(r.i32()?);
        b.input_max = Volts::from_bits(r.i32()?);
        let (n, c) = (r.u8()? as usize, r.u8()? as usize);
        r.u8()?;
        r.u8()?;
        if n > N {
            return Err(over(Field::Operators));
        }
        if c > C {
            return Err(over(Field::Creep));
        }
        for o in self.operators.iter_mut().take(n) {
            o.threshold = I16F16::from_bits(r.i32()?);
            o.weight = UmPerVolt::from_bits(r.i32()?);
        }
        self.n = n;
        let k = &mut b.coupling;
        k.offset = Volts::from_bits(r.i32()?);
        k.k_f = crate::q::VoltsPerNewton::from_bits(r.i32()?);
        k.k_q = crate::q::VoltsPerNewton2::from_bits(r.i32()?);
        k.force_q = Newtons::from_bits(r.i32()?);
        k.compliance = crate::q::UmPerNewton::from_bits(r.i32()?);
        k.force_ref = Newtons::from_bits(r.i32()?);
        for t in self.creep.iter_mut().take(c) {
            t.rate = CreepRate::from_bits(r.i32()?);
            t.gain = UmPerVolt::from_bits(r.i32()?);
        }
        self.c = c;
        b.u_min = Volts::from_bits(r.i32()?);
        b.u_max = Volts::from_bits(r.i32()?);
        b.max_step = Volts::from_bits(r.i32()?);
        let sup = &mut b.supervision;
        sup.reference = Interval {
            lo: Micrometres::from_bits(r.i32()?),
            hi: Micrometres::from_bits(r.i32()?),
        };
        sup.force = Interval {
            lo: Newtons::from_bits(r.i32()?),
            hi: Newtons::from_bits(r.i32()?),
        };
        sup.force_tolerance = Newtons::from_bits(r.i32()?);
        sup.safe_voltage = Volts::from_bits(r.i32()?);
        sup.channel = ForceChannel {
            split: CreepRate::from_bits(r.i32()?),
            dynamic_limit: Newtons::from_bits(r.i32()?),
        };
        sup.force_source = if r.flags & FLAG_PREDICTED != 0 {
            ForceSource::Predicted
        } else {
            ForceSource::Measured
        };
        b.dead_zone = r.flags & FLAG_DEAD_ZONE != 0;
        b.saturation = r.flags & FLAG_SATURATION != 0;
        let (dz, sat) = (b.dead_zone, b.saturation);
        let mut used = 0;
        for (k, id) in ORDER.into_iter().enumerate() {
            let wanted = k < 3 || (k < 5 && dz) || (k >= 5 && sat);
            self.spans[k] = if wanted {
                read_table(&mut r, &mut self.pool, &mut used, id)?
            } else {
                NO_SPAN
            };
        }
        b.has_feedback = r.flags & FLAG_FEEDBACK != 0;
        if b.has_feedback {
            let f = &mut b.feedback;
            f.kp = LoopGain::from_bits(r.i32()?);
            f.ki = LoopGain::from_bits(r.i32()?);
            let mut um = || r.i32().map(Micrometres::from_bits);
            f.limit = um()?;
            f.sensor = Interval {
                lo: um()?,
                hi: um()?,
            };
            f.tolerance = um()?;
        }
        b.has_shaping = r.flags & FLAG_SHAPING != 0;
        if b.has_shaping {
            for c in b.shaping.sections.iter_mut().flatten() {
                *c = r.i32()?;
            }
        }
        b.has_dynamics = r.flags & FLAG_DYNAMICS != 0;
        if b.has_dynamics {
            let d = &mut b.dynamics;
            d.mode_mhz = r.u32()?;
            d.damping = CreepRate::from_bits(r.i32()?);
            d.lag_mhz = r.u32()?;
            d.force_gain = NewtonsPerUm::from_bits(r.i32()?);
        }
        b.has_damping = r.flags & FLAG_DAMPING != 0;
        if b.has_damping {
            let d = &mut b.damping;
            d.gain = LoopGain::from_bits(r.i32()?);
            d.highpass = CreepRate::from_bits(r.i32()?);
            d.leak = CreepRate::from_bits(r.i32()?);
            d.limit = Micrometres::from_bits(r.i32()?);
        }
        b.shaping.preview = 0;
        b.shaping.taps = [0; crate::preview::TAPS];
        if r.flags & FLAG_PREVIEW != 0 {
            // A preview without shaping, or beyond a byte, is not a model this
            // build wrote: refused (the validator bounds the rest).
            let ticks = r.u32()?;
            b.shaping.preview = match u8::try_from(ticks) {
                Ok(t) if b.has_shaping => t,
                _ => return Err(Invalid::at(Field::Preview, ModelError::OverCapacity)),
            };
            for t in b.shaping.taps.iter_mut() {
                *t = r.i32()?;
            }
        }
        b.has_lead = r.flags & FLAG_LEAD != 0;
        if b.has_lead {
            b.lead_baseline = LeadRatio::from_bits(r.i32()?);
        }
        b.has_watch = r.flags & FLAG_WATCH != 0;
        if b.has_watch {
            b.watch_swing = Micrometres::from_bits(r.i32()?);
        }
        if !r.finished() {
            return Err(Invalid::at(Field::Model, ModelError::Truncated));
        }
        Ok(())
    }

    /// The control step's configuration for the loaded model: operators padded to
    /// `N` with zero weights at the top of the domain, the creep terms in use.
    pub fn controller(&self) -> Result<RuntimeController<'_, N, C>, Invalid> {
        let model = |e: ModelError| Invalid::at(Field::Model, e);
        if !self.loaded {
            return Err(model(ModelError::Truncated));
        }
        let m = self.spec();
        let mut ops = [Operator {
            threshold: m.input_max.raw(),
            weight: UmPerVolt::ZERO,
        }; N];
        for (o, s) in ops.iter_mut().zip(m.operators) {
            *o = *s;
        }
        let pi = PiModel::from_operators(m.w0, ops, m.input_max).map_err(model)?;
        let mut creep = [Creep::DISABLED; C];
        for (t, s) in creep.iter_mut().zip(m.creep) {
            *t = Creep::new(s.rate, s.gain).map_err(model)?;
        }
        fn table<'t>(t: &TableSpec<'t>) -> Result<Table<'t>, Invalid> {
            t.table().map_err(|e| Invalid::at(Field::Model, e))
        }
        fn map<'t>(m: &Option<MapSpec<'t>>) -> Result<Option<Map<'t>>, Invalid> {
            m.as_ref()
                .map(|m| {
                    Ok(Map {
                        forward: table(&m.forward)?,
                        inverse: table(&m.inverse)?,
                    })
                })
                .transpose()
        }
        let fpi = Fpi::new(
            pi,
            m.coupling,
            map(&m.dead_zone)?,
            map(&m.saturation)?,
            creep,
        )
        .and_then(|f| f.with_creep_terms(m.creep.len()))
        .map_err(model)?
        .resolved();
        ControllerConfig::new(ControllerParts {
            fpi,
            f_f: table(&m.f_f)?,
            f_k: table(&m.f_k)?,
            f_k_inv: table(&m.f_k_inv)?,
            limits: OutputLimits::new(m.u_min, m.u_max, m.max_step).map_err(model)?,
            supervision: m.supervision,
        })
        .map_err(model)
    }
}

/// Reads one table's knots into the pool as intervals; where it lies.
fn read_table<const S: usize>(
    r: &mut Reader<'_>,
    pool: &mut [Segment; S],
    used: &mut usize,
    id: TableId,
) -> Result<Span, Invalid> {
    let x0 = I16F16::from_bits(r.i32()?);
    let shift = r.u32()?;
    let knots = r.u32()? as usize;
    let intervals = knots.saturating_sub(1);
    if *used + intervals > S {
        return Err(Invalid::at(
            Field::Table(id, TablePart::Values),
            ModelError::OverCapacity,
        ));
    }
    let start = *used;
    let mut prev = if knots > 0 { Some(r.i32()?) } else { None };
    for seg in pool.iter_mut().skip(start).take(intervals) {
        let (a, b) = (prev.unwrap_or(0), r.i32()?);
        *seg = Segment::from_wide(a, b as i64 - a as i64);
        prev = Some(b);
    }
    *used += intervals;
    Ok(Span {
        x0,
        shift,
        start,
        len: intervals,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::ControllerState;
    use crate::model::image::{encode, encoded_len, HEADER_LEN};
    use crate::q::{coupling, gain};
    use crate::testkit;

    const BOARD: Board = Board {
        rate_hz: 20_000,
        limits: HardwareLimits {
            u_min: Volts::ZERO,
            u_max: Volts::from_bits(150 << 16),
            max_step: Volts::from_bits(5 << 16),
            safe: Interval {
                lo: Volts::ZERO,
                hi: Volts::from_bits(10 << 16),
            },
            position: Interval {
                lo: Micrometres::from_bits(-10 << 16),
                hi: Micrometres::from_bits(70 << 16),
            },
            force: Interval {
                lo: Newtons::from_bits(-5 << 16),
                hi: Newtons::from_bits(506 << 16),
            },
        },
    };

    type Store = ModelStore<5, 2, 2048>;

    fn image(spec: &ModelSpec<'_>) -> Vec<u8> {
        let mut out = vec![0; encoded_len(spec)];
        let n = encode(spec, &mut out).unwrap();
        assert_eq!(n, out.len());
        out
    }

    fn parts() -> ControllerParts<'static, 3> {
        testkit::parts(ForceSource::Measured)
    }

    #[test]
    fn an_image_round_trips_into_the_store() {
        let p = parts();
        let creep = [CreepSpec {
            rate: coupling(0.005).unwrap(),
            gain: gain(0.003).unwrap(),
        }];
        let spec = testkit::spec(&p, &creep);
        let img = image(&spec);
        let mut store = Store::new();
        let shape = store.load(&img, &BOARD).unwrap();
        assert_eq!((shape.operators, shape.creep_terms), (3, 1));
        assert_eq!(store.spec(), spec);
        // And back to the same bytes.
        assert_eq!(image(&store.spec()), img);
    }

    #[test]
    fn a_shaping_filter_travels_with_the_image_and_is_validated() {
        let p = parts();
        let one = 1 << crate::biquad::COEFF_FRAC;
        // A stable unit-gain section: y = 0.5·x + 0.5·y[n-1]... as b0 = 0.5, a1 = -0.5.
        let section = [one / 2, 0, 0, -one / 2, 0];
        let shaping = ShapingSpec {
            sections: [section, ShapingSpec::IDENTITY.sections[0]],
            ..ShapingSpec::IDENTITY
        };
        let spec = ModelSpec {
            shaping: Some(shaping),
            ..testkit::spec(&p, &[])
        };
        let img = image(&spec);
        let mut store = Store::new();
        store.load(&img, &BOARD).unwrap();
        assert_eq!(store.spec().shaping, Some(shaping));
        assert_eq!(image(&store.spec()), img);
        let refuse = |s: [i32; 5]| {
            let bad = ModelSpec {
                shaping: Some(ShapingSpec {
                    sections: [ShapingSpec::IDENTITY.sections[0], s],
                    ..ShapingSpec::IDENTITY
                }),
                ..spec
            };
            let e = Store::new().load(&image(&bad), &BOARD).unwrap_err();
            (e.field, e.index, e.error)
        };
        // A static gain of 1.01 would move a held position: refused.
        assert_eq!(
            refuse([one / 2 + one / 200, 0, 0, -one / 2, 0]),
            (Field::Shaping, Some(1), ModelError::FilterStaticGain)
        );
        // A pole on the unit circle: refused.
        assert_eq!(
            refuse([0, 0, 0, -one, 0]),
            (Field::Shaping, Some(1), ModelError::FilterUnstable)
        );
        // A preview (taps on the delay line) travels in its own block, read
        // back as written; one beyond the board's delay line, one that is not
        // of unit gain and one with sections as well are refused.
        let mut taps = [0; crate::preview::TAPS];
        taps[..3].copy_from_slice(&[one * 2, -one / 2, -one / 2]);
        let ahead = ShapingSpec {
            preview: 3,
            taps,
            ..ShapingSpec::IDENTITY
        };
        for ticks in [1, crate::preview::PREVIEW_MAX] {
            let s = ShapingSpec {
                preview: ticks,
                ..ahead
            };
            let m = ModelSpec {
                shaping: Some(s),
                ..spec
            };
            let img = image(&m);
            assert_eq!(img.len(), image(&spec).len() + 4 + 4 * crate::preview::TAPS);
            let mut store = Store::new();
            store.load(&img, &BOARD).unwrap();
            assert_eq!(store.spec().shaping, Some(s));
        }
        let refused = |s: ShapingSpec| {
            let m = ModelSpec {
                shaping: Some(s),
                ..spec
            };
            let e = Store::new().load(&image(&m), &BOARD).unwrap_err();
            (e.field, e.error)
        };
        let long = ShapingSpec {
            preview: crate::preview::PREVIEW_MAX + 1,
            ..ahead
        };
        let mut gain = ahead;
        gain.taps[0] += 1;
        let both = ShapingSpec {
            sections: shaping.sections,
            ..ahead
        };
        assert_eq!(refused(long), (Field::Preview, ModelError::OverCapacity));
        assert_eq!(
            refused(gain),
            (Field::Preview, ModelError::FilterStaticGain)
        );
        assert_eq!(
            refused(both),
            (Field::Preview, ModelError::PreviewWithSections)
        );
    }

    /// Position-feedback settings the validator accepts.
    fn feedback() -> crate::feedback::FeedbackSpec {
        crate::feedback::FeedbackSpec {
            kp: LoopGain::from_num(0.25),
            ki: LoopGain::from_num(0.015),
            limit: crate::testkit::v(3.0),
            sensor: Interval {
                lo: crate::testkit::v(-5.0),
                hi: crate::testkit::v(50.0),
            },
            tolerance: crate::testkit::v(4.0),
        }
    }

    #[test]
    fn feedback_settings_travel_with_the_image_and_are_validated() {
        let p = parts();
        let fb = feedback();
        let spec = ModelSpec {
            feedback: Some(fb),
            ..testkit::spec(&p, &[])
        };
        let img = image(&spec);
        let mut store = Store::new();
        store.load(&img, &BOARD).unwrap();
        assert_eq!(store.spec().feedback, Some(fb));
        assert_eq!(image(&store.spec()), img);
        // Without the block the image is four words shorter and has none.
        let plain = image(&testkit::spec(&p, &[]));
        assert_eq!(plain.len() + 24, img.len());
        store.load(&plain, &BOARD).unwrap();
        assert_eq!(store.spec().feedback, None);
        // The one validator names the key.
        let bad = ModelSpec {
            feedback: Some(crate::feedback::FeedbackSpec {
                ki: LoopGain::from_num(2.0),
                ..fb
            }),
            ..spec
        };
        let e = Store::new().load(&image(&bad), &BOARD).unwrap_err();
        assert_eq!(
            (e.field, e.error),
            (Field::FeedbackKi, ModelError::GainOutOfRange)
        );
    }

    /// The watch's half swing travels in its own block (flag bit 9), within
    /// its range and only with a position loop to watch.
    #[test]
    fn the_watch_swing_travels_with_the_image_and_is_validated() {
        let p = parts();
        let fb = feedback();
        let swing = Some(crate::testkit::v(0.1));
        let spec = ModelSpec {
            feedback: Some(fb),
            watch_swing: swing,
            ..testkit::spec(&p, &[])
        };
        let img = image(&spec);
        let mut store = Store::new();
        store.load(&img, &BOARD).unwrap();
        assert_eq!(store.spec().watch_swing, swing);
        assert_eq!(image(&store.spec()), img);
        let refused = |m: ModelSpec<'_>| {
            let e = crate::model::validate(&m).unwrap_err();
            (e.field, e.error)
        };
        for h in [0.07, 0.21] {
            let m = ModelSpec {
                watch_swing: Some(crate::testkit::v(h)),
                ..spec
            };
            assert_eq!(
                refused(m),
                (Field::WatchSwing, ModelError::WatchSwingOutOfRange),
                "{h} µm"
            );
        }
        let m = ModelSpec {
            feedback: None,
            ..spec
        };
        assert_eq!(
            refused(m),
            (Field::WatchSwing, ModelError::WatchWithoutFeedback)
        );
    }

    /// The padded runtime controller steps bit for bit as the typed one.
    #[test]
    fn the_runtime_controller_is_the_typed_one_bit_for_bit() {
        let p = parts();
        let typed = ControllerConfig::new(p).unwrap();
        let mut store = Store::new();
        store.load(&image(&testkit::spec(&p, &[])), &BOARD).unwrap();
        let runtime = store.controller().unwrap();
        let (mut a, mut b): (ControllerState<3>, ControllerState<5, 2>) =
            (typed.initial_state(), runtime.initial_state());
        for k in 0..3000 {
            let x = crate::testkit::v(12.0 + 11.0 * (k as f64 * 0.01).sin());
            let f = Newtons::from_raw(typed.f_f().eval(a.x_pea_est().raw()));
            let (oa, ob) = (typed.step(&mut a, x, f), runtime.step(&mut b, x, f));
            assert_eq!(oa, ob, "step {k}");
        }
    }

    #[test]
    fn bad_images_are_refused_by_name() {
        let p = parts();
        let spec = testkit::spec(&p, &[]);
        let good = image(&spec);
        let refuse = |img: &[u8]| Store::new().load(img, &BOARD).unwrap_err().error;
        let mut bad = good.clone();
        bad[HEADER_LEN + 40] ^= 1;
        assert_eq!(refuse(&bad), ModelError::ChecksumMismatch);
        assert_eq!(refuse(&good[..good.len() - 3]), ModelError::Truncated);
        assert_eq!(refuse(&good[..10]), ModelError::Truncated);
        let mut bad = good.clone();
        bad[0] = b'X';
        assert_eq!(refuse(&bad), ModelError::NotAModelImage);
        let mut bad = good.clone();
        bad[4] = 9;
        assert_eq!(refuse(&bad), ModelError::UnsupportedVersion);
        let small = ModelStore::<2, 2, 2048>::new()
            .load(&good, &BOARD)
            .unwrap_err();
        assert_eq!(
            (small.field, small.error),
            (Field::Operators, ModelError::OverCapacity)
        );
        let tiny = ModelStore::<5, 2, 600>::new()
            .load(&good, &BOARD)
            .unwrap_err();
        assert_eq!(tiny.error, ModelError::OverCapacity);
    }

    #[test]
    fn a_model_may_narrow_the_hardware_limits_but_not_widen_them() {
        let p = parts();
        let spec = testkit::spec(&p, &[]);
        let load = |s: ModelSpec<'_>| Store::new().load(&image(&s), &BOARD);
        assert!(load(ModelSpec {
            u_max: crate::testkit::v(120.0),
            max_step: crate::testkit::v(1.0),
            ..spec
        })
        .is_ok());
        let widens = |s: ModelSpec<'_>, field| {
            let e = load(s).unwrap_err();
            assert_eq!((e.field, e.error), (field, ModelError::WidensHardwareLimit));
        };
        // Sensor windows that take a rail of the board's channel in (a
        // broken wire reads a rail): refused by key.
        let rails = |s: ModelSpec<'_>, field| {
            let e = load(s).unwrap_err();
            assert_eq!((e.field, e.error), (field, ModelError::OutsideRails));
        };
        let sup = spec.supervision;
        rails(
            ModelSpec {
                supervision: crate::control::Supervision {
                    force: Interval {
                        lo: crate::testkit::v(-5.0),
                        hi: sup.force.hi,
                    },
                    ..sup
                },
                ..spec
            },
            Field::ForceMin,
        );
        let fb = crate::feedback::FeedbackSpec {
            kp: LoopGain::from_num(0.5),
            ki: LoopGain::from_num(0.01),
            limit: crate::testkit::v(5.0),
            sensor: Interval {
                lo: crate::testkit::v(-1000.0),
                hi: crate::testkit::v(1000.0),
            },
            tolerance: crate::testkit::v(3.0),
        };
        rails(
            ModelSpec {
                feedback: Some(fb),
                ..spec
            },
            Field::PositionMin,
        );
        rails(
            ModelSpec {
                feedback: Some(crate::feedback::FeedbackSpec {
                    sensor: Interval {
                        lo: crate::testkit::v(-5.0),
                        hi: crate::testkit::v(70.0),
                    },
                    ..fb
                }),
                ..spec
            },
            Field::PositionMax,
        );
        widens(
            ModelSpec {
                u_max: crate::testkit::v(160.0),
                ..spec
            },
            Field::UMax,
        );
        widens(
            ModelSpec {
                max_step: crate::testkit::v(6.0),
                ..spec
            },
            Field::Slew,
        );
        let e = load(ModelSpec {
            rate_hz: 10_000,
            ..spec
        })
        .unwrap_err();
        assert_eq!(e.error, ModelError::RateMismatch);
        // A store that failed to load holds no model.
        let mut s = Store::new();
        assert!(s.load(&image(&spec), &BOARD).is_ok() && s.is_loaded());
        let mut bad = image(&spec);
        bad[20] ^= 0xff;
        assert!(s.load(&bad, &BOARD).is_err());
        assert!(!s.is_loaded() && s.controller().is_err());
    }
}
