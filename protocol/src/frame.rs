//! Framing: a message is its postcard encoding followed by the CRC-32 of those
//! bytes (little-endian), COBS-encoded and terminated by a zero byte.
//!
//! ```text
//! frame = COBS( postcard(Header) ‖ postcard(body) ‖ crc32_le ) ‖ 0x00
//! ```
//!
//! COBS makes the zero byte a reliable delimiter: a receiver that joins a stream
//! mid-frame, or loses bytes, resynchronises at the next zero. The CRC (the same
//! CRC-32 as the model image's) catches what COBS cannot.

use crc::{Crc, CRC_32_ISO_HDLC};
use serde::{Deserialize, Serialize};

use crate::{Command, CommandKind, Refusal, Reply, ReplyKind};

/// The frame's CRC: CRC-32/ISO-HDLC (zlib's `crc32`), the model image's CRC.
pub const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Why a frame could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// Not valid COBS.
    Cobs,
    /// Shorter than a header and a CRC.
    Short,
    /// The CRC does not match.
    Crc,
    /// The bytes are not a message (or a message with bytes left over).
    Encoding,
    /// A message of an unknown kind (a newer protocol's command, or garbage that
    /// happens to pass the CRC).
    UnknownKind,
    /// The output buffer is too small for the message.
    Overflow,
}

impl FrameError {
    /// The refusal a board answers with.
    pub const fn refusal(self) -> Refusal {
        match self {
            Self::UnknownKind => Refusal::Unknown,
            _ => Refusal::Malformed,
        }
    }

    /// A one-line description.
    pub const fn message(self) -> &'static str {
        match self {
            Self::Cobs => "frame is not valid COBS",
            Self::Short => "frame shorter than a header and its CRC",
            Self::Crc => "frame CRC mismatch",
            Self::Encoding => "frame does not decode as a message",
            Self::UnknownKind => "unknown message kind",
            Self::Overflow => "message too long for the frame buffer",
        }
    }
}

/// Encodes a message into `out` as one frame (delimiter included), using
/// `scratch` for the unstuffed bytes; the frame's length.
pub fn encode<H: Serialize, T: Serialize>(
    header: &H,
    body: &T,
    scratch: &mut [u8],
    out: &mut [u8],
) -> Result<usize, FrameError> {
    let n1 = postcard::to_slice(header, scratch)
        .map_err(|_| FrameError::Overflow)?
        .len();
    let rest = scratch.get_mut(n1..).ok_or(FrameError::Overflow)?;
    let n2 = postcard::to_slice(body, rest)
        .map_err(|_| FrameError::Overflow)?
        .len();
    let n = n1 + n2;
    let crc = CRC32.checksum(scratch.get(..n).ok_or(FrameError::Overflow)?);
    scratch
        .get_mut(n..n + 4)
        .ok_or(FrameError::Overflow)?
        .copy_from_slice(&crc.to_le_bytes());
    let raw = scratch.get(..n + 4).ok_or(FrameError::Overflow)?;
    let m = cobs::try_encode(raw, out).map_err(|_| FrameError::Overflow)?;
    *out.get_mut(m).ok_or(FrameError::Overflow)? = 0;
    Ok(m + 1)
}

/// Decodes a received frame (without its delimiter) in place: its header (a
/// request's [`Header`](crate::Header) or a reply's
/// [`ReplyHeader`](crate::ReplyHeader)) and the bytes of its body.
pub fn decode<'f, H: Deserialize<'f>>(frame: &'f mut [u8]) -> Result<(H, &'f [u8]), FrameError> {
    let len = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    let data = frame.get(..len).ok_or(FrameError::Cobs)?;
    let Some(split) = len.checked_sub(4) else {
        return Err(FrameError::Short);
    };
    let (msg, crc) = data.split_at(split);
    if CRC32.checksum(msg).to_le_bytes() != crc {
        return Err(FrameError::Crc);
    }
    let (header, body) = postcard::take_from_bytes::<H>(msg).map_err(|_| FrameError::Short)?;
    Ok((header, body))
}

/// A message body: a [`Command`] or a [`Reply`], whose first byte is its kind.
pub trait Body<'a>: Deserialize<'a> {
    /// Whether `kind` is the wire number of one of its kinds.
    fn knows(kind: u8) -> bool;
}

impl<'a> Body<'a> for Command<'a> {
    fn knows(kind: u8) -> bool {
        CommandKind::from_u8(kind).is_some()
    }
}

impl Body<'_> for Reply {
    fn knows(kind: u8) -> bool {
        ReplyKind::from_u8(kind).is_some()
    }
}

/// Reads a message body that must use every byte (a body whose kind byte is not
/// one of `T`'s kinds is [`FrameError::UnknownKind`]).
pub fn body<'a, T: Body<'a>>(bytes: &'a [u8]) -> Result<T, FrameError> {
    match postcard::take_from_bytes::<T>(bytes) {
        Ok((v, [])) => Ok(v),
        Ok(_) => Err(FrameError::Encoding),
        Err(_) => match bytes.first() {
            Some(&kind) if !T::knows(kind) => Err(FrameError::UnknownKind),
            _ => Err(FrameError::Encoding),
        },
    }
}

/// What one received byte did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Push {
    /// Still inside a frame.
    Pending,
    /// A frame is complete: [`FrameReader::frame`] holds it.
    Frame,
    /// A frame longer than the buffer ended; it was dropped.
    Overlong,
}

/// Splits a byte stream into frames at zero bytes, `N` bytes at most each.
#[derive(Debug, Clone)]
pub struct FrameReader<const N: usize> {
    buf: [u8; N],
    len: usize,
    overlong: bool,
    complete: bool,
}

impl<const N: usize> Default for FrameReader<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameReader<N> {
    /// Waiting for the first byte.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overlong: false,
            complete: false,
        }
    }

    /// Takes one byte from the line.
    pub fn push(&mut self, byte: u8) -> Push {
        if self.complete {
            self.complete = false;
            self.len = 0;
        }
        if byte == 0 {
            if self.overlong {
                self.overlong = false;
                self.len = 0;
                return Push::Overlong;
            }
            if self.len == 0 {
                return Push::Pending;
            }
            self.complete = true;
            return Push::Frame;
        }
        match self.buf.get_mut(self.len) {
            Some(slot) if !self.overlong => {
                *slot = byte;
                self.len += 1;
            }
            _ => self.overlong = true,
        }
        Push::Pending
    }

    /// The frame just completed (without its delimiter).
    pub fn frame(&mut self) -> &mut [u8] {
        let n = if self.complete { self.len } else { 0 };
        self.buf.get_mut(..n).unwrap_or(&mut [])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Header, VERSION};

    fn frame_of(cmd: &Command<'_>, seq: u16) -> Vec<u8> {
        let (mut scratch, mut out) = ([0u8; 512], [0u8; 600]);
        let h = Header {
            version: VERSION,
            seq,
        };
        let n = encode(&h, cmd, &mut scratch, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn read(bytes: &[u8]) -> Vec<Result<(Header, Command<'static>), FrameError>> {
        let mut r = FrameReader::<256>::new();
        let mut got = Vec::new();
        for &b in bytes {
            match r.push(b) {
                Push::Frame => {
                    let f = r.frame();
                    got.push(
                        decode::<Header>(f)
                            .and_then(|(h, b)| body::<Command<'_>>(b).map(|c| (h, owned(c)))),
                    );
                }
                Push::Overlong => got.push(Err(FrameError::Overflow)),
                Push::Pending => {}
            }
        }
        got
    }

    /// Commands without borrowed data, for comparing outside the buffer.
    fn owned(c: Command<'_>) -> Command<'static> {
        match c {
            Command::ModelChunk { offset, .. } => Command::ModelChunk { offset, data: &[] },
            Command::Hello => Command::Hello,
            Command::Move {
                axis,
                target,
                speed,
            } => Command::Move {
                axis,
                target,
                speed,
            },
            Command::Ping => Command::Ping,
            _ => Command::Status { axis: 0 },
        }
    }

    #[test]
    fn frames_round_trip_and_resynchronise_after_garbage() {
        let mut stream = frame_of(&Command::Hello, 1);
        stream.extend([7, 9, 0xFF, 3]); // line noise, then a delimiter
        stream.push(0);
        stream.extend(frame_of(
            &Command::Move {
                axis: 0,
                target: 123 << 16,
                speed: -5,
            },
            2,
        ));
        let got = read(&stream);
        assert_eq!(got.len(), 3);
        assert_eq!(got[0].as_ref().unwrap().1, Command::Hello);
        assert!(got[1].is_err(), "noise is refused");
        let (h, c) = got[2].as_ref().unwrap();
        assert_eq!(
            (h.seq, c),
            (
                2,
                &Command::Move {
                    axis: 0,
                    target: 123 << 16,
                    speed: -5
                }
            )
        );
    }

    #[test]
    fn a_flipped_bit_fails_the_crc_and_a_cut_frame_is_refused() {
        let good = frame_of(
            &Command::Move {
                axis: 0,
                target: 1,
                speed: 2,
            },
            9,
        );
        for i in 0..good.len() - 1 {
            for bit in 0..8 {
                let mut bad = good.clone();
                bad[i] ^= 1 << bit;
                for r in read(&bad) {
                    assert!(r.is_err(), "byte {i} bit {bit} passed");
                }
            }
        }
        let mut cut = good[..good.len() - 3].to_vec();
        cut.push(0);
        assert!(read(&cut)[0].is_err());
    }

    #[test]
    fn an_unknown_command_is_told_apart_from_garbage() {
        // Variant 100 of `Command` does not exist; the frame is otherwise valid.
        let (mut scratch, mut out) = ([0u8; 64], [0u8; 80]);
        let n = encode(
            &Header {
                version: VERSION,
                seq: 4,
            },
            &100u8,
            &mut scratch,
            &mut out,
        )
        .unwrap();
        let got = read(&out[..n]);
        assert_eq!(got[0].as_ref().err(), Some(&FrameError::UnknownKind));
        assert_eq!(FrameError::UnknownKind.refusal(), Refusal::Unknown);
        // Every kind is known, and is told from garbage by its first byte.
        assert!(CommandKind::ALL.iter().all(|k| Command::knows(k.to_u8())));
        let n = encode(
            &Header {
                version: VERSION,
                seq: 5,
            },
            &Command::Bench(crate::BenchOrder::Analog(7)),
            &mut scratch,
            &mut out,
        )
        .unwrap();
        assert!(read(&out[..n])[0].is_ok());
    }

    #[test]
    fn an_overlong_frame_is_dropped_and_the_next_one_read() {
        let mut stream = vec![1u8; 300];
        stream.push(0);
        stream.extend(frame_of(&Command::Ping, 3));
        let got = read(&stream);
        assert_eq!(got[0], Err(FrameError::Overflow));
        assert_eq!(got[1].as_ref().unwrap().1, Command::Ping);
    }

    #[test]
    fn the_largest_reply_fits_a_frame() {
        use crate::{Batch, MAX_BATCH_BYTES, MAX_FRAME};
        // The board fills a batch up to MAX_BATCH_BYTES of values: the worst is
        // that many bytes of five-byte values, plus one value that takes fewer.
        let mut values = heapless::Vec::new();
        for _ in 0..MAX_BATCH_BYTES / 5 {
            values.push(i32::MIN).unwrap();
        }
        values.push(-(1 << 27)).unwrap();
        let batch = Reply::Record(Batch {
            signals: 127,
            decimation: u16::MAX,
            active: true,
            dropped: u32::MAX,
            waiting: u32::MAX,
            values,
        });
        let (mut scratch, mut out) = ([0u8; MAX_FRAME], [0u8; MAX_FRAME]);
        let h = Header {
            version: VERSION,
            seq: u16::MAX,
        };
        assert!(encode(&h, &batch, &mut scratch, &mut out).is_ok());
    }
}
