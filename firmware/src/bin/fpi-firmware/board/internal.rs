//! The internal front end: the force sensor on ADC1, the position sensor on
//! ADC3 and the amplifier setpoint on the 12-bit DAC, as the board definition
//! places and scales them ([`fpi_firmware::board::definition::internal`]).
//!
//! The ADC conversions for tick k+1 are started at the end of tick k, so the ISR
//! reads finished results (3.4 µs conversions in a 50 µs period) instead of
//! waiting.

use super::{start_single, take_single, Enable, ReferenceAdc};
use fpi_firmware::board::analog_in::AnalogIn;
use fpi_firmware::board::converter_ports::ReferenceIn;
use fpi_firmware::board::definition::internal::{FORCE, FORCE_CHANNEL, POSITION_CHANNEL, SETPOINT};
use fpi_firmware::board::definition::pins::{ForceAdc, Internal, PositionAdc};
use fpi_firmware::control::task::ControlLoop;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Newtons, Volts};
use stm32f4xx_hal::adc::config::{AdcConfig, SampleTime, Sequence};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::dac::{DacOut, DacPin, C1};
use stm32f4xx_hal::gpio::{Analog as AnalogMode, PA0, PC0};
use stm32f4xx_hal::pac::DAC;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Enable as _, Rcc, Reset as _};

/// The force sensor on ADC1.
pub struct Sensor {
    adc: Adc<ForceAdc>,
    _pin: PA0<AnalogMode>,
}

impl ForceSensor for Sensor {
    fn read_force(&mut self) -> Newtons {
        let counts = self.adc.current_sample();
        self.adc.start_conversion();
        FORCE.to_force(counts)
    }
}

/// The amplifier setpoint on DAC channel 1.
pub struct Amplifier(C1);

impl Setpoint for Amplifier {
    fn write_voltage(&mut self, voltage: Volts) {
        self.0.set_value(SETPOINT.to_code(voltage));
    }
}

/// The analog reference input and the stage-position sensor on ADC3, driven
/// through its registers (the HAL's `Adc::new` only takes ADC1).
pub struct Analog {
    reference: ReferenceAdc,
    position: PositionAdc,
    _pin: PC0<AnalogMode>,
}

impl AnalogIn for Analog {
    fn read_counts(&mut self) -> u16 {
        self.reference.read_counts()
    }
    fn read_position(&mut self) -> u16 {
        // 12 bits, left-aligned to the channel's 16-bit code.
        take_single(&self.position) << 4
    }
}

/// The control loop on this front end.
pub type Control = ControlLoop<Sensor, Amplifier, Enable, Analog>;

/// Nothing to align before a tick: conversions start in software.
#[inline(always)]
pub fn before_tick() {}

/// Nothing to check after a tick: the on-chip converters cannot stall.
#[inline(always)]
pub fn after_tick(_control: &mut Control) {}

/// The converters with their first conversions started, the DAC at 0 V.
pub fn init(
    pins: Internal,
    (adc1, adc3, dac): (ForceAdc, PositionAdc, DAC),
    reference: ReferenceAdc,
    enable: Enable,
    rcc: &mut Rcc,
) -> (Hardware<Sensor, Amplifier, Enable>, Analog) {
    let mut dac = dac.constrain(pins.setpoint, rcc);
    dac.enable();
    dac.set_value(0);

    let force = pins.force;
    let mut adc = Adc::<ForceAdc>::new(adc1, true, AdcConfig::default(), rcc);
    adc.configure_channel(&force, Sequence::One, SampleTime::Cycles_56);
    adc.enable();
    let _ = adc.convert(&force, SampleTime::Cycles_56);
    adc.start_conversion();
    const _: () = assert!(
        FORCE_CHANNEL == 0,
        "the HAL takes ADC1's channel from its pin"
    );

    PositionAdc::enable(rcc);
    PositionAdc::reset(rcc);
    start_single(&adc3, POSITION_CHANNEL);
    let hw = Hardware {
        sensor: Sensor { adc, _pin: force },
        amplifier: Amplifier(dac),
        enable,
    };
    let analog = Analog {
        reference,
        position: adc3,
        _pin: pins.position,
    };
    (hw, analog)
}
