//! Every key of the firmware model file, declared once.
//!
//! One line of `declare!` per key gives its name ([`Field`]), its key in the
//! file, its unit, the core's format it is stored in, its range, its default and
//! its one-line doc, and where the model image carries it. From that line come:
//!
//! - the key every error names ([`Field::key`], through [`crate::error::Invalid`]),
//!   and the file's reader in `piezo-sim` (which quantises by the `Field`, not by a
//!   string of its own);
//! - the validator's static range checks: the constants it checks against
//!   ([`crate::model::WATCH_SWING_MIN`], [`crate::feedback::KP_MAX`],
//!   [`crate::model::MIN_RATE_HZ`], …) are read from the declared ranges
//!   ([`Decl::bits`]), at compile time;
//! - the image's blocks: [`Decl::image`] names the block (and its header flag)
//!   that carries the key, and a host test changes every declared key of a full
//!   model file and checks that its image changes and reads back;
//! - the reference page (`fpi reference model`), and a test that the file's
//!   sections (`piezo_sim::file`) hold exactly the declared keys.
//!
//! A range that depends on other keys (a mode below the Nyquist frequency of
//! `controller.rate_hz`) is declared as the rule the validator checks, in words.
//! Text keys (`format`, `provenance.*`, every section's `notes`) are no
//! quantity and are documented where the file's sections are.

/// One of the lookup tables of a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TableId {
    /// Preload `f_F`.
    FF,
    /// Kinematics `f_K`.
    FK,
    /// Inverse kinematics `f_K⁻¹`.
    FKInv,
    /// The soft dead zone `g`.
    DeadZone,
    /// Its inverse.
    DeadZoneInverse,
    /// The output saturation `h`.
    Saturation,
    /// Its inverse.
    SaturationInverse,
}

impl TableId {
    /// The table's key in the model file.
    pub const fn key(self) -> &'static str {
        match self {
            Self::FF => "tables.f_f",
            Self::FK => "tables.f_k",
            Self::FKInv => "tables.f_k_inv",
            Self::DeadZone => "dead_zone.forward",
            Self::DeadZoneInverse => "dead_zone.inverse",
            Self::Saturation => "saturation.forward",
            Self::SaturationInverse => "saturation.inverse",
        }
    }
}

/// A part of a lookup table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TablePart {
    /// The first knot.
    X0,
    /// The knot spacing.
    StepLog2,
    /// The values at the knots.
    Values,
}

/// Flag: the model has a soft dead zone (two tables).
pub const FLAG_DEAD_ZONE: u16 = 1;

/// Flag: the model has an output saturation (two tables).
pub const FLAG_SATURATION: u16 = 2;

/// Flag: the force comes from `f_F` of the reference, not the sensor.
pub const FLAG_PREDICTED: u16 = 4;

/// Flag: the model carries position-feedback settings (a block after the tables).
pub const FLAG_FEEDBACK: u16 = 8;

/// Flag: the model carries a reference-shaping filter (a block after the feedback's).
pub const FLAG_SHAPING: u16 = 16;

/// Flag: the model declares the stage's dynamics (a block after the shaping's).
pub const FLAG_DYNAMICS: u16 = 32;

/// Flag: the model carries active-damping settings (a block after the dynamics').
pub const FLAG_DAMPING: u16 = 64;

/// Flag: the shaping runs ahead of the tracked reference (a block after the
/// damping's; version-2 images without it read as before).
pub const FLAG_PREVIEW: u16 = 128;

/// Flag: the model carries the lead's baseline (a block after the preview's;
/// version-2 images without it read as before).
pub const FLAG_LEAD: u16 = 256;

/// Flag: the model carries the oscillation watch's half swing on the tracking
/// error (a block after the lead's; version-2 images without it read as before).
pub const FLAG_WATCH: u16 = 512;

/// The core's format a key is stored in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Q {
    /// Its name: `I16F16`, `u32`, `I0F32 per tick`, …
    pub name: &'static str,
    /// Fractional bits of the stored value (0 for an integer).
    pub frac: u32,
}

impl Q {
    /// Signals: µm, V, N (±4096, 15 µ LSB).
    pub const I16F16: Self = Self::fixed("I16F16", 16);
    /// Loop gains and filter coefficients (±128).
    pub const I8F24: Self = Self::fixed("I8F24", 24);
    /// PI weights and creep gains, µm/V (±8).
    pub const I4F28: Self = Self::fixed("I4F28", 28);
    /// The lead's ratio (±2).
    pub const I2F30: Self = Self::fixed("I2F30", 30);
    /// Couplings and ratios (±0.5).
    pub const I0F32: Self = Self::fixed("I0F32", 32);
    /// A corner or a time constant, stored as its rate per control tick.
    pub const PER_TICK: Self = Self::fixed("I0F32 per tick", 32);
    /// A slew, stored as volts per control tick.
    pub const V_PER_TICK: Self = Self::fixed("I16F16 per tick", 16);
    /// A frequency stored in millihertz.
    pub const MILLIHERTZ: Self = Self::fixed("u32 mHz", 0);
    /// An unsigned integer.
    pub const U32: Self = Self::fixed("u32", 0);
    /// A small integer.
    pub const U8: Self = Self::fixed("u8", 0);
    /// A table's knot spacing, stored as a shift.
    pub const SHIFT: Self = Self::fixed("u32 shift", 0);
    /// A choice, stored as a flag of the image's header.
    pub const FLAG: Self = Self::fixed("header flag", 0);
    /// Used by the host tools only, never quantised.
    pub const HOST: Self = Self::fixed("f64 (host)", 0);

    const fn fixed(name: &'static str, frac: u32) -> Self {
        Self { name, frac }
    }
}

/// The values a key may take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    /// Whatever its format holds (finite).
    Format,
    /// From `lo` to `hi`, both included, in the key's unit; checked at the
    /// value's format ([`Decl::bits`]).
    Within(f64, f64),
    /// A rule that depends on other keys, as the validator checks it.
    Rule(&'static str),
}

/// Where the model image carries a key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Image {
    /// In the body every image has.
    Body,
    /// In an optional block, present when the header's flag is set.
    Block {
        /// The block's name in [`crate::model::image`]'s layout.
        name: &'static str,
        /// Its header flag.
        flag: u16,
    },
    /// As a header flag alone.
    Flag(u16),
    /// Not at all: the host tools use it (to derive a key that is carried).
    Host,
}

/// One key's declaration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decl {
    /// The file's key, `section.key`; `creep[].tau_s` in an array of tables.
    pub key: &'static str,
    /// Its unit (`""`: dimensionless).
    pub unit: &'static str,
    /// The format it is stored in.
    pub q: Q,
    /// The values it may take.
    pub range: Range,
    /// Its value when absent; `None`: required (where its section is there).
    pub default: Option<&'static str>,
    /// What it holds, one line.
    pub doc: &'static str,
    /// Where the image carries it.
    pub image: Image,
}

impl Decl {
    /// The declared range in the stored format's raw bits, `(lo, hi)`, each
    /// rounded towards zero (as the file's reader quantises); the format's
    /// extremes for a range that is not static. Evaluated at compile time where
    /// the validator's constants are taken from it.
    pub const fn bits(&self) -> (i64, i64) {
        match self.range {
            Range::Within(lo, hi) => {
                let one = (1u64 << self.q.frac) as f64;
                ((lo * one) as i64, (hi * one) as i64)
            }
            _ => (i64::MIN, i64::MAX),
        }
    }
}

const fn block(name: &'static str, flag: u16) -> Image {
    Image::Block { name, flag }
}

const FEEDBACK: Image = block("feedback", FLAG_FEEDBACK);
const SHAPING: Image = block("shaping", FLAG_SHAPING);
const PREVIEW: Image = block("preview", FLAG_PREVIEW);
const DYNAMICS: Image = block("dynamics", FLAG_DYNAMICS);
const DAMPING: Image = block("damping", FLAG_DAMPING);

/// Declares the model's fields: `Name { key, unit, Q, range, default, image }`
/// under the field's one-line doc.
macro_rules! declare {
    ($(
        #[doc = $doc:literal]
        $name:ident { $key:literal, $unit:literal, $q:ident, $range:expr, $default:expr, $image:expr }
    )*) => {
        /// Where in a model a value lives: a key of the model file, without the
        /// index ([`Field::decl`] is its declaration).
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub enum Field {
            $( #[doc = $doc] $name, )*
            /// The number of play operators (and of thresholds and weights).
            Operators,
            /// The number of creep terms.
            Creep,
            /// A part of a table.
            Table(TableId, TablePart),
            /// The model as a whole (format, version, length, checksum).
            Model,
        }

        impl Field {
            /// Every declared key's field, in the file's order.
            pub const DECLARED: &'static [Field] = &[$(Field::$name),*];

            /// Every field that is one key of the file: the declared ones, then
            /// every part of every table (`tables.f_f.x0`, …).
            pub fn keyed() -> impl Iterator<Item = Field> {
                let tables = TableId::ALL
                    .into_iter()
                    .flat_map(|id| TablePart::ALL.map(|p| Field::Table(id, p)));
                Field::DECLARED.iter().copied().chain(tables)
            }

            /// The field's declaration. `Operators` and `Creep` are the lengths of
            /// arrays declared elsewhere (`pi.thresholds_v`, `creep[]`); a table
            /// part is declared per part ([`TablePart::decl`]) under its table's key.
            pub const fn decl(self) -> Decl {
                match self {
                    $(Field::$name => Decl {
                        key: $key,
                        unit: $unit,
                        q: Q::$q,
                        range: $range,
                        default: $default,
                        doc: $doc,
                        image: $image,
                    },)*
                    Field::Operators => Decl {
                        key: self.key(),
                        unit: "",
                        q: Q::U8,
                        range: Range::Rule("at most MAX_OPERATORS (32) play operators"),
                        default: None,
                        doc: " The number of play operators (and of thresholds and weights).",
                        image: Image::Body,
                    },
                    Field::Creep => Decl {
                        key: self.key(),
                        unit: "",
                        q: Q::U8,
                        range: Range::Rule("at most MAX_CREEP_TERMS (8) terms"),
                        default: Some("none"),
                        doc: " The number of creep terms.",
                        image: Image::Body,
                    },
                    Field::Table(id, part) => part.decl(id),
                    Field::Model => Decl {
                        key: self.key(),
                        unit: "",
                        q: Q::U32,
                        range: Range::Format,
                        default: None,
                        doc: " The model as a whole (format, version, length, checksum).",
                        image: Image::Body,
                    },
                }
            }

            /// The model file's key (a table's part is added by `Display`). A
            /// match of its own, not [`Field::decl`]'s: the board names keys in
            /// its errors, and `decl`'s docs and rules would cost it flash.
            pub const fn key(self) -> &'static str {
                match self {
                    $(Field::$name => $key,)*
                    Field::Operators => "pi.thresholds_v",
                    Field::Creep => "creep",
                    Field::Table(id, _) => id.key(),
                    Field::Model => "model",
                }
            }
        }
    };
}

declare! {
    /// Linear weight `w0` of the PI model.
    PiW0 { "pi.w0_um_per_v", "µm/V", I4F28, Range::Rule("> 0; every partial sum w0 + w_1 + … + w_j > 0"), None, Image::Body }
    /// The play operators' thresholds `r_i`, non-decreasing.
    PiThresholds { "pi.thresholds_v", "V", I16F16, Range::Rule("non-decreasing, within [0, pi.input_max_v]"), None, Image::Body }
    /// The play operators' weights `w_i`.
    PiWeights { "pi.weights_um_per_v", "µm/V", I4F28, Range::Rule("every partial sum w0 + w_1 + … + w_j > 0; Σ|w|·input_max within ±4096 µm"), None, Image::Body }
    /// The PI model's input domain `[0, input_max_v]`.
    PiInputMax { "pi.input_max_v", "V", I16F16, Range::Rule("> 0, within the signal range"), None, Image::Body }
    /// Constant part `k0` of the preload offset.
    CouplingOffset { "coupling.offset_v", "V", I16F16, Range::Format, Some("0"), Image::Body }
    /// Force–voltage coupling `k_f`: the stack responds to `u − k_f·F_p`.
    CouplingKf { "coupling.k_f_v_per_n", "V/N", I0F32, Range::Format, None, Image::Body }
    /// Curvature `k_q` of the preload offset.
    CouplingKq { "coupling.k_q_v_per_n2", "V/N²", I0F32, Range::Within(-0.001_953_125, 0.001_953_125), Some("0"), Image::Body }
    /// Centre `F_q` of the curvature term.
    CouplingForceQ { "coupling.force_q_n", "N", I16F16, Range::Format, Some("0"), Image::Body }
    /// Stack compliance (0 for the first paper's FPI).
    CouplingCompliance { "coupling.compliance_um_per_n", "µm/N", I0F32, Range::Format, Some("0"), Image::Body }
    /// Force at zero extension: the stage's rest preload.
    CouplingForceRef { "coupling.force_ref_n", "N", I16F16, Range::Format, None, Image::Body }
    /// A creep term's time constant `τ`.
    CreepTau { "creep[].tau_s", "s", PER_TICK, Range::Rule("> 0; its rate per tick within I0F32 at controller.rate_hz"), None, Image::Body }
    /// A creep term's gain `b`.
    CreepGain { "creep[].gain_um_per_v", "µm/V", I4F28, Range::Rule("w0 with every creep gain keeps the PI's output in range"), None, Image::Body }
    /// The control task's rate.
    Rate { "controller.rate_hz", "Hz", U32, Range::Within(100.0, 200_000.0), None, Image::Body }
    /// Lowest amplifier setpoint.
    UMin { "controller.u_min_v", "V", I16F16, Range::Rule("below controller.u_max_v"), None, Image::Body }
    /// Highest amplifier setpoint.
    UMax { "controller.u_max_v", "V", I16F16, Range::Rule("above controller.u_min_v"), None, Image::Body }
    /// Largest setpoint slew.
    Slew { "controller.slew_v_per_ms", "V/ms", V_PER_TICK, Range::Rule("> 0; at most I_max/C with current_limit_ma and capacitance_uf"), None, Image::Body }
    /// Lowest reachable reference, of stage output.
    ReferenceMin { "controller.reference_min_um", "µm", I16F16, Range::Rule("below reference_max_um, within the f_K⁻¹ table"), None, Image::Body }
    /// Highest reachable reference, of stage output.
    ReferenceMax { "controller.reference_max_um", "µm", I16F16, Range::Rule("above reference_min_um, within the f_K⁻¹ table"), None, Image::Body }
    /// Lowest plausible force reading.
    ForceMin { "controller.force_min_n", "N", I16F16, Range::Rule("below force_max_n"), None, Image::Body }
    /// Highest plausible force reading.
    ForceMax { "controller.force_max_n", "N", I16F16, Range::Rule("above force_min_n"), None, Image::Body }
    /// Largest tolerated `|F − f_F(x̂_pea)|` of the force's slow part.
    ForceTolerance { "controller.force_tolerance_n", "N", I16F16, Range::Rule("> 0, at most a quarter of the force window"), None, Image::Body }
    /// The setpoint of the safe state.
    SafeVoltage { "controller.safe_voltage_v", "V", I16F16, Range::Rule("within [u_min_v, u_max_v]"), None, Image::Body }
    /// Where the FPI's force comes from: `"measured"` (the sensor) or `"predicted"` (`f_F` of the reference).
    ForceSource { "controller.force_source", "", FLAG, Range::Rule("\"measured\" or \"predicted\""), None, Image::Flag(FLAG_PREDICTED) }
    /// The amplifier's output current limit: with the capacitance it bounds the slew to `I_max / C`.
    CurrentLimit { "controller.current_limit_ma", "mA", HOST, Range::Rule("> 0, with capacitance_uf"), Some("no bound"), Image::Host }
    /// The stack's capacitance (`fpi identify`).
    Capacitance { "controller.capacitance_uf", "µF", HOST, Range::Rule("> 0, with current_limit_ma"), Some("no bound"), Image::Host }
    /// Corner of the force channel's split: below it the FPI uses the measured force, above it the FEM's preload.
    ForceSplit { "controller.force_split_hz", "Hz", PER_TICK, Range::Rule("0 (no split) or up to rate_hz/64"), Some("10 Hz (at most rate_hz/64)"), Image::Body }
    /// Largest tolerated `|F − f_F(x̂_pea)|` at once, the dynamic force included.
    ForceDynamicLimit { "controller.force_dynamic_limit_n", "N", I16F16, Range::Rule("at least force_tolerance_n, at most the force window"), Some("DYNAMIC_LIMIT_FACTOR × force_tolerance_n"), Image::Body }
    /// Position feedback: proportional gain, µm per µm of error.
    FeedbackKp { "feedback.kp", "", I8F24, Range::Within(0.0, 16.0), None, FEEDBACK }
    /// Position feedback: integral gain (`ki_per_s / rate_hz` per tick, at most 1).
    FeedbackKi { "feedback.ki_per_s", "1/s", I8F24, Range::Rule("0 to rate_hz (0–1 per tick); not 0 with kp = 0"), None, FEEDBACK }
    /// Largest correction the feedback adds to the reference.
    FeedbackLimit { "feedback.limit_um", "µm", I16F16, Range::Rule("> 0"), None, FEEDBACK }
    /// Lowest plausible position reading.
    PositionMin { "feedback.position_min_um", "µm", I16F16, Range::Rule("below position_max_um"), None, FEEDBACK }
    /// Highest plausible position reading.
    PositionMax { "feedback.position_max_um", "µm", I16F16, Range::Rule("above position_min_um"), None, FEEDBACK }
    /// Largest tolerated `|x_sensor − f_K(x̂_pea)|`.
    PositionTolerance { "feedback.position_tolerance_um", "µm", I16F16, Range::Rule("> 0, at most a quarter of the position window"), None, FEEDBACK }
    /// The oscillation watch's half swing on the tracking error (`fpi board autotune` sets it from the noise at rest).
    WatchSwing { "feedback.watch_swing_um", "µm", I16F16, Range::Within(0.075, 0.2), Some("0.2 µm"), block("watch", FLAG_WATCH) }
    /// The shaping filter's sections `[b0, b1, b2, a1, a2]`, each of static gain 1.
    Shaping { "shaping.sections", "", I8F24, Range::Rule("at most two sections, poles inside the unit circle"), Some("none"), SHAPING }
    /// Ticks the shaping runs ahead of the reference the loops track (then its taps, not sections).
    PreviewTicks { "shaping.preview_ticks", "ticks", U8, Range::Within(0.0, 7.0), Some("0 (no preview)"), PREVIEW }
    /// The preview's taps on the delay line, newest first, summing to 1.
    Preview { "shaping.taps", "", I8F24, Range::Rule("at most TAPS (16), summing to 1, with preview_ticks > 0"), Some("none"), PREVIEW }
    /// The stage's first mode: natural frequency, small-signal, undamped.
    DynamicsModeHz { "dynamics.mode_hz", "Hz", MILLIHERTZ, Range::Rule("from 1 Hz to below rate_hz/2"), None, DYNAMICS }
    /// The first mode's damping ratio.
    DynamicsDamping { "dynamics.damping_ratio", "", I0F32, Range::Rule("within (0, 0.5)"), None, DYNAMICS }
    /// The amplifier's and sensors' lag as a real pole.
    DynamicsLagHz { "dynamics.lag_hz", "Hz", MILLIHERTZ, Range::Rule("above mode_hz"), Some("no lag"), DYNAMICS }
    /// κ: the dynamic force per µm of command well above the mode (active damping needs it).
    DynamicsForceGain { "dynamics.force_gain_n_per_um", "N/µm", I16F16, Range::Rule("≥ 0; > 0 with [damping]"), Some("not measured"), DYNAMICS }
    /// IFF gain: µm of command per N·s of dynamic force.
    DampingGain { "damping.gain_um_per_n_s", "µm/(N·s)", I8F24, Range::Rule("±128 µm/N per tick; needs [dynamics] with force_gain_n_per_um > 0"), None, DAMPING }
    /// Corner of the high-pass below which the damping stops integrating.
    DampingHighpass { "damping.highpass_hz", "Hz", PER_TICK, Range::Rule("> 0, up to rate_hz/64"), None, DAMPING }
    /// Corner of the damping integrator's leak.
    DampingLeak { "damping.leak_hz", "Hz", PER_TICK, Range::Rule("> 0, up to rate_hz/64"), None, DAMPING }
    /// Largest correction the damping adds to the command.
    DampingLimit { "damping.limit_um", "µm", I16F16, Range::Rule("> 0"), None, DAMPING }
    /// The lead's baseline `α_b`: the ratio the board's fit of the explained force settles at on the tuned stage.
    LeadBaseline { "damping.lead_baseline", "", I2F30, Range::Within(0.5, 2.0), Some("1 (no scaling)"), block("lead", FLAG_LEAD) }
}

impl TablePart {
    /// The declaration of this part of table `id`.
    pub const fn decl(self, id: TableId) -> Decl {
        let image = match id {
            TableId::FF | TableId::FK | TableId::FKInv => Image::Body,
            TableId::DeadZone | TableId::DeadZoneInverse => Image::Flag(FLAG_DEAD_ZONE),
            TableId::Saturation | TableId::SaturationInverse => Image::Flag(FLAG_SATURATION),
        };
        let (q, range, doc) = match self {
            Self::X0 => (Q::I16F16, Range::Format, " First knot, input unit."),
            Self::StepLog2 => (
                Q::SHIFT,
                Range::Within(-15.0, 0.0),
                " Knot spacing is 2^step_log2 input units.",
            ),
            Self::Values => (
                Q::I16F16,
                Range::Rule("2..=4096 knots, monotone"),
                " Values at the knots, output unit.",
            ),
        };
        Decl {
            key: id.key(),
            unit: "",
            q,
            range,
            default: None,
            doc,
            image,
        }
    }

    /// The part's key after its table's: `x0`, `step_log2`, `values`.
    pub const fn key(self) -> &'static str {
        match self {
            Self::X0 => "x0",
            Self::StepLog2 => "step_log2",
            Self::Values => "values",
        }
    }

    /// Every part.
    pub const ALL: [Self; 3] = [Self::X0, Self::StepLog2, Self::Values];
}

impl TableId {
    /// Every table, in the file's order.
    pub const ALL: [Self; 7] = [
        Self::DeadZone,
        Self::DeadZoneInverse,
        Self::Saturation,
        Self::SaturationInverse,
        Self::FF,
        Self::FK,
        Self::FKInv,
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_declared_key_is_one_field_s() {
        for f in [Field::Operators, Field::Creep, Field::Model] {
            assert_eq!(f.key(), f.decl().key);
        }
        for (i, a) in Field::DECLARED.iter().enumerate() {
            assert_eq!(a.key(), a.decl().key);
            for b in &Field::DECLARED[i + 1..] {
                assert_ne!(a.key(), b.key(), "{a:?} and {b:?}");
            }
            let d = a.decl();
            assert!(d.key.contains('.'), "{}", d.key);
            assert!(!d.doc.trim().is_empty(), "{}", d.key);
        }
    }

    #[test]
    fn a_static_range_rounds_towards_zero_in_its_format() {
        assert_eq!(Field::WatchSwing.decl().bits(), (4915, 13_107));
        assert_eq!(Field::Rate.decl().bits(), (100, 200_000));
        assert_eq!(Field::LeadBaseline.decl().bits(), (1 << 29, 1 << 31));
        assert_eq!(Field::Model.decl().bits(), (i64::MIN, i64::MAX));
    }

    #[test]
    fn the_checks_that_keep_their_own_constant_agree_with_the_declaration() {
        let q = crate::q::QUAD_MAX_BITS;
        assert_eq!(Field::CouplingKq.decl().bits(), (-q, q));
        let ki = Field::FeedbackKi.decl();
        assert_eq!(ki.q.frac, crate::q::LOOP_GAIN_FRAC);
    }
}
