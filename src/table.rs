//! Monotone lookup tables on a uniform grid with linear interpolation.
//!
//! The firmware's `f_F` (preload vs stack extension), `f_K` (stage output vs stack
//! extension) and `f_K⁻¹` live in flash as tables whose knot spacing is a power of
//! two in raw `I16F16` units: one 32 × 32 → 64-bit multiply of the offset from the
//! first knot by `2^(32 - shift)` puts the interval index in the high word and the
//! position inside the interval, as a 32-bit fraction, in the low word. No division,
//! no search, no variable shift. Each interval is stored as its start value and
//! twice its rise ([`Segment`]), so an evaluation is that multiply, one bounds test,
//! two loads and one rounding multiply-accumulate.
//! The grids are chosen and filled by the host tool (`fpi export`) and quantised
//! by `build.rs`.

use crate::error::ModelError;
use crate::fields::{TableId, TablePart};
use crate::q::{MAX_TABLE_LEN, SIGNAL_ABS_MAX_BITS};
use fixed::types::I16F16;

/// Largest knot spacing, as `log2` of raw LSB: one unit (µm or N).
pub const MAX_SHIFT: u32 = shift_of(TablePart::StepLog2.decl(TableId::FF).bits().1);

/// Smallest knot spacing, as `log2` of raw LSB: 2 LSB (30 pm or 30 µN), so that
/// `2^(32 - shift)` fits 32 bits.
pub const MIN_SHIFT: u32 = shift_of(TablePart::StepLog2.decl(TableId::FF).bits().0);

/// The raw shift of a file's `step_log2` (its spacing in units of `I16F16`).
const fn shift_of(step_log2: i64) -> u32 {
    (step_log2 + 16) as u32
}

/// Largest rise of one interval, raw: half a unit. It keeps every interval fine
/// (`fpi export` refines the grid until it holds) and `2·rise` within 16 bits, so
/// the interpolation product `2·rise × 31-bit fraction` stays far inside 64 bits.
pub const MAX_KNOT_STEP: i32 = 1 << 15;

/// One interval of a table: the value at its first knot and the rise to the next.
///
/// The rise is stored doubled (raw bits), the factor the interpolation's
/// multiply needs ([`Table::eval`]); a rise too large for a table (`|rise| >=`
/// [`MAX_KNOT_STEP`]) is stored as the saturated marker `i32::MAX`/`i32::MIN`,
/// which [`Table::new`] rejects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct Segment {
    start: I16F16,
    twice_rise: i32,
}

impl Segment {
    /// A segment from raw bits of its start and rise (generated code).
    pub const fn from_bits(start: i32, rise: i32) -> Self {
        Self::from_wide(start, rise as i64)
    }

    /// The one place a rise is stored: doubled, or saturated into the marker.
    pub(crate) const fn from_wide(start: i32, rise: i64) -> Self {
        let twice_rise = if rise >= MAX_KNOT_STEP as i64 {
            i32::MAX
        } else if rise <= -MAX_KNOT_STEP as i64 {
            i32::MIN
        } else {
            rise as i32 * 2
        };
        Self {
            start: I16F16::from_bits(start),
            twice_rise,
        }
    }

    /// A segment from its start value and its rise to the next knot.
    pub const fn new(start: I16F16, rise: I16F16) -> Self {
        Self::from_bits(start.to_bits(), rise.to_bits())
    }

    /// Value at the interval's first knot.
    pub const fn start(&self) -> I16F16 {
        self.start
    }

    /// Value at the next knot minus [`start`](Self::start) (for a rejected
    /// segment: a value at least [`MAX_KNOT_STEP`] in magnitude).
    pub const fn rise(&self) -> I16F16 {
        I16F16::from_bits(self.twice_rise >> 1)
    }

    /// The `K - 1` segments between `K` knot values (`S` must be `K - 1`).
    pub const fn between<const K: usize, const S: usize>(values: &[I16F16; K]) -> [Segment; S] {
        assert!(S + 1 == K, "S must be K - 1");
        let mut out = [Segment::from_bits(0, 0); S];
        let mut k = 0;
        while k < S {
            let a = values[k].to_bits();
            // Exact in i64; a rise out of range saturates into the marker.
            out[k] = Segment::from_wide(a, values[k + 1].to_bits() as i64 - a as i64);
            k += 1;
        }
        out
    }
}

/// A monotone function sampled at `x_k = x0 + k·2^shift` LSB.
///
/// Input and output are `I16F16` in their own units (µm or N). Outside
/// `[x_min, x_max]` the end values are held (callers that must not extrapolate
/// check the range first; the controller treats it as a fault).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Table<'a> {
    x0: I16F16,
    /// `2^(32 - shift)`: multiplying the offset from `x0` by it splits the offset
    /// into interval index (high word) and fraction (low word).
    scale: u32,
    segments: &'a [Segment],
    /// The last knot's value (held beyond the grid).
    end: I16F16,
    shift: u32,
}

impl<'a> Table<'a> {
    /// Validates and builds a table: `1..4096` segments, spacing `2^shift` LSB with
    /// `1 <= shift <= 16` (2 LSB to one unit), the last knot inside the signal range,
    /// rises of one sign (monotone; flat runs allowed) and below half a unit, and
    /// each segment starting where the previous one ends.
    pub const fn new(x0: I16F16, shift: u32, segments: &'a [Segment]) -> Result<Self, ModelError> {
        let n = segments.len();
        if n < 1 || n >= MAX_TABLE_LEN {
            return Err(ModelError::TableLength);
        }
        if shift < MIN_SHIFT || shift > MAX_SHIFT {
            return Err(ModelError::TableSpacing);
        }
        let last = x0.to_bits() as i64 + ((n as i64) << shift);
        let lim = SIGNAL_ABS_MAX_BITS as i64;
        if last > lim || (x0.to_bits() as i64) < -lim {
            return Err(ModelError::TableSpan);
        }
        let mut rising = false;
        let mut falling = false;
        let mut k = 0;
        let mut value = segments[0].start.to_bits() as i64;
        while k < n {
            let s = segments[k];
            if s.start.to_bits() as i64 != value {
                return Err(ModelError::TableNotMonotone { index: k as u16 });
            }
            let r = s.rise().to_bits();
            rising |= r > 0;
            falling |= r < 0;
            if rising && falling {
                return Err(ModelError::TableNotMonotone {
                    index: (k + 1) as u16,
                });
            }
            if r >= MAX_KNOT_STEP || r <= -MAX_KNOT_STEP {
                return Err(ModelError::TableTooSteep {
                    index: (k + 1) as u16,
                });
            }
            if value > lim || value < -lim {
                return Err(ModelError::TableSpan);
            }
            value += r as i64;
            k += 1;
        }
        if value > lim || value < -lim {
            return Err(ModelError::TableSpan);
        }
        Ok(Self {
            x0,
            scale: 1 << (32 - shift),
            segments,
            end: I16F16::from_bits(value as i32),
            shift,
        })
    }

    /// Interpolates at `x`; holds the end values outside the grid. No panic, no division.
    ///
    /// The offset `d` from the first knot (0 below the grid; exact as `u32`, since
    /// `x > x0` cannot wrap) times `2^(32 - shift)` is `k·2^32 + φ·2^32`: interval
    /// `k`, fraction `φ` of the spacing. With `|rise| < 2^15` and `φ` taken to 31
    /// bits, `start + round(rise·φ)` is one rounding multiply-accumulate (`smmlar`);
    /// `φ` has at most 16 significant bits, so the rounding is exact:
    /// `⌊rise·φ + ½⌋`.
    #[inline]
    pub fn eval(&self, x: I16F16) -> I16F16 {
        let (x, x0) = (x.to_bits(), self.x0.to_bits());
        let d = if x < x0 { 0 } else { x.wrapping_sub(x0) as u32 };
        let p = d as u64 * self.scale as u64;
        match self.segments.get((p >> 32) as usize) {
            Some(s) => {
                let phi = ((p as u32) >> 1) as i64; // φ·2^31, in [0, 2^31)
                let rise = s.twice_rise as i64; // |2·rise| < 2^16
                let step = ((rise * phi + (1 << 31)) >> 32) as i32;
                I16F16::from_bits(s.start.to_bits() + step)
            }
            None => self.end,
        }
    }

    /// [`eval`](Self::eval) for an `x` the caller knows to be at least
    /// [`x_min`](Self::x_min) (a reference checked against a window inside the
    /// grid): the same value there, without the clamp below the grid. Below it
    /// the offset wraps to at least 2³¹ LSB, an interval index of at least 2¹⁵
    /// (the spacing is at most 2¹⁶ LSB), beyond any table: the last knot's value
    /// is returned, no panic, no out-of-bounds read.
    #[inline]
    pub fn eval_from_x_min(&self, x: I16F16) -> I16F16 {
        let d = x.to_bits().wrapping_sub(self.x0.to_bits()) as u32;
        let p = d as u64 * self.scale as u64;
        match self.segments.get((p >> 32) as usize) {
            Some(s) => {
                let phi = ((p as u32) >> 1) as i64;
                let rise = s.twice_rise as i64;
                let step = ((rise * phi + (1 << 31)) >> 32) as i32;
                I16F16::from_bits(s.start.to_bits() + step)
            }
            None => self.end,
        }
    }

    /// First grid point (input unit).
    pub const fn x_min(&self) -> I16F16 {
        self.x0
    }
    /// Last grid point (input unit).
    pub const fn x_max(&self) -> I16F16 {
        I16F16::from_bits(self.x0.to_bits() + ((self.segments.len() as i32) << self.shift))
    }
    /// Knot spacing as `log2` of raw LSB.
    pub const fn shift(&self) -> u32 {
        self.shift
    }
    /// The intervals.
    pub const fn segments(&self) -> &'a [Segment] {
        self.segments
    }
    /// Value at the last knot.
    pub const fn last(&self) -> I16F16 {
        self.end
    }

    /// The first knot the table rises to by less than `min_rise` raw LSB from
    /// the knot before it (knots are numbered from 0), if any.
    pub fn first_rise_below(&self, min_rise: i32) -> Option<usize> {
        self.segments
            .iter()
            .position(|s| s.rise().to_bits() < min_rise)
            .map(|k| k + 1)
    }

    /// The first knot `y_j` of `inverse`, within this table's range, at which
    /// `self(inverse(y_j))` is more than `tolerance` from `y_j`, if any: where
    /// `inverse` does not invert this table.
    pub fn first_disagreement(&self, inverse: &Table<'_>, tolerance: I16F16) -> Option<usize> {
        // No indexing: the model's loading must not reach a panic (`no-panic`).
        let lo = self.segments.first()?.start;
        let hi = self.end;
        let step = 1i64 << inverse.shift;
        (0..=inverse.segments.len()).find(|&j| {
            let y = inverse.x0.to_bits() as i64 + j as i64 * step;
            if y < lo.to_bits() as i64 || y > hi.to_bits() as i64 {
                return false;
            }
            let back = self.eval(inverse.eval(I16F16::from_bits(y as i32)));
            (back.to_bits() as i64 - y).abs() > tolerance.to_bits() as i64
        })
    }
}

/// How far `f_K(f_K⁻¹(y))` may be from `y` at the knots of `f_K⁻¹`
/// ([`Table::first_disagreement`]): 1/64 µm. Tables sampled from one FEM map
/// agree to a few LSB (stage A: exactly); an inverse from another map, or of a
/// map that does not rise, does not.
pub const INVERSE_TOLERANCE: I16F16 = I16F16::from_bits(1 << 10);

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64) -> I16F16 {
        I16F16::from_num(x)
    }

    #[test]
    fn interpolates_and_holds_the_ends() {
        // Knots at 0, 0.25, 0.5, 0.75 um (shift 14 = 2^14 LSB = 0.25 um).
        let segs: [Segment; 3] = Segment::between(&[v(0.0), v(0.125), v(0.375), v(0.75)]);
        let t = Table::new(v(0.0), 14, &segs).unwrap();
        assert_eq!(t.x_max(), v(0.75));
        assert_eq!(t.last(), v(0.75));
        assert_eq!(t.eval(v(0.25)), v(0.125));
        assert_eq!(t.eval(v(0.125)), v(0.0625));
        assert_eq!(t.eval(v(0.625)), v(0.5625));
        assert_eq!(t.eval(v(-3.0)), v(0.0));
        assert_eq!(t.eval(v(0.75)), v(0.75));
        // One LSB before the end, on a slope of 1.5: 1.5 LSB below, rounded.
        assert_eq!(t.eval(v(0.75) - I16F16::DELTA), v(0.75) - I16F16::DELTA);
        assert_eq!(t.eval(v(9.0)), v(0.75));
        assert_eq!(t.eval(I16F16::MIN), v(0.0));
        assert_eq!(t.eval(I16F16::MAX), v(0.75));
    }

    /// From the first knot on, the evaluation without the lower clamp is the
    /// same; below it, it holds the last knot's value without a panic.
    #[test]
    fn evaluation_from_the_first_knot_matches_and_stays_in_bounds() {
        let segs: [Segment; 3] = Segment::between(&[v(-1.0), v(-0.875), v(-0.625), v(-0.25)]);
        for shift in [MIN_SHIFT, 8, 14, MAX_SHIFT] {
            let t = Table::new(v(-1.0), shift, &segs).unwrap();
            let top = t.x_max().to_bits();
            let mut x = t.x_min().to_bits();
            while x <= top + (1 << shift) {
                let xi = I16F16::from_bits(x);
                assert_eq!(t.eval_from_x_min(xi), t.eval(xi), "shift {shift} x {x}");
                x += (1 << shift) / 3 + 1;
            }
            for below in [t.x_min() - I16F16::DELTA, v(-2.0), I16F16::MIN] {
                assert_eq!(t.eval_from_x_min(below), t.last());
            }
            assert_eq!(t.eval_from_x_min(I16F16::MAX), t.last());
        }
    }

    /// The multiply-split evaluation equals the plain one: index by a shift,
    /// 16-bit fraction by a mask, `start + ⌊rise·f/2^16 + ½⌋`.
    #[test]
    fn evaluation_is_exact_for_every_spacing() {
        let plain = |t: &Table<'_>, x: I16F16| -> I16F16 {
            let d = (x.to_bits() as i64 - t.x_min().to_bits() as i64).max(0);
            let k = (d >> t.shift()) as usize;
            match t.segments().get(k) {
                Some(s) => {
                    let f = (d << (16 - t.shift())) & 0xFFFF;
                    let r = (s.rise().to_bits() as i64 * f + (1 << 15)) >> 16;
                    I16F16::from_bits(s.start().to_bits() + r as i32)
                }
                None => t.last(),
            }
        };
        // Rises of both signs up to the largest allowed, on every spacing.
        let values: [I16F16; 6] = [-3.0, -2.5000153, -2.0000306, -1.9, -1.41, -1.4].map(v);
        let segs: [Segment; 5] = Segment::between(&values);
        let down: [Segment; 5] = Segment::between(&values.map(|x| I16F16::from_bits(-x.to_bits())));
        let mut seed = 0x2545_f491u32;
        for shift in MIN_SHIFT..=MAX_SHIFT {
            for segs in [&segs, &down] {
                let t = Table::new(v(-7.25), shift, segs).unwrap();
                let (lo, hi) = (t.x_min().to_bits(), t.x_max().to_bits());
                let span = (hi - lo) as u32;
                for k in 0..4000u32 {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    let x = match k {
                        0 => i32::MIN,
                        1 => i32::MAX,
                        2 => lo,
                        3 => hi,
                        _ => lo - 3 + (seed % (span + 7)) as i32,
                    };
                    let x = I16F16::from_bits(x);
                    assert_eq!(t.eval(x), plain(&t, x), "shift {shift} x {x}");
                }
            }
        }
    }

    #[test]
    fn decreasing_tables_work_too() {
        let segs: [Segment; 3] = Segment::between(&[v(5.0), v(4.75), v(4.75), v(4.5)]);
        let t = Table::new(v(-1.0), 16, &segs).unwrap();
        assert_eq!(t.eval(v(1.5)), v(4.625));
    }

    #[test]
    fn rejects_bad_tables() {
        let steep: [Segment; 2] = Segment::between(&[v(0.0), v(0.25), v(1.0)]);
        assert_eq!(
            Table::new(v(0.0), 10, &steep).unwrap_err(),
            ModelError::TableTooSteep { index: 2 }
        );
        // Rises beyond i32 (from `between`) or near it saturate into the marker.
        let cliff: [Segment; 1] = Segment::between(&[I16F16::MIN, I16F16::MAX]);
        assert_eq!(cliff[0].rise().to_bits(), i32::MAX >> 1);
        assert_eq!(
            Table::new(v(0.0), 10, &cliff).unwrap_err(),
            ModelError::TableTooSteep { index: 1 }
        );
        for rise in [i32::MAX, i32::MIN, MAX_KNOT_STEP, -MAX_KNOT_STEP] {
            let s = [Segment::from_bits(0, rise)];
            assert_eq!(
                Table::new(v(0.0), 10, &s).unwrap_err(),
                ModelError::TableTooSteep { index: 1 },
                "rise {rise}"
            );
        }
        let s = [Segment::from_bits(0, MAX_KNOT_STEP - 1)];
        assert_eq!(
            Table::new(v(0.0), 16, &s).unwrap().last().to_bits(),
            MAX_KNOT_STEP - 1
        );
        let zigzag: [Segment; 2] = Segment::between(&[v(0.0), v(0.25), v(0.125)]);
        assert_eq!(
            Table::new(v(0.0), 10, &zigzag).unwrap_err(),
            ModelError::TableNotMonotone { index: 2 }
        );
        let mut broken = Segment::between::<3, 2>(&[v(0.0), v(0.25), v(0.375)]);
        broken[1] = Segment::new(v(0.3), broken[1].rise());
        assert_eq!(
            Table::new(v(0.0), 10, &broken).unwrap_err(),
            ModelError::TableNotMonotone { index: 1 }
        );
        assert_eq!(
            Table::new(v(0.0), 10, &[]).unwrap_err(),
            ModelError::TableLength
        );
        assert_eq!(
            Table::new(v(0.0), 17, &steep[..1]).unwrap_err(),
            ModelError::TableSpacing
        );
        assert_eq!(
            Table::new(v(0.0), 0, &steep[..1]).unwrap_err(),
            ModelError::TableSpacing
        );
        assert_eq!(
            Table::new(v(4095.5), 16, &steep[..1]).unwrap_err(),
            ModelError::TableSpan
        );
    }
}
