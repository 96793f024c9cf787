//! What the control ISR and the link task share: one order at a time in, its
//! outcome and a status snapshot out, the recorder's ring and the streamed points.
//!
//! The board keeps one [`Exchange`] in a static and shares it as an RTIC resource:
//! the ISR, the highest-priority task using it, reaches it for free; the link task
//! locks it for the few microseconds it needs to post an order, read the status,
//! take a batch of samples or append points. The link task never holds the lock
//! while it parses or sends a frame.

use fpi_protocol::{BenchOrder, TriggerStart};
use piezo_fpi::control::Fault;
use piezo_fpi::decoupling::Decoupling;
use piezo_fpi::lead::LeadGain;
use piezo_fpi::q::{LeadRatio, Micrometres, Newtons, Volts};
use piezo_fpi::trigger::Trigger;

use crate::board::capacity::{MAX_AXES, RECORDER_SAMPLES, STREAM_POINTS};
use crate::control::analyser::{AnalyseOrder, AnalysisSums};
use crate::control::recorder::{status, Recorder, Sample, NO_TRUE_POSITION};
use crate::control::reference::raster::Raster;
use crate::control::reference::stream::Points;
use crate::control::reference::{SourceKind, SourceOrder};
use crate::control::slots::Running;
use crate::control::tracking::LoopMode;

/// What the link task asks of the control ISR; applied at the start of a tick.
pub enum Order {
    /// Switch the reference source (re-arms a stage parked by [`Fault::Stopped`]).
    Source(SourceOrder),
    /// Move each axis that has a target to it, `step` µm a tick, all from
    /// this tick (or none, when one of them refuses).
    Moves {
        /// Each axis's target, µm (none: the axis keeps its source).
        targets: [Option<Micrometres>; MAX_AXES],
        /// The largest step of each move, µm a tick.
        step: Micrometres,
    },
    /// Inverse FPI (`true`) or the straight-line baseline (`false`).
    Drive {
        /// Compensated.
        compensated: bool,
    },
    /// Open the loop, or close it on the position sensor (with or without the
    /// inverse FPI as feedforward); without a jump.
    Loop(LoopMode),
    /// Switch active damping on or off (where the model has it); without a jump.
    Damping(bool),
    /// Drive the trigger output from this condition on (its memory starts
    /// from the position and the stream's points as they are).
    Trigger(Trigger),
    /// What the trigger input's rising edge starts from now on (a wave or
    /// stream order, a record order: armed until the edge).
    TriggerIn(TriggerStart),
    /// Switch the reference shaping on or off (where the model has it); without a
    /// jump.
    Shaping(bool),
    /// Learn the lead's mass ratio on from this one (the link has checked that
    /// the running model applies it).
    LeadRatio(LeadGain),
    /// Measure the response at one frequency (the stage holding).
    Analyse(AnalyseOrder),
    /// Park the stage: ramp to the safe voltage, amplifier off ([`Fault::Stopped`]).
    Safe,
    /// Clear a latched fault (once the output is at the safe voltage).
    ClearFault,
    /// Trip [`Fault::LinkLost`] after this many ticks without a heartbeat while the
    /// host drives the stage; 0 switches the supervision off.
    Supervise {
        /// Timeout, ticks.
        timeout_ticks: u32,
    },
    /// Start recording every `decimation`-th tick.
    Record {
        /// Keep one tick in this many.
        decimation: u16,
    },
    /// Stop recording.
    StopRecording,
    /// Run the model in [`Exchange::model`] from now on (only with the stage
    /// at rest in its safe state); the one it replaces (or the new one,
    /// refused) is left there.
    Swap,
    /// Run a raster on two axes ([`Raster`]): each moves to its start, and
    /// the lines start on one tick once both are there (refused as
    /// [`Refused::Axes`] for an axis the board does not have).
    Raster(Raster),
    /// Decouple the axes from this tick on: the input matrix (sensors → axes)
    /// and the output matrix (axes → stacks), over the board's most axes;
    /// their leading block is the board's (refused as [`Refused::Axes`] on a
    /// one-axis board, or where they couple an axis the board does not have).
    Decoupling(Decoupling<MAX_AXES>),
    /// An order for the emulated board's virtual bench (taken by the emulated
    /// board before the loop sees it; the loop ignores it).
    Bench(BenchOrder),
}

/// The axes an order addresses: bit `i` is axis `i` (x, y, z). An order that
/// concerns the whole board (recording, supervision, triggers) ignores it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisSet(u8);

impl AxisSet {
    /// Every axis the board has.
    pub const ALL: Self = Self(u8::MAX);
    /// No axis.
    pub const NONE: Self = Self(0);

    /// Axis `i` alone.
    pub const fn one(i: usize) -> Self {
        Self(1 << i)
    }

    /// These axes and axis `i`.
    pub const fn with(self, i: usize) -> Self {
        Self(self.0 | 1 << i)
    }

    /// Whether axis `i` is addressed.
    pub const fn contains(self, i: usize) -> bool {
        i < 8 && self.0 & (1 << i) != 0
    }

    /// The addressed axes of a board of `n`, in order.
    pub fn indices(self, n: usize) -> impl Iterator<Item = usize> {
        (0..n).filter(move |&i| self.contains(i))
    }
}

/// An order as the link task posts it: its sequence number (the link's
/// request number), the axes it addresses and the order.
pub struct Posted {
    /// The link's request number.
    pub seq: u16,
    /// The axes a per-axis order applies to (on each, on the same tick).
    pub axes: AxisSet,
    /// What to do.
    pub order: Order,
}

impl Posted {
    /// `order` for every axis.
    pub const fn all(seq: u16, order: Order) -> Self {
        Self {
            seq,
            axes: AxisSet::ALL,
            order,
        }
    }
}

/// Why the ISR did not carry out an order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// A fault other than a parked stage is latched: clear it first.
    Fault(Fault),
    /// The output has not reached the safe voltage yet.
    StillRamping,
    /// A new model needs the stage parked at the safe voltage.
    NotAtRest,
    /// The emulated bench swaps its stage only under a board parked at the
    /// safe voltage (a stage swapped under a running loop meets loops tuned
    /// for another).
    StageNotParked,
    /// An analysis needs the stage holding still, armed.
    NotHolding,
    /// Switching the damping off would leave the loop in use unstable on the
    /// model's dynamics.
    Unstable,
    /// The running model has no feedback settings: the loop cannot be closed.
    NoFeedback,
    /// The emulated board of several axes takes no bench order but its
    /// link's pace (its stage's faults and variants are one axis's).
    BenchOfAxes,
    /// The order addresses no axis of the board, or several where it takes
    /// one (a model swap, an analysis, a stream: the board has one hand-over
    /// slot, one analysis result and one stream buffer; one axis streams at
    /// a time).
    Axes,
}

/// The outcome of the last order: which, when, and whether it was carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Applied {
    /// The order's sequence number (the link's request number).
    pub seq: u16,
    /// The tick at whose start it was applied.
    pub tick: u32,
    /// Carried out, or why not.
    pub result: Result<(), Refused>,
}

/// What one tick did (for the recorder and the emulated board's virtual stage).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Telemetry {
    /// Tick number since start-up.
    pub tick: u32,
    /// Reference, µm.
    pub x_ref: Micrometres,
    /// Setpoint written, V.
    pub voltage: Volts,
    /// Force read, N.
    pub force: Newtons,
    /// Estimated stage position, µm.
    pub x_est: Micrometres,
    /// Position sensor reading, µm.
    pub x_sensor: Micrometres,
    /// [`status`] bits.
    pub status: u8,
    /// The trigger lines after the tick ([`lines`](crate::control::recorder::lines) bits).
    pub lines: u8,
}

impl Telemetry {
    /// Nothing yet: every signal zero, no status bit.
    pub const ZERO: Self = Self {
        tick: 0,
        x_ref: Micrometres::ZERO,
        voltage: Volts::ZERO,
        force: Newtons::ZERO,
        x_est: Micrometres::ZERO,
        x_sensor: Micrometres::ZERO,
        status: 0,
        lines: 0,
    };

    /// The amplifier is enabled after this tick.
    pub const fn amplifier_on(&self) -> bool {
        self.status & status::AMPLIFIER_ON != 0
    }

    /// The recorder's sample of this tick, with the stage's true position where the
    /// board knows it (the emulated board's virtual stage).
    #[inline]
    pub fn sample(&self, x_true: Option<Micrometres>) -> Sample {
        Sample {
            tick: self.tick,
            x_ref: self.x_ref.to_bits(),
            voltage: self.voltage.to_bits(),
            force: self.force.to_bits(),
            x_est: self.x_est.to_bits(),
            x_true: x_true.map_or(NO_TRUE_POSITION, |v| v.to_bits()),
            x_sensor: self.x_sensor.to_bits(),
            status: self.status,
            lines: self.lines,
        }
    }
}

/// One axis's state, refreshed by the ISR every tick (its settings and fault
/// where they change).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisSnapshot {
    /// The last tick: its number, the signals and the status bits.
    pub now: Telemetry,
    /// The latched fault, with the tick it latched at (a fault on another
    /// axis parks this one: [`Fault::Stopped`]; [`Snapshot::fault_axis`]).
    pub fault: Option<(Fault, u32)>,
    /// Tick at which the output reached the safe voltage after the fault.
    pub safe_at: Option<u32>,
    /// The reference's source.
    pub source: SourceKind,
    /// The reference is ramping to a new source's entry point.
    pub approaching: bool,
    /// Inverse FPI (else the straight-line baseline).
    pub compensated: bool,
    /// Ticks a stream spent holding for want of points.
    pub underruns: u32,
    /// Ticks in which the output limits bit.
    pub limited_steps: u32,
    /// Ticks in which the reference governor departed from the source.
    pub governed_ticks: u32,
    /// Open or closed loop.
    pub loop_mode: LoopMode,
    /// Active damping switched on (it runs where the model has it).
    pub damping_on: bool,
    /// Reference shaping switched on (it runs where the model has it).
    pub shaping_on: bool,
    /// The explained force's learned mass ratio (`piezo_fpi::lead`).
    pub lead_ratio: LeadRatio,
    /// An analysis is running.
    pub analysing: bool,
    /// A wave or stream order waits for the trigger input's edge.
    pub motion_armed: bool,
}

impl AxisSnapshot {
    /// The state at start-up, before the first tick (all zero).
    pub const fn new() -> Self {
        Self {
            now: Telemetry::ZERO,
            fault: None,
            safe_at: None,
            source: SourceKind::Hold,
            approaching: false,
            compensated: false,
            underruns: 0,
            limited_steps: 0,
            governed_ticks: 0,
            loop_mode: LoopMode::Open,
            damping_on: false,
            shaping_on: false,
            lead_ratio: LeadRatio::ZERO,
            analysing: false,
            motion_armed: false,
        }
    }
}

impl Default for AxisSnapshot {
    fn default() -> Self {
        Self::new()
    }
}

/// The loop's state, refreshed by the ISR every tick (its settings and
/// fault where they change): each of the `N` axes', and the board's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Snapshot<const N: usize = 1> {
    /// Each axis's state.
    pub axes: [AxisSnapshot; N],
    /// The number of the last tick.
    pub tick: u32,
    /// The axis whose fault parked every axis (none: no fault other than a
    /// parked stage is latched).
    pub fault_axis: Option<u8>,
    /// Heartbeat timeout, ticks (0: not supervised).
    pub timeout_ticks: u32,
    /// Ticks since the last heartbeat.
    pub silent_ticks: u32,
    /// Streamed points a motion dropped when it ended a stream that still
    /// had them queued (since start-up).
    pub ended_points: u32,
    /// Ticks that started late.
    pub overruns: u32,
    /// What drives the trigger output.
    pub trigger: Trigger,
    /// What the trigger input's edge starts.
    pub trigger_in: TriggerStart,
    /// A record order waits for the trigger input's edge.
    pub record_armed: bool,
}

impl<const N: usize> Snapshot<N> {
    /// The state at start-up, before the first tick (all zero, so the board's
    /// exchange costs no flash for its initial value).
    pub const fn new() -> Self {
        Self {
            axes: [AxisSnapshot::new(); N],
            tick: 0,
            fault_axis: None,
            timeout_ticks: 0,
            silent_ticks: 0,
            ended_points: 0,
            overruns: 0,
            trigger: Trigger::OFF,
            trigger_in: TriggerStart::Nothing,
            record_armed: false,
        }
    }
}

impl<const N: usize> Snapshot<N> {
    /// Axis `i`'s state (the first axis's where the board has no axis `i`:
    /// the link checks an axis before it asks).
    pub fn axis(&self, i: usize) -> &AxisSnapshot {
        self.axes.get(i).unwrap_or(&self.axes[0])
    }
}

impl<const N: usize> Default for Snapshot<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// Everything the ISR and the link task share. The recorder's ring and the stream
/// buffer are statics of their own (all zero, so they cost no flash), lent here.
pub struct Exchange<'a, const N: usize = 1> {
    /// The next order (link → ISR).
    pub order: Option<Posted>,
    /// The outcome of the last order (ISR → link).
    pub applied: Option<Applied>,
    /// The models' hand-over: a new model for [`Order::Swap`] (link → ISR),
    /// then the one the ISR ran before, or the new one it would not take
    /// (ISR → link). One slot both ways: a model (its controller, its
    /// governor) is large, and the board's RAM holds one spare copy only.
    pub model: Option<Running>,
    /// Heartbeats the link task has counted (every valid request is one).
    pub heartbeats: u32,

    /// The loop's state (ISR → link).
    pub snapshot: Snapshot<N>,
    /// The data recorder (ISR fills, link empties).
    pub recorder: &'a mut Recorder<RECORDER_SAMPLES>,
    /// The streamed trajectory (link fills, ISR empties).
    pub points: &'a mut Points<STREAM_POINTS>,
    /// The last analysis's result (ISR → link; `None` while one runs).
    pub analysis: Option<AnalysisSums>,
    /// The trigger input's level this tick (the board → ISR: the board reads
    /// its pin, the emulated board its bench, before the tick).
    pub trigger_in: bool,
}

impl<'a, const N: usize> Exchange<'a, N> {
    /// Nothing ordered yet, around an empty recorder and stream buffer.
    pub fn new(
        recorder: &'a mut Recorder<RECORDER_SAMPLES>,
        points: &'a mut Points<STREAM_POINTS>,
    ) -> Self {
        Self {
            order: None,
            applied: None,
            model: None,
            heartbeats: 0,
            snapshot: Snapshot::new(),
            recorder,
            points,
            analysis: None,
            trigger_in: false,
        }
    }
}
