//! What the board answers: the reply header, the [`Reply`]s with the wire
//! numbers of their [`ReplyKind`], the refusal codes and what the replies hold.

use heapless::Vec;
use serde::de::SeqAccess;
use serde::ser::SerializeTuple;
use serde::{Deserialize, Serialize};

use crate::bench::FrontEndKind;
use crate::link::LinkKind;
use crate::modes::{LoopMode, SourceKind};
use crate::put;
use crate::wire::{field, Tagged};
use crate::{Text, MAX_MODEL_BYTES, MAX_VALUES};

/// The start of every reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReplyHeader {
    /// [`VERSION`](crate::VERSION) of the board.
    pub version: u8,
    /// The request's number ([`NO_SEQ`](crate::NO_SEQ): the request was unreadable).
    pub seq: u16,
    /// The first control tick that saw the request: the tick an order took effect
    /// at, or the tick after the request was handled. Replaying the requests at
    /// their ticks reproduces the board's run (the host's twin does).
    pub tick: u32,
}

crate::wire_enum! {
    /// Why a request was not carried out.
    pub enum Refusal {
        /// The frame could not be read (COBS, CRC or encoding).
        Malformed = 0,
        /// The request's protocol version is not this firmware's.
        Version = 1,
        /// A command this firmware does not know.
        Unknown = 2,
        /// A fault is latched: clear it first.
        Fault = 3,
        /// Needs the stage parked at the safe voltage (`safe` first).
        NotAtRest = 4,
        /// The output is still ramping to the safe voltage: try again shortly.
        StillRamping = 5,
        /// A position outside the running model's stroke.
        OutOfRange = 6,
        /// An argument outside its allowed range.
        BadArgument = 7,
        /// The model image is invalid (the reason names the key).
        Model = 8,
        /// An upload step out of order.
        Upload = 9,
        /// The flash store failed.
        Storage = 10,
        /// Only the emulated board has a virtual bench.
        NotEmulated = 11,
        /// The stream buffer is full or the points are out of sequence.
        Stream = 12,
        /// The command addresses an axis this board does not have.
        Axis = 13,
        /// A setting the board does not have (or the running model lacks), or
        /// a value that is not of its type.
        Setting = 14,
        /// Another client of the board's hub (`fpi board serve`) holds what
        /// the command needs, the motion or the recorder: the reason names it.
        Held = 15,
    }
}

crate::wire_enum! {
    /// Which board answers.
    pub enum BoardKind {
        /// The STM32F405 driver board.
        Driver = 0,
        /// The emulated board (QEMU) with its virtual stage.
        Emulated = 1,
    }
}

crate::wire_enum! {
    /// Why the board last started.
    pub enum ResetReason {
        /// Power was applied.
        PowerOn = 0,
        /// The reset pin.
        Pin = 1,
        /// The board reset itself on a `Reset` command.
        Command = 2,
        /// The independent watchdog expired: a task hung.
        Watchdog = 3,
        /// The supply dipped below the brown-out threshold.
        BrownOut = 4,
        /// Another or unknown cause (the emulated board cannot tell power-on from a
        /// pin reset).
        Unknown = 5,
    }
}

crate::wire_enum! {
    /// The kinds of [`SlotReport`]: their wire numbers.
    pub enum SlotKind {
        /// [`SlotReport::Empty`].
        Empty = 0,
        /// [`SlotReport::Valid`].
        Valid = 1,
        /// [`SlotReport::Damaged`].
        Damaged = 2,
        /// [`SlotReport::Refused`].
        Refused = 3,
    }
}

/// What a flash slot held when the board started; on the wire its
/// [`SlotKind`] byte, then the generation (`Valid`, `Refused`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlotReport {
    /// Erased.
    Empty,
    /// A model of this generation, intact.
    Valid(u32),
    /// Something that is not an intact model (a damaged header or image).
    Damaged,
    /// An intact image the validator refused (e.g. from another firmware).
    Refused(u32),
}

impl<'de> Tagged<'de> for SlotReport {
    const NAME: &'static str = "a slot report";

    fn kind(&self) -> u8 {
        match self {
            Self::Empty => SlotKind::Empty,
            Self::Valid(_) => SlotKind::Valid,
            Self::Damaged => SlotKind::Damaged,
            Self::Refused(_) => SlotKind::Refused,
        }
        .to_u8()
    }

    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error> {
        match self {
            Self::Empty | Self::Damaged => {}
            Self::Valid(g) | Self::Refused(g) => put!(t; g),
        }
        Ok(())
    }

    fn read<A: SeqAccess<'de>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error> {
        Ok(match SlotKind::from_u8(kind) {
            None => None,
            Some(SlotKind::Empty) => Some(Self::Empty),
            Some(SlotKind::Valid) => Some(Self::Valid(field(a)?)),
            Some(SlotKind::Damaged) => Some(Self::Damaged),
            Some(SlotKind::Refused) => Some(Self::Refused(field(a)?)),
        })
    }
}

crate::tagged_serde!(SlotReport);

crate::wire_enum! {
    /// The kinds of [`Origin`]: their wire numbers.
    pub enum OriginKind {
        /// [`Origin::Factory`].
        Factory = 0,
        /// [`Origin::Stored`].
        Stored = 1,
        /// [`Origin::Received`].
        Received = 2,
    }
}

/// Where the running model came from; on the wire its [`OriginKind`] byte,
/// then the generation (`Stored`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// The model compiled into the firmware (the factory default).
    Factory,
    /// A model read from the board's flash at start-up; its generation.
    Stored(u32),
    /// A model received over the link (and not stored).
    Received,
}

impl<'de> Tagged<'de> for Origin {
    const NAME: &'static str = "a model origin";

    fn kind(&self) -> u8 {
        match self {
            Self::Factory => OriginKind::Factory,
            Self::Stored(_) => OriginKind::Stored,
            Self::Received => OriginKind::Received,
        }
        .to_u8()
    }

    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error> {
        if let Self::Stored(g) = self {
            put!(t; g);
        }
        Ok(())
    }

    fn read<A: SeqAccess<'de>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error> {
        Ok(match OriginKind::from_u8(kind) {
            None => None,
            Some(OriginKind::Factory) => Some(Self::Factory),
            Some(OriginKind::Stored) => Some(Self::Stored(field(a)?)),
            Some(OriginKind::Received) => Some(Self::Received),
        })
    }
}

crate::tagged_serde!(Origin);

/// The board's identity and capacity.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    /// [`VERSION`](crate::VERSION).
    pub protocol: u8,
    /// Firmware version.
    pub firmware: Text,
    /// Board.
    pub board: BoardKind,
    /// Control rate, Hz.
    pub rate_hz: u32,
    /// Capacity: operators, creep terms, table intervals, image bytes.
    pub capacity: [u32; 4],
    /// Recorder ring, samples; stream buffer, points.
    pub buffers: [u32; 2],
    /// Hardware limits: lowest and highest setpoint, largest step per tick, safe
    /// window low and high, V (`I16F16` bits).
    pub limits: [i32; 5],
    /// Why the board last started.
    pub reset: ResetReason,
    /// The link this hello came over (the emulated board: the link it paces
    /// its own as).
    pub link: LinkKind,
    /// Stages it drives: axes `0..axes` (x, y, z), at most
    /// [`MAX_AXES`](crate::MAX_AXES).
    pub axes: u8,
    /// The analog front end it converts with: the board's build (`precision`
    /// feature), or on the emulated board the one its bench was set to
    /// ([`BenchOrder::FrontEnd`](crate::BenchOrder::FrontEnd)).
    pub front_end: FrontEndKind,
}

/// A latched fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FaultReport {
    /// `piezo_fpi::control::Fault` code.
    pub code: u8,
    /// Tick it latched at.
    pub at: u32,
    /// Tick the output reached the safe voltage.
    pub safe_at: Option<u32>,
}

/// The loop's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Status {
    /// The stage it describes.
    pub axis: u8,
    /// Ticks since start-up.
    pub tick: u32,
    /// Reference, estimated position (µm), setpoint (V), force (N), position
    /// sensor (µm): `I16F16` bits.
    pub signals: [i32; 5],
    /// The latched fault (code 4, *parked*, is the resting state).
    pub fault: Option<FaultReport>,
    /// The axis whose fault parked every axis of the board, while that fault
    /// is latched (`None`: no fault other than a parked stage).
    pub fault_axis: Option<u8>,
    /// Amplifier enabled.
    pub amplifier_on: bool,
    /// Reference source.
    pub source: SourceKind,
    /// Approaching a new source's entry point, or, the source holding, the
    /// governed reference not yet where it holds (a governed move's end).
    pub approaching: bool,
    /// Inverse FPI drive (else the straight-line baseline).
    pub compensated: bool,
    /// Open or closed loop.
    pub loop_mode: LoopMode,
    /// Active damping: `None` if the running model has none, else whether it is
    /// switched on.
    pub damping: Option<bool>,
    /// Reference shaping: `None` if the running model has none, else whether it
    /// is switched on.
    pub shaping: Option<bool>,
    /// The explained force's learned ratio (`piezo_fpi::lead`), `I2F30` bits,
    /// and whether the damping applies it: `None` if the running model's
    /// damping leaves no lead out (no damping or no preview); `(β, true)`, the
    /// stage's mass over the tuned one's, where the model carries the lead's
    /// baseline; `(α, false)`, the fit's ratio itself, where it does not.
    pub lead_ratio: Option<(i32, bool)>,
    /// An analysis is running.
    pub analysing: bool,
    /// Heartbeat timeout, ticks (0: off), and ticks since the last request.
    pub supervision: [u32; 2],
    /// Stream: points queued, free, received since `Stream`/`StreamClear`; underrun ticks.
    pub stream: [u32; 4],
    /// Recorder: recording (0/1), samples kept, dropped, waiting to be read.
    pub recorder: [u32; 4],
    /// Ticks in which the output limits bit.
    pub limited_steps: u32,
    /// Ticks in which the reference governor departed from the source's
    /// reference (it asked for more than the stage can do within its stroke).
    pub governed_ticks: u32,
    /// Streamed points a motion dropped when it ended a stream that still had
    /// them queued (a client that died mid-stream left them), since start-up.
    pub ended_points: u32,
    /// Control ticks that started late (after their period), since start-up.
    pub overruns: u32,
    /// CRC-32 of the running model's image.
    pub model_crc: u32,
    /// Armed for the trigger input's next rising edge: a wave or stream
    /// order, a record order.
    pub armed: [bool; 2],
}

/// The running model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModelReport {
    /// CRC-32 of its image body.
    pub crc: u32,
    /// Where it came from.
    pub origin: Origin,
    /// Operators, creep terms.
    pub size: [u8; 2],
    /// Soft dead zone, saturation.
    pub maps: [bool; 2],
    /// Reference window (stroke) low and high, µm; safe voltage, V (`I16F16` bits).
    pub window: [i32; 3],
    /// The model in flash: generation and CRC.
    pub stored: Option<(u32, u32)>,
    /// What the two flash slots held when the board started.
    pub slots: [SlotReport; 2],
    /// Its feedback settings: kp, ki per tick (`I8F24` bits), correction limit,
    /// sensor range low and high, tolerance (µm, `I16F16` bits); `None`: open loop only.
    pub feedback: Option<[i32; 6]>,
    /// The stage dynamics it declares: mode (mHz), damping ratio (`I0F32` bits),
    /// lag (mHz), force gain (N/µm, `I16F16` bits); `None`: none.
    pub dynamics: Option<[i32; 4]>,
    /// Its damping: gain (`I8F24` bits, µm/N per tick), leak (`I0F32` bits), limit
    /// (µm, `I16F16` bits); `None`: none.
    pub damping: Option<[i32; 3]>,
    /// The force channel: split rate (`I0F32` bits), dynamic limit (N, `I16F16` bits).
    pub force_channel: [i32; 2],
}

/// The link's counters since start-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Counters {
    /// Requests read and answered.
    pub requests: u32,
    /// Frames refused as unreadable (COBS, length, CRC or encoding).
    pub malformed: u32,
    /// Of those, CRC mismatches.
    pub crc_errors: u32,
    /// Frames longer than [`MAX_FRAME`](crate::MAX_FRAME), dropped to the next delimiter.
    pub overlong: u32,
    /// Requests with another protocol version.
    pub version: u32,
    /// Unknown commands.
    pub unknown: u32,
    /// Requests refused for any reason (the above included).
    pub refused: u32,
    /// The deepest the board's stack has been since start-up, bytes (0: unknown).
    pub stack_bytes: u32,
}

/// A batch of recorded samples.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Batch {
    /// The signal mask of `values` ([`signal`](crate::record::signal) bits).
    pub signals: u8,
    /// Ticks between samples.
    pub decimation: u16,
    /// Recording now.
    pub active: bool,
    /// Samples dropped so far because the ring was full.
    pub dropped: u32,
    /// Samples still waiting after this batch.
    pub waiting: u32,
    /// Per sample: the tick, then the chosen signals in wire order, each as its
    /// difference from the batch's previous sample ([`Sample::deltas`]; read them
    /// back with [`Sample::batch`]). At most
    /// [`MAX_BATCH_BYTES`](crate::MAX_BATCH_BYTES) on the wire.
    ///
    /// [`Sample::deltas`]: crate::record::Sample::deltas
    /// [`Sample::batch`]: crate::record::Sample::batch
    pub values: Vec<i32, MAX_VALUES>,
}

/// One frequency of an analysis: the sums `Σ s·sin φ`, `Σ s·cos φ` of each
/// signal over the correlated ticks (signals in `I16F16` bits times the
/// excitation's `sin`/`cos` in `I2F30`, shifted right by 16: units of 2⁻³⁰ of the
/// signal's unit), in the order position sensor (µm), force reading (N), dynamic
/// force (N), setpoint (V), command excitation (µm).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Analysis {
    /// The frequency, mHz.
    pub freq_mhz: u32,
    /// Ticks correlated.
    pub ticks: u32,
    /// `[Σ s·sin, Σ s·cos]` per signal.
    pub sums: [[i64; 2]; 5],
    /// A fault latched while it ran (the result is then void).
    pub faulted: bool,
    /// Ticks in which the reference governor departed from the stimulus
    /// asked (the response is then to another stimulus: measure again with
    /// less).
    pub governed: u32,
}

crate::wire_enum! {
    /// The kinds of [`Reply`]: their wire numbers.
    pub enum ReplyKind {
        /// [`Reply::Ack`].
        Ack = 0,
        /// [`Reply::Hello`].
        Hello = 1,
        /// [`Reply::Status`].
        Status = 2,
        /// [`Reply::Record`].
        Record = 3,
        /// [`Reply::Model`].
        Model = 4,
        /// [`Reply::Counters`].
        Counters = 5,
        /// [`Reply::Analysis`].
        Analysis = 6,
        /// [`Reply::ModelBytes`].
        ModelBytes = 7,
        /// [`Reply::Refused`].
        Refused = 8,
        /// [`Reply::Setting`].
        Setting = 9,
    }
}

/// What the board answers; on the wire its [`ReplyKind`] byte, then its fields.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// Done (the header's tick says when).
    Ack,
    /// Identity and capacity.
    Hello(Hello),
    /// State.
    Status(Status),
    /// Recorded samples.
    Record(Batch),
    /// The running model.
    Model(ModelReport),
    /// The link's counters.
    Counters(Counters),
    /// An analysis (`None`: one is running, or none has run).
    Analysis(Option<Analysis>),
    /// A piece of the running model's image.
    ModelBytes {
        /// The image's length, bytes.
        total: u32,
        /// Where this piece starts.
        offset: u32,
        /// The bytes.
        data: Vec<u8, MAX_MODEL_BYTES>,
    },
    /// One runtime setting's value, JSON.
    Setting(Vec<u8, { crate::settings::MAX_VALUE }>),
    /// Not done, and why.
    Refused {
        /// The kind of refusal.
        code: Refusal,
        /// A one-line reason.
        reason: Text,
    },
}

impl Reply {
    /// Its kind (wire number).
    pub const fn kind(&self) -> ReplyKind {
        match self {
            Self::Ack => ReplyKind::Ack,
            Self::Hello(_) => ReplyKind::Hello,
            Self::Status(_) => ReplyKind::Status,
            Self::Record(_) => ReplyKind::Record,
            Self::Model(_) => ReplyKind::Model,
            Self::Counters(_) => ReplyKind::Counters,
            Self::Analysis(_) => ReplyKind::Analysis,
            Self::ModelBytes { .. } => ReplyKind::ModelBytes,
            Self::Refused { .. } => ReplyKind::Refused,
            Self::Setting(_) => ReplyKind::Setting,
        }
    }
}

impl<'de> Tagged<'de> for Reply {
    const NAME: &'static str = "a reply";

    fn kind(&self) -> u8 {
        Reply::kind(self).to_u8()
    }

    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error> {
        match self {
            Self::Ack => {}
            Self::Hello(h) => put!(t; h),
            Self::Status(s) => put!(t; s),
            Self::Record(b) => put!(t; b),
            Self::Model(m) => put!(t; m),
            Self::Counters(c) => put!(t; c),
            Self::Analysis(a) => put!(t; a),
            Self::ModelBytes {
                total,
                offset,
                data,
            } => put!(t; total, offset, data),
            Self::Refused { code, reason } => put!(t; code, reason),
            Self::Setting(v) => put!(t; v),
        }
        Ok(())
    }

    fn read<A: SeqAccess<'de>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error> {
        let Some(kind) = ReplyKind::from_u8(kind) else {
            return Ok(None);
        };
        Ok(Some(match kind {
            ReplyKind::Ack => Self::Ack,
            ReplyKind::Hello => Self::Hello(field(a)?),
            ReplyKind::Status => Self::Status(field(a)?),
            ReplyKind::Record => Self::Record(field(a)?),
            ReplyKind::Model => Self::Model(field(a)?),
            ReplyKind::Counters => Self::Counters(field(a)?),
            ReplyKind::Analysis => Self::Analysis(field(a)?),
            ReplyKind::ModelBytes => Self::ModelBytes {
                total: field(a)?,
                offset: field(a)?,
                data: field(a)?,
            },
            ReplyKind::Refused => Self::Refused {
                code: field(a)?,
                reason: field(a)?,
            },
            ReplyKind::Setting => Self::Setting(field(a)?),
        }))
    }
}

crate::tagged_serde!(Reply);
