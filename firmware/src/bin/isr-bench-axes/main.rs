//! Three axes in one tick (issue 44): the XYZ stage's three axes on the
//! closed-loop model (damping, position PI, the preview's feedforward
//! and the lead on each), decoupled (the input matrix takes out the
//! sensors' cross-talk, the output matrix the flexure's parasitic
//! motion, the preload coupling each stack's load from the others), the
//! trigger output on its costliest condition, each axis's
//! tick recorded. Its phases as the one-axis loop's: closing the loops
//! during a step on every axis, a 5 Hz full stroke, moves the governor
//! takes at its limits. Printed as `isr_tick_three_axes_instructions`
//! (the worst tick of every phase) and its stack.
//!
//! Its own binary: the one-axis benchmark (`isr-bench`) measures the
//! board's one-axis loop as the board builds it, which a three-axis loop in
//! the same program would change (the compiler then shares the axis's code
//! between the two instead of inlining it into each).
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
#[path = "../isr-bench/measure.rs"]
mod measure;

#[cfg(target_os = "none")]
mod bench {

    use crate::measure::{
        calibrate, closed_image, exit, full_stroke, run_ticks, start_counter, Counts, STEPS,
    };
    use core::mem::MaybeUninit;
    use cortex_m_rt::entry;
    use fpi_firmware::board::capacity::IMAGE_BYTES;
    // The device crate provides the interrupt vector table.
    use cortex_m_semihosting::hprintln;
    use fpi_firmware::board::capacity::{Store, MAX_AXES, RECORDER_SAMPLES, STREAM_POINTS};
    use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use fpi_firmware::board::factory_model::CONTROLLER;
    use fpi_firmware::control::exchange::{AxisSet, Exchange, Order, Posted};
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::reference::{step_phase_for, SourceOrder};
    use fpi_firmware::control::slots::{Origin, Spare};
    use fpi_firmware::control::tracking::LoopMode;
    use fpi_firmware::emulation::virtual_io::SimLink;
    use piezo_fpi::decoupling::{Decoupling, Matrix, Preload};
    use piezo_fpi::q::Micrometres;
    use piezo_fpi::trigger::{Condition, Trigger};
    use stm32f4xx_hal as _;

    type Three = crate::measure::Loop<3>;

    static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);
    static LINK_Y: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);
    static LINK_Z: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

    /// Two model stores in the CCM (`memory.x`), which the benchmark's
    /// 128 KiB of SRAM cannot hold beside the one-axis phases' two.
    #[link_section = ".ccm.stores"]
    static mut MORE: [MaybeUninit<Store>; 2] = [MaybeUninit::uninit(), MaybeUninit::uninit()];

    /// The two stores, empty; called once (out of line: its frame may
    /// hold a store's initial value).
    #[inline(never)]
    fn more_stores() -> [&'static mut Store; 2] {
        // SAFETY: called once, from `main`, before anything else names
        // the static; each element is written before it is lent out.
        let [y, z] = unsafe { &mut *core::ptr::addr_of_mut!(MORE) };
        [y.write(Store::new()), z.write(Store::new())]
    }

    /// `(I + c)⁻¹` of the XYZ stage's couplings as built
    /// (`piezo_sim::axes`): cross gains (Y 1.5 % of X, X 2 % of Y, Z 1 %
    /// of X and Y, X and Y 0.5 % of Z) and sensor cross-talk (0.2 %); its
    /// preload coupling (0.5 N/µm between X and Y, 0.2 with Z).
    fn decoupling() -> Option<Decoupling<MAX_AXES>> {
        let cross = [[0.0, 0.02, 0.005], [0.015, 0.0, 0.005], [0.01, 0.01, 0.0]];
        let talk = [
            [0.0, 0.002, 0.002],
            [0.002, 0.0, 0.002],
            [0.002, 0.002, 0.0],
        ];
        let preload = [[0.0, 0.5, 0.2], [0.5, 0.0, 0.2], [0.2, 0.2, 0.0]];
        Some(Decoupling {
            input: Matrix::undoing(talk).ok()?,
            output: Matrix::undoing(cross).ok()?,
            preload: Preload::from_f64(preload).ok()?,
        })
    }

    /// Posts `order` to every axis and runs a tick; whether it applied.
    fn order(lp: &mut Three, x: &mut Exchange<'static, 3>, seq: u16, order: Order) -> bool {
        x.order = Some(Posted {
            seq,
            axes: AxisSet::ALL,
            order,
        });
        lp.tick(x);
        matches!(x.applied.take(), Some(a) if a.result.is_ok())
    }

    /// The three-axis phases on `spares` (each loaded with `image`, the
    /// closed-loop model); whether they ran clean. Out of line: the
    /// loop lives in its frame, not in `main`'s.
    #[inline(never)]
    fn report(
        spares: [Spare; 3],
        image: &'static [u8],
        recorder: &'static mut Recorder<RECORDER_SAMPLES>,
        points: &'static mut Points<STREAM_POINTS>,
        baseline: u32,
    ) -> bool {
        let mut models = spares.map(|mut s| {
            s.load(image).ok()?;
            s.activate(image, Origin::Received).ok()
        });
        let [Some(a), Some(b), Some(c)] = [models[0].take(), models[1].take(), models[2].take()]
        else {
            hprintln!("isr_tick_three_axes: the closed-loop model was refused");
            return false;
        };
        let rest = CONTROLLER.preload(Micrometres::ZERO).to_num::<f32>();
        let links = [&LINK, &LINK_Y, &LINK_Z];
        for link in links {
            link.set_force(rest);
            link.set_position(0.0);
        }
        let hw = links.map(|l| (l.hardware(), l.analog()));
        let [(h0, a0), (h1, a1), (h2, a2)] = hw;
        let mut lp = Three::new([(a, h0, a0), (b, h1, a1), (c, h2, a2)]);
        let mut x = Exchange::new(recorder, points);
        let travel = Condition::Travel {
            step: Micrometres::from_num(0.1),
        };
        let (Ok(trigger), Some(d)) = (Trigger::new(travel, 2), decoupling()) else {
            return false;
        };
        let up = SourceOrder::Step {
            target: Micrometres::from_num(38),
            phase_step: step_phase_for(STEPS + 20),
        };
        let set_up = order(&mut lp, &mut x, 1, Order::Record { decimation: 1 })
            && order(&mut lp, &mut x, 2, Order::Trigger(trigger))
            && order(&mut lp, &mut x, 3, Order::Decoupling(d))
            && order(&mut lp, &mut x, 4, Order::Source(up))
            && order(&mut lp, &mut x, 5, Order::Loop(LoopMode::Closed));
        if !set_up {
            hprintln!("isr_tick_three_axes: an order was refused");
            return false;
        }
        // Closing the loops during a step, a full stroke, governed moves.
        let (mut all, mut ok, mut depth) = (Counts::new(), true, 0);
        let wave = Order::Source(SourceOrder::Wave(full_stroke(5.0)));
        let fast = |target: i32| {
            Order::Source(SourceOrder::Move {
                target: Micrometres::from_num(target),
                step: Micrometres::from_num(2),
            })
        };
        let phases = [None, Some(wave), Some(fast(5)), Some(fast(35))];
        for (seq, o) in (6..).zip(phases) {
            if let Some(o) = o {
                ok &= order(&mut lp, &mut x, seq, o);
            }
            let (c, part_ok, part_depth) =
                run_ticks(&mut lp, &mut x, [&LINK, &LINK_Y, &LINK_Z], baseline);
            all.merge(&c);
            ok &= part_ok;
            depth = depth.max(part_depth);
        }
        hprintln!(
            "isr_tick_three_axes_instructions n=9: {} (three axes in closed loop, decoupled: each with damping, PI, preview feedforward and lead; input and output matrices and the preload coupling; trigger (travel); every axis recorded; closing the loops during a step, a full stroke, governed moves; {}){}",
            all.max,
            all,
            if ok { "" } else { " FAILED: faulted or not recording" }
        );
        for (i, a) in x.snapshot.axes.iter().enumerate() {
            if let Some((f, at)) = a.fault {
                hprintln!("  axis {} fault at tick {}: {}", i, at, f.message());
            }
        }
        hprintln!("isr_tick_three_axes_stack_bytes: {}", depth);
        ok
    }

    #[entry]
    fn main() -> ! {
        start_counter();
        let (baseline, nops) = calibrate();
        // The closed-loop model's image, built in the first store; then
        // loaded into it and the two others.
        let ok = match (
            cortex_m::singleton!(: Store = Store::new()),
            cortex_m::singleton!(: [u8; IMAGE_BYTES] = [0; IMAGE_BYTES]),
            cortex_m::singleton!(: Recorder<RECORDER_SAMPLES> = Recorder::new()),
            cortex_m::singleton!(: Points<STREAM_POINTS> = Points::new()),
        ) {
            (Some(store), Some(buf), Some(recorder), Some(points)) => {
                match closed_image(store, buf) {
                    Some(image) => {
                        let [y, z] = more_stores();
                        let spares = [Spare::new(store), Spare::new(y), Spare::new(z)];
                        report(spares, image, recorder, points, baseline)
                    }
                    None => false,
                }
            }
            _ => false,
        };
        // ±1: the two calibration calls may be compiled with call sequences that
        // differ by an instruction.
        exit(nops.abs_diff(1000) <= 1 && ok)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("isr-bench-axes runs on the emulated Cortex-M4: use `cargo isr-bench`.");
    std::process::exit(2);
}
