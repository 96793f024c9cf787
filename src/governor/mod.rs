//! The reference governor: the one stage of the control ISR that every reference
//! source passes — a move, a step, a wave, a stream, the analog input, the
//! analyser's stimulus — before the loops track it, so that whatever a source
//! asks, the stage's true position stays inside the stroke.
//!
//! **What it bounds.** The loops in force (open or closed, the damping, the
//! feedforward) turn the governed reference `g` into the stage's position `x`.
//! Their deviation `e = x − g` is a linear response of `g`'s history, which
//! [`analysis`] measures on the model's dynamics (and on stages whose mode is
//! 20 % lower or 25 % higher with half the damping, or on a conservative floor
//! where the model declares no dynamics): after a unit ramp of `g` it settles
//! at the loops' lead `c_v` (negative: a lag), and what is left decays within
//! an exponential envelope `c_r·ρⁿ`. So, whatever `g` does,
//!
//! ```text
//! |e(k)| ≤ c_v⁺·|Δg(k)| + D(k),     D ← ρ·D + c_r·|Δ²g|
//! ```
//!
//! whatever the phase of its content: a wave at the mode builds `D` up as fast
//! as it can build the stage's swing up, so the mode's own content is what the
//! bound limits, while a slow scan, which asks almost no acceleration, leaves
//! it near zero. (An envelope of the step response would bound small fast
//! content more tightly — the analyser's stimulus above the mode — but its
//! upkeep did not fit the tick's budget: the host measures such a frequency
//! again with a smaller stimulus where the governor departs from it.)
//!
//! **What it does.** Each tick it takes the source's value `r` and moves `g`
//! toward it with at most [`GovernorConfig`]'s acceleration and speed (the
//! force room and the amplifier's slew): where `r` is within reach `g` lands on
//! it exactly (a source within the limits passes unchanged, to the bit), else it
//! accelerates toward `r` and brakes so as to arrive without overshoot. Then it
//! checks that the stage would stay in the window widened by the margin even if
//! `g` braked from now on:
//!
//! ```text
//! F = D + (c_v⁺ + c_r)·|v|                                  the deviation while braking
//! g + s(v) + F ≤ hi + m   and   g − F ≥ lo − m              moving up
//! s(v) = v²/(2A) + |v|/2                                    the stop distance
//! ```
//!
//! (braking from `v` adds at most `c_r·|v|` to `D`: its accelerations sum to
//! `|v|`) and, where it would not, brakes instead. Braking never makes either
//! side of the check grow, so a state that passed it once passes it for ever:
//! the stage's position is bounded by the window and the margin whatever the
//! source (within the dynamics the analysis covered). From rest, a move toward
//! an edge takes at most a share of the room left to it per tick, so that the
//! governed reference creeps up to the edge instead of stalling short of it.
//! A governed tick is counted and flagged in the recording.
//!
//! # Formats
//!
//! | quantity | unit | format | range |
//! |---|---|---|---|
//! | `g`, `D`, distances (state) | µm | `I16F16` | the window; 0…32768 (saturated) |
//! | `v`, `Δv`, `A` | µm/tick, µm/tick² | `I4F28` | ±[`SPEED_MAX`], magnitudes below 8 |
//! | `ρ` | 1 per tick | `I0F32` (raw `u32`) | [0, 1) |
//! | `c_r`, `c_v⁺ + c_r` | µm per µm/tick | `I12F20` (raw `u32`) | 0…2047 |
//! | `1/(2A)` | tick²/µm | `I8F24` (raw `u32`) | up to 1/(2·[`ACCEL_MIN`]) = 127 |
//! | `1/(2A_g)` | tick²/µm | `I12F20` (raw `u32`) | up to 1/(2·[`ACCEL_GOV_MIN`]) = 2047 |
//! | stop distance toward a governed source, the gap to it | µm | `I20F12` (raw `u32`) | below 2¹⁷ |
//!
//! Every product is one unsigned 32 × 32 → 64-bit multiply whose high word is
//! the result (a gain times a speed, the envelope's decay, `v²` and the stop
//! distance); the ranges keep it within 31 bits; sums saturate. No division,
//! no panic, constant time (two paths: the source passes, or is governed).

pub mod analysis;

use crate::control::Interval;
use crate::process::SplitProcess;
use crate::q::Micrometres;

/// Fractional bits of speeds and speed changes (`I4F28`).
pub const MOTION_FRAC: u32 = 28;
/// Fractional bits of the envelope gains (`I12F20`): a gain times a speed
/// (`I4F28`) is `I16F48`, whose high word is a distance (`I16F16`).
pub const GAIN_FRAC: u32 = 20;
/// Fractional bits of `1/(2A)` (`I8F24`): times a squared speed (`I8F24`) it
/// is `I16F48`, whose high word is the stop distance (`I16F16`).
pub const INV_ACCEL_FRAC: u32 = 24;
/// The fastest speed the governor lets through, µm/tick (78 mm/s at 20 kHz,
/// far beyond any stage's amplifier; a speed change stays below the 8 µm/tick
/// of `I4F28`).
pub const SPEED_MAX: f64 = 3.9;
/// The largest acceleration it lets through, µm/tick².
pub const ACCEL_MAX: f64 = 3.9;
/// The least acceleration a configuration may have, µm/tick² (`1/(2A)` then
/// fits its format).
pub const ACCEL_MIN: f64 = 1.0 / 254.0;
/// The least acceleration toward a governed source, µm/tick² (`1/(2A_g)` then
/// fits its format).
pub const ACCEL_GOV_MIN: f64 = 1.0 / 4094.0;
/// Fractional bits of `1/(2A_g)` (`I12F20`).
pub const INV_ACCEL_GOV_FRAC: u32 = 20;
/// The least speed a configuration may have, µm/tick.
pub const SPEED_MIN: f64 = 1.0 / 254.0;
/// The margin the stage may leave the reference window by, µm: the bound the
/// governor keeps the true position in (half of the one micrometre the
/// stroke's tests allow, the rest for what the analysis does not cover).
pub const MARGIN_UM: f64 = 0.5;
/// What the governor's own motion toward a source it governs may build the
/// envelope up to, µm: its acceleration then is at most `M·(1 − ρ)/c_r`, so
/// that governing a source does not itself fill the room it needs (a bang-bang
/// at a large acceleration would keep the envelope high and the source
/// governed; on the floor stage, a 15 Hz sine over the stroke was governed
/// for 57 % of its ticks at the full acceleration).
pub const GOVERNING_ENVELOPE_UM: f64 = 2.0;

/// How far past a governed source the gentle braking may carry the
/// governed reference before it brakes at `A` instead, µm.
pub const OVERSHOOT_UM: f64 = 1.0;
/// [`OVERSHOOT_UM`] as `I20F12` bits (the format of the stop distance toward
/// a governed source).
const OVERSHOOT_BITS: u32 = 1 << 12;

/// The largest envelope gain (`I12F20` bits of 2047).
const GAIN_BITS_MAX: f64 = (2047u64 << GAIN_FRAC) as f64;

/// Where the governor keeps the reference and the stage (configuration, one
/// per model): the reference window, and the window the stage's position
/// must stay in, widened by [`MARGIN_UM`], µm (`I16F16` bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GovernorWindow {
    lo: i32,
    hi: i32,
    lo_m: i32,
    hi_m: i32,
}

impl GovernorWindow {
    /// The governor's windows about the reference window `w`.
    pub fn new(w: Interval<Micrometres>) -> Self {
        let margin = bits(MARGIN_UM, 16, 0.0, 1.0) as i32;
        Self {
            lo: w.lo.to_bits(),
            hi: w.hi.to_bits(),
            lo_m: w.lo.to_bits().saturating_sub(margin),
            hi_m: w.hi.to_bits().saturating_add(margin),
        }
    }

    /// Whether a source's value `r` lies in the reference window (a source
    /// beyond it asks for what the model says the stage cannot reach).
    #[inline(always)]
    pub fn holds(&self, r: Micrometres) -> bool {
        let r = r.to_bits();
        r >= self.lo && r <= self.hi
    }

    /// The reference window it keeps the governed reference in.
    pub fn reference(&self) -> Interval<Micrometres> {
        Interval {
            lo: Micrometres::from_bits(self.lo),
            hi: Micrometres::from_bits(self.hi),
        }
    }
}

/// What the governor allows (configuration, one per set of loops in force):
/// the limits and the envelopes' constants ([`analysis`] computes them from a
/// model; the link task installs them with the model).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GovernorLimits {
    /// Largest acceleration `A`, µm/tick², `I4F28`.
    accel: u32,
    /// The acceleration toward a governed source, µm/tick², `I4F28`: `A` or
    /// less ([`GOVERNING_ENVELOPE_UM`]).
    accel_gov: u32,
    /// Largest speed, µm/tick, `I4F28`.
    speed: u32,
    /// `1/(2A)`, tick²/µm, `I8F24`: the stop distance braking at `A` (what
    /// the check assumes: the governor brakes at `A`).
    inv_2accel: u32,
    /// `1/(2A_g)`, tick²/µm, `I12F20`: the stop distance toward a governed
    /// source ([`Self::accel_gov`]).
    inv_2accel_gov: u32,
    /// The envelope's decay per tick, `I0F32`.
    rho: u32,
    /// The envelope's gain, µm per µm/tick of speed change, `I12F20`.
    c_r: u32,
    /// The loops' lead on a ramp (0 where they lag) plus `c_r`, `I12F20`: what
    /// braking from a speed adds to the bound, per µm/tick.
    c_vr: u32,
    /// The share of the room to an edge a move from rest may take per tick,
    /// `1/(3 + 2c_r + 2(c_v⁺ + c_r))`, `I0F32`: a move that would not pass
    /// the check at the full acceleration still creeps there.
    creep: u32,
}

/// A governor: its window and its limits (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GovernorConfig {
    /// The windows.
    pub window: GovernorWindow,
    /// The limits.
    pub limits: GovernorLimits,
}

impl GovernorConfig {
    /// The governor for the reference window `window` with `limits`
    /// ([`GovernorLimits::new`]).
    pub fn new(window: Interval<Micrometres>, l: &Limits) -> Self {
        Self {
            window: GovernorWindow::new(window),
            limits: GovernorLimits::new(l),
        }
    }

    /// Largest acceleration, µm/tick².
    pub fn accel(&self) -> f64 {
        self.limits.accel()
    }

    /// Largest speed, µm/tick.
    pub fn speed(&self) -> f64 {
        self.limits.speed()
    }
}

/// One tick ([`GovernorLimits::process`], in the configuration's window).
impl SplitProcess<Micrometres, Micrometres, GovernorState> for GovernorConfig {
    #[inline]
    fn process(&self, st: &mut GovernorState, r: Micrometres) -> Micrometres {
        self.limits.process(&self.window, st, r)
    }
}

/// The governor's constants as numbers (what [`analysis`] finds), before they
/// are quantised into a [`GovernorConfig`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Largest acceleration, µm/tick².
    pub accel: f64,
    /// Largest speed, µm/tick.
    pub speed: f64,
    /// The envelope of the ramp's transient: decay per tick and gain (µm per
    /// µm/tick).
    pub ramp: (f64, f64),
    /// The loops' lead on a ramp, µm per µm/tick (negative: a lag).
    pub lead: f64,
}

/// A number in `[lo, hi]` as raw bits with `frac` fractional bits (`NaN`: `lo`).
fn bits(x: f64, frac: u32, lo: f64, hi: f64) -> i64 {
    let x = if x.is_nan() { lo } else { x.max(lo).min(hi) };
    let s = x * (1u64 << frac) as f64;
    (if s >= 0.0 { s + 0.5 } else { s - 0.5 }) as i64
}

/// The least whole number at or above `x ≥ 0` (below 2⁶³; no `libm`).
fn ceil(x: f64) -> f64 {
    let t = x as u64 as f64;
    if t < x {
        t + 1.0
    } else {
        t
    }
}

/// A decay per tick in `[0, 1)` as `I0F32`, rounded up (a slower decay bounds
/// a faster one).
fn decay_bits(rho: f64) -> u32 {
    let r = if rho.is_nan() { 1.0 } else { rho.max(0.0) };
    let s = r * 4_294_967_296.0;
    if s >= 4_294_967_295.0 {
        u32::MAX
    } else {
        ceil(s) as u32
    }
}

/// An envelope gain as `I12F20`, rounded up (`NaN`: the largest).
fn gain_bits(c: f64) -> u32 {
    let c = if c.is_nan() { 2047.0 } else { c.abs() };
    ceil(c * (1u64 << GAIN_FRAC) as f64).min(GAIN_BITS_MAX) as u32
}

impl GovernorLimits {
    /// The limits of `l`, quantised: each gain rounded up, the limits held to
    /// their formats' ranges ([`ACCEL_MIN`]…[`ACCEL_MAX`],
    /// [`SPEED_MIN`]…[`SPEED_MAX`]).
    pub fn new(l: &Limits) -> Self {
        let accel = bits(l.accel, MOTION_FRAC, ACCEL_MIN, ACCEL_MAX) as u32;
        let c_r = gain_bits(l.ramp.1);
        let quiet = GOVERNING_ENVELOPE_UM * (1.0 - l.ramp.0) / l.ramp.1.max(1e-9);
        let accel_gov = (bits(quiet, MOTION_FRAC, ACCEL_GOV_MIN, ACCEL_MAX) as u32).min(accel);
        let a = accel as f64 / (1u64 << MOTION_FRAC) as f64;
        let a_gov = accel_gov as f64 / (1u64 << MOTION_FRAC) as f64;
        let speed = bits(l.speed, MOTION_FRAC, SPEED_MIN, SPEED_MAX) as u32;
        let c_vr = gain_bits(l.lead.max(0.0)).saturating_add(c_r);
        let gain = |c: u32| c as f64 / (1u64 << GAIN_FRAC) as f64;
        Self {
            accel,
            accel_gov,
            speed,
            inv_2accel: ceil(0.5 / a * (1u64 << INV_ACCEL_FRAC) as f64) as u32,
            inv_2accel_gov: ceil(0.5 / a_gov * (1u64 << INV_ACCEL_GOV_FRAC) as f64) as u32,
            rho: decay_bits(l.ramp.0),
            c_r,
            c_vr,
            creep: (4_294_967_296.0 / (3.0 + 2.0 * gain(c_r) + 2.0 * gain(c_vr))) as u32,
        }
    }

    /// Largest acceleration, µm/tick².
    pub fn accel(&self) -> f64 {
        self.accel as f64 / (1u64 << MOTION_FRAC) as f64
    }

    /// Largest speed, µm/tick.
    pub fn speed(&self) -> f64 {
        self.speed as f64 / (1u64 << MOTION_FRAC) as f64
    }

    /// One tick: takes the source's value `r` (µm, within the window: the
    /// sources are checked against it before they run) and gives the governed
    /// reference (µm, within the window); [`GovernorState::governed`] says
    /// whether it departed from `r`.
    #[inline(always)]
    pub fn process(
        &self,
        w: &GovernorWindow,
        st: &mut GovernorState,
        r: Micrometres,
    ) -> Micrometres {
        let r16 = r.to_bits();
        let v = st.v;
        // Landing on `r` this tick: the speed that does it. While governed,
        // the way there is taken instead (creeping up to an edge where
        // landing would not pass).
        let want16 = r16.wrapping_sub(st.g);
        let want = want16.wrapping_shl(MOTION_FRAC - 16);
        let lands = want16.unsigned_abs() <= self.speed >> (MOTION_FRAC - 16)
            && want.wrapping_sub(v).unsigned_abs() <= self.accel;
        let v1 = if lands && !st.governed {
            want
        } else {
            self.toward(w, st, r16, lands.then_some(want))
        };
        st.r_prev = r16;
        let d = decay(self.rho, st.d);
        let ringing = gain_mul(self.c_r, v1.wrapping_sub(v).unsigned_abs());
        let (v1, ringing) = if self.admits(w, st.g, d.saturating_add(ringing), v1) {
            (v1, ringing)
        } else {
            // Brake (or hold): never makes the check's sides grow.
            let a = self.accel as i32;
            let braked = v - v.max(-a).min(a);
            (
                braked,
                gain_mul(self.c_r, braked.wrapping_sub(v).unsigned_abs()),
            )
        };
        st.d = d.saturating_add(ringing);
        st.v = v1;
        st.g = st.g.wrapping_add(v1 >> (MOTION_FRAC - 16));
        st.governed = st.g != r16;
        Micrometres::from_bits(st.g)
    }

    /// The next speed toward `r16` (`I16F16` bits), `I4F28`: landing on it
    /// where it is in reach (`land`), else bang-bang at `A_g`, braking where
    /// the stop distance relative to the source reaches the gap (at `A` where
    /// it would pass the source by more than [`OVERSHOOT_UM`]); from rest (or slower
    /// than a tick's acceleration), at most a share of the room to the
    /// window's nearer edge ([`Self::creep`]).
    #[inline(never)]
    fn toward(&self, w: &GovernorWindow, st: &GovernorState, r16: i32, land: Option<i32>) -> i32 {
        let v = st.v;
        let a = self.accel_gov as i32;
        let limit = (self.speed >> (MOTION_FRAC - 16)) as i32;
        let dr = r16.wrapping_sub(st.r_prev).max(-limit).min(limit);
        let v1 = match land {
            // Landing only where the source's own speed is within a tick's
            // acceleration of the landing speed (else the next tick could not
            // follow the source and would swing past it), and where the check
            // admits it: a landing it refuses would brake, and next to the
            // window's edge a governed move out of the park braked to a stop at
            // every tick and filled the envelope with the braking.
            Some(want)
                if want.wrapping_sub(dr << (MOTION_FRAC - 16)).unsigned_abs() <= self.accel
                    && self.admits(
                        w,
                        st.g,
                        decay(self.rho, st.d).saturating_add(gain_mul(
                            self.c_r,
                            want.wrapping_sub(v).unsigned_abs(),
                        )),
                        want,
                    ) =>
            {
                want
            }
            _ => {
                // The gap if we coast one tick, and our speed relative to the
                // source.
                let gap = r16.wrapping_sub(st.g).wrapping_sub(v >> (MOTION_FRAC - 16));
                let q = v.wrapping_sub(dr << (MOTION_FRAC - 16));
                let up = gap >= 0;
                // The relative speed along the way to the source.
                let q = if up { q } else { q.wrapping_neg() };
                let closing = q > 0;
                let room = gap.unsigned_abs() >> 4;
                // Brake gently where the gentle stop reaches the gap, and at
                // `A` where it would pass the source by more than
                // [`OVERSHOOT_UM`] (a source that passed at `A`, or the
                // brake, hands over a speed that `A_g` cannot take off in
                // time: braking at `A_g` alone swung past the source by tens
                // of micrometres, and back; braking at `A` wherever the
                // gentle stop fell short rang an undamped stage's mode).
                let stop = stop_distance_gov(q as u32, self.inv_2accel_gov);
                let brake = closing && stop >= room;
                let hard = closing && stop > room + OVERSHOOT_BITS;
                let a = if hard { self.accel as i32 } else { a };
                let acc = if brake { -a } else { a };
                let acc = if up { acc } else { -acc };
                // Within the speed, and not past the window's edge.
                let lo = w.lo.wrapping_sub(st.g);
                let hi = w.hi.wrapping_sub(st.g);
                // (`±limit` is the speed to `I16F16` bits: no `±speed` clamp
                // of its own.)
                v.wrapping_add(acc)
                    .max(lo.max(-limit) << (MOTION_FRAC - 16))
                    .min(hi.min(limit) << (MOTION_FRAC - 16))
            }
        };
        if v.unsigned_abs() > self.accel_gov {
            return v1;
        }
        // The room on either side: the stage may swing both ways.
        let room = w
            .hi_m
            .saturating_sub(st.g)
            .min(st.g.saturating_sub(w.lo_m))
            .saturating_sub(st.d);
        // A share of it, as a speed (I16F16 µm per tick to I4F28).
        let share16 = ((room.max(0) as u64 * self.creep as u64) >> 32) as i32;
        let share = (share16.min(limit) << (MOTION_FRAC - 16)).max(1);
        v1.max(-share).min(share)
    }

    /// Whether moving at `v1` from `g` (the envelope `d` after this tick's
    /// change of speed) keeps the stage in the window with the margin,
    /// braking from then on.
    #[inline(always)]
    fn admits(&self, w: &GovernorWindow, g: i32, d: i32, v1: i32) -> bool {
        let speed = v1.unsigned_abs();
        let s = stop_distance(speed, self.inv_2accel)
            .wrapping_add((speed >> (MOTION_FRAC - 16 + 1)) as i32);
        let g1 = g.wrapping_add(v1 >> (MOTION_FRAC - 16));
        let (ahead, behind) = if v1 >= 0 {
            (w.hi_m.wrapping_sub(g1), g1.wrapping_sub(w.lo_m))
        } else {
            (g1.wrapping_sub(w.lo_m), w.hi_m.wrapping_sub(g1))
        };
        let bound = d.saturating_add(gain_mul(self.c_vr, speed));
        bound <= behind && s.saturating_add(bound) <= ahead
    }
}

/// `D·ρ`, the high word of the product (`D ≥ 0`).
#[inline(always)]
fn decay(rho: u32, d: i32) -> i32 {
    ((d as u32 as u64 * rho as u64) >> 32) as i32
}

/// A gain (`I12F20`, ≤ 2047) times a speed or a speed change (`I4F28`,
/// below 8 µm/tick): µm, `I16F16` (the high word; below 2¹⁴ µm).
#[inline(always)]
fn gain_mul(c: u32, x: u32) -> i32 {
    ((c as u64 * x as u64) >> 32) as i32
}

/// `v²/(2A)` for a speed `v` (`I4F28`, below 8 µm/tick) and `1/(2A)`
/// (`I8F24`, at most 127): µm, `I16F16` (below 2¹³ µm). `v²` is the high
/// word of its square (`I8F24`), the distance the high word of their product.
#[inline(always)]
fn stop_distance(v: u32, inv_2accel: u32) -> i32 {
    let v2 = ((v as u64 * v as u64) >> 32) as u32;
    ((v2 as u64 * inv_2accel as u64) >> 32) as i32
}

/// `v²/(2A_g)` for a speed `v` (`I4F28`, below 8 µm/tick) and `1/(2A_g)`
/// (`I12F20`, at most 2047): µm, `I20F12` (the high word of their product:
/// below 2¹⁷ µm, no clamp; compared with the gap to the source, which it
/// needs to a fraction of a nanometre only).
#[inline(always)]
fn stop_distance_gov(v: u32, inv: u32) -> u32 {
    let v2 = ((v as u64 * v as u64) >> 32) as u32;
    ((v2 as u64 * inv as u64) >> 32) as u32
}

/// The governor's memory (state): where the governed reference is and how it
/// moves, the envelope, and the source's last value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GovernorState {
    /// The governed reference, µm, `I16F16`.
    g: i32,
    /// Its speed, µm/tick, `I4F28`.
    v: i32,
    /// The envelope after the last tick, µm (`I16F16`).
    d: i32,
    /// The source's last value (`I16F16` bits).
    r_prev: i32,
    /// The last tick departed from the source.
    governed: bool,
}

impl GovernorState {
    /// At rest at `x`, µm: the source held there, nothing ringing.
    pub const fn at_rest(x: Micrometres) -> Self {
        Self {
            g: x.to_bits(),
            v: 0,
            d: 0,
            r_prev: x.to_bits(),
            governed: false,
        }
    }

    /// The last tick's governed reference departed from the source's value.
    pub const fn governed(&self) -> bool {
        self.governed
    }

    /// The governed reference, µm.
    pub const fn position(&self) -> Micrometres {
        Micrometres::from_bits(self.g)
    }

    /// Its speed, µm/tick.
    pub fn speed(&self) -> f64 {
        self.v as f64 / (1u64 << MOTION_FRAC) as f64
    }

    /// The deviation bound the envelope keeps now, µm.
    pub fn bound(&self) -> f64 {
        self.d as f64 / 65536.0
    }
}

#[cfg(test)]
mod tests;
