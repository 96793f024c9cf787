//! `fpi tune`: the gains of the board's position loop, chosen for a stated
//! stability margin and stored with the firmware model (its `[feedback]` section).
//!
//! **Plant.** The board's PI acts on the stage through a law that linearises it:
//! with the inverse FPI as feedforward the stage answers a command `x_cmd` (µm)
//! with `x ≈ x_cmd`; feedback alone goes through the straight-line drive, and the
//! stage answers with the hysteresis' local slope relative to that line. So the
//! loop sees `P(s) = k · M(s) · e^{−1.5·s·T}`:
//!
//! * `k` — a gain spread: the PI's smallest slope (`w0`, just after a reversal)
//!   to its largest (`w0 + Σw`), each relative to its mean slope over the input
//!   domain, widened to at least 0.8–1.25 (what the model may be off by);
//! * `M(s)` — the identified dynamics at unit static gain (`fpi identify`,
//!   `--dynamics`: the modes and the amplifier's lag); without them, 1;
//! * `1.5 T` — the loop's delay: the output written in one tick is read back in
//!   the next, plus the DAC's zero-order hold (`T` = one control period).
//!
//! **Law.** The firmware's PI per tick, `C(z) = kp + ki·z⁻¹/(1 − z⁻¹)`
//! ([`piezo_fpi::feedback`]).
//!
//! **Margin.** The peak of the sensitivity `|1/(1 + C·P)|` over frequency, for
//! every gain of the spread, stays at or below `max_sensitivity` (default 1.6):
//! a circle the Nyquist curve keeps out of, which guarantees a gain margin of at
//! least `Ms/(Ms − 1)` (8.5 dB) and a phase margin of at least
//! `2·asin(1/(2·Ms))` (36°). The search raises `ki` from a small value (where the
//! loop is stable) and keeps the largest that holds the margin, for each `kp` of a
//! grid, and takes the pair with the largest `ki` (the fastest integral action).
//! Without identified dynamics the crossover is also held at or below
//! `bandwidth_hz` (default 20 Hz): the stage's first mode is unknown, and a mode a
//! few hundred hertz up would not be seen by the margin.

use std::f64::consts::PI;

use anyhow::{bail, Result};
use nalgebra::Complex;
use piezo_sim::file::{FeedbackSection, FirmwareModel};

use super::dynamics::Dynamics;

/// What `fpi tune` is asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// Largest allowed sensitivity peak `max |1/(1 + L)|`.
    pub max_sensitivity: f64,
    /// Without dynamics: the highest crossover, Hz.
    pub bandwidth_hz: f64,
    /// Largest correction the feedback may add, µm (`None`: 10 % of the stroke).
    pub limit_um: Option<f64>,
    /// Position-plausibility tolerance, µm (`None`: 15 % of the stroke).
    pub tolerance_um: Option<f64>,
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self {
            max_sensitivity: 1.6,
            bandwidth_hz: 20.0,
            limit_um: None,
            tolerance_um: None,
        }
    }
}

/// The gains chosen and what they give.
#[derive(Debug, Clone, PartialEq)]
pub struct Tuning {
    /// Proportional gain, µm/µm.
    pub kp: f64,
    /// Integral gain, 1/s.
    pub ki_per_s: f64,
    /// Gain spread the margin holds for.
    pub gains: [f64; 2],
    /// Sensitivity peak at the worst gain of the spread.
    pub sensitivity_peak: f64,
    /// Gain crossover at the nominal gain, Hz.
    pub crossover_hz: f64,
    /// Gain and phase margins at the nominal gain, dB and degrees.
    pub margins: (f64, f64),
    /// What the plant was taken to be.
    pub plant: String,
}

/// The loop's frequency responses: frequency grid, plant shape `M·delay` at each.
struct Loop {
    f_hz: Vec<f64>,
    plant: Vec<Complex<f64>>,
    dt_s: f64,
}

impl Loop {
    fn new(rate_hz: f64, dynamics: Option<&Dynamics>) -> Self {
        let dt_s = 1.0 / rate_hz;
        let (lo, hi, n) = (0.1_f64, 0.499 * rate_hz, 6000);
        let f_hz: Vec<f64> = (0..n)
            .map(|k| lo * (hi / lo).powf(k as f64 / (n - 1) as f64))
            .collect();
        let plant = f_hz
            .iter()
            .map(|&f| {
                let m = dynamics.map_or(Complex::new(1.0, 0.0), |d| {
                    d.response(f) / d.dc_gain_um_per_v
                });
                m * Complex::from_polar(1.0, -2.0 * PI * f * 1.5 * dt_s)
            })
            .collect();
        Self { f_hz, plant, dt_s }
    }

    /// `C(e^{jωT})` of the firmware's PI.
    fn controller(&self, f: f64, kp: f64, ki_tick: f64) -> Complex<f64> {
        let z1 = Complex::from_polar(1.0, -2.0 * PI * f * self.dt_s);
        Complex::new(kp, 0.0) + z1 * ki_tick / (Complex::new(1.0, 0.0) - z1)
    }

    /// The open loop `L = C·k·P` over the grid.
    fn open(
        &self,
        kp: f64,
        ki_tick: f64,
        k: f64,
    ) -> impl Iterator<Item = (f64, Complex<f64>)> + '_ {
        self.f_hz
            .iter()
            .zip(&self.plant)
            .map(move |(&f, &p)| (f, self.controller(f, kp, ki_tick) * p * k))
    }

    /// Sensitivity peak of the loop at gain `k`.
    fn sensitivity_peak(&self, kp: f64, ki_tick: f64, k: f64) -> f64 {
        self.open(kp, ki_tick, k)
            .map(|(_, l)| 1.0 / (Complex::new(1.0, 0.0) + l).norm())
            .fold(0.0, f64::max)
    }

    /// First frequency where `|L|` falls to 1, Hz (0 if it never does).
    fn crossover(&self, kp: f64, ki_tick: f64, k: f64) -> f64 {
        self.open(kp, ki_tick, k)
            .find(|(_, l)| l.norm() <= 1.0)
            .map_or(0.0, |(f, _)| f)
    }

    /// Gain margin (dB, at the first −180° crossing) and phase margin (degrees,
    /// at the crossover) at gain `k`.
    fn margins(&self, kp: f64, ki_tick: f64, k: f64) -> (f64, f64) {
        let mut pm = f64::INFINITY;
        let mut gm = f64::INFINITY;
        let mut prev: Option<f64> = None;
        let mut unwrap = 0.0;
        for (_, l) in self.open(kp, ki_tick, k) {
            let mut ph = l.arg();
            if let Some(p) = prev {
                while ph + unwrap - p > PI {
                    unwrap -= 2.0 * PI;
                }
                while ph + unwrap - p < -PI {
                    unwrap += 2.0 * PI;
                }
            }
            ph += unwrap;
            if let Some(p) = prev {
                if p > -PI && ph <= -PI && gm.is_infinite() {
                    gm = -20.0 * l.norm().log10();
                }
            }
            if pm.is_infinite() && l.norm() <= 1.0 {
                pm = 180.0 + ph.to_degrees();
            }
            prev = Some(ph);
        }
        (gm, pm)
    }
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

/// Chooses the gains of `fw`'s position loop (see the module docs).
pub fn tune(fw: &FirmwareModel, dynamics: Option<&Dynamics>, o: &TuneOptions) -> Result<Tuning> {
    if !(o.max_sensitivity > 1.05 && o.max_sensitivity <= 3.0) {
        bail!(
            "--max-sensitivity {}: between 1.05 and 3 (1.6 gives ≥ 8.5 dB and ≥ 36°)",
            o.max_sensitivity
        );
    }
    if !(o.bandwidth_hz > 0.0 && o.bandwidth_hz.is_finite()) {
        bail!("--bandwidth-hz {}: a positive frequency", o.bandwidth_hz);
    }
    let rate = fw.controller.rate_hz as f64;
    let lp = Loop::new(rate, dynamics);
    let gains = gain_spread(fw);
    let holds = |kp: f64, ki: f64| {
        let ki_tick = ki / rate;
        let margin = [gains[0], 1.0, gains[1]]
            .iter()
            .all(|&k| lp.sensitivity_peak(kp, ki_tick, k) <= o.max_sensitivity);
        let slow = dynamics.is_some()
            || [1.0, gains[1]]
                .iter()
                .all(|&k| lp.crossover(kp, ki_tick, k) <= o.bandwidth_hz);
        margin && slow
    };
    let mut best: Option<(f64, f64)> = None;
    for kp in (0..=20).map(|j| j as f64 * 0.025) {
        let mut ki = 1.0;
        if !holds(kp, ki) {
            continue;
        }
        while ki < 0.9 * rate && holds(kp, ki * 1.05) {
            ki *= 1.05;
        }
        if best.is_none_or(|(_, b)| ki > b) {
            best = Some((kp, ki));
        }
    }
    let Some((kp, ki)) = best else {
        bail!(
            "no gains hold a sensitivity peak of {} over the gain spread {:.2}–{:.2}: the \
             plant's delay or mode leaves no room (try a larger --max-sensitivity)",
            o.max_sensitivity,
            gains[0],
            gains[1]
        );
    };
    let ki_tick = ki / rate;
    let peak = [gains[0], 1.0, gains[1]]
        .iter()
        .map(|&k| lp.sensitivity_peak(kp, ki_tick, k))
        .fold(0.0, f64::max);
    let plant = match dynamics {
        Some(d) => format!(
            "identified dynamics (modes {} Hz, damping {}) at unit gain, 1.5-tick delay",
            list(&d.natural_frequency_hz, 1),
            list(&d.damping_ratio, 4)
        ),
        None => format!(
            "no dynamics: unit gain with a 1.5-tick delay, crossover held at ≤ {} Hz",
            o.bandwidth_hz
        ),
    };
    Ok(Tuning {
        kp,
        ki_per_s: ki,
        gains,
        sensitivity_peak: peak,
        crossover_hz: lp.crossover(kp, ki_tick, 1.0),
        margins: lp.margins(kp, ki_tick, 1.0),
        plant,
    })
}

/// `[a, b]` with `digits` decimals.
fn list(v: &[f64], digits: usize) -> String {
    let items: Vec<String> = v.iter().map(|x| format!("{x:.digits$}")).collect();
    format!("[{}]", items.join(", "))
}

/// `fw` with the `[feedback]` section `t` gives: the gains, the correction's
/// limit and the position sensor's range and tolerance from the model's stroke.
pub fn with_feedback(fw: &FirmwareModel, t: &Tuning, o: &TuneOptions) -> Result<FirmwareModel> {
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
    out.feedback = Some(FeedbackSection {
        kp: t.kp,
        ki_per_s: t.ki_per_s,
        limit_um: o.limit_um.unwrap_or(0.10 * span),
        position_min_um: lo,
        position_max_um: hi,
        position_tolerance_um: o.tolerance_um.unwrap_or(0.15 * span),
        notes: format!(
            "fpi tune: plant = {}; gain spread {:.2}–{:.2}; sensitivity peak {:.2} (limit {}); \
             crossover {:.1} Hz, gain margin {:.1} dB, phase margin {:.0}° at unit gain",
            t.plant,
            t.gains[0],
            t.gains[1],
            t.sensitivity_peak,
            o.max_sensitivity,
            t.crossover_hz,
            t.margins.0,
            t.margins.1
        ),
    });
    out.check().map_err(anyhow::Error::msg)?;
    Ok(out)
}
