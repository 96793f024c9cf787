//! The reference governor of each set of loops a model can run
//! (`piezo_fpi::governor`): built once per model by the link task, picked by
//! the control ISR from the loops in force.
//!
//! A set of loops is the loop mode (open, closed, feedback alone), whether the
//! damping runs (switched on and in the model) and whether the reference's
//! shaping runs (switched on and in the model: the preview's taps or the
//! sections). Each gets the governor [`piezo_fpi::governor::analysis`] measures
//! on the model's dynamics, or on the floor stage where it declares none.

use piezo_fpi::biquad::{Cascade, SHAPING_SECTIONS};
use piezo_fpi::control::Interval;
use piezo_fpi::damping::{DampingConfig, DynamicsSpec};
use piezo_fpi::feedback::FeedbackConfig;
use piezo_fpi::governor::analysis::{Feedforward, Loops, Tracking};
use piezo_fpi::governor::{GovernorLimits, GovernorWindow};
use piezo_fpi::preview::Fir;
use piezo_fpi::q::Micrometres;
use piezo_fpi::stability::Laws;

use crate::control::tracking::LoopMode;

/// Sets of loops: three modes, damping and shaping each on or off.
pub const SETS: usize = 12;

/// Which set of loops runs: the index of its governor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoopSet(u8);

impl LoopSet {
    /// The set for `mode`, the damping running or not, the shaping running or
    /// not (each: switched on, and the model has it).
    pub const fn of(mode: LoopMode, damping: bool, shaping: bool) -> Self {
        let m = match mode {
            LoopMode::Open => 0,
            LoopMode::Closed => 1,
            LoopMode::FeedbackOnly => 2,
        };
        Self(m * 4 + (damping as u8) * 2 + shaping as u8)
    }

    fn parts(i: usize) -> (LoopMode, bool, bool) {
        let mode = match i / 4 {
            0 => LoopMode::Open,
            1 => LoopMode::Closed,
            // 8..=11, and the table's unused 12..=15.
            _ => LoopMode::FeedbackOnly,
        };
        (mode, i & 2 != 0, i & 1 != 0)
    }
}

/// What a model runs, as the governors are measured on it.
pub struct Parts<'a> {
    /// Control rate, Hz.
    pub rate_hz: u32,
    /// The reference window, µm.
    pub window: Interval<Micrometres>,
    /// The stage's dynamics, if declared.
    pub dynamics: Option<&'a DynamicsSpec>,
    /// The force channel's split rate (raw `I0F32`).
    pub split: i32,
    /// Active damping.
    pub damping: Option<&'a DampingConfig>,
    /// Position feedback.
    pub feedback: Option<&'a FeedbackConfig>,
    /// The preview's taps.
    pub preview: Option<&'a Fir>,
    /// The shaping's sections (where there is no preview).
    pub shaping: Option<&'a Cascade<SHAPING_SECTIONS>>,
    /// The lead's κ where the model applies it (damping and a preview), N/µm.
    pub lead_kappa: Option<f64>,
    /// The dynamic force a move may ask, N.
    pub force_room: f64,
    /// The amplifier's slew through the drive's slope, µm/tick.
    pub speed: f64,
}

/// The model's governor: its window, and the limits of each set of loops
/// (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Governors {
    /// The windows (the model's reference window, and it widened by the
    /// margin).
    pub window: GovernorWindow,
    sets: [GovernorLimits; SETS],
}

impl Governors {
    /// Measures each set the model can run (a set whose parts the model lacks
    /// is the set without them).
    pub fn of(p: &Parts<'_>) -> Self {
        let mut built: [Option<GovernorLimits>; SETS] = [None; SETS];
        let mut sets = [GovernorLimits::new(&limits(p, 0)); SETS];
        for (i, slot) in sets.iter_mut().enumerate() {
            let real = real_set(p, i);
            *slot = match built[real] {
                Some(g) => g,
                None => {
                    let g = GovernorLimits::new(&limits(p, real));
                    built[real] = Some(g);
                    g
                }
            };
        }
        Self {
            window: GovernorWindow::new(p.window),
            sets,
        }
    }

    /// The limits of `set`.
    #[inline(always)]
    pub fn limits(&self, set: LoopSet) -> &GovernorLimits {
        // A `LoopSet` is below `SETS` by construction.
        self.sets.get(set.0 as usize).unwrap_or(&self.sets[0])
    }
}

/// The set that really runs for index `i`: the damping and shaping where the
/// model has them, the position loop where it has feedback.
fn real_set(p: &Parts<'_>, i: usize) -> usize {
    let (mode, damping, shaping) = LoopSet::parts(i);
    let mode = if p.feedback.is_some() {
        mode
    } else {
        LoopMode::Open
    };
    let shaping =
        shaping && (p.preview.is_some() || p.shaping.is_some()) && mode != LoopMode::FeedbackOnly;
    LoopSet::of(mode, damping && p.damping.is_some(), shaping).0 as usize
}

/// The governor's limits for set `i` (a real one: [`real_set`]).
fn limits(p: &Parts<'_>, i: usize) -> piezo_fpi::governor::Limits {
    let (mode, damping, shaping) = LoopSet::parts(i);
    let damping_spec = p.damping.filter(|_| damping).map(|d| *d.spec());
    let feedback_spec = p.feedback.map(|f| *f.spec());
    let laws = Laws::of(p.split, damping_spec.as_ref(), feedback_spec.as_ref());
    let tracking = match mode {
        LoopMode::Open => Tracking::Open,
        LoopMode::Closed => Tracking::Closed,
        LoopMode::FeedbackOnly => Tracking::FeedbackOnly,
    };
    let feedforward = match (shaping, p.preview, p.shaping) {
        (true, Some(f), _) => Feedforward::Taps(f),
        (true, None, Some(c)) => Feedforward::Sections(c),
        _ => Feedforward::Identity,
    };
    let lead = match (shaping && damping, p.lead_kappa) {
        (true, Some(k)) => k,
        _ => 0.0,
    };
    Loops {
        rate_hz: p.rate_hz,
        dynamics: p.dynamics,
        laws,
        tracking,
        delay: p.preview.map_or(0, |f| f.ticks()),
        feedforward,
        lead,
    }
    .limits(p.force_room, p.speed)
}
