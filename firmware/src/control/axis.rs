//! One axis of the control task: its model, its controller's memory, its
//! hardware (force sensor, amplifier, enable line, position and analog
//! inputs), its reference and governor, its loops and watch, its analyser and
//! its faults. The control loop ([`crate::control::task::ControlLoop`]) holds
//! an array of them and what they share (the link's supervision, the tick, the
//! trigger lines, the recorder's armed order); it runs each axis's tick in
//! turn within one period, and parks every axis when one faults.
//!
//! **Parked.** At start-up, after a model change, after a `safe` order and after a
//! fault is cleared, the axis is *parked*: [`Fault::Stopped`] is latched, so the
//! output sits at the safe voltage with the amplifier off. The next source order
//! re-arms it and the reference approaches the new source from where the
//! stage rests, so no order ever makes the stage jump. Any other fault must be
//! cleared before the axis moves again.

use embedded_hal::digital::OutputPin;
use piezo_fpi::control::{ControllerState, Fault, Forces};
use piezo_fpi::governor::GovernorState;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint, Tick};
use piezo_fpi::q::{Micrometres, Newtons};

use crate::board::analog_in::{AnalogIn, POSITION_ADC};
use crate::board::capacity::{Controller, APPROACH_STEP, CREEP_TERMS, OPERATORS, STREAM_POINTS};
use crate::control::analyser::{AnalyseOrder, Analyser, AnalysisSums};
use crate::control::exchange::{AxisSnapshot, Refused, Telemetry};
use crate::control::governors::LoopSet;
use crate::control::recorder::status;
use crate::control::reference::analog::AnalogInput;
use crate::control::reference::stream::Points;
use crate::control::reference::{Reference, SourceKind, SourceOrder};
use crate::control::slots::{Running, Summary};
use crate::control::tracking::{Command, Inputs, Loop, LoopMode};

/// The loop watch's half swings are widened by this many times the
/// analyser's stimulus while it runs: the stimulus forces a swing of its own
/// (up to about 1.5 times it through a damped closed loop's sensitivity:
/// ±0.14 µm for 0.1 µm at 413 Hz on the stage as built), which is not an
/// oscillation; an unstable loop outgrows it.
pub const WATCH_WIDEN: i32 = 3;

/// The loop watch's half swings for a model (a closed loop's tracking
/// error's, the damping alone's), widened by `by`, µm.
fn watch_halves(s: &Summary, by: Micrometres) -> [Micrometres; 2] {
    let alone = Micrometres::from_bits(crate::control::watch::HALF_SWING);
    [s.watch_swing.saturating_add(by), alone.saturating_add(by)]
}

/// Where a parked stage rests on the stroke: `f_K` of the estimate, inside the
/// model's reference window.
fn rest_position(
    cfg: &Controller<'_>,
    st: &ControllerState<OPERATORS, CREEP_TERMS>,
) -> Micrometres {
    let r = cfg.reference();
    cfg.stage_position(st.x_pea_est()).max(r.lo).min(r.hi)
}

/// What an axis's tick found in its first phase ([`Axis::front`]), which
/// its later phases use.
#[derive(Debug, Clone, Copy)]
pub struct Front {
    /// The source's reference, µm.
    pub source: Micrometres,
    /// The reference the loops track (governed, previewed), µm.
    pub x_ref: Micrometres,
    /// The analyser's excitation on the command, µm.
    pub excitation: Micrometres,
    /// The force channel's reading.
    pub forces: Forces,
}

impl Front {
    /// Nothing read yet: every signal zero (a tick's phases overwrite it
    /// before they read it).
    pub const ZERO: Self = Self {
        source: Micrometres::ZERO,
        x_ref: Micrometres::ZERO,
        excitation: Micrometres::ZERO,
        forces: Forces {
            reading: Newtons::ZERO,
            feedforward: Newtons::ZERO,
            dynamic: Newtons::ZERO,
            in_range: true,
        },
    };
}

/// One axis's state; `S`, `A`, `E`, `R`: its force sensor, its amplifier, the
/// amplifier's enable line and its analog inputs (position, reference).
pub struct Axis<S, A, E, R> {
    model: Running,
    state: ControllerState<OPERATORS, CREEP_TERMS>,
    hw: Hardware<S, A, E>,
    analog_in: R,
    reference: Reference,
    compensated: bool,
    feedback: Loop,
    x_est: Micrometres,
    x_sensor: Micrometres,
    fault_at: Option<(Fault, u32)>,
    safe_at: Option<u32>,
    underruns: u32,
    force: Newtons,
    analyser: Analyser,
    /// The reference governor's memory.
    governor: GovernorState,
    /// The set of loops in force (which governor runs).
    loop_set: LoopSet,
    /// Ticks the governor departed from the source.
    governed: u32,
    /// The settings or the fault changed: the snapshot's copy of them is
    /// refreshed at the tick's end.
    changed: bool,
    /// A fault other than a parked stage latched since the loop last looked
    /// (the loop then parks the other axes).
    tripped: bool,
    /// The loop watch's half swings (a closed loop's, the damping alone's),
    /// widened by [`WATCH_WIDEN`] times the analyser's stimulus while it runs,
    /// µm.
    watch_halves: [Micrometres; 2],
    /// The status bits the settings set (uncompensated drive, feedback).
    status_base: u8,
    /// A wave or stream order armed for the trigger input's edge.
    armed: Option<SourceOrder>,
    /// Its part of a raster waits for the trigger input's edge (at its
    /// start, or on its way there) before its lines start.
    raster_armed: bool,
}

impl<S: ForceSensor, A: Setpoint, E: OutputPin, R: AnalogIn> Axis<S, A, E, R> {
    /// A parked axis running `model`. Reads the force once and takes it as the
    /// compliance term's reference force (the stage is at rest now).
    pub fn new(model: Running, mut hw: Hardware<S, A, E>, analog_in: R) -> Self {
        let force = hw.sensor.read_force();
        let (state, reference) = Self::parked(&model, force);
        let x_est = rest_position(model.get(), &state);
        let mut axis = Self {
            model,
            state,
            hw,
            analog_in,
            x_est,
            reference,
            compensated: true,
            feedback: Loop::new(),
            x_sensor: Micrometres::ZERO,
            fault_at: Some((Fault::Stopped, 0)),
            safe_at: None,
            underruns: 0,
            force,
            analyser: Analyser::new(),
            governor: GovernorState::at_rest(x_est),
            loop_set: LoopSet::default(),
            governed: 0,
            changed: true,
            tripped: false,
            watch_halves: [Micrometres::ZERO; 2],
            status_base: 0,
            armed: None,
            raster_armed: false,
        };
        axis.update_loop_set();
        axis
    }

    /// The loop watch's half swings, widened by `by` (µm).
    fn widen_watch(&mut self, by: Micrometres) {
        self.watch_halves = watch_halves(self.model.summary(), by);
    }

    /// Picks the governor of the loops in force (the loop mode, the damping
    /// and the shaping where they run) and the status bits they set.
    fn update_loop_set(&mut self) {
        if !self.analyser.running() {
            self.widen_watch(Micrometres::ZERO);
        }
        let s = self.model.summary();
        let damping = self.feedback.damping_on() && s.damping.is_some();
        let shaping = self.feedback.shaping_on() && (s.preview.is_some() || s.shaping.is_some());
        self.loop_set = LoopSet::of(self.feedback.mode(), damping, shaping);
        self.status_base = 0;
        if !self.compensated {
            self.status_base |= status::UNCOMPENSATED;
        }
        if self.feedback.mode() != LoopMode::Open {
            self.status_base |= status::FEEDBACK;
        }
        self.changed = true;
    }

    /// A fresh controller state for `model`, tared and parked, and its reference.
    fn parked(
        model: &Running,
        force: Newtons,
    ) -> (ControllerState<OPERATORS, CREEP_TERMS>, Reference) {
        let cfg = model.get();
        let mut state = cfg.initial_state();
        cfg.tare(&mut state, force);
        state.trip(Fault::Stopped);
        let analog = AnalogInput::over(cfg.reference());
        let reference = Reference::new(rest_position(cfg, &state), APPROACH_STEP, analog);
        (state, reference)
    }

    /// This axis's part of tick `tick`, whole: [`Axis::read_position`],
    /// [`Axis::front`], [`Axis::command`] and [`Axis::back`] in turn (a loop
    /// that decouples its axes reads every position, then runs the front and
    /// the command of every axis, then every back, its matrices between
    /// them). Its telemetry (without the trigger lines, which the
    /// loop adds) and the source's reference, µm. Bounded time, no panic.
    #[inline]
    pub fn tick(
        &mut self,
        tick: u32,
        points: &mut Points<STREAM_POINTS>,
        analysis: &mut Option<AnalysisSums>,
    ) -> (Telemetry, Micrometres) {
        self.read_position();
        let front = self.front(points, Newtons::ZERO);
        let cmd = self.command(&front);
        (self.back(tick, &front, &cmd, analysis), front.source)
    }

    /// Reads the position sensor ([`Axis::x_sensor`], until the loop's
    /// input matrix replaces it).
    #[inline]
    pub fn read_position(&mut self) {
        self.x_sensor = POSITION_ADC.to_position(self.analog_in.read_position());
    }

    /// The tick's first phase, after the position is read: the reference
    /// from its source (the streamed `points`, or the analog input), the
    /// governor, the preview, the force sensor (its model force with
    /// `coupled`, N: what the other stacks put on this one).
    #[inline]
    pub fn front(&mut self, points: &mut Points<STREAM_POINTS>, coupled: Newtons) -> Front {
        let counts = if self.reference.wants_analog() {
            self.analog_in.read_counts()
        } else {
            0
        };
        let source = match self.reference.next(points, counts) {
            Ok(r) => r,
            Err(_) => {
                self.trip(Fault::ReferenceInput);
                self.reference.position()
            }
        };
        // Every source, and the analyser's stimulus on top of a held one,
        // passes the governor of the loops in force.
        // A source beyond the window (a stream's points queued for a wider
        // model, say) asks for what the model cannot reach: named, parked.
        // The governor would hold the stage at the window's edge meanwhile.
        if !self.model.governors().window.holds(source) && self.state.fault().is_none() {
            self.trip(Fault::ReferenceUnreachable);
        }
        let asked = self.analyser.excitation();
        let summary = self.model.summary();
        let g = self.model.governors();
        let governed = g.limits(self.loop_set).process(
            &g.window,
            &mut self.governor,
            source.saturating_add(asked),
        );
        self.governed = self.governed.wrapping_add(self.governor.governed() as u32);
        let (x_ahead, excitation) = if self.analyser.running() {
            (source, governed.saturating_sub(source))
        } else {
            (governed, Micrometres::ZERO)
        };
        let stepping = self.reference.stepping();
        let x_ref = self
            .feedback
            .preview(x_ahead, summary.preview.as_ref(), stepping);
        let forces = self
            .hw
            .sense_coupled(self.model.get(), &mut self.state, coupled);
        Front {
            source,
            x_ref,
            excitation,
            forces,
        }
    }

    /// Its part of a raster has reached its start, the governor's
    /// reference too, and waits for the others.
    pub const fn raster_waiting(&self) -> bool {
        self.reference.waiting() && !self.governor.governed()
    }

    /// Its part of a raster is still on its way to its start (its source,
    /// or the governor's reference behind it), or waits there for the
    /// trigger input's edge.
    pub const fn raster_approaching(&self) -> bool {
        self.reference.raster_approaching()
            || (self.reference.waiting() && (self.governor.governed() || self.raster_armed))
    }

    /// Its part of a raster waits for the trigger input's edge (after
    /// [`Axis::start_source`] started it).
    pub fn arm_raster(&mut self) {
        self.raster_armed = true;
        self.changed = true;
    }

    /// The trigger input's edge came: a raster armed for it starts its
    /// lines once every one of its axes is at its start.
    pub fn fire_raster(&mut self) {
        self.changed |= self.raster_armed;
        self.raster_armed = false;
    }

    /// Starts its waiting part of a raster from the next tick on.
    pub fn release_raster(&mut self) {
        self.reference.release();
    }

    /// The axis's position as the loop's input matrix makes it of every
    /// sensor's reading, µm (replaces this tick's reading).
    #[inline]
    pub fn set_x_sensor(&mut self, x: Micrometres) {
        self.x_sensor = x;
    }

    /// The tick's second phase: checks the position (a bad reading trips a
    /// fault) and turns the reference the loops track into this tick's
    /// command, the analyser's excitation on top (µm of the axis's output,
    /// before the loop's output matrix).
    #[inline]
    pub fn command(&mut self, front: &Front) -> Command {
        if self.state.fault().is_none() {
            let fb = self.model.summary().feedback.as_ref();
            if let Some(f) = self.feedback.check(fb, self.x_sensor, self.x_est) {
                self.trip(f);
            }
        }
        let summary = self.model.summary();
        let feedback = summary.feedback.as_ref();
        let mut cmd = self.feedback.command(&Inputs {
            cfg: self.model.get(),
            feedback,
            shaping: summary.shaping.as_ref(),
            damping: summary.damping.as_ref(),
            lead: summary.lead.as_ref(),
            watch_halves: &self.watch_halves,
            dynamic: front.forces.dynamic,
            drive: &summary.baseline,
            compensated: self.compensated,
            x_ref: front.x_ref,
            reading: self.x_sensor,
            estimate: self.x_est,
            voltage: self.state.voltage(),
        });
        if let Some(f) = self.feedback.alarm() {
            if self.state.fault().is_none() {
                self.trip(f);
            }
        }
        cmd.x_cmd = cmd.x_cmd.saturating_add(front.excitation);
        cmd
    }

    /// The tick's last phase: the control step on `cmd` (the stack's
    /// command, µm, after the loop's output matrix), the amplifier, the
    /// analyser (an analysis that ends leaves its sums in `analysis`), the
    /// fault's bookkeeping. Its telemetry, without the trigger lines.
    #[inline]
    pub fn back(
        &mut self,
        tick: u32,
        front: &Front,
        cmd: &Command,
        analysis: &mut Option<AnalysisSums>,
    ) -> Telemetry {
        if self.state.fault().is_some() {
            self.damp_park();
        }
        let cfg = self.model.get();
        let before = self.state.voltage();
        let forces = &front.forces;
        let Tick { out, force } = self
            .hw
            .drive(cfg, &mut self.state, &cmd.mode, cmd.x_cmd, forces);
        self.feedback.after(&out, before, cfg);
        if self.analyser.running() {
            let signals = [
                self.x_sensor.to_bits(),
                force.to_bits(),
                forces.dynamic.to_bits(),
                out.voltage.to_bits(),
                front.excitation.to_bits(),
            ];
            let governed = self.governor.governed();
            if let Some(r) = self.analyser.take(signals, out.fault.is_some(), governed) {
                *analysis = Some(r);
                self.changed = true;
                self.watch_halves = watch_halves(self.model.summary(), Micrometres::ZERO);
            }
        }
        self.x_est = cfg.stage_position(out.x_pea_est);
        let at_safe = out.voltage == cfg.safe_voltage();
        let t = Telemetry {
            tick,
            x_ref: front.x_ref,
            voltage: out.voltage,
            force,
            x_est: self.x_est,
            x_sensor: self.x_sensor,
            status: self.status(out.limited, out.fault, at_safe),
            lines: 0,
        };
        if let Some(f) = out.fault {
            self.reference.freeze();
            if self.fault_at.is_none() {
                self.fault_at = Some((f, tick));
                self.changed = true;
                // Latched by the step (a sensor out of range…): the loop
                // parks the other axes as for a trip.
                self.tripped |= f != Fault::Stopped;
            }
            if self.safe_at.is_none() && at_safe {
                self.safe_at = Some(tick);
                self.changed = true;
            }
        }
        self.underruns = self
            .underruns
            .wrapping_add(self.reference.underrun() as u32);
        self.force = force;
        t
    }

    /// Offers the damping's correction, where it runs on through the park
    /// (`tracking`'s module docs), to the park's next step: half its µm
    /// through the straight-line drive's slope (the stroke's mean V/µm), V
    /// (`I16F16`). Half the loop gain: the law's gain is designed for the
    /// stage's mode, and the mode a caught oscillation rings at may be far
    /// below it, where the full gain overdamps the mode and leaves a slow swing
    /// of its own near the law's 100 Hz corners (measured: a mode at 300 Hz
    /// swings down to −2.3 to −3.2 µm with the full gain, −0.2 µm with half, −0.5 µm
    /// with a quarter; `autotune`'s unstable-loop test).
    #[inline(never)]
    #[cold]
    fn damp_park(&mut self) {
        let d = self.feedback.park_correction();
        let line = &self.model.summary().baseline;
        let v = line.voltage(d >> 1).saturating_sub(line.offset);
        self.state.damp_park(v);
    }

    fn status(&self, limited: bool, fault: Option<Fault>, at_safe: bool) -> u8 {
        let mut s = self.status_base;
        if fault.is_some() {
            s |= status::FAULT;
        }
        if !(fault.is_some() && at_safe) {
            s |= status::AMPLIFIER_ON;
        }
        if limited {
            s |= status::LIMITED;
        }
        if self.reference.underrun() {
            s |= status::UNDERRUN;
        }
        if self.reference.approaching() {
            s |= status::APPROACHING;
        }
        if self.governor.governed() {
            s |= status::GOVERNED;
        }
        s
    }

    /// Refreshes the axis's part of the link task's snapshot: what changes
    /// from tick to tick, and the settings and the fault where they changed.
    #[inline(never)]
    pub fn snapshot(&mut self, s: &mut AxisSnapshot, t: &Telemetry) {
        s.now = *t;
        s.source = self.reference.kind();
        s.approaching = self.reference.approaching();
        s.underruns = self.underruns;
        s.limited_steps = self.state.limited_steps();
        s.governed_ticks = self.governed;
        s.lead_ratio = self.feedback.lead_ratio();
        if self.changed {
            self.publish(s);
        }
    }

    /// The settings and the fault, into the snapshot (after a tick that
    /// changed them).
    #[cold]
    #[inline(never)]
    fn publish(&mut self, s: &mut AxisSnapshot) {
        self.changed = false;
        s.fault = self.state.fault().and(self.fault_at);
        s.safe_at = self.safe_at;
        s.compensated = self.compensated;
        s.loop_mode = self.feedback.mode();
        s.damping_on = self.feedback.damping_on();
        s.shaping_on = self.feedback.shaping_on();
        s.analysing = self.analyser.running();
        s.motion_armed = self.armed.is_some() || self.raster_armed;
    }

    /// Latches `fault` and stops the reference where it is; an armed motion
    /// is dropped.
    #[cold]
    #[inline(never)]
    pub fn trip(&mut self, fault: Fault) {
        self.armed = None;
        self.raster_armed = false;
        self.state.trip(fault);
        self.reference.freeze();
        self.changed = true;
        self.tripped |= fault != Fault::Stopped;
    }

    /// Whether a fault other than a parked stage latched since the last call.
    pub fn take_tripped(&mut self) -> bool {
        core::mem::take(&mut self.tripped)
    }

    /// Parks the axis (another axis faulted): [`Fault::Stopped`] unless a
    /// fault is latched already.
    #[cold]
    #[inline(never)]
    pub fn park(&mut self) {
        if self.state.fault().is_none() {
            self.trip(Fault::Stopped);
        } else {
            self.armed = None;
            self.raster_armed = false;
            self.changed = true;
        }
    }

    /// The output is at the safe voltage.
    fn at_safe_voltage(&self) -> bool {
        self.state.voltage() == self.model.get().safe_voltage()
    }

    /// A fault is latched and the output is at the safe voltage: the axis
    /// may take a new model or a new stage.
    fn at_rest(&self) -> bool {
        self.state.fault().is_some() && self.at_safe_voltage()
    }

    /// Whether a source order would re-arm the axis now (else why not).
    pub fn can_arm(&self) -> Result<(), Refused> {
        match self.state.fault() {
            None => Ok(()),
            Some(Fault::Stopped) if self.at_safe_voltage() => Ok(()),
            Some(Fault::Stopped) => Err(Refused::StillRamping),
            Some(f) => Err(Refused::Fault(f)),
        }
    }

    /// Leaves the parked state for a source order.
    #[inline(never)]
    fn arm(&mut self) -> Result<(), Refused> {
        self.can_arm()?;
        if self.state.fault().is_some() {
            let cfg = self.model.get();
            self.state.clear_fault(cfg);
            let rest = rest_position(cfg, &self.state);
            self.reference
                .reset(rest, AnalogInput::over(cfg.reference()));
            self.feedback.restart_reference(rest);
            self.governor = GovernorState::at_rest(rest);
            self.fault_at = None;
            self.safe_at = None;
        }
        Ok(())
    }

    /// Arms `s` for the trigger input's edge (re-arming a parked axis).
    pub fn arm_for_edge(&mut self, s: SourceOrder) -> Result<(), Refused> {
        self.arm()?;
        self.armed = Some(s);
        self.changed = true;
        Ok(())
    }

    /// The motion armed for the trigger input's edge, taken.
    pub fn take_armed(&mut self) -> Option<SourceOrder> {
        let armed = self.armed.take();
        self.changed |= armed.is_some();
        armed
    }

    /// Drops an armed motion (the trigger input no longer starts motions, or
    /// a source order replaced it).
    pub fn disarm(&mut self) {
        self.changed |= self.armed.is_some();
        self.armed = None;
        if self.raster_armed {
            // The raster waits for an edge that will not start it: it
            // ends, held where it is.
            self.raster_armed = false;
            self.reference.select(SourceOrder::Hold);
            self.changed = true;
        }
    }

    /// Switches the reference to source `s` (leaving the parked state); the
    /// board's stream bookkeeping is the loop's.
    pub fn start_source(&mut self, s: SourceOrder) -> Result<(), Refused> {
        self.arm()?;
        self.analyser.abort();
        self.widen_watch(Micrometres::ZERO);
        if matches!(s, SourceOrder::Stream { .. }) {
            self.underruns = 0;
        }
        self.reference.select(s);
        self.changed = true;
        Ok(())
    }

    /// Inverse FPI (`true`) or the straight-line baseline.
    pub fn set_compensated(&mut self, compensated: bool) {
        self.compensated = compensated;
        self.update_loop_set();
    }

    /// Whether the loop can take `mode` (closing it needs the model's feedback).
    pub fn can_loop(&self, mode: LoopMode) -> Result<(), Refused> {
        if mode != LoopMode::Open && self.model.summary().feedback.is_none() {
            return Err(Refused::NoFeedback);
        }
        Ok(())
    }

    /// Opens or closes the loop (checked by [`Self::can_loop`]).
    pub fn select_loop(&mut self, mode: LoopMode) {
        self.feedback.select(mode);
        self.update_loop_set();
    }

    /// Active damping on or off.
    pub fn set_damping(&mut self, on: bool) {
        self.feedback.set_damping(on);
        self.update_loop_set();
    }

    /// Reference shaping on or off.
    pub fn set_shaping(&mut self, on: bool) {
        self.feedback.set_shaping(on);
        self.update_loop_set();
    }

    /// Learns the lead's mass ratio on from `gain`.
    pub fn start_lead(&mut self, gain: piezo_fpi::lead::LeadGain) {
        self.feedback.start_lead(gain);
        self.changed = true;
    }

    /// Whether an analysis can start (the axis armed and holding still).
    pub fn can_analyse(&self) -> Result<(), Refused> {
        let holding = self.state.fault().is_none()
            && self.reference.kind() == SourceKind::Hold
            && !self.reference.approaching();
        if holding {
            Ok(())
        } else {
            Err(Refused::NotHolding)
        }
    }

    /// Starts the analysis `o` (checked by [`Self::can_analyse`]).
    pub fn analyse(&mut self, o: AnalyseOrder) {
        self.analyser.start(o);
        self.widen_watch(o.amplitude.saturating_mul_int(WATCH_WIDEN));
        self.changed = true;
    }

    /// Whether a latched fault can be cleared now.
    pub fn can_clear(&self) -> Result<(), Refused> {
        if self.state.fault().is_some() && !self.at_safe_voltage() {
            return Err(Refused::StillRamping);
        }
        Ok(())
    }

    /// Clears a fault into the parked state, at tick `tick` (checked by
    /// [`Self::can_clear`]).
    pub fn clear(&mut self, tick: u32) {
        if self.state.fault().is_none() {
            return;
        }
        self.state.clear_fault(self.model.get());
        // What the force channel learned while the fault grew is not trusted.
        self.state.forget_force_learning();
        self.state.trip(Fault::Stopped);
        self.fault_at = Some((Fault::Stopped, tick));
        self.safe_at = Some(tick);
        self.changed = true;
    }

    /// The axis is parked: stopped at the safe voltage, the amplifier off.
    pub fn is_parked(&self) -> bool {
        matches!(self.state.fault(), Some(Fault::Stopped)) && self.at_safe_voltage()
    }

    /// Runs the model in `slot` from tick `tick` on if the axis is at rest
    /// (a fault latched, the output at the safe voltage); the model it
    /// replaces goes back into `slot` (a model refused stays there).
    pub fn swap(&mut self, slot: &mut Option<Running>, tick: u32) -> Result<(), Refused> {
        if !self.at_rest() {
            return Err(Refused::NotAtRest);
        }
        let Some(new) = slot.take() else {
            return Err(Refused::NotAtRest);
        };
        *slot = Some(core::mem::replace(&mut self.model, new));
        self.start_parked(tick);
        Ok(())
    }

    /// A new stage attached at rest, at tick `tick`: if the axis is at rest,
    /// its model starts again as after its upload, tared at the new stage's
    /// force reading, and `true`.
    pub fn restart_on_new_stage(&mut self, tick: u32) -> bool {
        if !self.at_rest() {
            return false;
        }
        self.force = self.hw.sensor.read_force();
        self.start_parked(tick);
        true
    }

    /// The running model starts parked from a fresh state, tared at the last
    /// force reading, as designed (its damping and shaping on), the feedback's
    /// memory and the learned mass ratio forgotten.
    fn start_parked(&mut self, tick: u32) {
        let (state, reference) = Self::parked(&self.model, self.force);
        if self.model.summary().feedback.is_none() {
            self.feedback.select(LoopMode::Open);
        }
        self.feedback.set_damping(true);
        self.feedback.set_shaping(true);
        self.feedback.reset();
        self.feedback.forget_lead();
        self.x_est = rest_position(self.model.get(), &state);
        self.feedback.restart_reference(self.x_est);
        self.governor = GovernorState::at_rest(self.x_est);
        self.state = state;
        self.reference = reference;
        self.update_loop_set();
        self.fault_at = Some((Fault::Stopped, tick));
        self.safe_at = Some(tick);
    }

    /// The model running now.
    pub const fn model(&self) -> &Running {
        &self.model
    }

    /// The controller's memory (for diagnostics).
    pub const fn state(&self) -> &ControllerState<OPERATORS, CREEP_TERMS> {
        &self.state
    }

    /// The loop's mode and memories: feedback, damping, shaping (for diagnostics).
    pub const fn feedback(&self) -> &Loop {
        &self.feedback
    }

    /// The reference's source now.
    pub const fn source(&self) -> SourceKind {
        self.reference.kind()
    }

    /// `x` (µm of the axis's output: a command the loop's output matrix
    /// made) held to the model's reference window: where the other axes'
    /// parasitic motion asks for more than the stack can do (an axis at the
    /// end of its stroke), the stack does what it can rather than the step
    /// refusing a command outside the window as an unreachable reference.
    #[inline]
    pub fn within_reach(&self, x: Micrometres) -> Micrometres {
        let r = self.model.get().reference();
        x.max(r.lo).min(r.hi)
    }

    /// The position sensor's last reading, µm.
    pub const fn x_sensor(&self) -> Micrometres {
        self.x_sensor
    }
}
