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
use fpi_firmware::emulation::virtual_bench::overrides;
use fpi_protocol::StageVariant;
use piezo_sim::axes::{AxesSpec, AXIS_NAMES};
use piezo_sim::quote::{toml_error, Num, Quoted};
use serde::Deserialize;

/// The values a variant replaces, as a one-axis file or an axis's table
/// (`[y]`) gives them (its numbers as the file gives them: the board's `f32`
/// would make `1e308` an infinity).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisValues {
    mode_hz: Option<f64>,
    mode_damping: Option<f64>,
    output_gain: Option<f64>,
    force_scale: Option<f64>,
    creep_scale: Option<f64>,
    position_noise_um: Option<f64>,
    force_noise_n: Option<f64>,
}

impl AxisValues {
    /// The values as given, in [`StageVariant::KEYS`]'s order.
    fn given(&self) -> [Option<f64>; 7] {
        [
            self.mode_hz,
            self.mode_damping,
            self.output_gain,
            self.force_scale,
            self.creep_scale,
            self.position_noise_um,
            self.force_noise_n,
        ]
    }

    /// The variant of base `built` with these values, range-checked by
    /// [`StageVariant::check`]; errors name `{name}: {prefix}{key}`.
    fn variant(&self, built: bool, name: &str, prefix: &str) -> Result<StageVariant> {
        let narrow = |v: Option<f64>| v.map(|v| v as f32);
        let v = StageVariant {
            built,
            mode_hz: narrow(self.mode_hz),
            mode_damping: narrow(self.mode_damping),
            output_gain: narrow(self.output_gain),
            force_scale: narrow(self.force_scale),
            creep_scale: narrow(self.creep_scale),
            position_noise_um: narrow(self.position_noise_um),
            force_noise_n: narrow(self.force_noise_n),
        };
        if let Err((key, value, (lo, hi))) = v.check() {
            let given = StageVariant::KEYS
                .iter()
                .zip(self.given())
                .find(|((k, _), _)| *k == key)
                .and_then(|(_, v)| v)
                .unwrap_or(value as f64);
            bail!(
                "{name}: {prefix}{key} = {}: must lie in [{lo}, {hi}]",
                Num(given)
            );
        }
        Ok(v)
    }
}

/// A one-axis variant file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct VariantFile {
    base: String,
    #[serde(flatten)]
    values: AxisValues,
}

/// A several-axis variant file: its base (`xy-built`, …), each axis's table
/// and the couplings.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxesVariantFile {
    base: String,
    coupling_scale: Option<f64>,
    sensor_crosstalk: Option<f64>,
    x: Option<AxisValues>,
    y: Option<AxisValues>,
    z: Option<AxisValues>,
}

/// The range of a several-axis file's `coupling_scale`: from uncoupled to
/// four times the base's couplings.
pub const COUPLING_SCALE_RANGE: (f64, f64) = (0.0, 4.0);
/// The range of its `sensor_crosstalk`, a fraction.
pub const SENSOR_CROSSTALK_RANGE: (f64, f64) = (0.0, 0.05);

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
    let base_of: Option<String> = toml::from_str::<toml::Table>(text)
        .ok()
        .and_then(|t| t.get("base")?.as_str().map(str::to_string));
    if let Some(spec) = base_of.as_deref().and_then(AxesSpec::base) {
        bail!(
            "{name}: base = {}: a stage of {} axes; this board drives one \
             (`fpi axes record --stage {name}` takes it)",
            Quoted(base_of.as_deref().unwrap_or_default()),
            spec.axes
        );
    }
    let f: VariantFile = toml::from_str(text)
        .map_err(|e| anyhow!(toml_error(name, "stage variant file", text, &e)))?;
    let b = base(&f.base).ok_or_else(|| {
        anyhow!(
            "{name}: base = {}: \"nominal\" or \"built\" (or a stage of several axes: {})",
            Quoted(&f.base),
            AxesSpec::BASES.join(", ")
        )
    })?;
    f.values.variant(b.built, name, "")
}

/// A stage of several axes: a base's name (`xy`, `xyz`, `xy-built`,
/// `xyz-built`) or a TOML file naming one with its changes:
///
/// ```toml
/// base = "xy-built"
/// coupling_scale = 2.0      # every cross gain and preload coupling × 2
/// sensor_crosstalk = 0.004  # each position sensor reads 0.4 % of the others
/// [x]
/// mode_hz = 680.0           # a one-axis file's keys, per axis
/// [y]
/// mode_hz = 1200.0
/// ```
pub fn parse_axes(arg: &str) -> Result<AxesSpec> {
    if let Some(s) = AxesSpec::base(arg) {
        return Ok(s);
    }
    let path = Path::new(arg);
    if !path.exists() {
        bail!(
            "--stage {}: {} or a TOML file naming one as its base",
            Quoted(arg),
            AxesSpec::BASES.join(", ")
        );
    }
    let text = String::from_utf8(crate::data::read_bytes(path)?)
        .map_err(|e| anyhow!("{arg}: not a text file: {e}"))?;
    axes_from_toml(&text, arg)
}

/// The stage of several axes the TOML text of file `name` describes.
pub fn axes_from_toml(text: &str, name: &str) -> Result<AxesSpec> {
    let f: AxesVariantFile = toml::from_str(text)
        .map_err(|e| anyhow!(toml_error(name, "stage variant file", text, &e)))?;
    let mut spec = AxesSpec::base(&f.base).ok_or_else(|| {
        anyhow!(
            "{name}: base = {}: a stage of several axes ({})",
            Quoted(&f.base),
            AxesSpec::BASES.join(", ")
        )
    })?;
    for (i, table) in [&f.x, &f.y, &f.z].into_iter().enumerate() {
        let Some(t) = table else { continue };
        let axis = AXIS_NAMES[i];
        if i >= spec.axes {
            bail!(
                "{name}: [{axis}]: base {} has axes {} only",
                Quoted(&f.base),
                AXIS_NAMES[..spec.axes].join(", ")
            );
        }
        let v = t.variant(spec.built, name, &format!("{axis}."))?;
        spec.overrides[i] = overrides(&v);
    }
    for (key, v, (lo, hi)) in [
        ("coupling_scale", f.coupling_scale, COUPLING_SCALE_RANGE),
        (
            "sensor_crosstalk",
            f.sensor_crosstalk,
            SENSOR_CROSSTALK_RANGE,
        ),
    ] {
        if let Some(v) = v.filter(|v| !(*v >= lo && *v <= hi)) {
            bail!("{name}: {key} = {}: must lie in [{lo}, {hi}]", Num(v));
        }
    }
    spec.coupling_scale = f.coupling_scale.unwrap_or(1.0) as f32;
    spec.sensor_crosstalk = f.sensor_crosstalk.map(|v| v as f32);
    Ok(spec)
}

/// One line describing the variant.
pub fn describe(v: &StageVariant) -> String {
    let mut s = String::from(if v.built {
        "stage as built"
    } else {
        "nominal twin"
    });
    for ((k, _), x) in StageVariant::KEYS.iter().zip(v.values()) {
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

    /// Every key the protocol declares is a file's key and reaches its own
    /// value (the reader's fields and [`StageVariant::values`] in
    /// [`StageVariant::KEYS`]'s order), and the description names it.
    #[test]
    fn every_declared_key_reaches_its_value() {
        for (k, (key, (lo, hi))) in StageVariant::KEYS.iter().enumerate() {
            let x = 0.5 * (lo + hi);
            let v = from_toml(&format!("base = \"built\"\n{key} = {x}\n"), "v.toml").unwrap();
            let mut want = [None; 7];
            want[k] = Some(x);
            assert_eq!(v.values(), want, "{key}");
            assert!(describe(&v).ends_with(&format!(", {key} = {x}")), "{key}");
            let e = from_toml(&format!("base = \"built\"\n{key} = 1e9\n"), "v.toml");
            assert!(
                format!("{:#}", e.unwrap_err()).contains(&format!("{key} = 1e9")),
                "{key}"
            );
        }
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
        let e = from_toml("base = \"xy-built\"\n", "v.toml").unwrap_err();
        assert!(
            format!("{e:#}").contains("2 axes; this board drives one"),
            "{e:#}"
        );
    }

    #[test]
    fn a_several_axis_file_changes_each_axis_and_the_couplings() {
        let s = axes_from_toml(
            "base = \"xy-built\"\ncoupling_scale = 0.5\nsensor_crosstalk = 0.004\n\
             [y]\nmode_hz = 1200.0\n",
            "v.toml",
        )
        .unwrap();
        assert_eq!((s.axes, s.built), (2, true));
        assert_eq!(s.params()[1].mode_hz, 1200.0);
        assert_eq!(s.params()[0].mode_hz, 850.0);
        let c = s.coupling();
        assert_eq!(c.cross_um_per_um[1][0], 0.0075);
        assert_eq!(c.sensor_crosstalk, 0.004);
        assert!(s.build::<2>(1).is_some() && s.build::<3>(1).is_none());
    }

    #[test]
    fn a_several_axis_file_s_mistakes_are_named() {
        let cases = [
            (
                "base = \"xy-built\"\n[z]\nmode_hz = 700.0\n",
                "[z]: base \"xy-built\" has axes x, y only",
            ),
            (
                "base = \"xy-built\"\n[y]\nmode_hz = 50.0\n",
                "y.mode_hz = 50: must lie in [100, 5000]",
            ),
            (
                "base = \"xy-built\"\n[y]\nmode_hertz = 900.0\n",
                "mode_hertz",
            ),
            (
                "base = \"xy-built\"\ncoupling_scale = -1\n",
                "coupling_scale = -1: must lie in [0, 4]",
            ),
            (
                "base = \"xyz-built\"\nsensor_crosstalk = 0.5\n",
                "sensor_crosstalk = 0.5: must lie in [0, 0.05]",
            ),
            ("base = \"xy-built\"\ncoupling = 2\n", "coupling"),
            ("base = \"built\"\n", "a stage of several axes"),
        ];
        for (text, wanted) in cases {
            let e = format!("{:#}", axes_from_toml(text, "v.toml").unwrap_err());
            assert!(e.contains("v.toml") && e.contains(wanted), "{text}: {e}");
        }
    }
}
