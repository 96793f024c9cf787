//! The firmware model file: what `fpi export` writes and `build.rs` embeds.
//!
//! Not part of the `no_std` core. `build.rs` and the host crate include this file
//! with `#[path]`, so the writer and the reader share one schema and one set of
//! checks. Needs `serde` (derive) and `toml`.
//!
//! Every value is an engineering value (V, µm, N, µm/V, V/N, µm/N); `build.rs`
//! quantises them to the core's Q formats. Tables are sampled on uniform grids
//! with a power-of-two spacing `2^step_log2` in the input unit.

use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// The core's Q-format constants (the same file the core includes).
mod q {
    #![allow(dead_code)]
    include!("qformat.rs");
}

/// The `format` string this schema reads and writes.
pub const FORMAT: &str = "piezo-fpi-firmware/1";

/// A whole firmware model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FirmwareModel {
    /// Always [`FORMAT`].
    pub format: String,
    /// Where the numbers came from.
    pub provenance: Provenance,
    /// The forward PI model of the stack.
    pub pi: PiSection,
    /// The FPI force coupling.
    pub coupling: CouplingSection,
    /// The soft dead zone `û = g(u - U_p(F))`; absent: the hard one, `max(·, 0)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dead_zone: Option<MapSection>,
    /// The output saturation `z = h(Y)`; absent: the identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation: Option<MapSection>,
    /// Creep: first-order lags of the effective voltage, added to `Y`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub creep: Vec<CreepSection>,
    /// The control loop: rate, limits, fault thresholds.
    pub controller: ControllerSection,
    /// FEM-derived lookup tables.
    pub tables: Tables,
}

/// Provenance of a model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The calibrated model it was exported from.
    pub model: String,
    /// The FEM table the maps came from.
    pub fem: String,
    /// Tool and version that wrote it.
    pub created_by: String,
    /// Free text: calibration data, fit metrics.
    pub notes: String,
}

/// `Y[u] = w0·u + Σ w_i G_{r_i}[u]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PiSection {
    /// Linear weight, µm/V (> 0).
    pub w0_um_per_v: f64,
    /// Thresholds, V, non-decreasing, in `[0, input_max_v]`.
    pub thresholds_v: Vec<f64>,
    /// Weights, µm/V; partial sums with `w0` positive.
    pub weights_um_per_v: Vec<f64>,
    /// Input domain `[0, input_max_v]`, V.
    pub input_max_v: f64,
}

/// `U_p(F) = k0 + k_f·F + k_q·(F - F_q)²`, `x = h(Y[g(u - U_p)]) - c·(F - F_ref)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CouplingSection {
    /// Constant part `k0` of the preload offset, V.
    #[serde(default)]
    pub offset_v: f64,
    /// Force–voltage coupling, V/N.
    pub k_f_v_per_n: f64,
    /// Curvature `k_q` of the preload offset, V/N².
    #[serde(default)]
    pub k_q_v_per_n2: f64,
    /// Centre `F_q` of the curvature term, N.
    #[serde(default)]
    pub force_q_n: f64,
    /// Stack compliance, µm/N (0 for the paper's FPI).
    pub compliance_um_per_n: f64,
    /// Force at zero extension, N.
    pub force_ref_n: f64,
}

/// A monotone map and its inverse, both tabulated (see the core's `fpi::Map`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapSection {
    /// `y = map(x)`.
    pub forward: TableSection,
    /// `x = map⁻¹(y)`.
    pub inverse: TableSection,
}

impl MapSection {
    fn through(t: &TableSection, x: f64) -> f64 {
        if x > t.x_max() {
            t.values[t.values.len() - 1] + (x - t.x_max())
        } else {
            t.eval(x)
        }
    }
    /// `map(x)`: holds below the first knot, slope one beyond the last (the core's rule).
    pub fn apply(&self, x: f64) -> f64 {
        Self::through(&self.forward, x)
    }
    /// `map⁻¹(y)`, same rule.
    pub fn invert(&self, y: f64) -> f64 {
        Self::through(&self.inverse, y)
    }
}

/// One creep term: `m ← m + (1 - exp(-T_s/τ))·(û - m)`, contributing `b·m` to `Y`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepSection {
    /// Time constant `τ`, s.
    pub tau_s: f64,
    /// Gain `b`, µm/V.
    pub gain_um_per_v: f64,
}

impl CreepSection {
    /// `1 - a` per sample at a sample rate.
    pub fn rate(&self, rate_hz: f64) -> f64 {
        -(-1.0 / (rate_hz * self.tau_s)).exp_m1()
    }
}

/// Most creep terms a firmware model may have.
pub const MAX_CREEP: usize = 8;

/// Control-loop settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// ISR rate, Hz.
    pub rate_hz: u32,
    /// Lowest amplifier setpoint, V.
    pub u_min_v: f64,
    /// Highest amplifier setpoint, V.
    pub u_max_v: f64,
    /// Largest setpoint slew, V/ms.
    pub slew_v_per_ms: f64,
    /// Lowest reachable reference, µm of stage output.
    pub reference_min_um: f64,
    /// Highest reachable reference, µm of stage output.
    pub reference_max_um: f64,
    /// Lowest plausible force reading, N.
    pub force_min_n: f64,
    /// Highest plausible force reading, N.
    pub force_max_n: f64,
    /// Largest tolerated `|F - f_F(x_pea_est)|`, N.
    pub force_tolerance_n: f64,
    /// Safe-state voltage, V.
    pub safe_voltage_v: f64,
    /// `"measured"` (force sensor) or `"predicted"` (`f_F` of the reference).
    pub force_source: String,
}

/// The three FEM-derived maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tables {
    /// Preload, N, vs stack extension, µm.
    pub f_f: TableSection,
    /// Stage output, µm, vs stack extension, µm.
    pub f_k: TableSection,
    /// Stack extension, µm, vs stage output, µm.
    pub f_k_inv: TableSection,
}

/// A monotone function sampled at `x0 + k·2^step_log2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableSection {
    /// First knot, input unit.
    pub x0: f64,
    /// Knot spacing is `2^step_log2` input units; `-16..=0`.
    pub step_log2: i32,
    /// Values at the knots, output unit.
    pub values: Vec<f64>,
}

impl TableSection {
    /// Knot spacing in input units.
    pub fn step(&self) -> f64 {
        2f64.powi(self.step_log2)
    }
    /// Last knot, input unit.
    pub fn x_max(&self) -> f64 {
        self.x0 + self.step() * (self.values.len().saturating_sub(1)) as f64
    }
    /// Linear interpolation holding the end values: the f64 twin of the core's `Table::eval`.
    pub fn eval(&self, x: f64) -> f64 {
        let n = self.values.len();
        let t = (x - self.x0) / self.step();
        if t.is_nan() || t <= 0.0 {
            return self.values[0];
        }
        let k = t.floor() as usize;
        if k + 1 >= n {
            return self.values[n - 1];
        }
        let f = t - k as f64;
        self.values[k] + (self.values[k + 1] - self.values[k]) * f
    }
}

impl FirmwareModel {
    /// Parses and validates a model file; errors name the file and the key.
    pub fn parse(text: &str, file: &str) -> Result<Self, String> {
        let model: FirmwareModel =
            toml::from_str(text).map_err(|e| format!("{file}: not a firmware model file: {e}"))?;
        model.validate().map_err(|e| format!("{file}: {e}"))?;
        Ok(model)
    }

    /// The file's text (what `fpi export` writes), with a header comment.
    pub fn to_toml(&self) -> Result<String, String> {
        let body = toml::to_string(self).map_err(|e| e.to_string())?;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "# Firmware model: FPI parameters, FEM tables and loop settings for the\n\
             # no_std core. Written by `fpi export`; build.rs quantises it to the Q formats.\n\
             # Units are in the key names. Regenerate rather than edit by hand.\n"
        );
        out.push_str(&body);
        Ok(out)
    }

    /// Every check the build relies on; the first failure, naming its key.
    pub fn validate(&self) -> Result<(), String> {
        if self.format != FORMAT {
            return Err(format!("format = {:?}: expected {FORMAT:?}", self.format));
        }
        let p = &self.pi;
        let n = p.thresholds_v.len();
        if n > q::MAX_OPERATORS {
            return Err(format!(
                "pi.thresholds_v has {n} values: at most {} operators",
                q::MAX_OPERATORS
            ));
        }
        if p.weights_um_per_v.len() != n {
            return Err(format!(
                "pi.weights_um_per_v has {} values but pi.thresholds_v has {n}",
                p.weights_um_per_v.len()
            ));
        }
        signal_value("pi.input_max_v", p.input_max_v)?;
        if p.input_max_v <= 0.0 {
            return Err(format!("pi.input_max_v = {}: must be > 0", p.input_max_v));
        }
        gain_value("pi.w0_um_per_v", p.w0_um_per_v)?;
        let mut slope = p.w0_um_per_v;
        if slope <= 0.0 {
            return Err(format!(
                "pi.w0_um_per_v = {slope}: must be > 0 (the inverse PI needs S_0 = w0 > 0)"
            ));
        }
        let mut prev = 0.0;
        for (i, (&r, &w)) in p.thresholds_v.iter().zip(&p.weights_um_per_v).enumerate() {
            let key = format!("pi.thresholds_v[{i}]");
            signal_value(&key, r)?;
            if r < 0.0 {
                return Err(format!("{key} = {r}: thresholds must be >= 0"));
            }
            if r < prev {
                return Err(format!(
                    "{key} = {r}: thresholds must be non-decreasing (previous {prev})"
                ));
            }
            if r > p.input_max_v {
                return Err(format!(
                    "{key} = {r}: beyond pi.input_max_v = {}",
                    p.input_max_v
                ));
            }
            prev = r;
            gain_value(&format!("pi.weights_um_per_v[{i}]"), w)?;
            slope += w;
            if slope <= 0.0 {
                return Err(format!(
                    "pi.weights_um_per_v[{i}]: partial sum S_{} = w0 + w_1 + ... = {slope} is not \
                     positive; the PI would not be invertible",
                    i + 1
                ));
            }
        }
        let c = &self.coupling;
        signal_value("coupling.offset_v", c.offset_v)?;
        coupling_value("coupling.k_f_v_per_n", c.k_f_v_per_n)?;
        coupling_value("coupling.compliance_um_per_n", c.compliance_um_per_n)?;
        signal_value("coupling.force_ref_n", c.force_ref_n)?;
        signal_value("coupling.force_q_n", c.force_q_n)?;
        let kq_max = (2048.0 / (1024.0f64 * 1024.0)) * 0.999;
        if !c.k_q_v_per_n2.is_finite() || c.k_q_v_per_n2.abs() > kq_max {
            return Err(format!(
                "coupling.k_q_v_per_n2 = {}: must be finite and within ±{kq_max:.3e} V/N²",
                c.k_q_v_per_n2
            ));
        }

        let k = &self.controller;
        if !(100..=200_000).contains(&k.rate_hz) {
            return Err(format!(
                "controller.rate_hz = {}: must be 100..=200000",
                k.rate_hz
            ));
        }
        for (key, v) in [
            ("controller.u_min_v", k.u_min_v),
            ("controller.u_max_v", k.u_max_v),
            ("controller.reference_min_um", k.reference_min_um),
            ("controller.reference_max_um", k.reference_max_um),
            ("controller.force_min_n", k.force_min_n),
            ("controller.force_max_n", k.force_max_n),
            ("controller.force_tolerance_n", k.force_tolerance_n),
            ("controller.safe_voltage_v", k.safe_voltage_v),
        ] {
            signal_value(key, v)?;
        }
        ordered(
            "controller.u_min_v",
            k.u_min_v,
            "controller.u_max_v",
            k.u_max_v,
        )?;
        ordered(
            "controller.reference_min_um",
            k.reference_min_um,
            "controller.reference_max_um",
            k.reference_max_um,
        )?;
        ordered(
            "controller.force_min_n",
            k.force_min_n,
            "controller.force_max_n",
            k.force_max_n,
        )?;
        if !(k.u_min_v..=k.u_max_v).contains(&k.safe_voltage_v) {
            return Err(format!(
                "controller.safe_voltage_v = {}: outside [u_min_v, u_max_v]",
                k.safe_voltage_v
            ));
        }
        let step = k.slew_v_per_ms * 1e3 / k.rate_hz as f64;
        if !(step.is_finite() && step > 0.0 && step < q::SIGNAL_ABS_MAX) {
            return Err(format!(
                "controller.slew_v_per_ms = {}: must be > 0 (per-step limit {step} V)",
                k.slew_v_per_ms
            ));
        }
        if k.force_tolerance_n <= 0.0 {
            return Err("controller.force_tolerance_n: must be > 0".into());
        }
        if k.force_source != "measured" && k.force_source != "predicted" {
            return Err(format!(
                "controller.force_source = {:?}: expected \"measured\" or \"predicted\"",
                k.force_source
            ));
        }
        let t = &self.tables;
        for (name, tab) in [("f_f", &t.f_f), ("f_k", &t.f_k), ("f_k_inv", &t.f_k_inv)] {
            check_table(&format!("tables.{name}"), tab)?;
        }
        for (name, map) in [
            ("dead_zone", &self.dead_zone),
            ("saturation", &self.saturation),
        ] {
            if let Some(m) = map {
                for (dir, tab) in [("forward", &m.forward), ("inverse", &m.inverse)] {
                    let key = format!("{name}.{dir}");
                    check_table(&key, tab)?;
                    if tab.values[tab.values.len() - 1] < tab.values[0] {
                        return Err(format!("{key}.values: a map must be increasing"));
                    }
                }
            }
        }
        if self.creep.len() > MAX_CREEP {
            return Err(format!(
                "creep: {} terms, at most {MAX_CREEP}",
                self.creep.len()
            ));
        }
        for (j, c) in self.creep.iter().enumerate() {
            let rate = c.rate(k.rate_hz as f64);
            if !(c.tau_s.is_finite() && c.tau_s > 0.0 && rate < 0.5) {
                return Err(format!(
                    "creep[{j}].tau_s = {}: must be longer than {:.3e} s at {} Hz",
                    c.tau_s,
                    std::f64::consts::LN_2.recip() / k.rate_hz as f64,
                    k.rate_hz
                ));
            }
            gain_value(&format!("creep[{j}].gain_um_per_v"), c.gain_um_per_v)?;
        }
        if k.reference_min_um < t.f_k_inv.x0 || k.reference_max_um > t.f_k_inv.x_max() {
            return Err(format!(
                "controller.reference_min_um..reference_max_um = {}..{} um: outside the \
                 tables.f_k_inv grid {}..{} um",
                k.reference_min_um,
                k.reference_max_um,
                t.f_k_inv.x0,
                t.f_k_inv.x_max()
            ));
        }
        Ok(())
    }
}

fn signal_value(key: &str, v: f64) -> Result<(), String> {
    if !v.is_finite() || v.abs() > q::SIGNAL_ABS_MAX {
        return Err(format!(
            "{key} = {v}: not a finite value within ±{} (I16F16 signal range)",
            q::SIGNAL_ABS_MAX
        ));
    }
    Ok(())
}

fn gain_value(key: &str, v: f64) -> Result<(), String> {
    if !v.is_finite() || v.abs() > q::GAIN_ABS_MAX {
        return Err(format!(
            "{key} = {v}: not a finite value within ±{} (I4F28 gain range)",
            q::GAIN_ABS_MAX
        ));
    }
    Ok(())
}

fn coupling_value(key: &str, v: f64) -> Result<(), String> {
    if !v.is_finite() || v.abs() > q::COUPLING_ABS_MAX {
        return Err(format!(
            "{key} = {v}: not a finite value within ±{} (I0F32 coupling range)",
            q::COUPLING_ABS_MAX
        ));
    }
    Ok(())
}

fn ordered(lo_key: &str, lo: f64, hi_key: &str, hi: f64) -> Result<(), String> {
    if lo > hi {
        return Err(format!("{lo_key} = {lo} exceeds {hi_key} = {hi}"));
    }
    Ok(())
}

fn check_table(key: &str, t: &TableSection) -> Result<(), String> {
    let n = t.values.len();
    if !(2..=q::MAX_TABLE_LEN).contains(&n) {
        return Err(format!(
            "{key}.values has {n} values: need 2..={}",
            q::MAX_TABLE_LEN
        ));
    }
    if !(-16..=0).contains(&t.step_log2) {
        return Err(format!(
            "{key}.step_log2 = {}: must be -16..=0 (knots at most one unit apart)",
            t.step_log2
        ));
    }
    signal_value(&format!("{key}.x0"), t.x0)?;
    signal_value(&format!("{key} last knot"), t.x_max())?;
    let increasing = t.values[n - 1] >= t.values[0];
    for (i, &v) in t.values.iter().enumerate() {
        signal_value(&format!("{key}.values[{i}]"), v)?;
        if i > 0 {
            let p = t.values[i - 1];
            if (increasing && v < p) || (!increasing && v > p) {
                return Err(format!(
                    "{key}.values[{i}] = {v}: not monotone (previous {p}); the maps must be monotone"
                ));
            }
            if (v - p).abs() >= 0.5 {
                return Err(format!(
                    "{key}.values[{i}] = {v}: differs from the previous knot ({p}) by 0.5 or \
                     more; use a finer grid (step_log2)"
                ));
            }
        }
    }
    Ok(())
}
