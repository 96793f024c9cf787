//! Calibrated models of the actuator (host side, f64), their file format and
//! their evaluation: forward (voltage and force → extension), inverse, and the
//! non-committing "peek" the coupled FPI-FFEM solver needs.
//!
//! One structure covers every kind; a kind is a choice of which parts are active:
//!
//! | kind | input | parts |
//! |---|---|---|
//! | `pi` | `u` | PI with one-sided play operators (the conventional baseline) |
//! | `ldpi` | `u` | PI whose weights are affine in the preload, `w_i(F) = a_i + b_i·F` (the paper's LDPI baseline, as we implement it: its source is not available) |
//! | `fpi` | `û = max(u − k_f·F, 0)` | the paper's FPI (eqs. 5–7) |
//! | `efpi` | `û = g(u − U_p(F))` | extended FPI: `U_p = k0 + k_f·F + k_q·(F − F_q)²`, soft dead zone `g`, creep lags, output saturation, stack compliance |
//! | `gpi` | `u` | PI followed by a monotone quadratic output map and an offset (for recordings without force) |

use std::fmt;
use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use crate::reference::PiF64;

/// The model-file format string.
pub const FORMAT: &str = "piezo-fpi-model/1";

/// Which model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Classical PI on the voltage.
    Pi,
    /// Load-dependent PI: weights affine in the preload.
    Ldpi,
    /// The paper's force-dependent PI.
    Fpi,
    /// Extended FPI: curved preload offset, soft dead zone, creep, saturation, compliance.
    Efpi,
    /// PI with a monotone quadratic output map and an offset (no force).
    Gpi,
}

impl Kind {
    /// Every kind, in the order reports list them.
    pub const ALL: [Kind; 5] = [Kind::Pi, Kind::Ldpi, Kind::Fpi, Kind::Efpi, Kind::Gpi];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Pi => "pi",
            Kind::Ldpi => "ldpi",
            Kind::Fpi => "fpi",
            Kind::Efpi => "efpi",
            Kind::Gpi => "gpi",
        }
    }

    /// A kind by name.
    pub fn parse(s: &str) -> Result<Kind> {
        Kind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .with_context(|| {
                format!("unknown model kind {s:?}: expected pi, ldpi, fpi, efpi or gpi")
            })
    }

    /// Whether the model needs the preload.
    pub fn uses_force(self) -> bool {
        matches!(self, Kind::Ldpi | Kind::Fpi | Kind::Efpi)
    }

    /// The name the paper's method gets with this model (PI-FEM, FPI-FFEM, …).
    pub fn method(self) -> &'static str {
        match self {
            Kind::Pi => "PI-FEM",
            Kind::Ldpi => "LDPI-FEM",
            Kind::Fpi => "FPI-FFEM",
            Kind::Efpi => "EFPI-FFEM",
            Kind::Gpi => "GPI-FEM",
        }
    }
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The PI part: `w0·v + Σ w_i·G_{r_i}[v]`, inputs clamped to `[0, input_max]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PiParams {
    /// Linear weight, µm/V.
    pub w0_um_per_v: f64,
    /// Thresholds, V (sorted, > 0).
    pub thresholds_v: Vec<f64>,
    /// Weights, µm/V.
    pub weights_um_per_v: Vec<f64>,
    /// Input domain, V.
    pub input_max_v: f64,
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

/// The force coupling (FPI kinds).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct CouplingParams {
    /// Constant part of the preload offset `k0`, V.
    #[serde(default)]
    pub offset_v: f64,
    /// `k_f`, V/N.
    pub k_f_v_per_n: f64,
    /// Curvature `k_q`, V/N².
    #[serde(default)]
    pub k_q_v_per_n2: f64,
    /// Centre `F_q` of the curvature, N.
    #[serde(default)]
    pub force_q_n: f64,
    /// Stack compliance `c`, µm/N (the datasheet's 1/50 N/µm for stage A's stack).
    #[serde(default)]
    pub compliance_um_per_n: f64,
}

/// The map after the PI.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "map", rename_all = "lowercase", deny_unknown_fields)]
pub enum OutputMap {
    /// `x = Y`.
    #[default]
    Identity,
    /// Saturation: `z + β·z² = Y` (β > 0 flattens the top).
    Saturation {
        /// β, 1/µm.
        beta_per_um: f64,
    },
    /// `z = Y + γ·Y²`.
    Quadratic {
        /// γ, 1/µm.
        gamma_per_um: f64,
    },
}

impl core::fmt::Display for OutputMap {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            OutputMap::Identity => write!(f, "none (x = Y)"),
            OutputMap::Saturation { beta_per_um } => {
                write!(f, "x + {beta_per_um:.3e}/µm·x² = Y")
            }
            OutputMap::Quadratic { gamma_per_um } => {
                write!(f, "x = Y + {gamma_per_um:.3e}/µm·Y²")
            }
        }
    }
}

impl OutputMap {
    /// `z = h(Y)` and `dz/dY`.
    pub fn apply(self, y: f64) -> (f64, f64) {
        match self {
            OutputMap::Identity => (y, 1.0),
            OutputMap::Saturation { beta_per_um: b } => {
                if b == 0.0 {
                    return (y, 1.0);
                }
                let d = 1.0 + 4.0 * b * y;
                if d <= 0.0 {
                    return (-1.0 / (2.0 * b), 0.0);
                }
                let z = 2.0 * y / (1.0 + d.sqrt());
                (z, 1.0 / (1.0 + 2.0 * b * z))
            }
            OutputMap::Quadratic { gamma_per_um: g } => (y + g * y * y, 1.0 + 2.0 * g * y),
        }
    }

    /// `d²z/dY²` where the slope is `dz = dz/dY` (as [`apply`](Self::apply) returns it).
    pub fn curvature(self, dz: f64) -> f64 {
        match self {
            OutputMap::Identity => 0.0,
            // z + βz² = Y: dz/dY = 1/(1 + 2βz), d²z/dY² = −2β·(dz/dY)³.
            OutputMap::Saturation { beta_per_um: b } => -2.0 * b * dz * dz * dz,
            OutputMap::Quadratic { gamma_per_um: g } => 2.0 * g,
        }
    }

    /// `Y = h⁻¹(z)`.
    pub fn invert(self, z: f64) -> f64 {
        match self {
            OutputMap::Identity => z,
            OutputMap::Saturation { beta_per_um: b } => z + b * z * z,
            OutputMap::Quadratic { gamma_per_um: g } => {
                if g == 0.0 {
                    z
                } else {
                    let d = (1.0 + 4.0 * g * z).max(0.0);
                    (d.sqrt() - 1.0) / (2.0 * g)
                }
            }
        }
    }
}

/// A creep lag.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepParams {
    /// Time constant, s.
    pub tau_s: f64,
    /// Gain, µm/V.
    pub gain_um_per_v: f64,
}

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
}

/// A calibrated model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostModel {
    /// Always [`FORMAT`].
    pub format: String,
    /// Which model.
    pub kind: Kind,
    /// The PI part.
    pub pi: PiParams,
    /// LDPI weight slopes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ldpi: Option<LdpiParams>,
    /// Force coupling (FPI kinds).
    #[serde(default)]
    pub coupling: CouplingParams,
    /// Softness `s` of the dead zone `g(e) = s·ln(1 + e^{e/s})`, V (0: hard).
    #[serde(default)]
    pub dead_zone_softness_v: f64,
    /// The map after the PI.
    #[serde(default)]
    pub output: OutputMap,
    /// Constant added to the PI output `Y` before the output map, µm (recordings not
    /// zeroed at rest).
    #[serde(default)]
    pub offset_um: f64,
    /// Creep lags.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub creep: Vec<CreepParams>,
    /// Provenance and fit metrics.
    pub calibration: Calibration,
}

/// The soft (or hard) dead zone and its slope.
pub fn dead_zone(s: f64, e: f64) -> (f64, f64) {
    if s <= 0.0 {
        return if e > 0.0 { (e, 1.0) } else { (0.0, 0.0) };
    }
    let t = e / s;
    if t > 36.0 {
        (e, 1.0)
    } else {
        let ex = t.exp();
        (s * ex.ln_1p(), ex / (1.0 + ex))
    }
}

/// The inverse of [`dead_zone`] for a positive effective voltage.
pub fn dead_zone_inverse(s: f64, uh: f64) -> f64 {
    if s <= 0.0 {
        return uh;
    }
    let t = uh / s;
    if t > 36.0 {
        uh
    } else if t <= 1e-300 {
        -700.0 * s
    } else {
        s * t.exp_m1().ln()
    }
}

/// Narrows the open interval `(lo, hi)` around `at` to exclude the switch points
/// `bs`; a switch point at `at` itself empties it.
#[inline]
fn narrow_to(mut lo: f64, mut hi: f64, at: f64, bs: [f64; 2]) -> (f64, f64) {
    for b in bs {
        if b < at {
            lo = lo.max(b);
        } else if b > at {
            hi = hi.min(b);
        } else {
            return (at, at);
        }
    }
    (lo, hi)
}

/// The state of a model while it runs (operators, creep lags).
#[derive(Debug, Clone, PartialEq)]
pub struct ModelState {
    /// Operator outputs.
    pub y: Vec<f64>,
    /// Creep memories, V.
    pub m: Vec<f64>,
    /// Per-sample creep rates `1 − a_j`.
    pub rate: Vec<f64>,
}

/// One evaluation without committing: the extension and its derivative with
/// respect to the extension the preload map was read at (for the coupled solve).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peek {
    /// Stack extension, µm.
    pub x: f64,
    /// d(x)/d(x_guess) through the preload: ≤ 0 for physical models.
    pub dx: f64,
    /// The effective voltage the operators saw, V.
    pub uh: f64,
    /// The effective voltage before the dead zone and the domain clamp, V, and its
    /// derivative along the extension guess, V/µm.
    pub e: (f64, f64),
    /// For piecewise-linear models, the interval of `e` in which the model is this
    /// same linear function (no operator switches, no dead-zone or domain edge
    /// crossed): a Newton step that stays inside it (and inside the preload map's
    /// segment) lands exactly on the root. `None` for the smooth models.
    pub linear_in: Option<(f64, f64)>,
    /// d(û)/d(x_guess), V/µm (0 where û is clamped).
    pub duh: f64,
    /// d²(x)/d(x_guess)², 1/µm, inside the smooth piece (0 for piecewise-linear
    /// models): with `dx` it bounds the error of a Newton step.
    pub ddx: f64,
    /// For the smooth models, the open interval of `û` around this one in which no
    /// operator switches and no clamp or hard dead-zone edge acts, so the model is
    /// smooth there (linear in `û` for the PI part). `None` where `û` sits on such an
    /// edge, and for the piecewise-linear models (see `linear_in`).
    pub smooth_in: Option<(f64, f64)>,
}

impl HostModel {
    /// A new model of `kind` with the given PI part and everything else off.
    pub fn new(kind: Kind, pi: PiParams) -> Self {
        Self {
            format: FORMAT.into(),
            kind,
            pi,
            ldpi: None,
            coupling: CouplingParams::default(),
            dead_zone_softness_v: 0.0,
            output: OutputMap::Identity,
            offset_um: 0.0,
            creep: Vec::new(),
            calibration: Calibration::default(),
        }
    }

    /// Reads a model file; errors name the file and the key.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let m: HostModel = toml::from_str(&text)
            .with_context(|| format!("{}: not a model file", path.display()))?;
        m.validate()
            .with_context(|| format!("{}", path.display()))?;
        Ok(m)
    }

    /// Writes the model file.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = toml::to_string(self)?;
        let header = format!(
            "# A calibrated {} model (`fpi calibrate`). Units are in the key names.\n\n",
            self.kind
        );
        std::fs::write(path, header + &text).with_context(|| format!("writing {}", path.display()))
    }

    /// Checks the parameters; names the key that is wrong.
    pub fn validate(&self) -> Result<()> {
        if self.format != FORMAT {
            bail!("format = {:?}: expected {FORMAT:?}", self.format);
        }
        let p = &self.pi;
        if p.thresholds_v.len() != p.weights_um_per_v.len() {
            bail!(
                "pi.weights_um_per_v has {} values for {} thresholds",
                p.weights_um_per_v.len(),
                p.thresholds_v.len()
            );
        }
        let finite = |k: &str, v: f64| -> Result<()> {
            if v.is_finite() {
                Ok(())
            } else {
                bail!("{k} = {v}: not finite")
            }
        };
        finite("pi.w0_um_per_v", p.w0_um_per_v)?;
        finite("pi.input_max_v", p.input_max_v)?;
        if p.input_max_v <= 0.0 {
            bail!("pi.input_max_v = {}: must be > 0", p.input_max_v);
        }
        let mut prev = 0.0;
        for (i, (&r, &w)) in p.thresholds_v.iter().zip(&p.weights_um_per_v).enumerate() {
            finite(&format!("pi.thresholds_v[{i}]"), r)?;
            finite(&format!("pi.weights_um_per_v[{i}]"), w)?;
            if r < prev {
                bail!("pi.thresholds_v[{i}] = {r}: thresholds must be sorted");
            }
            prev = r;
        }
        if let Some(l) = &self.ldpi {
            if l.weights_per_n.len() != p.thresholds_v.len() {
                bail!(
                    "ldpi.weights_per_n has {} values for {} thresholds",
                    l.weights_per_n.len(),
                    p.thresholds_v.len()
                );
            }
        } else if self.kind == Kind::Ldpi {
            bail!("kind = \"ldpi\" needs an [ldpi] section");
        }
        for (j, c) in self.creep.iter().enumerate() {
            if !(c.tau_s.is_finite() && c.tau_s > 0.0 && c.gain_um_per_v.is_finite()) {
                bail!("creep[{j}]: tau_s must be > 0 and gain_um_per_v finite");
            }
        }
        Ok(())
    }

    /// Operators of the PI part.
    pub fn operators(&self) -> usize {
        self.pi.thresholds_v.len()
    }

    /// A state at rest for recordings sampled every `dt_s` seconds.
    pub fn state(&self, dt_s: f64) -> ModelState {
        ModelState {
            y: vec![0.0; self.operators()],
            m: vec![0.0; self.creep.len()],
            rate: self
                .creep
                .iter()
                .map(|c| -(-dt_s / c.tau_s).exp_m1())
                .collect(),
        }
    }

    /// The preload offset `U_p(F)` (the reverse voltage), V, and its slope, V/N.
    pub fn preload_offset(&self, force: f64) -> (f64, f64) {
        match self.kind {
            Kind::Fpi | Kind::Efpi => {
                let c = &self.coupling;
                let d = force - c.force_q_n;
                (
                    c.offset_v + c.k_f_v_per_n * force + c.k_q_v_per_n2 * d * d,
                    c.k_f_v_per_n + 2.0 * c.k_q_v_per_n2 * d,
                )
            }
            _ => (0.0, 0.0),
        }
    }

    /// Evaluates one sample without committing the state: voltage `u` (V), force
    /// `force` (N, read from the preload map at the extension guess), the map's
    /// slope there `dforce` (N/µm), and the compliance reference `force_ref` (N).
    pub fn peek(&self, st: &ModelState, u: f64, force: f64, dforce: f64, force_ref: f64) -> Peek {
        let p = &self.pi;
        // Effective voltage and its first and second derivatives along the extension
        // guess (the preload map is linear in one FEM segment; U_p is quadratic in F).
        let (e, de, dde) = if self.kind.uses_force() && self.kind != Kind::Ldpi {
            let (up, dup) = self.preload_offset(force);
            let ddup = 2.0 * self.coupling.k_q_v_per_n2;
            (u - up, -dup * dforce, -ddup * dforce * dforce)
        } else {
            (u, 0.0, 0.0)
        };
        let softness = self.dead_zone_softness_v;
        let (g, dg) = dead_zone(softness, e);
        let (uh, duh, clamped) = if g < 0.0 {
            (0.0, 0.0, true)
        } else if g > p.input_max_v {
            (p.input_max_v, 0.0, true)
        } else {
            (g, dg * de, false)
        };
        let piecewise_linear = softness <= 0.0 && self.output == OutputMap::Identity;
        // The e-interval of this linear piece: the dead-zone edge and the domain end…
        let (mut lo, mut hi) = if e <= 0.0 {
            (f64::NEG_INFINITY, 0.0)
        } else if e >= p.input_max_v {
            (p.input_max_v, f64::INFINITY)
        } else {
            (0.0, p.input_max_v)
        };
        let linear_inside = piecewise_linear && e > 0.0 && e < p.input_max_v;
        // …or, for smooth models, the û-interval without a clamp or the hard edge.
        let (mut u_lo, mut u_hi) = if piecewise_linear || clamped || (softness <= 0.0 && e <= 0.0) {
            (uh, uh) // none, or on an edge: empty
        } else {
            (f64::NEG_INFINITY, p.input_max_v)
        };
        let smooth_inside = u_lo < u_hi;
        // Weights (LDPI: affine in the force).
        let (w0, dw0) = match &self.ldpi {
            Some(l) => (p.w0_um_per_v + l.w0_per_n * force, l.w0_per_n * dforce),
            None => (p.w0_um_per_v, 0.0),
        };
        let mut y_sum = w0 * uh;
        let mut slope = w0; // dY/dû
        let mut dy_w = dw0 * uh; // change through the weights (LDPI)
        for (i, (&r, &y)) in p.thresholds_v.iter().zip(&st.y).enumerate() {
            let dragged = uh - r;
            let (v, active) = if dragged > y {
                (dragged, true)
            } else if uh < y {
                (uh, true)
            } else {
                (y, false)
            };
            // …and the operator's switch points: dragged above y + r, pushed below y.
            // At a switch point itself the slope taken here is one side's only: the
            // interval is empty there.
            if linear_inside {
                (lo, hi) = narrow_to(lo, hi, e, [y + r, y]);
            } else if smooth_inside {
                (u_lo, u_hi) = narrow_to(u_lo, u_hi, uh, [y + r, y]);
            }
            let mut w = p.weights_um_per_v[i];
            if let Some(l) = &self.ldpi {
                w += l.weights_per_n[i] * force;
                dy_w += l.weights_per_n[i] * dforce * v;
            }
            y_sum += w * v;
            if active {
                slope += w;
            }
        }
        for ((c, &m), &rate) in self.creep.iter().zip(&st.m).zip(&st.rate) {
            y_sum += c.gain_um_per_v * (m + rate * (uh - m));
            slope += c.gain_um_per_v * rate;
        }
        let (z, dz) = self.output.apply(y_sum + self.offset_um);
        let c = if self.kind.uses_force() {
            self.coupling.compliance_um_per_n
        } else {
            0.0
        };
        // Second derivative inside a smooth piece: the PI is linear in û there, so the
        // curvature comes from U_p (through `dde`), the soft dead zone and the output map.
        let dy = slope * duh + dy_w;
        let ddx = if smooth_inside {
            let ddg = if softness > 0.0 {
                dg * (1.0 - dg) / softness
            } else {
                0.0
            };
            let dduh = ddg * de * de + dg * dde;
            self.output.curvature(dz) * dy * dy + dz * slope * dduh
        } else {
            0.0
        };
        Peek {
            x: z - c * (force - force_ref),
            dx: dz * dy - c * dforce,
            uh,
            e: (e, de),
            linear_in: piecewise_linear.then_some((lo, hi)),
            duh,
            ddx,
            smooth_in: smooth_inside.then_some((u_lo, u_hi)),
        }
    }

    /// Commits one sample with the effective voltage a [`peek`](Self::peek) found.
    pub fn commit(&self, st: &mut ModelState, uh: f64) {
        for (&r, y) in self.pi.thresholds_v.iter().zip(st.y.iter_mut()) {
            *y = (uh - r).max(uh.min(*y));
        }
        for (m, &rate) in st.m.iter_mut().zip(&st.rate) {
            *m += rate * (uh - *m);
        }
    }

    /// Forward model with a known force (the rig, where force is measured):
    /// advances the state and returns the stack extension, µm.
    pub fn step(&self, st: &mut ModelState, u: f64, force: f64, force_ref: f64) -> f64 {
        let p = self.peek(st, u, force, 0.0, force_ref);
        self.commit(st, p.uh);
        p.x
    }

    /// The PI with this sample's creep folded into `w0`, and its closed-form inverse.
    pub fn inverse_pi(&self, st: &ModelState) -> PiF64 {
        let mut pi = PiF64 {
            w0: self.pi.w0_um_per_v,
            r: self.pi.thresholds_v.clone(),
            w: self.pi.weights_um_per_v.clone(),
            input_max: self.pi.input_max_v,
        };
        pi.w0 += self
            .creep
            .iter()
            .zip(&st.rate)
            .map(|(c, r)| c.gain_um_per_v * r)
            .sum::<f64>();
        pi.inverse()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn efpi() -> HostModel {
        let mut m = HostModel::new(
            Kind::Efpi,
            PiParams {
                w0_um_per_v: 0.06,
                thresholds_v: vec![10.0, 30.0, 60.0],
                weights_um_per_v: vec![0.01, 0.008, 0.004],
                input_max_v: 150.0,
            },
        );
        m.coupling = CouplingParams {
            offset_v: -0.4,
            k_f_v_per_n: 0.106,
            k_q_v_per_n2: 1.6e-4,
            force_q_n: 75.0,
            compliance_um_per_n: 0.02,
        };
        m.dead_zone_softness_v = 1.8;
        m.output = OutputMap::Saturation {
            beta_per_um: 0.0037,
        };
        m.creep = vec![CreepParams {
            tau_s: 0.01,
            gain_um_per_v: 0.003,
        }];
        m
    }

    /// The efpi model after a short history with reversals (operators held apart).
    fn efpi_driven() -> (HostModel, ModelState) {
        let m = efpi();
        let mut st = m.state(2e-4);
        for u in [20.0, 60.0, 45.0] {
            m.step(&mut st, u, 80.0, 61.8);
        }
        (m, st)
    }

    #[test]
    fn peek_derivative_matches_finite_differences() {
        let (m, st) = efpi_driven();
        let (f0, df) = (85.0, 4.5);
        let h = 1e-6;
        let a = m.peek(&st, 50.0, f0 - df * h, df, 61.8);
        let b = m.peek(&st, 50.0, f0 + df * h, df, 61.8);
        let mid = m.peek(&st, 50.0, f0, df, 61.8);
        let fd = (b.x - a.x) / (2.0 * h);
        assert!((fd - mid.dx).abs() < 1e-6, "{fd} vs {}", mid.dx);
        assert!(mid.dx < 0.0);
    }

    #[test]
    fn peek_curvature_matches_finite_differences() {
        let (m, st) = efpi_driven();
        // Deep in the stroke, and at the soft dead zone's edge (e ≈ 1 V), where the
        // curvature is largest.
        let df = 4.5;
        for (u, f0) in [(50.0, 85.0), (9.5, 80.0), (8.0, 75.0)] {
            let h = 1e-4;
            let at = |d: f64| m.peek(&st, u, f0 + df * d, df, 61.8);
            let (a, mid, b) = (at(-h), at(0.0), at(h));
            assert!(mid.smooth_in.is_some() && mid.linear_in.is_none());
            let fd = (b.dx - a.dx) / (2.0 * h);
            assert!(
                (fd - mid.ddx).abs() < 1e-6 * (1.0 + fd.abs()),
                "u {u}: {fd} vs {}",
                mid.ddx
            );
            assert!(mid.ddx != 0.0, "u {u}: the model is curved there");
        }
    }

    #[test]
    fn output_maps_invert() {
        for map in [
            OutputMap::Saturation { beta_per_um: 0.004 },
            OutputMap::Quadratic {
                gamma_per_um: -0.0014,
            },
            OutputMap::Identity,
        ] {
            for y in [0.0, 1.0, 7.5, 14.0] {
                let (z, _) = map.apply(y);
                assert!((map.invert(z) - y).abs() < 1e-12, "{map:?} {y}");
            }
        }
        assert!((dead_zone_inverse(1.8, dead_zone(1.8, -3.0).0) + 3.0).abs() < 1e-9);
    }

    #[test]
    fn model_files_round_trip() {
        let m = efpi();
        let dir = std::env::temp_dir().join(format!("hmodel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.toml");
        m.write(&p).unwrap();
        assert_eq!(HostModel::read(&p).unwrap(), m);
    }
}
