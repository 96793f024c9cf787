//! Instructions per control step, counted on the emulated Cortex-M4 (`cargo isr-bench`).
//!
//! Run under `qemu-system-arm -machine netduinoplus2 -icount shift=10,align=off,sleep=off`:
//! every instruction then advances virtual time by 2¹⁰ ns, and SysTick (clocked at
//! QEMU's 168 MHz core clock) advances 0.168 × 1024 ticks per instruction, so a
//! SysTick difference is an exact, repeatable instruction count (DWT CYCCNT reads
//! 0 in QEMU). These are instructions, not M4 cycles.
//!
//! For n = 4, 10, 16 and 32 operators it drives `ControllerConfig::step` along a
//! full-stroke reference with a realistic force and prints
//! `control_step_instructions n=<N>: <worst>` plus min/mean/max, then the same for
//! the slew-limited path (which realigns the inverse memory); the embedded model
//! (its structure in its types); models received at run time
//! (`runtime_model_step_instructions`: the synthetic n = 10 paper FPI and the
//! embedded model as images, loaded into the board's RAM store with its capacity of
//! 10 operators); the board's whole control task on the runtime embedded model
//! (`isr_tick_instructions`); and the stack high-water mark (painted stack).
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod measure;

#[cfg(target_os = "none")]
mod bench {
    use core::hint::black_box;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::hprintln;
    use fpi_firmware::board::capacity::{self, Store, BOARD};
    use fpi_firmware::board::capacity::{RECORDER_SAMPLES, STREAM_POINTS};
    use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use fpi_firmware::board::factory_model::{self, CONTROLLER, MODEL_IMAGE};
    use fpi_firmware::control::exchange::{Exchange, Order, Posted};
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::reference::wave::WavePhase;
    use fpi_firmware::control::reference::SourceOrder;
    use fpi_firmware::control::slots::{Origin, Running, Spare};
    use fpi_firmware::control::task::ControlLoop;
    use fpi_firmware::control::tracking::LoopMode;
    use fpi_firmware::emulation::virtual_io::SimLink;
    use piezo_fpi::control::{
        split_rate, ControllerConfig, ControllerParts, ForceChannel, ForceSource, Interval,
        Supervision, DEFAULT_SPLIT_HZ,
    };
    use piezo_fpi::fpi::{Coupling, Fpi, Identity, Shape};
    use piezo_fpi::model::{image, ModelSpec, TableSpec};
    use piezo_fpi::pi::PiModel;
    use piezo_fpi::q::{Micrometres, Newtons, UmPerNewton, UmPerVolt, Volts, VoltsPerNewton};
    use piezo_fpi::trigger::{Condition, Trigger};
    // The device crate provides the interrupt vector table.
    use stm32f4xx_hal as _;

    use crate::measure::{
        calibrate, closed_image, exit, full_stroke, instructions, run_ticks, start_counter, ticks,
        Counts, STEPS,
    };

    /// A synthetic n-operator model at compile time: thresholds evenly spread over
    /// 0–100 V, the weight budget of the embedded model spread evenly.
    const fn synthetic<const N: usize>() -> Fpi<'static, N> {
        let mut r = [Volts::ZERO; N];
        let mut w = [UmPerVolt::ZERO; N];
        let mut i = 0;
        while i < N {
            r[i] = Volts::from_bits(((((i as i64 + 1) * 100) << 16) / (N as i64 + 1)) as i32);
            w[i] = UmPerVolt::from_bits(((1i64 << 28) / 50 / N as i64) as i32);
            i += 1;
        }
        let pi = match PiModel::new(
            UmPerVolt::from_bits((1 << 28) / 16),
            r,
            w,
            Volts::from_bits(150 << 16),
        ) {
            Ok(p) => p,
            Err(e) => panic!("{}", e.message()),
        };
        // The paper's FPI with compliance: hard dead zone, no saturation, no creep.
        match Fpi::new(
            pi,
            Coupling {
                compliance: UmPerNewton::from_bits(((1i64 << 32) / 50) as i32),
                force_ref: Newtons::from_bits(60 << 16),
                ..Coupling::paper(VoltsPerNewton::from_bits(((1i64 << 32) / 10) as i32))
            },
            Identity,
            Identity,
            [],
        ) {
            Ok(f) => f,
            Err(e) => panic!("{}", e.message()),
        }
    }

    const fn config<const N: usize>(fpi: Fpi<'static, N>) -> ControllerConfig<'static, N> {
        match ControllerConfig::new(ControllerParts {
            fpi,
            f_f: factory_model::F_F,
            f_k: factory_model::F_K,
            f_k_inv: factory_model::F_K_INV,
            limits: factory_model::LIMITS,
            supervision: Supervision {
                reference: CONTROLLER.reference(),
                force: Interval {
                    lo: Newtons::from_bits(20 << 16),
                    hi: Newtons::from_bits(200 << 16),
                },
                // The factory model's tolerances (what the validator lets a
                // model have: checks that can trip).
                force_tolerance: Newtons::from_bits(15 << 16),
                safe_voltage: Volts::ZERO,
                force_source: ForceSource::Measured,
                // The channel every exported model has: the default split.
                channel: ForceChannel {
                    split: split_rate(DEFAULT_SPLIT_HZ, capacity::RATE_HZ),
                    dynamic_limit: Newtons::from_bits(45 << 16),
                },
            },
        }) {
            Ok(c) => c,
            Err(e) => panic!("{}", e.message()),
        }
    }

    static C4: ControllerConfig<'static, 4> = config(synthetic::<4>());
    static C10: ControllerConfig<'static, 10> = config(synthetic::<10>());
    static C16: ControllerConfig<'static, 16> = config(synthetic::<16>());
    static C32: ControllerConfig<'static, 32> = config(synthetic::<32>());

    /// Force the stage would put on the stack at a reference (what the sensor reads).
    fn force_at(x_ref: Micrometres) -> Newtons {
        CONTROLLER.preload(CONTROLLER.extension(x_ref))
    }

    /// The step as its own function, so its code can be inspected and is not
    /// scheduled into the measurement.
    #[inline(never)]
    fn step_of<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        cfg: &ControllerConfig<'a, N, C, G, H>,
        st: &mut piezo_fpi::control::ControllerState<N, C>,
        x: Micrometres,
        f: Newtons,
    ) -> piezo_fpi::control::StepOutput {
        cfg.step(st, x, f)
    }

    /// Instruction counts of the nominal steps and of the slew-limited ones (which
    /// also realign the inverse memory), over a full-stroke trajectory at `hz`.
    fn measure<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        cfg: &ControllerConfig<'a, N, C, G, H>,
        baseline: u32,
        hz: f32,
    ) -> (Counts, Counts) {
        let wave = full_stroke(hz);
        let mut w = WavePhase::default();
        let mut st = cfg.initial_state();
        let (mut nominal, mut limited) = (Counts::new(), Counts::new());
        // The firmware's ISR reaches its configuration through a reference held in
        // its context; hide the constant here too, so LLVM cannot fold the model
        // into the code and the figure is that of the firmware.
        let cfg = black_box(cfg);
        for _ in 0..STEPS {
            let x = wave.next(&mut w);
            let f = force_at(x);
            let (x, f) = (black_box(x), black_box(f));
            let mut out = None;
            let t = ticks(|| out = Some(step_of(cfg, &mut st, x, f)));
            let n = instructions(t, baseline);
            match out {
                Some(o) if o.limited => limited.add(n),
                _ => nominal.add(n),
            }
        }
        (nominal, limited)
    }

    /// 5 Hz full stroke: nominal steps (the slew limit only bites while the output
    /// first rises from 0 V); 500 Hz: the slew limit bites on most steps.
    fn report<const N: usize>(cfg: &ControllerConfig<'_, N>, baseline: u32) {
        let (c, start) = measure(cfg, baseline, 5.0);
        let (_, l) = measure(cfg, baseline, 500.0);
        hprintln!("control_step_instructions n={}: {}", N, c.max);
        detail("paper FPI + compliance", N, &c, &l, &start);
    }

    fn detail(what: &str, n: usize, c: &Counts, l: &Counts, start: &Counts) {
        hprintln!(
            "  n={:<2} {}: nominal step {} max {} ({} steps); slew-limited step with inverse realignment min {} max {} ({} steps)",
            n, what, c, c.max, c.n,
            l.min.min(start.min), l.max.max(start.max), l.n + start.n
        );
    }

    /// The synthetic n = 10 model as the board would receive it: an image.
    fn spec_of_c10() -> ModelSpec<'static> {
        let (fpi, sup) = (C10.fpi(), C10.supervision());
        ModelSpec {
            rate_hz: capacity::RATE_HZ,
            w0: fpi.pi().w0(),
            operators: fpi.pi().operators(),
            input_max: fpi.pi().input_max(),
            coupling: *fpi.coupling(),
            dead_zone: None,
            saturation: None,
            creep: &[],
            f_f: TableSpec::of(C10.f_f()),
            f_k: TableSpec::of(C10.f_k()),
            f_k_inv: TableSpec::of(C10.f_k_inv()),
            u_min: C10.limits().min(),
            u_max: C10.limits().max(),
            max_step: C10.limits().max_step(),
            supervision: sup,
            feedback: None,
            shaping: None,
            dynamics: None,
            damping: None,
            lead_baseline: None,
            watch_swing: None,
        }
    }

    /// Loads an image into a store as the board does at run time and measures the
    /// step of the runtime controller (operators padded to the board's capacity).
    fn report_runtime<const CC: usize>(
        store: &mut piezo_fpi::model::store::ModelStore<10, CC, 3072>,
        image: &[u8],
        what: &str,
        baseline: u32,
    ) -> bool {
        let shape = match store.load(image, &BOARD) {
            Ok(s) => s,
            Err(e) => {
                hprintln!("{}: image refused: {}", what, e);
                return false;
            }
        };
        let Ok(cfg) = store.controller() else {
            return false;
        };
        let (c, start) = measure(&cfg, baseline, 5.0);
        let (_, l) = measure(&cfg, baseline, 500.0);
        hprintln!(
            "runtime_model_step_instructions n={} creep={} dead_zone={} saturation={} capacity={}: {}",
            shape.operators,
            shape.creep_terms,
            if shape.dead_zone { "soft" } else { "hard" },
            if shape.saturation { "yes" } else { "no" },
            capacity::OPERATORS,
            c.max
        );
        detail(what, shape.operators, &c, &l, &start);
        true
    }

    /// The board's control task on the embedded model received at run time, its
    /// instruction counts per tick; then, with `closed` (the same model with
    /// feedback and shaping, swapped in parked), the same in closed loop.
    fn report_tick(
        store: &'static mut Store,
        x: &mut Exchange<'static>,
        baseline: u32,
        closed: Option<Running>,
    ) -> bool {
        let mut spare = Spare::new(store);
        if let Err(e) = spare.load(MODEL_IMAGE) {
            hprintln!("the benchmark's model was refused: {}", e);
            return false;
        }
        let Ok(running) = spare.activate(MODEL_IMAGE, Origin::Factory) else {
            return false;
        };
        let rest = CONTROLLER.preload(Micrometres::ZERO).to_num::<f32>();
        LINK.set_force(rest);
        LINK.set_position(0.0);
        let mut lp = ControlLoop::new([(running, LINK.hardware(), LINK.analog())]);
        x.order = Some(Posted::all(1, Order::Record { decimation: 1 }));
        lp.tick(x);
        // The trigger output on its costliest condition throughout: a pulse
        // every 0.1 µm of travel.
        let travel = Condition::Travel {
            step: Micrometres::from_num(0.1),
        };
        let Ok(trigger) = Trigger::new(travel, 2) else {
            return false;
        };
        x.order = Some(Posted::all(3, Order::Trigger(trigger)));
        lp.tick(x);
        let open_ok = tick_phase(&mut lp, x, baseline, false);
        let Some(closed) = closed else {
            hprintln!("the closed-loop benchmark could not be set up");
            return false;
        };
        // Park, swap the model in, close the loop, run the stroke again.
        x.order = Some(Posted::all(4, Order::Safe));
        for _ in 0..200 {
            lp.tick(x);
        }
        x.model = Some(closed);
        x.order = Some(Posted::all(5, Order::Swap));
        lp.tick(x);
        let swapped = matches!(x.applied, Some(a) if a.result.is_ok());
        // A step command over the stroke, as long as the phase, running when
        // the loop closes: the lead's mass ratio (which learns from steps
        // only) learns at every tick, the loop's transfer included.
        let up = SourceOrder::Step {
            target: Micrometres::from_num(38),
            phase_step: fpi_firmware::control::reference::step_phase_for(STEPS + 20),
        };
        x.order = Some(Posted::all(6, Order::Source(up)));
        lp.tick(x);
        x.order = Some(Posted::all(7, Order::Loop(LoopMode::Closed)));
        lp.tick(x);
        let stepping_ok = swapped && stepping_phase(&mut lp, x, baseline);
        let closed_ok = stepping_ok && tick_phase(&mut lp, x, baseline, true);
        let governed_ok = closed_ok && governed_phase(&mut lp, x, baseline);
        open_ok && closed_ok && stepping_ok && governed_ok
    }

    /// The benchmark's control loop (its I/O is the simulated link).
    type Loop = crate::measure::Loop<1>;

    /// Runs a 5 Hz full stroke from where the loop is and prints its counts.
    fn tick_phase(lp: &mut Loop, x: &mut Exchange<'static>, baseline: u32, closed: bool) -> bool {
        x.order = Some(Posted::all(
            2,
            Order::Source(SourceOrder::Wave(full_stroke(5.0))),
        ));
        lp.tick(x);
        let (c, ok, depth) = run_ticks(lp, x, [&LINK], baseline);
        let names = if closed {
            (
                "isr_tick_closed_loop_instructions",
                "isr_tick_closed_loop_stack_bytes",
            )
        } else {
            ("isr_tick_instructions", "isr_tick_stack_bytes")
        };
        let what = if closed {
            "the board's control task on the runtime embedded model in closed loop (damping from the force sensor, PI on the position sensor, feedforward: 16 taps on the preview's delay line, 4 ticks ahead, with the damping's lead force): order check, reference, supervision, sensors, step, DAC, enable, trigger (travel), snapshot, recorder"
        } else {
            "the board's control task on the runtime embedded model: order check, reference, supervision, sensors, step, DAC, enable, trigger (travel), snapshot, recorder"
        };
        print_phase(x, names, what, &c, ok, depth)
    }

    /// In closed loop, a move ordered at 2 µm a tick (40 m/s), which the
    /// reference governor takes at its own limits back and forth across the
    /// stroke: the governed ticks' counts.
    fn governed_phase(lp: &mut Loop, x: &mut Exchange<'static>, baseline: u32) -> bool {
        let mut c = Counts::new();
        let (mut ok, mut depth) = (true, 0);
        for (seq, target) in [(8, 5), (9, 35)] {
            let fast = SourceOrder::Move {
                target: Micrometres::from_num(target),
                step: Micrometres::from_num(2),
            };
            x.order = Some(Posted::all(seq, Order::Source(fast)));
            lp.tick(x);
            let (part, part_ok, part_depth) = run_ticks(lp, x, [&LINK], baseline);
            c.merge(&part);
            ok &= part_ok;
            depth = depth.max(part_depth);
        }
        let names = (
            "isr_tick_closed_loop_governed_instructions",
            "isr_tick_closed_loop_governed_stack_bytes",
        );
        let what = "the same in closed loop, moves ordered at 2 µm a tick that the reference governor takes at its limits";
        print_phase(x, names, what, &c, ok, depth)
    }

    /// Runs on in closed loop during the step command the loop closed in, and
    /// prints the counts: the ticks in which the lead's mass ratio learns.
    fn stepping_phase(lp: &mut Loop, x: &mut Exchange<'static>, baseline: u32) -> bool {
        let (c, ok, depth) = run_ticks(lp, x, [&LINK], baseline);
        let names = (
            "isr_tick_closed_loop_stepping_instructions",
            "isr_tick_closed_loop_stepping_stack_bytes",
        );
        let what = "the same, closing the loop during a step command over the stroke: the lead's mass ratio learns at every tick";
        print_phase(x, names, what, &c, ok, depth)
    }

    /// Prints a phase's counts (`names`: of its instructions and its stack
    /// line; `what` it ran), the fault if one latched, and the tick's own
    /// stack (without the benchmark's frames above it, the measurement closure
    /// included, a few words); whether it ran clean.
    fn print_phase(
        x: &Exchange<'static>,
        (instructions, stack): (&str, &str),
        what: &str,
        c: &Counts,
        ok: bool,
        depth: usize,
    ) -> bool {
        hprintln!(
            "{} n={}: {} ({}; {}){}",
            instructions,
            factory_model::OPERATORS,
            c.max,
            what,
            c,
            if ok {
                ""
            } else {
                " FAILED: faulted or not recording"
            }
        );
        if let Some((f, at)) = x.snapshot.axes[0].fault {
            hprintln!("  fault at tick {}: {}", at, f.message());
        }
        hprintln!(
            "  governed ticks so far: {}",
            x.snapshot.axes[0].governed_ticks
        );
        hprintln!("{}: {}", stack, depth);
        ok
    }

    static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

    /// The dynamic compensator of issue 12 (`piezo_fpi::biquad`): one section and a
    /// two-section cascade, instructions per sample along the 5 Hz full-stroke
    /// reference in volts. Self-contained: printed as
    /// `biquad_section_instructions` and `biquad_cascade2_instructions`.
    mod biquad_bench {
        use crate::measure::{full_stroke, instructions, ticks, Counts, STEPS};
        use core::hint::black_box;
        use cortex_m_semihosting::hprintln;
        use fpi_firmware::control::reference::wave::WavePhase;
        use piezo_fpi::biquad::{Biquad, BiquadState, Cascade, CascadeState};
        use piezo_fpi::process::SplitProcess;
        use piezo_fpi::q::Volts;

        /// `piezo_sim::filter::mode_inverse(850.0, 0.02, 0.7, 20_000.0)`: the stable
        /// inverse of an 850 Hz mode with ζ = 0.02, placed at ζ_d = 0.7.
        pub(super) const INVERSE: Biquad = match Biquad::from_f64(
            [
                0.848_542_257_535_104,
                -1.628_341_947_638_625,
                0.839_632_978_566_580_6,
            ],
            [-1.628_341_947_638_625, 0.688_175_236_101_684_6],
        ) {
            Ok(b) => b,
            Err(e) => panic!("{}", e.message()),
        };
        /// `piezo_sim::filter::notch(2_600.0, 0.1, 0.05, 20_000.0)`.
        pub(super) const NOTCH: Biquad = match Biquad::from_f64(
            [
                0.935_453_236_923_409_6,
                -1.276_072_527_939_178_2,
                0.928_658_840_810_084_3,
            ],
            [-1.276_072_527_939_178_2, 0.864_112_077_733_494],
        ) {
            Ok(b) => b,
            Err(e) => panic!("{}", e.message()),
        };
        static SECTION: Biquad = INVERSE;
        static CASCADE2: Cascade<2> = Cascade::new([INVERSE, NOTCH]);

        #[inline(never)]
        fn section_of(f: &Biquad, st: &mut BiquadState, x: Volts) -> Volts {
            Volts::from_raw(f.process(st, x.raw()))
        }

        #[inline(never)]
        fn cascade_of(f: &Cascade<2>, st: &mut CascadeState<2>, x: Volts) -> Volts {
            Volts::from_raw(f.process(st, x.raw()))
        }

        fn line(name: &str, c: &Counts) {
            hprintln!(
                "{}: {} ({} max {}, {} samples, the call included)",
                name,
                c.max,
                c,
                c.max,
                c.n
            );
        }

        pub(super) fn report(baseline: u32) {
            let wave = full_stroke(5.0);
            let (f1, f2) = (black_box(&SECTION), black_box(&CASCADE2));
            let (mut s1, mut s2) = (BiquadState::new(), CascadeState::new());
            let (mut c1, mut c2) = (Counts::new(), Counts::new());
            let mut w = WavePhase::default();
            for _ in 0..STEPS {
                // The reference in µm, read as volts (4× to span 8–152 V).
                let x = black_box(Volts::from_bits(wave.next(&mut w).to_bits() << 2));
                c1.add(instructions(ticks(|| section_of(f1, &mut s1, x)), baseline));
                c2.add(instructions(ticks(|| cascade_of(f2, &mut s2, x)), baseline));
            }
            line("biquad_section_instructions", &c1);
            line("biquad_cascade2_instructions", &c2);
        }
    }

    /// The reference governor alone (`piezo_fpi::governor`): instructions per
    /// tick where the source passes and where it is governed, along a square
    /// wave between 5 and 35 µm (jumps the governor takes at its limits) on
    /// limits like a tuned stage's. Printed as `governor_passing_instructions`
    /// and `governor_governed_instructions`.
    mod governor_bench {
        use crate::measure::{instructions, ticks, Counts, STEPS};
        use core::hint::black_box;
        use cortex_m_semihosting::hprintln;
        use piezo_fpi::control::Interval;
        use piezo_fpi::governor::{GovernorConfig, GovernorState, Limits};
        use piezo_fpi::process::SplitProcess;
        use piezo_fpi::q::Micrometres;

        #[inline(never)]
        fn tick(g: &GovernorConfig, st: &mut GovernorState, r: Micrometres) -> Micrometres {
            g.process(st, r)
        }

        pub(super) fn report(baseline: u32) {
            let window = Interval {
                lo: Micrometres::ZERO,
                hi: Micrometres::from_num(39),
            };
            let limits = Limits {
                accel: 0.02,
                speed: 0.5,
                ramp: (0.995, 3.0),
                lead: -1.0,
            };
            let g = black_box(GovernorConfig::new(window, &limits));
            let mut st = GovernorState::at_rest(Micrometres::from_num(5));
            let (mut pass, mut gov) = (Counts::new(), Counts::new());
            for i in 0..STEPS {
                let r = if (i / 400) % 2 == 0 { 35 } else { 5 };
                let r = black_box(Micrometres::from_num(r));
                let c = instructions(ticks(|| tick(&g, &mut st, r)), baseline);
                if st.governed() {
                    gov.add(c);
                } else {
                    pass.add(c);
                }
            }
            for (name, c) in [
                ("governor_passing_instructions", &pass),
                ("governor_governed_instructions", &gov),
            ] {
                hprintln!(
                    "{}: {} ({}, {} ticks, the call included)",
                    name,
                    c.max,
                    c,
                    c.n
                );
            }
        }
    }

    /// One tick's converter work on the precision front end
    /// (`fpi_firmware::converters::tick_frames`: read the AD7606's two channels,
    /// scale them, write the AD5791's code) on SPI devices that answer at once:
    /// the processor's share, without the bus time. Printed as
    /// `converter_tick_instructions`.
    fn converter_report(baseline: u32) {
        use fpi_firmware::converters::{bench, tick_frames};
        let mut fe = bench::front_end(fpi_firmware::board::definition::precision::DAC);
        let wave = full_stroke(5.0);
        let mut w = fpi_firmware::control::reference::wave::WavePhase::default();
        let mut c = Counts::new();
        for _ in 0..STEPS {
            let u = black_box(Volts::from_bits(wave.next(&mut w).to_bits() << 2));
            c.add(instructions(
                ticks(|| {
                    tick_frames(
                        &mut fe,
                        &fpi_firmware::board::definition::precision::FRONT_END,
                        u,
                    )
                }),
                baseline,
            ));
        }
        hprintln!(
            "converter_tick_instructions: {} ({}, {} ticks: AD7606 read and scale, AD5791 write)",
            c.max,
            c,
            c.n
        );
    }

    #[entry]
    fn main() -> ! {
        start_counter();

        let (baseline, nops) = calibrate();
        biquad_bench::report(baseline);
        governor_bench::report(baseline);
        converter_report(baseline);

        report(&C4, baseline);
        report(&C10, baseline);
        report(&C16, baseline);
        report(&C32, baseline);

        // The embedded model (whatever structure the model file has).
        let (c, start) = measure(&CONTROLLER, baseline, 5.0);
        let (_, l) = measure(&CONTROLLER, baseline, 500.0);
        hprintln!(
            "embedded_model_step_instructions n={} creep={} dead_zone={} saturation={}: {}",
            factory_model::OPERATORS,
            factory_model::CREEP_TERMS,
            if CONTROLLER.fpi().dead_zone().is_some() {
                "soft"
            } else {
                "hard"
            },
            if CONTROLLER.fpi().saturation().is_some() {
                "yes"
            } else {
                "no"
            },
            c.max
        );
        detail("embedded model", factory_model::OPERATORS, &c, &l, &start);

        // Models received at run time (the board's RAM store).
        let mut runtime_ok = false;
        let mut store = cortex_m::singleton!(: Store = Store::new());
        let mut buf =
            cortex_m::singleton!(: [u8; capacity::IMAGE_BYTES] = [0; capacity::IMAGE_BYTES]);
        if let (Some(store), Some(buf)) = (store.as_deref_mut(), buf.as_deref_mut()) {
            runtime_ok =
                match image::encode(&spec_of_c10(), buf) {
                    Ok(len) => report_runtime(store, &buf[..len], "runtime paper FPI", baseline),
                    Err(e) => {
                        hprintln!("cannot encode the synthetic model: {}", e);
                        false
                    }
                } && report_runtime(store, MODEL_IMAGE, "runtime embedded model", baseline);
        }

        // The closed-loop model: built in the first store (free again), its image in
        // the benchmark's buffer, loaded into a second store and made runnable.
        let image = match (store.as_deref_mut(), buf) {
            (Some(s), Some(b)) => closed_image(s, b),
            _ => None,
        };
        let closed = match (image, cortex_m::singleton!(: Store = Store::new())) {
            (Some(image), Some(s2)) => {
                let mut spare = Spare::new(s2);
                spare
                    .load(image)
                    .ok()
                    .and_then(|_| spare.activate(image, Origin::Received).ok())
            }
            _ => None,
        };
        // The board's whole control task, on the embedded model loaded at run time
        // (order check, reference, supervision, sensors, step, DAC, enable, status
        // snapshot, recorder, recording every tick), then in closed loop.
        let tick_ok = match (
            store,
            cortex_m::singleton!(: Recorder<RECORDER_SAMPLES> = Recorder::new()),
            cortex_m::singleton!(: Points<STREAM_POINTS> = Points::new()),
        ) {
            (Some(store), Some(recorder), Some(points)) => {
                let mut x = Exchange::new(recorder, points);
                report_tick(store, &mut x, baseline, closed)
            }
            _ => false,
        };
        // ±1: the two calibration calls may be compiled with call sequences that
        // differ by an instruction.
        exit(nops.abs_diff(1000) <= 1 && runtime_ok && tick_ok)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("isr-bench runs on the emulated Cortex-M4: use `cargo isr-bench`.");
    std::process::exit(2);
}
