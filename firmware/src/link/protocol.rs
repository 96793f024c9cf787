//! The messages of the board's command link (see `firmware/PROTOCOL.md`).
//!
//! Every request is a [`Header`] (protocol version, sequence number) and a
//! [`Command`]; every reply is a [`Header`] echoing the sequence number and a
//! [`Reply`]: an acknowledgement, the data asked for, or [`Reply::Refused`] with a
//! [`Refusal`] code and a one-line reason. Positions, voltages and forces travel
//! as the core's raw `I16F16` bits (µm, V, N: multiply by 2⁻¹⁶), so the host sends
//! and receives exactly the values the control loop uses.

use heapless::{String, Vec};
use serde::{Deserialize, Serialize};

use crate::closed_loop::LoopMode;
use crate::reference::wave::Shape;
use crate::reference::SourceKind;
use crate::slots::Origin;

/// The protocol version this firmware speaks.
pub const VERSION: u8 = 4;
/// Largest encoded frame, delimiter included, bytes.
pub const MAX_FRAME: usize = 1280;
/// Model bytes per [`Command::ModelChunk`].
pub const MAX_CHUNK: usize = 256;
/// Points per [`Command::Points`].
pub const MAX_POINTS: usize = 64;
/// Values per [`Reply::Record`].
pub const MAX_VALUES: usize = 200;
/// The sequence number of a reply to a frame that could not be read.
pub const NO_SEQ: u16 = u16::MAX;

/// Variants of [`Command`] (the last one, [`Command::ModelRead`], is number
/// `COMMAND_KINDS - 1`): a request whose variant number is beyond is refused as
/// [`Refusal::Unknown`] rather than as garbage.
pub const COMMAND_KINDS: u32 = 33;

/// A short text (a refusal's reason, a firmware version).
pub type Text = String<96>;

/// The start of every request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// [`VERSION`] of the sender.
    pub version: u8,
    /// Request number, echoed by its reply.
    pub seq: u16,
}

/// The start of every reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReplyHeader {
    /// [`VERSION`] of the board.
    pub version: u8,
    /// The request's number ([`NO_SEQ`]: the request was unreadable).
    pub seq: u16,
    /// The first control tick that saw the request: the tick an order took effect
    /// at, or the tick after the request was handled. Replaying the requests at
    /// their ticks reproduces the board's run (the host's twin does).
    pub tick: u32,
}

/// Orders for the emulated board's virtual bench (a real board refuses them).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum BenchOrder {
    /// The force sensor's wire is open (the reading sits on the ADC's top rail), or intact.
    SensorOpen(bool),
    /// The force sensor freezes at its present reading, or follows the stage again.
    SensorStuck(bool),
    /// The analog reference input reads this many ADC counts.
    Analog(u16),
    /// The force sensor's reading is offset by this much (N, `I16F16` bits): a
    /// sudden step, as a loose connector or a knock would cause.
    SensorOffset(i32),
    /// The next this-many control ticks take longer than the control period (the
    /// emulated board burns time in its control task): a loop that cannot keep
    /// its rate.
    Stall(u16),
    /// Damage the newest model stored in flash (one byte cleared), to see the
    /// board refuse it at its next start.
    DamageStored,
    /// The position sensor's wire is open (the reading sits on a rail), or intact.
    PositionOpen(bool),
    /// The position sensor freezes at its present reading, or follows the stage again.
    PositionStuck(bool),
    /// Replace the virtual stage by a fresh one at rest: the nominal twin of
    /// stage A or the stage as built (kinematics, preload and creep a few percent
    /// off the model, a lightly damped first mode, position sensor noise), with
    /// any of their values replaced. Send it with the stage parked.
    Stage(StageVariant),
}

/// A virtual stage: a base and the values that replace the base's (`None`: the
/// base's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct StageVariant {
    /// The stage as built (`true`) or the nominal twin.
    pub built: bool,
    /// First mode, Hz (the nominal twin has none: quasi-static).
    pub mode_hz: Option<f32>,
    /// Its damping ratio.
    pub mode_damping: Option<f32>,
    /// Kinematics relative to the FEM's `f_K`.
    pub output_gain: Option<f32>,
    /// Preload relative to the FEM's `f_F`.
    pub force_scale: Option<f32>,
    /// Creep relative to the model's.
    pub creep_scale: Option<f32>,
    /// Position sensor noise (standard deviation), µm.
    pub position_noise_um: Option<f32>,
    /// Force sensor noise (standard deviation), N.
    pub force_noise_n: Option<f32>,
}

impl StageVariant {
    /// The nominal twin.
    pub const NOMINAL: Self = Self {
        built: false,
        mode_hz: None,
        mode_damping: None,
        output_gain: None,
        force_scale: None,
        creep_scale: None,
        position_noise_um: None,
        force_noise_n: None,
    };
    /// The stage as built.
    pub const BUILT: Self = Self {
        built: true,
        ..Self::NOMINAL
    };

    /// Each value that is given, by its key, with the range it must lie in: the
    /// one check of a variant, for the host's file reader and the board.
    pub fn check(&self) -> Result<(), (&'static str, f32, (f32, f32))> {
        let ranges: [(&'static str, Option<f32>, (f32, f32)); 7] = [
            ("mode_hz", self.mode_hz, (100.0, 5000.0)),
            ("mode_damping", self.mode_damping, (0.001, 0.5)),
            ("output_gain", self.output_gain, (0.5, 2.0)),
            ("force_scale", self.force_scale, (0.5, 1.5)),
            ("creep_scale", self.creep_scale, (0.0, 5.0)),
            ("position_noise_um", self.position_noise_um, (0.0, 1.0)),
            ("force_noise_n", self.force_noise_n, (0.0, 10.0)),
        ];
        for (key, v, (lo, hi)) in ranges {
            if let Some(v) = v {
                if !(v >= lo && v <= hi) {
                    return Err((key, v, (lo, hi)));
                }
            }
        }
        Ok(())
    }
}

/// Why the board last started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ResetReason {
    /// Power was applied.
    PowerOn,
    /// The reset pin.
    Pin,
    /// The board reset itself on a `Reset` command.
    Command,
    /// The independent watchdog expired: a task hung.
    Watchdog,
    /// The supply dipped below the brown-out threshold.
    BrownOut,
    /// Another or unknown cause (the emulated board cannot tell power-on from a
    /// pin reset).
    Unknown,
}

/// What a flash slot held when the board started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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

/// What the host asks.
// Messages are built once per request and there is no heap to box the large ones.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Command<'a> {
    /// Who are you? → [`Reply::Hello`].
    Hello,
    /// The loop's state → [`Reply::Status`].
    Status,
    /// A heartbeat (any valid request is one) → [`Reply::Ack`].
    Ping,
    /// Ramp to `target` at `speed`, then hold.
    Move {
        /// Position, µm (`I16F16` bits).
        target: i32,
        /// Speed, µm/s (`I16F16` bits, > 0).
        speed: i32,
    },
    /// Run a waveform between `offset − amplitude` and `offset + amplitude`.
    Wave {
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
        /// Index of the first point.
        first: u32,
        /// Positions, µm (`I16F16` bits).
        points: Vec<i32, MAX_POINTS>,
    },
    /// Play the buffered points, one every `interval` ticks, interpolated.
    Stream {
        /// Ticks per point (≥ 1).
        interval: u16,
    },
    /// The stream has no more points: hold the last without an underrun flag.
    StreamEnd,
    /// Drop the stream buffer and count points from 0 again.
    StreamClear,
    /// Follow the analog reference input.
    Analog,
    /// Stop where the reference is.
    Hold,
    /// Park the stage: ramp to the safe voltage, amplifier off.
    Safe,
    /// Clear a latched fault (the stage stays parked until the next motion command).
    ClearFault,
    /// Inverse FPI (`true`) or the straight-line baseline (`false`).
    Drive {
        /// Compensated.
        compensated: bool,
    },
    /// Supervise the host: a motion with no request for `timeout_ms` parks the stage
    /// with a [`LinkLost`](piezo_fpi::control::Fault::LinkLost) fault; 0 switches it off.
    Supervise {
        /// Timeout, ms.
        timeout_ms: u32,
    },
    /// Start recording every `decimation`-th tick; `signals` (recorder::signal bits)
    /// says what [`Command::ReadRecord`] sends.
    Record {
        /// Keep one tick in this many (≥ 1).
        decimation: u16,
        /// Signal mask.
        signals: u8,
    },
    /// Stop recording (the samples stay readable).
    RecordStop,
    /// Take up to `max` recorded samples → [`Reply::Record`].
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
    /// The image's bytes from `offset` (in order, at most [`MAX_CHUNK`]).
    ModelChunk {
        /// Where these bytes go.
        offset: u32,
        /// The bytes.
        #[serde(borrow)]
        data: &'a [u8],
    },
    /// Validate the received image and run it (the stage must be parked);
    /// `store` also writes it to flash, where it survives a reset.
    ModelCommit {
        /// Keep it in flash.
        store: bool,
    },
    /// The running model → [`Reply::Model`].
    ModelInfo,
    /// Forget the stored model and run the factory default (the stage must be parked).
    ModelFactory,
    /// The link's counters → [`Reply::Counters`].
    Counters,
    /// An order for the emulated board's virtual bench.
    Bench(BenchOrder),
    /// Reset the board (after this reply); it starts parked with its stored model.
    Reset,
    /// Open the loop or close it on the position sensor, without a jump (the
    /// running model must have feedback settings to close it).
    Loop {
        /// Open, closed (feedback plus the inverse FPI) or feedback only.
        mode: LoopMode,
    },
    /// Switch active damping on or off (it runs where the running model has it),
    /// without a jump.
    Damping {
        /// On.
        on: bool,
    },
    /// Step to `target` along a raised cosine lasting `duration_us` (zero speed at
    /// both ends), then hold.
    Step {
        /// Position, µm (`I16F16` bits).
        target: i32,
        /// Duration, µs (one control period to one second).
        duration_us: u32,
    },
    /// Switch the model's reference shaping (the feedforward of the stage's
    /// dynamics) on or off, without a jump.
    Shaping {
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
        /// Frequency, mHz (below a quarter of the control rate).
        freq_mhz: u32,
        /// Excitation, µm (`I16F16` bits, > 0).
        amplitude: i32,
        /// Periods before the correlation starts.
        settle: u16,
        /// Periods correlated (≥ 1).
        cycles: u16,
    },
    /// The last analysis → [`Reply::Analysis`] (`None` while one runs or before any).
    AnalysisResult,
    /// A piece of the running model's image, from `offset` → [`Reply::ModelBytes`].
    ModelRead {
        /// Where in the image.
        offset: u32,
    },
}

/// Why a request was not carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Refusal {
    /// The frame could not be read (COBS, CRC or encoding).
    Malformed,
    /// The request's protocol version is not this firmware's.
    Version,
    /// A command this firmware does not know.
    Unknown,
    /// A fault is latched: clear it first.
    Fault,
    /// Needs the stage parked at the safe voltage (`safe` first).
    NotAtRest,
    /// The output is still ramping to the safe voltage: try again shortly.
    StillRamping,
    /// A position outside the running model's stroke.
    OutOfRange,
    /// An argument outside its allowed range.
    BadArgument,
    /// The model image is invalid (the reason names the key).
    Model,
    /// An upload step out of order.
    Upload,
    /// The flash store failed.
    Storage,
    /// Only the emulated board has a virtual bench.
    NotEmulated,
    /// The stream buffer is full or the points are out of sequence.
    Stream,
}

/// Which board answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BoardKind {
    /// The STM32F405 driver board.
    Driver,
    /// The emulated board (QEMU) with its virtual stage.
    Emulated,
}

/// The board's identity and capacity.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    /// [`VERSION`].
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
    /// Ticks since start-up.
    pub tick: u32,
    /// Reference, estimated position (µm), setpoint (V), force (N), position
    /// sensor (µm): `I16F16` bits.
    pub signals: [i32; 5],
    /// The latched fault (code 4, *parked*, is the resting state).
    pub fault: Option<FaultReport>,
    /// Amplifier enabled.
    pub amplifier_on: bool,
    /// Reference source.
    pub source: SourceKind,
    /// Approaching a new source's entry point.
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
    /// Control ticks that started late (after their period), since start-up.
    pub overruns: u32,
    /// CRC-32 of the running model's image.
    pub model_crc: u32,
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
    /// Frames longer than [`MAX_FRAME`], dropped to the next delimiter.
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
    /// The signal mask of `values` (recorder::signal bits).
    pub signals: u8,
    /// Ticks between samples.
    pub decimation: u16,
    /// Recording now.
    pub active: bool,
    /// Samples dropped so far because the ring was full.
    pub dropped: u32,
    /// Samples still waiting after this batch.
    pub waiting: u32,
    /// Per sample: the tick, then the chosen signals in wire order.
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
}

/// Bytes per [`Reply::ModelBytes`].
pub const MAX_MODEL_BYTES: usize = 256;

/// What the board answers.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
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
    /// Not done, and why.
    Refused {
        /// The kind of refusal.
        code: Refusal,
        /// A one-line reason.
        reason: Text,
    },
}
