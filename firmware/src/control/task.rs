//! The control ISR's whole job, hardware-independent: take an order, generate the
//! reference, supervise the link, run one control tick, report.
//!
//! The board's control task owns a [`ControlLoop`] and calls [`ControlLoop::tick`]
//! once per period with the [`Exchange`] it shares with the link task, then
//! [`ControlLoop::record`] (the emulated board first steps its virtual stage, so
//! the recording carries the true position too). The host's twin of the emulated
//! board calls the same two functions in a plain loop.
//!
//! **Parked.** At start-up, after a model change, after a `safe` order and after a
//! fault is cleared, the stage is *parked*: [`Fault::Stopped`] is latched, so the
//! output sits at the safe voltage with the amplifier off. The next source order
//! re-arms the loop and the reference approaches the new source from where the
//! stage rests, so no order ever makes the stage jump. Any other fault must be
//! cleared before the stage moves again.

use embedded_hal::digital::OutputPin;
use piezo_fpi::control::{ControllerState, Fault};
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint, Tick};
use piezo_fpi::q::{Micrometres, Newtons};

use piezo_fpi::governor::GovernorState;

use crate::board::analog_in::{AnalogIn, POSITION_ADC};
use crate::board::capacity::{Controller, APPROACH_STEP, CREEP_TERMS, OPERATORS, RATE_HZ};
use crate::control::analyser::Analyser;
pub use crate::control::exchange::Telemetry;
use crate::control::exchange::{Applied, Exchange, Order, Refused, Snapshot};
use crate::control::governors::LoopSet;
use crate::control::tracking::{Command, Inputs, Loop, LoopMode};

/// Heartbeat timeout a stream gets when the host has configured none: 0.5 s.
pub const STREAM_TIMEOUT_TICKS: u32 = RATE_HZ / 2;
/// Late ticks in a row that latch [`Fault::Overrun`]: 1 ms of a loop that cannot
/// keep its rate (a single late tick is counted, not a fault).
pub const OVERRUN_RUN: u32 = RATE_HZ / 1000;
use crate::control::recorder::{lines, status, Sample};
use crate::control::reference::analog::AnalogInput;
use crate::control::reference::{Reference, SourceKind, SourceOrder};
use crate::control::slots::Running;
use fpi_protocol::TriggerStart;
use piezo_fpi::process::SplitProcess as _;
use piezo_fpi::trigger::{Condition, Readings, Trigger, TriggerState};

/// The control ISR's state (one per stage channel); `S`, `A`, `E`, `R`: the force
/// sensor, the amplifier, its enable line and the analog reference input.
pub struct ControlLoop<S, A, E, R> {
    model: Running,
    state: ControllerState<OPERATORS, CREEP_TERMS>,
    hw: Hardware<S, A, E>,
    analog_in: R,
    reference: Reference,
    compensated: bool,
    feedback: Loop,
    x_est: Micrometres,
    x_sensor: Micrometres,
    timeout: u32,
    silent: u32,
    last_heartbeat: u32,
    tick: u32,
    fault_at: Option<(Fault, u32)>,
    safe_at: Option<u32>,
    underruns: u32,
    overruns: u32,
    late_run: u32,
    force: Newtons,
    analyser: Analyser,
    /// The reference governor's memory.
    governor: GovernorState,
    /// The set of loops in force (which governor runs).
    loop_set: LoopSet,
    /// Ticks the governor departed from the source.
    governed: u32,
    /// The settings or the fault changed this tick: the snapshot's copy of
    /// them is refreshed at its end.
    changed: bool,
    /// The supervision's timeout is a stream's (it switched it on), not the
    /// host's.
    stream_supervised: bool,
    /// The loop watch's half swings (a closed loop's, the damping alone's),
    /// widened by [`WATCH_WIDEN`] times the analyser's stimulus while it runs,
    /// µm.
    watch_halves: [Micrometres; 2],
    /// The status bits the settings set (uncompensated drive, feedback).
    status_base: u8,
    /// What drives the trigger output.
    trigger: Trigger,
    /// The trigger output's memory.
    trigger_state: TriggerState,
    /// What the trigger input's rising edge starts.
    starts: TriggerStart,
    /// The trigger input's level at the last tick.
    input_was: bool,
    /// A wave or stream order armed for the trigger input's edge.
    armed: Option<SourceOrder>,
    /// A recording (its decimation) armed for the trigger input's edge.
    armed_record: Option<u16>,
}

/// The loop watch's half swings are widened by this many times the
/// analyser's stimulus while it runs: the stimulus forces a swing of its own
/// (up to about 1.5 times it through a damped closed loop's sensitivity:
/// ±0.14 µm for 0.1 µm at 413 Hz on the stage as built), which is not an
/// oscillation; an unstable loop outgrows it.
pub const WATCH_WIDEN: i32 = 3;

/// The loop watch's half swings for a model (a closed loop's tracking
/// error's, the damping alone's), widened by `by`, µm.
fn watch_halves(s: &crate::control::slots::Summary, by: Micrometres) -> [Micrometres; 2] {
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

impl<S: ForceSensor, A: Setpoint, E: OutputPin, R: AnalogIn> ControlLoop<S, A, E, R> {
    /// A parked loop running `model`. Reads the force once and takes it as the
    /// compliance term's reference force (the stage is at rest now).
    pub fn new(model: Running, mut hw: Hardware<S, A, E>, analog_in: R) -> Self {
        let force = hw.sensor.read_force();
        let (state, reference) = Self::parked(&model, force);
        let x_est = rest_position(model.get(), &state);
        Self {
            model,
            state,
            hw,
            analog_in,
            x_est,
            reference,
            compensated: true,
            feedback: Loop::new(),
            x_sensor: Micrometres::ZERO,
            timeout: 0,
            silent: 0,
            last_heartbeat: 0,
            tick: 0,
            fault_at: Some((Fault::Stopped, 0)),
            safe_at: None,
            underruns: 0,
            overruns: 0,
            late_run: 0,
            force,
            analyser: Analyser::new(),
            governor: GovernorState::at_rest(x_est),
            loop_set: LoopSet::default(),
            governed: 0,
            changed: true,
            stream_supervised: false,
            watch_halves: [Micrometres::ZERO; 2],
            status_base: 0,
            trigger: Trigger::OFF,
            trigger_state: TriggerState::at(Micrometres::ZERO, 0),
            starts: TriggerStart::Nothing,
            input_was: false,
            armed: None,
            armed_record: None,
        }
        .with_loop_set()
    }

    /// The loop set of the loops in force (after an order that changes them).
    fn with_loop_set(mut self) -> Self {
        self.update_loop_set();
        self
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

    /// One control period. Bounded time, no panic.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_>) -> Telemetry {
        if x.order.is_some() {
            self.take_order(x);
        }
        if x.trigger_in && !self.input_was {
            self.trigger_edge(x);
        }
        self.input_was = x.trigger_in;
        self.supervise(x.heartbeats);
        let counts = if self.reference.wants_analog() {
            self.analog_in.read_counts()
        } else {
            0
        };
        let source = match self.reference.next(x.points, counts) {
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
        let cfg = self.model.get();
        let forces = self.hw.sense(cfg, &mut self.state);
        let cmd = self.command(x_ref, forces.dynamic);
        if self.state.fault().is_some() {
            self.damp_park();
        }
        let cfg = self.model.get();
        let before = self.state.voltage();
        let Tick { out, force } = self.hw.drive(
            cfg,
            &mut self.state,
            &cmd.mode,
            cmd.x_cmd.saturating_add(excitation),
            &forces,
        );
        self.feedback.after(&out, before, cfg);
        if self.analyser.running() {
            let signals = [
                self.x_sensor.to_bits(),
                force.to_bits(),
                forces.dynamic.to_bits(),
                out.voltage.to_bits(),
                excitation.to_bits(),
            ];
            let governed = self.governor.governed();
            if let Some(r) = self.analyser.take(signals, out.fault.is_some(), governed) {
                x.analysis = Some(r);
                self.changed = true;
                self.watch_halves = watch_halves(self.model.summary(), Micrometres::ZERO);
            }
        }
        self.x_est = cfg.stage_position(out.x_pea_est);
        let at_safe = out.voltage == cfg.safe_voltage();
        let out_line = if self.trigger.condition() == Condition::Off {
            0
        } else {
            self.trigger_line(source, x.points.taken())
        };
        let lines = out_line | ((x.trigger_in as u8) * lines::TRIGGER_IN);
        let t = Telemetry {
            tick: self.tick,
            x_ref,
            voltage: out.voltage,
            force,
            x_est: self.x_est,
            x_sensor: self.x_sensor,
            status: self.status(out.limited, out.fault, at_safe),
            lines,
        };
        if let Some(f) = out.fault {
            self.reference.freeze();
            if self.fault_at.is_none() {
                self.fault_at = Some((f, self.tick));
                self.changed = true;
            }
            if self.safe_at.is_none() && at_safe {
                self.safe_at = Some(self.tick);
                self.changed = true;
            }
        }
        self.underruns = self
            .underruns
            .wrapping_add(self.reference.underrun() as u32);
        self.force = force;
        self.snapshot(&mut x.snapshot, &t);
        self.tick = self.tick.wrapping_add(1);
        t
    }

    /// Reads the position sensor, checks it (a bad reading trips a fault), and
    /// turns the reference the loops track (µm) into this tick's command, with
    /// the force channel's dynamic part (N) for the damping.
    #[inline]
    fn command(&mut self, x_ref: Micrometres, dynamic: Newtons) -> Command {
        self.x_sensor = POSITION_ADC.to_position(self.analog_in.read_position());
        if self.state.fault().is_none() {
            let fb = self.model.summary().feedback.as_ref();
            if let Some(f) = self.feedback.check(fb, self.x_sensor, self.x_est) {
                self.trip(f);
            }
        }
        let summary = self.model.summary();
        let feedback = summary.feedback.as_ref();
        let cmd = self.feedback.command(&Inputs {
            cfg: self.model.get(),
            feedback,
            shaping: summary.shaping.as_ref(),
            damping: summary.damping.as_ref(),
            lead: summary.lead.as_ref(),
            watch_halves: &self.watch_halves,
            dynamic,
            drive: &summary.baseline,
            compensated: self.compensated,
            x_ref,
            reading: self.x_sensor,
            estimate: self.x_est,
            voltage: self.state.voltage(),
        });
        if let Some(f) = self.feedback.alarm() {
            if self.state.fault().is_none() {
                self.trip(f);
            }
        }
        cmd
    }

    /// Offers the damping's correction, where it runs on through the park
    /// (`closed_loop`'s module docs), to the park's next step: half its µm
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

    /// Offers this tick to the recorder, with the stage's true position where the
    /// board knows it (the emulated board's virtual stage); the sample.
    #[inline]
    pub fn record(
        &self,
        x: &mut Exchange<'_>,
        t: &Telemetry,
        x_true: Option<Micrometres>,
    ) -> Sample {
        let s = t.sample(x_true);
        x.recorder.offer(&s);
        s
    }

    /// Tells the loop whether the tick just run ended after the next one was due
    /// (the board checks its timer's pending flag). Late ticks are counted; a run
    /// of [`OVERRUN_RUN`] latches [`Fault::Overrun`] and the output ramps to the
    /// safe voltage.
    #[inline]
    pub fn late(&mut self, late: bool) {
        if !late {
            self.late_run = 0;
            return;
        }
        self.overruns = self.overruns.wrapping_add(1);
        self.changed = true;
        self.late_run += 1;
        if self.late_run >= OVERRUN_RUN {
            self.trip(Fault::Overrun);
        }
    }

    /// Latches a fault the board finds outside the loop (a failed converter,
    /// [`Fault::Converter`]); from the next tick the output ramps to the safe
    /// voltage. A fault already latched stays.
    pub fn fail(&mut self, fault: Fault) {
        self.trip(fault);
    }

    /// The number the next tick will have.
    pub const fn next_tick(&self) -> u32 {
        self.tick
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

    #[inline(never)]
    /// Refreshes the link task's snapshot: what changes from tick to tick,
    /// and the settings and the fault where they changed ([`Self::changed`]).
    fn snapshot(&mut self, s: &mut Snapshot, t: &Telemetry) {
        s.now = *t;
        s.source = self.reference.kind();
        s.approaching = self.reference.approaching();
        s.silent_ticks = self.silent;
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
    fn publish(&mut self, s: &mut Snapshot) {
        self.changed = false;
        s.fault = self.state.fault().and(self.fault_at);
        s.safe_at = self.safe_at;
        s.compensated = self.compensated;
        s.timeout_ticks = self.timeout;
        s.overruns = self.overruns;
        s.loop_mode = self.feedback.mode();
        s.damping_on = self.feedback.damping_on();
        s.shaping_on = self.feedback.shaping_on();
        s.analysing = self.analyser.running();
        s.trigger = self.trigger;
        s.trigger_in = self.starts;
        s.motion_armed = self.armed.is_some();
        s.record_armed = self.armed_record.is_some();
    }

    /// The trigger lines after this tick, the output's condition on
    /// (out of line: the ordinary tick keeps its registers).
    #[inline(never)]
    fn trigger_line(&mut self, x_ref: Micrometres, points: u32) -> u8 {
        let r = Readings {
            x: self.x_sensor,
            x_ref,
            points,
        };
        self.trigger.process(&mut self.trigger_state, r) as u8 * lines::TRIGGER_OUT
    }

    /// The trigger input rose: what is armed starts (out of line: an edge is
    /// rare). An armed motion the board cannot start now (a fault latched
    /// since) is dropped; the status says why.
    #[cold]
    #[inline(never)]
    fn trigger_edge(&mut self, x: &mut Exchange<'_>) {
        if let Some(s) = self.armed.take() {
            let _ = self.start_source(s, x);
        }
        if let Some(decimation) = self.armed_record.take() {
            x.recorder.start(decimation);
        }
        self.changed = true;
    }

    /// Latches `fault` and stops the reference where it is.
    fn trip(&mut self, fault: Fault) {
        self.armed = None;
        self.state.trip(fault);
        self.reference.freeze();
        self.changed = true;
    }

    /// Counts silent ticks; trips [`Fault::LinkLost`] when the host, driving the
    /// stage, has been silent for longer than the timeout.
    #[inline]
    fn supervise(&mut self, heartbeats: u32) {
        if heartbeats != self.last_heartbeat {
            self.last_heartbeat = heartbeats;
            self.silent = 0;
        } else {
            self.silent = self.silent.saturating_add(1);
        }
        if self.timeout != 0
            && self.silent > self.timeout
            && self.state.fault().is_none()
            && self.reference.kind() != SourceKind::Analog
        {
            self.lost();
        }
    }

    /// The host has been silent past the timeout: the link is lost, unless
    /// the timeout was a stream's and the stream is over (the stage holds
    /// its last point; its client may be gone): the supervision then ends.
    #[cold]
    #[inline(never)]
    fn lost(&mut self) {
        if self.stream_supervised && self.reference.kind() != SourceKind::Stream {
            self.stream_supervised = false;
            self.timeout = 0;
            self.changed = true;
        } else {
            self.trip(Fault::LinkLost);
        }
    }

    /// Applies the pending order. Out of line: an order (a model swap carries a
    /// whole controller) needs a stack frame the ordinary tick does not.
    #[inline(never)]
    #[cold]
    fn take_order(&mut self, x: &mut Exchange<'_>) {
        if let Some((seq, order)) = x.order.take() {
            self.changed = true;
            let result = self.apply(order, x);
            x.applied = Some(Applied {
                seq,
                tick: self.tick,
                result,
            });
        }
    }

    fn apply(&mut self, order: Order, x: &mut Exchange<'_>) -> Result<(), Refused> {
        match order {
            Order::Source(s) if self.starts.motion() && s.waits_for_trigger() => {
                self.arm()?;
                self.armed = Some(s);
                Ok(())
            }
            Order::Source(s) => {
                self.armed = None;
                self.start_source(s, x)
            }
            Order::TriggerIn(starts) => {
                self.starts = starts;
                self.input_was = x.trigger_in;
                if !starts.motion() {
                    self.armed = None;
                }
                if !starts.recorder() {
                    self.armed_record = None;
                }
                Ok(())
            }
            Order::Record { decimation } if self.starts.recorder() => {
                self.armed_record = Some(decimation);
                Ok(())
            }
            Order::Drive { compensated } => {
                self.compensated = compensated;
                self.update_loop_set();
                Ok(())
            }
            Order::Loop(mode) => {
                if mode != LoopMode::Open && self.model.summary().feedback.is_none() {
                    return Err(Refused::NoFeedback);
                }
                self.feedback.select(mode);
                self.update_loop_set();
                Ok(())
            }
            Order::Damping(on) => {
                self.feedback.set_damping(on);
                self.update_loop_set();
                Ok(())
            }
            Order::Trigger(t) => {
                self.trigger = t;
                self.trigger_state = TriggerState::at(self.x_sensor, x.points.taken());
                Ok(())
            }
            Order::Shaping(on) => {
                self.feedback.set_shaping(on);
                self.update_loop_set();
                Ok(())
            }
            Order::LeadRatio(gain) => {
                self.feedback.start_lead(gain);
                Ok(())
            }
            Order::Analyse(o) => {
                let holding = self.state.fault().is_none()
                    && self.reference.kind() == SourceKind::Hold
                    && !self.reference.approaching();
                if !holding {
                    return Err(Refused::NotHolding);
                }
                x.analysis = None;
                self.analyser.start(o);
                self.widen_watch(o.amplitude.saturating_mul_int(WATCH_WIDEN));
                Ok(())
            }
            Order::Safe => {
                self.trip(Fault::Stopped);
                Ok(())
            }
            Order::ClearFault => self.clear(),
            Order::Supervise { timeout_ticks } => {
                self.timeout = timeout_ticks;
                self.silent = 0;
                self.stream_supervised = false;
                Ok(())
            }
            Order::Record { decimation } => {
                x.recorder.start(decimation);
                Ok(())
            }
            Order::StopRecording => {
                self.armed_record = None;
                x.recorder.stop();
                Ok(())
            }
            Order::Swap => self.swap(x),
            Order::Bench(_) => Ok(()),
        }
    }

    /// Switches the reference to source `s` (leaving the parked state).
    fn start_source(&mut self, s: SourceOrder, x: &mut Exchange<'_>) -> Result<(), Refused> {
        self.arm()?;
        self.analyser.abort();
        self.widen_watch(Micrometres::ZERO);
        if matches!(s, SourceOrder::Stream { .. }) {
            self.underruns = 0;
            // A stream is always supervised.
            if self.timeout == 0 {
                self.timeout = STREAM_TIMEOUT_TICKS;
                self.silent = 0;
                self.stream_supervised = true;
            }
        } else {
            self.end_stream(x);
        }
        self.reference.select(s);
        Ok(())
    }

    /// The output is at the safe voltage.
    fn at_safe_voltage(&self) -> bool {
        self.state.voltage() == self.model.get().safe_voltage()
    }

    /// A motion that is not a stream's ends whatever a stream left: its
    /// queued points (counted in [`Snapshot::ended_points`]: a client that
    /// died mid-stream left them, and the next stream would play them) and
    /// the supervision the stream switched on (the new motion's client may
    /// not send heartbeats).
    fn end_stream(&mut self, x: &mut Exchange<'_>) {
        let queued = x.points.len() as u32;
        if queued > 0 {
            x.points.clear();
            x.snapshot.ended_points = x.snapshot.ended_points.wrapping_add(queued);
        }
        if self.stream_supervised {
            self.stream_supervised = false;
            self.timeout = 0;
        }
    }

    /// Leaves the parked state for a source order.
    #[inline(never)]
    fn arm(&mut self) -> Result<(), Refused> {
        match self.state.fault() {
            None => Ok(()),
            Some(Fault::Stopped) if self.at_safe_voltage() => {
                let cfg = self.model.get();
                self.state.clear_fault(cfg);
                let rest = rest_position(cfg, &self.state);
                self.reference
                    .reset(rest, AnalogInput::over(cfg.reference()));
                self.feedback.restart_reference(rest);
                self.governor = GovernorState::at_rest(rest);
                self.fault_at = None;
                self.safe_at = None;
                Ok(())
            }
            Some(Fault::Stopped) => Err(Refused::StillRamping),
            Some(f) => Err(Refused::Fault(f)),
        }
    }

    /// Clears a fault into the parked state.
    fn clear(&mut self) -> Result<(), Refused> {
        if self.state.fault().is_none() {
            return Ok(());
        }
        if !self.at_safe_voltage() {
            return Err(Refused::StillRamping);
        }
        self.state.clear_fault(self.model.get());
        // What the force channel learned while the fault grew is not trusted.
        self.state.forget_force_learning();
        self.state.trip(Fault::Stopped);
        self.fault_at = Some((Fault::Stopped, self.tick));
        self.safe_at = Some(self.tick);
        Ok(())
    }

    /// Runs the model the link task handed over ([`Exchange::model`]) from
    /// this tick on if the stage is parked at the safe voltage; the model it
    /// replaces (or the new one, refused) goes back to the link task in the
    /// same slot.
    #[inline(never)]
    fn swap(&mut self, x: &mut Exchange<'_>) -> Result<(), Refused> {
        if self.state.fault().is_none() || !self.at_safe_voltage() {
            return Err(Refused::NotAtRest);
        }
        let Some(new) = x.model.take() else {
            return Err(Refused::NotAtRest);
        };
        x.model = Some(core::mem::replace(&mut self.model, new));
        self.start_parked();
        Ok(())
    }

    /// The stage is parked: stopped at the safe voltage, the amplifier off.
    pub fn is_parked(&self) -> bool {
        matches!(self.state.fault(), Some(Fault::Stopped)) && self.at_safe_voltage()
    }

    /// A new stage attached at rest (the emulated bench swapped it, as a
    /// power-up with another stage would): if the loop is parked at the safe
    /// voltage, the running model starts again as after its upload — tared at
    /// the new stage's force reading, its operators at rest, the learned mass
    /// ratio forgotten — and `true`; else nothing changes (a stage swapped
    /// under a running loop keeps the old tare, which the force channel's
    /// learning then corrects over seconds of motion).
    pub fn restart_on_new_stage(&mut self) -> bool {
        if self.state.fault().is_none() || !self.at_safe_voltage() {
            return false;
        }
        self.force = self.hw.sensor.read_force();
        self.start_parked();
        true
    }

    /// The running model starts parked from a fresh state, tared at the last
    /// force reading, as designed (its damping and shaping on), the feedback's
    /// memory and the learned mass ratio forgotten.
    fn start_parked(&mut self) {
        let (state, reference) = Self::parked(&self.model, self.force);
        if self.model.summary().feedback.is_none() {
            self.feedback.select(LoopMode::Open);
        }
        self.feedback.set_damping(true);
        self.feedback.set_shaping(true);
        self.feedback.reset();
        self.feedback.forget_lead();
        self.changed = true;
        self.x_est = rest_position(self.model.get(), &state);
        self.feedback.restart_reference(self.x_est);
        self.governor = GovernorState::at_rest(self.x_est);
        self.update_loop_set();
        self.state = state;
        self.reference = reference;
        self.fault_at = Some((Fault::Stopped, self.tick));
        self.safe_at = Some(self.tick);
    }
}
