//! What the governor may allow, from a model: the loops in force simulated as a
//! linear system at the control rate, their deviation's envelopes measured, and
//! the limits the stage's force room and amplifier set.
//!
//! The loops are the ones [`crate::stability`] models (the amplifier's lag, the
//! mode, the force channel's split, the damping, the PI), plus the reference's
//! path the governor feeds: the preview's delay and its feedforward taps, or the
//! shaping's sections, and the lead (the damping leaves out `κ·(S_{k−1} − x_ref)`).
//! Their deviation `e(n) = x(n) − g(n)` after a unit step of the governed
//! reference `g` at `n = 0` is `P(n)`; after a unit ramp, `T(n) = Σ_{i≤n} P(i)`,
//! which settles at the loops' lead `c_v` (negative: a lag). The governor's
//! envelope is the least `c` with `|T(n) − c_v| ≤ c·ρⁿ`, for the `ρ` (from
//! `1 − 2⁻²` to `1 − 2⁻¹⁶`) that makes `c/(1 − ρ)` least.
//!
//! **Which stages.** A model describes the stage it was identified on; the one
//! it runs may differ (a payload, a variant of the design). So each envelope is
//! the worst over the model's mode, the mode 20 % lower and 25 % higher, each
//! with half the model's damping ratio ([`MODE_SCALES`], [`DAMPING_SCALE`]). A
//! model that declares no dynamics gets the floor stage ([`FLOOR_MODE_HZ`],
//! [`FLOOR_DAMPING`]): the governor then assumes the slowest, least damped mode
//! a stage this board drives is built with, and limits every source as it would
//! for such a mode — conservative, never off (a stage below the floor needs
//! its dynamics declared: `fpi board autotune` measures them).
//!
//! The simulation is `f32` (the Cortex-M4F's floating point, about 60
//! operations a tick, until the responses have decayed to 10⁻⁴ of their peak
//! or [`HORIZON_MAX`] ticks) with the envelopes' bookkeeping in `f64`; once per
//! model and set of loops, in the link task, never in the ISR.

use crate::biquad::{Cascade, SHAPING_SECTIONS};
use crate::damping::DynamicsSpec;
use crate::preview::{Fir, TAPS};
use crate::q::{CreepRate, NewtonsPerUm};
use crate::stability::{section_f64, Laws, Plant};

use super::Limits;

/// The modes the envelopes cover, as multiples of the model's.
pub const MODE_SCALES: [f64; 3] = [0.8, 1.0, 1.25];
/// The damping ratio the envelopes cover, as a multiple of the model's.
pub const DAMPING_SCALE: f64 = 0.5;
/// The floor stage's mode, Hz: where a model declares no dynamics.
pub const FLOOR_MODE_HZ: f64 = 500.0;
/// The floor stage's damping ratio. With the mode's floor it covers stage A's
/// family (its first mode 680–1000 Hz, damped 0.015–0.05: a higher mode
/// less damped bounds lower); at ζ 0.01 the floor governed a 15 Hz sine over
/// the stroke through most of its ticks, which a 500 Hz mode does not need.
pub const FLOOR_DAMPING: f64 = 0.02;
/// The longest simulation, ticks.
pub const HORIZON_MAX: usize = 24_000;
/// The shortest simulation, ticks.
const HORIZON_MIN: usize = 400;
/// Ticks of the window a response must have decayed over.
const WINDOW: usize = 256;
/// How far a response must have decayed, against its peak.
const DECAYED: f32 = 1e-4;
/// Decays tried: `ρ = 1 − 2⁻ᵏ` for `k` in this range.
const DECAYS: core::ops::RangeInclusive<u32> = 2..=16;
const N_DECAYS: usize = 15;
/// The acceleration the force room allows is taken with this margin (the
/// loops and the mode's ringing add to a sustained acceleration's force).
pub const FORCE_MARGIN: f64 = 1.5;
/// The largest acceleration where the force room does not bound it (a model
/// without κ), µm/tick².
pub const ACCEL_UNBOUNDED: f64 = 1.0;

/// How the position loop runs (the firmware's loop modes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tracking {
    /// No position loop: the feedforward alone.
    Open,
    /// The PI's correction on top of the feedforward.
    Closed,
    /// The PI alone.
    FeedbackOnly,
}

/// The reference's path to the command (besides the loops).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Feedforward<'a> {
    /// The tracked reference as it is.
    Identity,
    /// Taps on the preview's line.
    Taps(&'a Fir),
    /// The shaping's sections on the tracked reference.
    Sections(&'a Cascade<SHAPING_SECTIONS>),
}

/// The loops a model runs in one of its modes: what the governor's envelopes
/// are measured on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Loops<'a> {
    /// Control rate, Hz.
    pub rate_hz: u32,
    /// The stage's dynamics as the model declares them (`None`: the floor).
    pub dynamics: Option<&'a DynamicsSpec>,
    /// The laws in force: split, damping, PI gains ([`Laws::of`], with the
    /// damping and the PI left out where they do not run).
    pub laws: Laws,
    /// The position loop.
    pub tracking: Tracking,
    /// The ticks the loops track the governed reference late (the
    /// preview's delay, where the model has one, whatever runs on its line).
    pub delay: u8,
    /// The reference's path.
    pub feedforward: Feedforward<'a>,
    /// The lead's κ where the damping leaves the shaped reference's force out
    /// (0: it does not), N/µm.
    pub lead: f64,
}

/// The response's envelope and the loops' lead (what [`Limits`] carries
/// besides the acceleration and the speed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Envelopes {
    /// The ramp's transient: decay per tick, gain.
    pub ramp: (f64, f64),
    /// The lead on a ramp (the largest over the stages covered), ticks.
    pub lead: f64,
    /// Ticks simulated (the longest over the stages covered).
    pub horizon: usize,
    /// Stages covered on which the loops did not settle within
    /// [`HORIZON_MAX`] ticks: left out of the envelope (a loop that rings on
    /// is the oscillation watch's to catch and park).
    pub unsettled: usize,
}

impl Envelopes {
    /// The envelope of loops that do not settle on the model's own stage: the
    /// largest the governor holds, which leaves the reference almost still
    /// (the link refuses to run such loops in the first place).
    pub const UNSETTLED: Self = Self {
        ramp: (1.0 - 1.0 / 65536.0, 2047.0),
        lead: 2047.0,
        horizon: HORIZON_MAX,
        unsettled: 1,
    };
}

/// One stage's plant in `f32`.
#[derive(Clone, Copy)]
struct PlantF32 {
    phi: [[f32; 3]; 3],
    gamma: [f32; 3],
    kappa: f32,
}

/// The floor stage's dynamics (see the module docs).
pub fn floor(rate_hz: u32) -> DynamicsSpec {
    let nyquist_mhz = rate_hz.saturating_mul(500).saturating_sub(1);
    DynamicsSpec {
        mode_mhz: ((FLOOR_MODE_HZ * 1000.0) as u32).min(nyquist_mhz),
        damping: CreepRate::from_bits((FLOOR_DAMPING * 4_294_967_296.0) as i32),
        lag_mhz: 0,
        force_gain: NewtonsPerUm::ZERO,
    }
}

/// The stages the envelopes cover: `(mode scale, damping ratio)`.
fn stages(d: Option<&DynamicsSpec>) -> ([(f64, f64); 3], usize) {
    match d {
        Some(d) => {
            let z = d.damping_ratio() * DAMPING_SCALE;
            (MODE_SCALES.map(|s| (s, z)), MODE_SCALES.len())
        }
        None => ([(1.0, FLOOR_DAMPING); 3], 1),
    }
}

impl Loops<'_> {
    /// The envelopes of these loops over the stages they cover.
    pub fn envelopes(&self) -> Envelopes {
        let floor = floor(self.rate_hz);
        let d = self.dynamics.unwrap_or(&floor);
        let (stages, n) = stages(self.dynamics);
        let mut ramp = Candidates::new();
        let mut lead = f64::NEG_INFINITY;
        let mut horizon = 0;
        let mut unsettled = 0;
        for &(scale, zeta) in &stages[..n] {
            let p = Plant::new(d, self.rate_hz, scale, Some(zeta), 1.0);
            let plant = PlantF32 {
                phi: p.phi.map(|r| r.map(|x| x as f32)),
                gamma: p.gamma.map(|x| x as f32),
                kappa: p.force_gain as f32,
            };
            // Pass 1: the step response until it has decayed, and the ramp's
            // settled value.
            let mut sim = Sim::new(self, &plant);
            let mut sum = 0.0f64;
            let mut peak = 0.0f32;
            let mut recent = [0.0f32; 2];
            let mut n_ticks = 0;
            for k in 0..HORIZON_MAX {
                let p = sim.tick();
                sum += p as f64;
                peak = peak.max(p.abs());
                let w = (k / WINDOW) & 1;
                recent[w] = recent[w].max(p.abs());
                if k % WINDOW == WINDOW - 1 {
                    if k >= HORIZON_MIN && recent[w] <= DECAYED * peak {
                        n_ticks = k + 1;
                        break;
                    }
                    recent[1 - w] = 0.0;
                }
            }
            if n_ticks == 0 || !sum.is_finite() {
                // The loops do not settle on this stage within the horizon.
                if scale == 1.0 {
                    return Envelopes::UNSETTLED;
                }
                unsettled += 1;
                continue;
            }
            let c_v = sum;
            lead = lead.max(c_v);
            horizon = horizon.max(n_ticks);
            // Pass 2: the ramp's transient, T(n) − c_v.
            let mut sim = Sim::new(self, &plant);
            let mut t = 0.0f64;
            let mut st = Track::new();
            for _ in 0..n_ticks {
                t += sim.tick() as f64;
                st.see((t - c_v).abs(), &mut ramp);
            }
            ramp.next_stage();
        }
        Envelopes {
            ramp: ramp.best(),
            lead,
            horizon,
            unsettled,
        }
    }

    /// The governor's limits: these loops' envelopes, the acceleration the
    /// force room allows (`force_room`, N, with [`FORCE_MARGIN`]: the stage's
    /// mass `κ/θ²` at the lowest mode covered, `θ` its angle per tick), and
    /// `speed` (µm/tick, the amplifier's slew through the drive's slope).
    pub fn limits(&self, force_room: f64, speed: f64) -> Limits {
        let e = self.envelopes();
        let accel = match self.dynamics {
            Some(d) if d.force_gain.to_bits() > 0 => {
                let theta = core::f64::consts::TAU * d.mode_mhz as f64 / 1000.0 * MODE_SCALES[0]
                    / self.rate_hz as f64;
                let mass = d.force_gain.to_num::<f64>() / (theta * theta);
                (force_room / (mass * FORCE_MARGIN)).min(ACCEL_UNBOUNDED)
            }
            _ => ACCEL_UNBOUNDED,
        };
        Limits {
            accel,
            speed,
            ramp: e.ramp,
            lead: e.lead,
        }
    }
}

/// For each decay tried, the least gain that bounds a response (the largest
/// over the stages seen so far).
struct Candidates {
    gains: [f64; N_DECAYS],
    stage: [f64; N_DECAYS],
}

impl Candidates {
    fn new() -> Self {
        Self {
            gains: [0.0; N_DECAYS],
            stage: [0.0; N_DECAYS],
        }
    }

    fn next_stage(&mut self) {
        for (g, s) in self.gains.iter_mut().zip(&mut self.stage) {
            *g = g.max(*s);
            *s = 0.0;
        }
    }

    /// The decay and gain whose bound of a steady input, `c/(1 − ρ)`, is least.
    fn best(&self) -> (f64, f64) {
        let mut best = (1.0 - 1.0 / 65536.0, f64::INFINITY, f64::INFINITY);
        for (i, k) in DECAYS.enumerate() {
            let one_minus = 1.0 / (1u64 << k) as f64;
            let c = self.gains[i];
            if c.is_finite() && c / one_minus < best.2 {
                best = (1.0 - one_minus, c, c / one_minus);
            }
        }
        (best.0, best.1)
    }
}

/// `ρ⁻ⁿ` for each decay tried, as `n` grows.
struct Track {
    inv: [f64; N_DECAYS],
    factor: [f64; N_DECAYS],
}

impl Track {
    fn new() -> Self {
        let mut factor = [1.0; N_DECAYS];
        for (f, k) in factor.iter_mut().zip(DECAYS) {
            *f = 1.0 / (1.0 - 1.0 / (1u64 << k) as f64);
        }
        Self {
            inv: [1.0; N_DECAYS],
            factor,
        }
    }

    /// Takes `|x(n)|` for the next `n`. Out of line: one copy (flash).
    #[inline(never)]
    fn see(&mut self, x: f64, c: &mut Candidates) {
        for ((inv, f), stage) in self.inv.iter_mut().zip(&self.factor).zip(&mut c.stage) {
            if x > 0.0 {
                let need = x * *inv;
                if need > *stage {
                    *stage = need;
                }
            }
            if *inv < 1e300 {
                *inv *= f;
            } else {
                *inv = f64::INFINITY;
            }
        }
    }
}

/// The loops and one stage, stepped in `f32` after a unit step of the governed
/// reference.
struct Sim<'a> {
    l: &'a Loops<'a>,
    p: PlantF32,
    y: [f32; 3],
    tick: usize,
    split_state: f32,
    damp: [f32; 2],
    integral: f32,
    sections: [[f32; 2]; SHAPING_SECTIONS],
    last_ff: f32,
    coeffs: [[f32; 5]; SHAPING_SECTIONS],
    damping: [f32; 5],
}

impl<'a> Sim<'a> {
    fn new(l: &'a Loops<'a>, p: &PlantF32) -> Self {
        let coeffs = match l.feedforward {
            Feedforward::Sections(c) => c.sections().map(|s| section_f64(&s).map(|x| x as f32)),
            _ => [[0.0; 5]; SHAPING_SECTIONS],
        };
        Self {
            l,
            p: *p,
            y: [0.0; 3],
            tick: 0,
            split_state: 0.0,
            damp: [0.0; 2],
            integral: 0.0,
            sections: [[0.0; 2]; SHAPING_SECTIONS],
            last_ff: 0.0,
            coeffs,
            damping: l.laws.damping.map(|x| x as f32),
        }
    }

    /// The governed reference at tick `k` (a unit step at 0).
    fn g(&self, back: usize) -> f32 {
        if back <= self.tick {
            1.0
        } else {
            0.0
        }
    }

    /// One tick: the deviation `x − g` read at its start, then the command.
    /// Out of line: one copy (flash).
    #[inline(never)]
    fn tick(&mut self) -> f32 {
        let l = self.l;
        let x_ref = self.g(l.delay as usize);
        let ff = match l.feedforward {
            Feedforward::Taps(f) => {
                let mut s = 0.0f32;
                for (j, &h) in f.taps().iter().enumerate().take(TAPS) {
                    s += h as f32 / (1u32 << 24) as f32 * self.g(j);
                }
                s
            }
            Feedforward::Sections(_) => self.shape(x_ref),
            Feedforward::Identity => x_ref,
        };
        let x = self.y[1];
        let dev = x - 1.0;
        let r = self.p.kappa * (self.y[0] - x);
        let a = l.laws.split as f32;
        let r_d = if a > 0.0 {
            self.split_state += a * (r - self.split_state);
            r - self.split_state
        } else {
            0.0
        };
        let dynamic = r_d - l.lead as f32 * (self.last_ff - x_ref);
        let [b0, b1, b2, a1, a2] = self.damping;
        let w = dynamic - a1 * self.damp[0] - a2 * self.damp[1];
        let y = b0 * w + b1 * self.damp[0] + b2 * self.damp[1];
        self.damp = [w, self.damp[0]];
        let e = x_ref - x;
        let pi = self.l.laws.kp as f32 * e + self.integral;
        let u = match l.tracking {
            Tracking::Open => ff - y,
            Tracking::Closed => {
                self.integral += l.laws.ki as f32 * e;
                ff + pi - y
            }
            Tracking::FeedbackOnly => {
                self.integral += l.laws.ki as f32 * e;
                pi - y
            }
        };
        self.last_ff = ff;
        let [v, xx, xd] = self.y;
        let phi = &self.p.phi;
        let g = &self.p.gamma;
        self.y = [
            phi[0][0] * v + phi[0][1] * xx + phi[0][2] * xd + g[0] * u,
            phi[1][0] * v + phi[1][1] * xx + phi[1][2] * xd + g[1] * u,
            phi[2][0] * v + phi[2][1] * xx + phi[2][2] * xd + g[2] * u,
        ];
        self.tick += 1;
        dev
    }

    /// The shaping's sections in series.
    fn shape(&mut self, x: f32) -> f32 {
        let mut s = x;
        for (c, st) in self.coeffs.iter().zip(self.sections.iter_mut()) {
            let [b0, b1, b2, a1, a2] = *c;
            let w = s - a1 * st[0] - a2 * st[1];
            s = b0 * w + b1 * st[0] + b2 * st[1];
            *st = [w, st[0]];
        }
        s
    }
}
