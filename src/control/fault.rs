//! The faults the controller latches, and what each one means for the park.

/// Why the controller went to its safe state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Fault {
    /// The force reading is outside the sensor's plausible range (open or shorted wire, saturated ADC).
    ForceOutOfRange = 1,
    /// The force reading disagrees with `f_F(x_pea_est)` by more than the tolerance (stuck or drifting sensor).
    ForceImplausible = 2,
    /// The reference lies outside the stage's reachable stroke.
    ReferenceUnreachable = 3,
    /// The application parked the stage in its safe state (at start-up, after a
    /// model change, or on a host's `safe` command); the next motion command
    /// re-arms it.
    Stopped = 4,
    /// The host controlling the stage fell silent for longer than its heartbeat timeout.
    LinkLost = 5,
    /// The analog reference input left its range or jumped implausibly (open or shorted wire).
    ReferenceInput = 6,
    /// Control ticks kept starting before the previous one had finished (the loop
    /// cannot keep its rate).
    Overrun = 7,
    /// In closed loop, the position sensor's reading is outside its plausible range
    /// (open or shorted wire, saturated ADC).
    PositionOutOfRange = 8,
    /// In closed loop, the position sensor disagrees with the model's estimate of
    /// where the stage is by more than the tolerance (stuck or drifting sensor).
    PositionImplausible = 9,
    /// The loops' correction oscillates (a stage that changed, a wrong model:
    /// the loop is no longer stable on the stage it runs on).
    Oscillation = 10,
    /// The command stayed at a limit (voltage, slew or stroke) for longer than a
    /// loop may: the stage cannot follow what the loop asks.
    Saturated = 11,
    /// A precision converter failed: the sensor ADC's conversions stopped
    /// completing (BUSY high at the read of too many ticks in a row) or an SPI
    /// transaction with the ADC or the setpoint DAC failed.
    Converter = 12,
}

impl Fault {
    /// Every fault, by code.
    pub const ALL: [Fault; 12] = [
        Self::ForceOutOfRange,
        Self::ForceImplausible,
        Self::ReferenceUnreachable,
        Self::Stopped,
        Self::LinkLost,
        Self::ReferenceInput,
        Self::Overrun,
        Self::PositionOutOfRange,
        Self::PositionImplausible,
        Self::Oscillation,
        Self::Saturated,
        Self::Converter,
    ];

    /// A one-line description for logs.
    pub const fn message(&self) -> &'static str {
        match self {
            Self::ForceOutOfRange => "force reading outside the sensor range",
            Self::ForceImplausible => "force reading disagrees with the FEM preload map",
            Self::ReferenceUnreachable => "reference outside the reachable stroke",
            Self::Stopped => "parked in the safe state (start-up, new model or stop command)",
            Self::LinkLost => "host link lost: no heartbeat within the timeout",
            Self::ReferenceInput => "analog reference input out of range or implausible",
            Self::Overrun => "control ticks overran their period",
            Self::PositionOutOfRange => "position sensor reading outside its range",
            Self::PositionImplausible => "position sensor disagrees with the model's estimate",
            Self::Oscillation => "the loop oscillates (the stage or its model changed)",
            Self::Saturated => "the loop stayed saturated: the stage cannot follow",
            Self::Converter => {
                "a sensor ADC or setpoint DAC stopped answering (stalled or SPI error)"
            }
        }
    }

    /// Whether a park after this fault may keep the active damping running
    /// ([`crate::limits::OutputLimits::park_damped`]): where neither the force
    /// sensor nor the damping law can be the fault's cause, and the loop's
    /// timing and the model's force map still hold.
    ///
    /// * Kept: [`Oscillation`](Self::Oscillation) (the position loop is
    ///   dropped by the park; the application keeps the damping only if the
    ///   swing the watch caught was the tracking error, not the damping's own
    ///   correction), [`Stopped`](Self::Stopped), [`LinkLost`](Self::LinkLost),
    ///   [`ReferenceUnreachable`](Self::ReferenceUnreachable),
    ///   [`ReferenceInput`](Self::ReferenceInput) and
    ///   [`PositionOutOfRange`](Self::PositionOutOfRange) (the damping reads
    ///   the force, not the position).
    /// * Dropped: [`ForceOutOfRange`](Self::ForceOutOfRange) and
    ///   [`ForceImplausible`](Self::ForceImplausible) (the damping's own sensor
    ///   is suspect), [`Overrun`](Self::Overrun) (a loop whose ticks come late
    ///   has more delay than it was designed for),
    ///   [`PositionImplausible`](Self::PositionImplausible) and
    ///   [`Saturated`](Self::Saturated) (the stage no longer matches the model
    ///   whose preload map the damping's dynamic force is taken against, or the
    ///   output cannot follow), [`Converter`](Self::Converter) (the force
    ///   reading may be stale or the converter dead).
    pub const fn damps_park(&self) -> bool {
        match self {
            Self::Oscillation
            | Self::Stopped
            | Self::LinkLost
            | Self::ReferenceUnreachable
            | Self::ReferenceInput
            | Self::PositionOutOfRange => true,
            Self::ForceOutOfRange
            | Self::ForceImplausible
            | Self::Overrun
            | Self::PositionImplausible
            | Self::Saturated
            | Self::Converter => false,
        }
    }

    /// The fault with code `code` (its `repr(u8)` value).
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|f| *f as u8 == code)
    }
}
