//! Golden bytes: the encoding of every command and reply, written out in hex,
//! so that no change elsewhere (a variant moved, a field added) can change
//! what crosses the link without a test saying so — and a new protocol
//! version with it. Each message also decodes back from its bytes.
//!
//! Encoding (see the book's `docs/src/protocol.md`): a message is its kind's wire number
//! (one byte), then its fields in order, in postcard's encoding: `u8` and
//! `bool` one byte, other unsigned integers LEB128 varints, signed integers
//! zig-zag varints, `Option` 0/1 then the value, sequences and text a varint
//! length then the items, `f32` four bytes little-endian.

use std::collections::BTreeSet;
use std::fmt::Debug;

use fpi_protocol::frame::{self, Body};
use fpi_protocol::record::signal;
use fpi_protocol::*;
use serde::Serialize;

/// `bytes` as lower-case hex, a space between bytes.
fn hex(bytes: &[u8]) -> String {
    let h: Vec<String> = bytes.iter().map(|b| format!("{b:02x}")).collect();
    h.join(" ")
}

fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn encoded<T: Serialize>(v: &T) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    postcard::to_slice(v, &mut buf).unwrap().to_vec()
}

/// `v` encodes to `golden` and `golden` decodes (as a frame body) to `v`.
fn check<'a, T: Serialize + Body<'a> + PartialEq + Debug>(v: &T, golden: &'a [u8]) {
    assert_eq!(hex(&encoded(v)), hex(golden), "the bytes of {v:?}");
    assert_eq!(&frame::body::<T>(golden).unwrap(), v, "{v:?} decoded");
}

/// One test per message (`name: value => "hex"`), and `$all` listing them for
/// the coverage checks.
macro_rules! goldens {
    ($ty:ty, $all:ident; $($name:ident: $value:expr => $hex:literal;)+) => {
        $(
            #[test]
            fn $name() {
                let golden: &'static [u8] = Box::leak(unhex($hex).into_boxed_slice());
                check::<$ty>(&$value, golden);
            }
        )+

        fn $all() -> Vec<$ty> {
            vec![$($value),+]
        }
    };
}

fn text(s: &str) -> Text {
    s.try_into().unwrap()
}

fn points() -> heapless::Vec<i32, MAX_POINTS> {
    heapless::Vec::from_slice(&[0, 1 << 16, -(1 << 16)]).unwrap()
}

goldens! {
    Command<'static>, all_commands;
    command_hello: Command::Hello => "00";
    command_status: Command::Status { axis: 0 } => "01 00";
    command_ping: Command::Ping => "02";
    command_move: Command::Move { axis: 0, target: 20 << 16, speed: 1000 << 16 }
        => "03 00 80 80 a0 01 80 80 c0 3e";
    command_wave: Command::Wave {
        axis: 0,
        shape: Shape::Triangle,
        offset: 20 << 16,
        amplitude: 5 << 16,
        freq_mhz: 5000,
        cycles: 3,
    } => "04 00 01 80 80 a0 01 80 80 28 88 27 03";
    command_points: Command::Points { axis: 0, first: 130, points: points() }
        => "05 00 82 01 03 00 80 80 08 ff ff 07";
    command_stream: Command::Stream { axis: 0, interval: 300 } => "06 00 ac 02";
    command_stream_end: Command::StreamEnd { axis: 0 } => "07 00";
    command_stream_clear: Command::StreamClear { axis: 0 } => "08 00";
    command_analog: Command::Analog { axis: 0 } => "09 00";
    command_hold: Command::Hold { axis: 0 } => "0a 00";
    command_safe: Command::Safe => "0b";
    command_clear_fault: Command::ClearFault => "0c";
    command_drive: Command::Drive { axis: 0, compensated: true } => "0d 00 01";
    command_supervise: Command::Supervise { timeout_ms: 500 } => "0e f4 03";
    command_record: Command::Record { axis: 1, decimation: 25, signals: signal::ALL } => "0f 01 19 7f";
    command_record_stop: Command::RecordStop => "10";
    command_read_record: Command::ReadRecord { max: u16::MAX } => "11 ff ff 03";
    command_model_begin: Command::ModelBegin { len: 1000, crc: 0xdead_beef }
        => "12 e8 07 ef fd b6 f5 0d";
    command_model_chunk: Command::ModelChunk { offset: 256, data: &[0, 1, 0xff] }
        => "13 80 02 03 00 01 ff";
    command_model_commit: Command::ModelCommit { axis: 1, store: true } => "14 01 01";
    command_model_info: Command::ModelInfo { axis: 0 } => "15 00";
    command_model_factory: Command::ModelFactory { axis: 2 } => "16 02";
    command_counters: Command::Counters => "17";
    command_bench: Command::Bench(BenchOrder::SensorOffset(-(2 << 16))) => "18 03 ff ff 0f";
    command_bench_link: Command::Bench(BenchOrder::Link(LinkKind::Usb)) => "18 09 01";
    command_bench_front_end: Command::Bench(BenchOrder::FrontEnd(FrontEndKind::Precision)) => "18 0a 01";
    command_bench_trigger_in: Command::Bench(BenchOrder::TriggerIn(300)) => "18 0b ac 02";
    command_reset: Command::Reset => "19";
    command_loop: Command::Loop { axis: 0, mode: LoopMode::FeedbackOnly } => "1a 00 02";
    command_damping: Command::Damping { axis: 0, on: false } => "1b 00 00";
    command_step: Command::Step { axis: 0, target: 10 << 16, duration_us: 2000 }
        => "1c 00 80 80 50 d0 0f";
    command_shaping: Command::Shaping { axis: 0, on: true } => "1d 00 01";
    command_analyse: Command::Analyse {
        axis: 0,
        freq_mhz: 100_000,
        amplitude: 1 << 15,
        settle: 5,
        cycles: 20,
    } => "1e 00 a0 8d 06 80 80 04 05 14";
    command_analysis_result: Command::AnalysisResult { axis: 0 } => "1f 00";
    command_model_read: Command::ModelRead { axis: 0, offset: 512 } => "20 00 80 04";
    command_lead_ratio: Command::LeadRatio { axis: 0, ratio: 3 << 29 } => "21 00 80 80 80 80 0c";
    command_setting_get: Command::SettingGet { path: b"/supervise_ms" }
        => "22 0d 2f 73 75 70 65 72 76 69 73 65 5f 6d 73";
    command_setting_set: Command::SettingSet { path: b"/stage/0/damping", value: b"false" }
        => "23 10 2f 73 74 61 67 65 2f 30 2f 64 61 6d 70 69 6e 67 05 66 61 6c 73 65";
    command_trigger: Command::Trigger {
        axis: 0,
        settings: TriggerSettings {
            mode: TriggerMode::Travel,
            step_nm: 500,
            band_nm: 100,
            low_nm: -2,
            high_nm: 0,
            pulse_ticks: 3,
        },
    } => "24 00 01 f4 03 64 03 00 03";
    command_trigger_in: Command::TriggerIn { axis: 0, starts: TriggerStart::Both } => "25 00 03";
    command_raster: Command::Raster(RasterOrder {
        fast: 0,
        slow: 1,
        fast_span: [5 << 16, 35 << 16],
        slow_span: [5 << 16, 35 << 16],
        freq_mhz: 100_000,
        lines: 20,
        staircase: false,
    }) => "26 00 01 80 80 28 80 80 98 02 80 80 28 80 80 98 02 a0 8d 06 14 00";
    command_move_axes: Command::MoveAxes { mask: 3, targets: [10 << 16, 20 << 16, 0], speed: 1000 << 16 }
        => "28 03 80 80 50 80 80 a0 01 00 80 80 c0 3e";
    command_decoupling: Command::Decoupling {
        input: [[1 << 30, 0, 0], [0, 1 << 30, 0], [0, 0, 1 << 30]],
        output: [[1 << 30, -(1 << 24), 0], [0, 1 << 30, 0], [0, 0, 1 << 30]],
        preload: [[0, 1 << 15, 0], [1 << 15, 0, 0], [0, 0, 0]],
    } => "27 80 80 80 80 08 00 00 00 80 80 80 80 08 00 00 00 80 80 80 80 08 80 80 80 80 08 ff ff \
          ff 0f 00 00 80 80 80 80 08 00 00 00 80 80 80 80 08 00 80 80 04 00 80 80 04 00 00 00 00 00";
}

fn hello() -> Hello {
    Hello {
        protocol: VERSION,
        firmware: text("0.1.0"),
        board: BoardKind::Emulated,
        rate_hz: 20_000,
        capacity: [8, 2, 64, 4096],
        buffers: [8192, 1024],
        limits: [0, 150 << 16, 5 << 16, 0, 10 << 16],
        reset: ResetReason::Command,
        link: LinkKind::Usb,
        axes: 1,
        front_end: FrontEndKind::Precision,
    }
}

fn status() -> Status {
    Status {
        axis: 0,
        tick: 123_456,
        signals: [20 << 16, -1, 75 << 16, 300 << 16, (20 << 16) + 7],
        fault: Some(FaultReport {
            code: 4,
            at: 10,
            safe_at: None,
        }),
        fault_axis: Some(1),
        amplifier_on: false,
        source: SourceKind::Stream,
        approaching: true,
        compensated: true,
        loop_mode: LoopMode::Closed,
        damping: Some(true),
        shaping: None,
        lead_ratio: Some((1 << 30, true)),
        analysing: false,
        supervision: [10_000, 3],
        stream: [100, 924, 1100, 0],
        recorder: [1, 500, 0, 20],
        limited_steps: 0,
        governed_ticks: 0,
        ended_points: 0,
        overruns: 2,
        model_crc: 0x1234_5678,
        armed: [true, false],
    }
}

fn model_report() -> ModelReport {
    ModelReport {
        crc: 0x1234_5678,
        origin: Origin::Stored(3),
        size: [8, 2],
        maps: [true, false],
        window: [0, 40 << 16, 1 << 16],
        stored: Some((3, 0x1234_5678)),
        slots: [SlotReport::Valid(3), SlotReport::Refused(2)],
        feedback: None,
        dynamics: Some([1_000_000, 1 << 28, 0, 1 << 16]),
        damping: None,
        force_channel: [1 << 20, 50 << 16],
    }
}

fn batch() -> Batch {
    Batch {
        signals: signal::X_REF | signal::STATUS,
        decimation: 25,
        active: true,
        dropped: 0,
        waiting: 7,
        // Two samples, ticks 1000 and 1025: the second as differences.
        values: heapless::Vec::from_slice(&[1000, 1 << 16, 3, 25, 0, 0]).unwrap(),
    }
}

goldens! {
    Reply, all_replies;
    reply_ack: Reply::Ack => "00";
    reply_hello: Reply::Hello(hello())
        => "01 0e 05 30 2e 31 2e 30 01 a0 9c 01 08 02 40 80 20 80 40 80 08 00 80 80 b0 09 80 80 28 00 80 80 50 02 01 01 01";
    reply_status: Reply::Status(status())
        => "02 00 c0 c4 07 80 80 a0 01 01 80 80 d8 04 80 80 e0 12 8e 80 a0 01 01 04 0a 00 01 01 00 03 01 01 01 01 01 00 01 80 80 80 80 08 01 00 90 4e 03 64 9c 07 cc 08 00 01 f4 03 00 14 00 00 00 02 f8 ac d1 91 01 01 00";
    reply_record: Reply::Record(batch())
        => "03 11 19 01 00 07 06 d0 0f 80 80 08 06 32 00 00";
    reply_model: Reply::Model(model_report())
        => "04 f8 ac d1 91 01 01 03 08 02 01 00 00 80 80 c0 02 80 80 08 01 03 f8 ac d1 91 01 01 03 03 02 00 01 80 89 7a 80 80 80 80 02 00 80 80 08 00 80 80 80 01 80 80 90 03";
    reply_counters: Reply::Counters(Counters {
        requests: 300,
        malformed: 2,
        crc_errors: 1,
        overlong: 0,
        version: 0,
        unknown: 1,
        refused: 4,
        stack_bytes: 1536,
    }) => "05 ac 02 02 01 00 00 01 04 80 0c";
    reply_analysis: Reply::Analysis(Some(Analysis {
        freq_mhz: 100_000,
        ticks: 4000,
        sums: [[1, -1], [0, 0], [2, -2], [0, 1 << 40], [-3, 3]],
        faulted: false,
        governed: 3,
    })) => "06 01 a0 8d 06 a0 1f 02 01 00 00 04 03 00 80 80 80 80 80 40 05 06 00 03";
    reply_model_bytes: Reply::ModelBytes {
        total: 1000,
        offset: 768,
        data: heapless::Vec::from_slice(&[0x46, 0x50, 0x49]).unwrap(),
    } => "07 e8 07 80 06 03 46 50 49";
    reply_refused: Reply::Refused { code: Refusal::Axis, reason: text("axis 1") }
        => "08 0d 06 61 78 69 73 20 31";
    reply_setting: Reply::Setting(heapless::Vec::from_slice(b"\"open\"").unwrap())
        => "09 06 22 6f 70 65 6e 22";
}

#[test]
fn every_command_and_reply_kind_has_its_golden_bytes() {
    let commands: BTreeSet<u8> = all_commands().iter().map(|c| c.kind().to_u8()).collect();
    let kinds: BTreeSet<u8> = CommandKind::ALL.iter().map(|k| k.to_u8()).collect();
    assert_eq!(commands, kinds);
    let replies: BTreeSet<u8> = all_replies().iter().map(|r| r.kind().to_u8()).collect();
    let kinds: BTreeSet<u8> = ReplyKind::ALL.iter().map(|k| k.to_u8()).collect();
    assert_eq!(replies, kinds);
}

/// Every wire number of every enum, by name: renaming a variant is free,
/// renumbering one is a protocol change.
#[test]
fn wire_numbers_are_pinned() {
    fn names<T: Debug + Copy>(all: &[T], number: impl Fn(T) -> u8) -> String {
        let n: Vec<String> = all
            .iter()
            .map(|&v| format!("{v:?}={}", number(v)))
            .collect();
        n.join(" ")
    }
    let pinned = [
        names(Shape::ALL, Shape::to_u8),
        names(LoopMode::ALL, LoopMode::to_u8),
        names(SourceKind::ALL, SourceKind::to_u8),
        names(Refusal::ALL, Refusal::to_u8),
        names(BoardKind::ALL, BoardKind::to_u8),
        names(ResetReason::ALL, ResetReason::to_u8),
        names(SlotKind::ALL, SlotKind::to_u8),
        names(OriginKind::ALL, OriginKind::to_u8),
        names(BenchKind::ALL, BenchKind::to_u8),
        names(LinkKind::ALL, LinkKind::to_u8),
        names(FrontEndKind::ALL, FrontEndKind::to_u8),
        names(TriggerMode::ALL, TriggerMode::to_u8),
        names(TriggerStart::ALL, TriggerStart::to_u8),
    ];
    let golden = [
        "Sine=0 Triangle=1 RaisedCosine=2",
        "Open=0 Closed=1 FeedbackOnly=2",
        "Hold=0 Move=1 Wave=2 Stream=3 Analog=4",
        "Malformed=0 Version=1 Unknown=2 Fault=3 NotAtRest=4 StillRamping=5 OutOfRange=6 \
         BadArgument=7 Model=8 Upload=9 Storage=10 NotEmulated=11 Stream=12 Axis=13 \
         Setting=14 Held=15",
        "Driver=0 Emulated=1",
        "PowerOn=0 Pin=1 Command=2 Watchdog=3 BrownOut=4 Unknown=5",
        "Empty=0 Valid=1 Damaged=2 Refused=3",
        "Factory=0 Stored=1 Received=2",
        "SensorOpen=0 SensorStuck=1 Analog=2 SensorOffset=3 Stall=4 DamageStored=5 \
         PositionOpen=6 PositionStuck=7 Stage=8 Link=9 FrontEnd=10 TriggerIn=11",
        "Uart=0 Usb=1",
        "Internal=0 Precision=1",
        "Off=0 Travel=1 OnTarget=2 Window=3 Point=4",
        "Nothing=0 Motion=1 Recorder=2 Both=3",
    ];
    assert_eq!(pinned, golden);
    for k in CommandKind::ALL {
        assert_eq!(CommandKind::from_u8(k.to_u8()), Some(*k));
    }
}

fpi_protocol::wire_enum! {
    /// Declared out of order: the bytes follow the numbers written out.
    pub enum Scrambled {
        /// Declared first.
        First = 7,
        /// Declared second.
        Second = 2,
        /// Declared third.
        Third = 0,
    }
}

/// The serde-derived encoding would number these 0, 1, 2 by their places; the
/// wire encoding writes the declared numbers, so moving a declaration changes
/// nothing on the wire.
#[test]
fn declaration_order_does_not_number_the_wire() {
    assert_eq!(encoded(&Scrambled::First), [7]);
    assert_eq!(encoded(&Scrambled::Second), [2]);
    assert_eq!(encoded(&Scrambled::Third), [0]);
    assert_eq!(
        postcard::from_bytes::<Scrambled>(&[2]).unwrap(),
        Scrambled::Second
    );
    assert!(
        postcard::from_bytes::<Scrambled>(&[1]).is_err(),
        "1 is no variant"
    );
    // A tagged message: `Bench`'s number, then the order's own.
    assert_eq!(
        encoded(&Command::Bench(BenchOrder::Stage(StageVariant::BUILT)))[..3],
        [24, 8, 1]
    );
}

/// A whole request frame: COBS(header ‖ body ‖ CRC-32 LE) ‖ 0.
#[test]
fn a_request_frame_golden() {
    let (mut scratch, mut out) = ([0u8; 64], [0u8; 64]);
    let h = Header {
        version: VERSION,
        seq: 1,
    };
    let n = frame::encode(&h, &Command::Status { axis: 0 }, &mut scratch, &mut out).unwrap();
    assert_eq!(hex(&out[..n]), "04 0e 01 01 05 59 f3 42 d9 00");
}

/// An unknown kind is told apart from garbage; a known kind with bad fields is
/// garbage.
#[test]
fn unknown_kinds_and_axes() {
    assert_eq!(
        frame::body::<Command<'_>>(&[41]),
        Err(frame::FrameError::UnknownKind)
    );
    assert_eq!(
        frame::body::<Command<'_>>(&[3, 0]),
        Err(frame::FrameError::Encoding)
    );
    assert_eq!(
        frame::body::<Reply>(&[10]),
        Err(frame::FrameError::UnknownKind)
    );
    assert_eq!(
        Command::Move {
            axis: 1,
            target: 0,
            speed: 1
        }
        .axis(),
        Some(1)
    );
    assert_eq!(Command::Safe.axis(), None);
}

/// The size of the replies the host polls most, bytes of body (the test
/// prints the status reply's figure with `--nocapture`).
#[test]
fn status_reply_size() {
    let n = encoded(&Reply::Status(status())).len();
    let h = ReplyHeader {
        version: VERSION,
        seq: 1,
        tick: status().tick,
    };
    let (mut scratch, mut out) = ([0u8; MAX_FRAME], [0u8; MAX_FRAME]);
    let framed = frame::encode(&h, &Reply::Status(status()), &mut scratch, &mut out).unwrap();
    println!("status reply: {n} bytes of body, {framed} bytes framed");
    assert_eq!(
        (n, framed),
        (69, 80),
        "the status reply's size changed: update docs/src/protocol.md"
    );
}
