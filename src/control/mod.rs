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
//! estimated extension moves by more than half the tolerance is a stuck sensor
//! ([`Fault::ForceImplausible`]): neither the learned map nor the split's
//! low-pass can hide it. Half, so that a stage swinging the preload by more than
//! twice the tolerance shows a frozen reading within one swing wherever in it
//! the sensor froze (with the whole tolerance, one frozen near the middle of a
//! swing of 2.2 × the tolerance went unseen for cycles). A working sensor never
//! holds its bits while the preload moves by several newtons.
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
//! step; its inverse bank is double-buffered too, and a limited step, or one
//! in the soft dead zone's foot, does the inverse's step again with the input
//! the applied voltage's forward step matches ([`crate::fpi::Fpi::realign`]:
//! the primed bank's output) instead of a resync (two passes over the
//! operators): the worst closed-loop tick on the board's embedded model took
//! 1526 instructions instead of 1593 (with 8 feedforward taps), for about 25
//! more in an ordinary step (the bank's step reads one buffer and writes the
//! other).
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

use crate::error::ModelError;
use crate::fpi::{CreepMemory, Fpi, Identity, Shape};
use crate::limits::OutputLimits;
use crate::play::{PlayBank, Stepped};
use crate::q::{Micrometres, Newtons, Volts};
use crate::table::Table;

mod channel;
mod drive;
mod fault;
mod state;
mod window;

pub use channel::{
    check_force_channel, split_rate, ForceChannel, Forces, DEFAULT_SPLIT_HZ, DELTA_MAX_BITS,
    OFFSET_ADAPT_SHIFT, SCALE_ADAPT_SHIFT, SCALE_ERROR_MAX_BITS,
};
pub use drive::{LinearDrive, Mode};
pub use fault::Fault;
pub use state::{ControllerState, StepOutput};
pub(crate) use window::Window;
pub use window::{check_settings, Interval, Supervision, Windows};

use channel::{add_shifted, hi_word, residual, HALF_LSB_I16F48, SCALE_MAX_BITS};
use state::Memory;

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
    reference: Interval<Micrometres>,
    force: Interval<Newtons>,
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
            st.force_tare_model = self.preload(st.x_pea_est);
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
        self.sense_coupled(st, reading, Newtons::ZERO)
    }

    /// [`sense`](Self::sense) on a stage of several stacks: the FEM's preload
    /// at the last estimated extension plus `coupled` (N), what the other
    /// stacks' extensions put on this one (the first paper's coupled
    /// equation, each stack's preload a function of every stack's
    /// extension; `piezo_fpi::decoupling::Preload`). The channel's model
    /// force, its split and its checks all take the coupled preload, so the
    /// other stacks' motion is neither a dynamic force for the damping nor a
    /// residual for the slow part to chase.
    #[inline(always)]
    pub fn sense_coupled(
        &self,
        st: &mut ControllerState<N, C>,
        reading: Newtons,
        coupled: Newtons,
    ) -> Forces {
        if matches!(self.force_source, ForceSource::Measured) {
            self.sense_as::<true>(st, reading, coupled)
        } else {
            self.sense_as::<false>(st, reading, coupled)
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
        coupled: Newtons,
    ) -> Forces {
        let model = self.preload(st.x_pea_est).saturating_add(coupled);
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
        // moved by more than half the tolerance (twice the move against the
        // tolerance's window, no field of its own): a stuck sensor, whatever the
        // learned map and the split's low-pass have absorbed of the residual.
        // Twice a move wraps only beyond 16 384 N, where the reading (inside
        // ±4096 N) is already far outside the dynamic window.
        let stuck = if reading.to_bits() == st.force_held.to_bits() {
            let moved = residual(model, st.force_held_model).to_bits();
            !self.residual_window.contains_bits(moved.wrapping_shl(1))
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
                let f = self.sense_as::<true>(st, force, Newtons::ZERO);
                self.step_with::<true, true>(st, x_ref, &f)
            }
            (true, false) => self.step_general::<true>(st, x_ref, force),
            (false, true) => {
                let f = self.sense_as::<false>(st, force, Newtons::ZERO);
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
            let f = self.sense_as::<MEASURED>(st, force, Newtons::ZERO);
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
        let f = self.sense_as::<MEASURED>(st, force, Newtons::ZERO);
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
        let x_pea_ref = self.extension_within(x_ref);
        let f = if MEASURED {
            forces.feedforward
        } else {
            self.preload(x_pea_ref)
        };
        let terms = self.fpi.force_terms_at(f, st.force_ref);
        // Double-buffered: the state before this step stays at hand.
        let (want, foot) =
            self.fpi
                .inverse_as::<_, BARE>(&mut st.inverse, &st.creep, x_pea_ref, &terms);
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
            // this one's step (below).
            st.catch_up(&self.fpi, Memory::Before);
        }
        let (x_pea_est, own) =
            self.fpi
                .forward_traced::<_, BARE>(&mut st.forward, &mut st.creep, voltage, &terms);
        st.x_pea_est = x_pea_est;
        if limited || foot {
            // The stack got another drive than the inverse asked for (the limits, or
            // the foot of a soft dead zone): the inverse's step is done again with
            // the input that drive's forward step matches. The inverse then holds
            // that drive's memory, as a resync would, for the price of one
            // bank's step.
            self.fpi.realign::<_, BARE>(&mut st.inverse, own);
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
        let x_pea_ref = self.extension(x_ref);
        let f = if matches!(self.force_source, ForceSource::Measured) {
            forces.feedforward
        } else {
            self.preload(x_pea_ref)
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
            self.preload(st.x_pea_est)
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
        Micrometres::from_raw(self.f_k.eval(x_pea_est.raw()))
    }

    /// The FEM preload `f_F(x_pea)`, N, at a stack extension, µm (the table's
    /// input and output units made explicit).
    #[inline(always)]
    pub fn preload(&self, x_pea: Micrometres) -> Newtons {
        Newtons::from_raw(self.f_f.eval(x_pea.raw()))
    }

    /// The stack extension `f_K⁻¹(x_ref)`, µm, for a stage position, µm.
    #[inline(always)]
    pub fn extension(&self, x_ref: Micrometres) -> Micrometres {
        Micrometres::from_raw(self.f_k_inv.eval(x_ref.raw()))
    }

    /// [`extension`](Self::extension) for a reference known to be at or above
    /// the table's first knot (it passed the reference window).
    #[inline(always)]
    fn extension_within(&self, x_ref: Micrometres) -> Micrometres {
        Micrometres::from_raw(self.f_k_inv.eval_from_x_min(x_ref.raw()))
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
    pub const fn reference(&self) -> Interval<Micrometres> {
        self.reference
    }
    /// Plausible force readings, N.
    pub const fn force(&self) -> Interval<Newtons> {
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

#[cfg(test)]
mod tests;
