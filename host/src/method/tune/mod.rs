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
use piezo_fpi::q::{CreepRate, LoopGain, Micrometres, NewtonsPerUm};
use piezo_fpi::stability::{section_f64, Laws};
use piezo_sim::file::{
    DampingSection, DynamicsSection, FeedbackSection, FirmwareModel, ShapingSection,
};

pub use feedforward::{Feedforward, TimeOptions};
use loops::{Family, Variant};

use super::dynamics::Dynamics;

mod design;
use design::design;
pub use design::{damping_spec, split_rate_f64};

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
/// (`fpi_firmware::control::watch::HALF_SWING`, 0.2 µm), so that the motion's peaks
/// stay below it at four σ. (On the emulated stage as built, tuned at
/// ζ 0.5: 0.02 µm at its σ 0.15 N; at σ 1 N, 0.12 µm, and the watch parked
/// the healthy loop at rest.)
pub const NOISE_BUDGET_UM: f64 = fpi_firmware::control::watch::HALF_SWING as f64 / 65_536.0 / 4.0;
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
        force_gain: NewtonsPerUm::from_num(force_gain.clamp(0.0, 4000.0)),
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
    let channel = fpi_firmware::board::analog_in::POSITION_ADC;
    let (chan_lo, lsb) = (
        channel.offset.to_num::<f64>(),
        channel.per_count.to_num::<f64>(),
    );
    let chan_hi = chan_lo + lsb * fpi_firmware::board::analog_in::POSITION_MAX as f64;
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
            force_gain_n_per_um: (d.force_gain > NewtonsPerUm::ZERO)
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
mod tests;
