//! The control ISR's whole job, hardware-independent: apply a pending command,
//! generate the reference, run one control tick, report telemetry.
//!
//! The firmware's timer interrupt owns a [`ControlLoop`] and calls
//! [`ControlLoop::run`]; thread mode talks to it only through [`Command`]s (in) and
//! [`Telemetry`] (out), like Stabilizer's settings swapped in by a low-priority task.

use crate::reference::{RaisedCosine, Waveform};
use embedded_hal::digital::OutputPin;
use piezo_fpi::control::{ControllerConfig, ControllerState, Fault, Mode};
use piezo_fpi::fpi::Shape;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Micrometres, Volts};

/// What thread mode asks of the control ISR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Command {
    /// Compensated or straight-line drive.
    pub mode: Mode,
    /// The reference trajectory (restarted from its phase 0).
    pub wave: RaisedCosine,
    /// Leave the safe state (only once the output is at the safe voltage).
    pub clear_fault: bool,
}

/// What one control tick reports to thread mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Telemetry {
    /// Tick number since start (wraps).
    pub step: u32,
    /// Reference, µm.
    pub x_ref: Micrometres,
    /// Applied setpoint, V.
    pub voltage: Volts,
    /// Virtual sensor: estimated stack extension, µm (stage position:
    /// [`ControllerConfig::stage_position`]).
    pub x_pea_est: Micrometres,
    /// Latched fault.
    pub fault: Option<Fault>,
}

/// The control ISR's state (one per stage channel).
///
/// `N`, `C`, `G`, `H`: the model's structure (see [`piezo_fpi::Fpi`]); `S`, `A`, `E`:
/// the force sensor, the amplifier and its enable line.
pub struct ControlLoop<'c, const N: usize, const C: usize, G, H, S, A, E> {
    cfg: &'c ControllerConfig<'c, N, C, G, H>,
    hw: Hardware<S, A, E>,
    state: ControllerState<N, C>,
    mode: Mode,
    wave: RaisedCosine,
    wave_state: Waveform,
    step: u32,
}

impl<
        'c,
        const N: usize,
        const C: usize,
        G: Shape<'c>,
        H: Shape<'c>,
        S: ForceSensor,
        A: Setpoint,
        E: OutputPin,
    > ControlLoop<'c, N, C, G, H, S, A, E>
{
    /// A loop at rest, running `first`. Reads the force sensor once and takes the
    /// reading as the compliance term's reference force ([`ControllerConfig::tare`]):
    /// the stage is at rest and its position is zero now.
    pub fn new(
        cfg: &'c ControllerConfig<'c, N, C, G, H>,
        mut hw: Hardware<S, A, E>,
        first: Command,
    ) -> Self {
        let mut state = cfg.initial_state();
        let rest = hw.sensor.read_force();
        cfg.tare(&mut state, rest);
        Self {
            cfg,
            hw,
            state,
            mode: first.mode,
            wave: first.wave,
            wave_state: first.wave.start(),
            step: 0,
        }
    }

    /// Takes a command: new mode and trajectory, and a fault-clear request.
    pub fn apply(&mut self, c: Command) {
        self.mode = c.mode;
        self.wave = c.wave;
        self.wave_state = c.wave.start();
        if c.clear_fault {
            self.state.clear_fault(self.cfg);
        }
    }

    /// One control period. Bounded time, no panic.
    #[inline]
    pub fn run(&mut self) -> Telemetry {
        let x_ref = self.wave.next(&mut self.wave_state);
        let out = self.hw.tick(self.cfg, &mut self.state, &self.mode, x_ref);
        let t = Telemetry {
            step: self.step,
            x_ref,
            voltage: out.voltage,
            x_pea_est: out.x_pea_est,
            fault: out.fault,
        };
        self.step = self.step.wrapping_add(1);
        t
    }

    /// The controller's memory (for diagnostics).
    pub const fn state(&self) -> &ControllerState<N, C> {
        &self.state
    }
}

/// A value in nanometres rounded to an integer, for logs that print no floats.
pub fn nm(um: f32) -> i32 {
    let x = um * 1000.0;
    (if x < 0.0 { x - 0.5 } else { x + 0.5 }) as i32
}
