//! The classical Prandtl–Ishlinskii model with one-sided play operators (Actuators 2025, 14(8):411, eq. 4):
//! `Y[u] = w0·u + Σ w_i·G_{r_i}[u]`.

use crate::error::ModelError;
use crate::play::{Edge, Operator, Operators, PlayBank};
use crate::process::SplitProcess;
use crate::q::{
    self, narrow_gain, within, GainAcc, Micrometres, UmPerVolt, Volts, GAIN_FRAC, MAX_OPERATORS,
    SIGNAL_ABS_MAX_BITS,
};
use fixed::types::I16F16;

/// Configuration of a forward PI model: voltage in, stack extension out.
///
/// * `w0` — linear weight, µm/V, `I4F28`.
/// * `thresholds` — `r_i`, V, `I16F16`, `0 <= r_1 <= … <= r_N <= input_max`.
/// * `weights` — `w_i`, µm/V, `I4F28`; any sign as long as every partial sum
///   `S_j = w0 + w_1 + … + w_j` is positive (then the model is strictly increasing
///   on every branch and has the closed-form inverse of [`crate::InversePi`]).
/// * `input_max` — the input domain is `[0, input_max]` V; inputs are clamped to it
///   (a unipolar stack; the FPI model clamps the effective voltage at 0, see [`crate::fpi`]).
///
/// With inputs in the domain the output lies in `[0, output_max]` µm, where
/// `output_max = Y[input_max]` on any history.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PiModel<const N: usize> {
    w0: UmPerVolt,
    ops: Operators<UmPerVolt, N>,
    input_max: Volts,
    output_max: Micrometres,
}

/// What a validated operator set derives: the sums its bank needs and its range.
///
/// * `slope` — `w0 + Σ w_i`, raw `I4F28` bits (fits an `i32`: `Σ|w|` is checked).
/// * `offset` — `Σ w_i·r_i`, raw bits with `GAIN_FRAC + SIGNAL_FRAC` fractional bits.
/// * `output_max` — `Y[input_max]` on the loading curve, µm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PiSums {
    /// `w0 + Σ w_i`, raw weight bits.
    pub slope: i32,
    /// `Σ w_i·r_i`, raw gain × signal bits.
    pub offset: i64,
    /// `Y[input_max]`, µm.
    pub output_max: Micrometres,
}

/// Checks a forward PI's parameters and derives its sums; the one check of an
/// operator set, shared by [`PiModel::new`] and the model validator
/// ([`crate::model::validate`]).
///
/// `w0 > 0`; thresholds in `[0, input_max]` and sorted; every partial sum
/// `S_j = w0 + w_1 + … + w_j` positive (indices of [`ModelError::NonPositiveSlope`]
/// are `j`, 0 for `w0` alone); `Σ|w|·input_max` inside the signal range.
pub const fn check(
    w0: UmPerVolt,
    ops: &[Operator<UmPerVolt>],
    input_max: Volts,
) -> Result<PiSums, ModelError> {
    let n = ops.len();
    if n > MAX_OPERATORS {
        return Err(ModelError::TooManyOperators);
    }
    let u_max = input_max.to_bits() as i64;
    if u_max <= 0 || u_max > SIGNAL_ABS_MAX_BITS as i64 {
        return Err(ModelError::DomainOutOfRange);
    }
    let mut slope = w0.to_bits() as i64;
    if slope <= 0 {
        return Err(ModelError::NonPositiveSlope { index: 0 });
    }
    let mut abs_sum = slope;
    let mut offset = 0i64; // Σ w_i r_i, GAIN_FRAC + SIGNAL_FRAC bits
    let mut prev = 0i64;
    let mut i = 0;
    while i < n {
        let r = ops[i].threshold.to_bits() as i64;
        if r < 0 {
            return Err(ModelError::NegativeThreshold { index: i as u8 });
        }
        if r < prev {
            return Err(ModelError::ThresholdsNotSorted { index: i as u8 });
        }
        if r > u_max {
            return Err(ModelError::ThresholdBeyondDomain { index: i as u8 });
        }
        prev = r;
        let w = ops[i].weight.to_bits() as i64;
        slope += w;
        offset += w * r;
        if slope <= 0 {
            return Err(ModelError::NonPositiveSlope {
                index: (i + 1) as u8,
            });
        }
        abs_sum += if w < 0 { -w } else { w };
        i += 1;
    }
    // Every partial sum of products is bounded by sum|w| * input_max; it must
    // narrow back into the signal range. Raw units: GAIN_FRAC + SIGNAL_FRAC bits.
    // And sum|w| itself fits a gain, so every partial slope S_j is an I4F28.
    if abs_sum * u_max >= (SIGNAL_ABS_MAX_BITS as i64) << GAIN_FRAC || abs_sum > i32::MAX as i64 {
        return Err(ModelError::OutputOutOfRange);
    }
    // Y[input_max] on the loading curve: S_N * U - sum w_i r_i (operators all active).
    let mut acc = w0.wide_mul(input_max.raw());
    let mut j = 0;
    while j < n {
        let y = I16F16::from_bits(input_max.to_bits() - ops[j].threshold.to_bits());
        acc = GainAcc::from_bits(acc.to_bits() + ops[j].weight.wide_mul(y).to_bits());
        j += 1;
    }
    Ok(PiSums {
        // |slope| <= sum|w| fits an i32 (checked above).
        slope: slope as i32,
        offset,
        output_max: narrow_gain(acc),
    })
}

impl<const N: usize> PiModel<N> {
    /// Validates ([`check`]) and builds a model; `const` so an embedded model is
    /// checked at compile time.
    pub const fn new(
        w0: UmPerVolt,
        thresholds: [Volts; N],
        weights: [UmPerVolt; N],
        input_max: Volts,
    ) -> Result<Self, ModelError> {
        let mut ops = [Operator {
            threshold: I16F16::ZERO,
            weight: UmPerVolt::ZERO,
        }; N];
        let mut i = 0;
        while i < N {
            ops[i] = Operator {
                threshold: thresholds[i].raw(),
                weight: weights[i],
            };
            i += 1;
        }
        Self::from_operators(w0, ops, input_max)
    }

    /// [`new`](Self::new) from the operators, thresholds and weights side by side.
    pub const fn from_operators(
        w0: UmPerVolt,
        ops: [Operator<UmPerVolt>; N],
        input_max: Volts,
    ) -> Result<Self, ModelError> {
        let sums = match check(w0, &ops, input_max) {
            Ok(s) => s,
            Err(e) => return Err(e),
        };
        Ok(Self {
            w0,
            ops: Operators::from_parts(ops, sums.slope, sums.offset, q::GAIN_ROUND),
            input_max,
            output_max: sums.output_max,
        })
    }

    /// The same operators with another linear weight `w0` (validated again).
    pub const fn with_w0(&self, w0: UmPerVolt) -> Result<Self, ModelError> {
        Self::from_operators(w0, *self.ops.ops(), self.input_max)
    }

    /// Builds a model from engineering values (µm/V, V); for host tools and tests.
    pub fn from_f64(
        w0: f64,
        thresholds: &[f64; N],
        weights: &[f64; N],
        input_max: f64,
    ) -> Result<Self, ModelError> {
        let g = |x: f64| q::gain(x).ok_or(ModelError::NotRepresentable);
        let s = |x: f64| {
            q::signal(x)
                .map(Volts::from_raw)
                .ok_or(ModelError::NotRepresentable)
        };
        let mut r = [Volts::ZERO; N];
        let mut w = [UmPerVolt::ZERO; N];
        for i in 0..N {
            r[i] = s(thresholds[i])?;
            w[i] = g(weights[i])?;
        }
        Self::new(g(w0)?, r, w, s(input_max)?)
    }

    /// Linear weight `w0`, µm/V.
    pub const fn w0(&self) -> UmPerVolt {
        self.w0
    }
    /// The operators: thresholds `r_i` (V) with their weights `w_i` (µm/V).
    pub const fn operators(&self) -> &[Operator<UmPerVolt>; N] {
        self.ops.ops()
    }
    /// The operators with the sums their banks need.
    pub const fn bank(&self) -> &Operators<UmPerVolt, N> {
        &self.ops
    }
    /// Upper end of the input domain, V.
    pub const fn input_max(&self) -> Volts {
        self.input_max
    }
    /// `Y[input_max]`, the largest output, µm.
    pub const fn output_max(&self) -> Micrometres {
        self.output_max
    }
}

impl<const N: usize, E: Edge> SplitProcess<Volts, Micrometres, PlayBank<N, E>> for PiModel<N> {
    /// One sample: advances the operator states with input `u` (V) and returns `Y[u]` (µm).
    ///
    /// `u` is clamped to `[0, input_max]`. No division, no panic, one rounding.
    #[inline(always)]
    fn process(&self, state: &mut PlayBank<N, E>, u: Volts) -> Micrometres {
        let u = within(u, Volts::ZERO, self.input_max);
        q::narrow_gain_biased(state.advance(&self.ops, u.raw()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> PiModel<3> {
        PiModel::from_f64(0.06, &[10.0, 30.0, 60.0], &[0.01, 0.008, 0.004], 150.0).unwrap()
    }

    #[test]
    fn loading_curve_matches_closed_form() {
        let m = model();
        let mut s = PlayBank::new();
        for k in 0..=150 {
            let u = k as f64;
            let x = m.process(&mut s, Volts::from_num(u)).to_num::<f64>();
            let want = 0.06 * u
                + 0.01 * (u - 10.0).max(0.0)
                + 0.008 * (u - 30.0).max(0.0)
                + 0.004 * (u - 60.0).max(0.0);
            assert!((x - want).abs() < 2e-5, "u={u}: {x} vs {want}");
        }
        let top = m.output_max().to_num::<f64>();
        assert!((top - (0.082 * 150.0 - 0.1 - 0.24 - 0.24)).abs() < 2e-5);
    }

    #[test]
    fn inputs_are_clamped_to_the_domain() {
        let m = model();
        let mut s = PlayBank::new();
        assert_eq!(m.process(&mut s, Volts::from_num(-20)), Micrometres::ZERO);
        let top = m.process(&mut s, Volts::from_num(400));
        assert_eq!(top, m.output_max());
    }

    #[test]
    fn rejects_bad_weight_sets() {
        let e = PiModel::from_f64(0.0, &[10.0], &[0.1], 150.0).unwrap_err();
        assert_eq!(e, ModelError::NonPositiveSlope { index: 0 });
        let e = PiModel::from_f64(0.05, &[10.0, 20.0], &[-0.02, -0.04], 150.0).unwrap_err();
        assert_eq!(e, ModelError::NonPositiveSlope { index: 2 });
        let e = PiModel::from_f64(0.05, &[20.0, 10.0], &[0.01, 0.01], 150.0).unwrap_err();
        assert_eq!(e, ModelError::ThresholdsNotSorted { index: 1 });
        let e = PiModel::from_f64(0.05, &[-1.0], &[0.01], 150.0).unwrap_err();
        assert_eq!(e, ModelError::NegativeThreshold { index: 0 });
        let e = PiModel::from_f64(0.05, &[200.0], &[0.01], 150.0).unwrap_err();
        assert_eq!(e, ModelError::ThresholdBeyondDomain { index: 0 });
        let e = PiModel::from_f64(7.0, &[1.0], &[0.9], 1000.0).unwrap_err();
        assert_eq!(e, ModelError::OutputOutOfRange);
        let e = PiModel::from_f64(f64::NAN, &[1.0], &[0.1], 150.0).unwrap_err();
        assert_eq!(e, ModelError::NotRepresentable);
        // Negative weights are fine while every partial sum stays positive.
        assert!(PiModel::from_f64(0.05, &[10.0, 20.0], &[0.02, -0.04], 150.0).is_ok());
    }
}
