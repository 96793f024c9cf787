//! The handler's runtime settings by key path ([`Settings`], declared once in
//! the protocol): a get reads the live state into the tree and serializes the
//! leaf; a set changes a copy of it and carries the difference out as the
//! named command that makes it, with that command's checks — a setting and
//! its named command cannot disagree.

use embedded_storage::nor_flash::NorFlash;
use fpi_protocol::miniconf::{json_core, KeyError, SerdeError, ValueError};
use heapless::Vec;

use super::{Board, Handler};
use crate::link::protocol::settings::{StageSettings, MAX_PATH, MAX_VALUE, STAGES};
use crate::link::protocol::{Command, Refusal, Reply, Settings};
use crate::link::refusal::{refuse, Refuse};

impl<F: NorFlash, const N: usize> Handler<F, N> {
    /// The board's settings as they are now: what its status says (which
    /// sections the running model has, and whether each is on).
    fn settings(&mut self, board: &mut impl Board<N>) -> Settings {
        let summary = self.summary[0];
        let (s, trigger_in) =
            board.exchange(|x| (super::status(x, &summary, 0), x.snapshot.trigger_in));
        let stage = StageSettings {
            loop_mode: s.loop_mode,
            damping: s.damping,
            shaping: s.shaping,
            compensated: s.compensated,
            trigger: self.trigger,
            trigger_in,
        };
        Settings {
            stage: [stage; STAGES],
            supervise_ms: self.timeout_ms,
        }
    }

    /// The value at `path`, JSON.
    pub(super) fn setting_get(
        &mut self,
        board: &mut impl Board<N>,
        path: &[u8],
    ) -> Result<Reply, Refuse> {
        let path = key(path)?;
        let now = self.settings(board);
        let mut value = Vec::<u8, MAX_VALUE>::new();
        // `MAX_VALUE` holds every leaf's longest value (a u32, a mode's name).
        let _ = value.resize_default(MAX_VALUE);
        match json_core::get(&now, path, &mut value) {
            Ok(n) => {
                value.truncate(n);
                Ok(Reply::Setting(value))
            }
            Err(e) => Err(not_set(path, None, e.into())),
        }
    }

    /// The named command that sets `path` to `value` (JSON), `None` where
    /// nothing changes.
    pub(super) fn setting_change(
        &mut self,
        board: &mut impl Board<N>,
        path: &[u8],
        value: &[u8],
    ) -> Result<Option<Command<'static>>, Refuse> {
        let path = key(path)?;
        let now = self.settings(board);
        let mut next = now;
        if let Err(e) = json_core::set(&mut next, path, value) {
            return Err(not_set(path, Some(value), e.into()));
        }
        Ok(now.command_to(&next))
    }
}

/// What went wrong, from either direction's error.
enum Failure {
    Key(KeyError),
    Absent,
    Value,
}

impl<E> From<SerdeError<E>> for Failure {
    fn from(e: SerdeError<E>) -> Self {
        match e {
            SerdeError::Value(ValueError::Key(k)) => Self::Key(k),
            SerdeError::Value(ValueError::Absent) => Self::Absent,
            _ => Self::Value,
        }
    }
}

/// The key path as text.
fn key(path: &[u8]) -> Result<&str, Refuse> {
    match core::str::from_utf8(path) {
        Ok(p) if p.len() <= MAX_PATH => Ok(p),
        _ => Err(refuse(
            Refusal::Setting,
            format_args!("a setting's key path is UTF-8 of at most {MAX_PATH} bytes"),
        )),
    }
}

/// The refusal naming the key, the value and the rule.
fn not_set(path: &str, value: Option<&[u8]>, f: Failure) -> Refuse {
    let value = value
        .and_then(|v| core::str::from_utf8(v).ok())
        .unwrap_or("");
    match f {
        Failure::Key(KeyError::NotFound) => refuse(
            Refusal::Setting,
            format_args!("no setting {path}: `fpi board get` lists them"),
        ),
        Failure::Key(KeyError::TooShort) => refuse(
            Refusal::Setting,
            format_args!("{path} holds settings, not a value: name one of them"),
        ),
        Failure::Key(KeyError::TooLong) => refuse(
            Refusal::Setting,
            format_args!("{path} goes past a setting's value"),
        ),
        Failure::Absent => refuse(
            Refusal::Setting,
            format_args!("{path}: the running model has no such section"),
        ),
        Failure::Value => refuse(
            Refusal::Setting,
            format_args!("{path} = {value}: not a value of this setting's type"),
        ),
    }
}
