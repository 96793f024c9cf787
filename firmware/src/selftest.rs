//! The emulated board's scripted run: phases, the virtual stage, statistics, self-checks.
//!
//! The `qemu` firmware calls [`Demo::after_tick`] in thread mode after every
//! control interrupt; the host test suite calls the same function after the same
//! control step in a plain loop. Everything is deterministic (fixed-point core,
//! IEEE `f32` virtual stage, seeded noise), so both produce identical figures and
//! the host predicts what the emulator prints.
//!
//! The script, at the embedded model's control rate (20 kHz):
//!
//! | phase | drive | reference | what is checked |
//! |---|---|---|---|
//! | 1 | straight line (uncompensated) | 2–38 µm raised cosine, 5 Hz | baseline error |
//! | 2 | inverse FPI | same | RMS ≤ 10 % of phase 1, max < 0.5 µm |
//! | 3 | inverse FPI | 15 Hz, amplitude decaying (nested minor loops) | max < 0.5 µm |
//! | 4 | inverse FPI | 5 Hz; force-sensor wire breaks | fault at once, ramp to 0 V, amplifier off |
//! | 5 | inverse FPI | swings to 50 µm, beyond the stroke | fault at the crossing, ramp to 0 V |

use piezo_fpi::control::{ControllerConfig, Fault, ForceSource, LinearDrive, Mode};
use piezo_fpi::fpi::Shape;
use piezo_fpi::q::{Micrometres, Newtons};
use piezo_sim::stage::{stage_a, Stage};
use piezo_sim::stats::ErrorStats;

use crate::frontend::{FORCE_ADC, SETPOINT_DAC};
use crate::reference::RaisedCosine;
use crate::runner::{Command, ControlLoop, Telemetry};
use crate::sim_io::SimLink;

/// The phases of the script.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Phase {
    /// Straight-line drive, 5 Hz full stroke.
    Uncompensated,
    /// Inverse FPI, 5 Hz full stroke.
    Compensated,
    /// Inverse FPI, 15 Hz with decaying amplitude.
    MinorLoops,
    /// Inverse FPI; the force sensor's wire breaks.
    SensorFault,
    /// Inverse FPI; the reference leaves the stroke.
    UnreachableReference,
}

impl Phase {
    /// Short name for logs.
    pub const fn name(&self) -> &'static str {
        match self {
            Self::Uncompensated => "uncompensated 5 Hz",
            Self::Compensated => "compensated 5 Hz",
            Self::MinorLoops => "compensated 15 Hz minor loops",
            Self::SensorFault => "force sensor fault",
            Self::UnreachableReference => "unreachable reference",
        }
    }
}

/// Figures of one finished phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseReport {
    /// Which phase.
    pub phase: Phase,
    /// Stage position minus reference (after the settling period), µm.
    pub tracking: ErrorStats<f32>,
    /// Virtual sensor minus stage position (after settling, outside faults), µm.
    pub estimate: ErrorStats<f32>,
    /// Ticks in the phase.
    pub steps: u32,
    /// First fault seen, with the phase tick it appeared at.
    pub fault: Option<(Fault, u32)>,
    /// Phase tick at which the output reached the safe voltage after the fault.
    pub safe_at: Option<u32>,
    /// The amplifier was switched off while in the safe state.
    pub amplifier_off: bool,
    /// Largest setpoint seen, V.
    pub max_voltage: f32,
    /// The phase's self-check passed.
    pub pass: bool,
}

/// A value rounded to the nearest integer (halves away from zero), for logs that
/// print no floats.
pub fn round(x: f32) -> i64 {
    (if x < 0.0 { x - 0.5 } else { x + 0.5 }) as i64
}

/// The figures of a phase the emulator reports and the host's twin recomputes,
/// compared value by value within [`TWIN_BOUND_UM`].
///
/// The emulated board prints them as one line ([`write`](Self::write)) that the
/// host reads back ([`parse`](Self::parse)), lengths in picometres (integers: no
/// float formatting in the firmware):
/// `values phase 1 ticks 12000 rms_pm 37068 max_pm 93630 est_rms_pm 37082 fault 0 0 safe_at - amp_off 0 pass 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseValues {
    /// Position of the phase in the script.
    pub phase: u8,
    /// Ticks in the phase.
    pub ticks: u32,
    /// Tracking error RMS, µm.
    pub rms_um: f32,
    /// Largest tracking error, µm.
    pub max_um: f32,
    /// Virtual-sensor error RMS, µm.
    pub est_rms_um: f32,
    /// First fault (its code, 0 for none) and the phase tick it latched at.
    pub fault: (u8, u32),
    /// Phase tick at which the output reached the safe voltage.
    pub safe_at: Option<u32>,
    /// The amplifier was switched off in the safe state.
    pub amplifier_off: bool,
    /// The phase's self-check.
    pub pass: bool,
}

/// How far the emulator's figures may lie from the host twin's, µm (0.5 nm, a
/// hundredth of the smallest figure). The two run the same fixed-point core and
/// the same `f32` virtual stage (`libm` on both), so they agree to the bit; the
/// bound is what a legitimate difference in float evaluation could cost.
pub const TWIN_BOUND_UM: f32 = 5e-4;

impl PhaseValues {
    /// The values of a phase report, the phase at position `phase` of the script.
    pub fn of(phase: u8, r: &PhaseReport) -> Self {
        Self {
            phase,
            ticks: r.steps,
            rms_um: r.tracking.rms(),
            max_um: r.tracking.max_abs(),
            est_rms_um: r.estimate.rms(),
            fault: r.fault.map_or((0, 0), |(f, at)| (f as u8, at)),
            safe_at: r.safe_at,
            amplifier_off: r.amplifier_off,
            pass: r.pass,
        }
    }

    /// The line the emulator prints (lengths rounded to 1 pm).
    pub fn write(&self, w: &mut impl core::fmt::Write) -> core::fmt::Result {
        let pm = |um: f32| round(um * 1e6);
        write!(
            w,
            "values phase {} ticks {} rms_pm {} max_pm {} est_rms_pm {} fault {} {} safe_at ",
            self.phase,
            self.ticks,
            pm(self.rms_um),
            pm(self.max_um),
            pm(self.est_rms_um),
            self.fault.0,
            self.fault.1
        )?;
        match self.safe_at {
            Some(t) => write!(w, "{t}")?,
            None => w.write_str("-")?,
        }
        write!(
            w,
            " amp_off {} pass {}",
            self.amplifier_off as u8, self.pass as u8
        )
    }

    /// Reads a line [`write`](Self::write) made; `None` for any other line.
    pub fn parse(line: &str) -> Option<Self> {
        let mut f = line.strip_prefix("values ")?.split_whitespace();
        // `key value`; an empty key reads the next value alone.
        let mut field = |key: &str| -> Option<&str> {
            if !key.is_empty() {
                (f.next()? == key).then_some(())?;
            }
            f.next()
        };
        let phase = field("phase")?.parse().ok()?;
        let ticks = field("ticks")?.parse().ok()?;
        let mut um =
            |key: &str| -> Option<f32> { Some(field(key)?.parse::<i64>().ok()? as f32 * 1e-6) };
        let rms_um = um("rms_pm")?;
        let max_um = um("max_pm")?;
        let est_rms_um = um("est_rms_pm")?;
        let code = field("fault")?.parse().ok()?;
        let at = field("")?.parse().ok()?;
        let safe_at = match field("safe_at")? {
            "-" => None,
            t => Some(t.parse().ok()?),
        };
        let amplifier_off = field("amp_off")? == "1";
        let pass = field("pass")? == "1";
        Some(Self {
            phase,
            ticks,
            rms_um,
            max_um,
            est_rms_um,
            fault: (code, at),
            safe_at,
            amplifier_off,
            pass,
        })
    }

    /// What differs from another run's values: events and ticks exactly, the
    /// error figures within `bound_um`; `None` if they agree.
    pub fn differs(&self, other: &Self, bound_um: f32) -> Option<&'static str> {
        let near = |a: f32, b: f32| (a - b).abs() <= bound_um;
        if (self.phase, self.ticks) != (other.phase, other.ticks) {
            Some("phase or ticks")
        } else if (self.fault, self.safe_at, self.amplifier_off, self.pass)
            != (other.fault, other.safe_at, other.amplifier_off, other.pass)
        {
            Some("fault, safe state or self-check")
        } else if !near(self.rms_um, other.rms_um) || !near(self.max_um, other.max_um) {
            Some("tracking error")
        } else if !near(self.est_rms_um, other.est_rms_um) {
            Some("virtual-sensor error")
        } else {
            None
        }
    }
}

/// What thread mode does after a tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Advance {
    /// A new command for the ISR, at phase boundaries.
    pub command: Option<Command>,
    /// The report of the phase that just ended.
    pub report: Option<PhaseReport>,
    /// The script is over.
    pub done: bool,
}

const PHASES: [Phase; 5] = [
    Phase::Uncompensated,
    Phase::Compensated,
    Phase::MinorLoops,
    Phase::SensorFault,
    Phase::UnreachableReference,
];

/// Sensor reading of a broken wire: the ADC's top rail through the board's scale (N).
pub const BROKEN_WIRE_N: f32 = 500.0;

/// The scripted run (state of thread mode).
pub struct Demo {
    f_k: piezo_fpi::table::Table<'static>,
    rate_hz: f32,
    linear: LinearDrive,
    stage: Stage<'static>,
    phase: usize,
    tick: u32,
    report: PhaseReport,
    safe_voltage: f32,
    slew_steps_to_safe: u32,
}

impl Demo {
    /// The script for a controller; the baseline line runs through the compensated
    /// controller's own voltages at the ends of the 2–38 µm stroke on the loading
    /// curve (a fair straight-line drive: right at the ends, hysteresis in between).
    pub fn new<const N: usize, const C: usize, G: Shape<'static>, H: Shape<'static>>(
        cfg: &ControllerConfig<'static, N, C, G, H>,
        rate_hz: u32,
    ) -> Option<Self> {
        let predicted = cfg.with_force_source(ForceSource::Predicted);
        let mut st = predicted.initial_state();
        // Walk up the loading curve slowly so the slew limit never bites.
        let mut u_lo = 0.0;
        let mut u_hi = 0.0;
        for k in 0..=4000 {
            let x = Micrometres::from_num(2.0 + 36.0 * k as f64 / 4000.0);
            let out = predicted.step(&mut st, x, Newtons::ZERO);
            if k == 0 {
                u_lo = out.voltage.to_num::<f64>();
            }
            u_hi = out.voltage.to_num::<f64>();
        }
        let linear = LinearDrive::through(2.0, u_lo, 38.0, u_hi)?;
        let safe_voltage = cfg.safe_voltage().to_num::<f32>();
        let step = cfg.limits().max_step().to_num::<f32>();
        let span = cfg.limits().max().to_num::<f32>() - cfg.limits().min().to_num::<f32>();
        Some(Self {
            f_k: *cfg.f_k(),
            rate_hz: rate_hz as f32,
            linear,
            stage: Stage::new(&stage_a::PARAMS, 0x5EED)?,
            phase: 0,
            tick: 0,
            report: Self::blank(PHASES[0]),
            safe_voltage,
            slew_steps_to_safe: (span / step) as u32 + 2,
        })
    }

    fn blank(phase: Phase) -> PhaseReport {
        PhaseReport {
            phase,
            tracking: ErrorStats::new(),
            estimate: ErrorStats::new(),
            steps: 0,
            fault: None,
            safe_at: None,
            amplifier_off: false,
            max_voltage: 0.0,
            pass: false,
        }
    }

    fn wave(
        &self,
        frequency_hz: f32,
        top_um: f32,
        decay_to_um: Option<f32>,
        steps: u32,
    ) -> RaisedCosine {
        let amplitude = (top_um - 2.0) / 2.0;
        let amplitude_step = match decay_to_um {
            Some(end) => Micrometres::from_num((end - amplitude) / steps as f32),
            None => Micrometres::ZERO,
        };
        RaisedCosine {
            center: Micrometres::from_num(2.0 + amplitude),
            amplitude: Micrometres::from_num(amplitude),
            phase_step: RaisedCosine::phase_step_for(frequency_hz, self.rate_hz),
            amplitude_step,
        }
    }

    /// (ticks, settling ticks) of a phase.
    fn length(&self, phase: Phase) -> (u32, u32) {
        let s = |seconds: f32| (seconds * self.rate_hz) as u32;
        match phase {
            Phase::Uncompensated | Phase::Compensated => (s(0.6), s(0.2)),
            Phase::MinorLoops => (s(0.8), s(0.0)),
            // Statistics of the fault phases skip the jump to the new trajectory.
            Phase::SensorFault => (s(0.3), s(0.05)),
            Phase::UnreachableReference => (s(0.3), s(0.05)),
        }
    }

    /// The tick (within the phase) at which the sensor fault is injected.
    fn fault_tick(&self) -> u32 {
        (0.1 * self.rate_hz) as u32
    }

    /// The command that starts the current phase.
    pub fn command(&self) -> Command {
        let phase = PHASES[self.phase];
        let (steps, _) = self.length(phase);
        let (mode, wave) = match phase {
            Phase::Uncompensated => (
                Mode::Uncompensated(self.linear),
                self.wave(5.0, 38.0, None, steps),
            ),
            Phase::Compensated | Phase::SensorFault => {
                (Mode::Compensated, self.wave(5.0, 38.0, None, steps))
            }
            Phase::MinorLoops => (Mode::Compensated, self.wave(15.0, 38.0, Some(1.0), steps)),
            Phase::UnreachableReference => (Mode::Compensated, self.wave(5.0, 50.0, None, steps)),
        };
        Command {
            mode,
            wave,
            clear_fault: true,
        }
    }

    /// Advances the virtual stage by one tick and scripts the next: `tel` is what
    /// the ISR reported; the DAC output and enable line are read from `link`, and
    /// the force for the next tick is left there.
    pub fn after_tick(&mut self, tel: &Telemetry, link: &SimLink) -> Advance {
        let phase = PHASES[self.phase];
        let (steps, settle) = self.length(phase);
        let (voltage_v, amplifier_on) = link.output();
        let sample = self.stage.step(if amplifier_on { voltage_v } else { 0.0 });
        let r = &mut self.report;
        if voltage_v > r.max_voltage {
            r.max_voltage = voltage_v;
        }
        if let (None, Some(f)) = (r.fault, tel.fault) {
            r.fault = Some((f, self.tick));
        }
        if r.fault.is_some() {
            if r.safe_at.is_none() && voltage_v <= self.safe_voltage {
                r.safe_at = Some(self.tick);
            }
            if !amplifier_on {
                r.amplifier_off = true;
            }
        } else if self.tick >= settle {
            r.tracking.add(sample.x_fhps_um - tel.x_ref.to_num::<f32>());
            let x_est = self.f_k.eval(tel.x_pea_est);
            r.estimate.add(x_est.to_num::<f32>() - sample.x_fhps_um);
        }
        self.tick += 1;
        r.steps = self.tick;

        let mut advance = Advance {
            command: None,
            report: None,
            done: false,
        };
        if self.tick >= steps {
            let mut report = *r;
            report.pass = self.check(&report);
            advance.report = Some(report);
            self.tick = 0;
            if self.phase + 1 < PHASES.len() {
                self.phase += 1;
                self.report = Self::blank(PHASES[self.phase]);
                advance.command = Some(self.command());
            } else {
                advance.done = true;
            }
        }
        // The sensor reading for the next tick, with the scripted wire break.
        let mut force = self.stage.sense_force(sample.force_n);
        if PHASES[self.phase] == Phase::SensorFault && self.tick >= self.fault_tick() {
            force = BROKEN_WIRE_N;
        }
        link.set_force(force);
        advance
    }

    fn check(&self, r: &PhaseReport) -> bool {
        let ramp_ok = |r: &PhaseReport| match (r.fault, r.safe_at) {
            (Some((_, at)), Some(safe)) => safe - at <= self.slew_steps_to_safe && r.amplifier_off,
            _ => false,
        };
        match r.phase {
            Phase::Uncompensated => r.fault.is_none(),
            Phase::Compensated | Phase::MinorLoops => {
                r.fault.is_none() && r.tracking.max_abs() < Self::MAX_ERROR_UM
            }
            Phase::SensorFault => {
                matches!(r.fault, Some((Fault::ForceOutOfRange, at)) if at == self.fault_tick())
                    && ramp_ok(r)
            }
            Phase::UnreachableReference => {
                matches!(r.fault, Some((Fault::ReferenceUnreachable, _))) && ramp_ok(r)
            }
        }
    }

    /// The compensated phase must cut the uncompensated RMS error to this fraction or less.
    pub const REQUIRED_RATIO: f32 = 0.10;
    /// Largest tracking error a compensated phase may show, µm.
    pub const MAX_ERROR_UM: f32 = 0.5;
}

/// Runs the whole script with the control loop called in place of the interrupt:
/// the figures the emulated board must print. Returns the phase reports and the
/// number of ticks.
pub fn run_on_host<const N: usize, const C: usize, G: Shape<'static>, H: Shape<'static>>(
    cfg: &'static ControllerConfig<'static, N, C, G, H>,
    rate_hz: u32,
) -> Option<([Option<PhaseReport>; 5], u32)> {
    let link = SimLink::new(FORCE_ADC, SETPOINT_DAC);
    let mut demo = Demo::new(cfg, rate_hz)?;
    demo.prime(&link);
    let mut lp = ControlLoop::new(cfg, link.hardware(), demo.command());
    let mut reports = [None; 5];
    let mut k = 0;
    for _ in 0..10_000_000u32 {
        let tel = lp.run();
        let adv = demo.after_tick(&tel, &link);
        if let Some(r) = adv.report {
            if let Some(slot) = reports.get_mut(k) {
                *slot = Some(r);
            }
            k += 1;
        }
        if let Some(c) = adv.command {
            lp.apply(c);
        }
        if adv.done {
            return Some((reports, tel.step + 1));
        }
    }
    None
}

impl Demo {
    /// Leaves the first force reading (the stage at rest) on the link.
    pub fn prime(&mut self, link: &SimLink) {
        let f = self.stage.rest_force();
        link.set_force(self.stage.sense_force(f));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model;

    #[test]
    fn phase_values_round_trip_through_their_line() {
        let v = PhaseValues {
            phase: 3,
            ticks: 6000,
            rms_um: 0.043_187_2,
            max_um: 0.083_001,
            est_rms_um: 1.0e-7,
            fault: (1, 2000),
            safe_at: Some(2018),
            amplifier_off: true,
            pass: true,
        };
        let mut line = String::new();
        v.write(&mut line).unwrap();
        let back = PhaseValues::parse(&line).unwrap();
        assert_eq!(v.differs(&back, 1e-6), None, "{line}");
        let off = PhaseValues {
            rms_um: v.rms_um + 1e-3,
            ..v
        };
        assert_eq!(v.differs(&off, TWIN_BOUND_UM), Some("tracking error"));
        assert_eq!(PhaseValues::parse("phase compensated 5 Hz ..."), None);
    }

    #[test]
    fn scripted_run_passes_its_self_checks_on_the_host() {
        let (reports, ticks) = run_on_host(&model::CONTROLLER, model::CONTROL_RATE_HZ).unwrap();
        let r: Vec<&PhaseReport> = reports.iter().flatten().collect();
        assert_eq!(r.len(), PHASES.len(), "every phase reported");
        assert_eq!(ticks, r.iter().map(|r| r.steps).sum::<u32>());
        for r in &r {
            assert!(r.pass, "{} failed its self-check: {r:?}", r.phase.name());
        }
        let (off, on) = (r[0].tracking.rms(), r[1].tracking.rms());
        assert!(on <= Demo::REQUIRED_RATIO * off, "{on} µm vs {off} µm");
        assert!(matches!(r[3].fault, Some((Fault::ForceOutOfRange, _))));
        assert!(matches!(r[4].fault, Some((Fault::ReferenceUnreachable, _))));
    }
}
