//! Orders for the emulated board's virtual bench: fault injection and the
//! virtual stage (a real board refuses them).

use serde::de::SeqAccess;
use serde::ser::SerializeTuple;
use serde::{Deserialize, Serialize};

use crate::link::LinkKind;
use crate::wire::{field, Tagged};

crate::wire_enum! {
    /// The kinds of [`BenchOrder`]: its wire numbers.
    pub enum BenchKind {
        /// [`BenchOrder::SensorOpen`].
        SensorOpen = 0,
        /// [`BenchOrder::SensorStuck`].
        SensorStuck = 1,
        /// [`BenchOrder::Analog`].
        Analog = 2,
        /// [`BenchOrder::SensorOffset`].
        SensorOffset = 3,
        /// [`BenchOrder::Stall`].
        Stall = 4,
        /// [`BenchOrder::DamageStored`].
        DamageStored = 5,
        /// [`BenchOrder::PositionOpen`].
        PositionOpen = 6,
        /// [`BenchOrder::PositionStuck`].
        PositionStuck = 7,
        /// [`BenchOrder::Stage`].
        Stage = 8,
        /// [`BenchOrder::Link`].
        Link = 9,
        /// [`BenchOrder::FrontEnd`].
        FrontEnd = 10,
        /// [`BenchOrder::TriggerIn`].
        TriggerIn = 11,
    }
}

crate::wire_enum! {
    /// The analog front end a board converts with ([`Hello::front_end`](crate::Hello::front_end));
    /// the emulated board's is set by [`BenchOrder::FrontEnd`].
    pub enum FrontEndKind {
        /// The STM32's on-chip converters: a 12-bit ADC for the force sensor
        /// (0.125 N a count), the 12-bit DAC for the setpoint (36.6 mV of the
        /// 0–150 V amplifier a code), the position channel's 16-bit code.
        Internal = 0,
        /// The precision front end: an AD5791 20-bit DAC for the setpoint
        /// (143 µV a code) and an AD7606 16-bit ADC for the force (7.8 mN a code)
        /// and position (1.22 nm a code) sensors, with its transition noise.
        Precision = 1,
    }
}

impl FrontEndKind {
    /// Its name as the command line spells it (`internal`, `precision`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Internal => "internal",
            Self::Precision => "precision",
        }
    }

    /// The kind a command-line name stands for.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }
}

/// Orders for the emulated board's virtual bench (a real board refuses them);
/// on the wire its [`BenchKind`] byte, then its value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BenchOrder {
    /// The force sensor's wire is open (the reading sits on the ADC's top rail), or intact.
    SensorOpen(bool),
    /// The force sensor freezes at its present reading, or follows the stage again.
    SensorStuck(bool),
    /// The analog reference input reads this many ADC counts.
    Analog(u16),
    /// The force sensor's reading is offset by this much (N, `I16F16` bits): a
    /// sudden step, as a loose connector or a knock would cause.
    SensorOffset(i32),
    /// The next this-many control ticks take longer than the control period (the
    /// emulated board burns time in its control task): a loop that cannot keep
    /// its rate.
    Stall(u16),
    /// Damage the newest model stored in flash (one byte cleared), to see the
    /// board refuse it at its next start.
    DamageStored,
    /// The position sensor's wire is open (the reading sits on a rail), or intact.
    PositionOpen(bool),
    /// The position sensor freezes at its present reading, or follows the stage again.
    PositionStuck(bool),
    /// Replace the virtual stage by a fresh one at rest: the nominal twin of
    /// stage A or the stage as built (kinematics, preload and creep a few percent
    /// off the model, a lightly damped first mode, position sensor noise), with
    /// any of their values replaced. Send it with the stage parked.
    Stage(StageVariant),
    /// Pace the link as this one: its rate each way and its latency
    /// ([`LinkKind::bytes_per_s`], [`LinkKind::latency_us`]) in board time, so
    /// the emulated board's recorder drops what a real board's would. The
    /// emulated board starts paced as [`LinkKind::Uart`].
    Link(LinkKind),
    /// Convert with this front end from now on, both the virtual stage's side
    /// (the converters' resolution and noise) and the firmware's (the scale it
    /// turns codes into newtons, micrometres and volts with). The emulated board
    /// starts with [`FrontEndKind::Internal`]; a reset returns to it.
    FrontEnd(FrontEndKind),
    /// Raise the trigger input for this many control ticks from the tick the
    /// order is taken on (a pulse: its rising edge is that tick's).
    TriggerIn(u16),
}

impl BenchOrder {
    /// Its kind (wire number).
    pub const fn kind(&self) -> BenchKind {
        match self {
            Self::SensorOpen(_) => BenchKind::SensorOpen,
            Self::SensorStuck(_) => BenchKind::SensorStuck,
            Self::Analog(_) => BenchKind::Analog,
            Self::SensorOffset(_) => BenchKind::SensorOffset,
            Self::Stall(_) => BenchKind::Stall,
            Self::DamageStored => BenchKind::DamageStored,
            Self::PositionOpen(_) => BenchKind::PositionOpen,
            Self::PositionStuck(_) => BenchKind::PositionStuck,
            Self::Stage(_) => BenchKind::Stage,
            Self::Link(_) => BenchKind::Link,
            Self::FrontEnd(_) => BenchKind::FrontEnd,
            Self::TriggerIn(_) => BenchKind::TriggerIn,
        }
    }
}

impl<'de> Tagged<'de> for BenchOrder {
    const NAME: &'static str = "a bench order";

    fn kind(&self) -> u8 {
        BenchOrder::kind(self).to_u8()
    }

    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error> {
        match self {
            Self::SensorOpen(on)
            | Self::SensorStuck(on)
            | Self::PositionOpen(on)
            | Self::PositionStuck(on) => t.serialize_element(on),
            Self::Analog(n) | Self::Stall(n) => t.serialize_element(n),
            Self::SensorOffset(x) => t.serialize_element(x),
            Self::DamageStored => Ok(()),
            Self::Stage(v) => t.serialize_element(v),
            Self::Link(l) => t.serialize_element(l),
            Self::FrontEnd(f) => t.serialize_element(f),
            Self::TriggerIn(ticks) => t.serialize_element(ticks),
        }
    }

    fn read<A: SeqAccess<'de>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error> {
        let Some(kind) = BenchKind::from_u8(kind) else {
            return Ok(None);
        };
        Ok(Some(match kind {
            BenchKind::SensorOpen => Self::SensorOpen(field(a)?),
            BenchKind::SensorStuck => Self::SensorStuck(field(a)?),
            BenchKind::Analog => Self::Analog(field(a)?),
            BenchKind::SensorOffset => Self::SensorOffset(field(a)?),
            BenchKind::Stall => Self::Stall(field(a)?),
            BenchKind::DamageStored => Self::DamageStored,
            BenchKind::PositionOpen => Self::PositionOpen(field(a)?),
            BenchKind::PositionStuck => Self::PositionStuck(field(a)?),
            BenchKind::Stage => Self::Stage(field(a)?),
            BenchKind::Link => Self::Link(field(a)?),
            BenchKind::FrontEnd => Self::FrontEnd(field(a)?),
            BenchKind::TriggerIn => Self::TriggerIn(field(a)?),
        }))
    }
}

crate::tagged_serde!(BenchOrder);

/// A virtual stage: a base and the values that replace the base's (`None`: the
/// base's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct StageVariant {
    /// The stage as built (`true`) or the nominal twin.
    pub built: bool,
    /// First mode, Hz (the nominal twin has none: quasi-static).
    pub mode_hz: Option<f32>,
    /// Its damping ratio.
    pub mode_damping: Option<f32>,
    /// Kinematics relative to the FEM's `f_K`.
    pub output_gain: Option<f32>,
    /// Preload relative to the FEM's `f_F`.
    pub force_scale: Option<f32>,
    /// Creep relative to the model's.
    pub creep_scale: Option<f32>,
    /// Position sensor noise (standard deviation), µm.
    pub position_noise_um: Option<f32>,
    /// Force sensor noise (standard deviation), N.
    pub force_noise_n: Option<f32>,
}

impl StageVariant {
    /// The nominal twin.
    pub const NOMINAL: Self = Self {
        built: false,
        mode_hz: None,
        mode_damping: None,
        output_gain: None,
        force_scale: None,
        creep_scale: None,
        position_noise_um: None,
        force_noise_n: None,
    };
    /// The stage as built.
    pub const BUILT: Self = Self {
        built: true,
        ..Self::NOMINAL
    };

    /// The keys a variant may change (a variant file's, `fpi board bench`'s),
    /// each with the range its value must lie in, in [`Self::values`]'s order.
    pub const KEYS: [(&'static str, (f32, f32)); 7] = [
        ("mode_hz", (100.0, 5000.0)),
        ("mode_damping", (0.001, 0.5)),
        ("output_gain", (0.5, 2.0)),
        ("force_scale", (0.5, 1.5)),
        ("creep_scale", (0.0, 5.0)),
        ("position_noise_um", (0.0, 1.0)),
        ("force_noise_n", (0.0, 10.0)),
    ];

    /// The values, in [`Self::KEYS`]'s order (`None`: the base's).
    pub const fn values(&self) -> [Option<f32>; 7] {
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

    /// Each value that is given, by its key, with the range it must lie in: the
    /// one check of a variant, for the host's file reader and the board.
    pub fn check(&self) -> Result<(), (&'static str, f32, (f32, f32))> {
        for ((key, (lo, hi)), v) in Self::KEYS.into_iter().zip(self.values()) {
            if let Some(v) = v {
                if !(v >= lo && v <= hi) {
                    return Err((key, v, (lo, hi)));
                }
            }
        }
        Ok(())
    }
}
