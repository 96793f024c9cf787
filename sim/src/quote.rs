//! What an error message quotes of a file's text: at most [`QUOTE_CHARS`]
//! characters of a value, then `…`, so that a 10 MB cell or a line of 200 000
//! brackets does not come back whole; a number as a file gave it ([`Num`]:
//! `1e308`, not 309 digits); and a TOML parse error as
//! `FILE:LINE:COLUMN: not a WHAT: message`, without the source excerpt the
//! parser prints.

use std::borrow::Cow;
use std::fmt;
use std::string::String;

/// The most characters of a value an error message quotes.
pub const QUOTE_CHARS: usize = 80;

/// `s` cut to [`QUOTE_CHARS`] characters, with `…` where it was cut.
pub fn clip(s: &str) -> Cow<'_, str> {
    match head(s, QUOTE_CHARS) {
        (all, false) => Cow::Borrowed(all),
        (kept, true) => Cow::Owned(format!("{kept}…")),
    }
}

/// The first `chars` characters of `s`, and whether that cut anything.
fn head(s: &str, chars: usize) -> (&str, bool) {
    match s.char_indices().nth(chars) {
        None => (s, false),
        Some((end, _)) => (&s[..end], true),
    }
}

/// A value as an error message quotes it: in double quotes, escaped as `{:?}`
/// escapes, cut to [`QUOTE_CHARS`] characters with `…` before the closing quote.
pub struct Quoted<'a>(pub &'a str);

impl fmt::Display for Quoted<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match head(self.0, QUOTE_CHARS) {
            (all, false) => write!(f, "{all:?}"),
            (kept, true) => {
                let q = format!("{kept:?}");
                write!(f, "{}…\"", &q[..q.len() - 1])
            }
        }
    }
}

/// `message` with every double-quoted span in it cut by [`clip`] (a parser's
/// message quotes the value it did not take: `invalid type: string "…"`), and the
/// whole cut to 4 × [`QUOTE_CHARS`] characters.
pub fn clip_quoted(message: &str) -> String {
    let mut out = String::with_capacity(message.len().min(8 * QUOTE_CHARS));
    let (mut inside, mut escaped, mut n) = (false, false, 0usize);
    for c in message.chars() {
        if inside {
            let closing = c == '"' && !escaped;
            escaped = c == '\\' && !escaped;
            n += 1;
            if closing {
                inside = false;
                if n > QUOTE_CHARS + 1 {
                    out.push('…');
                }
            } else if n > QUOTE_CHARS {
                continue;
            }
        } else if c == '"' {
            (inside, escaped, n) = (true, false, 0);
        }
        out.push(c);
    }
    clip_to(&out)
}

/// `s` cut to 4 × [`QUOTE_CHARS`] characters, with `…` where it was cut.
fn clip_to(s: &str) -> String {
    match head(s, 4 * QUOTE_CHARS) {
        (all, false) => all.into(),
        (kept, true) => format!("{kept}…"),
    }
}

/// A number for a message: as Rust writes it (`0.25`, `150`) within
/// `1e-4 ≤ |v| < 1e9`, else in scientific notation (`1e308`, not 309 digits):
/// the value a file gave, as it gave it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.abs();
        if a == 0.0 || !a.is_finite() || (1e-4..1e9).contains(&a) {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// A TOML parse error of the file `file` whose text is `text`, which should have
/// been a `what` (e.g. `firmware model file`): `FILE:LINE:COLUMN: not a WHAT:
/// MESSAGE (in LINE'S TEXT)` (1-based; where the parser stopped; the line names
/// the key), with what the message and the line quote cut ([`clip_quoted`],
/// [`Quoted`]).
pub fn toml_error(file: &str, what: &str, text: &str, e: &toml::de::Error) -> String {
    let message = clip_quoted(e.message().trim());
    match e.span() {
        Some(span) => {
            let start = floor_char_boundary(text, span.start);
            let before = &text[..start];
            let line = before.matches('\n').count() + 1;
            let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            let source = text.lines().nth(line - 1).unwrap_or("").trim();
            format!(
                "{file}:{line}:{column}: not a {what}: {message} (in {})",
                Quoted(source)
            )
        }
        None => format!("{file}: not a {what}: {message}"),
    }
}

/// The largest char boundary of `s` at or before `at`.
fn floor_char_boundary(s: &str, at: usize) -> usize {
    let mut k = at.min(s.len());
    while !s.is_char_boundary(k) {
        k -= 1;
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::string::ToString;

    #[test]
    fn long_values_are_cut_and_short_ones_kept() {
        assert_eq!(clip("abc"), "abc");
        let long = "x".repeat(10_000_000);
        let q = Quoted(&long).to_string();
        assert_eq!(q, format!("\"{}…\"", "x".repeat(QUOTE_CHARS)));
        assert_eq!(Quoted("a\"b").to_string(), "\"a\\\"b\"");
        let wide = "é".repeat(100);
        assert_eq!(clip(&wide).chars().count(), QUOTE_CHARS + 1);
    }

    #[test]
    fn a_message_quoting_a_long_value_is_cut() {
        let m = format!(
            "invalid type: string \"{}\", expected f64",
            "y".repeat(5000)
        );
        let c = clip_quoted(&m);
        assert_eq!(
            c,
            format!(
                "invalid type: string \"{}…\", expected f64",
                "y".repeat(QUOTE_CHARS)
            )
        );
        assert_eq!(clip_quoted("a \"short\" one"), "a \"short\" one");
    }

    #[test]
    fn a_toml_error_names_the_line_and_column_and_quotes_little() {
        let text = format!("a = 1\nkind = {}\n", "[".repeat(200_000));
        let e = toml::from_str::<toml::Table>(&text).unwrap_err();
        let m = toml_error("m.toml", "model file", &text, &e);
        assert!(m.starts_with("m.toml:2:"), "{m}");
        assert!(m.contains(": not a model file: "), "{m}");
        assert!(m.len() < 500, "{} characters: {m}", m.len());
        let text = format!("w = \"{}\"\n", "z".repeat(1_000_000));
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct W {
            w: f64,
        }
        let e = toml::from_str::<W>(&text).unwrap_err();
        let m = toml_error("m.toml", "model file", &text, &e);
        assert!(m.starts_with("m.toml:1:5: ") && m.len() < 500, "{m}");
    }
}
