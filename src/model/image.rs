//! The model image: a whole model as bytes — what the board keeps in flash (the
//! factory default and the stored model) and receives over its link.
//!
//! Little-endian, every value in the core's raw format:
//!
//! ```text
//! header (16 bytes)  magic "PFPM", u16 version, u16 flags, u32 body length, u32 CRC-32 of the body
//!                    flags: bit 0 soft dead zone, bit 1 output saturation, bit 2 predicted force,
//!                    bit 3 position feedback, bit 4 reference shaping, bit 5 stage dynamics,
//!                    bit 6 active damping, bit 7 reference preview, bit 8 lead baseline,
//!                    bit 9 watch swing
//! body               u32 rate_hz; i32 w0 (I4F28); i32 input_max (I16F16); u8 operators; u8 creep terms; u16 0
//!                    operators × (i32 threshold I16F16, i32 weight I4F28)
//!                    coupling: i32 k0, k_f (I0F32), k_q (I0F32), F_q, compliance (I0F32), F_ref
//!                    creep terms × (i32 rate I0F32, i32 gain I4F28)
//!                    limits: i32 u_min, u_max, max_step (I16F16)
//!                    supervision: i32 reference lo, hi, force lo, hi, force tolerance, safe voltage (I16F16),
//!                    force split rate (I0F32), dynamic force limit (I16F16)
//!                    tables f_F, f_K, f_K⁻¹, then the dead zone's map and inverse, then the saturation's
//!                    (when flagged): i32 x0, u32 shift, u32 knots, knots × i32 value (I16F16)
//!                    feedback (when flagged): i32 kp, ki (I8F24), limit, position lo, hi, tolerance (I16F16)
//!                    shaping (when flagged): 2 sections × i32 b0, b1, b2, a1, a2 (I8F24)
//!                    dynamics (when flagged): u32 mode mHz, i32 damping ratio (I0F32), u32 lag mHz,
//!                    i32 force gain (I16F16, N/µm)
//!                    damping (when flagged): i32 gain (I8F24), high-pass and leak rates (I0F32), limit (I16F16)
//!                    preview (when flagged, with shaping): u32 ticks the shaping runs ahead, 8 × i32 taps (I8F24)
//!                    lead baseline (when flagged): i32 α_b (I2F30, `crate::lead`)
//!                    watch swing (when flagged): i32 the oscillation watch's half swing (I16F16, µm)
//! ```
//!
//! [`encode`] writes a [`ModelSpec`]; [`Reader`] walks an image for
//! [`super::store::ModelStore::load`], which then runs the validator. A corrupt,
//! truncated or foreign image is refused before any value is used
//! ([`ModelError::NotAModelImage`], [`ModelError::UnsupportedVersion`],
//! [`ModelError::ChecksumMismatch`], [`ModelError::Truncated`]).

use crc::{Crc, CRC_32_ISO_HDLC};

pub use crate::fields::{
    FLAG_DAMPING, FLAG_DEAD_ZONE, FLAG_DYNAMICS, FLAG_FEEDBACK, FLAG_LEAD, FLAG_PREDICTED,
    FLAG_PREVIEW, FLAG_SATURATION, FLAG_SHAPING, FLAG_WATCH,
};

use super::{MapSpec, ModelSpec, TableSpec};
use crate::biquad::SHAPING_SECTIONS;
use crate::control::ForceSource;
use crate::error::{Field, Invalid, ModelError};

/// The first four bytes of every model image.
pub const MAGIC: [u8; 4] = *b"PFPM";
/// The image format this build reads and writes (2: the force channel, the stage
/// dynamics and damping blocks, `I8F24` shaping coefficients; 3: sixteen taps
/// on the preview's delay line, not eight).
pub const VERSION: u16 = 3;
/// Bytes before the body.
pub const HEADER_LEN: usize = 16;

/// Bytes of the lead block.
const LEAD_LEN: usize = 4;
/// Bytes of the watch block.
const WATCH_LEN: usize = 4;
/// Bytes of the preview block.
const PREVIEW_LEN: usize = 4 + 4 * crate::preview::TAPS;
/// Bytes of the dynamics block.
const DYNAMICS_LEN: usize = 16;
/// Bytes of the damping block.
const DAMPING_LEN: usize = 16;
/// Bytes of the shaping block.
const SHAPING_LEN: usize = 4 * 5 * SHAPING_SECTIONS;
/// Bytes of the feedback block.
const FEEDBACK_LEN: usize = 24;

/// The checksum of images and of the link's frames: CRC-32 (ISO-HDLC, as zlib's).
pub const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

fn truncated() -> Invalid {
    Invalid::at(Field::Model, ModelError::Truncated)
}

/// Writes values one after the other into a buffer.
struct Writer<'b> {
    out: &'b mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) -> Result<(), Invalid> {
        let end = self.at + b.len();
        let dst = self.out.get_mut(self.at..end).ok_or_else(truncated)?;
        dst.copy_from_slice(b);
        self.at = end;
        Ok(())
    }
    fn u32(&mut self, v: u32) -> Result<(), Invalid> {
        self.bytes(&v.to_le_bytes())
    }
    fn i32(&mut self, v: i32) -> Result<(), Invalid> {
        self.bytes(&v.to_le_bytes())
    }
    fn table(&mut self, t: &TableSpec<'_>) -> Result<(), Invalid> {
        self.i32(t.x0.to_bits())?;
        self.u32(t.shift)?;
        // Knots: each interval's start, then the last interval's end.
        self.u32(t.segments.len() as u32 + 1)?;
        for s in t.segments {
            self.i32(s.start().to_bits())?;
        }
        let end = t
            .segments
            .last()
            .map_or(0, |s| s.start().to_bits().wrapping_add(s.rise().to_bits()));
        self.i32(end)
    }
}

/// Bytes of an image without its tables' values: header, scalars, operators,
/// coupling, creep terms, limits, supervision.
const fn fixed_len(operators: usize, creep: usize) -> usize {
    HEADER_LEN + 16 + 8 * operators + 24 + 8 * creep + 12 + 32
}

/// Bytes per table besides its values (x0, shift, knot count).
const TABLE_HEAD: usize = 12;

/// Bytes an image of `m` takes.
pub fn encoded_len(m: &ModelSpec<'_>) -> usize {
    let table = |t: &TableSpec<'_>| TABLE_HEAD + 4 * (t.segments.len() + 1);
    let map = |m: &Option<MapSpec<'_>>| {
        m.as_ref()
            .map_or(0, |m| table(&m.forward) + table(&m.inverse))
    };
    fixed_len(m.operators.len(), m.creep.len())
        + table(&m.f_f)
        + table(&m.f_k)
        + table(&m.f_k_inv)
        + map(&m.dead_zone)
        + map(&m.saturation)
        + if m.feedback.is_some() {
            FEEDBACK_LEN
        } else {
            0
        }
        + if m.shaping.is_some() { SHAPING_LEN } else { 0 }
        + if m.dynamics.is_some() {
            DYNAMICS_LEN
        } else {
            0
        }
        + if m.damping.is_some() { DAMPING_LEN } else { 0 }
        + if previews(m) { PREVIEW_LEN } else { 0 }
        + if m.lead_baseline.is_some() {
            LEAD_LEN
        } else {
            0
        }
        + if m.watch_swing.is_some() {
            WATCH_LEN
        } else {
            0
        }
}

/// Whether `m`'s shaping runs ahead of the reference (the image's preview block).
fn previews(m: &ModelSpec<'_>) -> bool {
    matches!(&m.shaping, Some(s) if s.preview > 0)
}

/// Bytes of the largest image a board with room for `operators`, `creep` terms and
/// `intervals` table intervals (all seven tables together) can hold.
pub const fn max_len(operators: usize, creep: usize, intervals: usize) -> usize {
    fixed_len(operators, creep)
        + 7 * TABLE_HEAD
        + 4 * (intervals + 7)
        + FEEDBACK_LEN
        + SHAPING_LEN
        + DYNAMICS_LEN
        + DAMPING_LEN
        + PREVIEW_LEN
        + LEAD_LEN
        + WATCH_LEN
}

/// Writes the image of a model into `out`; its length. The model should be valid
/// ([`super::validate`]): the image carries what it is given.
pub fn encode(m: &ModelSpec<'_>, out: &mut [u8]) -> Result<usize, Invalid> {
    if m.operators.len() > u8::MAX as usize || m.creep.len() > u8::MAX as usize {
        return Err(Invalid::at(Field::Model, ModelError::OverCapacity));
    }
    let mut w = Writer {
        out,
        at: HEADER_LEN,
    };
    w.u32(m.rate_hz)?;
    w.i32(m.w0.to_bits())?;
    w.i32(m.input_max.to_bits())?;
    w.bytes(&[m.operators.len() as u8, m.creep.len() as u8, 0, 0])?;
    for o in m.operators {
        w.i32(o.threshold.to_bits())?;
        w.i32(o.weight.to_bits())?;
    }
    let c = &m.coupling;
    for v in [c.offset.to_bits(), c.k_f.to_bits(), c.k_q.to_bits()] {
        w.i32(v)?;
    }
    for v in [
        c.force_q.to_bits(),
        c.compliance.to_bits(),
        c.force_ref.to_bits(),
    ] {
        w.i32(v)?;
    }
    for t in m.creep {
        w.i32(t.rate.to_bits())?;
        w.i32(t.gain.to_bits())?;
    }
    for v in [m.u_min, m.u_max, m.max_step] {
        w.i32(v.to_bits())?;
    }
    let s = &m.supervision;
    for v in [s.reference.lo, s.reference.hi] {
        w.i32(v.to_bits())?;
    }
    for v in [s.force.lo, s.force.hi] {
        w.i32(v.to_bits())?;
    }
    w.i32(s.force_tolerance.to_bits())?;
    w.i32(s.safe_voltage.to_bits())?;
    w.i32(s.channel.split.to_bits())?;
    w.i32(s.channel.dynamic_limit.to_bits())?;
    for t in [&m.f_f, &m.f_k, &m.f_k_inv] {
        w.table(t)?;
    }
    for map in [&m.dead_zone, &m.saturation].into_iter().flatten() {
        w.table(&map.forward)?;
        w.table(&map.inverse)?;
    }
    if let Some(f) = &m.feedback {
        w.i32(f.kp.to_bits())?;
        w.i32(f.ki.to_bits())?;
        for v in [f.limit, f.sensor.lo, f.sensor.hi, f.tolerance] {
            w.i32(v.to_bits())?;
        }
    }
    if let Some(s) = &m.shaping {
        for c in s.sections.iter().flatten() {
            w.i32(*c)?;
        }
    }
    if let Some(d) = &m.dynamics {
        w.u32(d.mode_mhz)?;
        w.i32(d.damping.to_bits())?;
        w.u32(d.lag_mhz)?;
        w.i32(d.force_gain.to_bits())?;
    }
    if let Some(d) = &m.damping {
        w.i32(d.gain.to_bits())?;
        w.i32(d.highpass.to_bits())?;
        w.i32(d.leak.to_bits())?;
        w.i32(d.limit.to_bits())?;
    }
    if let Some(s) = m.shaping.as_ref().filter(|_| previews(m)) {
        w.u32(u32::from(s.preview))?;
        for t in s.taps {
            w.i32(t)?;
        }
    }
    if let Some(b) = m.lead_baseline {
        w.i32(b.to_bits())?;
    }
    if let Some(h) = m.watch_swing {
        w.i32(h.to_bits())?;
    }
    let len = w.at;
    let mut flags = 0;
    if m.dead_zone.is_some() {
        flags |= FLAG_DEAD_ZONE;
    }
    if m.saturation.is_some() {
        flags |= FLAG_SATURATION;
    }
    if matches!(s.force_source, ForceSource::Predicted) {
        flags |= FLAG_PREDICTED;
    }
    if m.feedback.is_some() {
        flags |= FLAG_FEEDBACK;
    }
    if m.shaping.is_some() {
        flags |= FLAG_SHAPING;
    }
    if m.dynamics.is_some() {
        flags |= FLAG_DYNAMICS;
    }
    if m.damping.is_some() {
        flags |= FLAG_DAMPING;
    }
    if previews(m) {
        flags |= FLAG_PREVIEW;
    }
    if m.lead_baseline.is_some() {
        flags |= FLAG_LEAD;
    }
    if m.watch_swing.is_some() {
        flags |= FLAG_WATCH;
    }
    let out = w.out;
    let body = out.get(HEADER_LEN..len).ok_or_else(truncated)?;
    let crc = CRC32.checksum(body);
    let mut h = Writer { out, at: 0 };
    h.bytes(&MAGIC)?;
    h.bytes(&VERSION.to_le_bytes())?;
    h.bytes(&flags.to_le_bytes())?;
    h.u32((len - HEADER_LEN) as u32)?;
    h.u32(crc)?;
    Ok(len)
}

/// Walks an image whose header has been checked: values in order.
pub struct Reader<'b> {
    body: &'b [u8],
    at: usize,
    /// The header's flags.
    pub flags: u16,
}

impl<'b> Reader<'b> {
    /// Checks an image's header and checksum; a reader of its body.
    pub fn new(image: &'b [u8]) -> Result<Self, Invalid> {
        let model = |e| Invalid::at(Field::Model, e);
        if image.len() < HEADER_LEN {
            return Err(model(ModelError::Truncated));
        }
        let (header, body) = image.split_at(HEADER_LEN);
        let u16_at = |i: usize| u16::from_le_bytes([header[i], header[i + 1]]);
        let u32_at =
            |i: usize| u32::from_le_bytes([header[i], header[i + 1], header[i + 2], header[i + 3]]);
        if header[..4] != MAGIC {
            return Err(model(ModelError::NotAModelImage));
        }
        if u16_at(4) != VERSION {
            return Err(model(ModelError::UnsupportedVersion));
        }
        if u32_at(8) as usize != body.len() {
            return Err(model(ModelError::Truncated));
        }
        if CRC32.checksum(body) != u32_at(12) {
            return Err(model(ModelError::ChecksumMismatch));
        }
        Ok(Self {
            body,
            at: 0,
            flags: u16_at(6),
        })
    }

    fn take<const K: usize>(&mut self) -> Result<[u8; K], Invalid> {
        let end = self.at + K;
        let b = self.body.get(self.at..end).ok_or_else(truncated)?;
        self.at = end;
        let mut out = [0; K];
        out.copy_from_slice(b);
        Ok(out)
    }
    /// The next byte.
    pub fn u8(&mut self) -> Result<u8, Invalid> {
        Ok(self.take::<1>()?[0])
    }
    /// The next `u32`.
    pub fn u32(&mut self) -> Result<u32, Invalid> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    /// The next `i32`.
    pub fn i32(&mut self) -> Result<i32, Invalid> {
        Ok(i32::from_le_bytes(self.take()?))
    }
    /// Whether the body has been read to its end (an image with trailing bytes is
    /// refused).
    pub fn finished(&self) -> bool {
        self.at == self.body.len()
    }
}
