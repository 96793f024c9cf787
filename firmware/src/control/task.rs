//! The control ISR's whole job, hardware-independent: take an order, supervise
//! the link, run one control tick on every axis, report.
//!
//! The board's control task owns a [`ControlLoop`] and calls [`ControlLoop::tick`]
//! once per period with the [`Exchange`] it shares with the link task, then
//! [`ControlLoop::record`] (the emulated board first steps its virtual stage, so
//! the recording carries the true position too). The host's twin of the emulated
//! board calls the same two functions in a plain loop.
//!
//! **Axes.** The loop drives `N` axes ([`Axis`]: each its model, loops,
//! reference, governor, watch and faults) in one tick, and holds what they
//! share: the link's supervision, the tick count and its overruns, the trigger
//! output (on the first axis's position and reference) and input, and the
//! recorder's armed order. An order addresses a set of axes
//! ([`Posted::axes`](crate::control::exchange::Posted)) and applies to each on
//! the same tick, or to none when one of them refuses it; a wave or stream
//! order armed for the trigger input starts on every armed axis on the
//! edge's tick. A fault on any axis parks every axis (each ramps to its safe
//! voltage; [`Snapshot::fault_axis`](crate::control::exchange::Snapshot) names
//! the axis). A model swap, an analysis and a stream take one axis at a time:
//! the board has one model hand-over slot, one analysis result and one stream
//! buffer.
//!
//! **Parked.** At start-up, after a model change, after a `safe` order and after a
//! fault is cleared, an axis is *parked* ([`crate::control::axis`]); the next
//! source order re-arms it without a jump.

use embedded_hal::digital::OutputPin;
use piezo_fpi::control::Fault;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Micrometres, Newtons};

use crate::board::analog_in::AnalogIn;
use crate::board::capacity::RATE_HZ;
pub use crate::control::axis::{Axis, Front, WATCH_WIDEN};
pub use crate::control::exchange::Telemetry;
use crate::control::exchange::{Applied, AxisSet, Exchange, Order, Posted, Refused, Snapshot};

/// Heartbeat timeout a stream gets when the host has configured none: 0.5 s.
pub const STREAM_TIMEOUT_TICKS: u32 = RATE_HZ / 2;
/// Late ticks in a row that latch [`Fault::Overrun`]: 1 ms of a loop that cannot
/// keep its rate (a single late tick is counted, not a fault).
pub const OVERRUN_RUN: u32 = RATE_HZ / 1000;
use crate::control::recorder::{lines, Sample};
use crate::control::reference::raster::Raster;
use crate::control::reference::{SourceKind, SourceOrder};
use crate::control::slots::Running;
use crate::control::tracking::Command;
use fpi_protocol::TriggerStart;
use piezo_fpi::decoupling::Decoupling;
use piezo_fpi::process::SplitProcess as _;
use piezo_fpi::trigger::{Condition, Readings, Trigger, TriggerState};

/// The control ISR's state: `N` axes and what they share; `S`, `A`, `E`, `R`:
/// each axis's force sensor, amplifier, its enable line and analog inputs.
pub struct ControlLoop<S, A, E, R, const N: usize = 1> {
    axes: [Axis<S, A, E, R>; N],
    timeout: u32,
    silent: u32,
    last_heartbeat: u32,
    tick: u32,
    overruns: u32,
    late_run: u32,
    /// The axis whose fault parked every axis.
    fault_axis: Option<u8>,
    /// The board's settings changed this tick: the snapshot's copy of them
    /// is refreshed at its end.
    changed: bool,
    /// The supervision's timeout is a stream's (it switched it on), not the
    /// host's.
    stream_supervised: bool,
    /// What drives the trigger output.
    trigger: Trigger,
    /// The trigger output's memory.
    trigger_state: TriggerState,
    /// What the trigger input's rising edge starts.
    starts: TriggerStart,
    /// The trigger input's level at the last tick.
    input_was: bool,
    /// A recording (its decimation) armed for the trigger input's edge.
    armed_record: Option<u16>,
    /// The axis the recorder records (a record order's one), or every
    /// axis (`None`: a record order that addresses several).
    recorded: Option<usize>,
    /// The axes' input and output matrices and the stacks' preload coupling
    /// (none on one axis).
    decoupling: Decoupling<N>,
    /// A raster's axes are on their way to its start: its lines start on
    /// every one of them on the tick the last arrives.
    raster_pending: bool,
    /// Each axis's front and command between the phases of a coupled tick
    /// (scratch, written before it is read: kept here so that the tick
    /// writes them in place, where an array built on the stack was copied).
    staged: [(Front, Command); N],
    /// Each axis's telemetry of the last tick ([`ControlLoop::tick`]'s
    /// answer).
    telemetry: [Telemetry; N],
}

impl<S: ForceSensor, A: Setpoint, E: OutputPin, R: AnalogIn, const N: usize>
    ControlLoop<S, A, E, R, N>
{
    /// `N` parked axes, axis `i` running its model on its hardware and
    /// analog inputs (`axes[i]`). Each reads its force once and takes it as
    /// its compliance term's reference force (the stage is at rest now).
    pub fn new(axes: [(Running, Hardware<S, A, E>, R); N]) -> Self {
        let axes = axes.map(|(model, hw, analog_in)| Axis::new(model, hw, analog_in));
        Self {
            axes,
            timeout: 0,
            silent: 0,
            last_heartbeat: 0,
            tick: 0,
            overruns: 0,
            late_run: 0,
            fault_axis: None,
            changed: true,
            stream_supervised: false,
            trigger: Trigger::OFF,
            trigger_state: TriggerState::at(Micrometres::ZERO, 0),
            starts: TriggerStart::Nothing,
            input_was: false,
            armed_record: None,
            recorded: Some(0),
            decoupling: Decoupling::NONE,
            raster_pending: false,
            staged: [(Front::ZERO, Command::ZERO); N],
            telemetry: [Telemetry::ZERO; N],
        }
    }

    /// One control period: the pending order, the trigger input, the link's
    /// supervision, each axis's tick, the trigger output, the snapshot. Each
    /// axis's telemetry. Bounded time, no panic.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_, N>) -> &[Telemetry; N] {
        if x.order.is_some() {
            self.take_order(x);
        }
        if x.trigger_in && !self.input_was {
            self.trigger_edge(x);
        }
        self.input_was = x.trigger_in;
        self.supervise(x.heartbeats);
        let tick = self.tick;
        let first_source = if N == 1 {
            self.tick_one(tick, x)
        } else {
            self.tick_coupled(tick, x)
        };
        if N > 1 {
            self.park_on_fault();
            if self.raster_pending {
                self.release_raster();
            }
        }
        let out_line = if self.trigger.condition() == Condition::Off {
            0
        } else {
            let reading = self.axes[0].x_sensor();
            trigger_line(
                &self.trigger,
                &mut self.trigger_state,
                first_source,
                reading,
                x.points.taken(),
            )
        };
        let lines = out_line | ((x.trigger_in as u8) * lines::TRIGGER_IN);
        let each = self
            .axes
            .iter_mut()
            .zip(x.snapshot.axes.iter_mut())
            .zip(self.telemetry.iter_mut());
        for ((axis, s), t) in each {
            t.lines = lines;
            axis.snapshot(s, t);
        }
        self.snapshot(&mut x.snapshot);
        self.tick = tick.wrapping_add(1);
        &self.telemetry
    }

    /// Each axis's tick whole, one axis after the other (no matrix between
    /// them: one axis, or none coupled), its telemetry kept; the first
    /// axis's source reference, µm.
    #[inline(always)]
    fn tick_one(&mut self, tick: u32, x: &mut Exchange<'_, N>) -> Micrometres {
        let mut first_source = Micrometres::ZERO;
        for (i, (a, t)) in self
            .axes
            .iter_mut()
            .zip(self.telemetry.iter_mut())
            .enumerate()
        {
            let source;
            (*t, source) = a.tick(tick, x.points, &mut x.analysis);
            if i == 0 {
                first_source = source;
            }
        }
        first_source
    }

    /// Every axis's tick in phases, the decoupling between them: every
    /// axis's position; the input matrix (sensors → axes); every axis's
    /// reference, force (its model force with the preload the other stacks'
    /// last estimated extensions put on it) and command; the output matrix
    /// (axes → stacks), each command held to its axis's reference window;
    /// every axis's step and amplifier, its telemetry kept.
    /// The first axis's source reference, µm.
    #[inline(always)]
    fn tick_coupled(&mut self, tick: u32, x: &mut Exchange<'_, N>) -> Micrometres {
        self.axes.iter_mut().for_each(Axis::read_position);
        let d = &self.decoupling;
        if !d.input.is_identity() {
            let read = core::array::from_fn(|i| self.axes[i].x_sensor());
            let x = d.input.process(&mut (), read);
            for (a, x) in self.axes.iter_mut().zip(x) {
                a.set_x_sensor(x);
            }
        }
        let coupled = if d.preload.is_none() {
            [Newtons::ZERO; N]
        } else {
            let pea = core::array::from_fn(|i| self.axes[i].state().x_pea_est());
            d.preload.process(&mut (), pea)
        };
        let each = self.axes.iter_mut().zip(self.staged.iter_mut());
        for ((a, (front, cmd)), coupled) in each.zip(coupled) {
            *front = a.front(x.points, coupled);
            *cmd = a.command(front);
        }
        let d = &self.decoupling;
        if !d.output.is_identity() {
            let commands = core::array::from_fn(|i| self.staged[i].1.x_cmd);
            let x = d.output.process(&mut (), commands);
            let each = self.axes.iter().zip(self.staged.iter_mut());
            for ((a, (_, c)), x) in each.zip(x) {
                c.x_cmd = a.within_reach(x);
            }
        }
        let each = self.axes.iter_mut().zip(&self.staged);
        for ((a, (front, cmd)), t) in each.zip(self.telemetry.iter_mut()) {
            *t = a.back(tick, front, cmd, &mut x.analysis);
        }
        self.staged
            .first()
            .map_or(Micrometres::ZERO, |(f, _)| f.source)
    }

    /// Parks every axis when one latched a fault this tick, and names it.
    #[inline]
    fn park_on_fault(&mut self) {
        let Some(i) = self.axes.iter_mut().position(|a| a.take_tripped()) else {
            return;
        };
        self.fault_axis = Some(i as u8);
        self.park_all();
    }

    /// Starts a raster's lines on every one of its axes once none is still
    /// on its way to its start (out of line: a raster starts rarely). A
    /// raster whose axes were stopped before it started is forgotten.
    #[cold]
    #[inline(never)]
    fn release_raster(&mut self) {
        if self.axes.iter().any(Axis::raster_approaching) {
            return;
        }
        self.raster_pending = false;
        for a in self.axes.iter_mut().filter(|a| a.raster_waiting()) {
            a.release_raster();
        }
    }

    /// Parks every axis (a fault latched on one of them, or on the board).
    #[cold]
    #[inline(never)]
    fn park_all(&mut self) {
        for a in self.axes.iter_mut() {
            a.park();
            a.take_tripped();
        }
        self.changed = true;
    }

    /// Latches a fault the board finds on all of it (the link lost, a late
    /// loop, a failed converter) on every axis.
    #[cold]
    #[inline(never)]
    fn trip_all(&mut self, fault: Fault) {
        for a in self.axes.iter_mut() {
            a.trip(fault);
            a.take_tripped();
        }
        self.changed = true;
    }

    /// Each axis's telemetry of the last tick.
    #[inline]
    pub const fn telemetry(&self) -> &[Telemetry; N] {
        &self.telemetry
    }

    /// Offers this tick of axis `axis` to the recorder, with the stage's true
    /// position where the board knows it (the emulated board's virtual stage);
    /// the sample.
    #[inline]
    pub fn record(
        &self,
        x: &mut Exchange<'_, N>,
        t: &Telemetry,
        x_true: Option<Micrometres>,
    ) -> Sample {
        let s = t.sample(x_true);
        x.recorder.offer(&s);
        s
    }

    /// The axis the recorder records (the last record order's): the board
    /// offers its telemetry to [`ControlLoop::record`]; `None` where it
    /// records every axis ([`ControlLoop::record_axes`]).
    #[inline]
    pub const fn recorded_axis(&self) -> Option<usize> {
        self.recorded
    }

    /// Offers this tick of the recorded axis, or of every axis, to the
    /// recorder, each with its stage's true position where the board knows
    /// it (`x_true[i]`, the emulated board's virtual stage): a board of
    /// several axes.
    pub fn record_axes(&self, x: &mut Exchange<'_, N>, x_true: &[Option<Micrometres>; N]) {
        match self.recorded {
            Some(i) => {
                if let (Some(t), Some(&at)) = (self.telemetry.get(i), x_true.get(i)) {
                    x.recorder.offer(&t.sample(at));
                }
            }
            None => {
                let mut samples = [Sample::default(); N];
                for ((s, t), &at) in samples.iter_mut().zip(&self.telemetry).zip(x_true) {
                    *s = t.sample(at);
                }
                x.recorder.offer_all(&samples);
            }
        }
    }

    /// The axes a record order records: one, or every axis.
    fn recorded_of(&self, axes: AxisSet) -> Result<Option<usize>, Refused> {
        let mut it = axes.indices(N);
        match (it.next(), it.next()) {
            (Some(i), None) => Ok(Some(i)),
            (Some(_), Some(_)) => Ok(None),
            (None, _) => Err(Refused::Axes),
        }
    }

    /// Tells the loop whether the tick just run ended after the next one was due
    /// (the board checks its timer's pending flag). Late ticks are counted; a run
    /// of [`OVERRUN_RUN`] latches [`Fault::Overrun`] and the outputs ramp to the
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
            self.trip_all(Fault::Overrun);
        }
    }

    /// Latches a fault the board finds outside the loop (a failed converter,
    /// [`Fault::Converter`]) on every axis; from the next tick the outputs ramp
    /// to the safe voltage. A fault already latched stays.
    pub fn fail(&mut self, fault: Fault) {
        self.trip_all(fault);
    }

    /// The number the next tick will have.
    pub const fn next_tick(&self) -> u32 {
        self.tick
    }

    /// The axes.
    pub const fn axes(&self) -> &[Axis<S, A, E, R>; N] {
        &self.axes
    }

    /// Refreshes the board's part of the link task's snapshot: what changes
    /// from tick to tick, and the settings where they changed.
    #[inline(never)]
    fn snapshot(&mut self, s: &mut Snapshot<N>) {
        s.tick = self.tick;
        s.silent_ticks = self.silent;
        if self.changed {
            self.publish(s);
        }
    }

    /// The board's settings into the snapshot (after a tick that changed
    /// them).
    #[cold]
    #[inline(never)]
    fn publish(&mut self, s: &mut Snapshot<N>) {
        self.changed = false;
        s.fault_axis = self.fault_axis;
        s.timeout_ticks = self.timeout;
        s.overruns = self.overruns;
        s.trigger = self.trigger;
        s.trigger_in = self.starts;
        s.record_armed = self.armed_record.is_some();
    }

    /// The trigger input rose: what is armed starts, on every armed axis on
    /// this tick (out of line: an edge is rare). An armed motion an axis
    /// cannot start now (a fault latched since) is dropped; the status says
    /// why.
    #[cold]
    #[inline(never)]
    fn trigger_edge(&mut self, x: &mut Exchange<'_, N>) {
        for i in 0..N {
            if let Some(s) = self.axes[i].take_armed() {
                let _ = self.start_source(i, s, x);
            }
            self.axes[i].fire_raster();
        }
        if let Some(decimation) = self.armed_record.take() {
            x.recorder.start(decimation);
        }
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
        if self.timeout != 0 && self.silent > self.timeout && self.host_drives() {
            self.lost();
        }
    }

    /// Whether the host drives an axis that runs: one is armed (no fault) and
    /// its reference is not the analog input's.
    #[inline]
    fn host_drives(&self) -> bool {
        self.axes
            .iter()
            .any(|a| a.state().fault().is_none() && a.source() != SourceKind::Analog)
    }

    /// Whether an axis outside `axes` streams.
    fn streams_elsewhere(&self, axes: AxisSet) -> bool {
        let elsewhere = |(i, a): (usize, &Axis<S, A, E, R>)| {
            !axes.contains(i) && a.source() == SourceKind::Stream
        };
        self.axes.iter().enumerate().any(elsewhere)
    }

    /// The host has been silent past the timeout: the link is lost, unless
    /// the timeout was a stream's and the stream is over (the stage holds
    /// its last point; its client may be gone): the supervision then ends.
    #[cold]
    #[inline(never)]
    fn lost(&mut self) {
        let streaming = self.axes.iter().any(|a| a.source() == SourceKind::Stream);
        if self.stream_supervised && !streaming {
            self.stream_supervised = false;
            self.timeout = 0;
            self.changed = true;
        } else {
            self.trip_all(Fault::LinkLost);
        }
    }

    /// Applies the pending order. Out of line: an order (a model swap carries a
    /// whole controller) needs a stack frame the ordinary tick does not.
    #[inline(never)]
    #[cold]
    fn take_order(&mut self, x: &mut Exchange<'_, N>) {
        if let Some(Posted { seq, axes, order }) = x.order.take() {
            self.changed = true;
            let result = self.apply(axes, order, x);
            x.applied = Some(Applied {
                seq,
                tick: self.tick,
                result,
            });
        }
    }

    /// The addressed axes' indices, each checked by `check` first: all of
    /// them, or why the first that refuses does (then none is changed).
    fn addressed(
        &self,
        axes: AxisSet,
        check: impl Fn(&Axis<S, A, E, R>) -> Result<(), Refused>,
    ) -> Result<impl Iterator<Item = usize>, Refused> {
        let mut any = false;
        for (i, a) in self.axes.iter().enumerate() {
            if axes.contains(i) {
                check(a)?;
                any = true;
            }
        }
        if !any {
            return Err(Refused::Axes);
        }
        Ok(axes.indices(N))
    }

    /// Applies `f` to every addressed axis once `check` passes on each of
    /// them; else why the first that refuses does (then none is changed).
    fn each(
        &mut self,
        axes: AxisSet,
        check: impl Fn(&Axis<S, A, E, R>) -> Result<(), Refused>,
        mut f: impl FnMut(&mut Axis<S, A, E, R>),
    ) -> Result<(), Refused> {
        for i in self.addressed(axes, check)? {
            f(&mut self.axes[i]);
        }
        Ok(())
    }

    /// The one axis an order that takes one addresses.
    fn only(&self, axes: AxisSet) -> Result<usize, Refused> {
        let mut it = axes.indices(N);
        match (it.next(), it.next()) {
            (Some(i), None) => Ok(i),
            _ => Err(Refused::Axes),
        }
    }

    fn apply(
        &mut self,
        axes: AxisSet,
        order: Order,
        x: &mut Exchange<'_, N>,
    ) -> Result<(), Refused> {
        match order {
            Order::Source(s) => self.sources(axes, s, x),
            Order::Moves { targets, step } => self.moves(&targets, step, x),
            Order::TriggerIn(starts) => {
                self.starts = starts;
                self.input_was = x.trigger_in;
                if !starts.motion() {
                    self.axes.iter_mut().for_each(Axis::disarm);
                }
                if !starts.recorder() {
                    self.armed_record = None;
                }
                Ok(())
            }
            Order::Record { decimation } if self.starts.recorder() => {
                self.recorded = self.recorded_of(axes)?;
                self.armed_record = Some(decimation);
                Ok(())
            }
            Order::Drive { compensated } => {
                self.each(axes, |_| Ok(()), |a| a.set_compensated(compensated))
            }
            Order::Loop(mode) => self.each(axes, |a| a.can_loop(mode), |a| a.select_loop(mode)),
            Order::Damping(on) => self.each(axes, |_| Ok(()), |a| a.set_damping(on)),
            Order::Trigger(t) => {
                self.trigger = t;
                self.trigger_state = TriggerState::at(
                    self.axes.first().map_or(Micrometres::ZERO, Axis::x_sensor),
                    x.points.taken(),
                );
                Ok(())
            }
            Order::Shaping(on) => self.each(axes, |_| Ok(()), |a| a.set_shaping(on)),
            Order::LeadRatio(gain) => self.each(axes, |_| Ok(()), |a| a.start_lead(gain)),
            Order::Analyse(o) => {
                let i = self.only(axes)?;
                self.axes[i].can_analyse()?;
                x.analysis = None;
                self.axes[i].analyse(o);
                Ok(())
            }
            Order::Safe => self.each(axes, |_| Ok(()), |a| a.trip(Fault::Stopped)),
            Order::ClearFault => {
                let tick = self.tick;
                self.each(axes, Axis::can_clear, |a| a.clear(tick))?;
                // The board's fault is gone once no axis holds one (a parked
                // axis, still ramping or at rest, holds none).
                let holds = |a: &Axis<S, A, E, R>| {
                    !matches!(a.state().fault(), None | Some(Fault::Stopped))
                };
                if !self.axes.iter().any(holds) {
                    self.fault_axis = None;
                }
                Ok(())
            }
            Order::Supervise { timeout_ticks } => {
                self.timeout = timeout_ticks;
                self.silent = 0;
                self.stream_supervised = false;
                Ok(())
            }
            Order::Record { decimation } => {
                self.recorded = self.recorded_of(axes)?;
                x.recorder.start(decimation);
                Ok(())
            }
            Order::StopRecording => {
                self.armed_record = None;
                x.recorder.stop();
                Ok(())
            }
            Order::Swap => self.swap(axes, x),
            Order::Raster(r) => self.raster(r, x),
            Order::Decoupling(d) => match d.leading() {
                Some(d) if N > 1 => {
                    self.decoupling = d;
                    Ok(())
                }
                _ => Err(Refused::Axes),
            },
            Order::Bench(_) => Ok(()),
        }
    }

    /// A source order for `axes`: armed for the trigger input's edge where
    /// the input starts motions and the source waits for it, else started;
    /// on every addressed axis on this tick, or on none.
    fn sources(
        &mut self,
        axes: AxisSet,
        s: SourceOrder,
        x: &mut Exchange<'_, N>,
    ) -> Result<(), Refused> {
        if matches!(s, SourceOrder::Stream { .. })
            && (self.only(axes).is_err() || self.streams_elsewhere(axes))
        {
            return Err(Refused::Axes);
        }
        let arm = self.starts.motion() && s.waits_for_trigger();
        for i in self.addressed(axes, Axis::can_arm)? {
            if arm {
                self.axes[i].arm_for_edge(s)?;
            } else {
                self.start_source(i, s, x)?;
            }
        }
        Ok(())
    }

    /// Each axis with a target moves to it from this tick, or none does
    /// (one cannot leave where it is).
    fn moves(
        &mut self,
        targets: &[Option<Micrometres>; crate::board::capacity::MAX_AXES],
        step: Micrometres,
        x: &mut Exchange<'_, N>,
    ) -> Result<(), Refused> {
        let set = targets
            .iter()
            .enumerate()
            .filter(|(_, t)| t.is_some())
            .fold(AxisSet::NONE, |set, (i, _)| set.with(i));
        if targets.iter().skip(N).any(Option::is_some) {
            return Err(Refused::Axes);
        }
        let mut any = false;
        for i in self.addressed(set, Axis::can_arm)? {
            if let Some(&Some(target)) = targets.get(i) {
                self.start_source(i, SourceOrder::Move { target, step }, x)?;
                any = true;
            }
        }
        if any {
            Ok(())
        } else {
            Err(Refused::Axes)
        }
    }

    /// Starts raster `r`: both its axes leave for their starts on this tick
    /// (or neither, when one refuses); the lines start on the tick both are
    /// there, or, where the trigger input starts motions, on the first tick
    /// both are there after its rising edge.
    fn raster(&mut self, r: Raster, x: &mut Exchange<'_, N>) -> Result<(), Refused> {
        let (fast, slow) = (r.fast.0, r.slow.0);
        if fast >= N || slow >= N {
            return Err(Refused::Axes);
        }
        let both = AxisSet::one(fast).with(slow);
        // Both can start, or neither is changed.
        let _ = self.addressed(both, Axis::can_arm)?;
        let armed = self.starts.motion();
        for (i, part) in [r.fast, r.slow] {
            self.start_source(i, SourceOrder::Raster(part), x)?;
            if let (true, Some(a)) = (armed, self.axes.get_mut(i)) {
                a.arm_raster();
            }
        }
        self.raster_pending = true;
        Ok(())
    }

    /// Switches axis `i`'s reference to source `s` (leaving the parked
    /// state; a motion armed for the trigger is dropped), with the board's
    /// stream bookkeeping: a stream is supervised; another motion ends what a
    /// stream left, where no other axis streams.
    fn start_source(
        &mut self,
        i: usize,
        s: SourceOrder,
        x: &mut Exchange<'_, N>,
    ) -> Result<(), Refused> {
        let Some(axis) = self.axes.get_mut(i) else {
            return Err(Refused::Axes);
        };
        axis.disarm();
        axis.start_source(s)?;
        if matches!(s, SourceOrder::Stream { .. }) {
            // A stream is always supervised.
            if self.timeout == 0 {
                self.timeout = STREAM_TIMEOUT_TICKS;
                self.silent = 0;
                self.stream_supervised = true;
            }
        } else if !self.streams_elsewhere(AxisSet::one(i)) {
            self.end_stream(x);
        }
        Ok(())
    }

    /// A motion that is not a stream's ends whatever a stream left: its
    /// queued points (counted in [`Snapshot::ended_points`]: a client that
    /// died mid-stream left them, and the next stream would play them) and
    /// the supervision the stream switched on (the new motion's client may
    /// not send heartbeats).
    ///
    /// [`Snapshot::ended_points`]: crate::control::exchange::Snapshot::ended_points
    fn end_stream(&mut self, x: &mut Exchange<'_, N>) {
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

    /// Runs the model the link task handed over ([`Exchange::model`]) on the
    /// one addressed axis from this tick on if that axis is parked at the safe
    /// voltage; the model it replaces (or the new one, refused) goes back to
    /// the link task in the same slot.
    #[inline(never)]
    fn swap(&mut self, axes: AxisSet, x: &mut Exchange<'_, N>) -> Result<(), Refused> {
        let i = self.only(axes)?;
        let tick = self.tick;
        self.axes[i].swap(&mut x.model, tick)
    }

    /// Every axis is parked: stopped at the safe voltage, the amplifier off.
    pub fn is_parked(&self) -> bool {
        self.axes.iter().all(Axis::is_parked)
    }

    /// A new stage attached at rest (the emulated bench swapped it, as a
    /// power-up with another stage would): if every axis is parked at the
    /// safe voltage, the running models start again as after their upload —
    /// tared at the new stage's force readings, their operators at rest, the
    /// learned mass ratios forgotten — and `true`; else nothing changes (a
    /// stage swapped under a running loop keeps the old tare, which the force
    /// channel's learning then corrects over seconds of motion).
    pub fn restart_on_new_stage(&mut self) -> bool {
        if !self.is_parked() {
            return false;
        }
        let tick = self.tick;
        for a in self.axes.iter_mut() {
            a.restart_on_new_stage(tick);
        }
        self.changed = true;
        true
    }
}

#[cfg(all(test, feature = "sim"))]
mod tests;

/// The trigger lines after a tick, the output's condition on, from the
/// source's reference and the position sensor's reading (µm) and the streamed
/// points taken (out of line: the ordinary tick keeps its registers).
#[inline(never)]
fn trigger_line(
    trigger: &Trigger,
    state: &mut TriggerState,
    x_ref: Micrometres,
    x: Micrometres,
    points: u32,
) -> u8 {
    let r = Readings { x, x_ref, points };
    trigger.process(state, r) as u8 * lines::TRIGGER_OUT
}
