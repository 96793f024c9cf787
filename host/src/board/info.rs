//! What a board has (`fpi board info`, Python's `Board.info()`), as PI's
//! `qHLP`/`HasCMD` tell it: the board, its axes, analog front end, link,
//! protocol, control rate, capacity and hardware limits (its hello), the
//! features its running model gives it (closed loop, declared dynamics,
//! damping, shaping, the learned mass ratio), the commands it takes and the
//! runtime settings it has.

use std::fmt::Write as _;

use anyhow::Result;
use fpi_protocol::{BoardKind, CommandKind, Hello};

use super::client::{real, Client};
use super::inprocess;

/// A board's features, each on or off.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Features {
    /// The running model has feedback settings: the loop can close on the
    /// position sensor.
    pub closed_loop: bool,
    /// It declares the stage's dynamics (the governor's and the shaping's).
    pub dynamics: bool,
    /// It has active damping from the force sensor.
    pub damping: bool,
    /// It has reference shaping (the preview feedforward).
    pub shaping: bool,
    /// Its damping leaves out the force the shaped reference explains, and the
    /// board learns the stage's mass ratio (`fpi board load --match-mass`).
    pub mass_ratio: bool,
    /// The emulated board's virtual bench (fault injection, stage variants).
    pub bench: bool,
}

impl Features {
    /// Each feature's name (as `info()` and the CLI spell it) and whether the
    /// board has it.
    pub fn named(&self) -> [(&'static str, bool); 6] {
        [
            ("closed_loop", self.closed_loop),
            ("dynamics", self.dynamics),
            ("damping", self.damping),
            ("shaping", self.shaping),
            ("mass_ratio", self.mass_ratio),
            ("bench", self.bench),
        ]
    }
}

/// What a board has.
#[derive(Debug, Clone)]
pub struct BoardInfo {
    /// Its hello: identity, axes, front end, link, capacity, limits.
    pub hello: Hello,
    /// `driver`, `emulated` (QEMU) or `virtual` (its firmware in-process).
    pub kind: &'static str,
    /// What its running model gives it.
    pub features: Features,
    /// The commands it takes (the bench's only on the emulated board), by
    /// their names in the protocol's declaration.
    pub commands: Vec<String>,
    /// The runtime settings it has with the running model (`fpi board get`).
    pub settings: Vec<String>,
}

/// What the board `c` has, asked of it (hello, model, status and settings).
pub fn read(c: &mut Client) -> Result<BoardInfo> {
    let hello = c.hello().clone();
    let m = c.model()?;
    let s = c.status()?;
    let emulated = hello.board == BoardKind::Emulated;
    let kind = match hello.board {
        BoardKind::Driver => "driver",
        BoardKind::Emulated if inprocess::is_in_process(c.port_name()) => "virtual",
        BoardKind::Emulated => "emulated",
    };
    let features = Features {
        closed_loop: m.feedback.is_some(),
        dynamics: m.dynamics.is_some(),
        damping: s.damping.is_some(),
        shaping: s.shaping.is_some(),
        mass_ratio: s.lead_ratio.is_some_and(|(_, applied)| applied),
        bench: emulated,
    };
    let commands = CommandKind::ALL
        .iter()
        .filter(|k| emulated || **k != CommandKind::Bench)
        .map(|k| format!("{k:?}"))
        .collect();
    let settings = super::settings::read_all(c)?
        .into_iter()
        .filter(|(_, v)| v.is_some())
        .map(|(k, _)| k)
        .collect();
    Ok(BoardInfo {
        hello,
        kind,
        features,
        commands,
        settings,
    })
}

/// What `fpi board info` prints: one line per topic.
pub fn describe(i: &BoardInfo) -> String {
    let h = &i.hello;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "board: {} (firmware {}), protocol {}, axes {}, front end {}, link {} ({} B/s each \
         way), control at {} Hz",
        i.kind,
        h.firmware,
        h.protocol,
        h.axes,
        h.front_end.name(),
        h.link.name(),
        h.link.bytes_per_s(),
        h.rate_hz
    );
    let _ = writeln!(
        out,
        "capacity: {} operators, {} creep terms, {} table intervals, {} image bytes; recorder \
         {} samples, stream {} points",
        h.capacity[0], h.capacity[1], h.capacity[2], h.capacity[3], h.buffers[0], h.buffers[1]
    );
    let l = h.limits.map(real);
    let _ = writeln!(
        out,
        "limits: setpoint {:.1}…{:.1} V, at most {:.3} V per tick; safe voltage within {:.1}…{:.1} V",
        l[0], l[1], l[2], l[3], l[4]
    );
    let (on, off): (Vec<_>, Vec<_>) = i.features.named().into_iter().partition(|f| f.1);
    let [on, off] = [on, off].map(|fs| fs.into_iter().map(|f| f.0).collect::<Vec<_>>());
    let _ = writeln!(out, "features: {}; without: {}", list(&on), list(&off));
    let _ = writeln!(out, "commands: {}", i.commands.join(" "));
    let _ = writeln!(out, "settings: {}", list(&i.settings));
    out
}

fn list<S: AsRef<str>>(items: &[S]) -> String {
    if items.is_empty() {
        "none".into()
    } else {
        items
            .iter()
            .map(AsRef::as_ref)
            .collect::<Vec<_>>()
            .join(", ")
    }
}
