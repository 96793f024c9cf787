//! The link task's model upload buffer: the image arrives in chunks, in order, and
//! is complete when all its bytes are in and match its CRC. The command handler
//! ([`super::handler`]) then checks it further (the validator, the board's
//! capacity and hardware limits), writes it to flash if asked and hands it to the
//! control ISR between two ticks — only with the stage parked. On any failure the
//! running model stays.

use piezo_fpi::model::image::CRC32;

use super::protocol::Refusal;
use super::refusal::{refuse, Refuse};
use crate::board::capacity::IMAGE_BYTES;

/// A model being received.
pub(super) struct Upload {
    pub(super) image: &'static mut [u8; IMAGE_BYTES],
    pub(super) expected: Option<(usize, u32)>,
    pub(super) received: usize,
}

impl Upload {
    /// An image of `len` bytes whose CRC is `crc` begins.
    pub(super) fn begin(&mut self, len: u32, crc: u32) -> Result<(), Refuse> {
        if len == 0 || len as usize > IMAGE_BYTES {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("image of {len} bytes: this board takes 1–{IMAGE_BYTES}"),
            ));
        }
        self.expected = Some((len as usize, crc));
        self.received = 0;
        Ok(())
    }

    /// The image's bytes from `offset` on.
    pub(super) fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), Refuse> {
        let Some((len, _)) = self.expected else {
            return Err(refuse(Refusal::Upload, format_args!("no upload begun")));
        };
        if offset as usize != self.received {
            return Err(refuse(
                Refusal::Upload,
                format_args!("bytes from {offset} sent, from {} expected", self.received),
            ));
        }
        let end = self.received + data.len();
        match self.image.get_mut(self.received..end) {
            Some(dst) if end <= len => dst.copy_from_slice(data),
            _ => {
                return Err(refuse(
                    Refusal::Upload,
                    format_args!("bytes up to {end} sent, the image has {len}"),
                ))
            }
        }
        self.received = end;
        Ok(())
    }

    /// The image's length, once all its bytes are in and match its CRC.
    pub(super) fn complete(&self) -> Result<usize, Refuse> {
        let Some((len, crc)) = self.expected else {
            return Err(refuse(Refusal::Upload, format_args!("no upload begun")));
        };
        if self.received != len {
            return Err(refuse(
                Refusal::Upload,
                format_args!("{} of {len} bytes received", self.received),
            ));
        }
        let image = self.image.get(..len).unwrap_or(&[]);
        if CRC32.checksum(image) != crc {
            return Err(refuse(
                Refusal::Model,
                format_args!("the received image does not match its CRC"),
            ));
        }
        Ok(len)
    }

    /// Copies `image` (the factory image) into the buffer, in place of any
    /// upload; returns the bytes copied.
    pub(super) fn hold(&mut self, image: &[u8]) -> usize {
        let n = image.len().min(IMAGE_BYTES);
        if let (Some(dst), Some(src)) = (self.image.get_mut(..n), image.get(..n)) {
            dst.copy_from_slice(src);
        }
        self.expected = None;
        n
    }

    /// The upload is over (its image taken, or replaced).
    pub(super) fn done(&mut self) {
        self.expected = None;
    }
}
