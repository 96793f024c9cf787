//! The controller's unit tests: the force channel's split and learning, the
//! plausibility checks and faults, the park, the hand-overs and the lagging
//! forward bank.

use super::*;
use crate::error::Field;
use crate::q::{CreepRate, VoltsPerUm};
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

fn with(force: Interval<Newtons>, tolerance: Newtons) -> Result<TestController, ModelError> {
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
    let model = Newtons::from_raw(c.f_f().eval(st.x_pea_est().raw()));
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
        0.95 * c.f_f().eval(st.x_pea_est().raw()).to_num::<f64>()
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
    let swing = (c.f_f().eval(c.f_k_inv().eval(um(20.0).raw()))
        - c.f_f().eval(c.f_k_inv().eval(um(2.0).raw())))
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
fn plausible(c: &TestController, st: &mut ControllerState<3>, x_ref: Micrometres) -> StepOutput {
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
            let expected = Newtons::from_raw(cfg.f_f().eval(st.x_pea_est().raw()));
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

/// Frozen in the middle of a swing whose preload stays within the tolerance of
/// the frozen reading (±0.6 × 15 N): the residual never leaves the tolerance, but
/// the preload moves by more than half of it under an unchanged reading, within
/// the first half swing.
#[test]
fn a_reading_frozen_mid_swing_is_seen_within_the_swing() {
    let c = testkit::controller();
    let mut st = c.initial_state();
    drive_to(&c, &mut st, 1.0);
    assert_eq!(drive_to(&c, &mut st, 12.0).fault, None);
    let mid = st.x_pea_est().to_num::<f64>();
    let frozen = force_at(&c, st.x_pea_est());
    // The testkit's preload is 60 + 4·x_pea N: ±9 N is ±2.25 µm of extension.
    let stage = |x_pea: f64| c.stage_position(um(x_pea)).to_num::<f64>();
    let (lo, hi) = (stage(mid - 2.25), stage(mid + 2.25));
    let centre = stage(mid);
    let mut seen = None;
    for k in 1..=1600 {
        let phase = 2.0 * core::f64::consts::PI * k as f64 / 800.0;
        let s = phase.sin();
        let x_ref = centre + s * if s > 0.0 { hi - centre } else { centre - lo };
        let out = c.step(&mut st, um(x_ref), frozen);
        let off = force_at(&c, st.x_pea_est()).to_num::<f64>() - frozen.to_num::<f64>();
        assert!(
            off.abs() < 15.0,
            "the preload stays within the tolerance: {off}"
        );
        if let Some(f) = out.fault {
            seen = Some((k, f));
            break;
        }
    }
    let (k, f) = seen.expect("a sensor frozen mid-swing is seen");
    assert_eq!(f, Fault::ForceImplausible);
    assert!(k < 400, "seen within the first half swing: {k}");
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
            let faded = Volts::from_raw(
                left.raw() * Volts::from_num(12).raw() / crate::limits::PARK_FADE.raw(),
            );
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
