//! The precision front end: the AD7606 (force on V1, position on V2) on SPI1 and
//! the AD5791 (setpoint) on SPI2, each an embedded-hal `SpiDevice` through
//! `embedded-hal-bus`'s `ExclusiveDevice` (the bus and its chip select), as the
//! board definition places, straps and scales them
//! ([`fpi_firmware::board::definition::precision`]).
//!
//! **Timing** ([`fpi_firmware::converters::schedule`]): TIM4 runs the control
//! period from the same clock as SysTick (84 MHz timer clock, 4 200 counts per
//! 50 µs; SysTick 8 400 core cycles), so the two never drift. Channel 1 (PWM
//! mode 2) raises CONVST 44 µs into the period; channel 2 holds LDAC̅ low for the
//! period's first microsecond, so the AD5791 takes the code the previous tick
//! wrote at a fixed instant. The first control tick sets TIM4's counter to 0:
//! from then on the period starts at the ISR's entry, give or take the entry
//! latency of that first tick (12 cycles, plus any critical section of the link
//! task that held it off, a few µs at most: a constant offset, not a jitter). No
//! software is involved in sampling: the sample is 6 µs old when the tick that
//! uses it starts, every tick.
//!
//! The ISR reads the ADC at its start (one 32-bit frame, BUSY checked once,
//! never waited for) and writes the DAC after the step (one 24-bit frame); a
//! stalled ADC or a failed transaction latches `Fault::Converter`
//! ([`fpi_firmware::board::converter_ports`]).

use super::{Enable, ReferenceAdc};
use core::sync::atomic::{AtomicBool, Ordering};
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::spi::ExclusiveDevice;
use fpi_firmware::board::capacity::RATE_HZ;
use fpi_firmware::board::converter_ports::{self, Health};
use fpi_firmware::board::definition::pins::{AdcSpi, ConvTimer, DacSpi, Precision};
use fpi_firmware::board::definition::precision::{
    ADC, ADC_SCLK_HZ, DAC, DAC_SCLK_HZ, FRONT_END, LDAC_PULSE_NS, TIMING,
};
use fpi_firmware::board::definition::CORE_HZ;
use fpi_firmware::control::task::ControlLoop;
use fpi_firmware::converters::ad579x::{self, Ad579x};
use fpi_firmware::converters::ad7606::{self, Ad7606};
use fpi_firmware::converters::front_end::{Driving, Sensing};
use piezo_fpi::io::Hardware;
use piezo_fpi::q::{Newtons, Volts};
use stm32f4xx_hal::gpio::{AnyPin, Input, Output};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Enable as _, Rcc, Reset as _};
use stm32f4xx_hal::spi::{Spi, SpiExt};

/// A busy wait for the chip selects' and the AD7606's RESET delays (none of the
/// tick's frames has a delay operation).
pub struct Spin;

impl DelayNs for Spin {
    fn delay_ns(&mut self, ns: u32) {
        let cycles = (u64::from(ns) * u64::from(CORE_HZ)).div_ceil(1_000_000_000);
        cortex_m::asm::delay(cycles.min(u64::from(u32::MAX)) as u32);
    }
}

/// The AD7606 as an `SpiDevice`.
pub type AdcDevice = ExclusiveDevice<Spi<AdcSpi>, AnyPin<Output>, Spin>;
/// The AD5791 as an `SpiDevice`.
pub type DacDevice = ExclusiveDevice<Spi<DacSpi>, AnyPin<Output>, Spin>;
/// The force sensor: the AD7606's V1.
pub type Sensor = converter_ports::Force<'static, AdcDevice, AnyPin<Input>>;
/// The amplifier setpoint: the AD5791.
pub type Amplifier = converter_ports::Amplifier<'static, DacDevice>;
/// The position (the AD7606's V2) and the analog reference input (ADC2).
pub type Analog = converter_ports::Analog<'static, ReferenceAdc>;
/// The control loop on this front end.
pub type Control = ControlLoop<Sensor, Amplifier, Enable, Analog>;

/// The ports' shared state: the position code, the converters' failures.
static HEALTH: Health = Health::new(0x8000);
/// TIM4's counter has been aligned with the control tick.
static ALIGNED: AtomicBool = AtomicBool::new(false);

/// Before the first tick's read: TIM4's period starts now (see the module).
#[inline(always)]
pub fn before_tick() {
    if !ALIGNED.load(Ordering::Relaxed) {
        // SAFETY: only the counter is written; TIM4 belongs to this front end,
        // which configured it in `init` and touches it nowhere else.
        let tim = unsafe { &*ConvTimer::ptr() };
        tim.cnt().write(|w| w.cnt().set(0));
        ALIGNED.store(true, Ordering::Relaxed);
    }
}

/// After a tick: a converter that failed latches `Fault::Converter`.
#[inline(always)]
pub fn after_tick(control: &mut Control) {
    let _ = converter_ports::latch(&HEALTH, |f| control.fail(f));
}

/// Both converters set up (the DAC at code 0 with its output on, the ADC strapped
/// and reset), TIM4 running.
pub fn init(
    pins: Precision,
    (spi1, spi2, tim): (AdcSpi, DacSpi, ConvTimer),
    reference: ReferenceAdc,
    enable: Enable,
    rcc: &mut Rcc,
) -> (Hardware<Sensor, Amplifier, Enable>, Analog) {
    let mut config = pins.adc_config;
    if ad7606::configure(&ADC, &mut config, &mut Spin).is_err() {
        super::halt("AD7606 configuration pins");
    }
    let (sck, miso) = pins.adc_spi;
    let bus = Spi::new(
        spi1,
        (Some(sck), Some(miso), AdcSpi::NoMosi),
        ad7606::SPI_MODE,
        ADC_SCLK_HZ.Hz(),
        rcc,
    );
    let Ok(adc) = ExclusiveDevice::new(bus, pins.adc_cs, Spin);
    let (sck, miso, mosi) = pins.dac_spi;
    let bus = Spi::new(
        spi2,
        (Some(sck), Some(miso), Some(mosi)),
        ad579x::SPI_MODE,
        DAC_SCLK_HZ.Hz(),
        rcc,
    );
    let Ok(dac) = ExclusiveDevice::new(bus, pins.dac_cs, Spin);
    let mut dac = Ad579x::new(dac, DAC);
    if dac.init(FRONT_END.setpoint.to_code(Volts::ZERO)).is_err() {
        super::halt("AD5791 start-up (no answer or a wrong readback)");
    }
    start_timer(&tim, rcc);
    let sensing = Sensing::new(Ad7606::new(adc, pins.busy), [0, 0]);
    let hw = Hardware {
        sensor: converter_ports::Force::new(sensing, &FRONT_END, &HEALTH, Newtons::ZERO),
        amplifier: converter_ports::Amplifier::new(Driving::new(dac), &FRONT_END, &HEALTH),
        enable,
    };
    (hw, converter_ports::Analog::new(reference, &HEALTH))
}

/// TIM4 at the control rate: channel 1 (CONVST) high from [`TIMING`]'s
/// `convst_ns` to the period's end, channel 2 (LDAC̅) low for the first
/// [`LDAC_PULSE_NS`]; both PWM mode 2 (inactive below the compare value).
fn start_timer(tim: &ConvTimer, rcc: &mut Rcc) {
    ConvTimer::enable(rcc);
    ConvTimer::reset(rcc);
    let hz = u64::from(rcc.clocks.timclk1().raw());
    let counts = |ns: u32| (hz * u64::from(ns) / 1_000_000_000) as u16;
    let period = (hz / u64::from(RATE_HZ)) as u16;
    tim.psc().write(|w| w.psc().set(0));
    tim.arr().write(|w| w.arr().set(period - 1));
    tim.ccr1().write(|w| w.ccr().set(counts(TIMING.convst_ns)));
    tim.ccr2().write(|w| w.ccr().set(counts(LDAC_PULSE_NS)));
    tim.ccmr1_output().write(|w| {
        w.oc1m().pwm_mode2().oc1pe().enabled();
        w.oc2m().pwm_mode2().oc2pe().enabled()
    });
    tim.ccer().write(|w| w.cc1e().set_bit().cc2e().set_bit());
    tim.egr().write(|w| w.ug().set_bit());
    tim.cr1().write(|w| w.arpe().set_bit().cen().set_bit());
}
