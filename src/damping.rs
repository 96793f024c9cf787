//! Active damping of the stage's first mode from the force sensor: integral force
//! feedback (IFF) on the dynamic part of the force, and the stage dynamics a model
//! declares (what the validator checks the loops against, and what the board
//! refuses to excite).
//!
//! ```text
//! r_d = F_read − f_F(x̂_pea) − p − r_s            N, I16F16    the force channel's dynamic part
//! δ   = −C(z)·r_d,  C(z) = g·(1 − z⁻¹)/((1 − p_h·z⁻¹)(1 − p_l·z⁻¹))      µm, within ±limit
//! ```
//!
//! A force sensor in series with the stack reads `m·ẍ + K_d·ẋ` on top of the
//! preload; integrated, that is velocity feedback, the damper the mode lacks
//! (Preumont's integral force feedback; Fleming & Leang, *Design, Modeling and
//! Control of Nanopositioning Systems*, ch. 8). Because the force channel
//! subtracts the FEM's preload at the estimated extension (and its slow
//! disagreement with the reading), `r_d` holds no static force: the damping loop
//! adds no slow pole to the tracking loop, and its integrator can leak slowly. The
//! correction `δ` goes into the command in micrometres, before the inverse FPI,
//! which linearises the stack: the loop gain is the same all along the hysteresis.
//!
//! # Formats
//!
//! | quantity | unit | format | range |
//! |---|---|---|---|
//! | `g` ([`DampingSpec::gain`]) | µm per N per tick | `I8F24` | 0 < g ≤ [`GAIN_MAX`] |
//! | high-pass, leak rates | 1/tick | `I0F32` | (0, 0.5) |
//! | the section's coefficients | µm/N, 1 | `I8F24` | see [`crate::biquad`] |
//! | the section's input `r_d`, output | N, µm | `I16F16` | output within ±`limit` |
//! | `limit` | µm | `I16F16` | (0, 4096] |
//! | mode frequency ([`DynamicsSpec::mode_mhz`]) | mHz | `u32` | 1 Hz – rate/2 |
//! | damping ratio ([`DynamicsSpec::damping`]) | 1 | `I0F32` | (0, 0.5) |
//! | force gain κ ([`DynamicsSpec::force_gain`]) | N/µm | `I16F16` | > 0 |
//!
//! The section's arithmetic is the biquad's (exact products, one rounding, its
//! residual kept): bounded time, no division, no panic.

use crate::biquad::{Biquad, BiquadState, Coefficient, COEFF_FRAC};
use crate::control::ForceChannel;
use crate::error::{Field, Invalid, ModelError};
use crate::process::SplitProcess;
use crate::q::{
    CreepRate, LoopGain, Micrometres, Newtons, NewtonsPerUm, LOOP_GAIN_FRAC, SIGNAL_ABS_MAX_BITS,
};
use fixed::types::I16F16;

/// Largest IFF gain, µm of command per N of dynamic force per tick.
pub const GAIN_MAX: LoopGain = LoopGain::from_bits(1 << 24);

/// The stage's dynamics as the model declares them (configuration): its first
/// mode, small-signal and undamped, as the loops see it from the command.
///
/// ```text
/// x / x_cmd   = ω²/(s² + 2ζω·s + ω²) · 1/(1 + s/ω_l) · z⁻¹
/// r_d / x_cmd = κ·(s² + 2ζω·s)/(s² + 2ζω·s + ω²) · 1/(1 + s/ω_l) · z⁻¹
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DynamicsSpec {
    /// First mode, mHz.
    pub mode_mhz: u32,
    /// Its damping ratio, `I0F32`, in (0, 0.5).
    pub damping: CreepRate,
    /// The amplifier's (and sensors') lag as a real pole, mHz; 0: none.
    pub lag_mhz: u32,
    /// κ: the dynamic force per µm of command well above the mode, N/µm, `I16F16`
    /// (0: the force channel's response is not known; damping then cannot be
    /// checked and is refused).
    pub force_gain: NewtonsPerUm,
}

impl DynamicsSpec {
    /// Checks the ranges at control rate `rate_hz`: the mode between 1 Hz and the
    /// Nyquist frequency, the damping ratio in (0, 0.5), the lag above the mode (or
    /// none), κ not negative. The one check, shared by the validator and the board.
    pub const fn check(&self, rate_hz: u32) -> Result<(), Invalid> {
        let nyquist_mhz = rate_hz as u64 * 500;
        if self.mode_mhz < 1000 || self.mode_mhz as u64 >= nyquist_mhz {
            return Err(Invalid::at(
                Field::DynamicsModeHz,
                ModelError::DampingOutOfRange,
            ));
        }
        let z = self.damping.to_bits();
        if z <= 0 {
            return Err(Invalid::at(
                Field::DynamicsDamping,
                ModelError::DampingOutOfRange,
            ));
        }
        if self.lag_mhz != 0 && self.lag_mhz <= self.mode_mhz {
            return Err(Invalid::at(
                Field::DynamicsLagHz,
                ModelError::DampingOutOfRange,
            ));
        }
        if self.force_gain.to_bits() < 0 {
            return Err(Invalid::at(
                Field::DynamicsForceGain,
                ModelError::DampingOutOfRange,
            ));
        }
        Ok(())
    }

    /// The mode's frequency, Hz (for host tools and messages).
    pub fn mode_hz(&self) -> f64 {
        self.mode_mhz as f64 / 1000.0
    }

    /// Its damping ratio.
    pub fn damping_ratio(&self) -> f64 {
        self.damping.to_bits() as f64 / 4_294_967_296.0
    }

    /// `|x/x_ref|²` of a sinusoid at `freq_mhz` through the mode with damping
    /// ratio `zeta` (the undamped stage, or the damped one), as `(num, den)` with
    /// `|·|² = num/den`: `1 / ((1 − r²)² + (2ζr)²)`, `r = f/f_n`. Integer-free
    /// arithmetic in `f32` for the link task (not the ISR).
    pub fn gain_squared(&self, freq_mhz: u32, zeta: f32) -> f32 {
        let r = freq_mhz as f32 / self.mode_mhz as f32;
        let a = 1.0 - r * r;
        let b = 2.0 * zeta * r;
        1.0 / (a * a + b * b)
    }
}

/// The damping law's settings as a model stores them (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DampingSpec {
    /// IFF gain `g`, µm of command per N of dynamic force per tick, `I8F24`.
    pub gain: LoopGain,
    /// The high-pass's rate per tick, `I0F32` (`1 − e^{−2π·f_h/f_s}`): below
    /// `f_h` the law stops integrating, so a static force it is given (a model
    /// that is a little off) leaves no lasting correction.
    pub highpass: CreepRate,
    /// The integrator's leak per tick, `I0F32` (`1 − e^{−2π·f_l/f_s}`).
    pub leak: CreepRate,
    /// Largest correction the damping adds to the command, µm.
    pub limit: Micrometres,
}

impl DampingSpec {
    /// The law as a biquad section (`I8F24` coefficients), output held to
    /// `±limit`: `C(z) = g·(1 − z⁻¹)/((1 − p_h·z⁻¹)(1 − p_l·z⁻¹))` with
    /// `p = 1 − rate`. Its static gain is exactly zero (`b0 + b1 = 0`). Integer
    /// arithmetic, so the host and the board build the same section.
    pub const fn section(&self) -> Result<Biquad, Invalid> {
        let frac = COEFF_FRAC;
        // I8F24 → I8F24: two more fractional bits (the gain is at most 1 per tick).
        let b0 = (self.gain.to_bits() as i64) << (frac - LOOP_GAIN_FRAC);
        let one = 1i64 << frac;
        // I0F32 → I8F24, rounded.
        let ph = one - rate_to_coeff(self.highpass);
        let pl = one - rate_to_coeff(self.leak);
        let a1 = -(ph + pl);
        let a2 = (ph * pl + (1 << (frac - 1))) >> frac;
        let lim = self.limit;
        let b = [
            Coefficient::from_bits(b0 as i32),
            Coefficient::from_bits(-b0 as i32),
            Coefficient::ZERO,
        ];
        let a = [
            Coefficient::from_bits(a1 as i32),
            Coefficient::from_bits(a2 as i32),
        ];
        match Biquad::new(b, a) {
            Ok(b) => match b.with_limits(I16F16::from_bits(-lim.to_bits()), lim.raw()) {
                Ok(b) => Ok(b),
                Err(_) => Err(Invalid::at(
                    Field::DampingLimit,
                    ModelError::NotRepresentable,
                )),
            },
            Err(_) => Err(Invalid::at(Field::DampingLeak, ModelError::FilterUnstable)),
        }
    }
}

/// A per-tick rate (`I0F32`) as a coefficient (`I8F24`), rounded.
const fn rate_to_coeff(r: CreepRate) -> i64 {
    const SHIFT: u32 = 32 - COEFF_FRAC;
    ((r.to_bits() as i64) + (1 << (SHIFT - 1))) >> SHIFT
}

/// Validated damping settings and the section they make (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DampingConfig {
    spec: DampingSpec,
    section: Biquad,
}

impl DampingConfig {
    /// Checks `spec`: a positive gain up to [`GAIN_MAX`], a high-pass and a leak
    /// in `(0, 0.5)`, a positive limit in the signal range, and a force channel
    /// that splits the reading (damping needs the dynamic force).
    pub const fn new(spec: DampingSpec, channel: &ForceChannel) -> Result<Self, Invalid> {
        let g = spec.gain.to_bits();
        if g <= 0 || g > GAIN_MAX.to_bits() {
            return Err(Invalid::at(
                Field::DampingGain,
                ModelError::DampingOutOfRange,
            ));
        }
        if spec.highpass.to_bits() <= 0 {
            return Err(Invalid::at(
                Field::DampingHighpass,
                ModelError::DampingOutOfRange,
            ));
        }
        if spec.leak.to_bits() <= 0 {
            return Err(Invalid::at(
                Field::DampingLeak,
                ModelError::DampingOutOfRange,
            ));
        }
        let lim = spec.limit.to_bits();
        if lim <= 0 || lim > SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::DampingLimit,
                ModelError::LimitOutOfRange,
            ));
        }
        if channel.split.to_bits() <= 0 {
            return Err(Invalid::at(
                Field::ForceSplit,
                ModelError::DampingOutOfRange,
            ));
        }
        match spec.section() {
            Ok(section) => Ok(Self { spec, section }),
            Err(e) => Err(e),
        }
    }

    /// The settings.
    pub const fn spec(&self) -> &DampingSpec {
        &self.spec
    }

    /// The section the law runs.
    pub const fn section(&self) -> &Biquad {
        &self.section
    }
}

/// One step of the law with the dynamic force `r_d` (N): the correction (µm),
/// `−C(z)·r_d`, held to `±limit`.
impl SplitProcess<Newtons, Micrometres, Damping> for DampingConfig {
    #[inline]
    fn process(&self, d: &mut Damping, dynamic: Newtons) -> Micrometres {
        let y = self.section.process(&mut d.state, dynamic.raw());
        Micrometres::from_bits(y.to_bits().wrapping_neg())
    }
}

/// The damping law's memory: its section's (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Damping {
    state: BiquadState,
}

impl Damping {
    /// At rest.
    pub const fn new() -> Self {
        Self {
            state: BiquadState::new(),
        }
    }

    /// The correction it adds now, µm.
    pub const fn correction(&self) -> Micrometres {
        Micrometres::from_bits(self.state.output().to_bits().wrapping_neg())
    }

    /// Forgets its memory (after a fault, a park or a new model).
    pub fn reset(&mut self) {
        self.state = BiquadState::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::split_rate;

    const CHANNEL: ForceChannel = ForceChannel {
        split: split_rate(10, 20_000),
        dynamic_limit: Newtons::from_bits(60 << 16),
    };

    fn spec(gain: f64, corner_hz: u32) -> DampingSpec {
        DampingSpec {
            gain: LoopGain::from_num(gain),
            highpass: split_rate(corner_hz, 20_000),
            leak: split_rate(corner_hz, 20_000),
            limit: Micrometres::from_num(4),
        }
    }

    fn cfg(gain: f64, corner_hz: u32) -> DampingConfig {
        DampingConfig::new(spec(gain, corner_hz), &CHANNEL).unwrap()
    }

    #[test]
    fn settings_are_checked_naming_the_key() {
        let good = spec(0.05, 100);
        let bad = |s: DampingSpec| DampingConfig::new(s, &CHANNEL).unwrap_err().field;
        let gain = LoopGain::ZERO;
        assert_eq!(bad(DampingSpec { gain, ..good }), Field::DampingGain);
        let gain = LoopGain::from_num(2);
        assert_eq!(bad(DampingSpec { gain, ..good }), Field::DampingGain);
        let leak = CreepRate::from_bits(-1);
        assert_eq!(bad(DampingSpec { leak, ..good }), Field::DampingLeak);
        let highpass = CreepRate::ZERO;
        assert_eq!(
            bad(DampingSpec { highpass, ..good }),
            Field::DampingHighpass
        );
        let limit = Micrometres::ZERO;
        assert_eq!(bad(DampingSpec { limit, ..good }), Field::DampingLimit);
        let raw = ForceChannel {
            split: CreepRate::ZERO,
            ..CHANNEL
        };
        assert_eq!(
            DampingConfig::new(good, &raw).unwrap_err().field,
            Field::ForceSplit
        );
    }

    /// In its band the law integrates (`g` per tick at first); a held force
    /// leaves no lasting correction (zero static gain); it stays in its limit.
    #[test]
    fn it_integrates_in_its_band_forgets_a_static_force_and_holds_its_limit() {
        let c = cfg(0.01, 100);
        assert_eq!(c.section().dc_gain(), 0.0);
        let mut d = Damping::new();
        let first = c.process(&mut d, Newtons::from_num(1));
        assert!((first.to_num::<f64>() + 0.01).abs() < 1e-4, "{first}");
        for _ in 0..20_000 {
            c.process(&mut d, Newtons::from_num(1));
        }
        assert!(
            d.correction().to_num::<f64>().abs() < 1e-4,
            "{}",
            d.correction()
        );
        // A large force at the band's centre: the output is held to ±4 µm.
        let mut peak = 0.0f64;
        for k in 0..20_000 {
            let f = 100.0 * (k as f64 * core::f64::consts::TAU * 100.0 / 20_000.0).sin();
            peak = peak.max(
                c.process(&mut d, Newtons::from_num(f))
                    .to_num::<f64>()
                    .abs(),
            );
        }
        assert_eq!(peak, 4.0);
        d.reset();
        assert_eq!(d.correction(), Micrometres::ZERO);
    }

    #[test]
    fn dynamics_are_checked_and_give_the_resonance_gain() {
        let d = DynamicsSpec {
            mode_mhz: 850_000,
            damping: CreepRate::from_num(0.03),
            lag_mhz: 2_000_000,
            force_gain: NewtonsPerUm::from_num(7),
        };
        assert_eq!(d.check(20_000), Ok(()));
        let at = |e: DynamicsSpec| e.check(20_000).unwrap_err().field;
        assert_eq!(
            at(DynamicsSpec {
                mode_mhz: 10_000_000,
                ..d
            }),
            Field::DynamicsModeHz
        );
        let damping = CreepRate::ZERO;
        assert_eq!(at(DynamicsSpec { damping, ..d }), Field::DynamicsDamping);
        assert_eq!(
            at(DynamicsSpec {
                lag_mhz: 800_000,
                ..d
            }),
            Field::DynamicsLagHz
        );
        // At the mode the gain is 1/(2ζ) = 16.7; far below it 1.
        let peak = d.gain_squared(850_000, 0.03).sqrt();
        assert!((peak - 16.667).abs() < 0.01, "{peak}");
        assert!((d.gain_squared(10_000, 0.03) - 1.0).abs() < 1e-3);
    }
}
