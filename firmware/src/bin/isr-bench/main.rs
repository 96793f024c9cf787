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
mod bench {
    use core::hint::black_box;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::SYST;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::debug::{self, EXIT_FAILURE, EXIT_SUCCESS};
    use cortex_m_semihosting::hprintln;
    use fpi_firmware::board::capacity::{self, Store, BOARD};
    use fpi_firmware::board::capacity::{RECORDER_SAMPLES, STREAM_POINTS};
    use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use fpi_firmware::board::factory_model::{self, CONTROLLER, MODEL_IMAGE};
    use fpi_firmware::control::exchange::{Exchange, Order, Posted};
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::reference::wave::{Shape as WaveShape, Wave, WavePhase};
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

    /// SysTick ticks per instruction at `-icount shift=10` on a 168 MHz core clock.
    const TICKS_PER_INSTRUCTION: f32 = 0.168 * 1024.0;

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

    /// min, sum, max of instruction counts.
    #[derive(Clone, Copy)]
    struct Counts {
        min: u32,
        sum: u64,
        max: u32,
        n: u32,
    }

    impl Counts {
        fn new() -> Self {
            Self {
                min: u32::MAX,
                sum: 0,
                max: 0,
                n: 0,
            }
        }
        fn add(&mut self, c: u32) {
            self.min = self.min.min(c);
            self.max = self.max.max(c);
            self.sum += c as u64;
            self.n += 1;
        }
        fn merge(&mut self, o: &Self) {
            self.min = self.min.min(o.min);
            self.max = self.max.max(o.max);
            self.sum += o.sum;
            self.n += o.n;
        }
        fn mean_x10(&self) -> u32 {
            (self.sum * 10 / self.n.max(1) as u64) as u32
        }
    }

    /// SysTick ticks of `f`, the two counter reads included.
    #[inline(always)]
    fn ticks<R>(f: impl FnOnce() -> R) -> u32 {
        let t0 = SYST::get_current();
        black_box(f());
        let t1 = SYST::get_current();
        t0.wrapping_sub(t1) & 0x00FF_FFFF
    }

    fn instructions(ticks: u32, baseline: u32) -> u32 {
        ((ticks.saturating_sub(baseline)) as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32
    }

    /// Force the stage would put on the stack at a reference (what the sensor reads).
    fn force_at(x_ref: Micrometres) -> Newtons {
        CONTROLLER.preload(CONTROLLER.extension(x_ref))
    }

    #[inline(never)]
    fn nop_1000() {
        // SAFETY: nops only.
        unsafe {
            core::arch::asm!(
                ".rept 1000",
                "nop",
                ".endr",
                options(nomem, nostack, preserves_flags)
            )
        }
    }

    #[inline(never)]
    fn nop_0() {
        // SAFETY: empty.
        unsafe { core::arch::asm!("", options(nomem, nostack, preserves_flags)) }
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

    const STEPS: u32 = 4000;

    /// A raised cosine over 2–38 µm at `hz`, continuous.
    fn full_stroke(hz: f32) -> Wave {
        Wave {
            shape: WaveShape::RaisedCosine,
            offset: Micrometres::from_num(20),
            amplitude: Micrometres::from_num(18),
            phase_step: Wave::phase_step_for((hz * 1000.0) as u32, 20_000),
            cycles: 0,
        }
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
            "  n={:<2} {}: nominal step min {} mean {}.{} max {} ({} steps); slew-limited step with inverse realignment min {} max {} ({} steps)",
            n, what, c.min, c.mean_x10() / 10, c.mean_x10() % 10, c.max, c.n,
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

    /// The embedded model with every loop on, as `fpi tune --dynamics` tunes it for
    /// stage A (its 850.9 Hz mode, ζ 0.0301, the 2027 Hz lag, κ 7.02 N/µm): active
    /// damping (IFF, 1316 µm/(N·s) between 100 Hz corners), the position PI
    /// (kp 0.75, ki 1762.6/s) and the feedforward of the damped stage (16 taps on the preview's line);
    /// its image in `buf`. The validator's loop check runs on it as on any model.
    fn closed_image<'b>(store: &mut Store, buf: &'b mut [u8]) -> Option<&'b [u8]> {
        use piezo_fpi::damping::{DampingSpec, DynamicsSpec};
        use piezo_fpi::q::{CreepRate, LoopGain, NewtonsPerUm};
        store.load(MODEL_IMAGE, &BOARD).ok()?;
        let spec = store.spec();
        let um = |x: f64| piezo_fpi::q::signal(x).map_or(Micrometres::ZERO, Micrometres::from_raw);
        let gain = |x: f64| LoopGain::from_num(x);
        let r = spec.supervision.reference;
        let rate = capacity::RATE_HZ as f64;
        let feedback = piezo_fpi::feedback::FeedbackSpec {
            kp: gain(0.75),
            ki: gain(1762.611 / rate),
            limit: um(9.98),
            // Inside the position channel's rails (−10…70 µm), as the
            // validator has a sensor window.
            sensor: piezo_fpi::control::Interval {
                lo: r.lo - um(9.0),
                hi: r.hi + um(9.0),
            },
            tolerance: um(6.0),
        };
        // 1 − e^{−2π·100 Hz/20 kHz}
        let corner = CreepRate::from_num(0.030_929_031_800_5);
        let damping = DampingSpec {
            gain: gain(1315.733 / rate),
            highpass: corner,
            leak: corner,
            limit: um(39.921),
        };
        let dynamics = DynamicsSpec {
            mode_mhz: 850_852,
            damping: CreepRate::from_num(0.030_098),
            lag_mhz: 2_026_966,
            force_gain: NewtonsPerUm::from_num(7.017),
        };
        // Autotune's feedforward: taps on the preview's delay line, 4 ticks
        // ahead (the delay line, the taps and the damping's lead force, with
        // its learned mass ratio, run).
        let one = f64::from(1 << piezo_fpi::biquad::COEFF_FRAC);
        let mut taps = [
            1.67, -0.08, -0.63, -0.57, -0.7, -0.04, 0.61, 0.74, 0.2, -0.1, -0.15, 0.05, 0.1, -0.05,
            -0.05, 0.02,
        ]
        .map(|t| (t * one) as i32);
        taps[0] += (1 << piezo_fpi::biquad::COEFF_FRAC) - taps.iter().sum::<i32>();
        let shaping = piezo_fpi::biquad::ShapingSpec {
            preview: 4,
            taps,
            ..piezo_fpi::biquad::ShapingSpec::IDENTITY
        };
        let closed = ModelSpec {
            feedback: Some(feedback),
            shaping: Some(shaping),
            dynamics: Some(dynamics),
            damping: Some(damping),
            // The lead's learned mass ratio, applied (piezo_fpi::lead).
            lead_baseline: Some(piezo_fpi::q::LeadRatio::from_num(0.88)),
            // The watch's least half swing (the most half-cycles counted).
            watch_swing: Some(piezo_fpi::model::WATCH_SWING_MIN),
            ..spec
        };
        let len = match image::encode(&closed, buf) {
            Ok(len) => len,
            Err(e) => {
                hprintln!("the closed-loop model was refused: {}", e);
                return None;
            }
        };
        buf.get(..len)
    }

    /// The board's control task on the embedded model received at run time, its
    /// instruction counts per tick; then, with `closed` (the same model with
    /// feedback and shaping, swapped in parked), the same in closed loop.
    fn report_tick(
        store: &'static mut Store,
        mut x: Exchange<'static>,
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
        lp.tick(&mut x);
        // The trigger output on its costliest condition throughout: a pulse
        // every 0.1 µm of travel.
        let travel = Condition::Travel {
            step: Micrometres::from_num(0.1),
        };
        let Ok(trigger) = Trigger::new(travel, 2) else {
            return false;
        };
        x.order = Some(Posted::all(3, Order::Trigger(trigger)));
        lp.tick(&mut x);
        let open_ok = tick_phase(&mut lp, &mut x, baseline, false);
        let Some(closed) = closed else {
            hprintln!("the closed-loop benchmark could not be set up");
            return false;
        };
        // Park, swap the model in, close the loop, run the stroke again.
        x.order = Some(Posted::all(4, Order::Safe));
        for _ in 0..200 {
            lp.tick(&mut x);
        }
        x.model = Some(closed);
        x.order = Some(Posted::all(5, Order::Swap));
        lp.tick(&mut x);
        let swapped = matches!(x.applied, Some(a) if a.result.is_ok());
        // A step command over the stroke, as long as the phase, running when
        // the loop closes: the lead's mass ratio (which learns from steps
        // only) learns at every tick, the loop's transfer included.
        let up = SourceOrder::Step {
            target: Micrometres::from_num(38),
            phase_step: fpi_firmware::control::reference::step_phase_for(STEPS + 20),
        };
        x.order = Some(Posted::all(6, Order::Source(up)));
        lp.tick(&mut x);
        x.order = Some(Posted::all(7, Order::Loop(LoopMode::Closed)));
        lp.tick(&mut x);
        let stepping_ok = swapped && stepping_phase(&mut lp, &mut x, baseline);
        let closed_ok = stepping_ok && tick_phase(&mut lp, &mut x, baseline, true);
        let governed_ok = closed_ok && governed_phase(&mut lp, &mut x, baseline);
        open_ok && closed_ok && stepping_ok && governed_ok
    }

    /// The benchmark's control loop (its I/O is the simulated link).
    type Loop = ControlLoop<
        fpi_firmware::emulation::virtual_io::SimSensor<'static>,
        fpi_firmware::emulation::virtual_io::SimAmplifier<'static>,
        fpi_firmware::emulation::virtual_io::SimEnable<'static>,
        fpi_firmware::emulation::virtual_io::SimAnalog<'static>,
    >;

    /// Runs a 5 Hz full stroke from where the loop is and prints its counts.
    fn tick_phase(lp: &mut Loop, x: &mut Exchange<'static>, baseline: u32, closed: bool) -> bool {
        x.order = Some(Posted::all(
            2,
            Order::Source(SourceOrder::Wave(full_stroke(5.0))),
        ));
        lp.tick(x);
        let (c, ok, depth) = run_ticks(lp, x, baseline);
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
            let (part, part_ok, part_depth) = run_ticks(lp, x, baseline);
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
        let (c, ok, depth) = run_ticks(lp, x, baseline);
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
            "{} n={}: {} ({}; min {} mean {}.{}){}",
            instructions,
            factory_model::OPERATORS,
            c.max,
            what,
            c.min,
            c.mean_x10() / 10,
            c.mean_x10() % 10,
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

    /// [`STEPS`] ticks of the loop as it runs: their instruction counts,
    /// whether it ran without a fault and recorded every tick, and the stack
    /// the tick used, bytes.
    fn run_ticks(lp: &mut Loop, x: &mut Exchange<'static>, baseline: u32) -> (Counts, bool, usize) {
        let kept = x.recorder.kept();
        let mut c = Counts::new();
        const PAINT: usize = 8192;
        let sp = paint_below(PAINT);
        for _ in 0..STEPS {
            let t = ticks(|| {
                let [t] = lp.tick(x);
                lp.record(x, &t, None)
            });
            c.add(instructions(t, baseline));
            // The link task reads the recorder; the sensors follow the stage.
            while x.recorder.take().is_some() {}
            let f = CONTROLLER.preload(lp.axes()[0].state().x_pea_est());
            LINK.set_force(f.to_num::<f32>());
            LINK.set_position(x.snapshot.axes[0].now.x_est.to_num::<f32>());
        }
        let ok = x.snapshot.axes[0].fault.is_none() && x.recorder.kept() >= kept + STEPS;
        (c, ok, depth_below(sp, PAINT))
    }

    static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

    /// Paints `bytes` of the unused stack below the current stack pointer with a
    /// pattern; [`depth_below`] then tells how much of it a call used.
    #[inline(never)]
    fn paint_below(bytes: usize) -> usize {
        let sp = cortex_m::register::msp::read() as usize;
        // SAFETY: the region lies below the stack pointer of this function, in the
        // stack's free space (the benchmark's statics are far below); nothing else
        // runs (no interrupts are enabled in the benchmark).
        unsafe {
            let mut p = sp - bytes;
            while p < sp - 64 {
                core::ptr::write_volatile(p as *mut u32, 0xCCCC_CCCC);
                p += 4;
            }
        }
        sp
    }

    /// Bytes below `sp` (from [`paint_below`]) that were written since it painted.
    #[inline(never)]
    fn depth_below(sp: usize, bytes: usize) -> usize {
        let mut p = sp - bytes;
        // SAFETY: reads the region `paint_below` painted.
        while p < sp && unsafe { core::ptr::read_volatile(p as *const u32) } == 0xCCCC_CCCC {
            p += 4;
        }
        sp - p
    }

    /// The dynamic compensator of issue 12 (`piezo_fpi::biquad`): one section and a
    /// two-section cascade, instructions per sample along the 5 Hz full-stroke
    /// reference in volts. Self-contained: printed as
    /// `biquad_section_instructions` and `biquad_cascade2_instructions`.
    mod biquad_bench {
        use super::{full_stroke, instructions, ticks, Counts, STEPS};
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
                "{}: {} (min {} mean {}.{} max {}, {} samples, the call included)",
                name,
                c.max,
                c.min,
                c.mean_x10() / 10,
                c.mean_x10() % 10,
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
        use super::{instructions, ticks, Counts, STEPS};
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
                    "{}: {} (min {} mean {}.{}, {} ticks, the call included)",
                    name,
                    c.max,
                    c.min,
                    c.mean_x10() / 10,
                    c.mean_x10() % 10,
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
            "converter_tick_instructions: {} (min {} mean {}.{}, {} ticks: AD7606 read and scale, AD5791 write)",
            c.max,
            c.min,
            c.mean_x10() / 10,
            c.mean_x10() % 10,
            c.n
        );
    }

    #[entry]
    fn main() -> ! {
        let Some(mut cp) = cortex_m::Peripherals::take() else {
            debug::exit(EXIT_FAILURE);
            loop {
                cortex_m::asm::wfi();
            }
        };
        cp.SYST.set_clock_source(SystClkSource::Core);
        cp.SYST.set_reload(0x00FF_FFFF);
        cp.SYST.clear_current();
        cp.SYST.enable_counter();

        // Calibration: the counter reads alone, and a block of known length.
        let baseline = (0..64).map(|_| ticks(|| ())).min().unwrap_or(0);
        // A function of 1000 nops minus an empty function: exactly 1000 instructions.
        let best = |f: fn()| (0..8).map(|_| ticks(f)).min().unwrap_or(0);
        let nops = instructions(best(nop_1000).saturating_sub(best(nop_0)), 0);
        hprintln!(
            "calibration: 1000 nops counted as {} instructions (baseline {} SysTick ticks)",
            nops,
            baseline
        );
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
        let closed = match (
            store.as_deref_mut(),
            buf,
            cortex_m::singleton!(: Store = Store::new()),
        ) {
            (Some(s), Some(b), Some(s2)) => closed_image(s, b).and_then(|image| {
                let mut spare = Spare::new(s2);
                spare.load(image).ok()?;
                spare.activate(image, Origin::Received).ok()
            }),
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
                report_tick(store, Exchange::new(recorder, points), baseline, closed)
            }
            _ => false,
        };
        // ±1: the two calibration calls may be compiled with call sequences that
        // differ by an instruction.
        debug::exit(if nops.abs_diff(1000) <= 1 && runtime_ok && tick_ok {
            EXIT_SUCCESS
        } else {
            EXIT_FAILURE
        });
        loop {
            cortex_m::asm::wfi();
        }
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        hprintln!("panic: {}", info);
        debug::exit(EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("isr-bench runs on the emulated Cortex-M4: use `cargo isr-bench`.");
    std::process::exit(2);
}
