//! A scripted session with a board, as a user would run it: load a model, record,
//! move, run the stroke without and with compensation, stream nested minor loops,
//! break the force sensor's wire (emulated board), ask for an unreachable
//! position, send bad frames — then read the recording back, score each phase from
//! it, and replay the whole session on the twin.
//!
//! `cargo demo` runs it on the emulated board; the integration tests check its
//! figures. Every phase is scored from the board's own recording: tracking error
//! = true stage position − reference (the emulated board records the virtual
//! stage's position), after a settling time, outside faults.

use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use fpi_firmware::control::recorder::{signal, status};
use fpi_protocol::Shape;
use fpi_protocol::{BenchOrder, Command, Counters, FaultReport, Refusal, Reply};
use piezo_fpi::control::Fault;
use piezo_sim::stats::ErrorStats;

use super::client::{refusal, Client};
use super::follow::Follow;
use super::recording::Recording;
use super::twin::{self, Agreement};

/// Ticks per recorded sample: 400 samples/s of every signal, about 9 kB/s with
/// the polls, within what the UART carries (`fpi_host::board::budget`).
pub const DECIMATION: u16 = 50;
/// The compensated 5 Hz phase's RMS error must be at most this fraction of the
/// uncompensated one.
pub const REQUIRED_RATIO: f64 = 0.10;
/// Largest tracking error a compensated phase may show, µm.
pub const MAX_ERROR_UM: f64 = 0.5;

/// One phase of the session, scored from the recording.
#[derive(Debug, Clone)]
pub struct PhaseResult {
    /// What it does.
    pub name: &'static str,
    /// Its ticks: `[from, to)`.
    pub from: u32,
    /// End tick (exclusive).
    pub to: u32,
    /// True position − reference after settling, µm.
    pub tracking: ErrorStats<f64>,
    /// Estimated − true position, µm.
    pub estimate: ErrorStats<f64>,
    /// What else happened, for the report.
    pub note: String,
    /// Its check passed.
    pub pass: bool,
}

impl PhaseResult {
    /// Its figures as the terminal and the report print them, whole nm: the
    /// tracking error's RMS and largest value and the virtual sensor's RMS
    /// error; `-` each for a phase that tracked nothing (a refused reference).
    pub fn figures_nm(&self) -> [String; 3] {
        if self.tracking.count() == 0 {
            return ["-".into(), "-".into(), "-".into()];
        }
        let nm = |x: f64| format!("{:.0}", x * 1e3);
        [
            nm(self.tracking.rms()),
            nm(self.tracking.max_abs()),
            nm(self.estimate.rms()),
        ]
    }
}

/// The whole session.
#[derive(Debug, Clone)]
pub struct SessionReport {
    /// The phases in order.
    pub phases: Vec<PhaseResult>,
    /// The recording of the whole session.
    pub recording: Recording,
    /// The recording against the twin's replay of the session.
    pub twin: Agreement,
    /// The link's counters at the end.
    pub counters: Counters,
    /// Wall-clock time of the session on the board.
    pub elapsed: Duration,
    /// Board ticks per wall-clock second.
    pub ticks_per_second: f64,
}

impl SessionReport {
    /// Every phase passed, the twin agrees, nothing was dropped.
    pub fn pass(&self) -> bool {
        self.phases.iter().all(|p| p.pass)
            && self.twin.within(twin::TWIN_BOUND)
            && self.recording.dropped == 0
    }

    /// A phase by name.
    pub fn phase(&self, name: &str) -> Option<&PhaseResult> {
        self.phases.iter().find(|p| p.name == name)
    }
}

/// The client and the recording gathered while the session runs.
struct Session<'c> {
    f: Follow<'c>,
}

impl Session<'_> {
    fn phase(&self, name: &'static str, from: u32, to: u32, settle: u32) -> PhaseResult {
        PhaseResult {
            name,
            from,
            to,
            tracking: self.f.rec.tracking(from + settle, to),
            estimate: self.f.rec.estimate(from + settle, to),
            note: String::new(),
            pass: false,
        }
    }

    /// A raised cosine over 2–38 µm at `hz` for `cycles` periods, driven `compensated`
    /// or not; the phase, settled for 0.2 s.
    fn stroke(
        &mut self,
        name: &'static str,
        compensated: bool,
        hz: f64,
        cycles: u32,
    ) -> Result<PhaseResult> {
        self.f.c.ack(&Command::Drive {
            axis: self.f.c.axis(),
            compensated,
        })?;
        let from = self.f.c.wave(Shape::RaisedCosine, 18.0, 20.0, hz, cycles)?;
        let to = self.f.until_hold()?;
        let settle = self.f.ticks(0.2);
        Ok(self.phase(name, from, to, settle))
    }

    /// Nested minor loops: a 15 Hz raised cosine whose amplitude decays from 18 to
    /// 1 µm, streamed at 1 kHz (the board interpolates).
    fn minor_loops(&mut self) -> Result<PhaseResult> {
        let (hz, seconds, interval) = (15.0, 0.8, 20u16);
        let n = (seconds * self.f.rate() / interval as f64) as usize;
        let points: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 * interval as f64 / self.f.rate();
                let a = 18.0 + (1.0 - 18.0) * t / seconds;
                2.0 + a - a * (std::f64::consts::TAU * hz * t).cos()
            })
            .collect();
        let rec = &mut self.f.rec;
        let r = self.f.c.stream(
            &points,
            interval,
            |_| {},
            |c| {
                let (s, dropped) = c.drain()?;
                rec.samples.extend(s);
                rec.dropped = dropped;
                Ok(())
            },
        )?;
        let to = self.f.until_hold()?;
        self.f.drain()?;
        let mut p = self.phase("compensated 15 Hz minor loops (streamed)", r.started, to, 0);
        p.note = format!(
            "{} points at 1 kHz, {} underrun ticks",
            r.points, r.underruns
        );
        p.pass = p.tracking.count() > 0 && p.tracking.max_abs() < MAX_ERROR_UM && r.underruns == 0;
        Ok(p)
    }

    /// The force sensor's wire breaks during a 5 Hz stroke: the fault latches at
    /// once and the output parks at the safe voltage along the gentle profile
    /// (`piezo_fpi::limits`), then the amplifier goes off.
    fn sensor_fault(&mut self) -> Result<PhaseResult> {
        let from = self.f.c.wave(Shape::RaisedCosine, 18.0, 20.0, 5.0, 0)?;
        self.f.until_tick(from + self.f.ticks(0.15))?;
        let broken = self.f.c.bench(BenchOrder::SensorOpen(true))?;
        let f = self.wait_fault()?;
        let to = f.safe_at.unwrap_or(f.at) + self.f.ticks(0.01);
        self.f.until_tick(to)?;
        self.f.drain()?;
        self.f.c.bench(BenchOrder::SensorOpen(false))?;
        self.f.c.ack(&Command::ClearFault)?;
        let mut p = self.phase("force sensor wire breaks", from, broken, self.f.ticks(0.05));
        let ramp = f.safe_at.map(|s| s - f.at);
        let off = self
            .f
            .rec
            .between(f.safe_at.unwrap_or(u32::MAX), to)
            .all(|s| s.status & status::AMPLIFIER_ON == 0);
        // The park over the whole 150 V at most, and one tick to notice.
        let full = piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150));
        let ramp_ok = ramp.is_some_and(|r| r <= full + 1);
        // The broken wire's reading reaches the loop at the next tick's sample.
        p.pass = f.code == Fault::ForceOutOfRange as u8 && f.at == broken + 1 && ramp_ok && off;
        p.note = format!(
            "fault at tick {} (wire broken after tick {broken}): {}; output at the safe voltage \
             {} ticks later; amplifier {}",
            f.at,
            Fault::from_code(f.code).map_or("?", |f| f.message()),
            ramp.map_or("never".to_string(), |r| r.to_string()),
            if off { "switched off" } else { "STILL ON" }
        );
        Ok(p)
    }

    fn wait_fault(&mut self) -> Result<FaultReport> {
        let start = Instant::now();
        loop {
            self.f.drain()?;
            let s = self.f.c.status()?;
            if let Some(f) = s.fault.filter(|f| f.safe_at.is_some()) {
                return Ok(f);
            }
            if start.elapsed() > Duration::from_secs(60) {
                bail!("no fault reached the safe state within a minute");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// 50 µm lies beyond the stroke: the board refuses to go there.
    fn unreachable(&mut self) -> Result<PhaseResult> {
        let from = self.f.c.status()?.tick;
        let mut p = self.phase("unreachable reference (50 µm)", from, from, 0);
        match self.f.c.move_to(50.0, 1000.0) {
            Ok(_) => p.note = "ACCEPTED a move beyond the stroke".into(),
            Err(e) => match refusal(&e) {
                Some(r) => {
                    p.pass = r.code == Refusal::OutOfRange;
                    p.note = format!("refused: {}", r.reason);
                }
                None => return Err(e),
            },
        }
        Ok(p)
    }

    /// Bad frames while a 15 Hz sine runs: each is refused and counted; the loop
    /// carries on (the twin, which never saw them, checks it).
    fn bad_frames(&mut self) -> Result<PhaseResult> {
        let from = self.f.c.wave(Shape::Sine, 17.0, 20.0, 15.0, 6)?;
        let before = self.f.c.counters()?;
        let mut good = Vec::new();
        {
            use fpi_protocol::frame;
            use fpi_protocol::{Header, MAX_FRAME, VERSION};
            let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
            let h = Header {
                version: VERSION,
                seq: 999,
            };
            let n = frame::encode(&h, &Command::Status { axis: 0 }, &mut scratch, &mut out)
                .map_err(|e| anyhow::anyhow!(e.message()))?;
            good.extend_from_slice(&out[..n]);
        }
        let mut wrong_crc = good.clone();
        wrong_crc[1] ^= 0x40;
        let mut truncated = good[..good.len() - 3].to_vec();
        truncated.push(0);
        let garbage: Vec<u8> = (0..40u8)
            .map(|k| k.wrapping_mul(37) | 1)
            .chain([0])
            .collect();
        let mut refused = 0;
        for f in [&garbage, &truncated, &wrong_crc] {
            if let (
                _,
                Reply::Refused {
                    code: Refusal::Malformed,
                    ..
                },
            ) = self.f.c.send_raw(f)?
            {
                refused += 1;
            }
        }
        let after = self.f.c.counters()?;
        let to = self.f.until_hold()?;
        let mut p = self.phase(
            "15 Hz sine while bad frames arrive",
            from,
            to,
            self.f.ticks(0.05),
        );
        let counted = after.malformed - before.malformed;
        p.pass = refused == 3 && counted == 3 && p.tracking.max_abs() < MAX_ERROR_UM;
        p.note = format!(
            "garbage, truncated and wrong-CRC frames: {refused} refused, {counted} counted as malformed"
        );
        Ok(p)
    }
}

/// Runs the session on an open board with `image` as its model (uploaded and
/// stored); the board must be freshly started (the twin boots the same way).
pub fn run(c: &mut Client, image: &[u8]) -> Result<SessionReport> {
    let started = Instant::now();
    let t0 = c.status()?.tick;
    c.upload(image, true, |_| {})
        .context("uploading the model")?;
    c.ack(&Command::Record {
        axis: c.axis(),
        decimation: DECIMATION,
        signals: signal::ALL,
    })?;
    let mut s = Session {
        f: Follow::new(c, signal::ALL),
    };
    s.f.c.move_to(2.0, 1000.0)?;
    s.f.until_hold()?;
    let mut phases = Vec::new();
    let mut off = s.stroke("uncompensated 5 Hz", false, 5.0, 3)?;
    off.pass = off.tracking.count() > 0;
    let mut on = s.stroke("compensated 5 Hz", true, 5.0, 3)?;
    let ratio = on.tracking.rms() / off.tracking.rms();
    on.pass = on.tracking.max_abs() < MAX_ERROR_UM && ratio <= REQUIRED_RATIO;
    on.note = format!("{:.1} % of the uncompensated RMS error", ratio * 100.0);
    phases.extend([off, on]);
    phases.push(s.minor_loops()?);
    phases.push(s.sensor_fault()?);
    phases.push(s.unreachable()?);
    phases.push(s.bad_frames()?);
    s.f.c.ack(&Command::RecordStop)?;
    s.f.drain()?;
    let end = s.f.c.status()?.tick;
    let counters = s.f.c.counters()?;
    let elapsed = started.elapsed();
    let rec = s.f.rec;
    let last = rec.samples.last().map_or(end, |x| x.tick);
    let trace = twin::replay(&c.log, last)?;
    let agreement = twin::compare(&rec.samples, rec.signals, &trace);
    Ok(SessionReport {
        phases,
        recording: rec,
        twin: agreement,
        counters,
        elapsed,
        ticks_per_second: (end - t0) as f64 / elapsed.as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn phase(errors: &[f64]) -> PhaseResult {
        let mut tracking = ErrorStats::new();
        let mut estimate = ErrorStats::new();
        for e in errors {
            tracking.add(*e);
            estimate.add(e / 2.0);
        }
        PhaseResult {
            name: "a phase",
            from: 0,
            to: 1,
            tracking,
            estimate,
            note: String::new(),
            pass: true,
        }
    }

    #[test]
    fn a_phase_that_tracked_nothing_prints_dashes_not_zeros() {
        assert_eq!(phase(&[]).figures_nm(), ["-", "-", "-"]);
        assert_eq!(phase(&[0.003, -0.004]).figures_nm(), ["4", "4", "2"]);
    }
}
