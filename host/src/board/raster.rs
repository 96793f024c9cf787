//! A raster on two axes of a board of several (`fpi board raster`): the fast
//! axis a triangle, the slow axis a ramp or a staircase, the lines started
//! on the same tick on both, every axis recorded; and its figures, scored on
//! the stage's true positions where the board knows them (the emulated
//! board), else on the position sensors.
//!
//! **Figures.** Over the central 80 % of every line (the turnarounds left
//! out, as a scan's image is): the fast axis's RMS error in % of its span,
//! and the slow axis's RMS error against its own reference in % of the fast
//! axis's span (how far a scanned line lies from where it should).

use anyhow::{bail, Result};
use fpi_protocol::record::signal;
use fpi_protocol::{Command, RasterOrder};

use super::client::{axis_name, to_link, Client};
use super::motion::{self, Motion, Until};
use super::recording::{AxesRecording, Recording};
use crate::data::Num;

/// A raster as the user asks for it (configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterSpec {
    /// The fast axis (0: x).
    pub fast: u8,
    /// The slow axis.
    pub slow: u8,
    /// The fast axis's start and end, µm.
    pub fast_um: (f64, f64),
    /// The slow axis's start and end, µm.
    pub slow_um: (f64, f64),
    /// The fast axis's triangle, Hz (a line is half its period).
    pub freq_hz: f64,
    /// Lines.
    pub lines: u16,
    /// The slow axis steps at each line's start (else it ramps).
    pub staircase: bool,
}

/// A raster's figures (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterFigures {
    /// The fast axis's RMS error, % of its span.
    pub fast_rms_pct: f64,
    /// The slow axis's RMS error against its reference, % of the fast
    /// axis's span.
    pub slow_rms_pct: f64,
    /// Samples scored per axis.
    pub samples: usize,
    /// Ticks of the scored windows the recording lacks (the board's ring
    /// dropped them).
    pub missing: usize,
    /// Scored on the true positions (the emulated board), else on the
    /// position sensors.
    pub on_truth: bool,
}

impl RasterSpec {
    /// The fast axis's frequency as the link carries it, mHz.
    pub fn freq_mhz(&self) -> u32 {
        (self.freq_hz * 1000.0).round() as u32
    }

    /// Ticks of a line at `rate_hz`: half the fast axis's period, rounded as
    /// the board rounds it (its own function); `None` where the board
    /// refuses the frequency.
    pub fn line_ticks(&self, rate_hz: f64) -> Option<u32> {
        fpi_firmware::control::reference::raster::line_ticks(self.freq_mhz(), rate_hz as u32)
            .map(u32::from)
    }

    /// The lines' duration, s.
    pub fn seconds(&self) -> f64 {
        f64::from(self.lines) / (2.0 * self.freq_hz)
    }

    /// The command, its arguments checked (the board checks the strokes).
    pub fn command(&self) -> Result<Command<'static>> {
        if self.fast == self.slow {
            bail!(
                "--fast {} --slow {}: a raster's fast and slow axes are two",
                axis_name(self.fast),
                axis_name(self.slow)
            );
        }
        if !(self.freq_hz.is_finite() && self.freq_hz > 0.0) {
            bail!("--freq-hz {}: a frequency above 0 Hz", Num(self.freq_hz));
        }
        if self.lines == 0 || (self.staircase && self.lines < 2) {
            bail!(
                "--lines {}: one line at least, two for a staircase",
                self.lines
            );
        }
        let span = |what: &str, (a, b): (f64, f64)| -> Result<[i32; 2]> {
            Ok([
                to_link(&format!("{what} start"), a, "µm")?,
                to_link(&format!("{what} end"), b, "µm")?,
            ])
        };
        Ok(Command::Raster(RasterOrder {
            fast: self.fast,
            slow: self.slow,
            fast_span: span("--from-um", self.fast_um)?,
            slow_span: span("--slow-from-um", self.slow_um)?,
            freq_mhz: self.freq_mhz(),
            lines: self.lines,
            staircase: self.staircase,
        }))
    }
}

/// Runs the raster `spec` on `c`, recording every axis from its start (the
/// approach to the start included) until the fast axis holds at its end;
/// the motion, its recording split by axis.
pub fn run(c: &mut Client, spec: &RasterSpec) -> Result<(Motion<()>, AxesRecording)> {
    let cmd = spec.command()?;
    let n = c.hello().axes;
    if n < 2 {
        bail!(
            "the board on {} has one axis: a raster takes two",
            c.port_name()
        );
    }
    let addressed = c.axis();
    c.on_axis(spec.fast)?;
    // The approach to the start: at most the stroke at the board's 1 mm/s.
    let approach_s = 0.05;
    let m = motion::record_every_axis(
        c,
        motion::EVERY_AXIS_SIGNALS,
        "the raster",
        approach_s + spec.seconds(),
        Until::Rest,
        |c, _| Ok((c.ack(&cmd)?, ())),
        || false,
    );
    c.on_axis(addressed)?;
    let m = m?;
    let axes = AxesRecording::split(&m.recording, usize::from(n));
    Ok((m, axes))
}

/// The raster's figures from its recording (see the module docs); `None`
/// where the recording holds no whole line.
pub fn figures(spec: &RasterSpec, rec: &AxesRecording) -> Option<RasterFigures> {
    let fast = rec.axes.get(usize::from(spec.fast))?;
    let slow = rec.axes.get(usize::from(spec.slow))?;
    let t = spec.line_ticks(fast.rate_hz)?;
    let first = lines_start(fast, spec.fast_um.0)?;
    let on_truth = fast.signals & signal::X_TRUE != 0;
    // The error at `tick`, µm, where the recording has it.
    let at = |r: &Recording, tick: u32| {
        let k = r.samples.binary_search_by_key(&tick, |s| s.tick).ok()?;
        r.samples.get(k).map(|s| {
            let x = if on_truth { s.x_true } else { s.x_sensor };
            super::client::real(x) - super::client::real(s.x_ref)
        })
    };
    let (mut ef, mut es, mut n, mut missing) = (0.0, 0.0, 0usize, 0usize);
    for line in 0..u32::from(spec.lines) {
        let start = first + line * t;
        for tick in start + t / 10..start + t * 9 / 10 {
            match (at(fast, tick), at(slow, tick)) {
                (Some(f), Some(s)) => {
                    ef += f * f;
                    es += s * s;
                    n += 1;
                }
                _ => missing += 1,
            }
        }
    }
    let span = (spec.fast_um.1 - spec.fast_um.0).abs();
    let pct = |e: f64| (e / n as f64).sqrt() / span * 100.0;
    (n > 0).then(|| RasterFigures {
        fast_rms_pct: pct(ef),
        slow_rms_pct: pct(es),
        samples: n,
        missing,
        on_truth,
    })
}

/// The tick of the lines' first sample: the first whose reference has
/// left `from` the tick after resting there (the start reached).
fn lines_start(fast: &Recording, from: f64) -> Option<u32> {
    let start = to_link("start", from, "µm").ok()?;
    fast.samples
        .windows(2)
        .find(|w| w[0].x_ref == start && w[1].x_ref != start && w[1].tick == w[0].tick + 1)
        .map(|w| w[1].tick)
}

/// The figures as a line of text.
pub fn describe(spec: &RasterSpec, f: &RasterFigures) -> String {
    format!(
        "{} {} Hz over {:.1}–{:.1} µm, {} lines of {}: RMS error over the central 80 % of each \
         line, on the {}: {} {:.3} % of its span, {} {:.3} % of {}'s span{}",
        axis_name(spec.fast),
        Num(spec.freq_hz),
        spec.fast_um.0,
        spec.fast_um.1,
        spec.lines,
        axis_name(spec.slow),
        if f.on_truth {
            "true positions"
        } else {
            "position sensors"
        },
        axis_name(spec.fast),
        f.fast_rms_pct,
        axis_name(spec.slow),
        f.slow_rms_pct,
        axis_name(spec.fast),
        if f.missing > 0 {
            format!(
                " ({} of the ticks scored were dropped by the board's ring)",
                f.missing
            )
        } else {
            String::new()
        }
    )
}
