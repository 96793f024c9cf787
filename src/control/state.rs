//! The controller's state (the operator memories, the force channel's learned
//! terms, the last output and the latched fault), and what one step produced.

use super::channel::{hi_word, residual, HALF_LSB_I16F48};
use super::{ControllerConfig, Fault};
use crate::fpi::{CreepMemory, Fpi, Shape};
use crate::play::{Bottom, PlayBank, Stepped, Top};
use crate::q::{Micrometres, Newtons, Volts};

/// Which state of the double-buffered inverse bank a lagging forward bank is
/// rebuilt from: `Before` the inverse advanced in this step, or as it is `Now`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Memory {
    Now,
    Before,
}

/// What one control step produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepOutput {
    /// Amplifier setpoint, V (after range and slew limits).
    pub voltage: Volts,
    /// Stack extension the reference asks for, µm.
    pub x_pea_ref: Micrometres,
    /// Virtual sensor: estimated stack extension, µm.
    pub x_pea_est: Micrometres,
    /// The limits changed the voltage (always true in the safe state).
    pub limited: bool,
    /// The latched fault, if the controller is in its safe state.
    pub fault: Option<Fault>,
}

/// The controller's memory: both operator banks, the last output, the fault latch.
///
/// The two banks keep their gaps to opposite edges ([`crate::play::Edge`]): they
/// move in the same direction, so each step pays one cheap and one dearer update
/// per operator pair.
///
/// With the paper's bare FPI the forward bank is not advanced while the drive
/// is the inverse's (its output would be the reference): it lags, and is rebuilt
/// from the inverse bank ([`crate::fpi::Fpi::forward_from_inverse`]) when the
/// drive departs from the inverse's (the limiter, a fault, the uncompensated
/// drive). The inverse bank is double-buffered ([`Stepped`]) so that the state
/// it had before the step is still at hand then; any other model advances it
/// in place, in its first buffer.
///
/// A state belongs to the configuration that made it
/// ([`ControllerConfig::initial_state`]): its banks hold that model's operators,
/// and its layout depends on whether that model is bare. The firmware makes a
/// fresh one with each model it runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ControllerState<const N: usize, const C: usize = 0> {
    pub(super) inverse: Stepped<N, Top>,
    pub(super) forward: PlayBank<N, Bottom>,
    /// The forward bank lags: it holds an older state than the inverse bank's.
    pub(super) forward_lags: bool,
    pub(super) creep: CreepMemory<C>,
    pub(super) force_ref: Newtons,
    pub(super) voltage: Volts,
    pub(super) x_pea_est: Micrometres,
    /// The slow part `r_s` of the force residual, N, `I16F48` (raw `i64`) plus
    /// [`HALF_LSB_I16F48`]: its high word is `r_s` rounded to `I16F16`.
    pub(super) force_slow: i64,
    /// The learned offset `r_0` of the preload map, N, `I16F48` (raw `i64`) plus
    /// [`HALF_LSB_I16F48`].
    pub(super) force_offset: i64,
    /// The FEM's preload at the tare, `f_F(x_0)`, N: where the scale's change
    /// `Δ` is counted from (the tared reading less the offset taken then).
    pub(super) force_tare_model: Newtons,
    /// The learned scale error `b` of the preload map, `I0F32` (raw `i32`).
    pub(super) force_scale: i32,
    pub(super) fault: Option<Fault>,
    /// The last force reading that differed from the one before, N, and the
    /// FEM's preload at the estimate then, N (the stuck-sensor check).
    pub(super) force_held: Newtons,
    pub(super) force_held_model: Newtons,
    /// The rate of the park in progress, V per tick (`crate::limits::OutputLimits::park`).
    pub(super) park_rate: Volts,
    /// The output's departure from the park's profile (the damping's share), V,
    /// `I16F16` (`crate::limits::OutputLimits::park_damped`); zero outside a park.
    pub(super) park_offset: Volts,
    /// The damping's correction offered for the next park step, V, `I16F16`
    /// ([`ControllerState::damp_park`]); zero once used.
    pub(super) park_damping: Volts,
    /// Ticks since the park began (saturating); zero outside a park.
    pub(super) park_tick: u32,
    pub(super) limited_steps: u32,
}

impl<const N: usize, const C: usize> ControllerState<N, C> {
    /// Brings a lagging forward bank up to the inverse bank's state, `now` or
    /// `before` this step advanced it (see [`ControllerState`]).
    #[inline(always)]
    pub(super) fn catch_up<'a, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        fpi: &Fpi<'a, N, C, G, H>,
        at: Memory,
    ) {
        if self.forward_lags {
            self.rebuild_forward(fpi, at);
        }
    }

    /// [`catch_up`](Self::catch_up)'s rebuild, out of line: it is rare.
    #[inline(never)]
    fn rebuild_forward<'a, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        fpi: &Fpi<'a, N, C, G, H>,
        at: Memory,
    ) {
        let inverse = match at {
            Memory::Now => self.inverse.now(),
            Memory::Before => self.inverse.before(),
        };
        fpi.forward_from_inverse(inverse, &mut self.forward);
        self.forward_lags = false;
    }

    /// The slow part of the force residual beyond the learned map, N (rounded to
    /// `I16F16`).
    pub const fn force_slow(&self) -> Newtons {
        Newtons::from_bits(hi_word(self.force_slow))
    }
    /// The preload map's learned offset, N (rounded to `I16F16`).
    pub const fn force_offset(&self) -> Newtons {
        Newtons::from_bits(hi_word(self.force_offset))
    }
    /// The learned scale error of the preload map (dimensionless, ±0.25).
    pub fn force_scale(&self) -> f64 {
        self.force_scale as f64 / (1u64 << 32) as f64
    }
    /// The latched fault, if any.
    pub const fn fault(&self) -> Option<Fault> {
        self.fault
    }
    /// The last applied voltage, V.
    pub const fn voltage(&self) -> Volts {
        self.voltage
    }
    /// The last estimated stack extension, µm.
    pub const fn x_pea_est(&self) -> Micrometres {
        self.x_pea_est
    }
    /// Steps in which the limits changed the voltage (wraps).
    pub const fn limited_steps(&self) -> u32 {
        self.limited_steps
    }
    /// The reference force of the compliance term in use (N).
    pub const fn force_ref(&self) -> Newtons {
        self.force_ref
    }

    /// Latches `fault` (if none is latched yet): from the next step the controller
    /// ramps to the safe voltage, as for a fault it detects itself. For the faults
    /// the application detects (a stop command, a lost host, a bad reference input).
    /// Returns whether this fault was latched.
    pub fn trip(&mut self, fault: Fault) -> bool {
        if self.fault.is_some() {
            return false;
        }
        self.fault = Some(fault);
        true
    }

    /// Offers the active damping's correction (V, `I16F16`: the damping's µm
    /// through the small-signal slope of the drive) to the next step, if it is
    /// a park after a fault that keeps the damping ([`Fault::damps_park`];
    /// otherwise it is ignored): see
    /// [`crate::limits::OutputLimits::park_damped`]. Used by one step.
    #[inline]
    pub fn damp_park(&mut self, correction: Volts) {
        self.park_damping = correction;
    }

    /// The output's present departure from the park's profile (the damping's
    /// share), V; zero outside a park.
    pub const fn park_offset(&self) -> Volts {
        self.park_offset
    }

    /// Forgets what the force channel learned since the tare (its offset and
    /// scale back to the tare's, its slow part to zero): after a fault, what it
    /// learned may be the fault's. The slow part settles again within a few of
    /// its time constants (16 ms at the default 10 Hz split) while parked.
    pub fn forget_force_learning(&mut self) {
        let at_tare = residual(self.force_ref, self.force_tare_model);
        self.force_offset = ((at_tare.to_bits() as i64) << 32) + HALF_LSB_I16F48;
        self.force_slow = HALF_LSB_I16F48;
        self.force_scale = 0;
    }

    /// Leaves the safe state once the output has reached the safe voltage; the
    /// inverse memory is realigned with the voltage history actually applied.
    /// Returns whether the fault was cleared.
    pub fn clear_fault<'a, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
    ) -> bool {
        if self.voltage != cfg.safe_voltage {
            return false;
        }
        self.catch_up(&cfg.fpi, Memory::Now);
        cfg.fpi.resync(&self.forward, self.inverse.now_mut());
        self.fault = None;
        self.park_rate = Volts::ZERO;
        self.park_offset = Volts::ZERO;
        self.park_damping = Volts::ZERO;
        self.park_tick = 0;
        true
    }
}
