//! `fpi board frf`: the stage's frequency response measured through the board
//! by its own analyser (a sine added to the command, the sensors correlated with
//! it in the ISR: [`fpi_firmware::control::analyser`]), one frequency at a time, holding
//! at a position.
//!
//! What the board measures is what the loops see: from the command to the
//! position sensor and to the force channel (µm/µm, N/µm) and from the setpoint
//! to the position sensor (µm/V). [`crate::method::tune::frf`] writes, reads and
//! fits it.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use fpi_protocol::{Analysis, Command};
use nalgebra::Complex;
use piezo_fpi::control::Fault;

use super::client::{bits, Client};
use super::follow::Follow;
use crate::method::tune::frf::{FrfConditions, FrfPoint};

/// How the response is measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrfSettings {
    /// Lowest frequency, Hz.
    pub from_hz: f64,
    /// Highest frequency, Hz (below a quarter of the control rate).
    pub to_hz: f64,
    /// Frequencies, log-spaced.
    pub points: usize,
    /// Excitation, µm (added to the command).
    pub amplitude_um: f64,
    /// Where the stage holds meanwhile, µm.
    pub at_um: f64,
    /// Frequencies added around the sweep's peak (±15 %, evenly): a lightly
    /// damped mode's peak is narrower than the sweep's steps.
    pub zoom_points: usize,
}

impl Default for FrfSettings {
    fn default() -> Self {
        Self {
            from_hz: 20.0,
            to_hz: 4000.0,
            points: 40,
            amplitude_um: 0.1,
            at_um: 20.0,
            zoom_points: 12,
        }
    }
}

/// How long the board's wait for one frequency may take (wall clock).
const PATIENCE: Duration = Duration::from_secs(120);

/// Periods before the correlation at `f_hz`: at least 30 ms (a lightly damped
/// mode's transient, 1/(ζω) = 6 ms at 850 Hz and ζ 0.03, decays 150-fold) and 3.
fn settle_periods(f_hz: f64) -> u16 {
    (0.03 * f_hz).ceil().clamp(3.0, 2000.0) as u16
}

/// Periods correlated at `f_hz`: at least 20 ms and 4.
fn measure_periods(f_hz: f64) -> u16 {
    (0.02 * f_hz).ceil().clamp(4.0, 2000.0) as u16
}

/// The frequencies of `s`, Hz.
pub fn frequencies(s: &FrfSettings) -> Result<Vec<f64>> {
    use super::commands::bad;
    if s.from_hz.is_nan() || s.from_hz <= 0.0 {
        return Err(bad(
            "from_hz",
            "--from-hz",
            format!("--from-hz {}: above 0 Hz", s.from_hz),
        ));
    }
    if s.to_hz.is_nan() || s.to_hz <= s.from_hz {
        return Err(bad(
            "to_hz",
            "--to-hz",
            format!("--to-hz {}: above --from-hz {}", s.to_hz, s.from_hz),
        ));
    }
    if !(8..=400).contains(&s.points) {
        return Err(bad(
            "points",
            "--points",
            format!("--points {}: 8 to 400 points", s.points),
        ));
    }
    if !(s.amplitude_um > 0.0 && s.amplitude_um <= 2.0) {
        return Err(bad(
            "amplitude_um",
            "--amplitude-um",
            format!("--amplitude-um {}: in (0, 2] µm", s.amplitude_um),
        ));
    }
    let n = s.points;
    Ok((0..n)
        .map(|k| s.from_hz * (s.to_hz / s.from_hz).powf(k as f64 / (n - 1) as f64))
        .collect())
}

/// A signal's phasor from its sums.
fn phasor(sums: [i64; 2]) -> Complex<f64> {
    Complex::new(sums[0] as f64, sums[1] as f64)
}

/// The responses of one analysis.
fn point(a: &Analysis, amplitude_um: f64) -> FrfPoint {
    let [x, force, dynamic, voltage, excitation] = a.sums.map(phasor);
    FrfPoint {
        f_hz: a.freq_mhz as f64 / 1000.0,
        x: x / excitation,
        force: force / excitation,
        dynamic: dynamic / excitation,
        x_per_v: x / voltage,
        excitation_um: amplitude_um,
        ticks: a.ticks,
    }
}

/// What the board `c` runs (loop, damping, shaping, drive): the conditions a
/// response measured now is measured under, which its file records.
pub fn conditions(c: &mut Client) -> Result<FrfConditions> {
    let s = c.status()?;
    Ok(FrfConditions {
        loop_mode: s.loop_mode,
        damping: s.damping,
        shaping: s.shaping,
        compensated: s.compensated,
    })
}

/// Measures the response of the board `c` (which must be able to move: not
/// faulted) holding at `s.at_um`, in whatever loop it runs; `progress` hears
/// each frequency done.
pub fn measure(
    c: &mut Client,
    s: &FrfSettings,
    mut progress: impl FnMut(usize, &FrfPoint),
) -> Result<Vec<FrfPoint>> {
    let freqs = frequencies(s)?;
    let quarter = c.rate_hz() / 4.0;
    if s.to_hz >= quarter {
        bail!(
            "--to-hz {}: below a quarter of the control rate ({quarter} Hz)",
            s.to_hz
        );
    }
    c.move_to(s.at_um, 1000.0)?;
    {
        let mut f = Follow::new(c, 0);
        let rest = f.until_hold()?;
        f.until_tick(rest + f.ticks(0.05))?;
    }
    let mut out = Vec::with_capacity(freqs.len() + s.zoom_points);
    for (k, &f) in freqs.iter().enumerate() {
        if let Some(p) = analyse(c, f, s.amplitude_um)? {
            progress(k, &p);
            out.push(p);
        }
    }
    let peak = out
        .iter()
        .max_by(|a, b| a.x.norm().total_cmp(&b.x.norm()))
        .map_or(0.0, |p| p.f_hz);
    let n = s.zoom_points;
    for j in 0..n {
        let f = peak * (0.85 + 0.3 * (j as f64 + 0.5) / n as f64);
        if f < quarter && f > 0.0 {
            if let Some(p) = analyse(c, f, s.amplitude_um)? {
                progress(freqs.len() + j, &p);
                out.push(p);
            }
        }
    }
    if out.len() < 8 {
        bail!(
            "the board's reference governor let a stimulus through at {} of the {} frequencies \
             only (the stage may ring out of its stroke there): measure further from the \
             stroke's ends, or with a model that declares the stage's dynamics",
            out.len(),
            freqs.len() + n
        );
    }
    out.sort_by(|a, b| a.f_hz.total_cmp(&b.f_hz));
    Ok(out)
}

/// Halvings of the stimulus a frequency is measured again with where the
/// board's reference governor departed from it (the stage could not take it
/// there: near a stroke's end, or at a mode the model does not rule out).
/// Beyond them the frequency is left out: a sixteenth of the stimulus is
/// about where the response drowns in the sensors' noise above the mode.
pub const HALVINGS: u32 = 4;

/// One frequency's analysis on `c`: at `amplitude_um`, or at the largest of
/// its halvings the reference governor lets through unchanged (a governed
/// stimulus is not the sine the response is measured against); `None` where
/// none is.
fn analyse(c: &mut Client, f: f64, amplitude_um: f64) -> Result<Option<FrfPoint>> {
    let mut a_um = amplitude_um;
    for _ in 0..=HALVINGS {
        let (a, p) = analyse_at(c, f, a_um)?;
        if a.governed == 0 {
            return Ok(Some(p));
        }
        a_um /= 2.0;
    }
    Ok(None)
}

/// One frequency's analysis on `c` at `amplitude_um`, and its point.
fn analyse_at(c: &mut Client, f: f64, amplitude_um: f64) -> Result<(Analysis, FrfPoint)> {
    {
        let freq_mhz = (f * 1000.0).round() as u32;
        c.ack(&Command::Analyse {
            axis: c.axis(),
            freq_mhz,
            amplitude: bits(amplitude_um),
            settle: settle_periods(f),
            cycles: measure_periods(f),
        })?;
        let a = wait(c, freq_mhz)?;
        if a.faulted {
            let st = c.status()?;
            let why = st
                .fault
                .and_then(|f| Fault::from_code(f.code))
                .map_or("a fault", |f| f.message());
            bail!("the analysis at {f:.1} Hz was stopped by {why}");
        }
        let p = point(&a, amplitude_um);
        Ok((a, p))
    }
}

/// Waits for the analysis at `freq_mhz` to finish.
fn wait(c: &mut Client, freq_mhz: u32) -> Result<Analysis> {
    let start = Instant::now();
    loop {
        if let Some(a) = c.analysis()? {
            if a.freq_mhz == freq_mhz {
                return Ok(a);
            }
        }
        if start.elapsed() > PATIENCE {
            bail!(
                "the analysis at {} Hz did not finish",
                freq_mhz as f64 / 1000.0
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}
