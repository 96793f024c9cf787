//! The board's link on arbitrary input: bytes into the firmware's `FrameReader`,
//! every completed frame into the link handler of an emulated board
//! (`fpi_firmware::emulation::virtual_bench::Virtual`: control loop, virtual stage, recorder,
//! stream buffer, model stores and flash, on the fuzzer's thread), every reply
//! checked.
//!
//! The board is built once per process and never reset: it sees every input one
//! after the other, as a board sees a host's session, so the handler must cope
//! with any history. A `Reset` request is answered but the board is not rebooted
//! (booting leaks the board's statics; the boot path is covered by the firmware's
//! own tests). (Set `FPI_FUZZ_FRESH_BOARD=1` to boot a new board for each input
//! instead, to reproduce a crash from its input alone; slower, and each board's
//! statics are kept for the rest of the process, so only for a few inputs.)
//!
//! Checked on every reply: a frame (COBS, no zero inside, the delimiter last, at
//! most `MAX_FRAME` bytes) that decodes as a `ReplyHeader` of this protocol version
//! and a `Reply`, echoing the request's sequence number (`NO_SEQ` for an
//! unreadable request); a request handled in at most [`MAX_WAITS`] control ticks
//! (an order the loop never takes would block the link for `APPLY_TIMEOUT_WAITS`).
//!
//! Two input formats:
//! * [`bytes`]: the input is the byte stream on the line.
//! * [`ops`]: the input is a script of operations ([`ops`] says which) that
//!   send raw bytes, frame a payload with a correct CRC (so the fuzzer reaches
//!   the command handler without having to find CRCs), let the board run idle for
//!   a while (supervision timeouts, streams, the recorder), or upload a model
//!   image (the factory image with an edit script, see [`crate::image::edit`]).

use std::sync::Mutex;

use fpi_firmware::emulation::virtual_bench::{EmulatedFlash, Virtual, FLASH_SLOTS};
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::board::analog_in::{FORCE_ADC, SETPOINT_DAC};
use fpi_firmware::board::capacity::{Store, IMAGE_BYTES};
use fpi_firmware::link::frame::{self, FrameReader, Push};
use fpi_firmware::link::handler::{Board, Handler};
use fpi_firmware::link::protocol::{
    Command, Header, Refusal, Reply, ReplyHeader, MAX_CHUNK, MAX_FRAME, NO_SEQ, VERSION,
};
use fpi_firmware::board::factory_model::MODEL_IMAGE;
use fpi_firmware::control::recorder::Recorder;
use fpi_firmware::control::reference::stream::Points;
use fpi_firmware::emulation::virtual_io::SimLink;
use fpi_firmware::board::storage::ModelFlash;
use piezo_fpi::model::image::CRC32;

/// Control ticks one request may take (an order is taken at the next tick).
pub const MAX_WAITS: u32 = 1000;
/// Idle ticks one input of [`ops`] may ask for, all operations together.
pub const IDLE_BUDGET: u32 = 8192;

fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

/// The emulated board and the link task's buffers.
pub struct Rig {
    board: Virtual,
    handler: Handler<EmulatedFlash>,
    reader: FrameReader<MAX_FRAME>,
    scratch: Vec<u8>,
    out: Vec<u8>,
    /// Sequence numbers of the frames this harness builds itself.
    seq: u16,
    /// Print each reply (`FPI_FUZZ_TRACE=1`).
    trace: bool,
}

/// The handler's view of the board: the virtual board, counting the ticks it waits.
struct Counted<'a> {
    board: &'a mut Virtual,
    waits: u32,
}

impl Board for Counted<'_> {
    fn exchange<R>(&mut self, f: impl FnOnce(&mut Exchange<'_>) -> R) -> R {
        self.board.exchange(f)
    }
    fn wait(&mut self) {
        self.waits += 1;
        assert!(
            self.waits <= MAX_WAITS,
            "a request kept the link task waiting for more than {MAX_WAITS} control ticks"
        );
        self.board.tick();
    }
}

impl Rig {
    /// Boots the emulated board as the firmware does (factory model, empty flash).
    pub fn boot() -> Box<Self> {
        let link = leak(SimLink::new(FORCE_ADC, SETPOINT_DAC));
        let (board, handler) = Virtual::boot(
            link,
            [leak(Store::new()), leak(Store::new())],
            leak([0; IMAGE_BYTES]),
            Exchange::new(leak(Recorder::new()), leak(Points::new())),
            ModelFlash::new(EmulatedFlash::new(), FLASH_SLOTS),
        )
        .expect("the emulated board boots");
        // Unpaced: the emulated board's link pace only makes the link task wait
        // for control ticks (thousands for a long frame at the UART's rate),
        // which would bury the requests' own waits and slow the fuzzing down;
        // the pace is tested in `fpi_firmware::link::pace` and on the board.
        let mut handler = handler;
        handler.unpaced();
        Box::new(Self {
            board,
            handler,
            reader: FrameReader::new(),
            scratch: vec![0; MAX_FRAME],
            out: vec![0; MAX_FRAME],
            seq: 0,
            trace: std::env::var_os("FPI_FUZZ_TRACE").is_some(),
        })
    }

    /// One byte from the line; a reply when it completes a frame.
    pub fn push(&mut self, byte: u8) {
        let (n, seq) = match self.reader.push(byte) {
            Push::Pending => return,
            Push::Frame => {
                let frame = self.reader.frame();
                let mut copy = frame.to_vec();
                let seq = frame::decode::<Header>(&mut copy).map_or(NO_SEQ, |(h, _)| h.seq);
                let mut board = Counted {
                    board: &mut self.board,
                    waits: 0,
                };
                let n = self
                    .handler
                    .handle(&mut board, frame, &mut self.scratch, &mut self.out);
                (n, seq)
            }
            Push::Overlong => (
                self.handler.overlong(&mut self.scratch, &mut self.out),
                NO_SEQ,
            ),
        };
        let reply = check_reply(&self.out[..n.min(self.out.len())], n, seq);
        if self.trace {
            eprintln!("reply seq {seq}: {reply:?}");
        }
    }

    /// Bytes from the line.
    pub fn push_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.push(b);
        }
    }

    /// A frame around `payload` (a request's postcard bytes) with its CRC, after a
    /// delimiter (as a host resynchronising).
    pub fn send_payload(&mut self, payload: &[u8]) {
        let mut raw = payload.to_vec();
        raw.extend_from_slice(&CRC32.checksum(payload).to_le_bytes());
        let mut line = vec![0];
        line.extend(cobs(&raw));
        line.push(0);
        self.push_all(&line);
    }

    /// A request built by the harness.
    pub fn send(&mut self, cmd: &Command<'_>) {
        self.seq = self.seq.wrapping_add(1);
        let h = Header {
            version: VERSION,
            seq: self.seq,
        };
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let n = frame::encode(&h, cmd, &mut scratch, &mut out).expect("a request fits a frame");
        let mut line = vec![0];
        line.extend_from_slice(&out[..n]);
        self.push_all(&line);
    }

    /// Uploads `image` (begin, chunks, commit) as a host does.
    pub fn upload(&mut self, image: &[u8], store: bool) {
        self.send(&Command::ModelBegin {
            len: image.len() as u32,
            crc: CRC32.checksum(image),
        });
        for (k, chunk) in image.chunks(MAX_CHUNK).enumerate() {
            self.send(&Command::ModelChunk {
                offset: (k * MAX_CHUNK) as u32,
                data: chunk,
            });
        }
        self.send(&Command::ModelCommit { axis: 0, store });
    }

    /// Lets the board run `ticks` ticks without a request.
    pub fn idle(&mut self, ticks: u32) {
        for _ in 0..ticks {
            self.board.tick();
        }
    }
}

/// COBS (the firmware decodes with the `cobs` crate).
pub fn cobs(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let (mut code_at, mut code) = (0, 1u8);
    for &b in data {
        if b == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(b);
            code += 1;
            if code == 0xFF {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out
}

/// Undoes [`cobs`] (a frame without its delimiter); `None` if it is not COBS.
pub fn uncobs(data: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(data.len());
    let mut i = 0;
    while i < data.len() {
        let code = data[i] as usize;
        if code == 0 || i + code > data.len() {
            return None;
        }
        out.extend_from_slice(&data[i + 1..i + code]);
        i += code;
        if code < 0xFF && i < data.len() {
            out.push(0);
        }
    }
    Some(out)
}

/// Checks a reply frame of `n` bytes (`bytes` its first `n`) to a request with
/// sequence number `seq`; the reply.
pub fn check_reply(bytes: &[u8], n: usize, seq: u16) -> Reply {
    assert!(n > 0, "no reply (the reply did not fit the frame buffer)");
    assert!(
        n <= MAX_FRAME,
        "a reply of {n} bytes, more than {MAX_FRAME}"
    );
    assert_eq!(bytes.len(), n);
    assert_eq!(bytes[n - 1], 0, "the reply does not end with its delimiter");
    assert!(
        !bytes[..n - 1].contains(&0),
        "a zero byte inside the reply frame"
    );
    let mut f = bytes[..n - 1].to_vec();
    let (h, body) = frame::decode::<ReplyHeader>(&mut f)
        .unwrap_or_else(|e| panic!("the reply frame does not decode: {e:?}"));
    assert_eq!(h.version, VERSION, "the reply's protocol version");
    assert_eq!(h.seq, seq, "the reply does not echo the request's number");
    let reply = frame::body::<Reply>(body)
        .unwrap_or_else(|e| panic!("the reply's body does not decode: {e:?}"));
    if let Reply::Refused { code, reason } = &reply {
        assert!(
            !(*code == Refusal::Fault && reason.contains("did not take the order")),
            "the control loop did not take an order"
        );
    }
    reply
}

/// This process's board. A global, never dropped: the board's statics (leaked
/// boxes, as the firmware's are `static`) stay reachable, so LeakSanitizer does
/// not report them at exit.
static RIG: Mutex<Option<Box<Rig>>> = Mutex::new(None);
/// Boards replaced with `FPI_FUZZ_FRESH_BOARD`, kept for the same reason.
static OLD: Mutex<Vec<Box<Rig>>> = Mutex::new(Vec::new());

/// Runs `f` on this process's board (booted on first use; a new one for every
/// input with `FPI_FUZZ_FRESH_BOARD`, the old one's statics leaked).
pub fn with_rig(f: impl FnOnce(&mut Rig)) {
    let fresh = std::env::var_os("FPI_FUZZ_FRESH_BOARD").is_some();
    // A panic (a crash) poisons the lock; the next input (`cargo test`) still runs.
    let mut slot = RIG.lock().unwrap_or_else(|p| p.into_inner());
    if fresh || slot.is_none() {
        if let Some(old) = slot.take() {
            OLD.lock().unwrap_or_else(|p| p.into_inner()).push(old);
        }
        *slot = Some(Rig::boot());
    }
    if let Some(rig) = slot.as_mut() {
        f(rig);
    }
}

/// The input is the byte stream on the line.
pub fn bytes(input: &[u8]) {
    with_rig(|rig| rig.push_all(input));
}

/// The input is a script of operations, each an op byte and its operands:
///
/// | `op % 4` | operands | operation |
/// |---|---|---|
/// | 0 | `len: u8`, `len` bytes | the bytes on the line as they are |
/// | 1 | `len: u16` LE (modulo 1400), `len` bytes | a frame of these bytes (a request's postcard encoding) with its CRC, after a delimiter |
/// | 2 | `ticks: u16` LE (modulo 2048) | the board runs that many ticks without a request (at most [`IDLE_BUDGET`] per input) |
/// | 3 | `len: u8`, `len` bytes | uploads the factory image edited by these bytes ([`crate::image::edit`]); `op & 4`: store it in flash |
///
/// Operands cut short by the input's end are taken as they are.
pub fn ops(input: &[u8]) {
    with_rig(|rig| {
        let mut budget = IDLE_BUDGET;
        let mut i = 0;
        let take = |i: &mut usize, len: usize| {
            let s = &input[(*i).min(input.len())..(*i + len).min(input.len())];
            *i += len;
            s
        };
        while i < input.len() {
            let op = input[i];
            i += 1;
            match op % 4 {
                0 => {
                    let len = take(&mut i, 1).first().copied().unwrap_or(0) as usize;
                    rig.push_all(take(&mut i, len));
                }
                1 => {
                    let len = crate::u16_at(take(&mut i, 2), 0) as usize % 1400;
                    rig.send_payload(take(&mut i, len));
                }
                2 => {
                    let ticks = (crate::u16_at(take(&mut i, 2), 0) as u32 % 2048).min(budget);
                    budget -= ticks;
                    rig.idle(ticks);
                }
                _ => {
                    let len = take(&mut i, 1).first().copied().unwrap_or(0) as usize;
                    let image = crate::image::edit(MODEL_IMAGE, take(&mut i, len));
                    rig.upload(&image, op & 4 != 0);
                }
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Payloads framed here decode with the firmware's decoder, whatever their
    /// zero bytes and length (COBS blocks of 254 bytes).
    #[test]
    fn framed_payloads_decode_in_the_firmware() {
        for len in [0usize, 1, 253, 254, 255, 300, 600, 1200] {
            let mut payload = vec![VERSION, 7];
            payload.extend((0..len).map(|k| (k % 7) as u8));
            let mut raw = payload.clone();
            raw.extend_from_slice(&CRC32.checksum(&payload).to_le_bytes());
            let mut enc = cobs(&raw);
            assert!(!enc.contains(&0));
            assert_eq!(uncobs(&enc).as_deref(), Some(&raw[..]));
            let (h, body) = frame::decode::<Header>(&mut enc).expect("our frame decodes");
            assert_eq!((h.version, h.seq), (VERSION, 7));
            assert_eq!(body, &payload[2..]);
        }
    }

    #[test]
    fn the_board_answers_every_request() {
        let mut rig = Rig::boot();
        rig.send(&Command::Hello);
        rig.send(&Command::Move {
            axis: 0,
            target: 10 << 16,
            speed: 1000 << 16,
        });
        rig.idle(100);
        rig.upload(MODEL_IMAGE, true);
        rig.push_all(&[1, 2, 3, 0, 0, 5]);
        rig.send(&Command::Status { axis: 0 });
    }
}
