//! The virtual stage a bench order puts on the emulated board: `nominal`, `built`
//! or a TOML file naming a base and the values that replace the base's.
//!
//! ```toml
//! base = "built"          # or "nominal"
//! mode_hz = 700.0         # first mode, Hz
//! mode_damping = 0.015    # its damping ratio
//! output_gain = 1.03      # kinematics relative to the FEM's f_K
//! force_scale = 0.97      # preload relative to the FEM's f_F
//! creep_scale = 1.5       # creep relative to the model's
//! position_noise_um = 0.002
//! force_noise_n = 0.05
//! ```
//!
//! Unknown keys are refused, and a value out of range is named by its key with
//! the range it must lie in (the range check is the protocol's
//! [`StageVariant::check`], the same the board applies).

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use fpi_protocol::StageVariant;
use piezo_sim::quote::{toml_error, Num, Quoted};
use serde::Deserialize;

/// The file's form (its numbers as the file gives them: the board's `f32`
/// would make `1e308` an infinity).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct VariantFile {
    base: String,
    mode_hz: Option<f64>,
    mode_damping: Option<f64>,
    output_gain: Option<f64>,
    force_scale: Option<f64>,
    creep_scale: Option<f64>,
    position_noise_um: Option<f64>,
    force_noise_n: Option<f64>,
}

/// The base named `name` (`nominal` or `built`).
fn base(name: &str) -> Option<StageVariant> {
    match name {
        "nominal" => Some(StageVariant::NOMINAL),
        "built" => Some(StageVariant::BUILT),
        _ => None,
    }
}

/// `nominal`, `built`, or the variant in the TOML file `arg`.
pub fn parse(arg: &str) -> Result<StageVariant> {
    if let Some(v) = base(arg) {
        return Ok(v);
    }
    let path = Path::new(arg);
    if !path.exists() {
        bail!(
            "--stage {}: nominal, built or a TOML file naming a base and its changes",
            Quoted(arg)
        );
    }
    let text = String::from_utf8(crate::data::read_bytes(path)?)
        .map_err(|e| anyhow!("{arg}: not a text file: {e}"))?;
    from_toml(&text, arg)
}

/// The variant the TOML text of the file `name` (for messages) describes.
pub fn from_toml(text: &str, name: &str) -> Result<StageVariant> {
    let f: VariantFile = toml::from_str(text)
        .map_err(|e| anyhow!(toml_error(name, "stage variant file", text, &e)))?;
    let b = base(&f.base).ok_or_else(|| {
        anyhow!(
            "{name}: base = {}: \"nominal\" or \"built\"",
            Quoted(&f.base)
        )
    })?;
    let narrow = |v: Option<f64>| v.map(|v| v as f32);
    let v = StageVariant {
        built: b.built,
        mode_hz: narrow(f.mode_hz),
        mode_damping: narrow(f.mode_damping),
        output_gain: narrow(f.output_gain),
        force_scale: narrow(f.force_scale),
        creep_scale: narrow(f.creep_scale),
        position_noise_um: narrow(f.position_noise_um),
        force_noise_n: narrow(f.force_noise_n),
    };
    if let Err((key, value, (lo, hi))) = v.check() {
        let given = [
            ("mode_hz", f.mode_hz),
            ("mode_damping", f.mode_damping),
            ("output_gain", f.output_gain),
            ("force_scale", f.force_scale),
            ("creep_scale", f.creep_scale),
            ("position_noise_um", f.position_noise_um),
            ("force_noise_n", f.force_noise_n),
        ]
        .into_iter()
        .find(|(k, _)| *k == key)
        .and_then(|(_, v)| v)
        .unwrap_or(value as f64);
        bail!("{name}: {key} = {}: must lie in [{lo}, {hi}]", Num(given));
    }
    Ok(v)
}

/// One line describing the variant.
pub fn describe(v: &StageVariant) -> String {
    let mut s = String::from(if v.built {
        "stage as built"
    } else {
        "nominal twin"
    });
    let fields: [(&str, Option<f32>); 7] = [
        ("mode_hz", v.mode_hz),
        ("mode_damping", v.mode_damping),
        ("output_gain", v.output_gain),
        ("force_scale", v.force_scale),
        ("creep_scale", v.creep_scale),
        ("position_noise_um", v.position_noise_um),
        ("force_noise_n", v.force_noise_n),
    ];
    for (k, x) in fields {
        if let Some(x) = x {
            s.push_str(&format!(", {k} = {x}"));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_replaces_the_base_values_it_names() {
        let v = from_toml(
            "base = \"built\"\nmode_hz = 700.0\nmode_damping = 0.015\n",
            "v.toml",
        )
        .unwrap();
        assert!(v.built);
        assert_eq!(v.mode_hz, Some(700.0));
        assert_eq!(v.mode_damping, Some(0.015));
        assert_eq!(v.output_gain, None);
    }

    #[test]
    fn unknown_keys_and_out_of_range_values_are_named() {
        let e = from_toml("base = \"built\"\nmode_hertz = 700.0\n", "v.toml").unwrap_err();
        assert!(format!("{e:#}").contains("mode_hertz"), "{e:#}");
        let e = from_toml("base = \"built\"\nmode_damping = 0.9\n", "v.toml").unwrap_err();
        let s = format!("{e:#}");
        assert!(s.contains("mode_damping") && s.contains("0.5"), "{s}");
        // As given, not as the board's f32 holds it (an infinity).
        let e = from_toml("base = \"built\"\nmode_hz = 1e308\n", "v.toml").unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            "v.toml: mode_hz = 1e308: must lie in [100, 5000]"
        );
        let e = from_toml("base = \"built\"\nforce_noise_n = nan\n", "v.toml").unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            "v.toml: force_noise_n = NaN: must lie in [0, 10]"
        );
        let e = from_toml("base = \"stage B\"\n", "v.toml").unwrap_err();
        assert!(format!("{e:#}").contains("base"), "{e:#}");
    }
}
