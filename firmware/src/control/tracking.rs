//! Open and closed loop: the command the control step gets, from the reference
//! and the stage-position sensor.
//!
//! | mode | command `x_cmd` (µm) | law |
//! |---|---|---|
//! | [`LoopMode::Open`] | `S(x_ref)` (+ a transfer offset bleeding to 0) | inverse FPI, or the straight line (`drive`) |
//! | [`LoopMode::Closed`] | `S(x_ref) + δ`, `δ = PI(x_ref − x_sensor)` in `±limit` | inverse FPI: feedback + feedforward |
//! | [`LoopMode::FeedbackOnly`] | `PI(x_ref − x_sensor)` in the stroke | the straight line: feedback alone |
//!
//! `S` is the model's reference shaping, where it has one: the inverse of the
//! stage's lightly damped modes, or of the damped stage (`piezo_fpi::biquad`), so
//! that a fast reference is followed without lag or ringing; otherwise `S(x) = x`.
//!
//! **Preview.** Where the model's shaping runs ahead (`preview` ticks,
//! `piezo_fpi::preview`), `S` is taps on a delay line whose newest entry is the
//! reference source's, and the loops (the PI's error, the recorder's `x_ref`,
//! the range check) take the one `preview` ticks older: the damped stage's lag
//! is then inverted, not just shaped. The damping then
//! also leaves out the force the shaped reference's own motion explains,
//! `κ·(S_{k−1} − x_ref)` (κ the model's dynamic force per µm): it damps what
//! departs from the motion asked for, not the motion itself, whose slow
//! high-pass-and-leak response would otherwise trail every step by milliseconds.
//! κ is the identified stage's; on a stage whose mass differs the explained
//! force is scaled by the mass ratio the loop learns (`piezo_fpi::lead`, where
//! the model carries the lead's baseline) from step commands only: while the
//! raised cosine of a step at least as long as autotune's runs
//! ([`crate::control::reference::LEARNING_STEP_TICKS`], 1.5 ms: the fit depends on the step's
//! speed) and for [`LEAD_WINDOW`] ticks after. The ratio's
//! fit depends on the motion (on the stage as built, where steps hold it at
//! 1, 15 Hz sines took it to 0.92, 100 Hz triangles to 0.74, sines near the
//! mode to 1.98), and autotune measured the baseline on steps. The learned
//! ratio survives faults and parks; a new model starts it again at 1.
//!
//! **Active damping** (`piezo_fpi::damping`), where the model has it and it is
//! switched on (the default): in every mode the command also gets `δ_d`, the
//! integral force feedback on the force channel's dynamic part, which damps the
//! stage's first mode. The position loop is then designed around the damped
//! stage (`fpi tune`, `fpi board autotune`).
//!
//! The PI law, its anti-windup and the sensor checks are the core's
//! ([`piezo_fpi::feedback`]). **Bumpless transfer**: when the mode or the law
//! changes, the new law starts from the command that reproduces the present
//! output under it — the last command if the law is the same, else the model's
//! estimate of the stage position (inverse FPI, whose memory follows the applied
//! voltage) or the straight line's inverse of the present voltage — and the PI's
//! integrator is preset to it ([`Pi::preset`]). Back in open loop, the
//! difference to the reference bleeds off at [`APPROACH_STEP`] per tick.
//!
//! **A damped park.** After a fault the loop's memory is forgotten tick by
//! tick and the core parks the output; the damping alone may run on through
//! the park ([`Loop::park_correction`], added to the park's profile by
//! `piezo_fpi::limits::OutputLimits::park_damped`, faded out by its end) where
//! it cannot be the fault's cause: it was on, the fault is one that keeps it
//! (`Fault::damps_park`: not the force sensor's, not an overrun, not a stage
//! that left its model), and for [`Fault::Oscillation`] the watch caught it
//! with the position loop closed (the loop the park drops), not with the
//! damping running alone. Integral force feedback on the collocated force sensor adds
//! damping to the first mode wherever the mode lies well above the law's
//! high-pass and leak corners (its root locus leaves the mode to the left while
//! the mode's frequency exceeds their geometric mean, whatever it is), and
//! the park bounds what it can do in any case (its share of the output is held
//! to ±32 V and faded out within the park). It runs at half its gain there
//! (`ControlLoop`'s park offer). It is decided at the fault's first tick, and
//! only ever dropped later (by a switch, or at the safe voltage).
//!
//! In the closed modes a position reading outside the sensor's range, or one that
//! disagrees with the model's estimate by more than the tolerance for
//! [`IMPLAUSIBLE_RUN`] ticks in a row, trips a fault: the output ramps to the safe
//! voltage like for any other fault.

use crate::control::watch::LoopWatch;
use piezo_fpi::biquad::{Cascade, CascadeState, SHAPING_SECTIONS};
use piezo_fpi::control::{Fault, Interval, LinearDrive, Mode, StepOutput};
use piezo_fpi::damping::{Damping, DampingConfig};
use piezo_fpi::feedback::{FeedbackConfig, Pi, Saturation};
use piezo_fpi::lead::{LeadGain, LeadSpec};
use piezo_fpi::preview::{Fir, Preview, PREVIEW_MAX};
use piezo_fpi::process::SplitProcess;
use piezo_fpi::q::{LeadRatio, Micrometres, Newtons, Volts};

use crate::board::capacity::{Controller, APPROACH_STEP, RATE_HZ};

pub use fpi_protocol::LoopMode;

/// Which law turns the command into a voltage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Law {
    Fpi,
    Linear,
}

/// What the control step is given this tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Command {
    /// The command, µm.
    pub x_cmd: Micrometres,
    /// The law.
    pub mode: Mode,
}

impl Command {
    /// No command yet: 0 µm through the inverse (a tick's phases overwrite
    /// it before it is read).
    pub const ZERO: Self = Self {
        x_cmd: Micrometres::ZERO,
        mode: Mode::Compensated,
    };
}

/// The loop's mode and the feedback's memory (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Loop {
    mode: LoopMode,
    law: Law,
    pi: Pi,
    held: Micrometres,
    last_cmd: Micrometres,
    clamp: Saturation,
    sat: Saturation,
    transfer: bool,
    fresh: bool,
    implausible: u32,
    shaped: CascadeState<SHAPING_SECTIONS>,
    damping: Damping,
    damping_on: bool,
    /// The loops watched for oscillation and saturation.
    watch: LoopWatch,
    /// The watch saw a tick since it was last reset (no loop runs: reset
    /// once, not at every tick).
    watching: bool,
    /// What the watch saw this tick.
    alarm: Option<Fault>,
    damped: Micrometres,
    shaping_on: bool,
    fresh_shaping: bool,
    /// The damping is the only loop running (open loop, or no position
    /// loop): an oscillation the watch sees is its own.
    damping_alone: bool,
    /// A fault is latched (the last step parked).
    parking: bool,
    /// The damping runs on through this park.
    park_damping: bool,
    /// The reference's delay line (the shaping's preview).
    ahead: Preview,
    /// The shaped reference of the last tick, µm.
    last_ff: Micrometres,
    /// The feedforward on the preview's line this tick ([`Loop::preview`]), µm.
    ahead_ff: Micrometres,
    /// The model's shaping runs on the preview's line.
    previewing: bool,
    /// The explained force's learned mass ratio.
    lead_gain: LeadGain,
    /// Ticks left in which the ratio learns: a step command's, and the
    /// preview's delay after it.
    lead_window: u8,
    /// The tracked reference of the last two ticks, µm (the lead's
    /// acceleration).
    tracked: [Micrometres; 2],
}

/// Ticks the mass ratio learns on after a step command's last one: the
/// preview's longest delay and the second difference's tick.
pub const LEAD_WINDOW: u8 = PREVIEW_MAX + 2;

/// Ticks in a row a position reading must disagree with the model's estimate to
/// trip [`Fault::PositionImplausible`]: 2 ms, longer than the swings of a stage
/// mode above 500 Hz (which the quasi-static model does not follow), short
/// against a stuck sensor's drift.
pub const IMPLAUSIBLE_RUN: u32 = RATE_HZ / 500;

impl Default for Loop {
    fn default() -> Self {
        Self::new()
    }
}

impl Loop {
    /// Open loop, compensated, nothing held.
    pub const fn new() -> Self {
        Self {
            mode: LoopMode::Open,
            law: Law::Fpi,
            pi: Pi::new(),
            held: Micrometres::ZERO,
            last_cmd: Micrometres::ZERO,
            clamp: Saturation::Free,
            sat: Saturation::Free,
            transfer: true,
            fresh: true,
            implausible: 0,
            shaped: CascadeState::new(),
            damping: Damping::new(),
            damping_on: true,
            damped: Micrometres::ZERO,
            shaping_on: true,
            fresh_shaping: false,
            watch: LoopWatch::new(),
            watching: false,
            alarm: None,
            damping_alone: false,
            parking: false,
            park_damping: false,
            ahead: Preview::new(),
            last_ff: Micrometres::ZERO,
            ahead_ff: Micrometres::ZERO,
            previewing: false,
            lead_gain: LeadGain::new(),
            lead_window: 0,
            tracked: [Micrometres::ZERO; 2],
        }
    }

    /// Takes the reference source's newest value `ahead` (µm) and gives the
    /// reference the loops track this tick: where the model's shaping runs ahead
    /// (`fir`, `piezo_fpi::preview`), the one its delay older, the shaping then
    /// taken on the line; else `ahead` itself. `stepping`: the reference is a
    /// step command's (the lead's mass ratio learns from it). Call it before
    /// [`Loop::command`].
    #[inline]
    pub fn preview(
        &mut self,
        ahead: Micrometres,
        fir: Option<&Fir>,
        stepping: bool,
    ) -> Micrometres {
        self.lead_window = if stepping {
            LEAD_WINDOW
        } else {
            self.lead_window.saturating_sub(1)
        };
        match fir {
            Some(f) => {
                let (tracked, ff) = f.process(&mut self.ahead, ahead);
                self.ahead_ff = ff;
                self.previewing = true;
                tracked
            }
            None => {
                self.previewing = false;
                ahead
            }
        }
    }

    /// The mode in use.
    pub const fn mode(&self) -> LoopMode {
        self.mode
    }

    /// Runs `mode` from the next tick on, without a jump.
    pub fn select(&mut self, mode: LoopMode) {
        if mode != self.mode {
            self.mode = mode;
            self.transfer = true;
        }
    }

    /// Switches active damping on or off (where the model has it), from the next
    /// tick on, without a jump.
    pub fn set_damping(&mut self, on: bool) {
        if on != self.damping_on {
            self.damping_on = on;
            self.transfer = true;
        }
    }

    /// Whether active damping is switched on (it runs where the model has it).
    pub const fn damping_on(&self) -> bool {
        self.damping_on
    }

    /// Switches the reference shaping on or off (where the model has it), from
    /// the next tick on, without a jump.
    pub fn set_shaping(&mut self, on: bool) {
        if on != self.shaping_on {
            self.shaping_on = on;
            self.transfer = true;
            self.fresh_shaping = true;
        }
    }

    /// Whether the reference shaping is switched on.
    pub const fn shaping_on(&self) -> bool {
        self.shaping_on
    }

    /// The damping's correction of the last command, µm.
    pub const fn damping_correction(&self) -> Micrometres {
        self.damped
    }

    /// The damping's correction of the last command where it runs on through a
    /// park (see the module docs), else zero, µm.
    pub const fn park_correction(&self) -> Micrometres {
        if self.park_damping {
            self.damped
        } else {
            Micrometres::ZERO
        }
    }

    /// The PI's integrator, µm (for diagnostics).
    pub const fn integral(&self) -> Micrometres {
        self.pi.integral()
    }

    /// The last command, µm (for diagnostics).
    pub const fn last_command(&self) -> Micrometres {
        self.last_cmd
    }

    /// The explained force's learned mass ratio (`piezo_fpi::lead`).
    pub const fn lead_ratio(&self) -> LeadRatio {
        self.lead_gain.ratio()
    }

    /// The reference starts afresh at `x`, µm (leaving a park, a new model): the
    /// preview's line refills from its next value, and the lead's memory of
    /// the shaped and the tracked reference is `x`. Else the reference held
    /// before the park (20 µm after a sweep) would read as a jump: the lead
    /// force `κ·(S − x_ref)` of a 20 µm jump, over 100 N, into the damping's
    /// integral, which threw a lightly damped stage out of its stroke.
    pub fn restart_reference(&mut self, x: Micrometres) {
        self.ahead.restart();
        self.last_ff = x;
        self.tracked = [x; 2];
    }

    /// Learns the mass ratio on from `gain` (one measured before the first step).
    pub fn start_lead(&mut self, gain: LeadGain) {
        self.lead_gain = gain;
    }

    /// Starts learning the mass ratio again from 1 (a new model: a new stage).
    pub fn forget_lead(&mut self) {
        self.lead_gain = LeadGain::new();
    }

    /// Forgets the feedback's memory (after a fault, a park or a new model): the
    /// next tick starts afresh from the present output. The learned mass ratio
    /// stays ([`Loop::forget_lead`]).
    pub fn reset(&mut self) {
        self.watch.reset();
        self.alarm = None;
        self.damping.reset();
        self.damped = Micrometres::ZERO;
        self.pi = Pi::new();
        self.held = Micrometres::ZERO;
        self.sat = Saturation::Free;
        self.transfer = true;
        self.fresh = true;
    }

    /// The position sensor's verdict in every mode, where the model declares the
    /// sensor (its `[feedback]` section): `reading` against the sensor's range (at
    /// once) and the model's last estimate (for [`IMPLAUSIBLE_RUN`] ticks in a
    /// row). In open loop too: a stage driven into a resonance, or a sensor that
    /// broke, is seen before the loop is closed on it.
    #[inline]
    pub fn check(
        &mut self,
        fb: Option<&FeedbackConfig>,
        reading: Micrometres,
        estimate: Micrometres,
    ) -> Option<Fault> {
        let verdict = fb.and_then(|f| f.check(reading, estimate));
        match verdict {
            Some(Fault::PositionImplausible) => {
                self.implausible = self.implausible.saturating_add(1);
                (self.implausible >= IMPLAUSIBLE_RUN).then_some(Fault::PositionImplausible)
            }
            other => {
                self.implausible = 0;
                other
            }
        }
    }

    /// What the loop watch saw in the last [`Loop::command`]
    /// ([`crate::control::watch`]): an oscillating or saturating loop.
    pub const fn alarm(&self) -> Option<Fault> {
        self.alarm
    }

    /// The command for this tick (see the module docs).
    #[inline]
    pub fn command(&mut self, io: &Inputs<'_, '_>) -> Command {
        let law = match (self.mode, io.compensated) {
            (LoopMode::Open, true) | (LoopMode::Closed, _) => Law::Fpi,
            (LoopMode::Open, false) | (LoopMode::FeedbackOnly, _) => Law::Linear,
        };
        // The force the shaped reference's motion explains is not damped (see
        // the module docs): β·κ·(S_{k−1} − x_ref), N, β learned.
        let dynamic = match io.lead {
            Some(lead) if self.shaping_on && !self.parking => {
                let moved = self.last_ff.saturating_sub(io.x_ref);
                // The tracked reference's second difference, µm/tick² (within
                // ±4096 µm, the preview's line: exact).
                let [t1, t2] = self.tracked.map(Micrometres::to_bits);
                let x = io.x_ref.to_bits();
                let accel =
                    Micrometres::from_bits(x.wrapping_sub(t1).wrapping_sub(t1.wrapping_sub(t2)));
                self.tracked = [io.x_ref, Micrometres::from_bits(t1)];
                let learn = self.lead_window > 0;
                lead.process(&mut self.lead_gain, (io.dynamic, moved, accel, learn))
            }
            _ => {
                self.tracked = [io.x_ref; 2];
                io.dynamic
            }
        };
        self.damped = match (self.damping_on, io.damping) {
            (true, Some(c)) => c.process(&mut self.damping, dynamic),
            _ => {
                self.damping.reset();
                Micrometres::ZERO
            }
        };
        if self.transfer || law != self.law {
            self.take_over(law, io);
        }
        // The feedforward's reference: shaped by the inverse of the stage's
        // dynamics, where the model has it and it is on.
        let ff = match (self.shaping_on, io.shaping) {
            (true, _) if self.previewing => self.ahead_ff,
            (true, Some(c)) => Micrometres::from_raw(c.process(&mut self.shaped, io.x_ref.raw())),
            _ => io.x_ref,
        };
        self.last_ff = ff;
        let window = io.cfg.reference();
        let error = io.x_ref.saturating_sub(io.reading);
        let wanted = match (self.mode, io.feedback) {
            (LoopMode::Closed, Some(f)) => {
                let d = f.process(&mut self.pi, (error, self.sat, f.correction()));
                ff.saturating_add(d)
            }
            (LoopMode::FeedbackOnly, Some(f)) => f.process(&mut self.pi, (error, self.sat, window)),
            _ => {
                self.held = toward_zero(self.held);
                ff.saturating_add(self.held)
            }
        }
        .saturating_add(self.damped);
        // Where a loop runs (closed, or damping on), it is watched on the
        // tracking error wherever the model declares the position sensor (an
        // unstable loop's clearest sign: with the damping alone on a stage
        // whose mode moved, the stage swings about the reference by several
        // times the damping's correction), else on the damping's correction.
        let looped = self.mode != LoopMode::Open || self.damped != Micrometres::ZERO;
        self.alarm = if looped {
            let limited = self.clamp != Saturation::Free || self.sat != Saturation::Free;
            self.damping_alone =
                matches!((self.mode, io.feedback), (LoopMode::Open, _) | (_, None));
            let swing = match io.feedback {
                Some(_) => error,
                None => wanted.saturating_sub(ff),
            };
            self.watching = true;
            self.watch.update(
                swing,
                self.damping_alone,
                io.x_ref,
                limited,
                io.watch_halves,
            )
        } else {
            if self.watching {
                self.watch.reset();
                self.watching = false;
            }
            None
        };
        let reachable = io.x_ref >= window.lo && io.x_ref <= window.hi;
        // An unreachable reference goes to the step as it is: the step trips.
        let x_cmd = if reachable {
            clamp_to(wanted, window)
        } else {
            io.x_ref
        };
        self.clamp = Saturation::Free.or_clamp(wanted, window.lo, window.hi);
        self.last_cmd = x_cmd;
        let mode = match law {
            Law::Fpi => Mode::Compensated,
            Law::Linear => Mode::Uncompensated(*io.drive),
        };
        Command { x_cmd, mode }
    }

    /// Takes the step's result: the direction it was limited in, for the
    /// integrator's anti-windup; a fault forgets the memory (but the damping's
    /// where it runs on through the park: see the module docs).
    #[inline]
    pub fn after(&mut self, out: &StepOutput, before: Volts, cfg: &Controller<'_>) {
        if let Some(f) = out.fault {
            self.after_fault(f, out.voltage == cfg.safe_voltage());
            return;
        }
        self.parking = false;
        self.park_damping = false;
        let l = cfg.limits();
        let mid = l.min() + ((l.max() - l.min()) >> 1);
        self.sat = match self.clamp {
            Saturation::Free => Saturation::of_step(out.limited, before, out.voltage, mid),
            clamped => clamped,
        };
    }

    /// A parking step: forgets the memory; decides at the fault's first step
    /// whether the damping runs on, and drops it later when switched off or at
    /// the safe voltage (`at_safe`).
    #[inline(never)]
    #[cold]
    fn after_fault(&mut self, f: Fault, at_safe: bool) {
        let keep = self.damping_on
            && f.damps_park()
            && !(matches!(f, Fault::Oscillation) && self.damping_alone)
            && (self.park_damping || !self.parking)
            && !at_safe;
        let damping = self.damping;
        self.reset();
        if keep {
            self.damping = damping;
        }
        self.park_damping = keep;
        self.parking = true;
    }

    /// Starts `law` from the command that reproduces the present output under it.
    #[inline(never)]
    #[cold]
    fn take_over(&mut self, law: Law, io: &Inputs<'_, '_>) {
        let c = if law == self.law && !self.fresh {
            self.last_cmd
        } else {
            match law {
                Law::Fpi => io.estimate,
                Law::Linear => io.drive.reference_for(io.voltage).unwrap_or(io.estimate),
            }
        };
        let error = io.x_ref.saturating_sub(io.reading);
        if self.fresh || self.fresh_shaping {
            // After a fault, a new model or a switch the shaping starts at rest.
            self.shaped = CascadeState::settled(io.x_ref.raw());
            self.fresh_shaping = false;
        }
        // The damping's correction of this tick is part of the new law's command.
        let c = c.saturating_sub(self.damped);
        match (self.mode, io.feedback) {
            (LoopMode::Closed, Some(f)) => {
                let d = clamp_to(c.saturating_sub(io.x_ref), f.correction());
                self.pi.preset(f, d, error);
            }
            (LoopMode::FeedbackOnly, Some(f)) => {
                self.pi.preset(f, clamp_to(c, io.cfg.reference()), error);
            }
            _ => self.held = c.saturating_sub(io.x_ref),
        }
        self.law = law;
        self.transfer = false;
        self.fresh = false;
        self.sat = Saturation::Free;
    }
}

/// What [`Loop::command`] reads.
pub struct Inputs<'c, 'm> {
    /// The running model's controller.
    pub cfg: &'c Controller<'m>,
    /// Its feedback settings, if it has them.
    pub feedback: Option<&'c FeedbackConfig>,
    /// Its reference shaping, if it has it.
    pub shaping: Option<&'c Cascade<SHAPING_SECTIONS>>,
    /// Its active damping, if it has it.
    pub damping: Option<&'c DampingConfig>,
    /// Its lead, where the damping leaves the shaped reference's force out
    /// (`Summary::lead`: damping and a preview).
    pub lead: Option<&'c LeadSpec>,
    /// The oscillation watch's half swings, µm: on a closed loop's tracking
    /// error (`Summary::watch_swing`) and with the damping alone
    /// ([`crate::control::watch::HALF_SWING`]), widened while an analysis runs (its
    /// stimulus's own forced swing is not an oscillation).
    pub watch_halves: &'c [Micrometres; 2],
    /// The force channel's dynamic part this tick, N.
    pub dynamic: Newtons,
    /// Its straight-line drive.
    pub drive: &'c LinearDrive,
    /// Inverse FPI (else the straight line) in open loop.
    pub compensated: bool,
    /// Reference the loops track ([`Loop::preview`]), µm.
    pub x_ref: Micrometres,
    /// Position sensor, µm.
    pub reading: Micrometres,
    /// The model's stage position after the last tick, µm.
    pub estimate: Micrometres,
    /// The output after the last tick, V.
    pub voltage: Volts,
}

/// `x` within `i` (`max`/`min`, not `clamp`: no panic path for an inverted `i`).
fn clamp_to(x: Micrometres, i: Interval<Micrometres>) -> Micrometres {
    x.max(i.lo).min(i.hi)
}

/// One [`APPROACH_STEP`] closer to zero.
fn toward_zero(x: Micrometres) -> Micrometres {
    if x > APPROACH_STEP {
        x - APPROACH_STEP
    } else if x < -APPROACH_STEP {
        x + APPROACH_STEP
    } else {
        Micrometres::ZERO
    }
}
