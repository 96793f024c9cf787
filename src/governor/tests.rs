use super::analysis::{floor, Feedforward, Loops, Tracking};
use super::*;
use crate::damping::DynamicsSpec;
use crate::q::{CreepRate, NewtonsPerUm};
use crate::stability::{Laws, Plant};

const RATE: u32 = 20_000;

fn um(x: f64) -> Micrometres {
    Micrometres::from_num(x)
}

fn window() -> Interval<Micrometres> {
    Interval {
        lo: um(0.0),
        hi: um(39.92),
    }
}

/// A governor that only the window limits (tiny envelopes, fast decay).
fn generous() -> GovernorConfig {
    GovernorConfig::new(
        window(),
        &Limits {
            accel: 1.0,
            speed: 2.0,
            ramp: (0.5, 1e-6),
            lead: 0.0,
        },
    )
}

/// The stage as built, as a model declares it.
fn as_built() -> DynamicsSpec {
    DynamicsSpec {
        mode_mhz: 856_400,
        damping: CreepRate::from_num(0.03),
        lag_mhz: 0,
        force_gain: NewtonsPerUm::from_num(6.46),
    }
}

fn open_loops(d: Option<&DynamicsSpec>) -> Loops<'_> {
    Loops {
        rate_hz: RATE,
        dynamics: d,
        laws: Laws::default(),
        tracking: Tracking::Open,
        delay: 0,
        feedforward: Feedforward::Identity,
        lead: 0.0,
    }
}

/// A small deterministic generator (xorshift).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Runs the governor on `source` (µm per tick) and a stage `plant` (f64, the
/// command held over a tick), open loop: the governed references and the
/// stage's positions.
fn run(cfg: &GovernorConfig, plant: &Plant, x0: f64, source: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut st = GovernorState::at_rest(um(x0));
    let mut y = [x0, x0, 0.0];
    let (mut gs, mut xs) = (Vec::new(), Vec::new());
    for &r in source {
        let g = cfg.process(&mut st, um(r)).to_num::<f64>();
        xs.push(y[1]);
        gs.push(g);
        let p = &plant.phi;
        y = [
            p[0][0] * y[0] + p[0][1] * y[1] + p[0][2] * y[2] + plant.gamma[0] * g,
            p[1][0] * y[0] + p[1][1] * y[1] + p[1][2] * y[2] + plant.gamma[1] * g,
            p[2][0] * y[0] + p[2][1] * y[1] + p[2][2] * y[2] + plant.gamma[2] * g,
        ];
    }
    (gs, xs)
}

#[test]
fn a_source_within_the_limits_passes_to_the_bit() {
    let cfg = generous();
    let mut st = GovernorState::at_rest(um(20.0));
    // A 100 Hz triangle and a 200 Hz sine over 5–35 µm: 0.3 and 0.94 µm/tick.
    for k in 0..4000u32 {
        let t = k as f64 / RATE as f64;
        let tri = 20.0
            + 15.0
                * (2.0 / core::f64::consts::PI)
                * (core::f64::consts::TAU * 100.0 * t).sin().asin();
        let sine = 20.0 + 15.0 * (core::f64::consts::TAU * 200.0 * t).sin();
        for r in [tri, sine] {
            let r = um(r);
            let _ = cfg.process(&mut st, r);
        }
    }
    let mut st = GovernorState::at_rest(um(20.0));
    for k in 0..4000u32 {
        let t = k as f64 / RATE as f64;
        let r = um(20.0 + 15.0 * (core::f64::consts::TAU * 200.0 * t).sin());
        assert_eq!(cfg.process(&mut st, r), r, "tick {k}");
        assert!(!st.governed());
    }
}

#[test]
fn a_jump_is_limited_in_speed_and_acceleration_and_lands_without_overshoot() {
    let cfg = generous();
    let (a, v) = (cfg.accel(), cfg.speed());
    for (from, to) in [(5.0, 39.0), (39.0, 0.5), (20.0, 20.3), (0.0, 39.92)] {
        let mut st = GovernorState::at_rest(um(from));
        let mut last = [from, from];
        let mut governed = 0;
        for k in 0..400 {
            let g = cfg.process(&mut st, um(to)).to_num::<f64>();
            governed += st.governed() as u32;
            let (dv, dd) = (g - last[1], g - 2.0 * last[1] + last[0]);
            assert!(dv.abs() <= v + 1e-4, "{from}→{to} tick {k}: speed {dv}");
            assert!(
                dd.abs() <= a + 1e-4,
                "{from}→{to} tick {k}: acceleration {dd}"
            );
            let (lo, hi) = (from.min(to), from.max(to));
            assert!(
                g >= lo - 1e-4 && g <= hi + 1e-4,
                "{from}→{to} tick {k}: {g}"
            );
            last = [last[1], g];
        }
        assert_eq!(last[1], um(to).to_num::<f64>(), "{from}→{to}: arrived");
        assert!(!st.governed(), "{from}→{to}: passes again once there");
        assert!(governed > 0 || (to - from).abs() < a);
    }
}

#[test]
fn the_window_holds_the_governed_reference() {
    let cfg = generous();
    let mut st = GovernorState::at_rest(um(39.0));
    for _ in 0..100 {
        let g = cfg.process(&mut st, um(60.0));
        assert!(g <= window().hi);
    }
    assert_eq!(st.position(), window().hi);
}

/// The floor stage's governor keeps a stage at the floor mode in its window
/// whatever the source: jumps, square waves at the mode, a chirp through it,
/// noise. On the stage itself (its own damping, not the halved one the
/// envelopes cover), and on a stiffer one.
#[test]
fn the_floor_governor_keeps_a_stage_at_the_floor_in_its_window() {
    let loops = open_loops(None);
    let limits = loops.limits(0.0, 1.0);
    let cfg = GovernorConfig::new(window(), &limits);
    println!("floor: {limits:?}");
    let d = floor(RATE);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    // The floor itself, a stiffer stage, stage A's least damped variant
    // (680 Hz, ζ 0.015) and a stiff, lightly damped one.
    for (scale, zeta) in [(1.0, FLOOR), (1.25, FLOOR), (1.36, 0.015), (2.0, 0.01)] {
        let plant = Plant::new(&d, RATE, scale, Some(zeta), 1.0);
        for case in 0..24 {
            let src = source(case, &mut rng, 500.0 * scale, 6000);
            let (_, xs) = run(&cfg, &plant, 20.0, &src);
            let (lo, hi) = extent(&xs);
            assert!(
                lo >= -MARGIN_UM - 1e-3 && hi <= 39.92 + MARGIN_UM + 1e-3,
                "mode ×{scale} ζ {zeta} case {case}: {lo:.3}…{hi:.3} µm"
            );
        }
    }
}

const FLOOR: f64 = super::analysis::FLOOR_DAMPING;

/// The governor of the as-built stage's model, open loop and without damping,
/// keeps the stage and stages 20 % slower, 25 % faster and half as damped in
/// the window.
#[test]
fn a_model_s_governor_keeps_the_stages_it_covers_in_the_window() {
    let d = as_built();
    let loops = open_loops(Some(&d));
    let limits = loops.limits(40.0, 1.0);
    println!("as built, open: {limits:?}");
    let cfg = GovernorConfig::new(window(), &limits);
    let mut rng = Rng(12345);
    for (scale, zeta) in [(1.0, 0.03), (0.8, 0.015), (1.25, 0.015)] {
        let plant = Plant::new(&d, RATE, scale, Some(zeta), 1.0);
        for case in 0..24 {
            let src = source(case, &mut rng, 856.4 * scale, 6000);
            let (_, xs) = run(&cfg, &plant, 20.0, &src);
            let (lo, hi) = extent(&xs);
            assert!(
                lo >= -MARGIN_UM - 1e-3 && hi <= 39.92 + MARGIN_UM + 1e-3,
                "mode ×{scale} ζ {zeta} case {case}: {lo:.3}…{hi:.3} µm"
            );
        }
    }
}

/// A source that tries to throw the stage out: jumps between the stroke's
/// ends, square waves and sines at the mode `mode_hz`, a chirp through it,
/// noise.
fn source(case: u32, rng: &mut Rng, mode_hz: f64, n: usize) -> Vec<f64> {
    let tau = core::f64::consts::TAU;
    let f = mode_hz * (0.8 + 0.4 * rng.next());
    let hi = 39.92;
    (0..n)
        .map(|k| {
            let t = k as f64 / RATE as f64;
            match case % 6 {
                0 => {
                    if (k / 400) % 2 == 0 {
                        0.0
                    } else {
                        hi
                    }
                }
                1 => 20.0 + 20.0 * (tau * f * t).sin().signum(),
                2 => 35.0 + 5.0 * (tau * f * t).sin(),
                3 => 20.0 + 20.0 * (tau * (50.0 + 2.0 * mode_hz * t / 0.3) * t).sin(),
                4 => hi * rng.next(),
                _ => {
                    if rng.next() < 0.02 {
                        hi * rng.next()
                    } else {
                        f64::NAN
                    }
                }
            }
        })
        .scan(20.0, |held, x| {
            if x.is_finite() {
                *held = x.max(0.0).min(hi);
            }
            Some(*held)
        })
        .collect()
}

fn extent(xs: &[f64]) -> (f64, f64) {
    xs.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        })
}

#[test]
fn slow_motion_passes_the_floor_governor() {
    // A full-stroke 5 Hz sine and a 1 mm/s ramp need nothing of it.
    let cfg = GovernorConfig::new(window(), &open_loops(None).limits(0.0, 1.0));
    let mut st = GovernorState::at_rest(um(20.0));
    let mut governed = 0;
    for k in 0..8000u32 {
        let t = k as f64 / RATE as f64;
        let r = um(20.0 + 18.0 * (core::f64::consts::TAU * 5.0 * t).sin());
        let g = cfg.process(&mut st, r);
        governed += (g != r) as u32;
    }
    assert!(governed < 200, "{governed} of 8000 ticks governed");
}

/// The loops of the isr-bench's closed-loop model (autotune's, as measured on
/// the stage as built), in each of their sets: the governor's limits printed.
#[test]
fn the_limits_of_a_tuned_model_s_loop_sets() {
    use crate::biquad::ShapingSpec;
    use crate::damping::DampingSpec;
    use crate::feedback::FeedbackSpec;
    use crate::q::LoopGain;
    let rate = RATE as f64;
    let d = DynamicsSpec {
        mode_mhz: 850_852,
        damping: CreepRate::from_num(0.030_098),
        lag_mhz: 2_026_966,
        force_gain: NewtonsPerUm::from_num(7.017),
    };
    let corner = CreepRate::from_num(0.030_929_031_800_5);
    let damping = DampingSpec {
        gain: LoopGain::from_num(1315.733 / rate),
        highpass: corner,
        leak: corner,
        limit: um(39.921),
    };
    let feedback = FeedbackSpec {
        kp: LoopGain::from_num(0.75),
        ki: LoopGain::from_num(1762.611 / rate),
        limit: um(9.98),
        sensor: Interval {
            lo: um(-10.0),
            hi: um(50.0),
        },
        tolerance: um(6.0),
    };
    let one = f64::from(1 << crate::biquad::COEFF_FRAC);
    let mut taps = [
        1.67, -0.08, -0.63, -0.57, -0.7, -0.04, 0.61, 0.74, 0.2, -0.1, -0.15, 0.05, 0.1, -0.05,
        -0.05, 0.02,
    ]
    .map(|t| (t * one) as i32);
    taps[0] += (1 << crate::biquad::COEFF_FRAC) - taps.iter().sum::<i32>();
    let fir = ShapingSpec {
        preview: 4,
        taps,
        ..ShapingSpec::IDENTITY
    }
    .fir()
    .unwrap()
    .unwrap();
    let split = crate::control::split_rate(crate::control::DEFAULT_SPLIT_HZ, RATE).to_bits();
    for (name, tracking, damped, shaped) in [
        ("open", Tracking::Open, false, false),
        ("open, damped", Tracking::Open, true, false),
        ("open, damped, feedforward", Tracking::Open, true, true),
        ("closed, damped, feedforward", Tracking::Closed, true, true),
        ("closed, damped", Tracking::Closed, true, false),
        ("closed, feedforward", Tracking::Closed, false, true),
    ] {
        let laws = Laws::of(split, damped.then_some(&damping), Some(&feedback));
        let loops = Loops {
            rate_hz: RATE,
            dynamics: Some(&d),
            laws,
            tracking,
            delay: 4,
            feedforward: if shaped {
                Feedforward::Taps(&fir)
            } else {
                Feedforward::Identity
            },
            lead: if shaped && damped { 7.017 } else { 0.0 },
        };
        let e = loops.envelopes();
        let l = loops.limits(40.0, 1.3);
        println!(
            "{name}: accel {:.4} µm/tick², ramp ρ {:.6} c {:.3}, lead {:.3} ticks, horizon {} (steady bound per µm/tick² {:.1} µm)",
            l.accel,
            l.ramp.0,
            l.ramp.1,
            l.lead,
            e.horizon,
            l.ramp.1 / (1.0 - l.ramp.0)
        );
        assert!(l.ramp.1.is_finite() && l.ramp.1 > 0.0, "{name}");
        assert!(e.unsettled == 0 || name == "closed, feedforward", "{name}");
    }
}

/// The open loop of a tuned model (slow decay, a large ramp gain): the
/// acceleration toward a governed source is a small fraction of `A`.
fn slow_envelope() -> GovernorConfig {
    GovernorConfig::new(
        window(),
        &Limits {
            accel: 0.1738,
            speed: 1.0,
            ramp: (0.998_047, 5.212),
            lead: -6.161,
        },
    )
}

/// A source that jumps, or ramps faster than the governor lets it, and then
/// holds is reached without swinging past it (further than the ramp's stop
/// distance at `A` and [`OVERSHOOT_UM`]), and landed on to the bit: the
/// speed a source handed over at `A` is taken off at up to `A` (a bang-bang
/// at the gentle acceleration alone swung ±12 µm about it for ever).
#[test]
fn a_governed_source_is_reached_without_swinging_past_it() {
    let cfg = slow_envelope();
    assert!(cfg.limits.accel_gov * 50 < cfg.limits.accel);
    let hold = |from: f64, to: f64, ramp: usize| {
        let mut s = vec![from; 10];
        s.extend((1..=ramp).map(|k| from + (to - from) * k as f64 / ramp as f64));
        s.extend(std::iter::repeat_n(to, 8000));
        s
    };
    for (from, to, ramp) in [
        (20.0, 10.0, 1),
        (20.0, 10.0, 30),
        (10.0, 20.0, 40),
        (5.0, 35.0, 60),
    ] {
        let mut st = GovernorState::at_rest(um(from));
        // A source that stops dead hands over its speed: braking it off at
        // `A` passes the source's end by its stop distance at most.
        let v = ((to - from) / ramp as f64).abs().min(1.0);
        let past = v * v / (2.0 * cfg.accel()) + v + OVERSHOOT_UM;
        let (lo, hi) = (from.min(to) - past, from.max(to) + past);
        let mut landed = None;
        for (i, &r) in hold(from, to, ramp).iter().enumerate() {
            let g = cfg.process(&mut st, um(r)).to_num::<f64>();
            assert!(g >= lo && g <= hi, "{from}→{to} over {ramp}: {g} at {i}");
            if landed.is_none() && i > 10 + ramp && !st.governed() {
                landed = Some(i);
            }
            if let Some(at) = landed {
                assert!(
                    !st.governed() && g == um(to).to_num::<f64>(),
                    "{from}→{to}: left {to} at {i} (landed at {at})"
                );
            }
        }
        assert!(landed.is_some(), "{from}→{to} over {ramp}: never landed");
    }
}

/// A full-stroke wave started away from where the stage rests (at the
/// window's edge) on the floor governor: the governed reference catches up
/// with it within its first cycle and passes it from then on (chasing it at
/// its own speed, a jump's difference taken for a speed, kept it governed
/// for ever).
#[test]
fn a_governed_wave_is_caught_up_with() {
    let (lo_edge, _) = (window().lo.to_num::<f64>(), ());
    let cfg = GovernorConfig::new(window(), &analysis_floor_limits());
    let mut st = GovernorState::at_rest(um(lo_edge));
    let mut last_governed = 0;
    for k in 0..8000 {
        let r = 20.0 - 18.0 * (2.0 * std::f64::consts::PI * 5.0 * k as f64 / RATE as f64).cos();
        cfg.process(&mut st, um(r));
        if st.governed() {
            last_governed = k;
        }
    }
    assert!(last_governed < 4000, "governed until tick {last_governed}");
}

/// The floor's limits (as the floor governor test prints them).
fn analysis_floor_limits() -> Limits {
    Limits {
        accel: 1.0,
        speed: 1.0,
        ramp: (0.998_046_875, 6.284),
        lead: -0.755,
    }
}

/// A move out of the park at the window's foot (1 mm/s, 0 → 20 µm) on the
/// floor's limits: the governor leaves the edge and catches up with the
/// move, which then ends on time (it once tried to land on the source at each
/// tick, failed the check and braked to a stop, and crept for 50 ms); on the
/// floor stage the stage stays above the window's foot less the margin.
#[test]
fn a_move_out_of_the_park_catches_up_with_its_source() {
    let cfg = GovernorConfig::new(window(), &analysis_floor_limits());
    let mut st = GovernorState::at_rest(um(0.0));
    let (mut last_governed, mut bound) = (0, 0.0f64);
    for k in 0..2000u32 {
        let r = (f64::from(k) * 0.05).min(20.0);
        cfg.process(&mut st, um(r));
        if st.governed() {
            last_governed = k;
        }
        bound = bound.max(st.bound());
    }
    println!("governed until tick {last_governed} of the move's 400; the envelope's largest bound {bound:.2} µm");
    let plant = Plant::new(&floor(RATE), RATE, 1.0, Some(FLOOR), 1.0);
    let src: Vec<f64> = (0..2000).map(|k| (f64::from(k) * 0.05).min(20.0)).collect();
    let (gs, xs) = run(&cfg, &plant, 0.0, &src);
    let ring = xs[400..]
        .iter()
        .map(|x| (x - 20.0).abs())
        .fold(0.0, f64::max);
    let dev = xs
        .iter()
        .zip(&gs)
        .map(|(x, g)| (x - g).abs())
        .fold(0.0, f64::max);
    let lowest = extent(&xs).0;
    println!("floor stage: lowest {lowest:.3} µm, |x − g| ≤ {dev:.3} µm, after the move |x − 20| ≤ {ring:.3} µm");
    assert!(lowest >= -MARGIN_UM, "{lowest}");
    assert!(last_governed < 250, "governed until tick {last_governed}");
    assert_eq!(st.position(), um(20.0));
}
