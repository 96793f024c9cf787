//! The one-sided play (OSP) operator and banks of them (Actuators 2025, 14(8):411, eqs. 1–3).

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

/// The operators of one PI model with the sums the gap form of its bank needs
/// (configuration, built once with the model).
///
/// * `slope` — `w0 + Σ w_i`, raw bits of the weight type `W` (checked by the
///   model's constructor to fit an `i32`).
/// * `offset` — `Σ w_i·r_i`, raw bits with the weight's plus the signal's
///   fractional bits (exact).
/// * `bias` — added to every sum [`PlayBank::advance`] returns, same raw unit:
///   the models use half an output LSB, so that narrowing the sum to a signal
///   is a plain shift (the rounding is folded into the precomputed constants).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Operators<W, const N: usize> {
    ops: [Operator<W>; N],
    slope: i32,
    /// `offset - bias`.
    offset_less_bias: i64,
    bias: i64,
}

impl<W: Copy, const N: usize> Operators<W, N> {
    /// Bundles the operators with `slope = w0 + Σ w_i`, `offset = Σ w_i·r_i` and
    /// the `bias` of the sums (raw bits); the model constructors compute them.
    pub const fn from_parts(ops: [Operator<W>; N], slope: i32, offset: i64, bias: i64) -> Self {
        Self {
            ops,
            slope,
            offset_less_bias: offset - bias,
            bias,
        }
    }
    /// The operators, thresholds sorted.
    pub const fn ops(&self) -> &[Operator<W>; N] {
        &self.ops
    }
    /// `w0 + Σ w_i`, raw weight bits.
    pub const fn slope(&self) -> i32 {
        self.slope
    }
}

/// Which edge of its band an operator's stored gap is measured from.
///
/// Every operator output lies in the band `[last - r, last]` of the last input.
/// A bank stores, instead of `y`, the gap `g ∈ [0, r]` between `y` and one edge:
///
/// * [`Top`]: `g = last - y`. A falling input shrinks the gap, `g ← max(g - δ, 0)`;
///   a rising one grows it, `g ← min(g + Δ, r)`.
/// * [`Bottom`]: `g = y - (last - r)`. A rising input shrinks the gap, a falling
///   one grows it.
///
/// Shrinking costs no threshold (one subtract, one sign mask); growing costs a
/// compare with `r`. The controller's two banks move in the same direction, so
/// it keeps one of each: per operator pair, every step pays one cheap and one
/// dearer update, instead of two dearer ones.
pub trait Edge: Copy + Eq + core::fmt::Debug {
    /// `true` for [`Bottom`].
    const BOTTOM: bool;
}

/// Gaps measured down from the top edge `last` of the band (see [`Edge`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Top;
impl Edge for Top {
    const BOTTOM: bool = false;
}

/// Gaps measured up from the bottom edge `last - r` of the band (see [`Edge`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bottom;
impl Edge for Bottom {
    const BOTTOM: bool = true;
}

/// The memory of a PI model: the `N` operator outputs, stored as gaps to one edge
/// of their band (`E`, see [`Edge`]), and the last input (state, not configuration).
///
/// The unit is that of the bank's input: V for a forward bank, µm for an inverse
/// bank, `I16F16`; gaps lie in `[0, r_i]`. Both forms hold exactly the same
/// outputs `y_i` ([`outputs`](Self::outputs)) and [`advance`](Self::advance) gives
/// bit-identical results in either.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlayBank<const N: usize, E: Edge = Top> {
    gap: [I16F16; N],
    last: I16F16,
    edge: E,
}

impl<const N: usize> PlayBank<N, Top> {
    /// All operators at rest (`y = 0` after an input of 0: every gap 0), the state
    /// of a stack that has not been driven since it was zeroed.
    pub const fn new() -> Self {
        Self {
            gap: [I16F16::ZERO; N],
            last: I16F16::ZERO,
            edge: Top,
        }
    }

    /// Returns every operator to rest (after the actuator has been discharged to 0).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

impl<const N: usize> Default for PlayBank<N, Top> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> PlayBank<N, Bottom> {
    /// All operators at rest for these operators (`y = 0` after an input of 0:
    /// every gap is the threshold).
    pub const fn at_rest<W: Copy>(ops: &Operators<W, N>) -> Self {
        let mut gap = [I16F16::ZERO; N];
        let mut i = 0;
        while i < N {
            gap[i] = ops.ops[i].threshold;
            i += 1;
        }
        Self {
            gap,
            last: I16F16::ZERO,
            edge: Bottom,
        }
    }
}

impl<const N: usize, E: Edge> PlayBank<N, E> {
    /// The last input the bank saw.
    pub const fn last(&self) -> I16F16 {
        self.last
    }

    /// The gap of one operator as its output, raw bits.
    #[inline(always)]
    fn y_bits(last: i32, r: i32, g: i32) -> i32 {
        if E::BOTTOM {
            last - r + g
        } else {
            last - g
        }
    }

    /// The operator outputs `y_i` (same unit as the input).
    pub fn outputs<W: Copy>(&self, ops: &Operators<W, N>) -> [I16F16; N] {
        core::array::from_fn(|i| self.output(ops, i))
    }

    /// The output `y_i` of operator `i` (same unit as the input); `i < N`.
    #[inline(always)]
    pub fn output<W: Copy>(&self, ops: &Operators<W, N>, i: usize) -> I16F16 {
        let r = ops.ops[i].threshold.to_bits();
        I16F16::from_bits(Self::y_bits(self.last.to_bits(), r, self.gap[i].to_bits()))
    }

    /// Sets the memory to outputs `y` after an input `last`. For a consistent
    /// state each `y_i` lies in `[last - r_i, last]`; [`advance`](Self::advance)
    /// then continues exactly as eq. (3) would.
    pub fn set<W: Copy>(&mut self, ops: &Operators<W, N>, last: I16F16, y: &[I16F16; N]) {
        let l = last.to_bits();
        for ((g, y), op) in self.gap.iter_mut().zip(y).zip(&ops.ops) {
            let y = y.to_bits();
            let g_bits = if E::BOTTOM {
                y - (l - op.threshold.to_bits())
            } else {
                l - y
            };
            *g = I16F16::from_bits(g_bits);
        }
        self.last = last;
    }

    /// Advances every operator with input `u` and returns `w0·u + Σ w_i·y_i +
    /// bias` exactly (raw bits with the weight's plus the signal's fractional
    /// bits; `bias` from [`Operators`]).
    ///
    /// Eq. (3) needs a min and a max per operator, but one of them is always a
    /// no-op: every output lies in `[u_prev - r, u_prev]`, so when the input rises
    /// `min(u, y) = y` and when it falls `max(u - r, min(u, y)) = min(u, y)`. The
    /// direction is tested once per bank. In gap form (see [`Edge`]) the update
    /// is then `max(g - d, 0)` or `min(g + d, r)` with `d = |u - u_prev|`, and
    /// the sum follows from the gaps and the precomputed sums:
    /// `Σ w_i·y_i = (Σ w_i)·u - Σ w_i·g_i` ([`Top`]) or
    /// `(Σ w_i)·u - Σ w_i·r_i + Σ w_i·g_i` ([`Bottom`]).
    #[inline(always)]
    pub fn advance<W: Weight>(&mut self, ops: &Operators<W, N>, u: I16F16) -> i64 {
        let last = self.last;
        self.last = u;
        Self::step(ops, last, u, self.gap.iter_mut().map(|g| (*g, g)))
    }

    /// [`advance`](Self::advance) from this state into `next`, which receives
    /// the new state; this one is left as it was (the state one step back, for
    /// a double-buffered bank: [`Stepped`]). The same operations per operator.
    #[inline(always)]
    pub fn advance_into<W: Weight>(
        &self,
        next: &mut Self,
        ops: &Operators<W, N>,
        u: I16F16,
    ) -> i64 {
        next.last = u;
        Self::step(
            ops,
            self.last,
            u,
            self.gap.iter().copied().zip(&mut next.gap),
        )
    }

    /// The one update of a bank's gaps (see [`advance`](Self::advance)): each
    /// pair is an operator's gap before the step and where its new gap goes.
    #[inline(always)]
    fn step<'g, W: Weight>(
        ops: &Operators<W, N>,
        last: I16F16,
        u: I16F16,
        gaps: impl Iterator<Item = (I16F16, &'g mut I16F16)>,
    ) -> i64 {
        let (u, last) = (u.to_bits(), last.to_bits());
        let rising = u >= last;
        let d = if rising { u - last } else { last - u };
        let mut acc = 0i64;
        if rising == E::BOTTOM {
            for (op, (g, next)) in ops.ops.iter().zip(gaps) {
                let v = (g.to_bits() - d).max(0);
                *next = I16F16::from_bits(v);
                acc += op.weight.bits() as i64 * v as i64;
            }
        } else {
            for (op, (g, next)) in ops.ops.iter().zip(gaps) {
                let v = (g.to_bits() + d).min(op.threshold.to_bits());
                *next = I16F16::from_bits(v);
                acc += op.weight.bits() as i64 * v as i64;
            }
        }
        let linear = ops.slope as i64 * u as i64;
        if E::BOTTOM {
            linear - ops.offset_less_bias + acc
        } else {
            linear + ops.bias - acc
        }
    }
}

/// A memory a model's bank advances ([`PlayBank::advance`]): one bank in
/// place, or a double-buffered one ([`Stepped`]).
pub trait Bank<const N: usize> {
    /// Advances with input `u`; returns the bank's sum ([`PlayBank::advance`]).
    fn advance<W: Weight>(&mut self, ops: &Operators<W, N>, u: I16F16) -> i64;
}

impl<const N: usize, E: Edge> Bank<N> for PlayBank<N, E> {
    #[inline(always)]
    fn advance<W: Weight>(&mut self, ops: &Operators<W, N>, u: I16F16) -> i64 {
        PlayBank::advance(self, ops, u)
    }
}

/// A double-buffered bank: each advance writes the new state into the other
/// buffer, so the state before the last advance stays at hand
/// ([`before`](Self::before)) at the cost of a buffer swap, not a copy.
///
/// The controller keeps its inverse bank so: when the limiter changes the
/// drive, the inverse's step is done again from the state before it ([`Redo`])
/// with the input the applied voltage matches; on the paper's bare FPI the
/// forward memory, which it does not advance while the inverse is exact, is
/// first rebuilt from the inverse memory as it was before the step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stepped<const N: usize, E: Edge = Top> {
    banks: [PlayBank<N, E>; 2],
    /// Which buffer holds the present state (0 or 1).
    now: usize,
}

impl<const N: usize, E: Edge> Stepped<N, E> {
    /// Both buffers at `bank`.
    pub const fn new(bank: PlayBank<N, E>) -> Self {
        Self {
            banks: [bank, bank],
            now: 0,
        }
    }

    /// The present state.
    #[inline(always)]
    pub fn now(&self) -> &PlayBank<N, E> {
        &self.banks[self.now & 1]
    }

    /// The present state, to set it ([`PlayBank::set`]).
    #[inline(always)]
    pub fn now_mut(&mut self) -> &mut PlayBank<N, E> {
        &mut self.banks[self.now & 1]
    }

    /// The state before the last [`advance`](Bank::advance); after a change
    /// through [`now_mut`](Self::now_mut), whatever the other buffer held.
    #[inline(always)]
    pub fn before(&self) -> &PlayBank<N, E> {
        &self.banks[(self.now & 1) ^ 1]
    }
}

/// A [`Stepped`] bank whose last advance is done again with another input:
/// from the state before it into the present buffer, without a swap.
pub struct Redo<'b, const N: usize, E: Edge>(pub &'b mut Stepped<N, E>);

impl<const N: usize, E: Edge> Bank<N> for Redo<'_, N, E> {
    #[inline(always)]
    fn advance<W: Weight>(&mut self, ops: &Operators<W, N>, u: I16F16) -> i64 {
        let [a, b] = &mut self.0.banks;
        let (from, to) = if self.0.now & 1 == 0 {
            (&*b, a)
        } else {
            (&*a, b)
        };
        from.advance_into(to, ops, u)
    }
}

impl<const N: usize, E: Edge> Bank<N> for Stepped<N, E> {
    #[inline(always)]
    fn advance<W: Weight>(&mut self, ops: &Operators<W, N>, u: I16F16) -> i64 {
        let [a, b] = &mut self.banks;
        let (from, to) = if self.now & 1 == 0 {
            (&*a, b)
        } else {
            (&*b, a)
        };
        self.now ^= 1;
        from.advance_into(to, ops, u)
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

    fn operators() -> Operators<I4F28, 6> {
        let ops: [Operator<I4F28>; 6] = core::array::from_fn(|i| Operator {
            threshold: v([0.0, 3.0, 3.0, 10.0, 25.5, 60.0][i]),
            weight: I4F28::from_num(0.01 * (i as f64 - 1.5)),
        });
        let w0 = I4F28::from_num(0.05).to_bits();
        let slope = w0 + ops.iter().map(|o| o.weight.to_bits()).sum::<i32>();
        let offset = ops
            .iter()
            .map(|o| o.weight.to_bits() as i64 * o.threshold.to_bits() as i64)
            .sum();
        Operators::from_parts(ops, slope, offset, 1 << 27)
    }

    /// Both gap forms against eq. (3) on a wandering input with reversals of
    /// every size and held steps: the same outputs and the same exact sum.
    fn follows_eq_3<E: Edge>(mut bank: PlayBank<6, E>) {
        let ops = operators();
        let w0 = I4F28::from_num(0.05).to_bits() as i64;
        let mut plain = [v(0.0); 6];
        let mut u = 0.0f64;
        for k in 0..5000 {
            u = (u + 9.0 * ((k as f64) * 0.731).sin() * ((k as f64) * 0.013).cos())
                .clamp(0.0, 150.0);
            if k % 17 == 0 {
                u = (u * 0.5).floor();
            }
            let acc = bank.advance(&ops, v(u));
            let mut want = w0 * v(u).to_bits() as i64 + (1 << 27);
            for (i, p) in plain.iter_mut().enumerate() {
                *p = osp(v(u), ops.ops()[i].threshold, *p);
                want += ops.ops()[i].weight.to_bits() as i64 * p.to_bits() as i64;
            }
            assert_eq!(bank.outputs(&ops), plain, "step {k}");
            assert_eq!(bank.last(), v(u));
            assert_eq!(acc, want, "step {k}");
        }
    }

    #[test]
    fn gaps_from_the_top_follow_eq_3_on_any_history() {
        follows_eq_3(PlayBank::<6, Top>::new());
    }

    #[test]
    fn gaps_from_the_bottom_follow_eq_3_on_any_history() {
        follows_eq_3(PlayBank::<6, Bottom>::at_rest(&operators()));
    }

    /// The double-buffered bank advances as one bank in place, keeps the
    /// state before each advance, and redoes its last advance from it.
    #[test]
    fn a_stepped_bank_advances_as_one_bank_and_keeps_the_state_before() {
        let ops = operators();
        let mut one = PlayBank::<6, Top>::new();
        let mut two = Stepped::new(PlayBank::<6, Top>::new());
        for (k, u) in [40.0, 12.0, 90.0, 55.0, 55.0, 150.0, 0.0, 33.5]
            .into_iter()
            .enumerate()
        {
            let before = one;
            let a = one.advance(&ops, v(u));
            let b = Bank::advance(&mut two, &ops, v(u));
            assert_eq!(a, b, "step {k}");
            assert_eq!(two.now(), &one, "step {k}");
            assert_eq!(two.before(), &before, "step {k}");
            // The same step done again with another input starts from the
            // state before it, as one bank advanced from there would.
            let (mut redone, again) = (before, u * 0.5 + 7.0);
            let a = redone.advance(&ops, v(again));
            let b = Bank::advance(&mut Redo(&mut two), &ops, v(again));
            assert_eq!(
                (a, two.now(), two.before()),
                (b, &redone, &before),
                "step {k}"
            );
            one = redone;
        }
    }

    #[test]
    fn set_round_trips_through_outputs() {
        let ops = operators();
        let mut a = PlayBank::<6, Top>::new();
        for u in [40.0, 12.0, 90.0, 55.0] {
            a.advance(&ops, v(u));
        }
        let y = a.outputs(&ops);
        let mut b = PlayBank::<6, Bottom>::at_rest(&ops);
        b.set(&ops, a.last(), &y);
        assert_eq!(b.outputs(&ops), y);
        // Both continue identically.
        for u in [70.0, 3.0, 150.0, 149.5] {
            assert_eq!(a.advance(&ops, v(u)), b.advance(&ops, v(u)));
            assert_eq!(a.outputs(&ops), b.outputs(&ops));
        }
    }
}
