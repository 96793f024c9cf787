//! A refused request: its code and reason, the reason's text cut to fit. The
//! command handler ([`super::handler`]) and the model upload ([`super::upload`])
//! both refuse with it.

use core::fmt::Write as _;

use super::protocol::{Refusal, Text};

/// A request refused: its code and reason.
pub(super) type Refuse = (Refusal, Text);

pub(super) fn refuse(code: Refusal, args: core::fmt::Arguments<'_>) -> Refuse {
    let mut t = Text::new();
    // A reason longer than the text is cut where it fills it; the code still
    // says what happened.
    let _ = Cut(&mut t).write_fmt(args);
    (code, t)
}

/// Writes into a [`Text`] as many characters as fit (a `heapless::String`
/// refuses a whole piece that does not fit, which left a long reason empty).
struct Cut<'a>(&'a mut Text);

impl core::fmt::Write for Cut<'_> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for ch in s.chars() {
            self.0.push(ch).map_err(|_| core::fmt::Error)?;
        }
        Ok(())
    }
}
