//! The emulated board (QEMU `netduinoplus2`): the real ISR drives the virtual stage.
//!
//! TIM2 interrupts at the control rate run the same control loop as on the board;
//! its sensor, DAC and enable line are the core's [`SimLink`]. Thread mode waits
//! for each tick's telemetry, steps the virtual stage (outside the ISR's budget)
//! and leaves the next force reading on the link, following the scripted run of
//! [`fpi_firmware::selftest`]. At the end it prints a report and exits through
//! semihosting with status 0 if every self-check passed, 1 otherwise.

use cortex_m_rt::entry;
use cortex_m_semihosting::debug::{self, EXIT_FAILURE, EXIT_SUCCESS};
use fpi_firmware::frontend::{FORCE_ADC, SETPOINT_DAC};
use fpi_firmware::model::{self, CONTROLLER, CREEP_TERMS, OPERATORS};
use fpi_firmware::runner::{nm, Telemetry};
use fpi_firmware::selftest::{Demo, Phase, PhaseReport, PhaseValues};
use fpi_firmware::sim_io::{SimAmplifier, SimEnable, SimLink, SimSensor};
use heapless::spsc::Queue;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::timer::Event;

use crate::isr::{self, Isr, RATE_HZ, TELEMETRY_DEPTH};

crate::bind_tim2!(
    SimSensor<'static>,
    SimAmplifier<'static>,
    SimEnable<'static>
);

static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

#[entry]
fn main() -> ! {
    let ok = run();
    debug::exit(if ok { EXIT_SUCCESS } else { EXIT_FAILURE });
    #[allow(clippy::empty_loop)]
    loop {}
}

fn run() -> bool {
    let Some(dp) = pac::Peripherals::take() else {
        return false;
    };
    // QEMU has no PLL: stay on the 16 MHz HSI.
    let mut rcc = dp.RCC.freeze(Config::hsi());
    say!(
        "fpi-firmware on the emulated STM32F405 (QEMU netduinoplus2): {} operators, {} creep terms, {} Hz control ISR",
        OPERATORS as u32,
        CREEP_TERMS as u32,
        RATE_HZ
    );
    say!("model: {}", model::MODEL_FILE);
    let Some(mut demo) = Demo::new(&CONTROLLER, RATE_HZ) else {
        say!("FAIL: cannot build the straight-line baseline from the model");
        return false;
    };
    demo.prime(&LINK);

    let queue: &'static mut Queue<Telemetry, TELEMETRY_DEPTH> = match cortex_m::singleton!(: Queue<Telemetry, TELEMETRY_DEPTH> = Queue::new())
    {
        Some(q) => q,
        None => return false,
    };
    let (producer, mut consumer) = queue.split();

    let mut timer = dp.TIM2.counter_hz(&mut rcc);
    if timer.start(RATE_HZ.Hz()).is_err() {
        say!("FAIL: TIM2 cannot run at {} Hz", RATE_HZ);
        return false;
    }
    timer.listen(Event::Update);
    let control = isr::Loop::new(&CONTROLLER, LINK.hardware(), demo.command());
    start(Isr {
        control,
        timer,
        telemetry: producer,
    });

    let mut overruns = 0u32;
    let mut all_pass = true;
    let mut reports: [Option<PhaseReport>; 5] = [None; 5];
    let mut k = 0;
    loop {
        let Some(tel) = consumer.dequeue() else {
            cortex_m::asm::wfi();
            continue;
        };
        let adv = demo.after_tick(&tel, &LINK);
        // The next tick must not have run before its force reading was posted.
        if consumer.ready() {
            overruns += 1;
        }
        if let Some(c) = adv.command {
            isr::post(c);
        }
        if let Some(r) = adv.report {
            print_phase(&r, tel.step + 1);
            print_values(&PhaseValues::of(k as u8, &r));
            all_pass &= r.pass;
            if let Some(slot) = reports.get_mut(k) {
                *slot = Some(r);
            }
            k += 1;
        }
        if adv.done {
            return summary(&reports, tel.step + 1, overruns, all_pass);
        }
    }
}

fn print_phase(r: &PhaseReport, tick: u32) {
    say!(
        "phase {:<30} ticks {:>6}  tracking rms {:>5} nm  max {:>5} nm  virtual-sensor rms {:>5} nm  {}",
        r.phase.name(),
        tick,
        nm(r.tracking.rms()),
        nm(r.tracking.max_abs()),
        nm(r.estimate.rms()),
        if r.pass { "ok" } else { "FAILED" }
    );
    if let Some((fault, at)) = r.fault {
        let ramp = r.safe_at.map(|s| (s - at) as i32).unwrap_or(-1);
        say!(
            "  FAULT at phase tick {}: {}; output ramped to the safe voltage in {} ticks; amplifier {}",
            at,
            fault.message(),
            ramp,
            if r.amplifier_off { "switched off" } else { "STILL ON" }
        );
    }
}

/// The phase's figures to full precision, for the host's twin comparison.
fn print_values(v: &PhaseValues) {
    let mut line = heapless::String::<256>::new();
    if v.write(&mut line).is_ok() {
        say!("{}", line.as_str());
    } else {
        say!("values line too long");
    }
}

fn summary(reports: &[Option<PhaseReport>; 5], ticks: u32, overruns: u32, phases_ok: bool) -> bool {
    let find = |p: Phase| reports.iter().flatten().find(|r| r.phase == p);
    let (Some(off), Some(on)) = (find(Phase::Uncompensated), find(Phase::Compensated)) else {
        say!("FAIL: missing phases");
        return false;
    };
    let ratio = on.tracking.rms() / off.tracking.rms();
    say!(
        "tracking error without compensation: rms {} nm, max {} nm",
        nm(off.tracking.rms()),
        nm(off.tracking.max_abs())
    );
    say!(
        "tracking error with FPI compensation: rms {} nm, max {} nm ({} % of uncompensated rms)",
        nm(on.tracking.rms()),
        nm(on.tracking.max_abs()),
        (ratio * 100.0 + 0.5) as u32
    );
    let dropped = isr::dropped();
    say!(
        "control ticks {}, telemetry dropped {}, thread-mode overruns {}",
        ticks,
        dropped,
        overruns
    );
    let ok = phases_ok && ratio <= Demo::REQUIRED_RATIO && dropped == 0 && overruns == 0;
    say!("RESULT {}", if ok { "PASS" } else { "FAIL" });
    ok
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    cortex_m_semihosting::hprintln!("HardFault");
    debug::exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m_semihosting::hprintln!("panic: {}", info);
    debug::exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
