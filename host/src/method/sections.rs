//! The sections of a calibrated model's file (`piezo-fpi-model/1`): each checks
//! its own keys. Which sections a kind uses, and what they mean to it, is the
//! kind's ([`crate::method::kinds`]); [`crate::method::model::HostModel`] holds
//! them.

use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

use crate::data::fem::FemMaps;
use crate::method::axes::grid::FemGrid;
use crate::model_file::PiSection;

/// Refuses a non-finite value of key `key`.
pub(crate) fn finite(key: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        bail!("{key} = {}: not finite", crate::data::Num(v))
    }
}

/// LDPI: the slopes of the weights in the preload, `w_i(F) = w_i + b_i·F`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct LdpiParams {
    /// Slope of `w0`, µm/V/N.
    pub w0_per_n: f64,
    /// Slopes of the operator weights, µm/V/N.
    pub weights_per_n: Vec<f64>,
}

/// The map after the PI (analytic), as the model file stores it.
pub type OutputMap = piezo_sim::maps::OutputMap<f64>;

/// Fit of one calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileFit {
    /// The recording.
    pub file: String,
    /// Samples scored.
    pub samples: usize,
    /// Root-mean-square error, µm.
    pub rmse_um: f64,
    /// Largest absolute error (MTE), µm.
    pub mte_um: f64,
}

/// Where a model came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Tool and version.
    pub created_by: String,
    /// Recordings it was fitted on.
    pub files: Vec<String>,
    /// Rows fitted (1-based, inclusive), when only part of one recording was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<[usize; 2]>,
    /// RMSE over all fitted samples, µm.
    pub rmse_um: f64,
    /// Largest error over all fitted samples, µm.
    pub mte_um: f64,
    /// Per recording.
    pub per_file: Vec<FileFit>,
    /// How it was fitted.
    pub method: String,
    /// What looked suspicious in the data (each names the file, the column and the
    /// value); empty when nothing did.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// RMSE over several files' fits, weighted by their samples.
pub fn pooled_rmse(per_file: &[FileFit]) -> f64 {
    let total: usize = per_file.iter().map(|f| f.samples).sum();
    let s2: f64 = per_file
        .iter()
        .map(|f| f.rmse_um * f.rmse_um * f.samples as f64)
        .sum();
    (s2 / total as f64).sqrt()
}

impl Calibration {
    /// The provenance and figures of a fit of `files` by `method`: its RMSE over
    /// every file, the per-file figures and the largest error among them.
    pub fn new(
        files: Vec<String>,
        rmse_um: f64,
        per_file: Vec<FileFit>,
        method: String,
        warnings: Vec<String>,
    ) -> Self {
        Self {
            created_by: format!("fpi calibrate {}", env!("CARGO_PKG_VERSION")),
            files,
            rows: None,
            rmse_um,
            mte_um: per_file.iter().map(|f| f.mte_um).fold(0.0, f64::max),
            per_file,
            method,
            warnings,
        }
    }
}

/// The range the gain of `f_K` and the scale of `f_F` may take in a
/// [`FemCorrection`]: a built stage differs from its FEM by a few percent, not by
/// a factor of two.
pub const CORRECTION_RANGE: (f64, f64) = (0.5, 2.0);

/// How the built stage differs from its FEM tables (`[fem_correction]` of a model
/// file, written by `fpi refine`): stage output `stage_gain·f_K(x_pea) +
/// stage_offset_um`, preload `preload_scale·f_F(x_pea)`. The actuator's
/// parameters are not touched.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FemCorrection {
    /// Gain of the stage output `f_K` (within [`CORRECTION_RANGE`]).
    pub stage_gain: f64,
    /// Offset added to the stage output, µm.
    pub stage_offset_um: f64,
    /// Scale of the preload `f_F` (within [`CORRECTION_RANGE`]).
    pub preload_scale: f64,
    /// The FEM file the correction was estimated against (provenance; a model is
    /// meant to be used with the same FEM tables).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub fem: String,
    /// The measured runs it was estimated from.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refined_on: Vec<String>,
    /// RMSE of the stage output on those runs with the FEM tables as they are, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_before_um: Option<f64>,
    /// The same with the correction, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_after_um: Option<f64>,
}

impl FemCorrection {
    /// No correction: the FEM tables as they are.
    pub fn identity() -> Self {
        Self {
            stage_gain: 1.0,
            stage_offset_um: 0.0,
            preload_scale: 1.0,
            fem: String::new(),
            refined_on: Vec::new(),
            rmse_before_um: None,
            rmse_after_um: None,
        }
    }

    /// The FEM maps corrected: new points `x_fhps·gain + offset` and
    /// `preload·scale`, checked as an FEM file's are.
    pub fn apply(&self, fem: &FemMaps) -> Result<FemMaps> {
        fem.corrected(self.stage_gain, self.stage_offset_um, self.preload_scale)
            .map_err(|e| {
                anyhow::anyhow!(
                    "[fem_correction] (stage_gain {}, stage_offset_um {}, preload_scale {}) \
                     applied to {}: {e}",
                    self.stage_gain,
                    self.stage_offset_um,
                    self.preload_scale,
                    fem.source
                )
            })
    }

    /// `grid` with this correction on stack and axis `i`
    /// ([`FemGrid::corrected`]). The correction must have been refined on this
    /// grid (`fpi axes refine`: its `fem` names the grid's file): one refined
    /// on a one-axis stage's FEM (`fpi refine`) holds that stage's numbers, not
    /// this one's, and is refused.
    pub fn apply_grid(&self, grid: &FemGrid, i: usize) -> Result<FemGrid> {
        let file = |s: &str| std::path::Path::new(s).file_name().map(|n| n.to_owned());
        if self.fem.is_empty() || file(&self.fem) != file(&grid.source) {
            bail!(
                "its [fem_correction] was refined against {}, not the grid {}: a grid takes \
                 the correction `fpi axes refine` makes on it (use the model before `fpi refine`)",
                if self.fem.is_empty() {
                    "no named FEM"
                } else {
                    &self.fem
                },
                grid.source
            );
        }
        grid.corrected(i, self.stage_gain, self.stage_offset_um, self.preload_scale)
    }

    /// Checks the section; names the key that is wrong.
    pub fn validate(&self) -> Result<()> {
        let (lo, hi) = CORRECTION_RANGE;
        for (key, v) in [
            ("fem_correction.stage_gain", self.stage_gain),
            ("fem_correction.preload_scale", self.preload_scale),
        ] {
            finite(key, v)?;
            if !(lo..=hi).contains(&v) {
                bail!(
                    "{key} = {v}: outside {lo}..{hi} (a built stage differs from its FEM by a \
                     few percent; is this the right stage or FEM?)"
                );
            }
        }
        finite("fem_correction.stage_offset_um", self.stage_offset_um)?;
        if self.stage_offset_um.abs() > piezo_fpi::q::SIGNAL_ABS_MAX {
            bail!(
                "fem_correction.stage_offset_um = {}: outside ±{} µm",
                self.stage_offset_um,
                piezo_fpi::q::SIGNAL_ABS_MAX
            );
        }
        for (key, v) in [
            ("fem_correction.rmse_before_um", self.rmse_before_um),
            ("fem_correction.rmse_after_um", self.rmse_after_um),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v >= 0.0) {
                    bail!("{key} = {v}: must be a finite number ≥ 0 µm");
                }
            }
        }
        Ok(())
    }
}

/// Highest degree of a branch polynomial.
pub const MAX_DEGREE: usize = 6;

/// The paper's degrees: ascending cubic (eq. 6), descending quartic (eq. 7).
pub const PAPER_DEGREES: (usize, usize) = (3, 4);

/// How turning points are remembered (`branch.memory`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Memory {
    /// A stack of turning points with closure and wiping-out.
    #[default]
    Stack,
    /// The last turning point only (the paper).
    Last,
}

/// The `[branch]` section of a model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BranchSection {
    /// Input domain `[0, input_max_v]` of the effective voltage, V.
    pub input_max_v: f64,
    /// How turning points are remembered.
    #[serde(default)]
    pub memory: Memory,
    /// Ascending branch: `a_k` of `(v − v_min)^k`, `k = 1, 2, …`, µm/V^k.
    pub ascending_um_per_vk: Vec<f64>,
    /// Descending branch: `d_k` of `(v − v_max)^k`, `k = 1, 2, …`, µm/V^k.
    pub descending_um_per_vk: Vec<f64>,
}

impl BranchSection {
    /// Checks the section; names the key that is wrong.
    pub fn validate(&self) -> Result<()> {
        let top = self.input_max_v;
        if !(top.is_finite() && top > 0.0) {
            bail!("branch.input_max_v = {top}: must be a finite voltage > 0 V");
        }
        for (key, c) in [
            ("branch.ascending_um_per_vk", &self.ascending_um_per_vk),
            ("branch.descending_um_per_vk", &self.descending_um_per_vk),
        ] {
            if c.is_empty() || c.len() > MAX_DEGREE {
                bail!(
                    "{key} has {} coefficients: a branch is a polynomial of degree 1..={MAX_DEGREE}",
                    c.len()
                );
            }
            for (i, &v) in c.iter().enumerate() {
                if !v.is_finite() {
                    bail!("{key}[{i}] = {}: not finite", crate::data::Num(v));
                }
            }
            if c.iter().all(|&v| v == 0.0) {
                bail!("{key} is all 0: the model cannot produce motion on that branch");
            }
        }
        Ok(())
    }
}

/// The PI section of a branch model: none (no weights, no range), which the model
/// file leaves out.
pub fn no_pi() -> PiSection {
    PiSection {
        w0_um_per_v: 0.0,
        thresholds_v: Vec::new(),
        weights_um_per_v: Vec::new(),
        input_max_v: 0.0,
    }
}

/// Whether `p` is [`no_pi`].
pub fn is_no_pi(p: &PiSection) -> bool {
    *p == no_pi()
}
