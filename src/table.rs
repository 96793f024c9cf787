//! Monotone lookup tables on a uniform grid with linear interpolation.
//!
//! The firmware's `f_F` (preload vs stack extension), `f_K` (stage output vs stack
//! extension) and `f_K⁻¹` live in flash as tables whose knot spacing is a power of
//! two in raw `I16F16` units, so finding the interval is a shift and the
//! interpolation weight a mask: no multiply for the index, no division, no search.
//! The grids are chosen and filled by the host tool (`fpi export`) and quantised
//! by `build.rs`.

use crate::error::ModelError;
use crate::q::{MAX_TABLE_LEN, SIGNAL_ABS_MAX_BITS};
use fixed::types::I16F16;

/// A monotone function sampled at `x_k = x0 + k·2^shift` LSB, `k = 0..len`.
///
/// Input and output are `I16F16` in their own units (µm or N). Outside
/// `[x_min, x_max]` the end values are held (callers that must not extrapolate
/// check the range first; the controller treats it as a fault).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Table<'a> {
    x0: I16F16,
    shift: u32,
    y: &'a [I16F16],
}

impl<'a> Table<'a> {
    /// Validates and builds a table: `2..=4096` knots, spacing `2^shift` LSB with
    /// `shift <= 24`, last knot inside the signal range, values monotone (either
    /// direction; flat runs allowed).
    pub const fn new(x0: I16F16, shift: u32, y: &'a [I16F16]) -> Result<Self, ModelError> {
        let n = y.len();
        if n < 2 || n > MAX_TABLE_LEN {
            return Err(ModelError::TableLength);
        }
        if shift > 24 {
            return Err(ModelError::TableSpacing);
        }
        let last = x0.to_bits() as i64 + ((n as i64 - 1) << shift);
        let lim = SIGNAL_ABS_MAX_BITS as i64;
        if last > lim || (x0.to_bits() as i64) < -lim {
            return Err(ModelError::TableSpan);
        }
        let increasing = y[n - 1].to_bits() >= y[0].to_bits();
        let mut k = 1;
        while k < n {
            let (a, b) = (y[k - 1].to_bits(), y[k].to_bits());
            if (increasing && b < a) || (!increasing && b > a) {
                return Err(ModelError::TableNotMonotone { index: k as u16 });
            }
            if b > SIGNAL_ABS_MAX_BITS || b < -SIGNAL_ABS_MAX_BITS {
                return Err(ModelError::TableSpan);
            }
            k += 1;
        }
        Ok(Self { x0, shift, y })
    }

    /// Interpolates at `x`; holds the end values outside the grid. No panic, no division.
    #[inline]
    pub fn eval(&self, x: I16F16) -> I16F16 {
        let d = x.to_bits().saturating_sub(self.x0.to_bits());
        let d = if d < 0 { 0u32 } else { d as u32 };
        let k = d.wrapping_shr(self.shift) as usize;
        let frac = d & (1u32.wrapping_shl(self.shift) - 1);
        match (self.y.get(k), self.y.get(k + 1)) {
            (Some(a), Some(b)) => {
                let (a, b) = (a.to_bits(), b.to_bits());
                let step = (b - a) as i64 * frac as i64;
                let half = 1i64.wrapping_shl(self.shift) >> 1;
                I16F16::from_bits(a + (step + half).wrapping_shr(self.shift) as i32)
            }
            _ => self.last(),
        }
    }

    /// First grid point (input unit).
    pub const fn x_min(&self) -> I16F16 {
        self.x0
    }
    /// Last grid point (input unit).
    pub const fn x_max(&self) -> I16F16 {
        I16F16::from_bits(self.x0.to_bits() + (((self.y.len() - 1) as i32) << self.shift))
    }
    /// Knot spacing as `log2` of raw LSB.
    pub const fn shift(&self) -> u32 {
        self.shift
    }
    /// Knot values.
    pub const fn values(&self) -> &'a [I16F16] {
        self.y
    }
    /// Value at the first knot.
    pub const fn first(&self) -> I16F16 {
        self.y[0]
    }
    /// Value at the last knot.
    pub const fn last(&self) -> I16F16 {
        self.y[self.y.len() - 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64) -> I16F16 {
        I16F16::from_num(x)
    }

    #[test]
    fn interpolates_and_holds_the_ends() {
        // Knots at 0, 0.25, 0.5, 0.75 um (shift 14 = 2^14 LSB = 0.25 um).
        let ys = [v(0.0), v(1.0), v(3.0), v(6.0)];
        let t = Table::new(v(0.0), 14, &ys).unwrap();
        assert_eq!(t.x_max(), v(0.75));
        assert_eq!(t.eval(v(0.25)), v(1.0));
        assert_eq!(t.eval(v(0.125)), v(0.5));
        assert_eq!(t.eval(v(0.625)), v(4.5));
        assert_eq!(t.eval(v(-3.0)), v(0.0));
        assert_eq!(t.eval(v(0.75)), v(6.0));
        assert_eq!(t.eval(v(9.0)), v(6.0));
        assert_eq!(t.eval(I16F16::MIN), v(0.0));
        assert_eq!(t.eval(I16F16::MAX), v(6.0));
    }

    #[test]
    fn decreasing_tables_work_too() {
        let ys = [v(5.0), v(4.0), v(4.0), v(1.0)];
        let t = Table::new(v(-1.0), 16, &ys).unwrap();
        assert_eq!(t.eval(v(1.5)), v(2.5));
    }

    #[test]
    fn rejects_bad_tables() {
        let ys = [v(0.0), v(2.0), v(1.0)];
        assert_eq!(
            Table::new(v(0.0), 10, &ys).unwrap_err(),
            ModelError::TableNotMonotone { index: 2 }
        );
        assert_eq!(
            Table::new(v(0.0), 10, &ys[..1]).unwrap_err(),
            ModelError::TableLength
        );
        assert_eq!(
            Table::new(v(0.0), 25, &ys[..2]).unwrap_err(),
            ModelError::TableSpacing
        );
        assert_eq!(
            Table::new(v(4095.0), 24, &ys[..2]).unwrap_err(),
            ModelError::TableSpan
        );
    }
}
