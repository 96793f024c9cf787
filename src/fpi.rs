//! The Force-dependent Prandtl–Ishlinskii model (Actuators 2025, 14(8):411,
//! eqs. 5–7) and the
//! effects the recorded data hold beyond it.
//!
//! The stack responds to an effective voltage: the preload `F` induces a reverse
//! voltage, so what drives the play operators is
//!
//! ```text
//! e  = u - U_p(F),            U_p(F) = k0 + k_f·F + k_q·(F - F_q)²
//! û  = g(e)                   dead zone: g(e) = max(e, 0), or a soft one (a table)
//! m_j ← m_j + (1 - a_j)(û - m_j)            creep: first-order lags of û
//! Y  = PI[û] + Σ_j b_j·m_j
//! x  = h(Y) - c·(F - F_ref)   output saturation h (a table, or identity); compliance c
//! ```
//!
//! * **The paper's FPI** is `k0 = k_q = 0`, the hard dead zone, no creep, `h` the
//!   identity and `c = 0`: `x = Y[max(u - k_f·F, 0)]`.
//! * **Dead zone (`û < 0`).** One-sided play operators are defined for a unipolar
//!   input. While the applied voltage has not overcome the preload's reverse
//!   voltage the stack does not extend: the hard dead zone clamps `e` at 0, so the
//!   operators see "no drive" and stay at rest. The recordings show it (the stack
//!   starts to move at `u ≈ 0.1 V/N · F`, and a higher preload both widens the dead
//!   zone and shortens the stroke) and show that its edge is soft, hence `g`.
//! * **Compliance.** The stack is a spring (datasheet ≈ 50 N/µm, `c ≈ 0.02 µm/N`):
//!   a rising hinge force compresses it. `F_ref` is the force at which the
//!   extension is zero (the assembly preload).
//!
//! Every part inverts in closed form, so the ISR needs no iteration:
//!
//! ```text
//! v  = h⁻¹(x + c·(F - F_ref)) - Σ_j b_j·a_j·m_j
//! û  = PI'⁻¹[v]        PI' = PI with w0' = w0 + Σ_j b_j(1 - a_j): this sample's creep
//! u  = U_p(F) + g⁻¹(û)
//! ```
//!
//! The creep memories `m_j` are advanced once per sample, by the forward model
//! with the voltage actually applied, and read by the next inverse.

use crate::error::{Field, Invalid, ModelError};
use crate::inverse::InversePi;
use crate::pi::PiModel;
use crate::play::{Bank, Edge, PlayBank, Redo, Stepped};
use crate::process::SplitProcess;
use crate::q::{
    compliance_mul, coupling_mul, quad_mul, within, CreepRate, GainAcc, Micrometres, Newtons,
    Signal, UmPerNewton, UmPerVolt, Volts, VoltsPerNewton, VoltsPerNewton2, GAIN_FRAC,
    MAX_CREEP_TERMS, QUAD_MAX_BITS, SIGNAL_ABS_MAX_BITS,
};
use crate::table::Table;
use fixed::types::I16F16;

/// How the force enters: the preload offset `U_p(F)` and the compliance.
///
/// * `offset` — `k0`, V, `I16F16`.
/// * `k_f` — force–voltage coupling, V/N, `I0F32`.
/// * `k_q`, `force_q` — curvature of the offset, V/N² (`I0F32`), about `F_q` (N).
/// * `compliance` — `c`, µm/N, `I0F32` (0 for the paper's model).
/// * `force_ref` — `F_ref`, N, `I16F16`: force at which the extension is zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Coupling {
    /// Constant part of the preload offset `k0`, V.
    pub offset: Volts,
    /// Force–voltage coupling `k_f`, V/N.
    pub k_f: VoltsPerNewton,
    /// Curvature `k_q` of the preload offset, V/N².
    pub k_q: VoltsPerNewton2,
    /// Centre `F_q` of the curvature term, N.
    pub force_q: Newtons,
    /// Stack compliance `c`, µm/N.
    pub compliance: UmPerNewton,
    /// Reference force `F_ref`, N.
    pub force_ref: Newtons,
}

impl Coupling {
    /// Checks what the model's arithmetic needs of a coupling: `F_ref` and `F_q`
    /// inside the signal range, `|k_q|·(1024 N)²` inside it too (the curvature
    /// product's clamp). The one check, shared by [`Fpi::new`] and the model
    /// validator.
    pub const fn check(&self) -> Result<(), Invalid> {
        // |k0| ≤ 4096 V keeps `k0 + k_f·F + k_q·(F − F_q)²` inside I16F16 (found by
        // fuzzing: an image with k0 near 32 768 V overflowed the sum).
        let k0 = self.offset.to_bits();
        if k0 > SIGNAL_ABS_MAX_BITS || k0 < -SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::CouplingOffset,
                ModelError::NotRepresentable,
            ));
        }
        let fr = self.force_ref.to_bits();
        if fr > SIGNAL_ABS_MAX_BITS || fr < -SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::CouplingForceRef,
                ModelError::NotRepresentable,
            ));
        }
        let fq = self.force_q.to_bits();
        if fq > SIGNAL_ABS_MAX_BITS || fq < -SIGNAL_ABS_MAX_BITS {
            return Err(Invalid::at(
                Field::CouplingForceQ,
                ModelError::NotRepresentable,
            ));
        }
        let kq = self.k_q.to_bits() as i64;
        let kq = if kq < 0 { -kq } else { kq };
        if kq > QUAD_MAX_BITS {
            return Err(Invalid::at(
                Field::CouplingKq,
                ModelError::CurvatureOutOfRange,
            ));
        }
        Ok(())
    }

    /// The paper's coupling: `U_p = k_f·F`, no compliance.
    pub const fn paper(k_f: VoltsPerNewton) -> Self {
        Self {
            offset: Volts::ZERO,
            k_f,
            k_q: VoltsPerNewton2::ZERO,
            force_q: Newtons::ZERO,
            compliance: UmPerNewton::ZERO,
            force_ref: Newtons::ZERO,
        }
    }
}

/// A monotone static map and its inverse, both as lookup tables. Below the first
/// knot they hold the first value; beyond the last knot they continue with slope
/// one (a dead zone is the identity far above its edge; a saturation map is built
/// to cover the whole output range).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Map<'a> {
    /// `y = map(x)`.
    pub forward: Table<'a>,
    /// `x = map⁻¹(y)`.
    pub inverse: Table<'a>,
}

impl Map<'_> {
    #[inline(always)]
    fn through<S: Signal>(t: &Table<'_>, x: S) -> S {
        let (top, x) = (t.x_max(), I16F16::from_bits(x.to_bits()));
        S::from_bits(
            if x > top {
                t.last() + (x - top)
            } else {
                t.eval(x)
            }
            .to_bits(),
        )
    }
    /// `map(x)`.
    #[inline(always)]
    pub fn apply<S: Signal>(&self, x: S) -> S {
        Self::through(&self.forward, x)
    }
    /// `map⁻¹(y)`.
    #[inline(always)]
    pub fn invert<S: Signal>(&self, y: S) -> S {
        Self::through(&self.inverse, y)
    }
}

/// A static monotone map of the chain, `g` (the soft dead zone) or `h` (the output
/// saturation), as a type: a [`Map`] of two tables, or [`Identity`] for a model
/// without it (the paper's FPI has neither). The ISR code is specialised for the
/// model's structure, so a part the model lacks costs nothing, not even a branch.
pub trait Shape<'a>: Copy + Eq + core::fmt::Debug {
    /// `map(x)`, in the unit of `x` (a dead zone maps volts, a saturation
    /// micrometres).
    fn apply<S: Signal>(&self, x: S) -> S;
    /// `map⁻¹(y)`.
    fn invert<S: Signal>(&self, y: S) -> S;
    /// `y` lies below the inverse table's first knot (for a dead zone: in its foot,
    /// where the inverse can only hold the first value).
    fn below_inverse<S: Signal>(&self, y: S) -> bool;
    /// The tables, if the map is not the identity.
    fn map(&self) -> Option<&Map<'a>>;
    /// Whether the map is not the identity (a constant for [`Map`] and
    /// [`Identity`], so a branch on it costs nothing in their code).
    fn present(&self) -> bool;
    /// [`present`](Self::present) when the type decides it; `None` when only the
    /// value does (a map chosen at run time).
    const FIXED: Option<bool>;
}

impl<'a> Shape<'a> for Map<'a> {
    const FIXED: Option<bool> = Some(true);
    #[inline(always)]
    fn apply<S: Signal>(&self, x: S) -> S {
        Map::apply(self, x)
    }
    #[inline(always)]
    fn invert<S: Signal>(&self, y: S) -> S {
        Map::invert(self, y)
    }
    #[inline(always)]
    fn below_inverse<S: Signal>(&self, y: S) -> bool {
        y.to_bits() < self.inverse.x_min().to_bits()
    }
    fn map(&self) -> Option<&Map<'a>> {
        Some(self)
    }
    #[inline(always)]
    fn present(&self) -> bool {
        true
    }
}

/// The absent map: `g` is then the hard dead zone `max(e, 0)` (the effective
/// voltage's clamp to the operator domain), `h` the identity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Identity;

impl<'a> Shape<'a> for Identity {
    const FIXED: Option<bool> = Some(false);
    #[inline(always)]
    fn apply<S: Signal>(&self, x: S) -> S {
        x
    }
    #[inline(always)]
    fn invert<S: Signal>(&self, y: S) -> S {
        y
    }
    #[inline(always)]
    fn below_inverse<S: Signal>(&self, _: S) -> bool {
        false
    }
    fn map(&self) -> Option<&Map<'a>> {
        None
    }
    #[inline(always)]
    fn present(&self) -> bool {
        false
    }
}

/// A map chosen at run time (a model received by the board): a [`Map`] or the
/// absent one, behind one branch.
impl<'a> Shape<'a> for Option<Map<'a>> {
    const FIXED: Option<bool> = None;
    #[inline(always)]
    fn apply<S: Signal>(&self, x: S) -> S {
        match self {
            Some(m) => m.apply(x),
            None => x,
        }
    }
    #[inline(always)]
    fn invert<S: Signal>(&self, y: S) -> S {
        match self {
            Some(m) => m.invert(y),
            None => y,
        }
    }
    #[inline(always)]
    fn below_inverse<S: Signal>(&self, y: S) -> bool {
        match self {
            Some(m) => y.to_bits() < m.inverse.x_min().to_bits(),
            None => false,
        }
    }
    fn map(&self) -> Option<&Map<'a>> {
        self.as_ref()
    }
    #[inline(always)]
    fn present(&self) -> bool {
        self.is_some()
    }
}

/// One creep term: a first-order lag of the effective voltage with gain `b`.
///
/// * `rate` — `1 - a = 1 - exp(-T_s/τ)`, per sample, `I0F32` in `(0, 0.5)`.
/// * `gain` — `b`, µm/V, `I4F28`.
/// * `held` — `b·a`, µm/V, `I4F28` (derived).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Creep {
    rate: CreepRate,
    gain: UmPerVolt,
    held: UmPerVolt,
}

impl Creep {
    /// A placeholder term (rate and gain 0) for unused slots of fixed-size arrays:
    /// it contributes nothing.
    pub const DISABLED: Self = Self {
        rate: CreepRate::ZERO,
        gain: UmPerVolt::ZERO,
        held: UmPerVolt::ZERO,
    };

    /// A creep term from its per-sample rate `1 - a` and gain `b`.
    pub const fn new(rate: CreepRate, gain: UmPerVolt) -> Result<Self, ModelError> {
        let r = rate.to_bits() as i64;
        if r <= 0 {
            return Err(ModelError::CreepRateOutOfRange);
        }
        // b·a = b - b·(1 - a), in GAIN_FRAC bits.
        let g = gain.to_bits() as i64;
        let held = g - ((g * r + (1 << 31)) >> 32);
        Ok(Self {
            rate,
            gain,
            held: UmPerVolt::from_bits(held as i32),
        })
    }
    /// `1 - a`, per sample.
    pub const fn rate(&self) -> CreepRate {
        self.rate
    }
    /// `b`, µm/V.
    pub const fn gain(&self) -> UmPerVolt {
        self.gain
    }
}

/// `w0' = w0 + Σ_j b_j·(1 - a_j)`, µm/V: the linear weight of this sample's PI once
/// the creep lags' response to it is folded in (the inverse inverts that PI). At
/// most [`MAX_CREEP_TERMS`] terms; fails if `w0'` does not fit a weight.
pub const fn creep_slope(w0: UmPerVolt, creep: &[Creep]) -> Result<UmPerVolt, ModelError> {
    if creep.len() > MAX_CREEP_TERMS {
        return Err(ModelError::TooManyCreepTerms);
    }
    let mut w0p = w0.to_bits() as i64;
    let mut j = 0;
    while j < creep.len() {
        let c = creep[j];
        w0p += (c.gain.to_bits() as i64 * c.rate.to_bits() as i64 + (1 << 31)) >> 32;
        j += 1;
    }
    if w0p > i32::MAX as i64 || w0p < i32::MIN as i64 {
        return Err(ModelError::NotRepresentable);
    }
    Ok(UmPerVolt::from_bits(w0p as i32))
}

/// The creep memories `m_j` (state), volts as `I16F48` raw bits: the extra
/// fractional bits let a slow lag (`1 - a` down to 10⁻⁵) move by less than one
/// `I16F16` LSB per sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CreepMemory<const C: usize> {
    m: [i64; C],
}

impl<const C: usize> CreepMemory<C> {
    /// All lags at rest (0 V).
    pub const fn new() -> Self {
        Self { m: [0; C] }
    }
}

impl<const C: usize> Default for CreepMemory<C> {
    fn default() -> Self {
        Self::new()
    }
}

/// The force terms of one sample, computed once and shared by inverse and forward.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceTerms {
    /// Preload offset `U_p(F)`, V.
    pub preload_offset: Volts,
    /// Compression `c·(F - F_ref)`, µm.
    pub compression: Micrometres,
}

/// A calibrated FPI model with its closed-form inverse (configuration).
///
/// `N` operators, `C` creep terms, the dead zone `G` and the output map `H`
/// ([`Shape`]: a [`Map`] or [`Identity`]). The defaults are the paper's FPI.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fpi<'a, const N: usize, const C: usize = 0, G = Identity, H = Identity> {
    pi: PiModel<N>,
    /// The PI with this sample's creep folded into `w0` (`w0' = w0 + Σ b(1-a)`).
    pi_prime: PiModel<N>,
    inverse: InversePi<N>,
    coupling: Coupling,
    dead_zone: G,
    saturation: H,
    creep: [Creep; C],
    /// The creep terms in use: `C` for a model built with its own count, fewer for
    /// a model received at run time into capacity `C`.
    creep_len: u8,
    /// The model is the paper's FPI (see [`is_bare`](Self::is_bare)), as far as
    /// is known when it is built ([`resolved`](Self::resolved) completes it).
    bare: bool,
    tables: core::marker::PhantomData<&'a ()>,
}

impl<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>> Fpi<'a, N, C, G, H> {
    /// Builds the model and its inverse; `const` so the firmware's model is checked
    /// when it is compiled.
    ///
    /// * `dead_zone` — the soft dead zone `g` ([`Identity`]: the hard one, `max(e, 0)`).
    /// * `saturation` — the output map `h` ([`Identity`]: none).
    pub const fn new(
        pi: PiModel<N>,
        coupling: Coupling,
        dead_zone: G,
        saturation: H,
        creep: [Creep; C],
    ) -> Result<Self, ModelError> {
        if let Err(e) = coupling.check() {
            return Err(e.error);
        }
        let (pi_prime, inverse) = match Self::primed(&pi, &creep) {
            Ok(p) => p,
            Err(e) => return Err(e),
        };
        Ok(Self {
            pi,
            pi_prime,
            inverse,
            coupling,
            dead_zone,
            saturation,
            creep,
            creep_len: C as u8,
            bare: Self::bare_by_type(C),
            tables: core::marker::PhantomData,
        })
    }

    /// The PI with `creep`'s share of this sample folded into `w0`, and its
    /// closed-form inverse.
    const fn primed(
        pi: &PiModel<N>,
        creep: &[Creep],
    ) -> Result<(PiModel<N>, InversePi<N>), ModelError> {
        let w0p = match creep_slope(pi.w0(), creep) {
            Ok(w) => w,
            Err(e) => return Err(e),
        };
        let pi_prime = match pi.with_w0(w0p) {
            Ok(p) => p,
            Err(e) => return Err(e),
        };
        match InversePi::from_forward(&pi_prime) {
            Ok(i) => Ok((pi_prime, i)),
            Err(e) => Err(e),
        }
    }

    /// The same model using only its first `len` creep terms (the rest are slots of
    /// a model received into capacity `C`); `None` if `len > C`. The closed-form
    /// inverse is rebuilt for the terms in use, and the slots beyond them are
    /// cleared ([`Creep::DISABLED`] contributes exactly nothing), so a model whose
    /// structure is in its type may run all `C` terms and get the same result.
    pub const fn with_creep_terms(mut self, len: usize) -> Result<Self, ModelError> {
        if len > C {
            return Err(ModelError::TooManyCreepTerms);
        }
        let mut j = len;
        while j < C {
            self.creep[j] = Creep::DISABLED;
            j += 1;
        }
        let (used, _) = self.creep.split_at(len);
        let (pi_prime, inverse) = match Self::primed(&self.pi, used) {
            Ok(p) => p,
            Err(e) => return Err(e),
        };
        Ok(Self {
            pi_prime,
            inverse,
            creep_len: len as u8,
            bare: Self::bare_by_type(len),
            ..self
        })
    }

    /// `U_p(F)` and `c·(F - F_ref)` for a force `F` (N), each rounded once.
    #[inline(always)]
    pub fn force_terms(&self, force: Newtons) -> ForceTerms {
        self.force_terms_at(force, self.coupling.force_ref)
    }

    /// [`force_terms`](Self::force_terms) with another reference force `F_ref` (N),
    /// e.g. the rest force measured at power-up.
    #[inline(always)]
    pub fn force_terms_at(&self, force: Newtons, force_ref: Newtons) -> ForceTerms {
        let c = &self.coupling;
        let mut offset = c.offset + coupling_mul(c.k_f, force);
        if c.k_q.to_bits() != 0 {
            offset += quad_mul(c.k_q, force.saturating_sub(c.force_q));
        }
        ForceTerms {
            preload_offset: offset,
            compression: compliance_mul(c.compliance, force.saturating_sub(force_ref)),
        }
    }

    /// Whether this model is the paper's FPI: no soft dead zone, no saturation, no
    /// creep terms in use. A constant for a model whose structure is in its type; for
    /// a model received at run time, the control step branches on it once and runs
    /// the paper's FPI without looking at the parts it lacks
    /// ([`forward_as`](Self::forward_as), [`inverse_as`](Self::inverse_as)).
    #[inline(always)]
    pub fn is_bare(&self) -> bool {
        match (G::FIXED, H::FIXED) {
            (Some(true), _) | (_, Some(true)) => false,
            (Some(false), Some(false)) if C == 0 => true,
            _ => self.bare,
        }
    }

    /// Creep terms the loops run: all `C` for a model whose structure is in its type
    /// (a constant trip count; unused slots are [`Creep::DISABLED`]), the terms in
    /// use for a model received at run time.
    #[inline(always)]
    fn creep_terms(&self) -> usize {
        if G::FIXED.is_some() && H::FIXED.is_some() {
            C
        } else {
            self.creep_len as usize
        }
    }

    /// Whether the types alone make a model with `creep` terms bare.
    const fn bare_by_type(creep: usize) -> bool {
        matches!(G::FIXED, Some(false)) && matches!(H::FIXED, Some(false)) && creep == 0
    }

    /// The same model with [`is_bare`](Self::is_bare) decided from its values: for
    /// a model whose maps are chosen at run time (`Option<Map>`), so the control
    /// step reads one flag instead of inspecting the parts.
    pub fn resolved(self) -> Self {
        let bare = !self.dead_zone.present()
            && !self.saturation.present()
            && (C == 0 || self.creep_len == 0);
        Self { bare, ..self }
    }

    /// The effective voltage the bank sees for an applied voltage, V, in `[0, input_max]`.
    #[inline(always)]
    fn effective<const BARE: bool>(&self, u: Volts, t: &ForceTerms) -> Volts {
        let e = u.saturating_sub(t.preload_offset);
        let e = if BARE { e } else { self.dead_zone.apply(e) };
        within(e, Volts::ZERO, self.pi.input_max())
    }

    /// Forward model: applied voltage `u` (V) under force terms `t` → stack
    /// extension (µm). Advances the forward bank and the creep memories.
    #[inline(always)]
    pub fn forward<E: Edge>(
        &self,
        bank: &mut PlayBank<N, E>,
        creep: &mut CreepMemory<C>,
        u: Volts,
        t: &ForceTerms,
    ) -> Micrometres {
        self.forward_as::<E, false>(bank, creep, u, t)
    }

    /// [`forward`](Self::forward); with `BARE` the caller has checked
    /// [`is_bare`](Self::is_bare) and the dead zone, creep and saturation are skipped.
    #[inline(always)]
    pub fn forward_as<E: Edge, const BARE: bool>(
        &self,
        bank: &mut PlayBank<N, E>,
        creep: &mut CreepMemory<C>,
        u: Volts,
        t: &ForceTerms,
    ) -> Micrometres {
        self.forward_traced::<E, BARE>(bank, creep, u, t).0
    }

    /// [`forward_as`](Self::forward_as), also giving the output of the primed
    /// bank (the PI with this sample's share of the creep folded into `w0`,
    /// which the inverse inverts) at the effective voltage, µm: the input with
    /// which an inverse bank's step, done again ([`realign`](Self::realign)),
    /// matches this one.
    #[inline(always)]
    pub fn forward_traced<E: Edge, const BARE: bool>(
        &self,
        bank: &mut PlayBank<N, E>,
        creep: &mut CreepMemory<C>,
        u: Volts,
        t: &ForceTerms,
    ) -> (Micrometres, Own) {
        let uh = self.effective::<BARE>(u, t);
        let mut acc = bank.advance(self.pi.bank(), uh.raw());
        if BARE {
            return (
                crate::q::narrow_gain_biased(acc) - t.compression,
                Own { acc, uh },
            );
        }
        let own = Own { acc, uh };
        // m += (1 - a)(û - m), with m's top 32 bits as the difference's m.
        let lag = |m: &mut i64, c: &Creep| {
            let m_hi = (*m >> 32) as i32;
            *m += c.rate.to_bits() as i64 * (uh.to_bits() - m_hi) as i64;
            c.gain.to_bits() as i64 * (*m >> 32)
        };
        for (m, c) in creep.m.iter_mut().zip(&self.creep).take(self.creep_terms()) {
            acc += lag(m, c);
        }
        // The bank's sum carries the rounding half LSB (its bias).
        let y = crate::q::narrow_gain_biased(acc);
        let z = self.saturation.apply(y);
        (z - t.compression, own)
    }

    /// Inverse model: desired stack extension `x_pea` (µm) under force terms `t` →
    /// the voltage (V) to apply. Advances the inverse bank; reads the creep memories.
    ///
    /// The PI target is clamped to the PI output range; the caller applies the
    /// actuator limits to the result.
    #[inline(always)]
    pub fn inverse<E: Edge>(
        &self,
        bank: &mut PlayBank<N, E>,
        creep: &CreepMemory<C>,
        x_pea: Micrometres,
        t: &ForceTerms,
    ) -> Volts {
        self.inverse_checked(bank, creep, x_pea, t).0
    }

    /// [`inverse`](Self::inverse), also telling whether the effective voltage asked
    /// for lies in the foot of the soft dead zone, below its inverse table: the
    /// voltage returned then drives the stack slightly harder than the inverse
    /// memory assumes, and the caller should realign it ([`Self::realign`] or
    /// [`Self::resync`]).
    #[inline(always)]
    pub fn inverse_checked<E: Edge>(
        &self,
        bank: &mut PlayBank<N, E>,
        creep: &CreepMemory<C>,
        x_pea: Micrometres,
        t: &ForceTerms,
    ) -> (Volts, bool) {
        self.inverse_as::<_, false>(bank, creep, x_pea, t)
    }

    /// [`inverse_checked`](Self::inverse_checked); with `BARE` the caller has
    /// checked [`is_bare`](Self::is_bare) (see [`forward_as`](Self::forward_as)).
    #[inline(always)]
    pub fn inverse_as<B: Bank<N>, const BARE: bool>(
        &self,
        bank: &mut B,
        creep: &CreepMemory<C>,
        x_pea: Micrometres,
        t: &ForceTerms,
    ) -> (Volts, bool) {
        let z = x_pea + t.compression;
        if BARE {
            let e = self.inverse.process(bank, z);
            return (t.preload_offset.saturating_add(e), false);
        }
        let mut v = self.saturation.invert(z);
        if C > 0 {
            let held: i64 = (creep.m.iter().zip(&self.creep))
                .take(self.creep_terms())
                .map(|(m, c)| c.held.to_bits() as i64 * (*m >> 32))
                .sum();
            v -= narrow(held);
        }
        let uh = self.inverse.process(bank, v);
        let (e, foot) = (self.dead_zone.invert(uh), self.dead_zone.below_inverse(uh));
        (t.preload_offset.saturating_add(e), foot)
    }

    /// Realigns a double-buffered inverse bank with the forward bank's step
    /// just taken: the inverse's own step done again, from the state before it,
    /// with `own`, the forward bank's output ([`forward_traced`](Self::forward_traced)).
    /// The banks then agree as [`resync`](Self::resync) would make them, up to
    /// rounding, for the price of one bank's step (a resync is N multiply-adds
    /// and a second pass); the inverse's last step must be the one to redo.
    /// With `BARE` (see [`forward_as`](Self::forward_as)) the primed bank is
    /// the bank.
    #[inline(always)]
    pub fn realign<E: Edge, const BARE: bool>(&self, inverse: &mut Stepped<N, E>, own: Own) {
        // The primed bank's sum: the same operators, its own `w0`.
        let dw0 = if BARE {
            0
        } else {
            self.pi_prime
                .w0()
                .to_bits()
                .wrapping_sub(self.pi.w0().to_bits())
        };
        let x = crate::q::narrow_gain_biased(own.acc + dw0 as i64 * own.uh.to_bits() as i64);
        self.inverse.process(&mut Redo(inverse), x);
    }

    /// Realigns the inverse bank with the forward bank (see [`InversePi::resync`]).
    #[inline]
    pub fn resync<F: Edge, E: Edge>(&self, forward: &PlayBank<N, F>, inverse: &mut PlayBank<N, E>) {
        self.inverse.resync(&self.pi_prime, forward, inverse);
    }

    /// Sets the forward bank to the state that matches the inverse bank (see
    /// [`InversePi::forward_state`]): the forward memory of the voltages the
    /// inverse returned, when they were applied as they were.
    #[inline]
    pub fn forward_from_inverse<E: Edge, F: Edge>(
        &self,
        inverse: &PlayBank<N, E>,
        forward: &mut PlayBank<N, F>,
    ) {
        self.inverse.forward_state(&self.pi_prime, inverse, forward);
    }

    /// What [`forward_as`](Self::forward_as) returns for the voltage the bare
    /// inverse ([`inverse_as`](Self::inverse_as) with `BARE`) returned for
    /// `x_pea` under the same terms, up to rounding: `x_pea`, held to the range
    /// the model reaches. The controller's estimate while the drive is the
    /// inverse's; µm.
    #[inline(always)]
    pub fn reached(&self, x_pea: Micrometres, t: &ForceTerms) -> Micrometres {
        let z = x_pea + t.compression;
        within(z, Micrometres::ZERO, self.inverse.input_max()) - t.compression
    }

    /// The forward PI model.
    pub const fn pi(&self) -> &PiModel<N> {
        &self.pi
    }
    /// The force coupling.
    pub const fn coupling(&self) -> &Coupling {
        &self.coupling
    }
    /// The soft dead zone, if any.
    pub fn dead_zone(&self) -> Option<&Map<'a>> {
        self.dead_zone.map()
    }
    /// The output saturation, if any.
    pub fn saturation(&self) -> Option<&Map<'a>> {
        self.saturation.map()
    }
    /// The creep terms in use.
    pub const fn creep(&self) -> &[Creep] {
        self.creep.split_at(self.creep_len as usize).0
    }
}

/// A forward step's bank sum and effective voltage, from which
/// [`Fpi::realign`] finds the inverse bank's input that matches it.
#[derive(Debug, Clone, Copy)]
pub struct Own {
    acc: i64,
    uh: Volts,
}

/// Rounds a `GAIN_FRAC + SIGNAL_FRAC` accumulator to a signal.
#[inline(always)]
fn narrow(acc: i64) -> Micrometres {
    crate::q::narrow_gain(GainAcc::from_bits(acc))
}

const _: () = assert!(GAIN_FRAC + 16 == 44);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::q::coupling;
    use crate::table::Segment;
    use fixed::types::{I0F32, I16F16};

    fn paper(c: f64) -> Fpi<'static, 3> {
        let pi =
            PiModel::from_f64(0.064, &[10.0, 30.0, 60.0], &[0.01, 0.008, 0.004], 150.0).unwrap();
        let cp = Coupling {
            compliance: coupling(c).unwrap(),
            force_ref: crate::testkit::v(60.0),
            ..Coupling::paper(coupling(0.1).unwrap())
        };
        Fpi::new(pi, cp, Identity, Identity, []).unwrap()
    }

    #[test]
    fn a_coupling_offset_beyond_the_signal_range_is_refused_by_key() {
        let ok = Coupling {
            offset: crate::testkit::v(4096.0),
            ..Coupling::paper(coupling(0.1).unwrap())
        };
        assert!(ok.check().is_ok());
        let bad = Coupling {
            offset: Volts::from_bits(i32::MAX),
            ..ok
        };
        assert_eq!(
            bad.check(),
            Err(Invalid::at(
                Field::CouplingOffset,
                ModelError::NotRepresentable
            ))
        );
    }

    #[test]
    fn the_bare_path_is_the_general_path_for_the_papers_fpi() {
        // A model received at run time: maps chosen by value, creep capacity unused.
        let typed = paper(0.02);
        let m: Fpi<'static, 3, 2, Option<Map<'static>>, Option<Map<'static>>> = Fpi::new(
            *typed.pi(),
            *typed.coupling(),
            None,
            None,
            [Creep::DISABLED; 2],
        )
        .and_then(|f| f.with_creep_terms(0))
        .unwrap()
        .resolved();
        assert!(m.is_bare() && typed.is_bare());
        let mut fa: PlayBank<3, crate::play::Bottom> = PlayBank::at_rest(m.pi().bank());
        let mut fb = fa;
        let (mut ia, mut ib): (PlayBank<3>, PlayBank<3>) = (PlayBank::new(), PlayBank::new());
        let (mut ca, mut cb) = (CreepMemory::new(), CreepMemory::new());
        for k in 0..2000 {
            let x = Micrometres::from_num(6.0 + 5.5 * (k as f64 * 0.013).sin());
            let t = m.force_terms(Newtons::from_num(60.0 + 20.0 * (k as f64 * 0.007).cos()));
            let ua = m.inverse_as::<_, true>(&mut ia, &ca, x, &t);
            let ub = m.inverse_as::<_, false>(&mut ib, &cb, x, &t);
            assert_eq!(ua, ub, "inverse at {k}");
            let xa = m.forward_as::<_, true>(&mut fa, &mut ca, ua.0, &t);
            let xb = m.forward_as::<_, false>(&mut fb, &mut cb, ub.0, &t);
            assert_eq!((xa, fa, ia), (xb, fb, ib), "forward at {k}");
        }
        let with_creep = Fpi::<'static, 3, 2, Option<Map<'static>>, Option<Map<'static>>>::new(
            *typed.pi(),
            *typed.coupling(),
            None,
            None,
            [Creep::new(CreepRate::from_num(0.01), UmPerVolt::from_num(0.001)).unwrap(); 2],
        )
        .unwrap()
        .resolved();
        assert!(!with_creep.is_bare());
    }

    #[test]
    fn dead_zone_holds_the_stack_until_u_exceeds_kf_f() {
        let m = paper(0.0);
        let (mut bank, mut cm) = (PlayBank::new(), CreepMemory::new());
        let t = m.force_terms(Newtons::from_num(100));
        // k_f F = 10 V: below it nothing moves.
        for u in [0.0, 4.0, 9.99] {
            assert_eq!(
                m.forward(&mut bank, &mut cm, Volts::from_num(u), &t),
                Micrometres::ZERO
            );
        }
        let x = m
            .forward(&mut bank, &mut cm, Volts::from_num(20), &t)
            .to_num::<f64>();
        assert!((x - 0.64).abs() < 1e-4, "{x}");
    }

    #[test]
    fn compliance_compresses_under_extra_force() {
        let m = paper(0.02);
        let (mut bank, mut cm) = (PlayBank::new(), CreepMemory::new());
        let t = m.force_terms(Newtons::from_num(80));
        let x = m
            .forward(&mut bank, &mut cm, Volts::from_num(8), &t)
            .to_num::<f64>();
        // In the dead zone (k_f F = 8 V): only the 20 N extra load compresses it.
        assert!((x + 0.4).abs() < 1e-4, "{x}");
    }

    #[test]
    fn inverse_then_forward_returns_the_target() {
        let m = paper(0.02);
        let (mut fb, mut ib, mut cm) = (PlayBank::new(), PlayBank::new(), CreepMemory::new());
        for (x, f) in [
            (2.0, 70.0),
            (6.5, 90.0),
            (3.2, 75.0),
            (5.0, 84.0),
            (0.5, 62.0),
        ] {
            let t = m.force_terms(Newtons::from_num(f));
            let u = m.inverse(&mut ib, &cm, Micrometres::from_num(x), &t);
            let back = m.forward(&mut fb, &mut cm, u, &t).to_num::<f64>();
            assert!((back - x).abs() < 1e-4, "x={x}: {back}");
        }
    }

    // A soft dead zone (softplus, s = 2 V) and a saturation z + 0.004 z² = Y, as tables.
    const S: f64 = 2.0;
    fn softplus(e: f64) -> f64 {
        S * (1.0 + (e / S).exp()).ln()
    }
    fn tables() -> (Vec<Segment>, Vec<Segment>, Vec<Segment>, Vec<Segment>) {
        let seg = |xs: Vec<f64>| -> Vec<Segment> {
            xs.windows(2)
                .map(|w| {
                    let a = I16F16::from_num(w[0]);
                    Segment::new(a, I16F16::from_num(w[1]) - a)
                })
                .collect()
        };
        // g on e in [-20, 20] V step 1/16; g^-1 on û in [0.25, 20] V step 1/32 (below
        // 0.25 V the inverse is too steep for the grid: it holds g^-1(0.25) = -4 V).
        let g: Vec<f64> = (0..=640)
            .map(|k| softplus(-20.0 + k as f64 / 16.0))
            .collect();
        let ginv: Vec<f64> = (0..=632)
            .map(|k| {
                let y = 0.25 + k as f64 / 32.0;
                S * ((y / S).exp() - 1.0).ln()
            })
            .collect();
        // h: Y in [0, 16] um step 1/32 -> z; h^-1: z in [0, 16] -> Y = z + 0.004 z^2.
        let h: Vec<f64> = (0..=512)
            .map(|k| {
                let y = k as f64 / 32.0;
                2.0 * y / (1.0 + (1.0 + 0.016 * y).sqrt())
            })
            .collect();
        let hinv: Vec<f64> = (0..=512)
            .map(|k| {
                let z = k as f64 / 32.0;
                z + 0.004 * z * z
            })
            .collect();
        (seg(g), seg(ginv), seg(h), seg(hinv))
    }

    /// The paper's model with a soft dead zone, a saturation and two creep
    /// terms, built on `tables`.
    fn extended<'t>(
        (g, ginv, h, hinv): &'t (Vec<Segment>, Vec<Segment>, Vec<Segment>, Vec<Segment>),
    ) -> Fpi<'t, 3, 2, Map<'t>, Map<'t>> {
        let g = Map {
            forward: Table::new(I16F16::from_num(-20), 12, g).unwrap(),
            inverse: Table::new(I16F16::from_num(0.25), 11, ginv).unwrap(),
        };
        let h = Map {
            forward: Table::new(I16F16::ZERO, 11, h).unwrap(),
            inverse: Table::new(I16F16::ZERO, 11, hinv).unwrap(),
        };
        let pi =
            PiModel::from_f64(0.064, &[10.0, 30.0, 60.0], &[0.01, 0.008, 0.004], 150.0).unwrap();
        let cp = Coupling {
            offset: crate::testkit::v(-0.4),
            k_f: coupling(0.106).unwrap(),
            k_q: I0F32::from_num(1.6e-4),
            force_q: crate::testkit::v(75.0),
            compliance: coupling(0.02).unwrap(),
            force_ref: crate::testkit::v(60.0),
        };
        let creep = [
            Creep::new(I0F32::from_num(0.005), UmPerVolt::from_num(0.003)).unwrap(),
            Creep::new(I0F32::from_num(0.00002), UmPerVolt::from_num(0.001)).unwrap(),
        ];
        Fpi::new(pi, cp, g, h, creep).unwrap()
    }

    #[test]
    fn extended_model_inverts_in_closed_form() {
        let t = tables();
        let m = extended(&t);
        let (mut fb, mut ib, mut cm) = (PlayBank::new(), PlayBank::new(), CreepMemory::<2>::new());
        let mut worst = 0.0f64;
        for k in 0..4000 {
            let x = 4.0 + 3.5 * (k as f64 * 0.01).sin();
            let f = 70.0 + 4.0 * x;
            let t = m.force_terms(Newtons::from_num(f));
            let u = m.inverse(&mut ib, &cm, Micrometres::from_num(x), &t);
            let back = m.forward(&mut fb, &mut cm, u, &t).to_num::<f64>();
            worst = worst.max((back - x).abs());
        }
        // Table round trips (g then g^-1, h^-1 then h) cost a few LSB each.
        assert!(worst < 5e-4, "worst {worst} um");
    }

    #[test]
    fn a_changed_drive_realigns_the_inverse_as_a_resync_does() {
        // A reference that dives into the dead zone's foot and moves faster
        // than a 0.5 V slew allows: the inverse's step done again
        // (`realign`) and the inverse memory rebuilt from the forward one
        // (`resync`) then ask for the same voltages, up to rounding.
        let t = tables();
        let m = extended(&t);
        let (mut fb, mut cm) = (PlayBank::new(), CreepMemory::<2>::new());
        let mut redone = Stepped::new(PlayBank::<3>::new());
        let mut resynced = PlayBank::<3>::new();
        let slew = Volts::from_num(0.5);
        let (mut prev, mut changed, mut feet, mut worst) = (Volts::ZERO, 0, 0, 0i32);
        for k in 0..6000 {
            let s = k as f64 * 0.004;
            let x = 3.6 + 3.7 * s.sin() + 1.5 * (7.0 * s).sin().signum();
            let t = m.force_terms(Newtons::from_num(70.0 + 4.0 * x));
            let x = Micrometres::from_num(x);
            let (want, foot) = m.inverse_as::<_, false>(&mut redone, &cm, x, &t);
            let (other, _) = m.inverse_as::<_, false>(&mut resynced, &cm, x, &t);
            worst = worst.max((want.to_bits() - other.to_bits()).abs());
            let u = want.clamp(prev - slew, prev + slew);
            let (_, own) = m.forward_traced::<_, false>(&mut fb, &mut cm, u, &t);
            if u != want || foot {
                m.realign::<_, false>(&mut redone, own);
                m.resync(&fb, &mut resynced);
                changed += (u != want) as u32;
                feet += foot as u32;
            }
            prev = u;
        }
        assert!(
            changed > 500 && feet > 100,
            "{changed} limited, {feet} in the foot"
        );
        // Measured: 0 LSB; bound 2 LSB of `I16F16` (31 µV).
        assert!(worst <= 2, "the voltages asked for differ by {worst} LSB");
    }
}
