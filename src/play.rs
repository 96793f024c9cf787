//! The one-sided play (OSP) operator and banks of them (seed 000, eqs. 1–3).

use fixed::types::{I10F22, I16F16, I4F28};

/// One step of a one-sided play operator, eq. (3): `y = max(u - r, min(u, y))`.
///
/// The output stays in the band `[u - r, u]`: it is dragged up by the lower edge
/// while the input rises and down by the upper edge while it falls. All three
/// values share one unit (V for the forward bank, µm for the inverse bank), `I16F16`.
/// Callers keep `u` and `r` inside the model domain, so `u - r` cannot overflow.
#[inline(always)]
pub fn osp(u: I16F16, r: I16F16, y: I16F16) -> I16F16 {
    let held = if y < u { y } else { u };
    let dragged = u - r;
    if dragged > held {
        dragged
    } else {
        held
    }
}

/// One operator of a bank: its threshold (`I16F16`, the bank's input unit) and its
/// weight (`W`: `I4F28` µm/V forward, `I10F22` V/µm inverse), stored side by side
/// so the ISR streams through them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct Operator<W> {
    /// Threshold `r`.
    pub threshold: I16F16,
    /// Weight `w`.
    pub weight: W,
}

/// Operator weights the bank can accumulate: raw bits of a signed 32-bit fixed type.
pub trait Weight: Copy {
    /// The raw bits.
    fn bits(self) -> i32;
}
impl Weight for I4F28 {
    #[inline(always)]
    fn bits(self) -> i32 {
        self.to_bits()
    }
}
impl Weight for I10F22 {
    #[inline(always)]
    fn bits(self) -> i32 {
        self.to_bits()
    }
}

/// Outputs of `N` play operators and the last input: the memory of a PI model
/// (state, not configuration).
///
/// The unit is that of the bank's input: V for a forward bank, µm for an inverse
/// bank, `I16F16`. All operators start at rest (0), the state of a stack that has
/// not been driven since it was zeroed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlayBank<const N: usize> {
    /// Operator outputs.
    pub y: [I16F16; N],
    /// The last input the bank saw.
    pub last: I16F16,
}

impl<const N: usize> PlayBank<N> {
    /// All operators at rest.
    pub const fn new() -> Self {
        Self {
            y: [I16F16::ZERO; N],
            last: I16F16::ZERO,
        }
    }

    /// Returns every operator to rest (after the actuator has been discharged to 0).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Advances every operator with input `u` and returns `Σ w_i·y_i` exactly (raw
    /// bits with the weight's plus the signal's fractional bits).
    ///
    /// Eq. (3) needs a min and a max per operator, but one of them is always a
    /// no-op: every output lies in `[u_prev - r, u_prev]`, so when the input rises
    /// `min(u, y) = y` and when it falls `max(u - r, min(u, y)) = min(u, y)`. The
    /// direction is tested once per bank, then each operator costs one compare.
    /// Thresholds must be sorted and the state must come from this bank's history
    /// (or [`InversePi::resync`](crate::InversePi::resync)).
    #[inline(always)]
    pub fn advance<W: Weight>(&mut self, ops: &[Operator<W>; N], u: I16F16) -> i64 {
        let u = u.to_bits();
        let mut acc = 0i64;
        if u >= self.last.to_bits() {
            for (op, y) in ops.iter().zip(self.y.iter_mut()) {
                let dragged = u - op.threshold.to_bits();
                let mut v = y.to_bits();
                if dragged > v {
                    v = dragged;
                }
                *y = I16F16::from_bits(v);
                acc += op.weight.bits() as i64 * v as i64;
            }
        } else {
            for (op, y) in ops.iter().zip(self.y.iter_mut()) {
                let mut v = y.to_bits();
                if u < v {
                    v = u;
                }
                *y = I16F16::from_bits(v);
                acc += op.weight.bits() as i64 * v as i64;
            }
        }
        self.last = I16F16::from_bits(u);
        acc
    }
}

impl<const N: usize> Default for PlayBank<N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64) -> I16F16 {
        I16F16::from_num(x)
    }

    #[test]
    fn osp_follows_the_paper_figure_1() {
        let r = v(10.0);
        let mut y = v(0.0);
        // Below the threshold the output stays at zero.
        y = osp(v(5.0), r, y);
        assert_eq!(y, v(0.0));
        // Above it, it tracks u - r.
        y = osp(v(30.0), r, y);
        assert_eq!(y, v(20.0));
        // On reversal it holds until u has dropped by r.
        y = osp(v(25.0), r, y);
        assert_eq!(y, v(20.0));
        y = osp(v(15.0), r, y);
        assert_eq!(y, v(15.0));
        // Rising again it holds until u - r catches up.
        y = osp(v(24.0), r, y);
        assert_eq!(y, v(15.0));
        y = osp(v(27.0), r, y);
        assert_eq!(y, v(17.0));
    }

    #[test]
    fn zero_threshold_is_the_identity() {
        let mut y = v(0.0);
        for u in [1.0, 7.5, 3.25, 0.0, 12.0] {
            y = osp(v(u), v(0.0), y);
            assert_eq!(y, v(u));
        }
    }

    #[test]
    fn one_sided_update_equals_eq_3_on_any_history() {
        let ops: [Operator<I4F28>; 6] = core::array::from_fn(|i| Operator {
            threshold: v([0.0, 3.0, 3.0, 10.0, 25.5, 60.0][i]),
            weight: I4F28::from_num(0.01 * (i + 1) as f64),
        });
        let mut bank = PlayBank::<6>::new();
        let mut plain = [v(0.0); 6];
        let mut u = 0.0f64;
        for k in 0..5000 {
            // A wandering input with reversals of every size, held steps included.
            u = (u + 9.0 * ((k as f64) * 0.731).sin() * ((k as f64) * 0.013).cos())
                .clamp(0.0, 150.0);
            if k % 17 == 0 {
                u = (u * 0.5).floor();
            }
            let acc = bank.advance(&ops, v(u));
            let mut want = 0i64;
            for (i, p) in plain.iter_mut().enumerate() {
                *p = osp(v(u), ops[i].threshold, *p);
                want += ops[i].weight.to_bits() as i64 * p.to_bits() as i64;
            }
            assert_eq!(bank.y, plain, "step {k}");
            assert_eq!(acc, want);
        }
    }
}
