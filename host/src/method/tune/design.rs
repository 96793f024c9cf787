//! The design steps of [`super`]: the damping (integral force feedback)
//! and the position PI on the family of plants, with and without dynamics.

use super::*;

/// The design on `known` dynamics (with where κ came from), or on none.
pub(super) fn design(
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
        force_gain: NewtonsPerUm::ZERO,
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
    // The largest gain the board takes (`[damping]`'s validator), µm/(N·s):
    // a plant with a tiny κ asks for more, and a design above it would be refused.
    let most = piezo_fpi::damping::GAIN_MAX.to_num::<f64>() * rate as f64;
    for k in 0..60 {
        let g = 20.0 * (1e5_f64 / 20.0).powf(k as f64 / 59.0);
        if g > most {
            break;
        }
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
