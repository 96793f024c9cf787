//! The board's command link in one place: every message, enum and frame that
//! crosses it, shared by the firmware and the host so the two cannot disagree
//! (the book's *The command link*, `docs/src/protocol.md`, describes the bytes
//! for other clients; its reference page is generated from these declarations).
//!
//! Every request is a [`Header`] (protocol version, sequence number) and a
//! [`Command`]; every reply is a [`ReplyHeader`] echoing the sequence number and
//! a [`Reply`]: an acknowledgement, the data asked for, or [`Reply::Refused`]
//! with a [`Refusal`] code and a one-line reason. Positions, voltages and forces
//! travel as the core's raw `I16F16` bits (µm, V, N: multiply by 2⁻¹⁶), so the
//! host sends and receives exactly the values the control loop uses.
//!
//! * [`wire`] — how an enum crosses the link: by the number written beside each
//!   variant (`#[repr(u8)]`), never by its place in the declaration;
//! * [`command`] — the requests; [`reply`] — the replies and refusals;
//! * [`modes`] — the loop's modes and sources the messages name; [`bench`](mod@bench) —
//!   the emulated board's bench orders; [`record`] — a recording's signals;
//! * [`settings`] — the runtime settings tree, addressed by key path;
//! * [`frame`] — COBS framing with a CRC-32; [`link`] — the links and their rates.
//!
//! `no_std`, no allocation; decoding never panics (the firmware's no-panic proof
//! links it).
#![cfg_attr(not(test), no_std)]
#![deny(clippy::panic, clippy::unwrap_used, clippy::expect_used)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod bench;
pub mod command;
pub mod frame;
pub mod link;
pub mod modes;
pub mod record;
pub mod reply;
pub mod settings;
pub mod wire;

/// The settings tree's crate, for the tools that walk or serialize [`Settings`].
pub use miniconf;
#[doc(hidden)]
pub use serde;

pub use bench::{BenchKind, BenchOrder, FrontEndKind, StageVariant};
pub use command::{Command, CommandKind, Header, RasterOrder};
pub use link::LinkKind;
pub use modes::{LoopMode, Shape, SourceKind, TriggerMode, TriggerStart};
pub use reply::{
    Analysis, Batch, BoardKind, Counters, FaultReport, Hello, ModelReport, Origin, OriginKind,
    Refusal, Reply, ReplyHeader, ReplyKind, ResetReason, SlotKind, SlotReport, Status,
};
pub use settings::{Settings, StageSettings, TriggerSettings};

/// The protocol version of these messages (14: an axis in the model
/// commands ([`Command::ModelCommit`], [`Command::ModelInfo`],
/// [`Command::ModelFactory`], [`Command::ModelRead`]) and in
/// [`Command::Record`] (or every axis), the axis whose fault parked the board in the
/// status, [`Command::Raster`], [`Command::Decoupling`] and [`Command::MoveAxes`]; 12: the refusal [`Refusal::Held`]
/// of the board's hub; 11: the board's axes and analog
/// front end in the hello; 10: the runtime settings by key
/// path, [`Command::SettingGet`] and [`Command::SettingSet`]; 9: the governed ticks and the
/// points a motion dropped from a stream in the status; 8: the learned mass ratio set by
/// [`Command::LeadRatio`]; 7: the learned mass ratio in the status; 6: the link in the hello, recordings
/// sent as differences between samples; 5: explicit wire numbers, an axis in
/// every command that addresses a stage).
pub const VERSION: u8 = 14;
/// The most axes a board drives (x, y, z): a board of fewer refuses a command
/// for an axis it does not have ([`Refusal::Axis`]; its hello says how many
/// it has).
pub const MAX_AXES: u8 = 3;
/// A command's `axis` that addresses every axis of the board (where the
/// command takes it: [`Command::Record`]).
pub const EVERY_AXIS: u8 = u8::MAX;
/// The axes' names by number (a command's `axis`: 0 is x).
pub const AXIS_NAMES: [&str; MAX_AXES as usize] = ["x", "y", "z"];
/// Largest encoded frame, delimiter included, bytes.
pub const MAX_FRAME: usize = 1280;
/// Model bytes per [`Command::ModelChunk`].
pub const MAX_CHUNK: usize = 256;
/// Points per [`Command::Points`].
pub const MAX_POINTS: usize = 64;
/// Values per [`Reply::Record`].
pub const MAX_VALUES: usize = 480;
/// Encoded bytes of the values of one [`Reply::Record`] at most (the board stops
/// adding samples to a batch before its values would take more): the batch fills
/// a frame by bytes, whatever the signals' deltas take.
pub const MAX_BATCH_BYTES: usize = 1_100;
/// Bytes per [`Reply::ModelBytes`].
pub const MAX_MODEL_BYTES: usize = 256;
/// The sequence number of a reply to a frame that could not be read.
pub const NO_SEQ: u16 = u16::MAX;

/// A short text (a refusal's reason, a firmware version).
pub type Text = heapless::String<96>;
