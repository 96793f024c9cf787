//! The host's side of an emulated board's link in the firmware's tests:
//! requests framed as a host frames them, handed to the board's handler,
//! their replies decoded.

use crate::emulation::virtual_bench::EmulatedFlash;
use crate::emulation::Emulated;
use crate::link::frame;
use crate::link::handler::Handler;
use crate::link::protocol::{
    Command, Header, Refusal, Reply, ReplyHeader, Status, MAX_CHUNK, MAX_FRAME, VERSION,
};

/// A board of `N` axes, its handler, and the host's request numbers.
pub(crate) struct Host<B, const N: usize = 1> {
    pub(crate) board: B,
    pub(crate) handler: Handler<EmulatedFlash, N>,
    pub(crate) seq: u16,
}

/// `x` µm as the link carries it (`I16F16` bits; 0 for a value beyond them).
pub(crate) fn um(x: f64) -> i32 {
    piezo_fpi::q::signal(x).map_or(0, |x| x.to_bits())
}

/// `v`, for as long as the test runs.
pub(crate) fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

impl<B: Emulated<N>, const N: usize> Host<B, N> {
    /// `board` and its `handler`, before the host's first request.
    pub(crate) fn new(board: B, handler: Handler<EmulatedFlash, N>) -> Self {
        Self {
            board,
            handler,
            seq: 0,
        }
    }

    pub(crate) fn raw(&mut self, frame_bytes: &mut [u8]) -> (ReplyHeader, Reply) {
        let (h, reply, _) = self.raw_sized(frame_bytes);
        (h, reply)
    }

    /// The reply to a frame, and the reply frame's size, bytes.
    pub(crate) fn raw_sized(&mut self, frame_bytes: &mut [u8]) -> (ReplyHeader, Reply, usize) {
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let n = self
            .handler
            .handle(&mut self.board, frame_bytes, &mut scratch, &mut out);
        assert!(n > 0 && out[n - 1] == 0);
        let (h, body) = frame::decode::<ReplyHeader>(&mut out[..n - 1]).unwrap();
        (h, frame::body::<Reply>(body).unwrap(), n)
    }

    /// The reply to `cmd` and its size on the line, bytes.
    pub(crate) fn sized(&mut self, cmd: Command<'_>) -> (usize, Reply) {
        self.seq = self.seq.wrapping_add(1);
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let h = Header {
            version: VERSION,
            seq: self.seq,
        };
        let n = frame::encode(&h, &cmd, &mut scratch, &mut out).unwrap();
        let (_, reply, m) = self.raw_sized(&mut out[..n - 1]);
        (m, reply)
    }

    pub(crate) fn send(&mut self, cmd: Command<'_>) -> Reply {
        self.exchange(cmd).1
    }

    pub(crate) fn exchange(&mut self, cmd: Command<'_>) -> (u32, Reply) {
        self.seq += 1;
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let h = Header {
            version: VERSION,
            seq: self.seq,
        };
        let n = frame::encode(&h, &cmd, &mut scratch, &mut out).unwrap();
        let (back, reply) = self.raw(&mut out[..n - 1]);
        assert_eq!(back.seq, self.seq, "the reply echoes the request");
        (back.tick, reply)
    }

    pub(crate) fn ack(&mut self, cmd: Command<'_>) -> u32 {
        match self.exchange(cmd) {
            (tick, Reply::Ack) => tick,
            (_, r) => panic!("not acknowledged: {r:?}"),
        }
    }

    pub(crate) fn refused(&mut self, cmd: Command<'_>) -> Refusal {
        match self.send(cmd) {
            Reply::Refused { code, .. } => code,
            r => panic!("not refused: {r:?}"),
        }
    }

    pub(crate) fn status(&mut self) -> Status {
        self.status_of(0)
    }

    /// The status of `axis`.
    pub(crate) fn status_of(&mut self, axis: u8) -> Status {
        match self.send(Command::Status { axis }) {
            Reply::Status(s) => s,
            r => panic!("{r:?}"),
        }
    }

    pub(crate) fn run(&mut self, ticks: u32) {
        for _ in 0..ticks {
            self.board.period();
        }
    }

    /// Uploads `image` as `axis`'s model (`store`: kept in flash); the
    /// commit's reply.
    pub(crate) fn upload(&mut self, axis: u8, image: &[u8], store: bool) -> Reply {
        let crc = piezo_fpi::model::image::CRC32.checksum(image);
        self.ack(Command::ModelBegin {
            len: image.len() as u32,
            crc,
        });
        for (k, chunk) in image.chunks(MAX_CHUNK).enumerate() {
            self.ack(Command::ModelChunk {
                offset: (k * MAX_CHUNK) as u32,
                data: chunk,
            });
        }
        self.send(Command::ModelCommit { axis, store })
    }
}
