//! The board's runtime settings as one tree: every switch the host may turn
//! while the board runs, declared once here (name, type, unit, one-line doc)
//! and addressed by key path (`/stage/0/damping`), as stabilizer's settings
//! are ([`miniconf`]).
//!
//! From this one declaration come the link's generic
//! [`Command::SettingGet`]/[`Command::SettingSet`] (values as JSON), the
//! `fpi board get|set` commands, Python's `board.settings[…]` and the book's
//! reference page (`fpi reference settings`). A change is carried out as the
//! named command that makes it ([`Settings::command_to`]), so a setting and
//! its named command (`fpi board damping on`) pass the same checks on the
//! board.
//!
//! What a setting holds is the board's live state, not a stored value: a reset
//! starts from the running model's defaults (loop open, damping and shaping
//! on where the model has them, compensated drive, no supervision).

use miniconf::{leaf, Tree};
use serde::{Deserialize, Serialize};

use crate::{Command, LoopMode, TriggerMode, TriggerStart};

/// Stages a board's settings tree holds: the first axis's (a board of
/// several axes takes the other axes' switches as their named commands,
/// which address an axis).
pub const STAGES: usize = 1;

/// Longest JSON value of one setting, bytes (a [`Reply::Setting`](crate::Reply::Setting)).
pub const MAX_VALUE: usize = 32;

/// Longest key path, bytes (a [`Command::SettingGet`]'s path).
pub const MAX_PATH: usize = 64;

/// Everything the host may switch while the board runs.
#[derive(Debug, Clone, Copy, PartialEq, Tree)]
pub struct Settings {
    /// Each stage's switches, by axis (`/stage/0/…`).
    #[tree(meta(doc))]
    pub stage: [StageSettings; STAGES],
    /// Heartbeat supervision: a motion with no request for this long parks
    /// every stage with a *link lost* fault; 0 switches it off.
    #[tree(meta(doc, unit = "ms", range = "0 – 4 294 967 295", default = "0"))]
    pub supervise_ms: u32,
}

/// One stage's switches.
#[derive(Debug, Clone, Copy, PartialEq, Tree)]
pub struct StageSettings {
    /// How the loop is closed: `"open"` (the reference through the inverse
    /// FPI), `"closed"` (PI feedback on the position sensor plus the inverse
    /// FPI) or `"feedback"` (PI feedback alone); closing it needs the running
    /// model's `[feedback]`, and a loop stable with the damping as it is.
    #[tree(
        with = leaf,
        meta(doc, range = "\"open\" | \"closed\" | \"feedback\"", default = "\"open\"")
    )]
    pub loop_mode: LoopMode,
    /// Active damping (integral force feedback) on; absent where the running
    /// model has no `[damping]`; off only where the loop as closed stays
    /// stable without it.
    #[tree(meta(doc, range = "true | false", default = "true"))]
    pub damping: Option<bool>,
    /// Reference shaping (the feedforward of the stage's dynamics) on; absent
    /// where the running model has no `[shaping]`.
    #[tree(meta(doc, range = "true | false", default = "true"))]
    pub shaping: Option<bool>,
    /// The inverse FPI drive (`true`), else the straight-line baseline.
    #[tree(meta(doc, range = "true | false", default = "true"))]
    pub compensated: bool,
    /// The trigger output (`…/trigger/…`): what drives it and its levels.
    #[tree(meta(doc))]
    pub trigger: TriggerSettings,
    /// What a rising edge on the trigger input starts: `"off"` (nothing:
    /// orders start at once), `"motion"` (a wave or stream order waits for
    /// it), `"recorder"` (a record order waits for it) or `"both"`.
    #[tree(
        with = leaf,
        meta(
            doc,
            range = "\"off\" | \"motion\" | \"recorder\" | \"both\"",
            default = "\"off\""
        )
    )]
    pub trigger_in: TriggerStart,
}

/// A stage's trigger output: its mode and every mode's level, kept while
/// another mode drives the line (a change of mode keeps the levels set
/// before it). Positions are the position sensor's, in integer nanometres
/// (the board parses and prints no floating point: that would cost it tens
/// of kilobytes of flash).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Tree, Serialize, Deserialize)]
pub struct TriggerSettings {
    /// What drives the line: `"off"`, `"travel"` (a pulse every `step_nm` of
    /// travel, either way, from where the position was when it was set),
    /// `"on_target"` (high while within `band_nm` of the reference),
    /// `"window"` (high while inside `low_nm … high_nm`) or `"point"` (a pulse
    /// at each point a stream takes).
    #[tree(
        with = leaf,
        meta(
            doc,
            range = "\"off\" | \"travel\" | \"on_target\" | \"window\" | \"point\"",
            default = "\"off\""
        )
    )]
    pub mode: TriggerMode,
    /// `travel`: the travel between pulses.
    #[tree(meta(doc, unit = "nm", range = "1 – 32 767 000", default = "1000"))]
    pub step_nm: u32,
    /// `on_target`: the band's half-width about the reference.
    #[tree(meta(doc, unit = "nm", range = "0 – 32 767 000", default = "100"))]
    pub band_nm: u32,
    /// `window`: its lower edge.
    #[tree(meta(doc, unit = "nm", range = "±32 767 000, ≤ high_nm", default = "0"))]
    pub low_nm: i32,
    /// `window`: its upper edge.
    #[tree(meta(doc, unit = "nm", range = "±32 767 000, ≥ low_nm", default = "0"))]
    pub high_nm: i32,
    /// `travel` and `point`: how long a pulse stays high.
    #[tree(meta(doc, unit = "ticks", range = "1 – 65 535", default = "1"))]
    pub pulse_ticks: u16,
}

impl TriggerSettings {
    /// A board's trigger at start-up: off, with the documented levels.
    pub const DEFAULT: Self = Self {
        mode: TriggerMode::Off,
        step_nm: 1000,
        band_nm: 100,
        low_nm: 0,
        high_nm: 0,
        pulse_ticks: 1,
    };
}

impl Default for TriggerSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Settings {
    /// The named command that turns `self` into `next` where they differ in
    /// one setting (a set changes one leaf); `None` where nothing changes.
    /// `Supervise` counts in milliseconds on the wire too.
    pub fn command_to(&self, next: &Self) -> Option<Command<'static>> {
        if self.supervise_ms != next.supervise_ms {
            return Some(Command::Supervise {
                timeout_ms: next.supervise_ms,
            });
        }
        self.stage
            .iter()
            .zip(&next.stage)
            .zip(0u8..)
            .find_map(|((now, next), axis)| now.command_to(next, axis))
    }
}

impl StageSettings {
    fn command_to(&self, next: &Self, axis: u8) -> Option<Command<'static>> {
        if self.loop_mode != next.loop_mode {
            return Some(Command::Loop {
                axis,
                mode: next.loop_mode,
            });
        }
        if let (Some(a), Some(on)) = (self.damping, next.damping) {
            if a != on {
                return Some(Command::Damping { axis, on });
            }
        }
        if let (Some(a), Some(on)) = (self.shaping, next.shaping) {
            if a != on {
                return Some(Command::Shaping { axis, on });
            }
        }
        if self.trigger_in != next.trigger_in {
            return Some(Command::TriggerIn {
                axis,
                starts: next.trigger_in,
            });
        }
        if self.trigger != next.trigger {
            return Some(Command::Trigger {
                axis,
                settings: next.trigger,
            });
        }
        (self.compensated != next.compensated).then_some(Command::Drive {
            axis,
            compensated: next.compensated,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use miniconf::{json_core, ConstPath, TreeSchema};

    fn board() -> Settings {
        Settings {
            stage: [StageSettings {
                loop_mode: LoopMode::Open,
                damping: Some(true),
                shaping: None,
                compensated: true,
                trigger: TriggerSettings::DEFAULT,
                trigger_in: TriggerStart::Nothing,
            }],
            supervise_ms: 0,
        }
    }

    #[test]
    fn every_leaf_has_a_path() {
        const D: usize = Settings::SCHEMA.max_depth();
        let paths: std::vec::Vec<std::string::String> = Settings::SCHEMA
            .nodes::<ConstPath<std::string::String, '/'>, D>()
            .map(|p| p.unwrap().0)
            .collect();
        assert_eq!(
            paths,
            [
                "/stage/0/loop_mode",
                "/stage/0/damping",
                "/stage/0/shaping",
                "/stage/0/compensated",
                "/stage/0/trigger/mode",
                "/stage/0/trigger/step_nm",
                "/stage/0/trigger/band_nm",
                "/stage/0/trigger/low_nm",
                "/stage/0/trigger/high_nm",
                "/stage/0/trigger/pulse_ticks",
                "/stage/0/trigger_in",
                "/supervise_ms"
            ]
        );
    }

    #[test]
    fn values_are_json_and_a_change_is_its_named_command() {
        let now = board();
        let mut buf = [0u8; MAX_VALUE];
        let n = json_core::get(&now, "/stage/0/loop_mode", &mut buf).unwrap();
        assert_eq!(&buf[..n], b"\"open\"");
        let mut next = now;
        json_core::set(&mut next, "/stage/0/loop_mode", b"\"feedback\"").unwrap();
        assert_eq!(
            now.command_to(&next),
            Some(Command::Loop {
                axis: 0,
                mode: LoopMode::FeedbackOnly
            })
        );
        let mut next = now;
        json_core::set(&mut next, "/stage/0/damping", b"false").unwrap();
        assert_eq!(
            now.command_to(&next),
            Some(Command::Damping { axis: 0, on: false })
        );
        let mut next = now;
        json_core::set(&mut next, "/supervise_ms", b"500").unwrap();
        assert_eq!(
            now.command_to(&next),
            Some(Command::Supervise { timeout_ms: 500 })
        );
        let mut next = now;
        json_core::set(&mut next, "/stage/0/trigger/mode", b"\"travel\"").unwrap();
        json_core::set(&mut next, "/stage/0/trigger/step_nm", b"250").unwrap();
        let mut settings = TriggerSettings::DEFAULT;
        settings.mode = TriggerMode::Travel;
        settings.step_nm = 250;
        assert_eq!(
            now.command_to(&next),
            Some(Command::Trigger { axis: 0, settings })
        );
        assert_eq!(now.command_to(&now), None);
    }

    #[test]
    fn a_wrong_name_value_or_absent_setting_is_an_error() {
        let mut s = board();
        assert!(json_core::set(&mut s, "/stage/0/lop", b"true").is_err());
        assert!(json_core::set(&mut s, "/stage/1/damping", b"true").is_err());
        assert!(json_core::set(&mut s, "/stage/0/loop_mode", b"\"shut\"").is_err());
        assert!(json_core::set(&mut s, "/stage/0/damping", b"1").is_err());
        // The running model has no shaping: the setting is absent.
        assert!(json_core::set(&mut s, "/stage/0/shaping", b"true").is_err());
        assert_eq!(s, board());
    }
}
