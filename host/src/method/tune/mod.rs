//! `fpi tune` (and the design step of `fpi board autotune`): the board's loops
//! designed around the stage's first mode, for a stated robustness, and stored
//! with the firmware model — its `[dynamics]`, `[damping]`, `[feedback]` and
//! `[shaping]` sections.
//!
//! **Plant.** What the loops see from the command `x_cmd` (µm, through the
//! inverse FPI, which linearises the stack): the first mode and the amplifier's
//! lag, one tick of delay, the position sensor on the mode's output, and the
//! force channel's dynamic part `κ·(v − x)` ([`piezo_fpi::stability`], the model
//! the board's validator checks). From `fpi identify`'s dynamics (the mode, its
//! damping, the real pole) or from the board's own measurement (`fpi board
//! autotune`), with κ measured there or estimated from the model's stack
//! stiffness, force coupling and lever ([`force_gain_estimate`]).
//!
//! **Robustness.** Every design holds on a family of plants: the mode at 0.8, 0.9,
//! 1.0, 1.1 and 1.2 times the identified one, each with damping 0.01, the
//! identified and 0.06, each at the smallest, unit and largest gain of the
//! model's spread ([`gain_spread`]: the PI's slopes relative to its mean, for
//! feedback alone; at least 0.8–1.25).
//!
//! 1. **Damping** (integral force feedback, [`piezo_fpi::damping`]): the gain that
//!    gives the family's least-damped mode the most damping (up to
//!    [`TuneOptions::target_damping`]), with a 6 dB gain margin (the family stays
//!    stable at twice the gain). Where the force sensor's noise is known
//!    ([`TuneOptions::force_noise_n`]; autotune measures it), the damping also
//!    keeps the stage's noise-driven motion at rest within [`NOISE_BUDGET_UM`]
//!    ([`Family::noise_motion_um`]): the damping feeds the sensor's noise to
//!    the stack, and the loop watch takes a large enough motion for an
//!    oscillation. Where the asked target's loops would move the stage more,
//!    the target is lowered (by fifths) until they do not, down to
//!    [`NOISE_TARGET_MIN`]; below that, no damping.
//! 2. **Position PI** around the damped stage: the largest integral gain, over a
//!    grid of proportional gains, whose sensitivity peak `max|1/(1 + L)|` over the
//!    family stays at or below `max_sensitivity` (1.6: gain margin ≥ 8.5 dB, phase
//!    margin ≥ 36°), and whose crossover stays at or below `--bandwidth-hz` where
//!    one is asked (a crossover the margin does not allow is refused).
//! 3. **Feedforward**: the reference shaping that inverts the nominal damped
//!    closed loop on a step and a 100 Hz triangle ([`feedforward`]); through a
//!    board, autotune then refines its taps on trials on the stage itself
//!    ([`trials`]).
//!
//! Without dynamics there is no mode to design around: only the PI, with its
//! crossover held at `--bandwidth-hz` (20 Hz by default), as a plain integrator
//! on a unit plant with the loop's delay.

pub mod feedforward;
pub mod frf;
pub mod loops;
pub mod simulate;
pub mod trials;

use anyhow::{bail, Result};
use piezo_fpi::control::{split_rate, DEFAULT_SPLIT_HZ};
use piezo_fpi::damping::{DampingSpec, DynamicsSpec};
use piezo_fpi::q::{CreepRate, LoopGain, Micrometres, Newtons};
use piezo_fpi::stability::{section_f64, Laws};
use piezo_sim::file::{
    DampingSection, DynamicsSection, FeedbackSection, FirmwareModel, ShapingSection,
};

pub use feedforward::{Feedforward, TimeOptions};
use loops::{Family, Variant};

use super::dynamics::Dynamics;

/// What `fpi tune` is asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// Largest allowed sensitivity peak `max |1/(1 + L)|` of the position loop.
    pub max_sensitivity: f64,
    /// The highest crossover of the position loop, Hz (`None`: as high as the
    /// margin allows; without dynamics, 20 Hz).
    pub bandwidth_hz: Option<f64>,
    /// Largest correction the feedback may add, µm (`None`: a quarter of the stroke).
    pub limit_um: Option<f64>,
    /// Position-plausibility tolerance, µm (`None`: 15 % of the stroke).
    pub tolerance_um: Option<f64>,
    /// Design active damping (where the dynamics allow it).
    pub damping: bool,
    /// The damping ratio the damping aims for on the least-damped plant.
    pub target_damping: f64,
    /// κ, the dynamic force per µm of command, N/µm (`None`: estimated from the
    /// model).
    pub force_gain: Option<f64>,
    /// Design the feedforward (reference shaping) of the damped stage: the
    /// candidates to choose from (`None`: none).
    pub feedforward: Option<TimeOptions>,
    /// The damping law's band: its high-pass and its leak, Hz.
    pub damping_band_hz: (f64, f64),
    /// σ of the force sensor's white noise, N (`None`: not known, not
    /// designed for).
    pub force_noise_n: Option<f64>,
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self {
            max_sensitivity: 1.6,
            bandwidth_hz: None,
            limit_um: None,
            tolerance_um: None,
            damping: true,
            target_damping: 0.5,
            force_gain: None,
            feedforward: Some(TimeOptions::default()),
            damping_band_hz: (DAMPING_HIGHPASS_HZ, DAMPING_LEAK_HZ),
            force_noise_n: None,
        }
    }
}

/// Crossover without identified dynamics, Hz.
pub const BLIND_BANDWIDTH_HZ: f64 = 20.0;
/// The damping integrator's leak, Hz.
pub const DAMPING_LEAK_HZ: f64 = 100.0;
/// The damping's high-pass, Hz.
pub const DAMPING_HIGHPASS_HZ: f64 = 100.0;
/// The least phase margin of the damping loop at the nominal plant, degrees.
pub const DAMPING_PHASE_MARGIN_DEG: f64 = 45.0;
/// The stage's RMS motion at rest the damping may make of the force sensor's
/// noise, µm: a quarter of the swing the loop watch counts
/// (`fpi_firmware::watch::HALF_SWING`, 0.2 µm), so that the motion's peaks
/// stay below it at four σ. (On the emulated stage as built, tuned at
/// ζ 0.5: 0.02 µm at its σ 0.15 N; at σ 1 N, 0.12 µm, and the watch parked
/// the healthy loop at rest.)
pub const NOISE_BUDGET_UM: f64 = fpi_firmware::watch::HALF_SWING as f64 / 65_536.0 / 4.0;
/// The least damping target the noise lowers the design to, just above the
/// family's least-damped member's own 0.01; below it, no damping. (At 0.05
/// the design fell from a 64 Hz bandwidth at σ 1.3 N to 5 Hz, the PI alone on
/// the undamped family, at 1.6 N; down to 0.012 it degrades gracefully: 39 Hz
/// at 2 N, 31 Hz at 3 N, 16 Hz at 6 N, on stage A as built.)
pub const NOISE_TARGET_MIN: f64 = 0.012;
/// The loop watch's half swing on the tracking error, in RMS of the swing it
/// sees at rest with the loops tuned: peaks of noise beyond five σ are rare,
/// and four half-cycles of them in a row that do not decay (the watch's
/// undecaying rule) rarer still; a transient's irregular peaks (a wave's end
/// on a stage whose mode moved) stay below it more often than below four σ.
pub const WATCH_SWING_RMS: f64 = 5.0;

/// The watch's half swing for a stage whose loops leave `rms_um` (µm RMS) of
/// swing in the tracking error at rest: [`WATCH_SWING_RMS`] of it, within the
/// model's range (`piezo_fpi::model::WATCH_SWING_MIN`…`WATCH_SWING_MAX`,
/// 0.075…0.2 µm), µm.
pub fn watch_swing_um(rms_um: f64) -> f64 {
    let um = |m: piezo_fpi::q::Micrometres| m.to_num::<f64>();
    let (lo, hi) = (
        um(piezo_fpi::model::WATCH_SWING_MIN),
        um(piezo_fpi::model::WATCH_SWING_MAX),
    );
    (WATCH_SWING_RMS * rms_um).clamp(lo, hi)
}

/// What the design chose and what it gives.
#[derive(Debug, Clone, PartialEq)]
pub struct Tuning {
    /// The stage dynamics designed for (absent: none known).
    pub dynamics: Option<DynamicsSpec>,
    /// IFF gain, µm of command per N·s (0: no damping).
    pub damping_gain: f64,
    /// The damping target asked for (0: no damping asked, or no dynamics or
    /// κ to design it on), and the one the design met or approached: the
    /// same, or lower for the force sensor's noise (0: no damping).
    pub damping_target: (f64, f64),
    /// The least damping ratio of the family's mode, without and with damping.
    pub mode_damping: (f64, f64),
    /// Margins of the damping loop at the nominal plant, dB and degrees.
    pub damping_margins: (f64, f64),
    /// Proportional gain, µm/µm.
    pub kp: f64,
    /// Integral gain, 1/s.
    pub ki_per_s: f64,
    /// Gain spread the margin holds for.
    pub gains: [f64; 2],
    /// Sensitivity peak of the position loop over the family.
    pub sensitivity_peak: f64,
    /// Gain crossover at the nominal plant, Hz.
    pub crossover_hz: f64,
    /// The feedback loop's −3 dB bandwidth (`L/(1 + L)`), Hz.
    pub bandwidth_hz: f64,
    /// Gain and phase margins of the position loop at the nominal plant, dB and degrees.
    pub margins: (f64, f64),
    /// The feedforward (sections, or taps on the preview's line; quantised), if designed.
    pub feedforward: Option<Feedforward>,
    /// The stage's RMS motion at rest per N RMS of the force sensor's white
    /// noise, µm/N ([`Family::noise_motion_um`]: the damping feeds the noise
    /// to the stack; 0 without damping).
    pub noise_motion_um_per_n: f64,
    /// The lead's baseline (`piezo_fpi::lead`): the ratio the board's fit of
    /// the explained force settles at on the tuned stage. Measured on the board
    /// (`fpi board autotune`); `None` from the design alone.
    pub lead_baseline: Option<f64>,
    /// The oscillation watch's half swing on the tracking error, µm
    /// (`piezo_fpi::model::WATCH_SWING_MIN`…`WATCH_SWING_MAX`): set from the
    /// noise the loops leave at rest, measured on the board (`fpi board
    /// autotune`); `None` from the design alone (the board's 0.2 µm).
    pub watch_swing_um: Option<f64>,
    /// What the plant was taken to be.
    pub plant: String,
    /// The laws' coefficients per tick as designed (the force channel's split,
    /// the damping section, the PI).
    pub laws: Laws,
}

/// The gain spread the loop must tolerate: the PI's slopes relative to its mean.
pub fn gain_spread(fw: &FirmwareModel) -> [f64; 2] {
    let p = &fw.pi;
    let umax = p.input_max_v;
    let top: f64 = p.weights_um_per_v.iter().sum::<f64>() + p.w0_um_per_v;
    let mean = (p.w0_um_per_v * umax
        + p.thresholds_v
            .iter()
            .zip(&p.weights_um_per_v)
            .map(|(r, w)| w * (umax - r).max(0.0))
            .sum::<f64>())
        / umax;
    if mean.is_nan() || mean <= 0.0 {
        return [0.8, 1.25];
    }
    [
        (p.w0_um_per_v / mean).clamp(0.05, 0.8),
        (top / mean).clamp(1.25, 20.0),
    ]
}

/// κ estimated from the model, N per µm of command: the stack's stiffness `1/c`,
/// softened by the force coupling at the small-signal slope `w0`
/// (`k_p/(1 + w0·k_f·k_p)`), over the lever `df_K/dx_pea` at mid-stroke; `None`
/// for a model without compliance.
pub fn force_gain_estimate(fw: &FirmwareModel) -> Option<f64> {
    let c = fw.coupling.compliance_um_per_n;
    if c.is_nan() || c <= 0.0 {
        return None;
    }
    let kp = 1.0 / c;
    let soft = kp / (1.0 + fw.pi.w0_um_per_v * fw.coupling.k_f_v_per_n * kp);
    let t = &fw.tables.f_k;
    let n = t.values.len();
    if n < 3 {
        return None;
    }
    let (a, b) = (n / 4, 3 * n / 4);
    let lever = (t.values[b] - t.values[a]) / ((b - a) as f64 * t.step());
    (lever > 0.0).then_some(soft / lever)
}

/// The core's dynamics for `d` (its first mode and real pole) with κ.
pub fn dynamics_spec(d: &Dynamics, force_gain: f64) -> Result<DynamicsSpec> {
    let (Some(&f), Some(&z)) = (d.natural_frequency_hz.first(), d.damping_ratio.first()) else {
        bail!("the dynamics name no mode: nothing to design the loops around");
    };
    let lag = d
        .real_pole_hz
        .iter()
        .copied()
        .filter(|&p| p > f)
        .fold(f64::NAN, f64::min);
    Ok(DynamicsSpec {
        mode_mhz: (f * 1000.0).round() as u32,
        damping: CreepRate::from_num(z.clamp(1e-4, 0.49)),
        lag_mhz: if lag.is_finite() {
            (lag * 1000.0).round() as u32
        } else {
            0
        },
        force_gain: Newtons::from_num(force_gain.clamp(0.0, 4000.0)),
    })
}

/// The plant family of the module docs.
fn family(d: &DynamicsSpec, rate_hz: u32, gains: [f64; 2]) -> Family {
    let mut v = Vec::new();
    for &m in &[0.8, 0.9, 1.0, 1.1, 1.2] {
        for &z in &[Some(0.01), None, Some(0.06)] {
            for &g in &[gains[0], 1.0, gains[1]] {
                v.push(Variant {
                    mode_scale: m,
                    zeta: z,
                    gain: g,
                });
            }
        }
    }
    Family::new(d, rate_hz, &v)
}

/// Designs the loops of `fw` (see the module docs).
pub fn tune(fw: &FirmwareModel, dynamics: Option<&Dynamics>, o: &TuneOptions) -> Result<Tuning> {
    check_options(fw, o)?;
    let kappa = o
        .force_gain
        .or_else(|| force_gain_estimate(fw))
        .unwrap_or(0.0);
    let known = match dynamics {
        Some(d) => {
            let spec = dynamics_spec(d, kappa)?;
            let source = if o.force_gain.is_some() {
                "given"
            } else {
                "estimated from the model"
            };
            Some((spec, source))
        }
        None => None,
    };
    design(fw, known, o)
}

/// Designs the loops of `fw` on dynamics measured through the board (κ
/// included).
pub fn tune_measured(fw: &FirmwareModel, spec: DynamicsSpec, o: &TuneOptions) -> Result<Tuning> {
    check_options(fw, o)?;
    design(fw, Some((spec, "measured")), o)
}

/// The option checks [`tune`] and [`tune_measured`] share (and autotune's,
/// before it measures anything).
pub fn check_options(fw: &FirmwareModel, o: &TuneOptions) -> Result<()> {
    if !(o.max_sensitivity > 1.05 && o.max_sensitivity <= 3.0) {
        bail!(
            "--max-sensitivity {}: between 1.05 and 3 (1.6 gives ≥ 8.5 dB and ≥ 36°)",
            o.max_sensitivity
        );
    }
    let nyquist = fw.controller.rate_hz as f64 / 2.0;
    if let Some(b) = o.bandwidth_hz {
        if !(b > 0.0 && b.is_finite() && b < nyquist) {
            bail!(
                "--bandwidth-hz {b}: a crossover between 0 and the Nyquist frequency ({nyquist} Hz)"
            );
        }
    }
    let (highpass, leak) = o.damping_band_hz;
    if !([highpass, leak].iter().all(|&f| f > 0.0 && f < nyquist)) {
        bail!(
            "damping_band_hz ({highpass}, {leak}): the damping's high-pass and leak, each \
             between 0 and the Nyquist frequency ({nyquist} Hz)"
        );
    }
    if !(o.target_damping > 0.0 && o.target_damping <= 1.0) {
        bail!("--target-damping {}: between 0 and 1", o.target_damping);
    }
    if let Some(n) = o.force_noise_n {
        if !(0.0..1e3).contains(&n) {
            bail!("--force-noise-n {n}: a σ in newtons, at least 0");
        }
    }
    Ok(())
}

/// The design on `known` dynamics (with where κ came from), or on none.
fn design(
    fw: &FirmwareModel,
    known: Option<(DynamicsSpec, &str)>,
    o: &TuneOptions,
) -> Result<Tuning> {
    let rate = fw.controller.rate_hz;
    let gains = gain_spread(fw);
    let split = split_hz(fw);
    let (spec, plant) = match known {
        Some((spec, source)) => {
            let text = format!(
                "mode {:.1} Hz (ζ {:.4}), lag {}, κ {:.2} N/µm ({source}); one tick of delay",
                spec.mode_hz(),
                spec.damping_ratio(),
                if spec.lag_mhz == 0 {
                    "none".to_string()
                } else {
                    format!("{:.0} Hz", spec.lag_mhz as f64 / 1000.0)
                },
                spec.force_gain.to_num::<f64>(),
            );
            (spec, text)
        }
        None => (
            blind_dynamics(rate),
            "no dynamics: a unit plant with one tick of delay".into(),
        ),
    };
    let dynamics = known.map(|k| k.0);
    let kappa = spec.force_gain.to_num::<f64>();
    let fam = family(&spec, rate, gains);
    let base = Laws {
        split: split_rate_f64(split, rate),
        ..Laws::default()
    };
    let open = fam.mode_damping(&spec, rate, &base);
    let cap = match (dynamics, o.bandwidth_hz) {
        (_, Some(b)) => Some(b),
        (None, None) => Some(BLIND_BANDWIDTH_HZ),
        (Some(_), None) => None,
    };
    let pi = |l: Laws| {
        design_pi(
            &fam,
            l,
            o.max_sensitivity,
            (cap, o.bandwidth_hz.is_some()),
            rate,
        )
    };
    let damps = o.damping && dynamics.is_some() && kappa > 0.0;
    let damped = if damps {
        design_for_noise(o, |target| {
            let l = design_damping(&fam, &spec, rate, base, (target, o.damping_band_hz))?;
            let l = pi(l)?;
            Ok((l, fam.noise_motion_um(&l, 1.0)))
        })?
    } else {
        None
    };
    let (laws, target) = match damped {
        Some(d) => d,
        None => (pi(base)?, 0.0),
    };
    let with_damping = laws.damps();
    // The damping's own (the PI's poles left out, as before it is designed).
    let damping_only = Laws {
        kp: 0.0,
        ki: 0.0,
        ..laws
    };
    let damped = fam.mode_damping(&spec, rate, &damping_only);
    let feedforward = match (&o.feedforward, dynamics) {
        (Some(ff), Some(_)) => {
            let p = piezo_fpi::stability::Plant::new(&spec, rate, 1.0, None, 1.0);
            Some(feedforward::design(&p, &laws, rate as f64, ff)?)
        }
        _ => None,
    };
    Ok(Tuning {
        dynamics: dynamics.map(|_| spec),
        damping_gain: if with_damping {
            damping_gain_of(&laws, rate)
        } else {
            0.0
        },
        damping_target: (if damps { o.target_damping } else { 0.0 }, target),
        mode_damping: (open, damped),
        damping_margins: if with_damping {
            fam.damping_margins(&laws)
        } else {
            (f64::INFINITY, f64::INFINITY)
        },
        kp: laws.kp,
        ki_per_s: laws.ki * rate as f64,
        gains,
        sensitivity_peak: fam.sensitivity_peak(&laws),
        crossover_hz: fam.crossover_hz(&laws),
        bandwidth_hz: fam.feedback_bandwidth_hz(&laws),
        margins: fam.margins(&laws),
        feedforward,
        noise_motion_um_per_n: fam.noise_motion_um(&laws, 1.0),
        lead_baseline: None,
        watch_swing_um: None,
        plant,
        laws,
    })
}

/// The damped loops `at(target)` gives (with their motion per N of force
/// noise, µm/N) at `o.target_damping`, or at the highest target a fifth lower
/// at a time whose noise-driven motion stays within [`NOISE_BUDGET_UM`]
/// (where [`TuneOptions::force_noise_n`] is known), with the target used;
/// `None` where none down to [`NOISE_TARGET_MIN`] does (the caller designs
/// without damping).
fn design_for_noise(
    o: &TuneOptions,
    mut at: impl FnMut(f64) -> Result<(Laws, f64)>,
) -> Result<Option<(Laws, f64)>> {
    let sigma = o.force_noise_n.unwrap_or(0.0);
    let mut target = o.target_damping;
    loop {
        let (laws, per_n) = at(target)?;
        if per_n * sigma <= NOISE_BUDGET_UM {
            return Ok(Some((laws, target)));
        }
        target *= 0.8;
        if target < NOISE_TARGET_MIN {
            return Ok(None);
        }
    }
}

/// The damping section's gain `b0`, per second.
fn damping_gain_of(l: &Laws, rate: u32) -> f64 {
    l.damping[0] * rate as f64
}

/// A stand-in for unknown dynamics: a mode far above the loop (at a quarter of
/// the rate, well damped), so that only the delay matters.
fn blind_dynamics(rate_hz: u32) -> DynamicsSpec {
    DynamicsSpec {
        mode_mhz: rate_hz * 250,
        // The largest damping ratio the spec holds (`I0F32` stops below 0.5);
        // `from_num(0.7)` overflowed and panicked.
        damping: CreepRate::from_bits(0x7333_3333), // 0.45
        lag_mhz: 0,
        force_gain: Newtons::ZERO,
    }
}

/// The model's force-channel corner, Hz.
fn split_hz(fw: &FirmwareModel) -> f64 {
    fw.controller
        .force_split_hz
        .unwrap_or(DEFAULT_SPLIT_HZ as f64)
}

/// `1 − e^{−2π·f/f_s}` as the board quantises it.
pub fn split_rate_f64(f_hz: f64, rate_hz: u32) -> f64 {
    if f_hz.fract() == 0.0 && (0.0..1e6).contains(&f_hz) {
        return split_rate(f_hz as u32, rate_hz).to_num::<f64>();
    }
    -(-std::f64::consts::TAU * f_hz / rate_hz as f64).exp_m1()
}

/// The damping gain: the least one that gives the family's least-damped mode the
/// target damping, or else the most damping, with the family stable at twice the
/// gain and the nominal damping loop's phase margin at least
/// [`DAMPING_PHASE_MARGIN_DEG`].
fn design_damping(
    fam: &Family,
    d: &DynamicsSpec,
    rate: u32,
    base: Laws,
    (target, band): (f64, (f64, f64)),
) -> Result<Laws> {
    let mut best: Option<(f64, Laws)> = None;
    for k in 0..60 {
        let g = 20.0 * (1e5_f64 / 20.0).powf(k as f64 / 59.0);
        let Some(laws) = damping_laws(base, g, rate, band) else {
            break;
        };
        let Some(doubled) = damping_laws(base, 2.0 * g, rate, band) else {
            break;
        };
        if !(fam.all_stable(&laws) && fam.all_stable(&doubled)) {
            break;
        }
        if fam.damping_margins(&laws).1 < DAMPING_PHASE_MARGIN_DEG {
            break;
        }
        let z = fam.mode_damping(d, rate, &laws);
        if best.as_ref().is_none_or(|(bz, _)| z > *bz + 1e-6) {
            best = Some((z, laws));
        }
        if z >= target {
            break;
        }
    }
    match best {
        Some((_, l)) => Ok(l),
        None => bail!(
            "no damping gain keeps the stage stable with a 6 dB margin over the mode's spread \
             (mode {:.0} Hz ±20 %, κ {:.2} N/µm): check the dynamics",
            d.mode_hz(),
            d.force_gain.to_num::<f64>()
        ),
    }
}

/// The damping law of gain `g` (µm/(N·s)) with the default corners, as the
/// board quantises it; `None` where the core cannot build it.
pub fn damping_spec(g: f64, rate: u32, limit_um: f64, band_hz: (f64, f64)) -> Option<DampingSpec> {
    let fs = rate as f64;
    let rate_of = |f: f64| CreepRate::checked_from_num(split_rate_f64(f, rate));
    Some(DampingSpec {
        gain: LoopGain::checked_from_num(g / fs)?,
        highpass: rate_of(band_hz.0)?,
        leak: rate_of(band_hz.1)?,
        limit: Micrometres::checked_from_num(limit_um)?,
    })
}

fn damping_laws(base: Laws, g: f64, rate: u32, band_hz: (f64, f64)) -> Option<Laws> {
    let s = damping_spec(g, rate, 4.0, band_hz)?.section().ok()?;
    Some(Laws {
        damping: section_f64(&s),
        ..base
    })
}

/// The PI: the largest integral gain, over a grid of proportional gains, that
/// holds the sensitivity peak and the stability margin on the family and the
/// crossover at or below `cap`; a cap the user `asked` for that the margins do
/// not reach is refused.
fn design_pi(
    fam: &Family,
    base: Laws,
    ms: f64,
    (cap, asked): (Option<f64>, bool),
    rate: u32,
) -> Result<Laws> {
    let fs = rate as f64;
    let holds = |l: &Laws| {
        fam.sensitivity_peak(l) <= ms
            && fam.all_stable(l)
            && cap.is_none_or(|c| fam.crossover_hz(l) <= c)
    };
    let mut best: Option<Laws> = None;
    for j in 0..=24 {
        let kp = j as f64 * 0.05;
        let mut ki = 1.0 / fs;
        let at = |ki: f64| Laws { kp, ki, ..base };
        if !holds(&at(ki)) {
            continue;
        }
        // Grow, then bisect the last step.
        let mut hi = ki;
        while hi < 0.25 && holds(&at(hi * 1.25)) {
            hi *= 1.25;
        }
        ki = hi;
        let mut top = hi * 1.25;
        for _ in 0..8 {
            let mid = (ki + top) / 2.0;
            if holds(&at(mid)) {
                ki = mid;
            } else {
                top = mid;
            }
        }
        if best.is_none_or(|b| ki > b.ki) {
            best = Some(at(ki));
        }
    }
    let Some(l) = best else {
        bail!(
            "no gains hold a sensitivity peak of {ms} over the plant family: the plant's \
             delay or mode leaves no room (try a larger --max-sensitivity)"
        );
    };
    if let (Some(c), true) = (cap, asked) {
        let got = fam.crossover_hz(&l);
        if got < 0.9 * c {
            bail!(
                "--bandwidth-hz {c}: the margins allow a crossover of {got:.0} Hz at most \
                 (sensitivity peak ≤ {ms} over the mode's spread and the gain spread); ask for \
                 less, or accept a larger --max-sensitivity"
            );
        }
    }
    Ok(l)
}

impl Tuning {
    /// What the force sensor's noise `n` (N) made of the damping, one line.
    fn noise_line(&self, n: f64) -> String {
        let motion = self.noise_motion_um_per_n * n;
        let budget = format!("budget {NOISE_BUDGET_UM:.2} µm");
        let (asked, used) = self.damping_target;
        if asked == 0.0 {
            String::new()
        } else if used == 0.0 {
            format!(
                "no damping: the force sensor's noise (σ {n:.2} N) would move the stage more \
                 than the {budget} RMS at rest even at a target of {NOISE_TARGET_MIN}\n"
            )
        } else if used < asked {
            format!(
                "damping target {used:.2}, lowered from {asked:.2} for the force sensor's noise \
                 (σ {n:.2} N): {motion:.3} µm RMS at rest ({budget})\n"
            )
        } else {
            format!(
                "the force sensor's noise (σ {n:.2} N): {motion:.3} µm RMS at rest ({budget})\n"
            )
        }
    }

    /// One line per loop, for people.
    pub fn summary(&self, o: &TuneOptions) -> String {
        let mut s = format!("plant: {}\n", self.plant);
        if self.damping_gain > 0.0 {
            s += &format!(
                "damping: IFF gain {:.0} µm/(N·s) between {} Hz and {} Hz; least damping of \
                 the family's poles {:.3} → {:.3}; damping loop GM {:.1} dB, PM {:.0}°\n",
                self.damping_gain,
                o.damping_band_hz.0,
                o.damping_band_hz.1,
                self.mode_damping.0,
                self.mode_damping.1,
                self.damping_margins.0,
                self.damping_margins.1
            );
        }
        if let Some(n) = o.force_noise_n {
            s += &self.noise_line(n);
        }
        s += &format!(
            "position PI: kp {:.3}, ki {:.1}/s; gain spread {:.2}–{:.2}; sensitivity peak {:.2} \
             (limit {}); crossover {:.1} Hz, −3 dB bandwidth {:.0} Hz, GM {:.1} dB, PM {:.0}°",
            self.kp,
            self.ki_per_s,
            self.gains[0],
            self.gains[1],
            self.sensitivity_peak,
            o.max_sensitivity,
            self.crossover_hz,
            self.bandwidth_hz,
            self.margins.0,
            self.margins.1
        );
        if let Some(ff) = &self.feedforward {
            s += &format!("\nfeedforward: {}", ff.describe());
        }
        s
    }
}

/// `fw` with the sections `t` gives: `[dynamics]`, `[damping]` (where designed),
/// `[feedback]` (the gains, the correction's limit and the position sensor's
/// range and tolerance from the model's stroke), `[shaping]` (the feedforward,
/// where designed) and a dynamic force limit wide enough for the stage's mode.
pub fn with_tuning(fw: &FirmwareModel, t: &Tuning, o: &TuneOptions) -> Result<FirmwareModel> {
    let k = &fw.controller;
    let span = k.reference_max_um - k.reference_min_um;
    if span.is_nan() || span <= 0.0 {
        bail!("the model's stroke is empty: controller.reference_min_um ≥ reference_max_um");
    }
    let channel = fpi_firmware::frontend::POSITION_ADC;
    let (chan_lo, lsb) = (
        channel.offset.to_num::<f64>(),
        channel.per_count.to_num::<f64>(),
    );
    let chan_hi = chan_lo + lsb * fpi_firmware::frontend::POSITION_MAX as f64;
    // Inside the rails, so that a broken wire (a rail) is out of range.
    let lo = (k.reference_min_um - 0.25 * span).max(chan_lo + 16.0 * lsb);
    let hi = (k.reference_max_um + 0.25 * span).min(chan_hi - 16.0 * lsb);
    let mut out = fw.clone();
    let summary = t.summary(o).replace('\n', "; ");
    out.feedback = Some(FeedbackSection {
        kp: t.kp,
        ki_per_s: t.ki_per_s,
        limit_um: o.limit_um.unwrap_or(0.25 * span),
        position_min_um: lo,
        position_max_um: hi,
        position_tolerance_um: o.tolerance_um.unwrap_or(0.15 * span),
        watch_swing_um: t.watch_swing_um,
        notes: format!("fpi tune: {summary}"),
    });
    if let Some(d) = &t.dynamics {
        out.dynamics = Some(DynamicsSection {
            mode_hz: d.mode_hz(),
            damping_ratio: d.damping_ratio(),
            lag_hz: (d.lag_mhz > 0).then(|| d.lag_mhz as f64 / 1000.0),
            force_gain_n_per_um: (d.force_gain > Newtons::ZERO)
                .then(|| d.force_gain.to_num::<f64>()),
            notes: format!("fpi tune: {}", t.plant),
        });
        // The mode rings the force by tens of newtons on a fast move: the dynamic
        // limit is the preload's range, the slow part keeps the tolerance.
        let preload_span = k.force_max_n - k.force_min_n;
        out.controller.force_dynamic_limit_n = Some(
            (0.5 * preload_span)
                .max(k.force_tolerance_n)
                .min(piezo_fpi::q::SIGNAL_ABS_MAX),
        );
    }
    out.damping = (t.damping_gain > 0.0).then(|| DampingSection {
        gain_um_per_n_s: t.damping_gain,
        highpass_hz: o.damping_band_hz.0,
        leak_hz: o.damping_band_hz.1,
        // A fast step asks the damping for a correction of its own size.
        limit_um: span,
        // Measured on the board, by `fpi board autotune` (piezo_fpi::lead).
        lead_baseline: t.lead_baseline,
        notes: format!("fpi tune: {summary}"),
    });
    if let Some(ff) = &t.feedforward {
        let (sections, preview_ticks, taps) = match ff {
            Feedforward::Sections(s) => (s.clone(), 0, Vec::new()),
            Feedforward::Preview { ticks, taps, .. } => (Vec::new(), *ticks, taps.clone()),
        };
        out.shaping = Some(ShapingSection {
            sections,
            preview_ticks,
            taps,
            notes: format!(
                "fpi tune: the feedforward of the damped stage ({}, least squares on a step \
                 and a triangle)",
                ff.describe()
            ),
        });
    }
    out.check().map_err(anyhow::Error::msg)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use piezo_fpi::stability::{decays, Plant};

    /// Stage A as built, as autotune fits it (850 Hz, ζ 0.03, a 1.9 kHz lag,
    /// κ 6.3 N/µm).
    pub(super) fn stage_a() -> (FirmwareModel, DynamicsSpec) {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/model/stage-a.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let fw = FirmwareModel::parse(&text, "stage-a.toml").unwrap();
        let d = DynamicsSpec {
            mode_mhz: 850_000,
            damping: CreepRate::from_num(0.03),
            lag_mhz: 1_900_000,
            force_gain: Newtons::from_num(6.3),
        };
        (fw, d)
    }

    /// The feedforward autotune designs by default: taps on the preview's line
    /// summing to 1 exactly; on the linear loops it designs for, a 10 µm, 1.5 ms
    /// step settles within ±0.1 µm in under 2 ms with little overshoot and the
    /// 100 Hz triangle is tracked far better than by the two sections without
    /// a preview (the figures are printed).
    #[test]
    fn the_preview_feedforward_tracks_the_linear_loops() {
        use simulate::{respond_led, step, triangle};
        let (fw, d) = stage_a();
        let rate = fw.controller.rate_hz;
        let t = tune_measured(&fw, d, &TuneOptions::default()).unwrap();
        let Some(Feedforward::Preview { ticks, taps, .. }) = &t.feedforward else {
            panic!("{:?}", t.feedforward)
        };
        let one = f64::from(1u32 << piezo_fpi::biquad::COEFF_FRAC);
        let raw: i64 = taps.iter().map(|h| (h * one) as i64).sum();
        assert_eq!(
            (*ticks, taps.len(), raw),
            (5, piezo_fpi::preview::TAPS, 1i64 << 24)
        );
        let p = Plant::new(&d, rate, 1.0, None, 1.0);
        let n = usize::from(*ticks);
        // The board's loops: the shaped reference from the line, the lead force.
        let run = |r: &[f64]| {
            let u: Vec<f64> = (0..r.len())
                .map(|k| {
                    (0..taps.len())
                        .map(|j| taps[j] * r[(k + n).saturating_sub(j).min(r.len() - 1)])
                        .sum()
                })
                .collect();
            let lead: Vec<f64> = (0..r.len())
                .map(|k| p.force_gain * (if k > 0 { u[k - 1] } else { 0.0 } - r[k]))
                .collect();
            respond_led(&p, &t.laws, r, &u, &lead, true)
        };
        let r = step(10.0, 30, 40, 600);
        let y = run(&r);
        let overshoot = y.iter().fold(f64::MIN, |m, v| m.max(v - 10.0));
        let out = (0..y.len())
            .rev()
            .find(|&k| (y[k] - 10.0).abs() > 0.1)
            .unwrap();
        let settle_ms = (out + 1 - 40) as f64 / rate as f64 * 1e3;
        let tr = triangle(15.0, (rate / 100) as usize, 6);
        let y = run(&tr);
        let e: Vec<f64> = (2 * rate as usize / 100..tr.len())
            .filter(|&k| tr[k].abs() <= 12.0)
            .map(|k| y[k] - tr[k])
            .collect();
        let rms = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
        println!("linear loops: step overshoot {overshoot:.3} µm, settles in {settle_ms:.2} ms; triangle {rms:.3} µm RMS");
        assert!(
            overshoot < 0.2 && settle_ms < 2.0,
            "{overshoot} {settle_ms}"
        );
        assert!(rms < 0.1, "{rms}");
    }

    /// The gain margins `fpi tune` reports (read off the loops' frequency
    /// responses on a grid) agree with an independent discrete-time evaluation:
    /// the closed loop's state matrix, iterated ([`decays`]), with the loop's
    /// gain scaled by the margin decays just below it and not just above it (2 %
    /// either side; the damping loop's margin was 4 dB too high before the
    /// crossings were located by bisection).
    #[test]
    fn the_reported_gain_margins_are_where_the_discrete_time_loop_turns_unstable() {
        let (fw, d) = stage_a();
        let rate = fw.controller.rate_hz;
        let t = tune_measured(&fw, d, &TuneOptions::default()).unwrap();
        let plant = Plant::new(&d, rate, 1.0, None, 1.0);
        let stable = |l: &Laws| decays(&plant.closed_loop(l));
        assert!(stable(&t.laws));
        // The position loop: the PI scaled by its gain margin.
        let k = 10f64.powf(t.margins.0 / 20.0);
        let pi = |f: f64| Laws {
            kp: t.laws.kp * f,
            ki: t.laws.ki * f,
            ..t.laws
        };
        println!("position loop: {:.2} dB, {:.1}°", t.margins.0, t.margins.1);
        assert!(t.margins.0 > 3.0 && t.margins.0 < 40.0, "{:?}", t.margins);
        assert!(stable(&pi(0.98 * k)), "stable below the margin ({k})");
        assert!(!stable(&pi(1.02 * k)), "unstable above the margin ({k})");
        // The damping loop alone (the PI off): its section scaled by its margin.
        let k = 10f64.powf(t.damping_margins.0 / 20.0);
        let damping = |f: f64| {
            let mut l = Laws {
                kp: 0.0,
                ki: 0.0,
                ..t.laws
            };
            for b in &mut l.damping[..3] {
                *b *= f;
            }
            l
        };
        println!(
            "damping loop: {:.2} dB, {:.1}°",
            t.damping_margins.0, t.damping_margins.1
        );
        assert!(stable(&damping(0.98 * k)), "stable below the margin ({k})");
        assert!(
            !stable(&damping(1.02 * k)),
            "unstable above the margin ({k})"
        );
    }

    #[test]
    fn a_bandwidth_beyond_nyquist_or_the_margins_is_refused() {
        let (fw, d) = stage_a();
        for (b, says) in [(1e6, "Nyquist"), (5000.0, "allow a crossover")] {
            let o = TuneOptions {
                bandwidth_hz: Some(b),
                ..TuneOptions::default()
            };
            let e = tune_measured(&fw, d, &o).unwrap_err().to_string();
            assert!(e.contains(says), "{b} Hz: {e}");
        }
    }

    /// The noise-driven motion the design predicts (from the loops' frequency
    /// responses) agrees with the loops simulated tick by tick
    /// ([`simulate::Loops`]) with white noise of σ 1 N on the force sensor,
    /// within 5 % over 10 s.
    #[test]
    fn the_predicted_noise_motion_matches_the_loops_simulated() {
        use simulate::{filter, Loops};
        let (fw, d) = stage_a();
        let rate = fw.controller.rate_hz;
        let t = tune_measured(&fw, d, &TuneOptions::default()).unwrap();
        let p = Plant::new(&d, rate, 1.0, None, 1.0);
        // Uniform white noise of unit variance (xorshift32).
        let mut rng = 0x2545_f491_u32;
        let noise: Vec<f64> = (0..10 * rate as usize)
            .map(|_| {
                rng ^= rng << 13;
                rng ^= rng >> 17;
                rng ^= rng << 5;
                (f64::from(rng) / f64::from(u32::MAX) - 0.5) * 12f64.sqrt()
            })
            .collect();
        // The sensor's noise reaches the damping through the split's high-pass,
        // as the force does: left out of it with the opposite sign.
        let a = 1.0 - t.laws.split;
        let through = filter(&[a, -a], &[1.0, -a], &noise);
        let mut loops = Loops::new(&p, &t.laws);
        let x: Vec<f64> = through
            .iter()
            .map(|n| loops.tick(0.0, 0.0, -n, true))
            .collect();
        let tail = &x[rate as usize / 10..];
        let rms = (tail.iter().map(|v| v * v).sum::<f64>() / tail.len() as f64).sqrt();
        let predicted = t.noise_motion_um_per_n;
        println!("σ 1 N: simulated {rms:.4} µm RMS, predicted {predicted:.4}");
        assert!((rms / predicted - 1.0).abs() < 0.05, "{rms} {predicted}");
    }

    /// The force sensor's noise lowers the damping until the motion it drives
    /// stays within the budget (σ 1 N: the default target's loops move the stage
    /// about 0.12 µm RMS), and takes it off where nothing above the least target
    /// does (σ 10 N); the stage as built's own σ 0.15 N changes nothing.
    #[test]
    fn the_damping_is_designed_for_the_force_sensor_s_noise() {
        let (fw, d) = stage_a();
        let with = |n: Option<f64>| {
            let o = TuneOptions {
                force_noise_n: n,
                ..TuneOptions::default()
            };
            (tune_measured(&fw, d, &o).unwrap(), o)
        };
        let (free, _) = with(None);
        let (quiet, _) = with(Some(0.15));
        assert_eq!(quiet.laws, free.laws);
        assert_eq!(quiet.damping_target, (0.5, 0.5));
        let (noisy, o) = with(Some(1.0));
        let (asked, used) = noisy.damping_target;
        let motion = noisy.noise_motion_um_per_n;
        println!(
            "σ 1 N: target {used:.3}, {motion:.4} µm RMS; {}",
            noisy.summary(&o)
        );
        assert!(free.noise_motion_um_per_n > NOISE_BUDGET_UM * 2.0);
        assert!(used < asked && used >= NOISE_TARGET_MIN, "{used}");
        assert!(
            motion <= NOISE_BUDGET_UM && noisy.damping_gain > 0.0,
            "{motion}"
        );
        assert!(noisy.summary(&o).contains("lowered from 0.50"));
        let (loud, o) = with(Some(10.0));
        assert_eq!((loud.damping_gain, loud.damping_target.1), (0.0, 0.0));
        assert!(loud.summary(&o).starts_with("plant") && loud.summary(&o).contains("no damping"));
        // No damping asked: nothing lowered, nothing said of the noise.
        let o = TuneOptions {
            damping: false,
            force_noise_n: Some(1.0),
            ..TuneOptions::default()
        };
        let none = tune_measured(&fw, d, &o).unwrap();
        assert_eq!(none.damping_target, (0.0, 0.0));
        assert!(!none.summary(&o).contains("noise"), "{}", none.summary(&o));
    }
}
