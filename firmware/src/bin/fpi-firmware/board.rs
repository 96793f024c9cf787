//! The STM32F405 driver board.
//!
//! | signal | pin | peripheral |
//! |---|---|---|
//! | force sensor (0–3.3 V = −5…507 N) | PA0 | ADC1 channel 0 |
//! | amplifier setpoint (0–3.3 V = 0–150 V) | PA4 | DAC channel 1 |
//! | amplifier enable (high = on) | PB0 | GPIO |
//!
//! The ADC conversion for tick k+1 is started at the end of tick k, so the ISR
//! reads a finished result (a 3.4 µs conversion in a 50 µs period) instead of
//! waiting for one. The board runs the self-test trajectory (full stroke at
//! 5 Hz, compensated) and logs a status line every 0.1 s over RTT. A fault keeps
//! the stage in its safe state (0 V, amplifier off) until the board is reset.

use cortex_m_rt::entry;
use defmt_rtt as _;
use fpi_firmware::frontend::{FORCE_ADC, SETPOINT_DAC};
use fpi_firmware::model::{CONTROLLER, OPERATORS};
use fpi_firmware::reference::RaisedCosine;
use fpi_firmware::runner::{nm, Command, Telemetry};
use heapless::spsc::Queue;
use panic_probe as _;
use piezo_fpi::control::Mode;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Micrometres, Newtons, Volts};
use stm32f4xx_hal::adc::config::{AdcConfig, SampleTime, Sequence};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::dac::{DacOut, DacPin, C1};
use stm32f4xx_hal::gpio::{Analog, Output, PushPull, PA0, PB0};
use stm32f4xx_hal::pac::{self, ADC1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::timer::Event;

use crate::isr::{self, Isr, RATE_HZ, TELEMETRY_DEPTH};

/// The force sensor on ADC1/PA0.
pub struct Sensor {
    adc: Adc<ADC1>,
    _pin: PA0<Analog>,
}

impl ForceSensor for Sensor {
    fn read_force(&mut self) -> Newtons {
        let counts = self.adc.current_sample();
        self.adc.start_conversion();
        FORCE_ADC.to_force(counts)
    }
}

/// The amplifier setpoint on DAC channel 1 (PA4).
pub struct Amplifier(C1);

impl Setpoint for Amplifier {
    fn write_voltage(&mut self, voltage: Volts) {
        self.0.set_value(SETPOINT_DAC.to_code(voltage));
    }
}

/// The amplifier's enable line.
pub type Enable = PB0<Output<PushPull>>;

crate::bind_tim2!(Sensor, Amplifier, Enable);

#[entry]
fn main() -> ! {
    let (Some(dp), Some(_cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        defmt::panic!("peripherals taken twice");
    };
    let mut rcc = dp.RCC.freeze(Config::hse(8.MHz()).sysclk(168.MHz()));
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);

    let mut enable = gpiob.pb0.into_push_pull_output();
    enable.set_low();

    let pa0 = gpioa.pa0.into_analog();
    let mut adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
    adc.configure_channel(&pa0, Sequence::One, SampleTime::Cycles_56);
    adc.enable();
    // One conversion before the first tick, so the first reading is real.
    let _ = adc.convert(&pa0, SampleTime::Cycles_56);
    adc.start_conversion();

    let mut dac = dp.DAC.constrain(gpioa.pa4.into_analog(), &mut rcc);
    dac.enable();
    dac.set_value(0);

    defmt::info!(
        "fpi-firmware: {=usize} operators, control ISR at {=u32} Hz, sysclk {=u32} Hz",
        OPERATORS,
        RATE_HZ,
        rcc.clocks.sysclk().raw()
    );

    let queue: &'static mut Queue<Telemetry, TELEMETRY_DEPTH> = match cortex_m::singleton!(: Queue<Telemetry, TELEMETRY_DEPTH> = Queue::new())
    {
        Some(q) => q,
        None => defmt::panic!("telemetry queue taken twice"),
    };
    let (producer, mut consumer) = queue.split();

    let self_test = Command {
        mode: Mode::Compensated,
        wave: RaisedCosine {
            center: Micrometres::from_num(20),
            amplitude: Micrometres::from_num(18),
            phase_step: RaisedCosine::phase_step_for(5.0, RATE_HZ as f32),
            amplitude_step: Micrometres::ZERO,
        },
        clear_fault: false,
    };
    let hw = Hardware {
        sensor: Sensor { adc, _pin: pa0 },
        amplifier: Amplifier(dac),
        enable,
    };
    let mut timer = dp.TIM2.counter_hz(&mut rcc);
    if timer.start(RATE_HZ.Hz()).is_err() {
        defmt::panic!("TIM2 cannot run at {=u32} Hz", RATE_HZ);
    }
    timer.listen(Event::Update);
    start(Isr {
        control: isr::Loop::new(&CONTROLLER, hw, self_test),
        timer,
        telemetry: producer,
    });

    let mut last_fault = None;
    loop {
        let Some(t) = consumer.dequeue() else {
            cortex_m::asm::wfi();
            continue;
        };
        if t.fault != last_fault {
            if let Some(f) = t.fault {
                defmt::error!(
                    "FAULT at tick {=u32}: {=str}; ramping to the safe voltage, then amplifier off. Reset to re-arm.",
                    t.step,
                    f.message()
                );
            }
            last_fault = t.fault;
        }
        if t.step % (RATE_HZ / 10) == 0 {
            say!(
                "tick {} ref {} nm est {} nm setpoint {} mV dropped {}",
                t.step,
                nm(t.x_ref.to_num::<f32>()),
                nm(CONTROLLER.stage_position(t.x_pea_est).to_num::<f32>()),
                nm(t.voltage.to_num::<f32>()),
                isr::dropped()
            );
        }
    }
}
