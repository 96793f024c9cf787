//! The one-sided play (OSP) operator and the state of a bank of them (seed 000, eqs. 1–3).

use crate::q::Volts;
use fixed::types::I16F16;

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

/// Outputs of `N` play operators: the memory of a PI model (state, not configuration).
///
/// The unit is that of the bank's input: V for a forward bank, µm for an inverse bank.
/// All operators start at rest (0), the state of a stack that has not been driven
/// since it was zeroed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlayBank<const N: usize> {
    /// Operator outputs, `I16F16` in the bank's input unit.
    pub y: [I16F16; N],
}

impl<const N: usize> PlayBank<N> {
    /// All operators at rest.
    pub const fn new() -> Self {
        Self {
            y: [Volts::ZERO; N],
        }
    }

    /// Returns every operator to rest (after the actuator has been discharged to 0).
    pub fn reset(&mut self) {
        self.y = [Volts::ZERO; N];
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
}
