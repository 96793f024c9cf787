//! The tracking bandwidth through the board, as a user scores it: small sines
//! on the *reference* (the board's wave generator), with whatever loops the
//! board runs, and the stage's true position recorded at every tick; the
//! response at each frequency is `x_true / x_ref`, and the bandwidth is where
//! its magnitude first falls 3 dB below the low-frequency level.
//!
//! Each sine starts from a hold at its mid-point (the generator's phase 0: no
//! approach), runs [`SETTLE_CYCLES`] periods unscored, then at least
//! [`SCORED_S`] (and [`MIN_CYCLES`] periods) scored. Both signals are fitted
//! by least squares with `a·sin + b·cos + c` at the sine's frequency over the
//! scored ticks; the response is the ratio of the two phasors. The recorded
//! reference is the one the loops track (the preview's delay later than the
//! source): a pure delay, which leaves the magnitude alone.

use anyhow::{bail, Result};
use fpi_protocol::{Shape, SourceKind};
use nalgebra::{Complex, DMatrix, DVector};

use super::client::{real, Client};
use super::follow::{no_fault, Capture, Follow};
use fpi_firmware::control::recorder::signal;

/// What a sine records.
const SIGNALS: u8 = signal::X_REF | signal::X_TRUE | signal::STATUS;
/// Periods run before the scoring starts.
pub const SETTLE_CYCLES: u32 = 3;
/// Least periods scored.
pub const MIN_CYCLES: u32 = 5;
/// Least board time scored, s.
pub const SCORED_S: f64 = 0.02;

/// The response at one frequency: true position over reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Frequency, Hz.
    pub f_hz: f64,
    /// `x_true / x_ref`.
    pub gain: Complex<f64>,
}

impl Point {
    /// Magnitude, dB.
    pub fn db(&self) -> f64 {
        20.0 * self.gain.norm().log10()
    }
}

/// `n` log-spaced frequencies from `lo` to `hi`, Hz.
pub fn log_spaced(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| lo * (hi / lo).powf(k as f64 / (n.max(2) - 1) as f64))
        .collect()
}

/// The phasor of `x` at `f_hz` over ticks `t` (at `rate` per s): `a + jb` for
/// the fit `a·sin ωt + b·cos ωt + c`.
fn phasor(t: &[f64], x: &[f64], f_hz: f64, rate: f64) -> Result<Complex<f64>> {
    let w = std::f64::consts::TAU * f_hz / rate;
    let a = DMatrix::from_fn(t.len(), 3, |i, j| match j {
        0 => (w * t[i]).sin(),
        1 => (w * t[i]).cos(),
        _ => 1.0,
    });
    let c = a
        .svd(true, true)
        .solve(&DVector::from_column_slice(x), 1e-12)
        .map_err(|e| anyhow::anyhow!("the fit at {f_hz:.1} Hz failed: {e}"))?;
    Ok(Complex::new(c[0], c[1]))
}

/// The response at `f_hz`: a sine of `amplitude_um` around `mid_um` on a board
/// holding at `mid_um` with its loops set up.
fn point(c: &mut Client, f_hz: f64, amplitude_um: f64, mid_um: f64) -> Result<Point> {
    let rate = c.rate_hz();
    let scored = (f64::from(MIN_CYCLES) / f_hz).max(SCORED_S);
    let cycles = SETTLE_CYCLES + (scored * f_hz).ceil() as u32;
    let seconds = f64::from(cycles) / f_hz;
    let what = format!("the {f_hz:.1} Hz sine");
    let cap = Capture {
        what: &what,
        decimation: 1,
        seconds: seconds + 0.005,
        hint: "the bandwidth records every tick",
    };
    let mut f = Follow::new(c, SIGNALS);
    let from = f.capture(
        &cap,
        |c| c.wave(Shape::Sine, amplitude_um, mid_um, f_hz, cycles),
        |s, from| {
            no_fault(s, "the sine")?;
            Ok(s.source == SourceKind::Hold && !s.approaching && s.tick > from)
        },
    )?;
    let start = from + (f64::from(SETTLE_CYCLES) * rate / f_hz).round() as u32;
    let end = from + (seconds * rate).round() as u32;
    let s: Vec<_> = f
        .rec
        .samples
        .iter()
        .filter(|s| s.tick >= start && s.tick < end)
        .collect();
    if s.len() < 16 {
        bail!("the {f_hz:.1} Hz sine: {} samples scored", s.len());
    }
    // The generator's phase: ticks since the sine began.
    let t: Vec<f64> = s.iter().map(|s| f64::from(s.tick - from)).collect();
    let r = phasor(
        &t,
        &s.iter().map(|s| real(s.x_ref)).collect::<Vec<_>>(),
        f_hz,
        rate,
    )?;
    let x = phasor(
        &t,
        &s.iter().map(|s| real(s.x_true)).collect::<Vec<_>>(),
        f_hz,
        rate,
    )?;
    if r.norm() < 0.1 * amplitude_um {
        bail!("the {f_hz:.1} Hz sine's reference did not move");
    }
    Ok(Point { f_hz, gain: x / r })
}

/// The responses at `freqs` (Hz), each a sine of `amplitude_um` around
/// `mid_um`, on a board whose loops are set up; it is left holding at `mid_um`.
pub fn measure(
    c: &mut Client,
    freqs: &[f64],
    amplitude_um: f64,
    mid_um: f64,
) -> Result<Vec<Point>> {
    c.move_to(mid_um, 1000.0)?;
    Follow::new(c, 0).until_hold()?;
    freqs
        .iter()
        .map(|&f| point(c, f, amplitude_um, mid_um))
        .collect()
}

/// The −3 dB bandwidth, Hz: where the magnitude first falls 3 dB below that
/// of the lowest frequency (interpolated in log frequency); `None` if it never
/// does within the points.
pub fn bandwidth_hz(points: &[Point]) -> Option<f64> {
    let level = points.first()?.db() - 3.0;
    points.windows(2).find_map(|w| {
        let (a, b) = (w[0].db(), w[1].db());
        (a >= level && b < level).then(|| {
            let s = (a - level) / (a - b);
            (w[0].f_hz.ln() + s * (w[1].f_hz.ln() - w[0].f_hz.ln())).exp()
        })
    })
}

/// The largest magnitude, dB, and where, Hz.
pub fn peak(points: &[Point]) -> Option<(f64, f64)> {
    points
        .iter()
        .map(|p| (p.db(), p.f_hz))
        .max_by(|a, b| a.0.total_cmp(&b.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn first_order(f: f64, corner: f64) -> Point {
        Point {
            f_hz: f,
            gain: Complex::new(1.0, 0.0) / Complex::new(1.0, f / corner),
        }
    }

    /// A first-order response with its corner at 300 Hz: the bandwidth is
    /// found within 2 % from 20 log-spaced points; none where the magnitude
    /// never falls; the peak of a flat response is 0 dB.
    #[test]
    fn the_bandwidth_of_a_known_response() {
        let pts: Vec<Point> = log_spaced(20.0, 2000.0, 20)
            .into_iter()
            .map(|f| first_order(f, 300.0))
            .collect();
        let bw = bandwidth_hz(&pts).unwrap();
        assert!((bw / 300.0 - 1.0).abs() < 0.02, "{bw}");
        let flat: Vec<Point> = log_spaced(20.0, 200.0, 5)
            .into_iter()
            .map(|f| first_order(f, 1e6))
            .collect();
        assert_eq!(bandwidth_hz(&flat), None);
        assert!(peak(&flat).unwrap().0.abs() < 1e-3);
    }

    /// The phasor fit recovers a sine's amplitude and phase on a fraction of
    /// a period's worth of extra ticks, with an offset.
    #[test]
    fn the_phasor_of_a_sine() {
        let rate = 20_000.0;
        let f = 730.0;
        let t: Vec<f64> = (0..1000).map(f64::from).collect();
        let w = std::f64::consts::TAU * f / rate;
        let x: Vec<f64> = t.iter().map(|k| 20.0 + 0.3 * (w * k + 0.4).sin()).collect();
        let p = phasor(&t, &x, f, rate).unwrap();
        assert!((p.norm() - 0.3).abs() < 1e-9, "{p}");
        assert!((p.arg() - 0.4).abs() < 1e-9, "{p}");
    }
}
