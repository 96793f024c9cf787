//! The lever chain's parameters (`--params LEVER.toml`): Table 5's geometry, the
//! output arm, the reflections and the load, with the checks of what they allow.

use super::*;

/// Table 5's dimensions (all mm) and the initial angular position of eq. 9.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Geometry {
    /// X₁₂: points 1 → 2, horizontal, mm.
    pub x12_mm: f64,
    /// Y₁₂: points 1 → 2, vertical, mm.
    pub y12_mm: f64,
    /// R₁₂: distance of points 1 and 2, mm (eq. 12; must match `hypot(X₁₂, Y₁₂)`).
    pub r12_mm: f64,
    /// Rb₁: movement radius of lever 1 (where the stack pushes it), mm.
    pub rb1_mm: f64,
    /// X₁₃: points 1 → 3, horizontal, mm.
    pub x13_mm: f64,
    /// Y₁₃: points 1 → 3, vertical, mm.
    pub y13_mm: f64,
    /// Rb₂: movement radius of lever 2 (its face's offset from point 3), mm.
    pub rb2_mm: f64,
    /// R₃₄: distance of points 3 and 4, mm.
    pub r34_mm: f64,
    /// X₃₅: points 3 → 5, horizontal, mm.
    pub x35_mm: f64,
    /// Y₃₅: points 3 → 5, vertical, mm.
    pub y35_mm: f64,
    /// Rb₃: movement radius of lever 3, mm.
    pub rb3_mm: f64,
    /// α₀: initial angular position of eq. 9, degrees (not given by the paper).
    pub alpha0_deg: f64,
}

impl Default for Geometry {
    fn default() -> Self {
        Self {
            x12_mm: 60.43,
            y12_mm: 13.0,
            r12_mm: 61.81,
            rb1_mm: 2.0,
            x13_mm: 65.31,
            y13_mm: 20.50,
            rb2_mm: 4.36,
            r34_mm: 30.0,
            x35_mm: 36.0,
            y35_mm: 0.044,
            rb3_mm: 4.48,
            alpha0_deg: TABLE5_ALPHA0_DEG,
        }
    }
}

/// The output axis's arm, for the arc-length column.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputArm {
    /// Radius at which the output's arc length is written, mm.
    pub radius_mm: f64,
}

impl Default for OutputArm {
    fn default() -> Self {
        Self { radius_mm: 1.0 }
    }
}

/// How the output load reaches the stack.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum Reflection {
    /// Eq. 12: the ratio `R₁₂·R₃₄/(Rb₁·L₁·L₂)`.
    #[default]
    #[serde(rename = "eq12")]
    Eq12,
    /// Virtual work: the slope `|dα_out/dx|` of eqs. 8–11.
    #[serde(rename = "virtual-work")]
    VirtualWork,
}

impl Reflection {
    /// The name the parameter file uses.
    pub fn name(self) -> &'static str {
        match self {
            Self::Eq12 => "eq. 12",
            Self::VirtualWork => "virtual-work",
        }
    }
}

/// The load on the stage: the stack's own preload and the load at the output.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Load {
    /// The stack's assembly preload with no output load, N.
    #[serde(rename = "stack_preload_N")]
    pub stack_preload_n: f64,
    /// Constant external torque at the output axis, N·mm.
    #[serde(rename = "torque_Nmm")]
    pub torque_nmm: f64,
    /// Torsional stiffness of an external spring at the output, N·mm/rad.
    #[serde(rename = "stiffness_Nmm_per_rad")]
    pub stiffness_nmm_per_rad: f64,
    /// How the load reaches the stack (eq. 12 by default).
    pub reflection: Reflection,
}

impl Default for Load {
    fn default() -> Self {
        Self {
            stack_preload_n: 30.0,
            torque_nmm: 2.0,
            stiffness_nmm_per_rad: 2.0,
            reflection: Reflection::Eq12,
        }
    }
}

/// A lever stage's parameters (the `--params` file).
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LeverParams {
    /// Table 5 and α₀.
    pub geometry: Geometry,
    /// The output arm of the arc-length column.
    pub output: OutputArm,
    /// The load.
    pub load: Load,
}

/// What a key's value must be.
#[derive(Clone, Copy)]
enum Rule {
    /// Any finite number.
    Finite,
    /// A finite number > 0.
    Positive,
    /// A finite number ≥ 0.
    NonNegative,
}

impl LeverParams {
    /// Reads and validates a parameter file; errors name the file and the key.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow!("{}: cannot read: {e}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parameters from the text of a file named `name` (for messages).
    pub fn parse(text: &str, name: &str) -> Result<Self> {
        let p: Self = toml::from_str(text).map_err(|e| {
            anyhow!(piezo_sim::quote::toml_error(
                name,
                "lever parameter file",
                text,
                &e
            ))
        })?;
        p.validate().map_err(|e| anyhow!("{name}: {e}"))?;
        Ok(p)
    }

    /// The keys and their values, with the rule each follows.
    fn keys(&self) -> [(&'static str, f64, Rule); 16] {
        let (g, l) = (&self.geometry, &self.load);
        use Rule::*;
        [
            ("geometry.x12_mm", g.x12_mm, Finite),
            ("geometry.y12_mm", g.y12_mm, Finite),
            ("geometry.r12_mm", g.r12_mm, Positive),
            ("geometry.rb1_mm", g.rb1_mm, Positive),
            ("geometry.x13_mm", g.x13_mm, Finite),
            ("geometry.y13_mm", g.y13_mm, Finite),
            ("geometry.rb2_mm", g.rb2_mm, Positive),
            ("geometry.r34_mm", g.r34_mm, Positive),
            ("geometry.x35_mm", g.x35_mm, Finite),
            ("geometry.y35_mm", g.y35_mm, Finite),
            ("geometry.rb3_mm", g.rb3_mm, Positive),
            ("geometry.alpha0_deg", g.alpha0_deg, Finite),
            ("output.radius_mm", self.output.radius_mm, Positive),
            ("load.stack_preload_N", l.stack_preload_n, Finite),
            ("load.torque_Nmm", l.torque_nmm, Finite),
            (
                "load.stiffness_Nmm_per_rad",
                l.stiffness_nmm_per_rad,
                NonNegative,
            ),
        ]
    }

    /// Checks every value; the error starts with the key (`geometry.rb1_mm = -2: …`).
    pub fn validate(&self) -> Result<(), String> {
        for (key, v, rule) in self.keys() {
            let why = match rule {
                Rule::Finite if !v.is_finite() => "must be a finite number",
                Rule::Positive if !(v.is_finite() && v > 0.0) => "must be a finite number > 0",
                Rule::NonNegative if !(v.is_finite() && v >= 0.0) => "must be a finite number ≥ 0",
                _ => continue,
            };
            return Err(format!("{key} = {}: {why}", Num(v)));
        }
        if self.geometry.alpha0_deg.abs() > 360.0 {
            let a = self.geometry.alpha0_deg;
            return Err(format!(
                "geometry.alpha0_deg = {}: an angle within ±360°",
                Num(a)
            ));
        }
        self.geometry.check_r12()?;
        self.geometry.pose(0.0).map(|_| ())
    }
}
