//! The closed-form inverse of a one-sided-play PI model, itself a PI model.
//!
//! For `Y[u] = w0·u + Σ_{i=1..N} w_i·G_{r_i}[u]` with thresholds sorted and every partial
//! sum `S_j = Σ_{i=0..j} w_i > 0` (`r_0 = 0`, `w_0 = w0`), the inverse is
//!
//! * `w0' = 1 / w0`
//! * `r'_j = Σ_{i<=j} w_i (r_j - r_i)` — the loading curve at `u = r_j`
//! * `w'_j = -w_j / (S_j · S_{j-1})`
//!
//! and `PI⁻¹[Y[u]] = u` exactly, on every history that starts with all operators
//! at rest. The ISR therefore inverts the hysteresis with one pass over the
//! bank: no iteration, no division.
//!
//! The states of the two banks are tied: if the forward operators hold `y_i`, the
//! inverse operators hold `z_j = S_j·y_j + Σ_{i>j} w_i·y_i`. [`InversePi::resync`]
//! uses this to realign the inverse bank when the output limiter applied a voltage
//! other than the one the inverse asked for. The relation is its own inverse: the
//! forward model is the inverse of the inverse, so `y_j = S'_j·z_j + Σ_{i>j} w'_i·z_i`
//! with `S'_j = 1/S_j` ([`InversePi::forward_state`]).

use crate::error::ModelError;
use crate::pi::PiModel;
use crate::play::{Bank, Edge, Operator, Operators, PlayBank, Weight};
use crate::process::SplitProcess;
use crate::q::{
    narrow_inv_gain_biased, within, Micrometres, UmPerVolt, Volts, VoltsPerUm, GAIN_FRAC,
    INV_GAIN_FRAC, INV_GAIN_ROUND, SIGNAL_ABS_MAX_BITS, SIGNAL_FRAC,
};
use fixed::types::I16F16;

/// Configuration of an inverse PI model: stack extension in (µm), voltage out (V).
///
/// * `w0` — `1/w0`, V/µm, `I10F22`.
/// * `thresholds` — `r'_j`, µm, `I16F16`, non-decreasing.
/// * `weights` — `w'_j`, V/µm, `I10F22` (non-positive when every `w_i >= 0`).
/// * Input domain `[0, input_max]` µm, with `input_max` the forward model's
///   `output_max`; output in `[0, output_max]` V, the forward input domain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InversePi<const N: usize> {
    w0: VoltsPerUm,
    ops: Operators<VoltsPerUm, N>,
    input_max: Micrometres,
    output_max: Volts,
}

/// `round(num / den)`, ties away from zero; `None` unless `den > 0` (which the
/// callers' validated partial sums guarantee: the check makes the division
/// panic-free, as the firmware's link-time proof requires).
const fn div_round(num: i128, den: i128) -> Option<i128> {
    if den <= 0 {
        return None;
    }
    Some(if num >= 0 {
        (num + den / 2) / den
    } else {
        (num - den / 2) / den
    })
}

/// What the closed-form inverse of a forward operator set derives (besides its
/// operators): the sums its bank needs.
///
/// * `w0` — `1/w0`, V/µm.
/// * `slope` — `w0' + Σ w'_j = 1/S_N`, raw `I10F22` bits.
/// * `offset` — `Σ w'_j·r'_j`, raw bits with `INV_GAIN_FRAC + SIGNAL_FRAC` fractional bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InverseSums {
    /// `1/w0`, V/µm.
    pub w0: VoltsPerUm,
    /// `1/S_N`, raw inverse-weight bits.
    pub slope: i32,
    /// `Σ w'_j·r'_j`, raw inverse-gain × signal bits.
    pub offset: i64,
}

/// The closed-form inverse of a validated forward operator set (`w0`, `fwd`, whose
/// largest output is `output_max` µm): writes the inverse operators into `out`
/// (same length as `fwd`) and returns its sums. The one computation of the inverse,
/// shared by [`InversePi::from_forward`] and the model validator.
///
/// Fails if an inverse weight does not fit `I10F22` (that is, `w0 < 1/512` µm/V;
/// indices as [`ModelError::NonPositiveSlope`]'s: `j` for the weight built from
/// `S_j`) or the output could leave the signal range.
pub const fn invert(
    w0: UmPerVolt,
    fwd: &[Operator<UmPerVolt>],
    output_max: Micrometres,
    out: &mut [Operator<VoltsPerUm>],
) -> Result<InverseSums, ModelError> {
    let n = fwd.len();
    if out.len() != n {
        return Err(ModelError::LengthMismatch);
    }
    let w0 = w0.to_bits() as i128; // GAIN_FRAC bits; > 0 by construction
                                   // 1/w0 in INV_GAIN_FRAC bits: 2^(INV + GAIN) / w0_bits.
    let Some(inv_w0) = div_round(1i128 << (INV_GAIN_FRAC + GAIN_FRAC), w0) else {
        return Err(ModelError::NonPositiveSlope { index: 0 });
    };
    if inv_w0 > i32::MAX as i128 {
        return Err(ModelError::InverseWeightOutOfRange { index: 0 });
    }
    let mut abs_sum = inv_w0;
    let mut slope = inv_w0; // w0' + Σ w'_j, INV_GAIN_FRAC bits
    let mut offset = 0i128; // Σ w'_j r'_j, INV_GAIN_FRAC + SIGNAL_FRAC bits
    let mut s_prev = w0; // S_{j-1}
    let mut sum_wr = 0i128; // Σ_{i<j} w_i r_i, GAIN_FRAC + SIGNAL_FRAC bits (r_0 = 0)
    let mut j = 0;
    while j < n {
        let wj = fwd[j].weight.to_bits() as i128;
        let rj = fwd[j].threshold.to_bits() as i128;
        let s = s_prev + wj; // S_j > 0 by construction
        sum_wr += wj * rj;
        // r'_j = S_j r_j - Σ_{i<=j} w_i r_i, rounded to SIGNAL_FRAC bits.
        let Some(rp) = div_round(s * rj - sum_wr, 1i128 << GAIN_FRAC) else {
            return Err(ModelError::NonPositiveSlope { index: j as u8 });
        };
        // w'_j = -w_j / (S_j S_{j-1}), with all three in GAIN_FRAC bits:
        // (-w_j · 2^(INV + GAIN)) / (S_j · S_{j-1}).
        let Some(wp) = div_round(-wj * (1i128 << (INV_GAIN_FRAC + GAIN_FRAC)), s * s_prev) else {
            return Err(ModelError::NonPositiveSlope {
                index: (j + 1) as u8,
            });
        };
        if wp > i32::MAX as i128 || wp < i32::MIN as i128 {
            return Err(ModelError::InverseWeightOutOfRange {
                index: (j + 1) as u8,
            });
        }
        out[j] = Operator {
            threshold: I16F16::from_bits(rp as i32),
            weight: VoltsPerUm::from_bits(wp as i32),
        };
        abs_sum += if wp < 0 { -wp } else { wp };
        slope += wp;
        offset += wp * rp;
        s_prev = s;
        j += 1;
    }
    if output_max.to_bits() <= 0 {
        return Err(ModelError::DomainOutOfRange);
    }
    // Bound of every partial sum: sum|w'| * x_max, in INV + SIGNAL bits.
    if abs_sum * output_max.to_bits() as i128 >= (SIGNAL_ABS_MAX_BITS as i128) << INV_GAIN_FRAC {
        return Err(ModelError::OutputOutOfRange);
    }
    // The final slope w0' + Σ w'_j = 1/S_N must fit a weight too (the gap
    // form multiplies the input by it): only a concern with negative weights,
    // where S_N < w0 is possible. Reported at the last partial sum.
    if slope > i32::MAX as i128 || slope < i32::MIN as i128 {
        return Err(ModelError::InverseWeightOutOfRange { index: n as u8 });
    }
    Ok(InverseSums {
        w0: VoltsPerUm::from_bits(inv_w0 as i32),
        slope: slope as i32,
        // |offset| <= sum|w'| * x_max, bounded just above.
        offset: offset as i64,
    })
}

impl<const N: usize> InversePi<N> {
    /// Computes the inverse of a validated forward model ([`invert`]); `const` so
    /// the firmware's inverse is built by the compiler.
    pub const fn from_forward(fwd: &PiModel<N>) -> Result<Self, ModelError> {
        let mut ops = [Operator {
            threshold: I16F16::ZERO,
            weight: VoltsPerUm::ZERO,
        }; N];
        let sums = match invert(fwd.w0(), fwd.operators(), fwd.output_max(), &mut ops) {
            Ok(s) => s,
            Err(e) => return Err(e),
        };
        Ok(Self {
            w0: sums.w0,
            ops: Operators::from_parts(ops, sums.slope, sums.offset, INV_GAIN_ROUND),
            input_max: fwd.output_max(),
            output_max: fwd.input_max(),
        })
    }

    /// Sets the inverse operators to the state that matches a forward bank:
    /// `z_j = S_j·y_j + Σ_{i>j} w_i·y_i` (µm), so that the next sample
    /// continues from the voltage history actually applied.
    ///
    /// Called when the output limiter changed the voltage; `fwd` must be the model
    /// this inverse was built from. N multiply-adds, no division.
    pub fn resync<F: Edge, E: Edge>(
        &self,
        fwd: &PiModel<N>,
        fwd_state: &PlayBank<N, F>,
        state: &mut PlayBank<N, E>,
    ) {
        let (w0, from) = (fwd.w0().to_bits(), fwd.bank());
        mirror::<_, _, GAIN_FRAC, N, F, E>(
            w0,
            from,
            fwd_state,
            &self.ops,
            self.input_max.raw(),
            state,
        );
    }

    /// The other way: sets a forward bank of `fwd` (the model this inverse was
    /// built from) to the state that matches this inverse's bank,
    /// `y_j = S'_j·z_j + Σ_{i>j} w'_i·z_i` (V) after the input
    /// `û = w0'·x + Σ w'_j·z_j`, the voltage the inverse last returned. Each is
    /// rounded once; they agree with the forward bank the voltages would have
    /// driven up to the rounding of the inverse weights (a few LSB, tested).
    /// N multiply-adds, no division.
    pub fn forward_state<E: Edge, F: Edge>(
        &self,
        fwd: &PiModel<N>,
        state: &PlayBank<N, E>,
        fwd_state: &mut PlayBank<N, F>,
    ) {
        let (w0, to) = (self.w0.to_bits(), fwd.bank());
        mirror::<_, _, INV_GAIN_FRAC, N, E, F>(
            w0,
            &self.ops,
            state,
            to,
            fwd.input_max().raw(),
            fwd_state,
        );
    }

    /// `1/w0`, V/µm.
    pub const fn w0(&self) -> VoltsPerUm {
        self.w0
    }
    /// The operators: thresholds `r'_j` (µm) with their weights `w'_j` (V/µm).
    pub const fn operators(&self) -> &[Operator<VoltsPerUm>; N] {
        self.ops.ops()
    }
    /// The operators with the sums their banks need.
    pub const fn bank(&self) -> &Operators<VoltsPerUm, N> {
        &self.ops
    }
    /// Thresholds `r'_j`, µm.
    pub fn thresholds(&self) -> [Micrometres; N] {
        self.ops.ops().map(|o| Micrometres::from_raw(o.threshold))
    }
    /// Weights `w'_j`, V/µm.
    pub fn weights(&self) -> [VoltsPerUm; N] {
        self.ops.ops().map(|o| o.weight)
    }
    /// Upper end of the input domain (the forward model's largest output), µm.
    pub const fn input_max(&self) -> Micrometres {
        self.input_max
    }
    /// Upper end of the output range (the forward model's input domain), V.
    pub const fn output_max(&self) -> Volts {
        self.output_max
    }
}

/// Sets `to` (a bank of the model with operators `to_ops`, inputs held to
/// `[0, to_max]`) to the state that matches `from`, a bank of the model with
/// linear weight `w0` and operators `from_ops` (weights with `FRAC` fractional
/// bits): `t_j = S_j·y_j + Σ_{i>j} w_i·y_i` after the input `w0·u + Σ w_i·y_i`,
/// with `S_j = w0 + Σ_{i<=j} w_i` (see the module docs). One mapping for both
/// directions: a model and its closed-form inverse are each other's inverse.
fn mirror<W: Weight, V: Copy, const FRAC: u32, const N: usize, E: Edge, F: Edge>(
    w0: i32,
    from_ops: &Operators<W, N>,
    from: &PlayBank<N, E>,
    to_ops: &Operators<V, N>,
    to_max: I16F16,
    to: &mut PlayBank<N, F>,
) {
    // S_N in FRAC bits: |S_j| <= sum|w| fits an i32 (checked by the constructors).
    let mut s = from_ops.slope();
    // `tail` carries the rounding half LSB from the start, so that each
    // rounding below is a shift alone (the same values as rounding each sum).
    let round = |v: i64| I16F16::from_bits((v >> FRAC) as i32);
    // The new outputs first: the gap form needs the new last input too.
    let mut t = [I16F16::ZERO; N];
    // Σ_{i>j} w_i y_i + ½ LSB, FRAC + SIGNAL bits.
    let mut tail: i64 = 1 << (FRAC - 1);
    for (j, (op, t)) in from_ops.ops().iter().zip(t.iter_mut()).enumerate().rev() {
        let y = from.output(from_ops, j).to_bits();
        *t = round(s as i64 * y as i64 + tail);
        let wj = op.weight.bits();
        tail += wj as i64 * y as i64;
        s = s.wrapping_sub(wj);
    }
    let last = round(w0 as i64 * from.last().to_bits() as i64 + tail);
    to.set(to_ops, within(last, I16F16::ZERO, to_max), &t);
}

const _: () = assert!(SIGNAL_FRAC + GAIN_FRAC < 63);

impl<const N: usize, B: Bank<N>> SplitProcess<Micrometres, Volts, B> for InversePi<N> {
    /// One sample: advances the inverse operators with the desired output `x` (µm)
    /// and returns the input `u` (V) that produces it.
    ///
    /// `x` is clamped to `[0, input_max]`; `u` then lies in `[0, output_max]` up to
    /// rounding (a few LSB; the caller's actuator limits bound it). No division, no panic.
    #[inline(always)]
    fn process(&self, state: &mut B, x: Micrometres) -> Volts {
        let x = within(x, Micrometres::ZERO, self.input_max);
        narrow_inv_gain_biased(state.advance(&self.ops, x.raw()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::play::Bottom;

    fn pair() -> (PiModel<4>, InversePi<4>) {
        let f = PiModel::from_f64(
            0.064,
            &[10.0, 20.0, 40.0, 80.0],
            &[0.008, 0.011, 0.004, 0.012],
            150.0,
        )
        .unwrap();
        let i = InversePi::from_forward(&f).unwrap();
        (f, i)
    }

    #[test]
    fn inverse_parameters_match_the_formulas() {
        let (f, i) = pair();
        assert!((i.w0().to_num::<f64>() - 1.0 / 0.064).abs() < 1e-6);
        // r'_1 = w0 (r_1 - 0) = 0.64 um; w'_1 = -0.008 / (0.072 * 0.064)
        assert!((i.thresholds()[0].to_num::<f64>() - 0.64).abs() < 1e-4);
        assert!((i.weights()[0].to_num::<f64>() + 0.008 / (0.072 * 0.064)).abs() < 1e-5);
        assert_eq!(i.input_max(), f.output_max());
        assert_eq!(i.output_max(), f.input_max());
    }

    #[test]
    fn inverse_undoes_forward_on_a_history() {
        let (f, i) = pair();
        let (mut fs, mut is) = (PlayBank::new(), PlayBank::new());
        let mut u = 0.0f64;
        let mut worst = 0.0f64;
        for k in 0..2000 {
            // A decaying, wandering drive with many reversals.
            u = (u + 13.7 * ((k as f64) * 0.37).sin() * (1.0 - k as f64 / 2500.0))
                .clamp(0.0, 150.0);
            let x = f.process(&mut fs, Volts::from_num(u));
            let back = i.process(&mut is, x).to_num::<f64>();
            worst = worst.max((back - u).abs());
        }
        // A few LSB of x (15 pm) times |dU/dx| <= 1/w0.
        assert!(worst < 2e-3, "worst {worst} V");
    }

    #[test]
    fn resync_reproduces_the_inverse_state() {
        let (f, i) = pair();
        let (mut fs, mut is) = (PlayBank::new(), PlayBank::new());
        for u in [30.0, 120.0, 60.0, 90.0, 10.0, 140.0, 75.0] {
            let x = f.process(&mut fs, Volts::from_num(u));
            i.process(&mut is, x);
            let mut synced = PlayBank::new();
            i.resync(&f, &fs, &mut synced);
            let (a, b) = (synced.outputs(i.bank()), is.outputs(i.bank()));
            for j in 0..4 {
                let d = (a[j] - b[j]).to_num::<f64>().abs();
                assert!(d < 1e-4, "u={u} j={j} d={d}");
            }
            let d = (synced.last() - is.last()).to_num::<f64>().abs();
            assert!(d < 1e-4, "u={u}: last differs by {d}");
        }
    }

    /// The forward bank rebuilt from the inverse bank is the one the inverse's
    /// voltages drive, within a few LSB, and continues as it does.
    #[test]
    fn forward_state_reproduces_the_forward_bank() {
        let (f, i) = pair();
        let (mut fs, mut is) = (PlayBank::<4, Bottom>::at_rest(f.bank()), PlayBank::new());
        let mut worst = 0.0f64;
        for x in [3.0, 9.5, 6.0, 8.0, 0.5, 11.0, 7.25, 7.5, 2.0] {
            let u = i.process(&mut is, Micrometres::from_num(x));
            f.process(&mut fs, u);
            let mut rebuilt = PlayBank::<4, Bottom>::at_rest(f.bank());
            i.forward_state(&f, &is, &mut rebuilt);
            let (a, b) = (rebuilt.outputs(f.bank()), fs.outputs(f.bank()));
            for j in 0..4 {
                worst = worst.max((a[j] - b[j]).to_num::<f64>().abs());
            }
            worst = worst.max((rebuilt.last() - fs.last()).to_num::<f64>().abs());
            // Both continue alike.
            let (mut r, mut s) = (rebuilt, fs);
            for u in [20.0, 140.0, 60.0] {
                let (a, b) = (
                    f.process(&mut r, Volts::from_num(u)),
                    f.process(&mut s, Volts::from_num(u)),
                );
                assert!((a - b).to_num::<f64>().abs() < 1e-4, "x={x} u={u}");
            }
        }
        eprintln!("forward bank rebuilt from the inverse: worst {worst:.2e} V");
        // Each output rounded once from inverse weights of 2^-22 V/µm.
        assert!(worst < 2e-4, "worst {worst} V");
    }

    #[test]
    fn rejects_a_tiny_linear_weight() {
        let f = PiModel::from_f64(0.001, &[10.0], &[0.05], 150.0).unwrap();
        assert_eq!(
            InversePi::from_forward(&f).unwrap_err(),
            ModelError::InverseWeightOutOfRange { index: 0 }
        );
    }
}
