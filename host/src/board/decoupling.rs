//! The axes' decoupling of a board of several (`piezo_fpi::decoupling`): the
//! input matrix, the output matrix and the stacks' preload coupling, measured
//! through the board ([`measure`]) and sent as the link carries them
//! ([`Command::Decoupling`]).
//!
//! # The measurement
//!
//! Every axis's loop is closed (each axis tuned first: `fpi board autotune`
//! of each) and holds mid-stroke. Each axis `j` in turn moves between two
//! positions and back while the others hold, and every axis is recorded (the
//! model's estimate, the force and the position sensor). Before each move
//! and once it has settled, each axis's signals are averaged. Two passes:
//!
//! 1. **No decoupling.** *What the sensors see*: an axis `i` whose loop holds
//!    its sensor still while `j` moves has moved its own stack against what
//!    reached it; its model's estimate of its own output (`x_est`, `f_K` of
//!    the estimated extension) moved by `−seen[i][j]` per µm of `j`'s sensor.
//!    *The preload coupling*: the force on stack `i`, less its own FEM
//!    preload's change (`f_F` at its own estimated extension), per µm of
//!    stack `j`'s estimated extension (`f_K⁻¹` of its estimate), N/µm: per
//!    µm of the extension the board estimates, which is what it multiplies.
//! 2. **The sensors' cross-talk and the preload coupling taken out** (the
//!    input matrix and the preload coupling set). What the sensors now see
//!    is the *parasitic motion*, in the units the output matrix acts in (µm
//!    of each axis's model): the force channel no longer chases the other
//!    stacks' preload, so each estimate is its model's whole answer.
//!
//! **The sensors' cross-talk** cannot be told from the parasitic motion by
//! the position sensors: both are µm that sensor `i` reads per µm of axis
//! `j`'s output. It is the sensors' calibration, given
//! ([`Settings::sensor_crosstalk`], from a reference measurement such as an
//! interferometer's, as a controller's input matrix is calibrated in the
//! factory; 0 if there is none). A cross-talk left out stays in the axes'
//! true positions (`s` µm per µm of the other axis).
//!
//! The moves go both ways and the two are averaged, so the hysteresis and the
//! creep of the holding axes' stacks cancel to first order.

use anyhow::{bail, Context, Result};
use fpi_firmware::control::recorder::{signal, Sample};
use fpi_protocol::Command;
use piezo_fpi::decoupling::Decoupling;
use piezo_sim::file::{CouplingTable, FirmwareModel};

use super::client::{axis_name, real, Client};
use super::follow::Follow;
use super::motion::{self, Until};
use super::recording::AxesRecording;
use super::warm;

/// The axes a decoupling spans on the link (x, y, z).
pub const MAX_AXES: usize = fpi_protocol::MAX_AXES as usize;

/// The command that sets `d` (its entries' fixed-point bits).
pub fn command(d: &Decoupling<MAX_AXES>) -> Command<'static> {
    Command::Decoupling {
        input: d.input.rows().map(|r| r.map(|e| e.to_bits())),
        output: d.output.rows().map(|r| r.map(|e| e.to_bits())),
        preload: d.preload.rows().map(|r| r.map(|k| k.to_bits())),
    }
}

/// Sets `d` on the board `c` (every axis parked); the tick it took effect.
pub fn set(c: &mut Client, d: &Decoupling<MAX_AXES>) -> Result<u32> {
    c.order(&command(d))
}

/// How the coupling is measured (configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// The two positions each axis moves between, µm (the others hold
    /// [`warm`]'s mid-stroke, 20 µm).
    pub between_um: (f64, f64),
    /// The moves' speed, µm/s.
    pub speed_um_s: f64,
    /// How long each axis is averaged before a move and after it has
    /// settled, s.
    pub window_s: f64,
    /// From the move's end until the window after it, s.
    pub settle_s: f64,
    /// The fraction of every other axis's output each position sensor reads
    /// (the sensors' calibration; 0: none known).
    pub sensor_crosstalk: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            between_um: (10.0, 30.0),
            speed_um_s: 2000.0,
            window_s: 0.01,
            settle_s: 0.04,
            sensor_crosstalk: 0.0,
        }
    }
}

/// The coupling measured, and the decoupling made of it. Arrays are over the
/// board's axes, `[i][j]`: of axis `i` per unit of axis `j`.
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    /// The board's axes.
    pub axes: usize,
    /// µm that sensor `i` sees per µm of axis `j` (parasitic motion and
    /// cross-talk together; the first pass).
    pub seen: Vec<Vec<f64>>,
    /// µm of each axis's estimate per µm of its sensor as it moved (its
    /// model's gain as the sensor sees it, ideally 1; the second pass).
    pub own_gain: Vec<f64>,
    /// The coupling as a model file of several axes keeps it: the sensors'
    /// cross-talk given, the parasitic motion (the second pass), the preload
    /// coupling (the first).
    pub coupling: CouplingTable,
    /// The decoupling made of it ([`CouplingTable::decoupling`]).
    pub decoupling: Decoupling<MAX_AXES>,
}

/// One axis's averages over a window.
#[derive(Debug, Clone, Copy, Default)]
struct Level {
    sensor_um: f64,
    est_um: f64,
    force_n: f64,
}

/// The signals recorded of every axis.
const SIGNALS: u8 = signal::X_EST | signal::FORCE | signal::X_SENSOR;

/// Measures the coupling of the board `c` (every axis running its tuned
/// model, `models` in axis order: see the module docs) and sets the
/// decoupling made of it; the board is left parked. Where it fails, the
/// board is parked and its decoupling is off.
pub fn measure(c: &mut Client, models: &[FirmwareModel], s: &Settings) -> Result<Measured> {
    let n = usize::from(c.hello().axes);
    if n < 2 {
        bail!("the board has one axis: it has no coupling to measure");
    }
    if models.len() != n {
        bail!(
            "the board has {n} axes, and {} models were given: one per axis, in axis order",
            models.len()
        );
    }
    let here = c.axis();
    let run = both_passes(c, models, s, n);
    let parked = park_every_axis(c);
    let d = match (run, parked) {
        (Ok(m), Ok(())) => set(c, &m.decoupling)
            .context("setting the decoupling measured")
            .map(|_| m),
        (Err(e), _) | (Ok(_), Err(e)) => {
            let _ = set(c, &Decoupling::NONE);
            Err(e)
        }
    };
    c.on_axis(here)?;
    d
}

/// The two passes of the module docs: what the sensors see and the preload
/// coupling with no decoupling; then, with the sensors' cross-talk and the
/// preload coupling taken out, the parasitic motion. The decoupling made of
/// them.
fn both_passes(
    c: &mut Client,
    models: &[FirmwareModel],
    s: &Settings,
    n: usize,
) -> Result<Measured> {
    let first = pass(c, models, s, n, &Decoupling::NONE)?;
    let mut coupling = CouplingTable {
        sensor_crosstalk: s.sensor_crosstalk,
        preload_n_per_um: first.preload_n_per_um.clone(),
        ..CouplingTable::none(n)
    };
    let partial = made_of(&coupling, n)?;
    let second = pass(c, models, s, n, &partial)?;
    coupling.parasitic = second.seen;
    Ok(Measured {
        axes: n,
        seen: first.seen,
        own_gain: second.own_gain,
        decoupling: made_of(&coupling, n)?,
        coupling,
    })
}

/// The decoupling of `coupling` over `n` axes, or why the board would not
/// take it.
fn made_of(coupling: &CouplingTable, n: usize) -> Result<Decoupling<MAX_AXES>> {
    coupling
        .decoupling(n)
        .map_err(|e| anyhow::anyhow!("the coupling measured cannot be decoupled: {e}"))
}

/// Parks every axis and clears a fault the measurement latched.
fn park_every_axis(c: &mut Client) -> Result<()> {
    c.on_axis(0)?;
    c.park()?;
    c.ack(&Command::ClearFault)?;
    Ok(())
}

/// What one pass measures (see [`Measured`]'s fields of the same names),
/// over the board's axes.
struct Pass {
    seen: Vec<Vec<f64>>,
    own_gain: Vec<f64>,
    preload_n_per_um: Vec<Vec<f64>>,
}

/// One pass of the measurement with the decoupling `d` set: every axis's
/// loop closed and warmed up, then each axis moved both ways.
fn pass(
    c: &mut Client,
    models: &[FirmwareModel],
    s: &Settings,
    n: usize,
    d: &Decoupling<MAX_AXES>,
) -> Result<Pass> {
    park_every_axis(c)?;
    set(c, d).context("setting the decoupling the pass runs with")?;
    for axis in 0..n {
        c.on_axis(axis as u8)?;
        warm::close_and_warm_up(c)
            .with_context(|| format!("closing axis {}'s loop", axis_name(axis as u8)))?;
    }
    let mut p = Pass {
        seen: vec![vec![0.0; n]; n],
        own_gain: vec![0.0; n],
        preload_n_per_um: vec![vec![0.0; n]; n],
    };
    let (lo, hi) = s.between_um;
    for j in 0..n {
        c.on_axis(j as u8)?;
        c.move_to(lo, s.speed_um_s)?;
        Follow::new(c, 0).until_hold()?;
        for (from, to) in [(lo, hi), (hi, lo)] {
            let (before, after) = levels_around(c, (from, to), s, n)?;
            add_move(&mut p, models, j, (&before, &after))?;
        }
        c.move_to(warm::MID_UM, s.speed_um_s)?;
        Follow::new(c, 0).until_hold()?;
    }
    for row in p.seen.iter_mut().chain(p.preload_n_per_um.iter_mut()) {
        row.iter_mut().for_each(|v| *v /= 2.0);
    }
    p.own_gain.iter_mut().for_each(|v| *v /= 2.0);
    Ok(p)
}

/// The addressed axis's move `from` → `to` recorded on every axis: each
/// axis's levels over the window before it and the window after it has
/// settled.
fn levels_around(
    c: &mut Client,
    (from, to): (f64, f64),
    s: &Settings,
    n: usize,
) -> Result<(Vec<Level>, Vec<Level>)> {
    let rate = c.rate_hz();
    let ticks = |t: f64| (t * rate).round() as u32;
    let window = ticks(s.window_s);
    // The window before, the move, its settling and the window after.
    let span_s =
        s.window_s + motion::move_seconds(from, to, s.speed_um_s) + s.settle_s + s.window_s;
    let cmd = super::commands::move_command(c.axis(), to, s.speed_um_s)?;
    let m = motion::record_every_axis(
        c,
        SIGNALS,
        "the coupling's measurement",
        span_s,
        Until::Seconds(span_s),
        |c, read| {
            let start = c.status()?.tick;
            while c.last_tick().unwrap_or(start) < start + window {
                read(c)?;
            }
            Ok((start, c.ack(&cmd)?))
        },
        || false,
    )?;
    if let Some(f) = m.fault {
        return Err(f);
    }
    let moved_at = m.result;
    let rec = AxesRecording::split(&m.recording, n);
    let end = m.start + ticks(span_s);
    let mean = |from: u32, to: u32| -> Result<Vec<Level>> {
        rec.axes
            .iter()
            .enumerate()
            .map(|(i, r)| {
                level(r.between(from, to)).with_context(|| {
                    format!(
                        "axis {}'s recording has no samples in ticks {from}..{to}",
                        axis_name(i as u8)
                    )
                })
            })
            .collect()
    };
    Ok((
        mean(moved_at.saturating_sub(window), moved_at)?,
        mean(end - window, end)?,
    ))
}

/// The average of `samples`; `None` if there are none.
fn level<'a>(samples: impl Iterator<Item = &'a Sample>) -> Option<Level> {
    let samples: Vec<&Sample> = samples.collect();
    if samples.is_empty() {
        return None;
    }
    let k = samples.len() as f64;
    let sum = |f: fn(&Sample) -> i32| samples.iter().map(|x| real(f(x))).sum::<f64>() / k;
    Some(Level {
        sensor_um: sum(|x| x.x_sensor),
        est_um: sum(|x| x.x_est),
        force_n: sum(|x| x.force),
    })
}

/// Adds axis `j`'s move (each axis's levels before and after) to `m`.
fn add_move(
    m: &mut Pass,
    models: &[FirmwareModel],
    j: usize,
    (before, after): (&[Level], &[Level]),
) -> Result<()> {
    let moved = after[j].sensor_um - before[j].sensor_um;
    if moved.abs() < 1.0 {
        bail!(
            "axis {}'s sensor moved {moved:.3} µm on a move of its own: the loop did not follow",
            axis_name(j as u8)
        );
    }
    let extension = |i: usize, l: &Level| -> Result<f64> {
        let t = &models[i].tables;
        let inv = t.f_k_inv.curve().context("the model's f_K⁻¹ table")?;
        Ok(inv.eval(l.est_um))
    };
    let preload = |i: usize, ext: f64| -> Result<f64> {
        let f = models[i]
            .tables
            .f_f
            .curve()
            .context("the model's f_F table")?;
        Ok(f.eval(ext))
    };
    let stretched = extension(j, &after[j])? - extension(j, &before[j])?;
    m.own_gain[j] += (after[j].est_um - before[j].est_um) / moved;
    for i in (0..before.len()).filter(|&i| i != j) {
        m.seen[i][j] += -(after[i].est_um - before[i].est_um) / moved;
        let own = preload(i, extension(i, &after[i])?)? - preload(i, extension(i, &before[i])?)?;
        m.preload_n_per_um[i][j] += (after[i].force_n - before[i].force_n - own) / stretched;
    }
    Ok(())
}

/// The coupling as a table: for each pair of axes, what the sensors saw,
/// the parasitic motion and the preload coupling.
pub fn table(m: &Measured) -> String {
    let mut out = format!(
        "coupling of {} axes, the sensors' cross-talk taken as {:.3} %:\n",
        m.axes,
        m.coupling.sensor_crosstalk * 100.0
    );
    out.push_str("  of     per µm of   sensors see   parasitic motion   preload\n");
    for i in 0..m.axes {
        for j in (0..m.axes).filter(|&j| j != i) {
            out.push_str(&format!(
                "  {:<6} {:<11} {:>9.3} %   {:>14.3} %   {:>6.3} N/µm\n",
                axis_name(i as u8),
                axis_name(j as u8),
                m.seen[i][j] * 100.0,
                m.coupling.parasitic[i][j] * 100.0,
                m.coupling.preload_n_per_um[i][j]
            ));
        }
    }
    for i in 0..m.axes {
        out.push_str(&format!(
            "  {}'s estimate per µm of its sensor: {:.4}\n",
            axis_name(i as u8),
            m.own_gain[i]
        ));
    }
    out
}
