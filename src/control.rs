//! The control step the ISR calls: reference and measured force in, amplifier setpoint out.
//!
//! ```text
//! r         = F_read − f_F(x_pea_est)              the reading against the FEM's preload
//! p         = r_0 + b·(f_F(x_pea_est) − f_F(x_0))  the preload map's offset and scale error (x_0: the tare's)
//! r_s      ← r_s + a·(r − p − r_s)                 what is left, its slow part (a first-order low-pass)
//! r_0      ← r_0 + μ_0·r_s,  b ← b + μ·r_s·(f_F(x_pea_est) − f_F(x_0))   learned as the stage moves (|b| ≤ 0.25)
//! F         = f_F(x_pea_est) + p + r_s              the force the FPI uses; r_d = r − p − r_s: the dynamic force
//! x_pea_ref = f_K⁻¹(x_ref)                        stage → stack, lookup
//! u         = PI⁻¹[x_pea_ref + c·(F - F_ref)] + k_f·F   closed-form inverse FPI
//! u_out     = limits(u)                            range and slew
//! x_pea_est = Y[u_out - k_f·F] - c·(F - F_ref)     forward FPI: virtual position sensor
//! ```
//!
//! **The force channel** ([`ForceChannel`], [`ControllerConfig::sense`]). A force
//! sensor in series with the stack reads the preload *and* the dynamic force of
//! the stage's modes. Fed straight into the inverse, the dynamic part closes a
//! positive loop through the stack (more force, more voltage, more force) whose
//! gain is `1 + k_f·k_p·dY/dû` above the first mode — unstable on a stiff stack.
//! So the FPI takes the measured force only below the split's corner (its slow
//! part `r_s` added to the FEM's preload at the estimated extension) and the FEM's
//! map above it; the dynamic part `r_d` is what active damping uses
//! ([`crate::damping`]). A built stage's preload differs from its FEM's by a few
//! percent, in offset and in scale; both are learned (a least-mean-squares fit
//! of the slow part against the FEM's preload change, from the tare's offset), so
//! that a move leaves no static force in `r_d` — which the damping's integrator
//! would otherwise turn into a slow tail.
//! With the split off (`a = 0`) the reading is used as it is and `r_d = 0`; a
//! model's default is a 10 Hz corner ([`DEFAULT_SPLIT_HZ`]).
//!
//! | quantity | unit | format |
//! |---|---|---|
//! | `r`, `p`, `r_d`, `r_0` | N | `I16F16` |
//! | `r_s`, `r_0` (state) | N | `I16F48` (raw `i64`) plus 2⁻¹⁷ (half an `I16F16` LSB), so that the high word is the rounded `I16F16` value |
//! | `b` | 1 | `I0F32` (raw `i32`), held to `[−0.25, 0.25 − 2⁻³²]` |
//! | `μ`, `μ_0` | 1/N² and 1 per tick | 2⁻¹⁸ ([`SCALE_ADAPT_SHIFT`]), 2⁻¹¹ ([`OFFSET_ADAPT_SHIFT`]) |
//!
//! The scale's step `μ·r_s·Δ` takes `r_s` held to ±32 N and `Δ` to ±2048 N
//! ([`SCALE_ERROR_MAX_BITS`], [`DELTA_MAX_BITS`]), so that it is one 32 × 32 → 64
//! multiply whose shifted product fits 32 bits: a slow part beyond 32 N (far
//! beyond any tolerance a stage is run with) learns the scale no faster than one
//! of 32 N.
//!
//! A reading that stays the same to the bit while the FEM's preload at the
//! estimated extension moves by more than the tolerance is a stuck sensor
//! ([`Fault::ForceImplausible`]): neither the learned map nor the split's
//! low-pass can hide it.
//!
//! The virtual sensor's stage position `f_K(x_pea_est)` is a lookup the ISR does
//! not need; telemetry consumers get it from [`ControllerConfig::stage_position`].
//!
//! **The forward FPI runs only when it tells something.** With the paper's bare
//! FPI, while the limits pass the inverse's voltage, the forward model of that
//! voltage returns `x_pea_ref` (the closed-form inverse is exact: up to
//! rounding, held to the model's range, [`crate::fpi::Fpi::reached`]). The step
//! then skips the forward bank and lets it lag; when the drive departs from the
//! inverse's (the limits, a fault's park, the uncompensated drive), the forward
//! bank is first rebuilt from the inverse bank as it was before the step
//! ([`crate::fpi::Fpi::forward_from_inverse`]; see [`ControllerState`]). A
//! limited step then runs the forward bank on the applied voltage and does the
//! inverse's step again, from the same state, with the extension that voltage
//! produced: the inverse bank then holds the applied voltage's memory (the
//! closed-form inverse is exact), as the general path's resync gives it, for
//! the price of one bank's step. On the unit tests' stage, over 6000 steps with
//! 831 limited ones, a fault and its park, the drive is the eager forward
//! bank's to the bit and the estimate within one LSB
//! (`the_lagging_forward_bank_gives_the_eager_ones_drive_and_estimate`). It
//! spares the ordinary step one bank (6 instructions per operator) and the
//! bank's set-up; the first limited step after ordinary ones pays the rebuild.
//! A model with creep, a soft dead zone or a saturation runs both banks every
//! step.
//!
//! Configuration ([`ControllerConfig`], in flash) is separate from state
//! ([`ControllerState`], the operator memories and the last output, in the ISR).
//!
//! **Safe state.** A force reading outside the sensor's plausible range, a force
//! that disagrees with the FEM preload map `f_F` at the estimated extension by
//! more than a tolerance, or a reference outside the reachable stroke latches a
//! [`Fault`]: from then on every step ramps the output to the safe voltage along
//! a gentle park profile (a piezo stack must not be discharged with a step, and a
//! stage's first mode must not be set ringing: [`crate::limits`]) and reports the
//! fault, until [`ControllerState::clear_fault`] is called once the ramp is done.

use crate::error::{Field, Invalid, ModelError};
use crate::fpi::{CreepMemory, Fpi, Identity, Shape};
use crate::limits::OutputLimits;
use crate::play::{Bottom, PlayBank, Redo, Stepped, Top};
use crate::q::{
    narrow_inv_gain, CreepRate, InvGainAcc, Micrometres, Newtons, Volts, VoltsPerUm, INV_GAIN_FRAC,
    SIGNAL_ABS_MAX_BITS,
};
use crate::table::Table;

/// A closed interval `[lo, hi]` of one quantity, `I16F16`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interval {
    /// Lower end.
    pub lo: fixed::types::I16F16,
    /// Upper end.
    pub hi: fixed::types::I16F16,
}

/// A validated interval (`lo <= hi`) as its lower end and its span, raw bits: `x`
/// lies in it iff `(x - lo) mod 2^32 <= span`, one unsigned compare.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Window {
    lo: i32,
    span: u32,
}

impl Window {
    /// `None` if the interval is inverted.
    pub(crate) const fn new(i: Interval) -> Option<Self> {
        let (lo, hi) = (i.lo.to_bits(), i.hi.to_bits());
        if lo > hi {
            return None;
        }
        Some(Self {
            lo,
            span: hi.wrapping_sub(lo) as u32,
        })
    }

    #[inline(always)]
    pub(crate) fn contains(&self, x: fixed::types::I16F16) -> bool {
        self.contains_bits(x.to_bits())
    }

    #[inline(always)]
    pub(crate) fn contains_bits(&self, x: i32) -> bool {
        (x.wrapping_sub(self.lo) as u32) <= self.span
    }
}

/// What the controller supervises, and where it goes when something is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Supervision {
    /// Reachable references (µm of stage output); anything else is a fault.
    pub reference: Interval,
    /// Plausible force readings (N); anything else is a fault.
    pub force: Interval,
    /// Largest tolerated `|F - f_F(x_pea_est)|` (N).
    pub force_tolerance: Newtons,
    /// Voltage of the safe state (V), inside the limits.
    pub safe_voltage: Volts,
    /// Measured or predicted preload.
    pub force_source: ForceSource,
    /// How the reading is split into its slow and dynamic parts, and the dynamic
    /// limit.
    pub channel: ForceChannel,
}

/// The supervision windows a validated controller checks its inputs against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Windows {
    reference: Window,
    force: Window,
    /// `[-tolerance, tolerance]`, for the slow part of the residual `F - f_F(x_pea_est)`.
    residual: Window,
    /// `[-limit, limit]`, for the residual at once.
    dynamic: Window,
}

/// How the force reading is split and checked (configuration, see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceChannel {
    /// Per-tick rate `a` of the slow part's low-pass, `I0F32` (`1 − e^{−2π·f_c/f_s}`);
    /// 0: no split, the reading is used as it is.
    pub split: CreepRate,
    /// Largest tolerated `|F − f_F(x_pea_est)|` at once, N (the dynamic force
    /// included); the slow part is held to [`Supervision::force_tolerance`].
    pub dynamic_limit: Newtons,
}

/// The force channel's scale adaptation: `b` moves by `2⁻¹⁸·r_s·Δ` per tick
/// (N², `Δ = f_F(x̂) − f_F(x_0)`): at 20 kHz and a 10 N swing of the preload, a
/// time constant of 0.13 s. As a shift of the `I32F32` product into `b`'s
/// `I0F32`: `18 + 32 − 32` (rounded toward −∞).
pub const SCALE_ADAPT_SHIFT: u32 = 18;
/// The force channel's offset adaptation: `r_0` moves by `2⁻¹¹·r_s` per tick
/// (a time constant of 0.1 s at 20 kHz), so that an offset the tare missed (a
/// stage that settled after it) does not bias the scale.
pub const OFFSET_ADAPT_SHIFT: u32 = 11;
/// Largest learned scale error `|b|` (`I0F32` bits): 0.25 (`b` is held to
/// `[−2³⁰, 2³⁰ − 1]`, one `ssat`).
const SCALE_MAX_BITS: i32 = 1 << 30;
/// The slow part `r_s` the scale's step takes, held to `[−2²¹, 2²¹ − 1]`
/// (`I16F16` bits: ±32 N).
pub const SCALE_ERROR_MAX_BITS: i32 = 1 << 21;
/// The preload's change `Δ` the scale's step takes, held to `[−2²⁷, 2²⁷ − 1]`
/// (`I16F16` bits: ±2048 N). With [`SCALE_ERROR_MAX_BITS`], `|r_s·Δ| ≤ 2⁴⁸`:
/// the step is at most 2³⁰, and `b` plus it cannot overflow 32 bits.
pub const DELTA_MAX_BITS: i32 = 1 << 27;
/// Half an `I16F16` LSB in `I16F48` (raw `i64`): the rounding bias `r_s` and
/// `r_0` carry.
const HALF_LSB_I16F48: i64 = 1 << 31;

/// The high word of an `I16F48` (raw `i64`): the `I16F16` bits, rounded for a
/// value stored with [`HALF_LSB_I16F48`].
#[inline(always)]
const fn hi_word(x: i64) -> i32 {
    (x >> 32) as i32
}

/// The force channel's default split corner, Hz: well above the motion a preload
/// change follows, well below any first mode of a stage.
pub const DEFAULT_SPLIT_HZ: u32 = 10;

/// The force channel's split rate `a = 1 − e^{−2π·f_c/f_s}` for a corner
/// `corner_hz` at a control rate `rate_hz`, `I0F32` (its Taylor series to the fourth
/// power in integer arithmetic, exact to 10⁻⁶ of `a` up to `f_c/f_s = 1/64`); 0 for
/// a zero corner or rate, or a corner above `f_s/64`.
pub const fn split_rate(corner_hz: u32, rate_hz: u32) -> CreepRate {
    if corner_hz == 0 || rate_hz == 0 || corner_hz as u64 * 64 > rate_hz as u64 {
        return CreepRate::ZERO;
    }
    // x = 2π·f_c/f_s in units of 2⁻³²; a = x − x²/2 + x³/6 − x⁴/24.
    const TWO_PI_Q32: u128 = 26_986_075_409; // round(2π·2³²)
    let x = (TWO_PI_Q32 * corner_hz as u128 / rate_hz as u128) as i128;
    let x2 = (x * x) >> 32;
    let x3 = (x2 * x) >> 32;
    let x4 = (x3 * x) >> 32;
    let a = x - x2 / 2 + x3 / 6 - x4 / 24;
    CreepRate::from_bits(a as i32)
}

/// What the force channel gives one tick: the force the FPI uses and the dynamic
/// force, N.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Forces {
    /// The sensor's reading.
    pub reading: Newtons,
    /// `f_F(x_pea_est) + r_s`: the force the inverse and the virtual sensor use
    /// (the reading itself without a split).
    pub feedforward: Newtons,
    /// `r_d = F_read − f_F(x_pea_est) − r_s`: the dynamic force (0 without a
    /// split, or for a reading outside the sensor's range).
    pub dynamic: Newtons,
    /// The reading lies in the sensor's range.
    pub in_range: bool,
}

/// Checks a controller's settings against its limits and its `f_K⁻¹` table: the
/// reference and force intervals not inverted, the reference interval inside the
/// `f_K⁻¹` grid, the safe voltage inside the limits, a positive tolerance, and the
/// force interval and tolerance inside the signal range (±4096 N, so that the
/// residual `F - f_F` is exact in 32 bits). The one check, shared by
/// [`ControllerConfig::new`] and the model validator.
pub const fn check_settings(
    limits: &OutputLimits,
    f_k_inv: &Table<'_>,
    s: &Supervision,
) -> Result<Windows, Invalid> {
    let (reference, force) = (s.reference, s.force);
    let (force_tolerance, safe_voltage) = (s.force_tolerance, s.safe_voltage);
    let s_channel = s.channel;
    let Some(reference_window) = Window::new(reference) else {
        return Err(Invalid::at(Field::ReferenceMin, ModelError::LimitsInverted));
    };
    let Some(force_window) = Window::new(force) else {
        return Err(Invalid::at(Field::ForceMin, ModelError::LimitsInverted));
    };
    if reference.lo.to_bits() < f_k_inv.x_min().to_bits() {
        return Err(Invalid::at(
            Field::ReferenceMin,
            ModelError::ReferenceOutsideTable,
        ));
    }
    if reference.hi.to_bits() > f_k_inv.x_max().to_bits() {
        return Err(Invalid::at(
            Field::ReferenceMax,
            ModelError::ReferenceOutsideTable,
        ));
    }
    let s = safe_voltage.to_bits();
    if s < limits.min().to_bits() || s > limits.max().to_bits() {
        return Err(Invalid::at(
            Field::SafeVoltage,
            ModelError::SafeVoltageOutsideLimits,
        ));
    }
    let tol = force_tolerance.to_bits();
    if tol <= 0 {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NonPositiveTolerance,
        ));
    }
    if tol > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NotRepresentable,
        ));
    }
    if force.lo.to_bits() < -SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(Field::ForceMin, ModelError::NotRepresentable));
    }
    if force.hi.to_bits() > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(Field::ForceMax, ModelError::NotRepresentable));
    }
    let Some(residual) = Window::new(Interval {
        lo: Newtons::from_bits(-tol),
        hi: force_tolerance,
    }) else {
        return Err(Invalid::at(
            Field::ForceTolerance,
            ModelError::NonPositiveTolerance,
        ));
    };
    let dynamic = match force_channel_window(&s_channel, force_tolerance) {
        Ok(w) => w,
        Err(e) => return Err(e),
    };
    Ok(Windows {
        reference: reference_window,
        force: force_window,
        residual,
        dynamic,
    })
}

/// Where the preload in `u = PI⁻¹[…] + k_f·F` comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ForceSource {
    /// The force sensor between stack and hinge (the paper's FPI with measured force).
    Measured,
    /// The FEM preload map at the reference, `f_F(x_pea_ref)`: FPI-FFEM feedforward
    /// for a stage without a force sensor. The force argument of `step` is ignored.
    Predicted,
}

/// Which law computes the voltage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Inverse FPI compensation ([`ControllerConfig::step`]).
    Compensated,
    /// The straight-line baseline ([`ControllerConfig::step_uncompensated`]).
    Uncompensated(LinearDrive),
}

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

/// Everything the control step needs that does not change while it runs.
///
/// `N`, `C`, `G` and `H` are the model's structure (see [`Fpi`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ControllerConfig<'a, const N: usize, const C: usize = 0, G = Identity, H = Identity> {
    fpi: Fpi<'a, N, C, G, H>,
    f_f: Table<'a>,
    f_k: Table<'a>,
    f_k_inv: Table<'a>,
    limits: OutputLimits,
    reference: Interval,
    force: Interval,
    reference_window: Window,
    force_window: Window,
    /// `[-tolerance, tolerance]`, for the slow part `r_s` of the residual.
    residual_window: Window,
    /// `[-limit, limit]`, for the residual `F - f_F(x_pea_est)` at once.
    dynamic_window: Window,
    force_tolerance: Newtons,
    safe_voltage: Volts,
    force_source: ForceSource,
    channel: ForceChannel,
}

/// The parts of a [`ControllerConfig`], named, for its constructor.
#[derive(Debug, Clone, Copy)]
pub struct ControllerParts<'a, const N: usize, const C: usize = 0, G = Identity, H = Identity> {
    /// The calibrated FPI model.
    pub fpi: Fpi<'a, N, C, G, H>,
    /// Preload `f_F`: stack extension (µm) → force on the stack (N).
    pub f_f: Table<'a>,
    /// Kinematics `f_K`: stack extension (µm) → stage output (µm).
    pub f_k: Table<'a>,
    /// Inverse kinematics `f_K⁻¹`: stage output (µm) → stack extension (µm).
    pub f_k_inv: Table<'a>,
    /// Actuator range and slew.
    pub limits: OutputLimits,
    /// Supervision and safe state.
    pub supervision: Supervision,
}

impl<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>
    ControllerConfig<'a, N, C, G, H>
{
    /// Validates the parts ([`check_settings`]) and builds the configuration.
    pub const fn new(p: ControllerParts<'a, N, C, G, H>) -> Result<Self, ModelError> {
        let w = match check_settings(&p.limits, &p.f_k_inv, &p.supervision) {
            Ok(w) => w,
            Err(e) => return Err(e.error),
        };
        let v = p.supervision;
        Ok(Self {
            fpi: p.fpi,
            f_f: p.f_f,
            f_k: p.f_k,
            f_k_inv: p.f_k_inv,
            limits: p.limits,
            reference: v.reference,
            force: v.force,
            reference_window: w.reference,
            force_window: w.force,
            residual_window: w.residual,
            dynamic_window: w.dynamic,
            force_tolerance: v.force_tolerance,
            safe_voltage: v.safe_voltage,
            force_source: v.force_source,
            channel: v.channel,
        })
    }

    /// The force channel.
    pub const fn force_channel(&self) -> ForceChannel {
        self.channel
    }

    /// Takes `force` (N) as the reference force `F_ref` of the compliance term: the
    /// force at which the stage's position is zero. Call it at power-up with the
    /// sensor's reading at rest (the FEM's `f_F(0)` is a design value; the built
    /// stage differs by a few percent, and `c·ΔF_ref` is a constant position error).
    /// Only at rest and with a measured, plausible force; returns whether it took it.
    pub fn tare(&self, st: &mut ControllerState<N, C>, force: Newtons) -> bool {
        let at_rest = st.voltage == self.safe_voltage && st.fault.is_none();
        if at_rest
            && matches!(self.force_source, ForceSource::Measured)
            && self.force_window.contains(force)
        {
            st.force_ref = force;
            // The channel starts settled: the residual at rest is the offset.
            st.force_tare_model = self.f_f.eval(st.x_pea_est);
            st.forget_force_learning();
            true
        } else {
            false
        }
    }

    /// The same configuration with another force source.
    pub const fn with_force_source(mut self, source: ForceSource) -> Self {
        self.force_source = source;
        self
    }

    /// A fresh state at the safe voltage, all operators at rest: the state of
    /// this configuration (see [`ControllerState`]).
    pub const fn initial_state(&self) -> ControllerState<N, C> {
        ControllerState {
            inverse: Stepped::new(PlayBank::new()),
            forward: PlayBank::at_rest(self.fpi.pi().bank()),
            forward_lags: false,
            creep: CreepMemory::new(),
            force_ref: self.fpi.coupling().force_ref,
            voltage: self.safe_voltage,
            x_pea_est: Micrometres::ZERO,
            force_slow: HALF_LSB_I16F48,
            force_offset: HALF_LSB_I16F48,
            force_tare_model: self.fpi.coupling().force_ref,
            force_scale: 0,
            fault: None,
            force_held: Newtons::MIN,
            force_held_model: Newtons::ZERO,
            park_rate: Volts::ZERO,
            park_offset: Volts::ZERO,
            park_damping: Volts::ZERO,
            park_tick: 0,
            limited_steps: 0,
        }
    }

    /// Reads the force channel (see the module docs): the force the FPI uses and
    /// the dynamic force, from the `reading` (N) against the FEM's preload at the
    /// last estimated extension; advances the split's slow part (for a reading in
    /// the sensor's range) and latches [`Fault::ForceOutOfRange`] or
    /// [`Fault::ForceImplausible`] (the slow part beyond the tolerance, or the
    /// residual at once beyond the dynamic limit) unless a fault is latched.
    /// With a predicted force the reading is ignored. Bounded time, no panic.
    #[inline(always)]
    pub fn sense(&self, st: &mut ControllerState<N, C>, reading: Newtons) -> Forces {
        if matches!(self.force_source, ForceSource::Measured) {
            self.sense_as::<true>(st, reading)
        } else {
            self.sense_as::<false>(st, reading)
        }
    }

    /// [`sense`](Self::sense) with the force source resolved at compile time.
    ///
    /// The channel's state is kept so that the tick needs no 64-bit shift or
    /// compare: `r_s` and `r_0` carry a rounding bias of half an `I16F16` LSB in
    /// their low words (their high words are the rounded values), `r_s` advances
    /// by one multiply-accumulate (`smlal`) and `b` is an `I0F32` word
    /// (`b·Δ` one rounding `smmulr`, its clamp one `ssat`).
    #[inline(always)]
    fn sense_as<const MEASURED: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        reading: Newtons,
    ) -> Forces {
        let model = self.f_f.eval(st.x_pea_est);
        if !MEASURED {
            return Forces {
                reading,
                feedforward: model,
                dynamic: Newtons::ZERO,
                in_range: true,
            };
        }
        let in_range = self.force_window.contains(reading);
        let r = residual(reading, model).to_bits();
        let split = self.channel.split.to_bits();
        let slow = if split == 0 {
            r
        } else {
            // The learned static part: the offset and the scale error times the
            // FEM preload's change since the tare.
            let delta = residual(model, st.force_tare_model).to_bits();
            let b = st.force_scale;
            // round(b·Δ): I0F32 × I16F16 → I16F16 (`smmulr`).
            let scaled = ((b as i64 * delta as i64 + (1 << 31)) >> 32) as i32;
            let learned = hi_word(st.force_offset).wrapping_add(scaled);
            if in_range {
                // r_s += a·(r − p − r_s): I16F16 × I0F32 into I16F48 (`smlal`).
                let diff = r
                    .wrapping_sub(learned)
                    .saturating_sub(hi_word(st.force_slow));
                st.force_slow = st.force_slow.wrapping_add(diff as i64 * split as i64);
                if st.fault.is_none() {
                    // Least mean squares on the slow part: the offset and the scale.
                    let rs = hi_word(st.force_slow); // I16F16 bits of r_s
                    st.force_offset = add_shifted(st.force_offset, rs);
                    // μ·r_s·Δ as I0F32: the I32F32 product shifted by
                    // SCALE_ADAPT_SHIFT, its factors held (`ssat`) so that it
                    // stays within ±2³⁰ (see SCALE_ERROR_MAX_BITS, DELTA_MAX_BITS).
                    #[allow(clippy::manual_clamp)]
                    let rs = rs.max(-SCALE_ERROR_MAX_BITS).min(SCALE_ERROR_MAX_BITS - 1);
                    #[allow(clippy::manual_clamp)]
                    let d = delta.max(-DELTA_MAX_BITS).min(DELTA_MAX_BITS - 1);
                    let step = ((rs as i64 * d as i64) >> SCALE_ADAPT_SHIFT) as i32;
                    // max/min, not `clamp`: no panic branch on the ISR path.
                    #[allow(clippy::manual_clamp)]
                    let scale = b
                        .wrapping_add(step)
                        .max(-SCALE_MAX_BITS)
                        .min(SCALE_MAX_BITS - 1);
                    st.force_scale = scale;
                }
            }
            learned.wrapping_add(hi_word(st.force_slow))
        };
        // A reading frozen (bit for bit) while the FEM's preload at the estimate
        // moved by more than the tolerance: a stuck sensor, whatever the learned
        // map and the split's low-pass have absorbed of the residual.
        let stuck = if reading.to_bits() == st.force_held.to_bits() {
            !self
                .residual_window
                .contains(residual(model, st.force_held_model))
        } else {
            st.force_held = reading;
            st.force_held_model = model;
            false
        };
        if st.fault.is_none() {
            if !in_range {
                st.fault = Some(Fault::ForceOutOfRange);
            } else if stuck
                || !self.residual_window.contains_bits(slow)
                || !self.dynamic_window.contains_bits(r)
            {
                st.fault = Some(Fault::ForceImplausible);
            }
        }
        Forces {
            reading,
            feedforward: model.wrapping_add(Newtons::from_bits(slow)),
            dynamic: Newtons::from_bits(if in_range { r.wrapping_sub(slow) } else { 0 }),
            in_range,
        }
    }

    /// One control step. Call it once per ISR with the reference stage position
    /// (µm) and the force reading (N); write [`StepOutput::voltage`] to the
    /// amplifier. [`sense`](Self::sense), then [`step_sensed`](Self::step_sensed).
    ///
    /// Bounded time, no division, no panic, no allocation. Always inlined: the ISR
    /// calls it once, and a call would cost the ISR a frame and its spills.
    #[inline(always)]
    pub fn step(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        force: Newtons,
    ) -> StepOutput {
        // One branch on the force source and the model's structure for both the
        // channel and the step. A model received at run time has its structure
        // as a flag: its general path is out of line, so that the paper's FPI,
        // the one the ISR's budget is set for, is compiled alone.
        match (
            matches!(self.force_source, ForceSource::Measured),
            self.fpi.is_bare(),
        ) {
            (true, true) => {
                let f = self.sense_as::<true>(st, force);
                self.step_with::<true, true>(st, x_ref, &f)
            }
            (true, false) => self.step_general::<true>(st, x_ref, force),
            (false, true) => {
                let f = self.sense_as::<false>(st, force);
                self.step_with::<false, true>(st, x_ref, &f)
            }
            (false, false) => self.step_general::<false>(st, x_ref, force),
        }
    }

    /// [`step`](Self::step) for a model that is not the paper's bare FPI:
    /// inlined where the model's structure is in its type (the one path), out of
    /// line where it is a run-time flag.
    #[inline(always)]
    fn step_general<const MEASURED: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        force: Newtons,
    ) -> StepOutput {
        if G::FIXED.is_some() && H::FIXED.is_some() {
            let f = self.sense_as::<MEASURED>(st, force);
            self.step_with::<MEASURED, false>(st, x_ref, &f)
        } else {
            self.step_general_outlined::<MEASURED>(st, x_ref, force)
        }
    }

    /// [`step_general`](Self::step_general), out of line.
    #[inline(never)]
    fn step_general_outlined<const MEASURED: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        force: Newtons,
    ) -> StepOutput {
        let f = self.sense_as::<MEASURED>(st, force);
        self.step_with::<MEASURED, false>(st, x_ref, &f)
    }

    /// The control step on a force channel read this tick ([`sense`](Self::sense)):
    /// checks the reference, then the inverse FPI, the limits and the virtual
    /// sensor (or the ramp to the safe voltage once a fault is latched).
    #[inline(always)]
    pub fn step_sensed(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        f: &Forces,
    ) -> StepOutput {
        let measured = matches!(self.force_source, ForceSource::Measured);
        match (measured, self.fpi.is_bare()) {
            (true, true) => self.step_sensed_as::<true, true>(st, x_ref, f),
            (true, false) => self.step_sensed_as::<true, false>(st, x_ref, f),
            (false, true) => self.step_sensed_as::<false, true>(st, x_ref, f),
            (false, false) => self.step_sensed_as::<false, false>(st, x_ref, f),
        }
    }

    /// [`step_with`](Self::step_with), out of line for a model received at run
    /// time: compiled alone, its step keeps its registers (inlined into the
    /// board's large control task, the banks' unrolled loops lost them and
    /// reloaded their base from the stack at every operator).
    #[inline(always)]
    fn step_sensed_as<const MEASURED: bool, const BARE: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        f: &Forces,
    ) -> StepOutput {
        if G::FIXED.is_none() || H::FIXED.is_none() {
            self.step_sensed_outlined::<MEASURED, BARE>(st, x_ref, f)
        } else {
            self.step_with::<MEASURED, BARE>(st, x_ref, f)
        }
    }

    /// [`step_with`](Self::step_with), out of line.
    #[inline(never)]
    fn step_sensed_outlined<const MEASURED: bool, const BARE: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        f: &Forces,
    ) -> StepOutput {
        self.step_with::<MEASURED, BARE>(st, x_ref, f)
    }

    /// [`step_sensed`](Self::step_sensed) with the force source and whether the
    /// model is the paper's bare FPI ([`Fpi::is_bare`]) resolved at compile time.
    #[inline(always)]
    fn step_with<const MEASURED: bool, const BARE: bool>(
        &self,
        st: &mut ControllerState<N, C>,
        x_ref: Micrometres,
        forces: &Forces,
    ) -> StepOutput {
        if let Some(fault) = self.supervise(st, x_ref) {
            return self.ramp_to_safe(st, forces, fault);
        }
        // The reference passed its window, which lies inside the grid.
        let x_pea_ref = self.f_k_inv.eval_from_x_min(x_ref);
        let f = if MEASURED {
            forces.feedforward
        } else {
            self.f_f.eval(x_pea_ref)
        };
        let terms = self.fpi.force_terms_at(f, st.force_ref);
        let (want, foot) = if BARE {
            // Double-buffered: the state before this step stays at hand.
            self.fpi
                .inverse_as::<_, true>(&mut st.inverse, &st.creep, x_pea_ref, &terms)
        } else {
            // In place, at a fixed address (cheaper where the loops are not
            // unrolled): a state of this configuration is never swapped.
            let bank = st.inverse.first_mut();
            self.fpi
                .inverse_as::<_, false>(bank, &st.creep, x_pea_ref, &terms)
        };
        let (voltage, limited) = self.limits.apply(st.voltage, want);
        st.voltage = voltage;
        if BARE && !limited {
            // The drive is the inverse's: the forward bank would return the
            // reference, up to rounding. It is left to lag, and rebuilt from the
            // inverse memory when the drive next departs from the inverse's.
            let x_pea_est = self.fpi.reached(x_pea_ref, &terms);
            st.x_pea_est = x_pea_est;
            st.forward_lags = true;
            return StepOutput {
                voltage,
                x_pea_ref,
                x_pea_est,
                limited: false,
                fault: None,
            };
        }
        if BARE {
            // Limited: the forward bank from the state before this step, then
            // the inverse's step done again with the extension the applied
            // voltage produces: the inverse then holds that voltage's memory,
            // as a resync would, for the price of one bank's step.
            st.catch_up(&self.fpi, Memory::Before);
            let x_pea_est =
                self.fpi
                    .forward_as::<_, true>(&mut st.forward, &mut st.creep, voltage, &terms);
            let redo = &mut Redo(&mut st.inverse);
            self.fpi
                .inverse_as::<_, true>(redo, &st.creep, x_pea_est, &terms);
            st.x_pea_est = x_pea_est;
            st.limited_steps = st.limited_steps.wrapping_add(1);
            return StepOutput {
                voltage,
                x_pea_ref,
                x_pea_est,
                limited: true,
                fault: None,
            };
        }
        let x_pea_est =
            self.fpi
                .forward_as::<_, BARE>(&mut st.forward, &mut st.creep, voltage, &terms);
        st.x_pea_est = x_pea_est;
        if limited || foot {
            // The stack got another drive than the inverse asked for (the limits, or
            // the foot of a soft dead zone): realign the inverse memory with it.
            self.fpi.resync(&st.forward, st.inverse.first_mut());
            st.limited_steps = st.limited_steps.wrapping_add(limited as u32);
            return StepOutput {
                voltage,
                x_pea_ref,
                x_pea_est,
                limited,
                fault: None,
            };
        }
        // `limited` is known to be false here; saying so spares the ISR
        // recomputing it for the store.
        StepOutput {
            voltage,
            x_pea_ref,
            x_pea_est,
            limited: false,
            fault: None,
        }
    }

    /// The uncompensated baseline step: the same supervision, limits and virtual
    /// sensor, but the voltage comes from a straight line instead of the inverse FPI.
    /// The inverse memory follows the applied voltage, so switching back to
    /// [`step`](Self::step) is seamless.
    pub fn step_uncompensated(
        &self,
        st: &mut ControllerState<N, C>,
        drive: &LinearDrive,
        x_ref: Micrometres,
        force: Newtons,
    ) -> StepOutput {
        let f = self.sense(st, force);
        self.step_uncompensated_sensed(st, drive, x_ref, &f)
    }

    /// [`step_uncompensated`](Self::step_uncompensated) on a force channel read
    /// this tick.
    pub fn step_uncompensated_sensed(
        &self,
        st: &mut ControllerState<N, C>,
        drive: &LinearDrive,
        x_ref: Micrometres,
        forces: &Forces,
    ) -> StepOutput {
        if let Some(fault) = self.supervise(st, x_ref) {
            return self.ramp_to_safe(st, forces, fault);
        }
        let x_pea_ref = self.f_k_inv.eval(x_ref);
        let f = if matches!(self.force_source, ForceSource::Measured) {
            forces.feedforward
        } else {
            self.f_f.eval(x_pea_ref)
        };
        let (voltage, limited) = self.limits.apply(st.voltage, drive.voltage(x_ref));
        let terms = self.fpi.force_terms_at(f, st.force_ref);
        st.catch_up(&self.fpi, Memory::Now);
        let x_pea_est = self
            .fpi
            .forward(&mut st.forward, &mut st.creep, voltage, &terms);
        self.fpi.resync(&st.forward, st.inverse.now_mut());
        st.voltage = voltage;
        st.x_pea_est = x_pea_est;
        StepOutput {
            voltage,
            x_pea_ref,
            x_pea_est,
            limited,
            fault: None,
        }
    }

    /// Checks the reference (the force channel was checked by
    /// [`sense`](Self::sense)) and latches the first fault; returns the latched
    /// fault.
    #[inline]
    fn supervise(&self, st: &mut ControllerState<N, C>, x_ref: Micrometres) -> Option<Fault> {
        if st.fault.is_none() && !self.reference_window.contains(x_ref) {
            st.fault = Some(Fault::ReferenceUnreachable);
        }
        st.fault
    }

    /// The step in the safe state: ramp toward the safe voltage, keep estimating.
    fn ramp_to_safe(
        &self,
        st: &mut ControllerState<N, C>,
        forces: &Forces,
        fault: Fault,
    ) -> StepOutput {
        // The damping's correction offered for this tick, where the fault
        // leaves it running (the application offers it only then; checked here
        // again), used once.
        let damping = if fault.damps_park() {
            st.park_damping
        } else {
            Volts::ZERO
        };
        st.park_damping = Volts::ZERO;
        let (voltage, rate, offset) = self.limits.park_damped(
            st.voltage,
            st.park_offset,
            st.park_rate,
            self.safe_voltage,
            st.park_tick,
            damping,
        );
        st.park_rate = rate;
        st.park_offset = offset;
        st.park_tick = st.park_tick.saturating_add(1);
        // Trust the sensor for the estimate only if it is in range.
        let f = if matches!(self.force_source, ForceSource::Measured) && forces.in_range {
            forces.feedforward
        } else {
            self.f_f.eval(st.x_pea_est)
        };
        let terms = self.fpi.force_terms_at(f, st.force_ref);
        st.catch_up(&self.fpi, Memory::Now);
        let x_pea_est = self
            .fpi
            .forward(&mut st.forward, &mut st.creep, voltage, &terms);
        st.voltage = voltage;
        st.x_pea_est = x_pea_est;
        StepOutput {
            voltage,
            x_pea_ref: x_pea_est,
            x_pea_est,
            limited: true,
            fault: Some(fault),
        }
    }

    /// The virtual sensor's stage position for an estimated stack extension,
    /// `f_K(x_pea_est)`, µm (outside the ISR: for telemetry).
    pub fn stage_position(&self, x_pea_est: Micrometres) -> Micrometres {
        self.f_k.eval(x_pea_est)
    }

    /// The calibrated model.
    pub const fn fpi(&self) -> &Fpi<'a, N, C, G, H> {
        &self.fpi
    }
    /// Preload map `f_F`.
    pub const fn f_f(&self) -> &Table<'a> {
        &self.f_f
    }
    /// Kinematic map `f_K`.
    pub const fn f_k(&self) -> &Table<'a> {
        &self.f_k
    }
    /// Inverse kinematic map `f_K⁻¹`.
    pub const fn f_k_inv(&self) -> &Table<'a> {
        &self.f_k_inv
    }
    /// Actuator limits.
    pub const fn limits(&self) -> &OutputLimits {
        &self.limits
    }
    /// The supervision settings.
    pub const fn supervision(&self) -> Supervision {
        Supervision {
            reference: self.reference,
            force: self.force,
            force_tolerance: self.force_tolerance,
            safe_voltage: self.safe_voltage,
            force_source: self.force_source,
            channel: self.channel,
        }
    }
    /// Reachable references, µm.
    pub const fn reference(&self) -> Interval {
        self.reference
    }
    /// Plausible force readings, N.
    pub const fn force(&self) -> Interval {
        self.force
    }
    /// Largest tolerated force disagreement with `f_F`, N.
    pub const fn force_tolerance(&self) -> Newtons {
        self.force_tolerance
    }
    /// Safe-state voltage, V.
    pub const fn safe_voltage(&self) -> Volts {
        self.safe_voltage
    }
    /// Measured or predicted preload.
    pub const fn force_source(&self) -> ForceSource {
        self.force_source
    }
}

/// Which state of the double-buffered inverse bank a lagging forward bank is
/// rebuilt from: `Before` the inverse advanced in this step, or as it is `Now`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Memory {
    Now,
    Before,
}

/// What one control step produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepOutput {
    /// Amplifier setpoint, V (after range and slew limits).
    pub voltage: Volts,
    /// Stack extension the reference asks for, µm.
    pub x_pea_ref: Micrometres,
    /// Virtual sensor: estimated stack extension, µm.
    pub x_pea_est: Micrometres,
    /// The limits changed the voltage (always true in the safe state).
    pub limited: bool,
    /// The latched fault, if the controller is in its safe state.
    pub fault: Option<Fault>,
}

/// The controller's memory: both operator banks, the last output, the fault latch.
///
/// The two banks keep their gaps to opposite edges ([`crate::play::Edge`]): they
/// move in the same direction, so each step pays one cheap and one dearer update
/// per operator pair.
///
/// With the paper's bare FPI the forward bank is not advanced while the drive
/// is the inverse's (its output would be the reference): it lags, and is rebuilt
/// from the inverse bank ([`crate::fpi::Fpi::forward_from_inverse`]) when the
/// drive departs from the inverse's (the limiter, a fault, the uncompensated
/// drive). The inverse bank is double-buffered ([`Stepped`]) so that the state
/// it had before the step is still at hand then; any other model advances it
/// in place, in its first buffer.
///
/// A state belongs to the configuration that made it
/// ([`ControllerConfig::initial_state`]): its banks hold that model's operators,
/// and its layout depends on whether that model is bare. The firmware makes a
/// fresh one with each model it runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ControllerState<const N: usize, const C: usize = 0> {
    inverse: Stepped<N, Top>,
    forward: PlayBank<N, Bottom>,
    /// The forward bank lags: it holds an older state than the inverse bank's.
    forward_lags: bool,
    creep: CreepMemory<C>,
    force_ref: Newtons,
    voltage: Volts,
    x_pea_est: Micrometres,
    /// The slow part `r_s` of the force residual, N, `I16F48` (raw `i64`) plus
    /// [`HALF_LSB_I16F48`]: its high word is `r_s` rounded to `I16F16`.
    force_slow: i64,
    /// The learned offset `r_0` of the preload map, N, `I16F48` (raw `i64`) plus
    /// [`HALF_LSB_I16F48`].
    force_offset: i64,
    /// The FEM's preload at the tare, `f_F(x_0)`, N: where the scale's change
    /// `Δ` is counted from (the tared reading less the offset taken then).
    force_tare_model: Newtons,
    /// The learned scale error `b` of the preload map, `I0F32` (raw `i32`).
    force_scale: i32,
    fault: Option<Fault>,
    /// The last force reading that differed from the one before, N, and the
    /// FEM's preload at the estimate then, N (the stuck-sensor check).
    force_held: Newtons,
    force_held_model: Newtons,
    /// The rate of the park in progress, V per tick (`crate::limits::OutputLimits::park`).
    park_rate: Volts,
    /// The output's departure from the park's profile (the damping's share), V,
    /// `I16F16` (`crate::limits::OutputLimits::park_damped`); zero outside a park.
    park_offset: Volts,
    /// The damping's correction offered for the next park step, V, `I16F16`
    /// ([`ControllerState::damp_park`]); zero once used.
    park_damping: Volts,
    /// Ticks since the park began (saturating); zero outside a park.
    park_tick: u32,
    limited_steps: u32,
}

impl<const N: usize, const C: usize> ControllerState<N, C> {
    /// Brings a lagging forward bank up to the inverse bank's state, `now` or
    /// `before` this step advanced it (see [`ControllerState`]).
    #[inline(always)]
    fn catch_up<'a, G: Shape<'a>, H: Shape<'a>>(&mut self, fpi: &Fpi<'a, N, C, G, H>, at: Memory) {
        if self.forward_lags {
            self.rebuild_forward(fpi, at);
        }
    }

    /// [`catch_up`](Self::catch_up)'s rebuild, out of line: it is rare.
    #[inline(never)]
    fn rebuild_forward<'a, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        fpi: &Fpi<'a, N, C, G, H>,
        at: Memory,
    ) {
        let inverse = match at {
            Memory::Now => self.inverse.now(),
            Memory::Before => self.inverse.before(),
        };
        fpi.forward_from_inverse(inverse, &mut self.forward);
        self.forward_lags = false;
    }

    /// The slow part of the force residual beyond the learned map, N (rounded to
    /// `I16F16`).
    pub const fn force_slow(&self) -> Newtons {
        Newtons::from_bits(hi_word(self.force_slow))
    }
    /// The preload map's learned offset, N (rounded to `I16F16`).
    pub const fn force_offset(&self) -> Newtons {
        Newtons::from_bits(hi_word(self.force_offset))
    }
    /// The learned scale error of the preload map (dimensionless, ±0.25).
    pub fn force_scale(&self) -> f64 {
        self.force_scale as f64 / (1u64 << 32) as f64
    }
    /// The latched fault, if any.
    pub const fn fault(&self) -> Option<Fault> {
        self.fault
    }
    /// The last applied voltage, V.
    pub const fn voltage(&self) -> Volts {
        self.voltage
    }
    /// The last estimated stack extension, µm.
    pub const fn x_pea_est(&self) -> Micrometres {
        self.x_pea_est
    }
    /// Steps in which the limits changed the voltage (wraps).
    pub const fn limited_steps(&self) -> u32 {
        self.limited_steps
    }
    /// The reference force of the compliance term in use (N).
    pub const fn force_ref(&self) -> Newtons {
        self.force_ref
    }

    /// Latches `fault` (if none is latched yet): from the next step the controller
    /// ramps to the safe voltage, as for a fault it detects itself. For the faults
    /// the application detects (a stop command, a lost host, a bad reference input).
    /// Returns whether this fault was latched.
    pub fn trip(&mut self, fault: Fault) -> bool {
        if self.fault.is_some() {
            return false;
        }
        self.fault = Some(fault);
        true
    }

    /// Offers the active damping's correction (V, `I16F16`: the damping's µm
    /// through the small-signal slope of the drive) to the next step, if it is
    /// a park after a fault that keeps the damping ([`Fault::damps_park`];
    /// otherwise it is ignored): see
    /// [`crate::limits::OutputLimits::park_damped`]. Used by one step.
    #[inline]
    pub fn damp_park(&mut self, correction: Volts) {
        self.park_damping = correction;
    }

    /// The output's present departure from the park's profile (the damping's
    /// share), V; zero outside a park.
    pub const fn park_offset(&self) -> Volts {
        self.park_offset
    }

    /// Forgets what the force channel learned since the tare (its offset and
    /// scale back to the tare's, its slow part to zero): after a fault, what it
    /// learned may be the fault's. The slow part settles again within a few of
    /// its time constants (16 ms at the default 10 Hz split) while parked.
    pub fn forget_force_learning(&mut self) {
        let at_tare = residual(self.force_ref, self.force_tare_model);
        self.force_offset = ((at_tare.to_bits() as i64) << 32) + HALF_LSB_I16F48;
        self.force_slow = HALF_LSB_I16F48;
        self.force_scale = 0;
    }

    /// Leaves the safe state once the output has reached the safe voltage; the
    /// inverse memory is realigned with the voltage history actually applied.
    /// Returns whether the fault was cleared.
    pub fn clear_fault<'a, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
    ) -> bool {
        if self.voltage != cfg.safe_voltage {
            return false;
        }
        self.catch_up(&cfg.fpi, Memory::Now);
        cfg.fpi.resync(&self.forward, self.inverse.now_mut());
        self.fault = None;
        self.park_rate = Volts::ZERO;
        self.park_offset = Volts::ZERO;
        self.park_damping = Volts::ZERO;
        self.park_tick = 0;
        true
    }
}

/// `x + 2⁻¹¹·rs` for an `I16F48` `x` (raw `i64`) and an `I16F16` `rs` (raw
/// `i32`), exact and wrapping ([`OFFSET_ADAPT_SHIFT`]): written as its two words
/// with the carry, so that it is one `adds` and one `adc` with shifted operands.
#[inline(always)]
const fn add_shifted(x: i64, rs: i32) -> i64 {
    let (lo, carry) = (x as u32).overflowing_add((rs as u32) << (32 - OFFSET_ADAPT_SHIFT));
    let hi = ((x >> 32) as i32)
        .wrapping_add(rs >> OFFSET_ADAPT_SHIFT)
        .wrapping_add(carry as i32);
    ((hi as i64) << 32) | lo as i64
}

/// `reading − model` (N): exact for readings and maps inside ±4096 N.
#[inline(always)]
const fn residual(reading: Newtons, model: Newtons) -> Newtons {
    Newtons::from_bits(reading.to_bits().wrapping_sub(model.to_bits()))
}

/// Checks a force channel against the force tolerance: the split rate in
/// `[0, 0.5)`, the dynamic limit at least the tolerance and inside the signal
/// range. The one check, shared by [`check_settings`] and
/// the model validator.
pub const fn check_force_channel(c: &ForceChannel, tolerance: Newtons) -> Result<(), Invalid> {
    match force_channel_window(c, tolerance) {
        Ok(_) => Ok(()),
        Err(e) => Err(e),
    }
}

/// [`check_force_channel`], and the window of the dynamic limit.
const fn force_channel_window(c: &ForceChannel, tolerance: Newtons) -> Result<Window, Invalid> {
    let a = c.split.to_bits();
    if a < 0 {
        return Err(Invalid::at(
            Field::ForceSplit,
            ModelError::CreepRateOutOfRange,
        ));
    }
    let lim = c.dynamic_limit.to_bits();
    if lim < tolerance.to_bits() || lim > SIGNAL_ABS_MAX_BITS {
        return Err(Invalid::at(
            Field::ForceDynamicLimit,
            ModelError::DynamicLimitBelowTolerance,
        ));
    }
    match Window::new(Interval {
        lo: Newtons::from_bits(-lim),
        hi: c.dynamic_limit,
    }) {
        Some(w) => Ok(w),
        None => Err(Invalid::at(
            Field::ForceDynamicLimit,
            ModelError::NonPositiveTolerance,
        )),
    }
}

/// The uncompensated baseline: a straight line from the reference to the voltage,
/// `u = offset + gain·x_ref`, as an amplifier driven without a hysteresis model would be.
///
/// * `gain` — V/µm, `I10F22`; `offset` — V, `I16F16`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinearDrive {
    /// Slope, V/µm.
    pub gain: VoltsPerUm,
    /// Voltage at zero reference, V.
    pub offset: Volts,
}

impl LinearDrive {
    /// The line through `(x_lo, u_lo)` and `(x_hi, u_hi)`; for host tools and start-up code.
    pub fn through(x_lo: f64, u_lo: f64, x_hi: f64, u_hi: f64) -> Option<Self> {
        let g = (u_hi - u_lo) / (x_hi - x_lo);
        let gain = crate::q::quantize(g, crate::q::INV_GAIN_FRAC, crate::q::INV_GAIN_ABS_MAX)?;
        Some(Self {
            gain: VoltsPerUm::from_bits(gain),
            offset: crate::q::signal(u_lo - g * x_lo)?,
        })
    }

    /// The voltage for a reference (before the limits), V.
    #[inline]
    pub fn voltage(&self, x_ref: Micrometres) -> Volts {
        // Saturate the product at the signal range before narrowing it.
        let lim = (SIGNAL_ABS_MAX_BITS as i64) << INV_GAIN_FRAC;
        let acc = self.gain.wide_mul(x_ref).to_bits().max(-lim).min(lim);
        narrow_inv_gain(InvGainAcc::from_bits(acc)).saturating_add(self.offset)
    }

    /// The reference whose voltage is `voltage`, `(u − offset) / gain`, µm,
    /// saturated to the signal range; `None` for a zero gain. One division: for a
    /// switch of control law (bumpless transfer), not for every tick.
    pub fn reference_for(&self, voltage: Volts) -> Option<Micrometres> {
        let num = ((voltage.to_bits() as i64) - (self.offset.to_bits() as i64)) << INV_GAIN_FRAC;
        let x = num.checked_div(self.gain.to_bits() as i64)?;
        let lim = SIGNAL_ABS_MAX_BITS as i64;
        Some(Micrometres::from_bits(x.max(-lim).min(lim) as i32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::{self, force_at, TestController};

    /// The offset's update in two words with the carry is the `i64` one.
    #[test]
    fn the_offset_update_in_two_words_is_exact() {
        let xs = [
            0i64,
            HALF_LSB_I16F48,
            -1,
            (61i64 << 48) + 12_345,
            -(61i64 << 48) - 7,
            ((1i64 << 28) << 32) - 1,
            i64::MIN / 3,
        ];
        let rss = [
            0,
            1,
            -1,
            2047,
            -2048,
            1 << 20,
            -(1 << 28),
            i32::MAX,
            i32::MIN,
        ];
        for &x in &xs {
            for &rs in &rss {
                let want = x.wrapping_add((rs as i64) << (32 - OFFSET_ADAPT_SHIFT));
                assert_eq!(add_shifted(x, rs), want, "{x} {rs}");
            }
        }
    }

    fn with(force: Interval, tolerance: Newtons) -> Result<TestController, ModelError> {
        let p = testkit::parts(ForceSource::Measured);
        ControllerConfig::new(ControllerParts {
            supervision: Supervision {
                force,
                force_tolerance: tolerance,
                channel: ForceChannel {
                    dynamic_limit: tolerance,
                    ..p.supervision.channel
                },
                ..p.supervision
            },
            ..p
        })
    }

    /// The controller with the force channel's dynamic limit at `limit`.
    fn with_dynamic_limit(limit: f64) -> TestController {
        let p = testkit::parts(ForceSource::Measured);
        ControllerConfig::new(ControllerParts {
            supervision: Supervision {
                channel: ForceChannel {
                    dynamic_limit: n(limit),
                    ..p.supervision.channel
                },
                ..p.supervision
            },
            ..p
        })
        .unwrap()
    }

    #[test]
    fn the_split_rate_is_one_minus_exp() {
        for (fc, fs) in [
            (10, 20_000),
            (1, 100),
            (100, 20_000),
            (3, 1_000),
            (312, 20_000),
        ] {
            let a = split_rate(fc, fs).to_num::<f64>();
            let want = 1.0 - (-2.0 * core::f64::consts::PI * fc as f64 / fs as f64).exp();
            assert!((a - want).abs() < 1e-6 * want, "{fc}/{fs}: {a} vs {want}");
        }
        assert_eq!(split_rate(0, 20_000), CreepRate::ZERO);
        assert_eq!(
            split_rate(313, 20_000),
            CreepRate::ZERO,
            "beyond f_s/64: none"
        );
    }

    /// A step in the reading goes to the dynamic part at once and into the slow
    /// part at the split's rate: after one time constant 63 % of it is slow.
    #[test]
    fn the_force_channel_splits_the_reading_into_slow_and_dynamic_parts() {
        let c = with_dynamic_limit(60.0);
        let mut st = c.initial_state();
        assert!(c.tare(&mut st, n(61.0)));
        // Settled on the tare's residual: nothing dynamic at rest.
        let model = c.f_f().eval(st.x_pea_est());
        let f = c.sense(&mut st, n(61.0));
        assert_eq!(f.dynamic, Newtons::ZERO);
        assert_eq!(f.feedforward, n(61.0));
        assert_eq!(st.force_offset(), n(61.0) - model);
        assert_eq!(st.force_slow(), Newtons::ZERO);
        let tau = (20_000.0 / (2.0 * core::f64::consts::PI * 10.0)).round() as usize;
        let mut last = f;
        for _ in 0..tau {
            last = c.sense(&mut st, n(71.0));
        }
        // The low-pass alone would have taken 63 %; the learned offset takes more.
        let slow = (last.feedforward - model).to_num::<f64>() - 1.0;
        assert!(slow > 6.3 && slow < 7.5, "{slow}");
        let dynamic = last.dynamic.to_num::<f64>();
        assert!((dynamic + slow - 10.0).abs() < 1e-3, "{dynamic}");
        assert_eq!(st.fault(), None);
        // The slow part beyond the tolerance (15 N) is a fault; the dynamic limit
        // (60 N) is a fault at once.
        let mut st2 = c.initial_state();
        assert!(c.tare(&mut st2, n(61.0)));
        c.sense(&mut st2, n(61.0 + 59.0));
        assert_eq!(st2.fault(), None, "59 N at once: a dynamic force");
        c.sense(&mut st2, n(61.0 + 61.0));
        assert_eq!(
            st2.fault(),
            Some(Fault::ForceImplausible),
            "beyond 60 N at once"
        );
        let mut st3 = c.initial_state();
        assert!(c.tare(&mut st3, n(61.0)));
        let mut ticks = 0;
        while st3.fault().is_none() && ticks < 100_000 {
            c.sense(&mut st3, n(61.0 + 20.0));
            ticks += 1;
        }
        // 20 N more held: the slow part, from 1 N at the tare to 21 N, reaches 15 N
        // after ln(20/6)·τ through the low-pass alone, sooner with the offset
        // learned too.
        let low_pass = ((20.0f64 / 6.0).ln() * tau as f64).round() as i64;
        assert!(
            ticks as i64 <= low_pass && ticks as i64 > low_pass / 2,
            "{ticks} vs {low_pass}"
        );
        assert_eq!(st3.fault(), Some(Fault::ForceImplausible));
    }

    /// A built stage whose preload is 5 % below the FEM's: moving through the
    /// stroke, the channel learns the scale error, and then a fast move leaves no
    /// static force in the dynamic part.
    #[test]
    fn the_force_channel_learns_the_preload_maps_scale() {
        let c = with_dynamic_limit(60.0);
        let mut st = c.initial_state();
        let built = |c: &TestController, st: &ControllerState<3>| {
            0.95 * c.f_f().eval(st.x_pea_est()).to_num::<f64>()
        };
        let rest = n(built(&c, &st));
        assert!(c.tare(&mut st, rest));
        let mut out = None;
        for k in 0..60_000 {
            // 2 Hz over most of the test stage's stroke.
            let x = 12.0 - 10.0 * (k as f64 * 2.0 * core::f64::consts::PI * 2.0 / 20_000.0).cos();
            let f = n(built(&c, &st));
            out = Some(c.step(&mut st, um(x), f));
        }
        assert_eq!(out.unwrap().fault, None);
        let b = st.force_scale();
        // Within a fifth of the error, after 3 s of motion (the slow part lags the
        // 2 Hz motion a little, so the estimate wanders by a few thousandths).
        assert!((b + 0.05).abs() < 0.01, "learned scale error {b}");
        // A jump of the reference: the dynamic part sees only what the map's scale
        // does not explain (here nothing; the test stage has no dynamics).
        let mut worst = 0.0f64;
        for k in 0..200 {
            let x = if k < 100 { 2.0 } else { 20.0 };
            let f = n(built(&c, &st));
            let forces = c.sense(&mut st, f);
            worst = worst.max(forces.dynamic.to_num::<f64>().abs());
            c.step_sensed(&mut st, um(x), &forces);
        }
        // Without the learned scale the whole 5 % of the preload's change would be
        // left: a fifth of it at most.
        let swing = (c.f_f().eval(c.f_k_inv().eval(um(20.0)))
            - c.f_f().eval(c.f_k_inv().eval(um(2.0))))
        .to_num::<f64>();
        assert!(
            worst < 0.2 * 0.05 * swing,
            "static force left in the dynamic part: {worst} N of {:.2} N",
            0.05 * swing
        );
    }

    /// Without a split the reading is used as it is, with no dynamic part.
    #[test]
    fn without_a_split_the_reading_is_the_feedforward() {
        let p = testkit::parts(ForceSource::Measured);
        let c = ControllerConfig::new(ControllerParts {
            supervision: Supervision {
                channel: ForceChannel {
                    split: CreepRate::ZERO,
                    ..p.supervision.channel
                },
                ..p.supervision
            },
            ..p
        })
        .unwrap();
        let mut st = c.initial_state();
        let f = c.sense(&mut st, n(67.5));
        assert_eq!((f.feedforward, f.dynamic), (n(67.5), Newtons::ZERO));
        let bad = ForceChannel {
            split: CreepRate::from_bits(-1),
            dynamic_limit: n(20.0),
        };
        assert_eq!(
            check_force_channel(&bad, n(15.0)).unwrap_err().field,
            Field::ForceSplit
        );
        let low = ForceChannel {
            split: CreepRate::ZERO,
            dynamic_limit: n(10.0),
        };
        assert_eq!(
            check_force_channel(&low, n(15.0)).unwrap_err().error,
            ModelError::DynamicLimitBelowTolerance
        );
    }

    fn n(x: f64) -> Newtons {
        Newtons::from_num(x)
    }
    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    /// One step with the force the stage puts on the stack where it is.
    fn plausible(
        c: &TestController,
        st: &mut ControllerState<3>,
        x_ref: Micrometres,
    ) -> StepOutput {
        let f = force_at(c, st.x_pea_est());
        c.step(st, x_ref, f)
    }

    /// Drives the stage along a slow ramp to `x` with plausible forces.
    fn drive_to(c: &TestController, st: &mut ControllerState<3>, x: f64) -> StepOutput {
        let from = c.stage_position(st.x_pea_est()).to_num::<f64>();
        let mut out = None;
        for k in 1..=400 {
            let x_ref = from + (x - from) * k as f64 / 400.0;
            out = Some(plausible(c, st, um(x_ref)));
        }
        out.unwrap()
    }

    #[test]
    fn rejects_force_settings_outside_the_signal_range() {
        let wide = Interval {
            lo: n(0.0),
            hi: n(30000.0),
        };
        assert_eq!(with(wide, n(5.0)), Err(ModelError::NotRepresentable));
        let ok = testkit::controller().force();
        assert_eq!(with(ok, n(30000.0)), Err(ModelError::NotRepresentable));
        assert_eq!(with(ok, n(0.0)), Err(ModelError::NonPositiveTolerance));
        let inverted = Interval {
            lo: n(100.0),
            hi: n(50.0),
        };
        assert_eq!(with(inverted, n(5.0)), Err(ModelError::LimitsInverted));
        assert!(with(ok, n(5.0)).is_ok());
    }

    /// The plausibility test's window: a residual of exactly the tolerance passes,
    /// one LSB more latches the fault, on both sides.
    #[test]
    fn plausibility_tolerance_is_inclusive_on_both_sides() {
        let tol = n(5.0);
        let cfg = with(testkit::controller().force(), tol).unwrap();
        let x_ref = cfg.reference().lo + um(1.0);
        for sign in [1, -1] {
            for (extra, faults) in [(0, false), (1, true)] {
                let mut st = cfg.initial_state();
                let expected = cfg.f_f().eval(st.x_pea_est());
                let d = Newtons::from_bits(sign * (tol.to_bits() + extra));
                let out = cfg.step(&mut st, x_ref, expected + d);
                let want = faults.then_some(Fault::ForceImplausible);
                assert_eq!(out.fault, want, "sign {sign} extra {extra}");
            }
        }
    }

    #[test]
    fn compensation_follows_the_reference() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        for x in [12.0, 4.0, 24.5, 18.0] {
            let out = drive_to(&c, &mut st, x);
            assert_eq!(out.fault, None);
            let est = c.stage_position(out.x_pea_est).to_num::<f64>();
            assert!(
                (est - x).abs() < 1e-3,
                "reference {x} µm, estimate {est} µm"
            );
        }
    }

    /// The bare path leaves the forward bank lagging while the drive is the
    /// inverse's; the general path, on the same model with one disabled creep
    /// term, runs it every step. Along a history with slew-limited steps, a
    /// fault, its park and the uncompensated drive, both give the same drive and
    /// estimate within a few LSB.
    #[test]
    fn the_lagging_forward_bank_gives_the_eager_ones_drive_and_estimate() {
        let lazy = testkit::controller();
        let p = testkit::parts(ForceSource::Measured);
        let disabled = [crate::fpi::Creep::DISABLED];
        let fpi = Fpi::new(*p.fpi.pi(), *p.fpi.coupling(), Identity, Identity, disabled);
        let eager = ControllerConfig::new(ControllerParts {
            fpi: fpi.unwrap(),
            f_f: p.f_f,
            f_k: p.f_k,
            f_k_inv: p.f_k_inv,
            limits: p.limits,
            supervision: p.supervision,
        })
        .unwrap();
        assert!(lazy.fpi().is_bare() && !eager.fpi().is_bare());
        let (mut a, mut b) = (lazy.initial_state(), eager.initial_state());
        let drive = LinearDrive::through(0.0, 0.0, 25.0, 140.0).unwrap();
        let (mut dv, mut dx, mut limited) = (0.0f64, 0.0f64, 0);
        for k in 0..6000 {
            // Slow wandering, jumps the slew limit cuts, a reference out of
            // range (a fault, then its park), and the uncompensated drive.
            let x = match k {
                0..=1999 => 12.0 + 10.0 * (k as f64 * 0.01).sin() * (k as f64 * 0.0013).cos(),
                2000..=2999 => [3.0, 22.0, 9.0, 17.5][(k / 150) % 4],
                3000 => 40.0,
                _ => 12.0 + 8.0 * (k as f64 * 0.007).sin(),
            };
            let f = force_at(&lazy, a.x_pea_est());
            let (oa, ob) = if (3600..4000).contains(&k) {
                (
                    lazy.step_uncompensated(&mut a, &drive, um(x), f),
                    eager.step_uncompensated(&mut b, &drive, um(x), f),
                )
            } else {
                (lazy.step(&mut a, um(x), f), eager.step(&mut b, um(x), f))
            };
            if k == 3500 {
                assert!(a.clear_fault(&lazy) && b.clear_fault(&eager));
            }
            assert_eq!((oa.fault, oa.limited), (ob.fault, ob.limited), "step {k}");
            limited += oa.limited as u32;
            dv = dv.max((oa.voltage - ob.voltage).to_num::<f64>().abs());
            dx = dx.max((oa.x_pea_est - ob.x_pea_est).to_num::<f64>().abs());
        }
        eprintln!("lagging vs eager forward bank: {limited} limited steps, drive within {dv:.2e} V, estimate within {dx:.2e} µm");
        assert!(limited > 100);
        assert!(dv < 1e-3 && dx < 1e-4, "{dv} V, {dx} µm");
    }

    #[test]
    fn tare_takes_a_plausible_force_only_at_rest() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        // At rest, measured, in range: taken.
        assert!(c.tare(&mut st, n(61.5)));
        assert_eq!(st.force_ref(), n(61.5));
        // Out of the sensor's range: refused, the last tare stays.
        assert!(!c.tare(&mut st, n(5.0)));
        assert_eq!(st.force_ref(), n(61.5));
        // Not at rest (the output is away from the safe voltage): refused.
        drive_to(&c, &mut st, 10.0);
        assert!(!c.tare(&mut st, n(62.0)));
        // A predicted force has nothing to tare.
        let p = c.with_force_source(ForceSource::Predicted);
        let mut sp = p.initial_state();
        assert!(!p.tare(&mut sp, n(62.0)));
    }

    #[test]
    fn a_reading_frozen_while_the_preload_moves_is_a_stuck_sensor() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        drive_to(&c, &mut st, 1.0);
        // A plausible reading follows the stage: no fault all the way up.
        assert_eq!(drive_to(&c, &mut st, 24.0).fault, None);
        let frozen = force_at(&c, st.x_pea_est());
        // Frozen there, at rest: not seen (nothing to disagree with).
        for _ in 0..100 {
            assert_eq!(c.step(&mut st, um(24.0), frozen).fault, None);
        }
        // Frozen while the stage moves down: seen once the FEM's preload has
        // moved by more than the tolerance, before the move ends.
        let mut seen = None;
        for k in 1..=400 {
            let x_ref = 24.0 - 23.0 * k as f64 / 400.0;
            if let Some(f) = c.step(&mut st, um(x_ref), frozen).fault {
                seen = Some((k, f));
                break;
            }
        }
        let (k, f) = seen.expect("a stuck sensor is seen");
        assert_eq!(f, Fault::ForceImplausible);
        assert!(k < 400, "{k}");
    }

    #[test]
    fn a_tripped_fault_ramps_to_safe_like_a_detected_one_and_codes_round_trip() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        let top = drive_to(&c, &mut st, 24.0).voltage;
        assert!(st.trip(Fault::LinkLost));
        assert!(!st.trip(Fault::Stopped), "the first fault stays latched");
        let out = plausible(&c, &mut st, um(24.0));
        assert_eq!(out.fault, Some(Fault::LinkLost));
        assert_eq!(
            top - out.voltage,
            crate::limits::PARK_ACCEL,
            "starts the park gently"
        );
        for f in Fault::ALL {
            assert_eq!(Fault::from_code(f as u8), Some(f));
        }
        assert_eq!(Fault::from_code(0), None);
    }

    /// The faults after which a park keeps the damping, and a damped park:
    /// the correction offered moves the output (within the slew limit), fades,
    /// and the park arrives at the safe voltage within the undamped bound; after
    /// a force fault the same offer is ignored, tick for tick.
    #[test]
    fn a_park_keeps_the_damping_only_where_it_cannot_be_the_cause() {
        let keeps: Vec<Fault> = Fault::ALL.into_iter().filter(Fault::damps_park).collect();
        assert_eq!(
            keeps,
            [
                Fault::ReferenceUnreachable,
                Fault::Stopped,
                Fault::LinkLost,
                Fault::ReferenceInput,
                Fault::PositionOutOfRange,
                Fault::Oscillation,
            ]
        );
        let c = testkit::controller();
        let ring = |k: usize| {
            Volts::from_num(12.0 * (k as f64 * 300.0 / 20_000.0 * std::f64::consts::TAU).cos())
        };
        let park = |fault: Fault| {
            let mut st = c.initial_state();
            let top = drive_to(&c, &mut st, 24.0).voltage;
            st.trip(fault);
            let mut path = Vec::new();
            let mut prev = top;
            while st.voltage() != c.safe_voltage() || path.is_empty() {
                st.damp_park(ring(path.len()));
                let out = plausible(&c, &mut st, um(24.0));
                assert_eq!(out.fault, Some(fault));
                assert!((out.voltage - prev).abs() <= c.limits().max_step());
                prev = out.voltage;
                path.push(out.voltage);
                assert!(path.len() < 1000);
            }
            assert_eq!(st.park_offset(), Volts::ZERO);
            assert!(st.clear_fault(&c));
            (top, path)
        };
        let (top, damped) = park(Fault::Oscillation);
        let (_, plain) = park(Fault::ForceImplausible);
        assert_eq!(plain, park(Fault::Overrun).1, "the offer ignored");
        assert_ne!(damped, plain, "the damping moves the output");
        let need = crate::limits::damped_park_ticks(top) as usize;
        assert!(damped.len() <= need, "{} {need}", damped.len());
        // The same profile underneath; the damping's share within the
        // profile's distance to go, and faded in proportion to it at the end.
        let safe = c.safe_voltage();
        for (k, (d, p)) in damped.iter().zip(&plain).enumerate() {
            let (share, left) = ((*d - *p).abs(), (*p - safe).abs());
            assert!(
                share <= left.min(Volts::from_num(12)),
                "{k}: {share} {left}"
            );
            if left < crate::limits::PARK_FADE {
                let faded = left * Volts::from_num(12) / crate::limits::PARK_FADE;
                assert!(share <= faded + Volts::from_bits(1), "{k}: {share} {faded}");
            }
        }
    }

    #[test]
    fn a_fault_parks_at_the_safe_voltage_along_the_gentle_profile_and_latches() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        let top = drive_to(&c, &mut st, 24.0).voltage;
        assert!(top > Volts::from_num(100));
        // A broken wire: the reading leaves the sensor range.
        let step = crate::limits::PARK_RATE;
        let mut prev = top;
        let mut ticks = 0;
        loop {
            let out = c.step(&mut st, um(24.0), n(500.0));
            assert_eq!(out.fault, Some(Fault::ForceOutOfRange));
            assert!(out.limited);
            assert!(out.voltage < prev || out.voltage == c.safe_voltage());
            assert!(
                prev - out.voltage <= step,
                "never faster than the park rate"
            );
            prev = out.voltage;
            ticks += 1;
            if out.voltage == c.safe_voltage() {
                break;
            }
            assert!(ticks < 1000);
        }
        // At the park rate, plus the ramp-up and the braking (40 ticks each: one
        // at the full rate's worth), not slower.
        let need = crate::limits::park_ticks(top) as usize;
        assert!(
            (need - 4..=need).contains(&ticks),
            "{ticks} ticks, {need} expected"
        );
        // Good inputs do not clear it; a later, different fault does not replace it.
        let out = plausible(&c, &mut st, um(40.0));
        assert_eq!(out.fault, Some(Fault::ForceOutOfRange));
        assert_eq!(out.voltage, c.safe_voltage());
    }

    #[test]
    fn clear_fault_waits_for_the_safe_voltage_and_resumes_without_a_jump() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        drive_to(&c, &mut st, 20.0);
        plausible(&c, &mut st, um(35.0));
        assert_eq!(st.fault(), Some(Fault::ReferenceUnreachable));
        assert!(!st.clear_fault(&c), "not before the ramp has ended");
        while st.voltage() != c.safe_voltage() {
            plausible(&c, &mut st, um(20.0));
        }
        assert!(st.clear_fault(&c));
        assert_eq!(st.fault(), None);
        // The inverse memory was realigned with the ramp actually applied: asking for
        // where the stage is now does not move it (the voltage may rise to the dead
        // zone's edge, k_f·F, where the stack has not started to move).
        let before = st.x_pea_est();
        let here = c.stage_position(before);
        let out = plausible(&c, &mut st, here);
        assert_eq!(out.fault, None);
        let moved = (out.x_pea_est - before).to_num::<f64>().abs();
        assert!(moved < 1e-4, "{moved} µm");
        let out = drive_to(&c, &mut st, 15.0);
        let est = c.stage_position(out.x_pea_est).to_num::<f64>();
        assert!((est - 15.0).abs() < 1e-3, "{est}");
    }

    #[test]
    fn the_uncompensated_baseline_hands_over_without_a_jump() {
        let c = testkit::controller();
        let mut st = c.initial_state();
        let line = LinearDrive::through(0.0, 8.0, 30.0, 100.0).unwrap();
        let mut out = None;
        for k in 0..=420 {
            // A ramp, then held so that the force has settled.
            let x = um(20.0 * k.min(400) as f64 / 400.0);
            let f = force_at(&c, st.x_pea_est());
            out = Some(c.step_uncompensated(&mut st, &line, x, f));
        }
        let out = out.unwrap();
        assert_eq!(out.fault, None);
        let want = line.voltage(um(20.0));
        assert_eq!(out.voltage, want, "the straight line, inside the limits");
        // Switching to compensation at the stage's actual position keeps the voltage.
        let here = c.stage_position(st.x_pea_est());
        let next = plausible(&c, &mut st, here);
        let jump = (next.voltage - want).to_num::<f64>().abs();
        assert!(jump < 0.01, "{jump} V");
        // Its inverse gives the reference back.
        let back = line.reference_for(want).unwrap().to_num::<f64>();
        assert!((back - 20.0).abs() < 1e-4, "{back}");
        assert_eq!(
            LinearDrive {
                gain: VoltsPerUm::ZERO,
                ..line
            }
            .reference_for(want),
            None
        );
        // The baseline is supervised too.
        let bad = c.step_uncompensated(&mut st, &line, um(10.0), n(1.0));
        assert_eq!(bad.fault, Some(Fault::ForceOutOfRange));
    }

    #[test]
    fn a_predicted_force_ignores_the_sensor() {
        let c = testkit::controller().with_force_source(ForceSource::Predicted);
        let mut st = c.initial_state();
        for k in 0..=200 {
            let out = c.step(&mut st, um(10.0 * k as f64 / 200.0), n(-999.0));
            assert_eq!(out.fault, None);
        }
        let est = c.stage_position(st.x_pea_est()).to_num::<f64>();
        assert!((est - 10.0).abs() < 0.05, "{est}");
    }
}
