//! What the host asks: the request header and the [`Command`]s, each with the
//! wire number of its [`CommandKind`].
//!
//! A command that addresses a stage carries its `axis` first (0: the board's one
//! axis today; a board refuses an axis it does not have with
//! [`Refusal::Axis`](crate::Refusal::Axis)), so a second axis needs no new
//! protocol.

use heapless::Vec;
use serde::de::SeqAccess;
use serde::ser::SerializeTuple;
use serde::{Deserialize, Serialize};

use crate::bench::BenchOrder;
use crate::modes::{LoopMode, Shape, TriggerStart};
use crate::put;
use crate::settings::TriggerSettings;
use crate::wire::{field, Tagged};
use crate::MAX_POINTS;

/// A raster on two axes, each to its start, then `lines` lines started on
/// the same tick on both: axis `fast` a triangle between `fast_span` (µm,
/// `I16F16` bits, from and to) at `freq_mhz` (a line is half its period),
/// axis `slow` over `slow_span` by a step at each line's start
/// (`staircase`) or a ramp. On the wire: its fields in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RasterOrder {
    /// The fast axis.
    pub fast: u8,
    /// The slow axis.
    pub slow: u8,
    /// The fast axis's from and to, µm (`I16F16` bits).
    pub fast_span: [i32; 2],
    /// The slow axis's from and to, µm (`I16F16` bits).
    pub slow_span: [i32; 2],
    /// The fast axis's triangle frequency, mHz.
    pub freq_mhz: u32,
    /// Lines.
    pub lines: u16,
    /// The slow axis steps at each line's start (else it ramps).
    pub staircase: bool,
}

/// The start of every request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// [`VERSION`](crate::VERSION) of the sender.
    pub version: u8,
    /// Request number, echoed by its reply.
    pub seq: u16,
}

crate::wire_enum! {
    /// The kinds of [`Command`]: their wire numbers.
    pub enum CommandKind {
        /// [`Command::Hello`].
        Hello = 0,
        /// [`Command::Status`].
        Status = 1,
        /// [`Command::Ping`].
        Ping = 2,
        /// [`Command::Move`].
        Move = 3,
        /// [`Command::Wave`].
        Wave = 4,
        /// [`Command::Points`].
        Points = 5,
        /// [`Command::Stream`].
        Stream = 6,
        /// [`Command::StreamEnd`].
        StreamEnd = 7,
        /// [`Command::StreamClear`].
        StreamClear = 8,
        /// [`Command::Analog`].
        Analog = 9,
        /// [`Command::Hold`].
        Hold = 10,
        /// [`Command::Safe`].
        Safe = 11,
        /// [`Command::ClearFault`].
        ClearFault = 12,
        /// [`Command::Drive`].
        Drive = 13,
        /// [`Command::Supervise`].
        Supervise = 14,
        /// [`Command::Record`].
        Record = 15,
        /// [`Command::RecordStop`].
        RecordStop = 16,
        /// [`Command::ReadRecord`].
        ReadRecord = 17,
        /// [`Command::ModelBegin`].
        ModelBegin = 18,
        /// [`Command::ModelChunk`].
        ModelChunk = 19,
        /// [`Command::ModelCommit`].
        ModelCommit = 20,
        /// [`Command::ModelInfo`].
        ModelInfo = 21,
        /// [`Command::ModelFactory`].
        ModelFactory = 22,
        /// [`Command::Counters`].
        Counters = 23,
        /// [`Command::Bench`].
        Bench = 24,
        /// [`Command::Reset`].
        Reset = 25,
        /// [`Command::Loop`].
        Loop = 26,
        /// [`Command::Damping`].
        Damping = 27,
        /// [`Command::Step`].
        Step = 28,
        /// [`Command::Shaping`].
        Shaping = 29,
        /// [`Command::Analyse`].
        Analyse = 30,
        /// [`Command::AnalysisResult`].
        AnalysisResult = 31,
        /// [`Command::ModelRead`].
        ModelRead = 32,
        /// [`Command::LeadRatio`].
        LeadRatio = 33,
        /// [`Command::SettingGet`].
        SettingGet = 34,
        /// [`Command::SettingSet`].
        SettingSet = 35,
        /// [`Command::Trigger`].
        Trigger = 36,
        /// [`Command::TriggerIn`].
        TriggerIn = 37,
        /// [`Command::Raster`].
        Raster = 38,
        /// [`Command::Decoupling`].
        Decoupling = 39,
        /// [`Command::MoveAxes`].
        MoveAxes = 40,
    }
}

/// What the host asks; on the wire its [`CommandKind`] byte, then its fields in
/// order.
// Messages are built once per request and there is no heap to box the large ones.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Command<'a> {
    /// Who are you? → [`Reply::Hello`](crate::Reply::Hello).
    Hello,
    /// The loop's state of `axis` → [`Reply::Status`](crate::Reply::Status).
    Status {
        /// The stage.
        axis: u8,
    },
    /// A heartbeat (any valid request is one) → `Ack`.
    Ping,
    /// Ramp to `target` at `speed`, then hold.
    Move {
        /// The stage.
        axis: u8,
        /// Position, µm (`I16F16` bits).
        target: i32,
        /// Speed, µm/s (`I16F16` bits, > 0 and at most 30 000).
        speed: i32,
    },
    /// Run a waveform between `offset − amplitude` and `offset + amplitude`.
    Wave {
        /// The stage.
        axis: u8,
        /// Sine, triangle or raised cosine.
        shape: Shape,
        /// Mid-point, µm (`I16F16` bits).
        offset: i32,
        /// Half-swing, µm (`I16F16` bits, ≥ 0).
        amplitude: i32,
        /// Frequency, mHz (below half the control rate).
        freq_mhz: u32,
        /// Periods to run; 0 runs until another source is chosen.
        cycles: u32,
    },
    /// Append points to the stream buffer; `first` must be the index the board
    /// expects next (the count of points received since the last `Stream`).
    Points {
        /// The stage.
        axis: u8,
        /// Index of the first point.
        first: u32,
        /// Positions, µm (`I16F16` bits).
        points: Vec<i32, MAX_POINTS>,
    },
    /// Play the buffered points, one every `interval` ticks, interpolated.
    Stream {
        /// The stage.
        axis: u8,
        /// Ticks per point (≥ 1).
        interval: u16,
    },
    /// The stream has no more points: hold the last without an underrun flag.
    StreamEnd {
        /// The stage.
        axis: u8,
    },
    /// Drop the stream buffer and count points from 0 again.
    StreamClear {
        /// The stage.
        axis: u8,
    },
    /// Follow the analog reference input.
    Analog {
        /// The stage.
        axis: u8,
    },
    /// Stop where the reference is.
    Hold {
        /// The stage.
        axis: u8,
    },
    /// Park every stage: ramp to the safe voltage, amplifier off.
    Safe,
    /// Clear a latched fault (the stage stays parked until the next motion command).
    ClearFault,
    /// Inverse FPI (`true`) or the straight-line baseline (`false`).
    Drive {
        /// The stage.
        axis: u8,
        /// Compensated.
        compensated: bool,
    },
    /// Supervise the host: a motion with no request for `timeout_ms` parks the
    /// stage with a *link lost* fault; 0 switches it off.
    Supervise {
        /// Timeout, ms.
        timeout_ms: u32,
    },
    /// Start recording `axis` ([`EVERY_AXIS`](crate::EVERY_AXIS): each
    /// axis, one sample per axis of each kept tick, in axis order) every
    /// `decimation`-th tick; `signals`
    /// ([`signal`](crate::record::signal) bits) says what
    /// [`Command::ReadRecord`] sends.
    Record {
        /// The axis recorded, or every axis.
        axis: u8,
        /// Keep one tick in this many (≥ 1).
        decimation: u16,
        /// Signal mask.
        signals: u8,
    },
    /// Stop recording (the samples stay readable).
    RecordStop,
    /// Take up to `max` recorded samples → [`Reply::Record`](crate::Reply::Record).
    ReadRecord {
        /// Most samples to send.
        max: u16,
    },
    /// Announce a model image of `len` bytes with CRC-32 `crc` (of the whole image).
    ModelBegin {
        /// Bytes.
        len: u32,
        /// CRC-32 (ISO-HDLC) of the image.
        crc: u32,
    },
    /// The image's bytes from `offset` (in order, at most [`MAX_CHUNK`](crate::MAX_CHUNK)).
    ModelChunk {
        /// Where these bytes go.
        offset: u32,
        /// The bytes.
        data: &'a [u8],
    },
    /// Validate the received image and run it (the stage must be parked);
    /// `store` also writes it to flash, where it survives a reset.
    ModelCommit {
        /// The axis whose model it becomes.
        axis: u8,
        /// Keep it in flash.
        store: bool,
    },
    /// The running model of `axis` → [`Reply::Model`](crate::Reply::Model).
    ModelInfo {
        /// The axis.
        axis: u8,
    },
    /// Forget `axis`'s stored model and run the factory default (the stage
    /// must be parked).
    ModelFactory {
        /// The axis.
        axis: u8,
    },
    /// The link's counters → [`Reply::Counters`](crate::Reply::Counters).
    Counters,
    /// An order for the emulated board's virtual bench.
    Bench(BenchOrder),
    /// Reset the board (after this reply); it starts parked with its stored model.
    Reset,
    /// Open the loop or close it on the position sensor, without a jump (the
    /// running model must have feedback settings to close it).
    Loop {
        /// The stage.
        axis: u8,
        /// Open, closed (feedback plus the inverse FPI) or feedback only.
        mode: LoopMode,
    },
    /// Switch active damping on or off (it runs where the running model has it),
    /// without a jump.
    Damping {
        /// The stage.
        axis: u8,
        /// On.
        on: bool,
    },
    /// Step to `target` along a raised cosine lasting `duration_us` (zero speed at
    /// both ends), then hold.
    Step {
        /// The stage.
        axis: u8,
        /// Position, µm (`I16F16` bits).
        target: i32,
        /// Duration, µs (one control period to one second).
        duration_us: u32,
    },
    /// Drive `axis`'s trigger output as `settings` say (checked by the board:
    /// a level out of its range is refused, naming it).
    Trigger {
        /// The stage.
        axis: u8,
        /// The mode and its levels.
        settings: TriggerSettings,
    },
    /// What a rising edge on `axis`'s trigger input starts: from now on a
    /// wave or stream order, a record order, or both, wait (armed) for the
    /// next edge instead of starting at once; another source order, a stop or
    /// a fault drops an armed motion, a record stop an armed recording.
    TriggerIn {
        /// The stage.
        axis: u8,
        /// What the edge starts.
        starts: TriggerStart,
    },
    /// Switch the model's reference shaping (the feedforward of the stage's
    /// dynamics) on or off, without a jump.
    Shaping {
        /// The stage.
        axis: u8,
        /// On.
        on: bool,
    },
    /// Measure the frequency response at one frequency: add
    /// `amplitude·sin(2π·f·t)` to the command (µm) for `settle` then `cycles`
    /// whole periods, correlating the position sensor, the force reading, the
    /// force channel's dynamic part and the setpoint with the excitation over
    /// the last `cycles` (the stage must be holding). → `Ack`; the result by
    /// [`Command::AnalysisResult`].
    Analyse {
        /// The stage.
        axis: u8,
        /// Frequency, mHz (below a quarter of the control rate).
        freq_mhz: u32,
        /// Excitation, µm (`I16F16` bits, > 0).
        amplitude: i32,
        /// Periods before the correlation starts.
        settle: u16,
        /// Periods correlated (≥ 1).
        cycles: u16,
    },
    /// The last analysis → [`Reply::Analysis`](crate::Reply::Analysis) (`None`
    /// while one runs or before any).
    AnalysisResult {
        /// The stage.
        axis: u8,
    },
    /// Start the learned mass ratio `β` (the stage's mass over the tuned
    /// one's, which scales the lead force) at `ratio` instead of 1; the board
    /// goes on learning from it. Refused where the running model applies no
    /// lead, or `ratio` is outside `[1/2, 2)`.
    LeadRatio {
        /// The stage.
        axis: u8,
        /// `β`, `I2F30` bits, in `[2²⁹, 2³¹)`.
        ratio: i32,
    },
    /// A piece of `axis`'s running model's image, from `offset` →
    /// [`Reply::ModelBytes`](crate::Reply::ModelBytes).
    ModelRead {
        /// The axis whose model it is.
        axis: u8,
        /// Where in the image.
        offset: u32,
    },
    /// One runtime setting's value, by key path (`/stage/0/damping`, see
    /// [`Settings`](crate::Settings)) → [`Reply::Setting`](crate::Reply::Setting)
    /// (its value as JSON).
    SettingGet {
        /// The key path, UTF-8 (at most [`MAX_PATH`](crate::settings::MAX_PATH) bytes).
        path: &'a [u8],
    },
    /// Change one runtime setting, by key path, to `value` (JSON): carried out
    /// as the named command that makes the change (`Loop`, `Damping`, …), with
    /// its checks → `Ack`; a key the board does not have, a value of the wrong
    /// type or a setting the running model lacks is refused
    /// ([`Refusal::Setting`](crate::Refusal::Setting)).
    SettingSet {
        /// The key path, UTF-8.
        path: &'a [u8],
        /// The value, JSON (at most [`MAX_VALUE`](crate::settings::MAX_VALUE) bytes).
        value: &'a [u8],
    },
    /// A raster on two axes ([`RasterOrder`]).
    Raster(RasterOrder),
    /// Ramp each axis of `mask` (bit `i`: axis `i`) to its target at `speed`
    /// (µm/s), all from the same tick, and hold (or none, when one refuses).
    MoveAxes {
        /// The axes that move.
        mask: u8,
        /// Each axis's target, µm (`I16F16` bits; an axis outside `mask`:
        /// unused).
        targets: [i32; 3],
        /// µm/s (`I16F16` bits).
        speed: i32,
    },
    /// The axes' decoupling from the next tick on (a board of several axes):
    /// the input matrix (sensors → axes) and the output matrix (axes →
    /// stacks), `I2F30` bits, `[row][column]` over x, y, z; the stacks'
    /// preload coupling, N/µm (`I16F16` bits). The rows and columns of axes
    /// the board does not have are the identity's (the coupling's zero).
    Decoupling {
        /// Sensors → axes.
        input: [[i32; 3]; 3],
        /// Axes → stacks.
        output: [[i32; 3]; 3],
        /// N on stack `i` per µm of stack `j`.
        preload: [[i32; 3]; 3],
    },
}

impl Command<'_> {
    /// Its kind (wire number).
    pub const fn kind(&self) -> CommandKind {
        use CommandKind as K;
        match self {
            Self::Hello => K::Hello,
            Self::Status { .. } => K::Status,
            Self::Ping => K::Ping,
            Self::Move { .. } => K::Move,
            Self::Wave { .. } => K::Wave,
            Self::Points { .. } => K::Points,
            Self::Stream { .. } => K::Stream,
            Self::StreamEnd { .. } => K::StreamEnd,
            Self::StreamClear { .. } => K::StreamClear,
            Self::Analog { .. } => K::Analog,
            Self::Hold { .. } => K::Hold,
            Self::Safe => K::Safe,
            Self::ClearFault => K::ClearFault,
            Self::Drive { .. } => K::Drive,
            Self::Supervise { .. } => K::Supervise,
            Self::Record { .. } => K::Record,
            Self::RecordStop => K::RecordStop,
            Self::ReadRecord { .. } => K::ReadRecord,
            Self::ModelBegin { .. } => K::ModelBegin,
            Self::ModelChunk { .. } => K::ModelChunk,
            Self::ModelCommit { .. } => K::ModelCommit,
            Self::ModelInfo { .. } => K::ModelInfo,
            Self::ModelFactory { .. } => K::ModelFactory,
            Self::Counters => K::Counters,
            Self::Bench(_) => K::Bench,
            Self::Reset => K::Reset,
            Self::Loop { .. } => K::Loop,
            Self::Damping { .. } => K::Damping,
            Self::Step { .. } => K::Step,
            Self::Shaping { .. } => K::Shaping,
            Self::Analyse { .. } => K::Analyse,
            Self::AnalysisResult { .. } => K::AnalysisResult,
            Self::ModelRead { .. } => K::ModelRead,
            Self::LeadRatio { .. } => K::LeadRatio,
            Self::SettingGet { .. } => K::SettingGet,
            Self::SettingSet { .. } => K::SettingSet,
            Self::Trigger { .. } => K::Trigger,
            Self::TriggerIn { .. } => K::TriggerIn,
            Self::Raster(_) => K::Raster,
            Self::Decoupling { .. } => K::Decoupling,
            Self::MoveAxes { .. } => K::MoveAxes,
        }
    }

    /// The stage it addresses (`None`: the board as a whole).
    pub const fn axis(&self) -> Option<u8> {
        match *self {
            Self::Status { axis }
            | Self::Move { axis, .. }
            | Self::Wave { axis, .. }
            | Self::Points { axis, .. }
            | Self::Stream { axis, .. }
            | Self::StreamEnd { axis }
            | Self::StreamClear { axis }
            | Self::Analog { axis }
            | Self::Hold { axis }
            | Self::Drive { axis, .. }
            | Self::Loop { axis, .. }
            | Self::Damping { axis, .. }
            | Self::Step { axis, .. }
            | Self::Shaping { axis, .. }
            | Self::Analyse { axis, .. }
            | Self::LeadRatio { axis, .. }
            | Self::Trigger { axis, .. }
            | Self::TriggerIn { axis, .. }
            | Self::AnalysisResult { axis }
            | Self::ModelCommit { axis, .. }
            | Self::ModelInfo { axis }
            | Self::ModelFactory { axis }
            | Self::ModelRead { axis, .. }
            | Self::Record { axis, .. } => Some(axis),
            _ => None,
        }
    }
}

impl<'a> Tagged<'a> for Command<'a> {
    const NAME: &'static str = "a command";

    fn kind(&self) -> u8 {
        Command::kind(self).to_u8()
    }

    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error> {
        match self {
            Self::Hello
            | Self::Ping
            | Self::Safe
            | Self::ClearFault
            | Self::RecordStop
            | Self::Counters
            | Self::Reset => {}
            Self::Status { axis }
            | Self::StreamEnd { axis }
            | Self::StreamClear { axis }
            | Self::Analog { axis }
            | Self::Hold { axis }
            | Self::AnalysisResult { axis }
            | Self::ModelInfo { axis }
            | Self::ModelFactory { axis } => put!(t; axis),
            Self::Move {
                axis,
                target,
                speed,
            } => put!(t; axis, target, speed),
            Self::Wave {
                axis,
                shape,
                offset,
                amplitude,
                freq_mhz,
                cycles,
            } => put!(t; axis, shape, offset, amplitude, freq_mhz, cycles),
            Self::Points {
                axis,
                first,
                points,
            } => put!(t; axis, first, points),
            Self::Stream { axis, interval } => put!(t; axis, interval),
            Self::Drive { axis, compensated } => put!(t; axis, compensated),
            Self::Supervise { timeout_ms } => put!(t; timeout_ms),
            Self::Record {
                axis,
                decimation,
                signals,
            } => put!(t; axis, decimation, signals),
            Self::ReadRecord { max } => put!(t; max),
            Self::ModelBegin { len, crc } => put!(t; len, crc),
            Self::ModelChunk { offset, data } => put!(t; offset, data),
            Self::ModelCommit { axis, store } => put!(t; axis, store),
            Self::Bench(order) => put!(t; order),
            Self::Loop { axis, mode } => put!(t; axis, mode),
            Self::Damping { axis, on } | Self::Shaping { axis, on } => put!(t; axis, on),
            Self::Step {
                axis,
                target,
                duration_us,
            } => put!(t; axis, target, duration_us),
            Self::Analyse {
                axis,
                freq_mhz,
                amplitude,
                settle,
                cycles,
            } => put!(t; axis, freq_mhz, amplitude, settle, cycles),
            Self::ModelRead { axis, offset } => put!(t; axis, offset),
            Self::LeadRatio { axis, ratio } => put!(t; axis, ratio),
            Self::SettingGet { path } => put!(t; path),
            Self::SettingSet { path, value } => put!(t; path, value),
            Self::Trigger { axis, settings } => put!(t; axis, settings),
            Self::TriggerIn { axis, starts } => put!(t; axis, starts),
            Self::Raster(r) => put!(t; r),
            Self::Decoupling {
                input,
                output,
                preload,
            } => put!(t; input, output, preload),
            Self::MoveAxes {
                mask,
                targets,
                speed,
            } => put!(t; mask, targets, speed),
        }
        Ok(())
    }

    fn read<A: SeqAccess<'a>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error> {
        use CommandKind as K;
        let Some(kind) = K::from_u8(kind) else {
            return Ok(None);
        };
        Ok(Some(match kind {
            K::Hello => Self::Hello,
            K::Status => Self::Status { axis: field(a)? },
            K::Ping => Self::Ping,
            K::Move => Self::Move {
                axis: field(a)?,
                target: field(a)?,
                speed: field(a)?,
            },
            K::Wave => Self::Wave {
                axis: field(a)?,
                shape: field(a)?,
                offset: field(a)?,
                amplitude: field(a)?,
                freq_mhz: field(a)?,
                cycles: field(a)?,
            },
            K::Points => Self::Points {
                axis: field(a)?,
                first: field(a)?,
                points: field(a)?,
            },
            K::Stream => Self::Stream {
                axis: field(a)?,
                interval: field(a)?,
            },
            K::StreamEnd => Self::StreamEnd { axis: field(a)? },
            K::StreamClear => Self::StreamClear { axis: field(a)? },
            K::Analog => Self::Analog { axis: field(a)? },
            K::Hold => Self::Hold { axis: field(a)? },
            K::Safe => Self::Safe,
            K::ClearFault => Self::ClearFault,
            K::Drive => Self::Drive {
                axis: field(a)?,
                compensated: field(a)?,
            },
            K::Supervise => Self::Supervise {
                timeout_ms: field(a)?,
            },
            K::Record => Self::Record {
                axis: field(a)?,
                decimation: field(a)?,
                signals: field(a)?,
            },
            K::RecordStop => Self::RecordStop,
            K::ReadRecord => Self::ReadRecord { max: field(a)? },
            K::ModelBegin => Self::ModelBegin {
                len: field(a)?,
                crc: field(a)?,
            },
            K::ModelChunk => Self::ModelChunk {
                offset: field(a)?,
                data: field(a)?,
            },
            K::ModelCommit => Self::ModelCommit {
                axis: field(a)?,
                store: field(a)?,
            },
            K::ModelInfo => Self::ModelInfo { axis: field(a)? },
            K::ModelFactory => Self::ModelFactory { axis: field(a)? },
            K::Counters => Self::Counters,
            K::Bench => Self::Bench(field(a)?),
            K::Reset => Self::Reset,
            K::Loop => Self::Loop {
                axis: field(a)?,
                mode: field(a)?,
            },
            K::Damping => Self::Damping {
                axis: field(a)?,
                on: field(a)?,
            },
            K::Step => Self::Step {
                axis: field(a)?,
                target: field(a)?,
                duration_us: field(a)?,
            },
            K::Shaping => Self::Shaping {
                axis: field(a)?,
                on: field(a)?,
            },
            K::Analyse => Self::Analyse {
                axis: field(a)?,
                freq_mhz: field(a)?,
                amplitude: field(a)?,
                settle: field(a)?,
                cycles: field(a)?,
            },
            K::AnalysisResult => Self::AnalysisResult { axis: field(a)? },
            K::ModelRead => Self::ModelRead {
                axis: field(a)?,
                offset: field(a)?,
            },
            K::LeadRatio => Self::LeadRatio {
                axis: field(a)?,
                ratio: field(a)?,
            },
            K::SettingGet => Self::SettingGet { path: field(a)? },
            K::SettingSet => Self::SettingSet {
                path: field(a)?,
                value: field(a)?,
            },
            K::Trigger => Self::Trigger {
                axis: field(a)?,
                settings: field(a)?,
            },
            K::TriggerIn => Self::TriggerIn {
                axis: field(a)?,
                starts: field(a)?,
            },
            K::Raster => Self::Raster(field(a)?),
            K::Decoupling => Self::Decoupling {
                input: field(a)?,
                output: field(a)?,
                preload: field(a)?,
            },
            K::MoveAxes => Self::MoveAxes {
                mask: field(a)?,
                targets: field(a)?,
                speed: field(a)?,
            },
        }))
    }
}

crate::tagged_serde!(Command<'a>);
