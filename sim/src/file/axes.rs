//! The model file of a board of several axes (`format =
//! "piezo-fpi-axes/1"`): each axis's firmware model under its axis's table
//! (`[x]`, `[y]`, `[z]`: each a whole [`FirmwareModel`]) and the coupling the
//! board's decoupling is made of (`[coupling]`). What `fpi board autotune`
//! writes on a board of several axes and `fpi board load` loads whole.
//!
//! The coupling is kept as the stage's physics, not as the board's matrices:
//! the sensors' cross-talk (their calibration), the parasitic motion measured
//! with the cross-talk taken out, and the stacks' preload coupling. The
//! matrices are made of it when the file is read ([`AxesModel::decoupling`]),
//! as the board takes them (`piezo_fpi::decoupling`).

use std::format;
use std::string::String;
use std::vec::Vec;

use piezo_fpi::decoupling::{Decoupling, Part, OFF_DIAGONAL_MAX, PRELOAD_MAX};
use serde::{Deserialize, Serialize};

use super::FirmwareModel;
use crate::axes::{AXIS_NAMES, MAX_AXES};
use crate::quote::{toml_error, Num};

/// The `format` string of a file of several axes.
pub const AXES_FORMAT: &str = "piezo-fpi-axes/1";

/// A model file of several axes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AxesModel {
    /// Always `piezo-fpi-axes/1` ([`AXES_FORMAT`]).
    pub format: String,
    /// How the axes couple: what the board's decoupling is made of.
    pub coupling: CouplingTable,
    /// Axis x's firmware model (every key of a firmware model file, under `x.`).
    pub x: FirmwareModel,
    /// Axis y's firmware model.
    pub y: FirmwareModel,
    /// Axis z's firmware model (a stage of three axes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub z: Option<FirmwareModel>,
}

/// How the axes of a stage couple, measured through its board (`[coupling]`).
/// Square arrays are `[i][j]`: of axis `i` per unit of axis `j`, one row per
/// axis of the file, the diagonal 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CouplingTable {
    /// The fraction of every other axis's output each position sensor reads:
    /// the sensors' calibration (from a reference measurement; the sensors
    /// cannot tell it from the parasitic motion). The input matrix undoes it.
    /// Within ±0.1.
    pub sensor_crosstalk: f64,
    /// µm of axis `i`'s output per µm of axis `j`'s own, the sensors'
    /// cross-talk taken out (the flexure's parasitic motion). The output
    /// matrix undoes it. Each entry within ±0.1.
    pub parasitic: Vec<Vec<f64>>,
    /// N on stack `i` per µm of stack `j`'s extension (the flexure's preload
    /// coupling, per µm of the extension the board estimates). Each entry
    /// within ±4 N/µm.
    pub preload_n_per_um: Vec<Vec<f64>>,
}

impl AxesModel {
    /// The axes' models, in axis order.
    pub fn models(&self) -> Vec<&FirmwareModel> {
        let mut m = std::vec![&self.x, &self.y];
        m.extend(self.z.as_ref());
        m
    }

    /// Parses and checks a file of several axes: its TOML, every axis's
    /// model ([`FirmwareModel::check`]) and the coupling; errors name the
    /// file, the key, the value and the rule.
    pub fn parse(text: &str, file: &str) -> Result<Self, String> {
        let m: AxesModel = toml::from_str(text)
            .map_err(|e| toml_error(file, "model file of several axes", text, &e))?;
        if m.format != AXES_FORMAT {
            return Err(format!(
                "{file}: format = {:?}: a model file of several axes has format = {AXES_FORMAT:?}",
                m.format
            ));
        }
        for (name, model) in AXIS_NAMES.iter().zip(m.models()) {
            model
                .check()
                .map_err(|e| format!("{file}: in [{name}]: {e}"))?;
        }
        m.decoupling().map_err(|e| format!("{file}: {e}"))?;
        Ok(m)
    }

    /// The file's text, with a header comment.
    pub fn to_toml(&self) -> Result<String, String> {
        let body = toml::to_string(self).map_err(|e| e.to_string())?;
        Ok(format!(
            "# Firmware models of a board of several axes and their coupling. Written by\n\
             # `fpi board autotune`; `fpi board load` loads it whole (each axis's model,\n\
             # then the decoupling made of [coupling]).\n\n{body}"
        ))
    }

    /// The board's decoupling made of `[coupling]` ([`CouplingTable::decoupling`]
    /// over the file's axes).
    pub fn decoupling(&self) -> Result<Decoupling<MAX_AXES>, String> {
        self.coupling.decoupling(self.models().len())
    }
}

impl CouplingTable {
    /// No coupling among `n` axes.
    pub fn none(n: usize) -> Self {
        let zeros = std::vec![std::vec![0.0; n]; n];
        Self {
            sensor_crosstalk: 0.0,
            parasitic: zeros.clone(),
            preload_n_per_um: zeros,
        }
    }

    /// The board's decoupling of `n` axes made of it (the input matrix
    /// undoing the sensors' cross-talk among the axes, the output matrix
    /// undoing the parasitic motion, the preload coupling), or the first key
    /// the board would refuse, with its value and the rule.
    pub fn decoupling(&self, n: usize) -> Result<Decoupling<MAX_AXES>, String> {
        let s = self.sensor_crosstalk;
        if !(s.is_finite() && s.abs() <= OFF_DIAGONAL_MAX) {
            return Err(format!(
                "coupling.sensor_crosstalk = {}: a fraction within ±{OFF_DIAGONAL_MAX}",
                Num(s)
            ));
        }
        let parasitic = square("coupling.parasitic", &self.parasitic, n, OFF_DIAGONAL_MAX)?;
        let preload = square(
            "coupling.preload_n_per_um",
            &self.preload_n_per_um,
            n,
            PRELOAD_MAX,
        )?;
        Decoupling::of_coupling(s, parasitic, preload, n).map_err(|(part, e)| {
            let key = match part {
                Part::Input => "coupling.sensor_crosstalk",
                Part::Output => "coupling.parasitic",
                Part::Preload => "coupling.preload_n_per_um",
            };
            format!("{key}: the board cannot undo it: {e}")
        })
    }
}

/// The `n`×`n` array `rows` of `key` as the board's square, checked: `n`
/// rows of `n` finite entries, the diagonal 0, the others within ±`max`.
fn square(
    key: &str,
    rows: &[Vec<f64>],
    n: usize,
    max: f64,
) -> Result<[[f64; MAX_AXES]; MAX_AXES], String> {
    if rows.len() != n || rows.iter().any(|r| r.len() != n) {
        return Err(format!(
            "{key}: {} rows of {:?} entries: the file has {n} axes, so {n} rows of {n}",
            rows.len(),
            rows.iter().map(Vec::len).collect::<Vec<_>>()
        ));
    }
    let mut out = [[0.0; MAX_AXES]; MAX_AXES];
    for (i, row) in rows.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            let ok = if i == j {
                v == 0.0
            } else {
                v.is_finite() && v.abs() <= max
            };
            if !ok {
                let rule = if i == j {
                    "0 on the diagonal (an axis's own motion is its model's)".into()
                } else {
                    format!("finite, within ±{max}")
                };
                return Err(format!("{key}[{i}][{j}] = {}: {rule}", Num(v)));
            }
            out[i][j] = v;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(parasitic: &str) -> String {
        let model = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../firmware/model/stage-a.toml"
        ))
        .unwrap();
        let m = FirmwareModel::parse(&model, "stage-a.toml").unwrap();
        let a = AxesModel {
            format: AXES_FORMAT.into(),
            coupling: CouplingTable {
                sensor_crosstalk: 0.002,
                parasitic: std::vec![std::vec![0.0, 0.02], std::vec![0.015, 0.0]],
                preload_n_per_um: std::vec![std::vec![0.0, 0.5], std::vec![0.5, 0.0]],
            },
            x: m.clone(),
            y: m,
            z: None,
        };
        a.to_toml()
            .unwrap()
            .replace("parasitic = [[0.0, 0.02], [0.015, 0.0]]", parasitic)
    }

    #[test]
    fn a_file_of_two_axes_round_trips_and_makes_the_decoupling() {
        let text = file("parasitic = [[0.0, 0.02], [0.015, 0.0]]");
        let m = AxesModel::parse(&text, "t.toml").unwrap();
        assert_eq!(m.models().len(), 2);
        let d = m.decoupling().unwrap();
        // (I + C)⁻¹: the off-diagonal about −C.
        let yx: f64 = d.output.rows()[1][0].to_num();
        assert!((yx + 0.015).abs() < 1e-3, "{yx}");
        let yx: f64 = d.input.rows()[1][0].to_num();
        assert!((yx + 0.002).abs() < 1e-4, "{yx}");
        assert_eq!(
            AxesModel::parse(&m.to_toml().unwrap(), "t.toml").unwrap(),
            m
        );
    }

    #[test]
    fn a_bad_coupling_is_named_by_key_value_and_rule() {
        let e = AxesModel::parse(&file("parasitic = [[0.0, 0.3], [0.015, 0.0]]"), "t.toml")
            .unwrap_err();
        assert!(
            e.contains("t.toml: coupling.parasitic[0][1] = 0.3: finite, within ±0.1"),
            "{e}"
        );
        let e = AxesModel::parse(&file("parasitic = [[0.0, 0.02]]"), "t.toml").unwrap_err();
        assert!(
            e.contains("coupling.parasitic: 1 rows") && e.contains("2 rows of 2"),
            "{e}"
        );
        let e = AxesModel::parse(&file("parasitic = [[0.5, 0.02], [0.015, 0.0]]"), "t.toml")
            .unwrap_err();
        assert!(
            e.contains("coupling.parasitic[0][0] = 0.5: 0 on the diagonal"),
            "{e}"
        );
        let e = AxesModel::parse(
            &file("parasitic = [[0.0, 0.02], [0.015, 0.0]]\nextra = 1"),
            "t.toml",
        )
        .unwrap_err();
        assert!(e.contains("t.toml:") && e.contains("extra"), "{e}");
    }
}
