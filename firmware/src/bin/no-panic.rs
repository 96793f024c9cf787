//! Link-time proof that the control path cannot panic.
//!
//! This firmware runs the control task of the board on opaque inputs: the
//! embedded model's typed control step, and the whole tick the ISR runs
//! (`ControlLoop::tick` and the recorder) on a model loaded at run time, orders
//! included, on one axis (the board's loop) and on three (their phases and
//! the decoupling between them). Its panic handler calls a function that exists nowhere, so if the
//! optimiser leaves any panic branch reachable (an index, an overflow check, an
//! `unwrap`, a division) the build (profile `firmware`) fails to link with
//! `undefined symbol: control_path_can_panic`. Loading the model (the link
//! task's work) is reachable too, so the proof covers it. CI builds it.
//!
//! `cargo build --profile firmware --target thumbv7em-none-eabihf -p fpi-firmware --bin no-panic --features qemu`
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod proof {
    use core::hint::black_box;
    use cortex_m_rt::entry;
    use fpi_firmware::board::capacity::{Store, RECORDER_SAMPLES, STREAM_POINTS};
    use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use fpi_firmware::board::factory_model::{CONTROLLER, MODEL_IMAGE};
    use fpi_firmware::control::exchange::{Exchange, Order, Posted};
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::reference::SourceOrder;
    use fpi_firmware::control::slots::{Origin, Running, Spare};
    use fpi_firmware::control::task::ControlLoop;
    use fpi_firmware::emulation::virtual_io::SimLink;
    use piezo_fpi::q::{Micrometres, Newtons};
    use stm32f4xx_hal as _;

    static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);
    static LINK_Y: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);
    static LINK_Z: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

    fn halt() -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    #[entry]
    fn main() -> ! {
        let cfg = black_box(&CONTROLLER);
        let mut st = cfg.initial_state();
        let (Some(s1), Some(s2), Some(s3), Some(recorder), Some(points)) = (
            cortex_m::singleton!(: Store = Store::new()),
            cortex_m::singleton!(: Store = Store::new()),
            cortex_m::singleton!(: Store = Store::new()),
            cortex_m::singleton!(: Recorder<RECORDER_SAMPLES> = Recorder::new()),
            cortex_m::singleton!(: Points<STREAM_POINTS> = Points::new()),
        ) else {
            halt()
        };
        let axis = |link: &'static SimLink| (link.hardware(), link.analog());
        if black_box(true) {
            let mut lp = ControlLoop::new([with(running(s1), axis(&LINK))]);
            let mut x = Exchange::new(recorder, points);
            loop {
                let xr = Micrometres::from_bits(black_box(0));
                let f = Newtons::from_bits(black_box(0));
                black_box(cfg.step(&mut st, xr, f));
                order(&mut x);
                let [t] = *lp.tick(&mut x);
                black_box(lp.record(&mut x, &t, None));
                if let Some(back) = x.model.take() {
                    black_box(back.retire());
                }
            }
        }
        let mut lp = ControlLoop::new([
            with(running(s1), axis(&LINK)),
            with(running(s2), axis(&LINK_Y)),
            with(running(s3), axis(&LINK_Z)),
        ]);
        let mut x: Exchange<'static, 3> = Exchange::new(recorder, points);
        loop {
            order(&mut x);
            lp.tick(&mut x);
            for t in lp.telemetry() {
                black_box(lp.record(&mut x, t, None));
            }
            if let Some(back) = x.model.take() {
                black_box(back.retire());
            }
        }
    }

    /// The embedded model loaded at run time into `store`, running.
    fn running(store: &'static mut Store) -> Running {
        let mut spare = Spare::new(store);
        if spare.load(black_box(MODEL_IMAGE)).is_err() {
            halt()
        }
        let Ok(running) = spare.activate(MODEL_IMAGE, Origin::Factory) else {
            halt()
        };
        running
    }

    /// An axis's model with its hardware.
    fn with<H, A>(model: Running, (hw, analog): (H, A)) -> (Running, H, A) {
        (model, hw, analog)
    }

    /// Posts an opaque order (the link task's), sometimes.
    fn order<const N: usize>(x: &mut Exchange<'static, N>) {
        if black_box(false) {
            x.order = Some(black_box(Posted::all(
                1,
                Order::Source(black_box(SourceOrder::Analog)),
            )));
        }
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        extern "C" {
            fn control_path_can_panic() -> !;
        }
        // SAFETY: never called if the proof holds; if it can be called, linking fails.
        unsafe { control_path_can_panic() }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("no-panic is a link-time check for the firmware target (see its doc comment).");
    std::process::exit(2);
}
