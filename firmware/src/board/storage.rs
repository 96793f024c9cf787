//! The stored model: a model image kept in flash across resets, in two slots
//! written alternately and found again at boot.
//!
//! # Layout
//!
//! Each slot is a whole number of erase sectors. It starts with a header, padded
//! to 32 bytes; the image follows at offset 32. All values little-endian:
//!
//! ```text
//! offset  0  magic "PFPS"
//!         4  u32 format version (1)
//!         8  u32 generation (1 for the first image stored, then +1 per store)
//!        12  u32 image length, bytes
//!        16  u32 CRC-32 of the image
//!        20  u32 CRC-32 of the 20 header bytes before it
//!        24  8 bytes 0xFF (padding)
//!        32  the image, padded with 0xFF to the flash's write size
//! ```
//!
//! The image is opaque here: it carries its own header and checksum, which the
//! model loader checks; this module only keeps and returns its bytes. A slot is
//! valid when its magic, version and header CRC check out, its length is between
//! 1 and the slot's capacity and the image's CRC matches. An erased slot (all
//! 0xFF) is not valid. At boot [`ModelFlash::newest`] returns the valid slot with
//! the highest generation.
//!
//! # Power-loss safety and wear
//!
//! [`ModelFlash::store`] writes the slot that does **not** hold the newest valid
//! image: the newest one is never touched, so a reset at any moment of a store
//! leaves it in place. The new slot is erased, its image programmed, and its
//! header programmed last: the header is the commit record. Until it is complete
//! the slot is invalid and the old image is found; once it is complete, so is the
//! image before it. Writing the slots alternately also spreads the erases evenly:
//! `n` stores erase each slot `n / 2` times.
//!
//! # On the board
//!
//! The STM32F405 keeps the slots in sectors 10 and 11 ([`BOARD_SLOTS`]) through
//! the HAL's unlocked flash. Erasing a 128 KiB sector stalls instruction fetch
//! from flash for up to about 2 s, interrupts included, so the firmware stores a
//! model only while the stage is in its safe state, never while it is being
//! controlled. The emulated board (QEMU cannot program flash) and the host tests
//! use [`RamFlash`], a NOR-flash simulator in RAM.

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashError, NorFlashErrorKind,
    ReadNorFlash,
};
use piezo_fpi::model::image::CRC32;

/// The first four bytes of a slot holding an image.
pub const MAGIC: [u8; 4] = *b"PFPS";
/// The slot format this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Offset of the image in its slot (the header, padded).
pub const IMAGE_OFFSET: u32 = 32;

/// Bytes of the padded header.
const HEADER_SPAN: usize = IMAGE_OFFSET as usize;
/// Bytes read at a time (a stack buffer).
const CHUNK: usize = 64;

/// Where the two slots are in the flash device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slots {
    /// Offset of slot A in the flash device.
    pub a: u32,
    /// Offset of slot B in the flash device.
    pub b: u32,
    /// Bytes of each slot: a whole number of erase sectors.
    pub len: u32,
}

impl Slots {
    /// The largest image a slot holds, bytes.
    pub const fn capacity(&self) -> usize {
        self.len.saturating_sub(IMAGE_OFFSET) as usize
    }

    /// The offset of a slot (0 = A, 1 = B).
    const fn base(&self, slot: u8) -> Option<u32> {
        match slot {
            0 => Some(self.a),
            1 => Some(self.b),
            _ => None,
        }
    }
}

/// The board's slots: sectors 10 and 11 of the STM32F405 (128 KiB each), as
/// offsets from the start of flash.
pub const BOARD_SLOTS: Slots = Slots {
    a: 0xC_0000,
    b: 0xE_0000,
    len: 0x2_0000,
};

// The board's slots hold the largest model it can run.
const _: () = assert!(BOARD_SLOTS.capacity() >= crate::board::capacity::IMAGE_BYTES);

/// A valid image found in a slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stored {
    /// The slot: 0 = A, 1 = B.
    pub slot: u8,
    /// The generation: 1 for the first image stored, +1 per store.
    pub generation: u32,
    /// Bytes of the image.
    pub len: u32,
    /// CRC-32 of the image.
    pub crc: u32,
}

/// Why the store refused or failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StorageError {
    /// The flash device reported an error.
    Flash(NorFlashErrorKind),
    /// The image does not fit a slot.
    TooLarge,
    /// The image is empty.
    Empty,
    /// What was read back differs from what was written (or from what the
    /// caller expected to read).
    VerifyFailed,
    /// The output buffer is smaller than the stored image.
    BufferTooSmall,
}

impl StorageError {
    /// Short English text, for the link's refusal reasons and logs.
    pub const fn message(&self) -> &'static str {
        match self {
            Self::Flash(NorFlashErrorKind::NotAligned) => "flash access not aligned",
            Self::Flash(NorFlashErrorKind::OutOfBounds) => "flash access out of bounds",
            Self::Flash(_) => "flash error",
            Self::TooLarge => "model image too large for the flash slot",
            Self::Empty => "empty model image",
            Self::VerifyFailed => "flash read-back does not match",
            Self::BufferTooSmall => "buffer too small for the stored image",
        }
    }
}

impl core::fmt::Display for StorageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.message())
    }
}

fn flash_error<E: NorFlashError>(error: E) -> StorageError {
    StorageError::Flash(error.kind())
}

const OUT_OF_BOUNDS: StorageError = StorageError::Flash(NorFlashErrorKind::OutOfBounds);

/// `base + offset` as a flash offset.
fn at(base: u32, offset: usize) -> Result<u32, StorageError> {
    u32::try_from(offset)
        .ok()
        .and_then(|offset| base.checked_add(offset))
        .ok_or(OUT_OF_BOUNDS)
}

/// The header's first five words: magic, version, generation, length, image CRC.
fn header_words(generation: u32, len: u32, crc: u32) -> [u32; 5] {
    [
        u32::from_le_bytes(MAGIC),
        FORMAT_VERSION,
        generation,
        len,
        crc,
    ]
}

/// CRC-32 of the header's first 20 bytes.
fn header_crc(words: &[u32; 5]) -> u32 {
    let mut digest = CRC32.digest();
    for word in words {
        digest.update(&word.to_le_bytes());
    }
    digest.finalize()
}

/// The padded header of a stored image.
fn encode_header(stored: &Stored) -> [u8; HEADER_SPAN] {
    let words = header_words(stored.generation, stored.len, stored.crc);
    let check = header_crc(&words);
    let mut raw = [0xFF; HEADER_SPAN];
    let all = words.iter().chain(core::iter::once(&check));
    for (dst, word) in raw.chunks_exact_mut(4).zip(all) {
        dst.iter_mut()
            .zip(word.to_le_bytes())
            .for_each(|(d, s)| *d = s);
    }
    raw
}

/// The generation, length and image CRC of a valid header.
fn decode_header(raw: &[u8; HEADER_SPAN], capacity: usize) -> Option<(u32, u32, u32)> {
    let mut words = [0u32; 6];
    for (word, bytes) in words.iter_mut().zip(raw.chunks_exact(4)) {
        *word = u32::from_le_bytes(bytes.try_into().ok()?);
    }
    let [_, _, generation, len, crc, check] = words;
    let expected = header_words(generation, len, crc);
    let fits = len > 0 && usize::try_from(len).is_ok_and(|len| len <= capacity);
    let ok = words.starts_with(&expected) && header_crc(&expected) == check && fits;
    ok.then_some((generation, len, crc))
}

/// A model image in two flash slots, written alternately (see the
/// [module documentation](self)).
#[derive(Debug)]
pub struct ModelFlash<F> {
    flash: F,
    slots: Slots,
}

impl<F: NorFlash> ModelFlash<F> {
    /// The store on `flash`, in `slots`. The flash's read and write sizes must
    /// divide 32 (a compile-time check).
    pub const fn new(flash: F, slots: Slots) -> Self {
        const {
            assert!(
                F::READ_SIZE > 0
                    && F::WRITE_SIZE > 0
                    && HEADER_SPAN.is_multiple_of(F::READ_SIZE)
                    && HEADER_SPAN.is_multiple_of(F::WRITE_SIZE)
            )
        };
        Self { flash, slots }
    }

    /// The flash device.
    pub const fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash device, giving up the store.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// The slots.
    pub const fn slots(&self) -> Slots {
        self.slots
    }

    /// What each slot holds: nothing (erased), an intact image, or something
    /// damaged (a header that is neither erased nor valid, or an image whose CRC
    /// fails).
    pub fn survey(&mut self) -> Result<[Slot; 2], StorageError> {
        Ok([self.slot_state(0)?, self.slot_state(1)?])
    }

    fn slot_state(&mut self, slot: u8) -> Result<Slot, StorageError> {
        let mut raw = [0; HEADER_SPAN];
        self.flash
            .read(self.slot_base(slot)?, &mut raw)
            .map_err(flash_error)?;
        if raw.iter().all(|b| *b == 0xFF) {
            return Ok(Slot::Empty);
        }
        Ok(match self.scan(slot)? {
            Some(s) => Slot::Holds(s),
            None => Slot::Damaged,
        })
    }

    /// Clears the first word of the image `stored` describes, from `offset` bytes
    /// into it (wrapped to its length), that holds a set bit: a deliberately damaged
    /// model, for fault-injection tests of the start-up check. Programming can only
    /// clear bits, as on the real flash. An image of zeros only cannot be damaged.
    pub fn damage(&mut self, stored: &Stored, offset: u32) -> Result<(), StorageError> {
        let base = self.image_base(stored.slot)?;
        let (len, word) = (stored.len.max(1), F::WRITE_SIZE.max(F::READ_SIZE) as u32);
        let mut raw = [0u8; HEADER_SPAN];
        let w = raw.get_mut(..word as usize).ok_or(OUT_OF_BOUNDS)?;
        for k in 0..len.div_ceil(word) {
            let at = base + (offset + k * word) % len;
            let aligned = at - at % word;
            self.flash.read(aligned, w).map_err(flash_error)?;
            if w.iter().any(|&b| b != 0) {
                w.iter_mut().for_each(|b| *b = 0);
                // Programming over programmed bits may be reported as an error (the
                // simulated flash does); the bits are cleared either way.
                let _ = self.flash.write(aligned, w);
                return Ok(());
            }
        }
        Ok(())
    }

    /// The valid image with the highest generation, if any slot holds one.
    pub fn newest(&mut self) -> Result<Option<Stored>, StorageError> {
        let a = self.scan(0)?;
        let b = self.scan(1)?;
        Ok(match (a, b) {
            (Some(a), Some(b)) if b.generation > a.generation => Some(b),
            (Some(a), _) => Some(a),
            (None, b) => b,
        })
    }

    /// Copies the image `stored` describes into the start of `out` and returns
    /// its length, after checking that the slot still holds it (header and CRC).
    pub fn read(&mut self, stored: &Stored, out: &mut [u8]) -> Result<usize, StorageError> {
        let len = usize::try_from(stored.len).map_err(|_| StorageError::BufferTooSmall)?;
        let out = out.get_mut(..len).ok_or(StorageError::BufferTooSmall)?;
        if self.scan_header(stored.slot)? != Some(*stored) {
            return Err(StorageError::VerifyFailed);
        }
        let base = self.image_base(stored.slot)?;
        let mut digest = CRC32.digest();
        self.visit(base, len, |offset, bytes| {
            digest.update(bytes);
            if let Some(dst) = out.get_mut(offset..) {
                dst.iter_mut().zip(bytes).for_each(|(d, s)| *d = *s);
            }
        })?;
        if digest.finalize() != stored.crc {
            return Err(StorageError::VerifyFailed);
        }
        Ok(len)
    }

    /// Stores `image` as the newest, in the slot not holding the current newest:
    /// erases that slot, programs the image, programs the header last, then reads
    /// it all back. Refuses an empty image or one larger than a slot's capacity.
    pub fn store(&mut self, image: &[u8]) -> Result<Stored, StorageError> {
        let len = self.check_size(image)?;
        let newest = self.newest()?;
        let stored = Stored {
            slot: match newest {
                Some(Stored { slot: 0, .. }) => 1,
                _ => 0,
            },
            generation: newest.map_or(1, |n| n.generation.saturating_add(1)),
            len,
            crc: CRC32.checksum(image),
        };
        self.erase_slot(stored.slot)?;
        let base = self.image_base(stored.slot)?;
        self.program(base, image)?;
        self.program(self.slot_base(stored.slot)?, &encode_header(&stored))?;
        self.verify(&stored, image)?;
        Ok(stored)
    }

    /// Erases both slots (factory reset): no image is stored afterwards.
    pub fn erase_all(&mut self) -> Result<(), StorageError> {
        self.erase_slot(0)?;
        self.erase_slot(1)
    }

    /// The image's length, if it is not empty and fits a slot.
    fn check_size(&self, image: &[u8]) -> Result<u32, StorageError> {
        if image.is_empty() {
            return Err(StorageError::Empty);
        }
        if image.len() > self.slots.capacity() {
            return Err(StorageError::TooLarge);
        }
        u32::try_from(image.len()).map_err(|_| StorageError::TooLarge)
    }

    fn slot_base(&self, slot: u8) -> Result<u32, StorageError> {
        self.slots.base(slot).ok_or(StorageError::VerifyFailed)
    }

    fn image_base(&self, slot: u8) -> Result<u32, StorageError> {
        at(self.slot_base(slot)?, HEADER_SPAN)
    }

    /// The image in `slot`, if the slot is valid.
    fn scan(&mut self, slot: u8) -> Result<Option<Stored>, StorageError> {
        let Some(stored) = self.scan_header(slot)? else {
            return Ok(None);
        };
        let base = self.image_base(slot)?;
        let mut digest = CRC32.digest();
        self.visit(base, stored.len as usize, |_, bytes| digest.update(bytes))?;
        Ok((digest.finalize() == stored.crc).then_some(stored))
    }

    /// What the header of `slot` says, if it is valid (the image unchecked).
    fn scan_header(&mut self, slot: u8) -> Result<Option<Stored>, StorageError> {
        let mut raw = [0; HEADER_SPAN];
        self.flash
            .read(self.slot_base(slot)?, &mut raw)
            .map_err(flash_error)?;
        let header = decode_header(&raw, self.slots.capacity());
        Ok(header.map(|(generation, len, crc)| Stored {
            slot,
            generation,
            len,
            crc,
        }))
    }

    /// Reads `len` bytes from `start` in chunks, handing each to `visit` with its
    /// offset from `start`. Reads are padded to the flash's read size.
    fn visit(
        &mut self,
        start: u32,
        len: usize,
        mut visit: impl FnMut(usize, &[u8]),
    ) -> Result<(), StorageError> {
        let mut buf = [0; CHUNK];
        let mut done = 0;
        while done < len {
            let n = (len - done).min(CHUNK);
            let padded = n.next_multiple_of(F::READ_SIZE);
            let chunk = buf.get_mut(..padded).ok_or(OUT_OF_BOUNDS)?;
            self.flash
                .read(at(start, done)?, chunk)
                .map_err(flash_error)?;
            visit(done, chunk.get(..n).ok_or(OUT_OF_BOUNDS)?);
            done += n;
        }
        Ok(())
    }

    /// Programs `data` at `start`, the last write padded with 0xFF to the
    /// flash's write size.
    fn program(&mut self, start: u32, data: &[u8]) -> Result<(), StorageError> {
        let whole = data.len() - data.len() % F::WRITE_SIZE;
        let (body, tail) = data.split_at_checked(whole).ok_or(OUT_OF_BOUNDS)?;
        if !body.is_empty() {
            self.flash.write(start, body).map_err(flash_error)?;
        }
        if !tail.is_empty() {
            let mut last = [0xFF; HEADER_SPAN];
            last.iter_mut().zip(tail).for_each(|(d, s)| *d = *s);
            let last = last.get(..F::WRITE_SIZE).ok_or(OUT_OF_BOUNDS)?;
            self.flash
                .write(at(start, whole)?, last)
                .map_err(flash_error)?;
        }
        Ok(())
    }

    fn erase_slot(&mut self, slot: u8) -> Result<(), StorageError> {
        let from = self.slot_base(slot)?;
        let to = from.checked_add(self.slots.len).ok_or(OUT_OF_BOUNDS)?;
        self.flash.erase(from, to).map_err(flash_error)
    }

    /// Reads back the slot just written: its header must say `stored` and its
    /// bytes must be `image`.
    fn verify(&mut self, stored: &Stored, image: &[u8]) -> Result<(), StorageError> {
        if self.scan_header(stored.slot)? != Some(*stored) {
            return Err(StorageError::VerifyFailed);
        }
        let base = self.image_base(stored.slot)?;
        let mut same = true;
        self.visit(base, image.len(), |offset, bytes| {
            same &= image.get(offset..offset + bytes.len()) == Some(bytes);
        })?;
        if same {
            Ok(())
        } else {
            Err(StorageError::VerifyFailed)
        }
    }
}

/// What a slot holds ([`ModelFlash::survey`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    /// Erased.
    Empty,
    /// An intact image.
    Holds(Stored),
    /// Neither erased nor an intact image.
    Damaged,
}

/// Sectors a [`RamFlash`] may have (its erase counters).
pub const RAM_FLASH_MAX_SECTORS: usize = 32;

/// A NOR flash in RAM, for the emulated board and the tests: `N` bytes in
/// sectors of `SECTOR` bytes, reading and programming single bytes.
///
/// It behaves as real NOR flash does: it starts erased (all 0xFF), erases whole
/// sectors only, and programming can only clear bits. Programming a byte that is
/// not erased stores `old & new`, as the real flash would, and reports
/// [`NorFlashErrorKind::Other`]. It counts erases per sector and bytes
/// programmed, and can simulate a reset in the middle of a write
/// ([`RamFlash::fail_after`]).
#[derive(Clone)]
pub struct RamFlash<const N: usize, const SECTOR: usize> {
    data: [u8; N],
    erases: [u32; RAM_FLASH_MAX_SECTORS],
    written: u32,
    budget: Option<u32>,
}

impl<const N: usize, const SECTOR: usize> RamFlash<N, SECTOR> {
    /// An erased flash. `N` must be a whole number of sectors, at most
    /// [`RAM_FLASH_MAX_SECTORS`] of them (a compile-time check).
    pub const fn new() -> Self {
        const {
            assert!(
                SECTOR > 0
                    && N.is_multiple_of(SECTOR)
                    && N / SECTOR <= RAM_FLASH_MAX_SECTORS
                    && N <= u32::MAX as usize
            )
        };
        Self {
            data: [0xFF; N],
            erases: [0; RAM_FLASH_MAX_SECTORS],
            written: 0,
            budget: None,
        }
    }

    /// The flash's contents.
    pub const fn as_bytes(&self) -> &[u8] {
        &self.data
    }

    /// Takes `bytes` as the flash's content (the rest stays as it is): what a
    /// real flash kept across a power cycle, for the emulated board, whose flash
    /// is seeded from a file the host gives QEMU.
    pub fn load(&mut self, bytes: &[u8]) {
        self.data.iter_mut().zip(bytes).for_each(|(d, s)| *d = *s);
    }

    /// Times sector `sector` (counted from 0) has been erased.
    pub fn erase_count(&self, sector: usize) -> u32 {
        self.erases.get(sector).copied().unwrap_or(0)
    }

    /// Bytes programmed since the flash was made.
    pub const fn bytes_written(&self) -> u32 {
        self.written
    }

    /// Simulates a reset in the middle of programming: after `bytes` more bytes
    /// have been programmed, further bytes are not programmed and every write
    /// that reaches them returns [`NorFlashErrorKind::Other`]. `None` programs
    /// normally. Erasing and reading are not affected.
    pub fn fail_after(&mut self, bytes: Option<u32>) {
        self.budget = bytes;
    }

    /// Ends the simulated reset: programming works again.
    pub fn power_cycle(&mut self) {
        self.budget = None;
    }
}

impl<const N: usize, const SECTOR: usize> Default for RamFlash<N, SECTOR> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const SECTOR: usize> ErrorType for RamFlash<N, SECTOR> {
    type Error = NorFlashErrorKind;
}

impl<const N: usize, const SECTOR: usize> ReadNorFlash for RamFlash<N, SECTOR> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_read(self, offset, bytes.len())?;
        let start = offset as usize;
        let src = self
            .data
            .get(start..start + bytes.len())
            .ok_or(NorFlashErrorKind::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize, const SECTOR: usize> NorFlash for RamFlash<N, SECTOR> {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(self, from, to)?;
        let (from, to) = (from as usize, to as usize);
        self.data
            .get_mut(from..to)
            .ok_or(NorFlashErrorKind::OutOfBounds)?
            .fill(0xFF);
        for count in self.erases.iter_mut().take(to / SECTOR).skip(from / SECTOR) {
            *count = count.saturating_add(1);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_write(self, offset, bytes.len())?;
        let start = offset as usize;
        let cells = self
            .data
            .get_mut(start..start + bytes.len())
            .ok_or(NorFlashErrorKind::OutOfBounds)?;
        let mut result = Ok(());
        for (cell, byte) in cells.iter_mut().zip(bytes) {
            match &mut self.budget {
                Some(0) => return Err(NorFlashErrorKind::Other),
                Some(left) => *left -= 1,
                None => {}
            }
            if *cell != 0xFF {
                result = Err(NorFlashErrorKind::Other);
            }
            *cell &= byte;
            self.written = self.written.saturating_add(1);
        }
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SECTOR: usize = 4096;
    /// Two sectors, one slot each.
    type Flash = RamFlash<{ 2 * SECTOR }, SECTOR>;
    const SLOTS: Slots = Slots {
        a: 0,
        b: SECTOR as u32,
        len: SECTOR as u32,
    };

    // Usable in a static (the emulated board keeps one in an RTIC local).
    static _ERASED: Flash = RamFlash::new();

    /// Deterministic pseudo-random bytes.
    fn image(seed: u32, len: usize) -> Vec<u8> {
        let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        (0..len)
            .map(|_| {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (x >> 24) as u8
            })
            .collect()
    }

    fn read_back<F: NorFlash>(store: &mut ModelFlash<F>, stored: &Stored) -> Vec<u8> {
        let mut out = vec![0; SECTOR];
        let n = store.read(stored, &mut out).unwrap();
        out.truncate(n);
        out
    }

    /// The newest image and its bytes, on a freshly opened store.
    fn reopen(flash: &mut Flash) -> Option<(u32, Vec<u8>)> {
        let mut store = ModelFlash::new(flash, SLOTS);
        let stored = store.newest().unwrap()?;
        Some((stored.generation, read_back(&mut store, &stored)))
    }

    #[test]
    fn storage_empty_flash_then_first_store() {
        let mut store = ModelFlash::new(Flash::new(), SLOTS);
        assert_eq!(store.newest(), Ok(None));
        let img = image(1, 700);
        let stored = store.store(&img).unwrap();
        let expected = Stored {
            slot: 0,
            generation: 1,
            len: 700,
            crc: CRC32.checksum(&img),
        };
        assert_eq!(stored, expected);
        assert_eq!(store.newest(), Ok(Some(expected)));
        assert_eq!(read_back(&mut store, &stored), img);
        let raw = store.flash().as_bytes();
        assert_eq!(&raw[..4], b"PFPS");
        assert_eq!(raw[4..8], 1u32.to_le_bytes());
        assert_eq!(raw[24..32], [0xFF; 8]);
        assert_eq!(&raw[32..732], &img[..]);
        assert!(raw[732..].iter().all(|&b| b == 0xFF));
        assert_eq!(store.flash().erase_count(0), 1);
        assert_eq!(store.flash().erase_count(1), 0);
        assert_eq!(store.flash().bytes_written(), 700 + 32);
    }

    #[test]
    fn storage_alternates_slots_and_levels_wear() {
        let mut store = ModelFlash::new(Flash::new(), SLOTS);
        let mut last = Vec::new();
        for n in 1..=100u32 {
            last = image(n, 200 + 29 * n as usize);
            let stored = store.store(&last).unwrap();
            assert_eq!(stored.generation, n);
            assert_eq!(stored.slot, ((n - 1) % 2) as u8);
            assert_eq!(store.newest(), Ok(Some(stored)));
        }
        assert_eq!(store.flash().erase_count(0), 50);
        assert_eq!(store.flash().erase_count(1), 50);
        let mut flash = store.into_inner();
        assert_eq!(reopen(&mut flash), Some((100, last)));
    }

    /// Power loss after every byte count of one store on `base`: a fresh store
    /// finds the old newest image (or none) or the new one, whole.
    fn power_loss_sweep(base: &Flash, new: &[u8]) {
        let old = reopen(&mut base.clone());
        let generation = old.as_ref().map_or(1, |(g, _)| g + 1);
        let total = u32::try_from(new.len()).unwrap() + IMAGE_OFFSET;
        let header_done = total - 8; // the padding writes nothing new
        for k in 0..=total {
            let mut flash = base.clone();
            flash.fail_after(Some(k));
            let result = ModelFlash::new(&mut flash, SLOTS).store(new);
            flash.power_cycle();
            let found = reopen(&mut flash);
            if k == total {
                assert!(result.is_ok(), "k = {k}");
            } else {
                assert_eq!(result, Err(StorageError::Flash(NorFlashErrorKind::Other)));
            }
            if k < header_done {
                assert_eq!(found, old, "k = {k}: the old image must survive");
            } else {
                assert_eq!(found, Some((generation, new.to_vec())), "k = {k}");
            }
        }
    }

    #[test]
    fn storage_power_loss_at_every_byte() {
        let mut base = Flash::new();
        power_loss_sweep(&base, &image(10, 1000));
        {
            let mut store = ModelFlash::new(&mut base, SLOTS);
            store.store(&image(11, 900)).unwrap();
            store.store(&image(12, 1300)).unwrap();
        }
        // Generation 1 in A, 2 in B: the store erases A and writes generation 3.
        power_loss_sweep(&base, &image(13, 1111));
    }

    #[test]
    fn storage_flipped_bit_falls_back_to_older_slot() {
        let (old, new) = (image(20, 600), image(21, 500));
        let mut base = Flash::new();
        {
            let mut store = ModelFlash::new(&mut base, SLOTS);
            store.store(&old).unwrap();
            store.store(&new).unwrap();
        }
        let b = SECTOR;
        // Every bit of the header's 24 meaningful bytes, and one bit per image byte.
        let header = (0..24 * 8).map(|bit| (b + bit / 8, bit % 8));
        let body = (0..new.len()).map(|i| (b + 32 + i, i % 8));
        for (byte, bit) in header.chain(body) {
            let mut flash = base.clone();
            flash.data[byte] ^= 1 << bit;
            assert_eq!(reopen(&mut flash), Some((1, old.clone())), "byte {byte}");
        }
        // The next store overwrites the corrupt slot and keeps the old one.
        let mut flash = base.clone();
        flash.data[b + 32 + 100] ^= 0x10;
        let mut store = ModelFlash::new(&mut flash, SLOTS);
        let stored = store.store(&image(22, 800)).unwrap();
        assert_eq!((stored.slot, stored.generation), (1, 2));
        let a = store.flash().as_bytes()[32..632].to_vec();
        assert_eq!(a, old);
    }

    #[test]
    fn storage_read_checks_buffer_and_slot() {
        let mut store = ModelFlash::new(Flash::new(), SLOTS);
        let stored = store.store(&image(30, 300)).unwrap();
        let mut small = [0; 299];
        assert_eq!(
            store.read(&stored, &mut small),
            Err(StorageError::BufferTooSmall)
        );
        let stale = Stored {
            generation: 7,
            ..stored
        };
        let mut out = [0; 300];
        assert_eq!(
            store.read(&stale, &mut out),
            Err(StorageError::VerifyFailed)
        );
        let mut flash = store.into_inner();
        flash.data[32 + 5] ^= 1;
        let mut store = ModelFlash::new(flash, SLOTS);
        assert_eq!(
            store.read(&stored, &mut out),
            Err(StorageError::VerifyFailed)
        );
        assert_eq!(store.newest(), Ok(None));
    }

    #[test]
    fn storage_refuses_empty_and_too_large_images() {
        let mut store = ModelFlash::new(Flash::new(), SLOTS);
        assert_eq!(SLOTS.capacity(), SECTOR - 32);
        assert_eq!(store.store(&[]), Err(StorageError::Empty));
        let too_large = image(40, SECTOR - 31);
        assert_eq!(store.store(&too_large), Err(StorageError::TooLarge));
        assert_eq!(store.flash().bytes_written(), 0);
        assert_eq!(store.flash().erase_count(0), 0);
        let full = image(41, SECTOR - 32);
        let stored = store.store(&full).unwrap();
        assert_eq!(read_back(&mut store, &stored), full);
        assert_eq!(
            StorageError::TooLarge.message(),
            StorageError::TooLarge.to_string()
        );
    }

    #[test]
    fn storage_erase_all_forgets_everything() {
        let mut store = ModelFlash::new(Flash::new(), SLOTS);
        store.store(&image(50, 100)).unwrap();
        store.store(&image(51, 100)).unwrap();
        store.erase_all().unwrap();
        assert_eq!(store.newest(), Ok(None));
        assert!(store.flash().as_bytes().iter().all(|&b| b == 0xFF));
        let stored = store.store(&image(52, 100)).unwrap();
        assert_eq!((stored.slot, stored.generation), (0, 1));
    }

    #[test]
    fn storage_ram_flash_behaves_as_nor_flash() {
        let mut flash = Flash::new();
        assert_eq!(flash.erase(1, 4097), Err(NorFlashErrorKind::NotAligned));
        assert_eq!(
            flash.erase(0, 3 * 4096),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(flash.erase(4096, 0), Err(NorFlashErrorKind::OutOfBounds));
        assert_eq!(
            flash.write(8190, &[0; 3]),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(
            flash.read(8190, &mut [0; 3]),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        flash.write(10, &[0xF0, 0x0F]).unwrap();
        // Programming bytes that are not erased is reported; the bits only clear.
        assert_eq!(flash.write(10, &[0x3C]), Err(NorFlashErrorKind::Other));
        let mut got = [0; 3];
        flash.read(10, &mut got).unwrap();
        assert_eq!(got, [0x30, 0x0F, 0xFF]);
        assert_eq!(flash.bytes_written(), 3);
        flash.erase(0, 8192).unwrap();
        assert_eq!((flash.erase_count(0), flash.erase_count(1)), (1, 1));
        assert!(flash.as_bytes().iter().all(|&b| b == 0xFF));
        // A reset after 2 bytes: the rest is not programmed.
        flash.fail_after(Some(2));
        assert_eq!(flash.write(0, &[1, 2, 3]), Err(NorFlashErrorKind::Other));
        assert_eq!(flash.write(3, &[4]), Err(NorFlashErrorKind::Other));
        assert_eq!(flash.as_bytes()[..4], [1, 2, 0xFF, 0xFF]);
        flash.power_cycle();
        flash.write(2, &[3]).unwrap();
        assert_eq!(flash.as_bytes()[..4], [1, 2, 3, 0xFF]);
    }

    /// A flash with 4-byte reads and 8-byte writes, checking alignment.
    struct Wide(Flash);

    impl ErrorType for Wide {
        type Error = NorFlashErrorKind;
    }

    impl ReadNorFlash for Wide {
        const READ_SIZE: usize = 4;
        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            check_read(self, offset, bytes.len())?;
            self.0.read(offset, bytes)
        }
        fn capacity(&self) -> usize {
            self.0.capacity()
        }
    }

    impl NorFlash for Wide {
        const WRITE_SIZE: usize = 8;
        const ERASE_SIZE: usize = SECTOR;
        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            self.0.erase(from, to)
        }
        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            check_write(self, offset, bytes.len())?;
            self.0.write(offset, bytes)
        }
    }

    #[test]
    fn storage_pads_to_read_and_write_sizes() {
        let mut store = ModelFlash::new(Wide(Flash::new()), SLOTS);
        for (n, len) in [1, 7, 8, 9, 63, 65, 1001, SECTOR - 32]
            .into_iter()
            .enumerate()
        {
            let img = image(60 + n as u32, len);
            let stored = store.store(&img).unwrap();
            assert_eq!(read_back(&mut store, &stored), img, "len {len}");
            let base = SLOTS.base(stored.slot).unwrap() as usize + 32;
            let raw = store.flash().0.as_bytes();
            assert!(raw[base + len..base + SECTOR - 32]
                .iter()
                .all(|&b| b == 0xFF));
        }
    }

    #[test]
    fn storage_board_slots_are_sectors_10_and_11() {
        assert_eq!(BOARD_SLOTS.a, 0x000C_0000);
        assert_eq!(BOARD_SLOTS.b, BOARD_SLOTS.a + BOARD_SLOTS.len);
        assert_eq!(BOARD_SLOTS.len, 128 * 1024);
        assert!(BOARD_SLOTS.capacity() >= crate::board::capacity::IMAGE_BYTES);
    }
}
