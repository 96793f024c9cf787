//! The host tools' own TOML files (a calibrated model, identified dynamics): read
//! within a size limit, parsed and validated on every read, validated before every
//! write, written atomically with a header. The errors name the file and, through
//! each file's one validator, the key.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use piezo_sim::quote::toml_error;
use serde::de::DeserializeOwned;
use serde::Serialize;

/// A validated TOML file of the host tools.
pub trait TomlFile: Serialize + DeserializeOwned {
    /// What the file is, for messages (e.g. `"model file"`).
    const WHAT: &'static str;
    /// Most bytes a reader takes.
    const MAX_BYTES: u64;
    /// The `format` string the file carries (`piezo-fpi-model/1`).
    const FORMAT: &'static str;
    /// The `format` string this one carries.
    fn format(&self) -> &str;
    /// Refuses a `format` other than [`FORMAT`](Self::FORMAT), quoting it.
    fn check_format(&self) -> Result<()> {
        if self.format() != Self::FORMAT {
            anyhow::bail!(
                "format = {}: expected {:?}",
                piezo_sim::quote::Quoted(self.format()),
                Self::FORMAT
            );
        }
        Ok(())
    }
    /// The file's one validator; the error names the key.
    fn check(&self) -> Result<()>;
    /// Comment lines written above the values.
    fn header(&self) -> String;
}

/// Reads and validates a file of type `T`.
pub fn read<T: TomlFile>(path: &Path) -> Result<T> {
    let limits = super::ReadLimits {
        max_bytes: T::MAX_BYTES,
        ..super::ReadLimits::INPUT
    };
    let bytes = super::read_bytes_within(path, limits)?;
    let text = String::from_utf8(bytes)
        .map_err(|e| anyhow!("{}: not a text file: {e}", path.display()))?;
    parse(&text, &path.display().to_string())
}

/// A `T` from the text of a file named `name` (for messages), validated.
pub fn parse<T: TomlFile>(text: &str, name: &str) -> Result<T> {
    let t: T = toml::from_str(text).map_err(|e| anyhow!(toml_error(name, T::WHAT, text, &e)))?;
    t.check().with_context(|| name.to_string())?;
    Ok(t)
}

/// Writes `t` atomically ([`crate::output::write_atomic`]) after validating it: a
/// file that reading would refuse is never written.
pub fn write<T: TomlFile>(t: &T, path: &Path) -> Result<()> {
    t.check()
        .with_context(|| format!("{}: not written", path.display()))?;
    let text = toml::to_string(t)
        .with_context(|| format!("{}: cannot format the {}", path.display(), T::WHAT))?;
    crate::output::write_atomic(path, (t.header() + &text).as_bytes())
}
