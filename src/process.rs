//! The core's one processing verb: a block's configuration (validated,
//! immutable, shared) processes one sample through the block's state
//! (`config.process(&mut state, x)`), in the spirit of idsp's
//! `SplitProcess`. Configuration apart from state lets one configuration
//! serve several states (an array of per-axis blocks) and a block be swapped
//! between ticks without touching its memory; one verb lets blocks compose.
//!
//! | block | configuration | state | `x` | `y` |
//! |---|---|---|---|---|
//! | biquad section | [`Biquad`](crate::biquad::Biquad) | [`BiquadState`](crate::biquad::BiquadState) | `I16F16` | `I16F16` |
//! | cascade of sections | [`Cascade`](crate::biquad::Cascade) | [`CascadeState`](crate::biquad::CascadeState) | `I16F16` | `I16F16` |
//! | forward PI (play operators) | [`PiModel`](crate::pi::PiModel) | [`PlayBank`](crate::play::PlayBank) | V | µm |
//! | inverse PI | [`InversePi`](crate::inverse::InversePi) | a [`Bank`](crate::play::Bank) | µm | V |
//! | damping (IFF) | [`DampingConfig`](crate::damping::DampingConfig) | [`Damping`](crate::damping::Damping) | N (dynamic force) | µm (correction) |
//! | position PI | [`FeedbackConfig`](crate::feedback::FeedbackConfig) | [`Pi`](crate::feedback::Pi) | (error µm, saturation, output range) | µm |
//! | explained force (lead) | [`LeadSpec`](crate::lead::LeadSpec) | [`LeadGain`](crate::lead::LeadGain) | (force N, lead µm, acceleration µm/tick², learn) | N |
//! | preview feedforward | [`Fir`](crate::preview::Fir) | [`Preview`](crate::preview::Preview) | µm (reference ahead) | (tracked µm, feedforward µm) |
//! | decoupling matrix | [`Matrix`](crate::decoupling::Matrix) | `()` | `[µm; N]` (every axis) | `[µm; N]` |
//! | reference governor | [`GovernorConfig`](crate::governor::GovernorConfig) | [`GovernorState`](crate::governor::GovernorState) | µm (source) | µm (governed) |

/// A block whose configuration processes one sample `x` through its state.
pub trait SplitProcess<X, Y = X, S = ()> {
    /// One sample: `x` in, the output out, `state` advanced. Bounded time, no
    /// division, no panic (each block's documentation says what it does).
    fn process(&self, state: &mut S, x: X) -> Y;
}

/// Per-axis blocks: an array of configurations processes an array of inputs
/// through an array of states, axis by axis (an XYZ stage's three damping
/// laws are one `[DampingConfig; 3]` over `[Damping; 3]`).
impl<X, Y, S, P, const N: usize> SplitProcess<[X; N], [Y; N], [S; N]> for [P; N]
where
    X: Copy,
    Y: Copy + Default,
    P: SplitProcess<X, Y, S>,
{
    #[inline]
    fn process(&self, state: &mut [S; N], x: [X; N]) -> [Y; N] {
        let mut y = [Y::default(); N];
        for ((p, s), (x, y)) in self
            .iter()
            .zip(state.iter_mut())
            .zip(x.iter().zip(y.iter_mut()))
        {
            *y = p.process(s, *x);
        }
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::biquad::{Biquad, BiquadState, Coefficient};
    use fixed::types::I16F16;

    /// A first-order low-pass `g(1 + z⁻¹)/(1 − p z⁻¹)`, `g = (1 − p)/2`.
    fn low_pass(p: f64) -> Biquad {
        let c = Coefficient::from_num;
        let g = (1.0 - p) / 2.0;
        Biquad::new([c(g), c(g), c(0.0)], [c(-p), c(0.0)]).unwrap()
    }

    /// Three axes' sections, one array: each axis is its own section
    /// processing its own input through its own state, as one at a time.
    #[test]
    fn an_array_of_blocks_processes_each_axis_as_alone() {
        let cfg = [low_pass(0.5), low_pass(0.9), Biquad::IDENTITY];
        let (mut states, mut alone) = ([BiquadState::new(); 3], [BiquadState::new(); 3]);
        for k in 0..50 {
            let x = [k, 2 * k, -k].map(I16F16::from_num);
            let y = cfg.process(&mut states, x);
            for a in 0..3 {
                assert_eq!(y[a], cfg[a].process(&mut alone[a], x[a]));
            }
            assert_eq!(states, alone);
        }
    }
}
