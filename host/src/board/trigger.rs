//! The trigger output, on the host: `fpi board trigger` and Python's
//! `Board.trigger` set a mode and the levels given (in µm, as the other
//! commands take positions), keeping the board's other levels; the board
//! holds them in nanometres ([`TriggerSettings`], one declaration with the
//! settings tree's `stage/0/trigger/…`).

use anyhow::{Context, Result};
use fpi_protocol::{Command, TriggerMode, TriggerSettings, TriggerStart};

use super::client::Client;
use super::commands::bad;
use crate::data::Quoted;

/// The levels `fpi board trigger` and Python take, µm (absent: as the board
/// has it).
#[derive(Debug, Clone, Copy, Default, PartialEq, clap::Args, serde::Deserialize)]
pub struct Levels {
    /// travel: the travel between pulses, µm (> 0).
    #[arg(long, allow_negative_numbers = true)]
    pub step_um: Option<f64>,
    /// on_target: the band's half-width about the reference, µm (≥ 0).
    #[arg(long, allow_negative_numbers = true)]
    pub band_um: Option<f64>,
    /// window: its lower edge, µm.
    #[arg(long, allow_negative_numbers = true)]
    pub low_um: Option<f64>,
    /// window: its upper edge, µm.
    #[arg(long, allow_negative_numbers = true)]
    pub high_um: Option<f64>,
    /// travel and point: how long a pulse stays high, ticks (≥ 1).
    #[arg(long)]
    pub pulse_ticks: Option<u16>,
}

/// The key path of the trigger's settings.
const PATH: &str = "/stage/0/trigger";

/// The leaves of [`TriggerSettings`], in order.
const LEAVES: [&str; 6] = [
    "mode",
    "step_nm",
    "band_nm",
    "low_nm",
    "high_nm",
    "pulse_ticks",
];

/// The trigger settings the board holds now.
pub fn settings(c: &mut Client) -> Result<TriggerSettings> {
    let mut fields = Vec::with_capacity(LEAVES.len());
    for leaf in LEAVES {
        fields.push(format!(
            "\"{leaf}\":{}",
            c.setting(&format!("{PATH}/{leaf}"))?
        ));
    }
    let json = format!("{{{}}}", fields.join(","));
    serde_json::from_str(&json).with_context(|| format!("the board's trigger settings {json}"))
}

/// A mode by name: `off`, `travel`, `on_target`, `window` or `point`.
pub fn mode(name: &str) -> Result<TriggerMode> {
    TriggerMode::from_label(&name.replace('-', "_")).ok_or_else(|| {
        bad(
            "mode",
            "the mode",
            format!(
                "the mode {}: off, travel, on_target, window or point",
                Quoted(name)
            ),
        )
    })
}

/// Sets the trigger output to `mode` with the `levels` given (the others as
/// the board has them); the tick it took effect and what the board holds.
pub fn set(c: &mut Client, mode: TriggerMode, levels: &Levels) -> Result<(u32, TriggerSettings)> {
    let s = with(settings(c)?, mode, levels)?;
    let t = c.order(&command(c.axis(), s))?;
    Ok((t, s))
}

/// The command that sets the trigger output as `s` says (`axis`: its stage).
pub fn command(axis: u8, s: TriggerSettings) -> Command<'static> {
    Command::Trigger { axis, settings: s }
}

/// `s` with `mode` and the `levels` given, each checked as the host can (the
/// board checks the rest, naming the rule).
pub fn with(mut s: TriggerSettings, mode: TriggerMode, levels: &Levels) -> Result<TriggerSettings> {
    s.mode = mode;
    let nm = |name: &'static str, cli: &'static str, um: f64| -> Result<i64> {
        let v = (um * 1000.0).round();
        if !v.is_finite() || v.abs() > 32_767_000.0 {
            return Err(bad(
                name,
                cli,
                format!("{cli} {um}: a position within ±32 767 µm"),
            ));
        }
        Ok(v as i64)
    };
    let non_negative = |name: &'static str, cli: &'static str, um: f64, least: i64| {
        let v = nm(name, cli, um)?;
        let rule = if least > 0 { "above 0" } else { "at least 0" };
        u32::try_from(v)
            .ok()
            .filter(|&v| i64::from(v) >= least)
            .ok_or_else(|| bad(name, cli, format!("{cli} {um}: {rule} µm (to the nm)")))
    };
    if let Some(v) = levels.step_um {
        s.step_nm = non_negative("step_um", "--step-um", v, 1)?;
    }
    if let Some(v) = levels.band_um {
        s.band_nm = non_negative("band_um", "--band-um", v, 0)?;
    }
    if let Some(v) = levels.low_um {
        s.low_nm = nm("low_um", "--low-um", v)? as i32;
    }
    if let Some(v) = levels.high_um {
        s.high_nm = nm("high_um", "--high-um", v)? as i32;
    }
    if let Some(p) = levels.pulse_ticks {
        s.pulse_ticks = p;
    }
    Ok(s)
}

/// `s` as a user reads it: `travel every 0.500 µm, pulses of 2 ticks`.
pub fn describe(s: &TriggerSettings) -> String {
    let um = |nm: i64| format!("{:.3} µm", nm as f64 / 1000.0);
    let pulse = |what: String| format!("{what}, pulses of {} tick(s)", s.pulse_ticks);
    match s.mode {
        TriggerMode::Off => "off".into(),
        TriggerMode::Travel => pulse(format!("travel: every {}", um(s.step_nm.into()))),
        TriggerMode::OnTarget => format!(
            "on target: within {} of the reference",
            um(s.band_nm.into())
        ),
        TriggerMode::Window => format!(
            "window: high inside {} … {}",
            um(s.low_nm.into()),
            um(s.high_nm.into())
        ),
        TriggerMode::Point => pulse("point: at each streamed point".into()),
    }
}

/// What the trigger input's edge starts, by name: `off`, `motion`,
/// `recorder` or `both`.
pub fn starts(name: &str) -> Result<TriggerStart> {
    TriggerStart::from_label(name).ok_or_else(|| {
        bad(
            "starts",
            "the input's action",
            format!(
                "the input's action {}: off, motion, recorder or both",
                Quoted(name)
            ),
        )
    })
}

/// Sets what the trigger input's rising edge starts; the tick it took effect.
pub fn set_input(c: &mut Client, starts: TriggerStart) -> Result<u32> {
    c.order(&Command::TriggerIn {
        axis: c.axis(),
        starts,
    })
}
