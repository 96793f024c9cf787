//! The emulated board's twin on the host: the firmware's control loop, virtual
//! stage and link handler in one thread ([`fpi_firmware::emulation::virtual_bench::Virtual`]),
//! fed the requests the real run received at the ticks their replies named.
//!
//! Both sides run the same code on the same inputs: the fixed-point core, the
//! `f32` virtual stage (IEEE arithmetic, `libm` on both), its seeded sensor noise,
//! and every request at the tick that first saw it. So the twin reproduces every
//! sample the board recorded; [`compare`] says by how much it does not.

use anyhow::Result;
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::recorder::{signal, Sample};
use fpi_firmware::emulation::virtual_bench::Virtual;
use fpi_firmware::link::handler::Board;
use fpi_protocol::MAX_FRAME;

use super::client::{real, Logged};

/// The virtual board with every tick's sample kept.
struct Traced {
    board: Virtual,
    trace: Vec<Sample>,
}

impl Traced {
    fn tick(&mut self) {
        let s = self.board.tick();
        self.trace.push(s);
    }
}

impl Board for Traced {
    fn exchange<R>(&mut self, f: impl FnOnce(&mut Exchange<'_>) -> R) -> R {
        self.board.exchange(f)
    }
    fn wait(&mut self) {
        self.tick();
    }
}

/// Replays `log` on a freshly booted virtual board (as the emulated board boots:
/// the factory model, empty flash) through tick `until`; every tick's sample.
pub fn replay(log: &[Logged], until: u32) -> Result<Vec<Sample>> {
    let (board, mut handler) = super::inprocess::boot()?;
    // The log's ticks already hold the link's pace.
    handler.unpaced();
    let mut t = Traced {
        board,
        trace: Vec::with_capacity(until as usize + 1),
    };
    let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
    for l in log {
        while t.board.control.next_tick() < l.tick {
            t.tick();
        }
        let mut frame = l.frame.clone();
        handler.handle(&mut t, &mut frame, &mut scratch, &mut out);
    }
    while t.board.control.next_tick() <= until {
        t.tick();
    }
    Ok(t.trace)
}

/// How far a recording lies from the twin's run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Agreement {
    /// Samples compared.
    pub samples: usize,
    /// Largest difference of a position (reference, estimate, true position), µm.
    pub position_um: f64,
    /// Largest difference of the setpoint, V.
    pub voltage_v: f64,
    /// Largest difference of the force reading, N.
    pub force_n: f64,
    /// Samples whose status bits differ.
    pub status: usize,
    /// Recorded ticks the twin did not reach.
    pub missing: usize,
}

/// Every sample of `recorded` (with `signals`) against the twin's sample of the
/// same tick.
pub fn compare(recorded: &[Sample], signals: u8, twin: &[Sample]) -> Agreement {
    let mut a = Agreement::default();
    for r in recorded {
        let Some(t) = twin.get(r.tick as usize) else {
            a.missing += 1;
            continue;
        };
        a.samples += 1;
        let d = |x: i32, y: i32| real(x.wrapping_sub(y)).abs();
        let mut pos = 0.0f64;
        if signals & signal::X_REF != 0 {
            pos = pos.max(d(r.x_ref, t.x_ref));
        }
        if signals & signal::X_EST != 0 {
            pos = pos.max(d(r.x_est, t.x_est));
        }
        if signals & signal::X_TRUE != 0 {
            pos = pos.max(d(r.x_true, t.x_true));
        }
        a.position_um = a.position_um.max(pos);
        if signals & signal::VOLTAGE != 0 {
            a.voltage_v = a.voltage_v.max(d(r.voltage, t.voltage));
        }
        if signals & signal::FORCE != 0 {
            a.force_n = a.force_n.max(d(r.force, t.force));
        }
        if signals & signal::STATUS != 0 && r.status != t.status {
            a.status += 1;
        }
    }
    a
}

/// How far a recording may lie from its twin: 0.5 nm, 0.5 mV, 0.5 mN (33 LSB of
/// the `I16F16` signals). The two run the same code on the same inputs and agree
/// to the bit; the bound is what a legitimate difference in float evaluation of
/// the virtual stage could cost.
pub const TWIN_BOUND: f64 = 5e-4;

impl Agreement {
    /// Positions within `bound` µm, the setpoint within `bound` V, the force within
    /// `bound` N, every status equal, nothing missing.
    pub fn within(&self, bound: f64) -> bool {
        self.samples > 0
            && self.missing == 0
            && self.status == 0
            && self.position_um <= bound
            && self.voltage_v <= bound
            && self.force_n <= bound
    }
}
