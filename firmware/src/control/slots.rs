//! The board's two model stores and who may touch which: the control ISR runs one
//! ([`Running`]), the link task fills the other ([`Spare`]).
//!
//! A model is swapped in between two ticks by moving values, not by sharing
//! memory: the link task loads an image into its [`Spare`] store and turns it into
//! a [`Running`] model ([`Spare::activate`], which validates it); the ISR takes the
//! `Running` at the start of a tick and hands the one it ran before back; the link
//! task turns that into a `Spare` again ([`Running::retire`]). Neither type is
//! `Copy` or `Clone`, so at any time each store has exactly one owner, and a
//! store is never written while the ISR reads it.
//!
//! The controller of a running model borrows the store's tables; [`Running::get`]
//! lends it only for as long as the `Running` is borrowed, so nothing keeps a
//! reference into a store once it has been retired. This is the one place the
//! firmware needs `unsafe`: turning the spare's `&'static mut` store into the
//! shared borrow the controller holds, and back.

use core::ptr::NonNull;

use piezo_fpi::biquad::{Cascade, SHAPING_SECTIONS};
use piezo_fpi::control::{ForceChannel, Interval, LinearDrive};
use piezo_fpi::damping::{DampingConfig, DynamicsSpec};
use piezo_fpi::error::{Field, Invalid, ModelError};
use piezo_fpi::feedback::FeedbackConfig;
use piezo_fpi::lead::LeadSpec;
use piezo_fpi::model::image::CRC32;
use piezo_fpi::model::{Shape, WATCH_SWING_MAX};
use piezo_fpi::preview::Fir;
use piezo_fpi::q::{Micrometres, Newtons, Volts};

use crate::board::capacity::{Controller, Store, BOARD, RATE_HZ};
use crate::control::governors::{Governors, Parts};

pub use fpi_protocol::Origin;

/// What the link task needs to know about a model, copied out of it: the link
/// task checks commands against it while the ISR owns the model itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// CRC-32 of the whole image (its identity; what the host computes of the file).
    pub crc: u32,
    /// Operators, creep terms, dead zone and saturation.
    pub shape: Shape,
    /// The reachable stroke: references must lie in it, µm.
    pub reference: Interval<Micrometres>,
    /// The safe voltage, V.
    pub safe_voltage: Volts,
    /// Where it came from.
    pub origin: Origin,
    /// The straight-line drive of the uncompensated mode.
    pub baseline: LinearDrive,
    /// Position feedback, if the model has it (else the loop stays open).
    pub feedback: Option<FeedbackConfig>,
    /// Reference shaping (the inverse of the stage's modes), if the model has it.
    pub shaping: Option<Cascade<SHAPING_SECTIONS>>,
    /// The shaping where it runs ahead of the tracked reference: taps on the
    /// preview's delay line (`piezo_fpi::preview`); [`Summary::shaping`] is then
    /// `None`.
    pub preview: Option<Fir>,
    /// The lead (κ, the learning's rate, the baseline; `piezo_fpi::lead`)
    /// where the shaping runs ahead and the model damps: the damping then
    /// leaves out the force the shaped reference's motion explains
    /// (`crate::control::tracking`).
    pub lead: Option<LeadSpec>,
    /// The stage's dynamics, if the model declares them.
    pub dynamics: Option<DynamicsSpec>,
    /// Active damping, if the model has it.
    pub damping: Option<DampingConfig>,
    /// The force channel (split and dynamic limit).
    pub channel: ForceChannel,
    /// The dynamic force a move may ask of the stack, N: the least of the
    /// room the force sensor's window leaves below the preload at the
    /// stroke's low end and above it at the high end, and the channel's
    /// dynamic limit ([`force_room`]).
    pub force_room: Newtons,
    /// The oscillation watch's half swing on the tracking error, µm
    /// (`crate::control::watch`): the model's, else
    /// [`piezo_fpi::model::WATCH_SWING_MAX`].
    pub watch_swing: Micrometres,
}

/// The fastest reference the amplifier follows, µm/tick: its slew (the
/// model's largest setpoint step) through the straight-line drive's slope.
pub fn amplifier_speed(cfg: &Controller<'_>, drive: &LinearDrive) -> f64 {
    let step = cfg.limits().max_step().to_num::<f64>();
    let slope = drive.gain.to_num::<f64>().abs();
    if slope > 0.0 {
        step / slope
    } else {
        piezo_fpi::governor::SPEED_MAX
    }
}

/// The dynamic force a move may ask of the stack of `cfg`, N (see
/// [`Summary::force_room`]); `limit` the channel's dynamic limit. The preload
/// `f_F(f_K⁻¹(x))` is monotone in `x` (both tables are), so the stroke's ends
/// bound it. Never negative.
pub fn force_room(cfg: &Controller<'_>, limit: Newtons) -> Newtons {
    let (r, f) = (cfg.reference(), cfg.force());
    let preload = |x| cfg.preload(cfg.extension(x));
    let (a, b) = (preload(r.lo), preload(r.hi));
    let below = a.min(b).saturating_sub(f.lo);
    let above = f.hi.saturating_sub(a.max(b));
    below.min(above).min(limit).max(Newtons::ZERO)
}

/// A store the link task owns: free to load an image into.
pub struct Spare {
    store: &'static mut Store,
    /// The shape of the model loaded into the store, if one is.
    loaded: Option<Shape>,
}

/// A validated model with its controller, owned by whoever runs it.
pub struct Running {
    store: NonNull<Store>,
    cfg: Controller<'static>,
    summary: Summary,
    /// The reference governor of each set of loops ([`crate::control::governors`]):
    /// the ISR's alone, not the link task's summary's.
    governors: Governors,
}

// SAFETY: a `Running` is the unique owner of its store (it was made from the
// store's `&'static mut`, which it consumed), so it may move to another task
// like the `&'static mut Store` it stands for.
unsafe impl Send for Running {}

impl Spare {
    /// A spare store (for start-up: the board's two stores are statics).
    pub fn new(store: &'static mut Store) -> Self {
        Self {
            store,
            loaded: None,
        }
    }

    /// Reads an image into the store and validates it against the board
    /// ([`piezo_fpi::model::store::ModelStore::load`]); the store keeps it.
    pub fn load(&mut self, image: &[u8]) -> Result<Shape, Invalid> {
        self.loaded = None;
        let shape = self.store.load(image, &BOARD)?;
        self.loaded = Some(shape);
        Ok(shape)
    }

    /// Makes the loaded model a running one: builds its controller and the
    /// straight-line baseline drive. The image is the one loaded (for its CRC).
    /// On failure the spare comes back with the reason.
    pub fn activate(self, image: &[u8], origin: Origin) -> Result<Running, (Spare, Invalid)> {
        let shape = self.loaded;
        let ptr = NonNull::from(&mut *self.store);
        // SAFETY: `self.store` is consumed here; from now on the store is only
        // reached through `ptr`, shared, until `Running::retire` (which needs the
        // `Running` by value, so every borrow lent by `Running::get` has ended)
        // makes it exclusive again.
        let shared: &'static Store = unsafe { ptr.as_ref() };
        let built = shared.controller().and_then(|cfg| {
            let shape = shape.ok_or(Invalid::at(Field::Model, ModelError::Truncated))?;
            let baseline = crate::control::baseline::drive(&cfg)?;
            let spec = shared.spec();
            let feedback = spec.feedback.map(FeedbackConfig::new).transpose()?;
            let preview = spec.shaping.map(|s| s.fir()).transpose()?.flatten();
            let shaping = spec
                .shaping
                .filter(|_| preview.is_none())
                .map(|s| s.cascade())
                .transpose()?;
            let channel = spec.supervision.channel;
            let damping = spec
                .damping
                .map(|d| DampingConfig::new(d, &channel))
                .transpose()?;
            let lead = spec
                .dynamics
                .filter(|_| preview.is_some() && damping.is_some())
                .map(|d| LeadSpec::of(&d, RATE_HZ, spec.lead_baseline));
            let watch_swing = spec.watch_swing.unwrap_or(WATCH_SWING_MAX);
            let room = force_room(&cfg, channel.dynamic_limit);
            let governors = Governors::of(&Parts {
                rate_hz: RATE_HZ,
                window: cfg.reference(),
                dynamics: spec.dynamics.as_ref(),
                split: channel.split.to_bits(),
                damping: damping.as_ref(),
                feedback: feedback.as_ref(),
                preview: preview.as_ref(),
                shaping: shaping.as_ref(),
                lead_kappa: lead.map(|l| l.force_gain.to_num::<f64>()),
                force_room: room.to_num::<f64>(),
                speed: amplifier_speed(&cfg, &baseline),
            });
            Ok((
                cfg,
                baseline,
                shape,
                (feedback, shaping, damping, spec.dynamics, channel),
                (preview, lead, watch_swing, room, governors),
            ))
        });
        match built {
            Ok((
                cfg,
                baseline,
                shape,
                (feedback, shaping, damping, dynamics, channel),
                (preview, lead, watch_swing, room, governors),
            )) => Ok(Running {
                store: ptr,
                summary: Summary {
                    crc: CRC32.checksum(image),
                    shape,
                    reference: cfg.reference(),
                    safe_voltage: cfg.safe_voltage(),
                    origin,
                    baseline,
                    feedback,
                    shaping,
                    preview,
                    lead,
                    dynamics,
                    damping,
                    channel,
                    force_room: room,
                    watch_swing,
                },
                governors,
                cfg,
            }),
            // SAFETY: `shared` and `built` are gone; the store is exclusive again.
            Err(e) => Err((
                Spare {
                    store: unsafe { &mut *ptr.as_ptr() },
                    loaded: shape,
                },
                e,
            )),
        }
    }
}

impl Running {
    /// The controller, lent for as long as this model is borrowed.
    #[inline(always)]
    pub fn get(&self) -> &Controller<'_> {
        &self.cfg
    }

    /// What the link task keeps about the model.
    pub const fn summary(&self) -> &Summary {
        &self.summary
    }

    /// Its reference governor.
    #[inline(always)]
    pub const fn governors(&self) -> &Governors {
        &self.governors
    }

    /// Gives the store back to be filled again.
    pub fn retire(self) -> Spare {
        let Running { store, .. } = self;
        // SAFETY: `self` is consumed, and with it the controller; every borrow of
        // it lent by `get` has ended, so nothing reads the store any more.
        Spare {
            store: unsafe { &mut *store.as_ptr() },
            loaded: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::factory_model::MODEL_IMAGE;

    fn spare() -> Spare {
        Spare::new(Box::leak(Box::new(Store::new())))
    }

    #[test]
    fn a_model_goes_from_spare_to_running_and_back() {
        let mut s = spare();
        let shape = s.load(MODEL_IMAGE).unwrap();
        let running = s.activate(MODEL_IMAGE, Origin::Factory).ok().unwrap();
        assert_eq!(running.summary().shape.operators, shape.operators);
        assert_eq!(running.summary().crc, CRC32.checksum(MODEL_IMAGE));
        assert!(running.get().reference().hi > running.get().reference().lo);
        let mut again = running.retire();
        // The store can be filled again and gives the same model.
        again.load(MODEL_IMAGE).unwrap();
        let r2 = again.activate(MODEL_IMAGE, Origin::Received).ok().unwrap();
        assert_eq!(r2.summary().origin, Origin::Received);
    }

    #[test]
    fn a_store_without_a_model_cannot_run() {
        let s = spare();
        let (back, e) = s.activate(MODEL_IMAGE, Origin::Factory).err().unwrap();
        assert_eq!(e.error, piezo_fpi::error::ModelError::Truncated);
        let mut back = back;
        back.load(MODEL_IMAGE).unwrap();
    }
}
