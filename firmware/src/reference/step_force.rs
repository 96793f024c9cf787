//! The force a step asks of the stack: what the link task checks a step
//! command against before the control loop runs it (`f32`; not the ISR).
//!
//! A step (a raised cosine of amplitude `A` over `T`, [`super::SourceOrder::Step`])
//! accelerates the stage at up to `a = A·π²/(2T²)`. The stack pushes that
//! acceleration through the force sensor, on top of the preload:
//!
//! * **shaped** (the reference shaped by the inverse of the stage's mode): the
//!   stage follows the step, and the dynamic force is its mass's, `M·a`, with
//!   `M = κ/ω²` (κ the dynamic force per µm of command above the mode, ω the
//!   mode's angular frequency) — the least any loop can ask for the step
//!   (taken with the loops' [`SHAPED_MARGIN`]);
//! * **unshaped**: the mode lags the command `u` and rings after it; the stack
//!   is compressed or stretched by `u − x`, and the dynamic force is
//!   `κ·max|u − x|` over the step and the ringing after it, `x` the mode's
//!   response (`ẍ = ω²(u − x) − 2ζωẋ`), simulated at the control rate. A short
//!   step (below a period of the mode) takes the stack through the whole of `κ·A`,
//!   one near a period through up to twice the mass's force.
//!
//! Both are the model's linear dynamics, without the loops: on the emulated
//! stage as built (mode 856 Hz, κ 6.46 N/µm) a 25 µm step in 0.5 ms asks for
//! 110 N shaped, and latches `ForceOutOfRange` (the reading leaves its
//! 15–178 N window). The loops make the real force larger unshaped (the
//! position loop pushes the lagging mode: 34 N of 24 N at 1.5 ms), so the
//! unshaped figure is taken [`UNSHAPED_MARGIN`] times. Shaped, the position
//! loop makes it smaller (0.45–0.94 times the mass's force for 10 and 25 µm
//! in 0.5–1.05 ms: the stage lags the step), but the damping alone (open
//! loop) larger: up to 1.14 times (30 → 5 µm in 0.8 ms, 43.0 N predicted:
//! 48.8 N below the preload), and a 10 → 20 µm step in 0.5 ms (44.1 N, in
//! the 46.8 N of room) took the reading out of its window at 50 N below the
//! preload in one sequence of steps; so the shaped figure is taken
//! [`SHAPED_MARGIN`] times.

/// The unshaped force taken this many times the mode's alone (the loops
/// added up to 1.4 times on the emulated stage as built: see the module docs).
pub const UNSHAPED_MARGIN: f32 = 1.5;
/// The shaped force taken this many times the mass's (the damping alone
/// added up to 1.14 times on the emulated stage as built: see the module
/// docs).
pub const SHAPED_MARGIN: f32 = 1.25;
/// Ticks simulated after the step: two periods of the mode at most, where the
/// ringing's largest swing lies.
const RINGING_PERIODS: f32 = 2.0;
/// Steps of the simulation per period of the mode (semi-implicit Euler: a
/// phase error of about 0.02 % per period), whatever the control rate: at most
/// `(LONG_PERIODS + RINGING_PERIODS)·STEPS_PER_PERIOD` = 1 152 steps, so that a
/// model with a slow mode does not hold the link task (and its watchdog).
const STEPS_PER_PERIOD: f32 = 96.0;
/// Beyond this many periods of the mode in the step, the unshaped force is
/// bounded by the shaped one's 3/2 (the ringing left is below 1/(4(fT)²) of
/// `A` there) instead of simulated.
const LONG_PERIODS: f32 = 10.0;

/// The stage's first mode and its force channel, as the model declares them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    /// Frequency, Hz (> 0).
    pub hz: f32,
    /// Damping ratio.
    pub zeta: f32,
    /// κ: the dynamic force per µm of command above the mode, N/µm.
    pub kappa: f32,
}

/// The largest dynamic force, N, a step of `amplitude_um` (µm, either sign)
/// over `ticks` ticks at `rate_hz` asks of the stack of a stage whose first
/// mode is `m`, `shaped` or not (see the module docs; with the loops'
/// [`SHAPED_MARGIN`] or [`UNSHAPED_MARGIN`]).
pub fn step_force(amplitude_um: f32, ticks: u32, rate_hz: f32, m: Mode, shaped: bool) -> f32 {
    let a = amplitude_um.abs();
    let t = ticks.max(1) as f32 / rate_hz;
    let w = core::f32::consts::TAU * m.hz;
    let pi = core::f32::consts::PI;
    // M·a_peak = κ·A·π²/(2·(ωT)²).
    let inertial = m.kappa * a * pi * pi / (2.0 * (w * t) * (w * t));
    if shaped {
        return SHAPED_MARGIN * inertial;
    }
    let periods = t * m.hz;
    let alone = if periods >= LONG_PERIODS {
        1.5 * inertial
    } else {
        m.kappa * lag_peak(a, t, w, m.zeta, m.hz)
    };
    UNSHAPED_MARGIN * alone
}

/// The largest `|u − x|`, µm, for the raised cosine `u` of `a` µm over `t`
/// seconds and the mode's response `x`, from rest.
fn lag_peak(a: f32, t: f32, w: f32, zeta: f32, mode_hz: f32) -> f32 {
    let dt = 1.0 / (STEPS_PER_PERIOD * mode_hz);
    let n = ((t * mode_hz + RINGING_PERIODS) * STEPS_PER_PERIOD) as u32;
    let (mut x, mut v, mut peak) = (0.0f32, 0.0f32, 0.0f32);
    for k in 0..n {
        let time = k as f32 * dt;
        let u = if time < t {
            0.5 * a * (1.0 - cos_half_turns(time / t))
        } else {
            a
        };
        v += (w * w * (u - x) - 2.0 * zeta * w * v) * dt;
        x += v * dt;
        peak = peak.max((u - x).abs());
    }
    peak
}

/// The shortest step of `amplitude_um` (µm), ticks, whose force stays within
/// `room` (N): `from_ticks` if it does, else searched above it by doubling,
/// then halving the interval; `None` beyond a second.
pub fn shortest_within(
    amplitude_um: f32,
    from_ticks: u32,
    rate_hz: f32,
    m: Mode,
    shaped: bool,
    room: f32,
) -> Option<u32> {
    let fits = |ticks: u32| step_force(amplitude_um, ticks, rate_hz, m, shaped) <= room;
    let most = rate_hz as u32;
    let mut lo = from_ticks.max(1);
    if fits(lo) {
        return Some(lo);
    }
    // `lo` does not fit: double until one does.
    let mut hi = lo;
    while !fits(hi) {
        if hi >= most {
            return None;
        }
        lo = hi;
        hi = (hi * 2).min(most);
    }
    // The force falls with the duration, but not monotonically (unshaped, near
    // whole periods of the mode): `lo` does not fit, `hi` does, and the
    // interval narrows keeping both so; the answer's tick less does not fit.
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if fits(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(hi)
}

/// `cos(π·s)` for `s` in `[0, 1)`: the ISR's own cosine table
/// ([`super::wave::cos_turns`]), which draws the step.
fn cos_half_turns(s: f32) -> f32 {
    let phase = (s * 2_147_483_648.0) as u32;
    super::wave::cos_turns(phase) as f32 / (1u32 << 30) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    const BUILT: Mode = Mode {
        hz: 856.4,
        zeta: 0.023,
        kappa: 6.46,
    };

    #[test]
    fn a_shaped_step_asks_for_its_mass_s_force() {
        // 25 µm in 0.5 ms (10 ticks): κ·A·π²/(2(ωT)²) = 110 N, with the
        // loops' margin.
        let f = step_force(25.0, 10, 20_000.0, BUILT, true);
        assert!((f / SHAPED_MARGIN - 110.0).abs() < 1.0, "{f}");
        // Four times less at twice the duration; the sign does not matter.
        let g = step_force(-25.0, 20, 20_000.0, BUILT, true);
        assert!((g * 4.0 - f).abs() < 0.5, "{g}");
    }

    #[test]
    fn an_unshaped_step_asks_for_more_near_the_mode_s_period() {
        // Short: nearly the whole of κ·A; near a period: more than the mass's
        // force; long: little (the loops' margin taken out).
        let alone = |ticks| step_force(25.0, ticks, 20_000.0, BUILT, false) / UNSHAPED_MARGIN;
        let short = alone(2);
        assert!(
            short > 0.8 * 6.46 * 25.0 && short < 1.1 * 6.46 * 25.0,
            "{short}"
        );
        let near = alone(20);
        assert!(
            near > 2.0 * step_force(25.0, 20, 20_000.0, BUILT, true) / SHAPED_MARGIN,
            "{near}"
        );
        assert!(
            (60.0..80.0).contains(&near),
            "{near} (f64 simulation: 70 N)"
        );
        assert!(alone(400) < 1.0, "{}", alone(400));
    }

    #[test]
    fn the_shortest_step_within_a_room_fits_and_one_tick_less_does_not() {
        for shaped in [true, false] {
            let k = shortest_within(25.0, 10, 20_000.0, BUILT, shaped, 40.0).unwrap();
            assert!(step_force(25.0, k, 20_000.0, BUILT, shaped) <= 40.0);
            assert!(
                step_force(25.0, k - 1, 20_000.0, BUILT, shaped) > 40.0,
                "{shaped}: {k}"
            );
            println!("shaped {shaped}: {} ms", k as f32 / 20.0);
        }
        // Already within: the duration asked for.
        assert_eq!(
            shortest_within(1.0, 30, 20_000.0, BUILT, true, 40.0),
            Some(30)
        );
        // Nothing fits a room of nothing.
        assert_eq!(shortest_within(1.0, 30, 20_000.0, BUILT, true, 0.0), None);
    }
}
