//! The emulated board's analog world: the ISR's sensor, DAC, enable line and analog
//! reference input on one side, the virtual stage (stepped after each tick) on the
//! other.

use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use embedded_hal::digital::{ErrorType, OutputPin};
use piezo_fpi::io::{AdcScale, DacScale, ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Newtons, Volts};

use crate::frontend::{AnalogIn, ADC_MAX, POSITION_ADC, POSITION_MAX};

/// The emulated board's analog world: the ADC result the virtual stage leaves for
/// the ISR, the DAC code and enable line the ISR leaves for the virtual stage.
/// Atomics, because the ISR and thread mode share it.
pub struct SimLink {
    adc_counts: AtomicU32,
    analog_counts: AtomicU32,
    position_code: AtomicU32,
    dac_code: AtomicU32,
    enabled: AtomicBool,
    /// Board scaling of the force ADC.
    pub adc: AdcScale,
    /// Board scaling of the setpoint DAC.
    pub dac: DacScale,
}

impl SimLink {
    /// An idle link (0 counts, 0 V, amplifier off).
    pub const fn new(adc: AdcScale, dac: DacScale) -> Self {
        Self {
            adc_counts: AtomicU32::new(0),
            analog_counts: AtomicU32::new(0),
            position_code: AtomicU32::new(0),
            dac_code: AtomicU32::new(0),
            enabled: AtomicBool::new(false),
            adc,
            dac,
        }
    }
    /// Thread mode: the force the sensor reads from now on, N.
    pub fn set_force(&self, force_n: f32) {
        let c = self.adc.to_counts(force_n, ADC_MAX);
        self.adc_counts.store(c as u32, Ordering::Release);
    }
    /// Thread mode: the position sensor's reading from now on, µm.
    pub fn set_position(&self, x_um: f32) {
        let c = POSITION_ADC.to_counts(x_um, POSITION_MAX);
        self.position_code.store(c as u32, Ordering::Release);
    }
    /// Thread mode: the analog reference input's reading from now on, ADC counts.
    pub fn set_analog_counts(&self, counts: u16) {
        self.analog_counts.store(counts as u32, Ordering::Release);
    }
    /// Thread mode: the amplifier output, V (0 while disabled), and the enable line.
    pub fn output(&self) -> (f32, bool) {
        let code = self.dac_code.load(Ordering::Acquire) as u16;
        (
            self.dac.to_voltage(code),
            self.enabled.load(Ordering::Acquire),
        )
    }
    /// The ISR's side of the analog reference input.
    pub fn analog(&self) -> SimAnalog<'_> {
        SimAnalog(self)
    }
    /// The ISR's side of the link: sensor, amplifier, enable.
    pub fn hardware(&self) -> Hardware<SimSensor<'_>, SimAmplifier<'_>, SimEnable<'_>> {
        Hardware {
            sensor: SimSensor(self),
            amplifier: SimAmplifier(self),
            enable: SimEnable(self),
        }
    }
}

/// The emulated force sensor (ISR side of a [`SimLink`]).
pub struct SimSensor<'a>(&'a SimLink);
/// The emulated DAC (ISR side of a [`SimLink`]).
pub struct SimAmplifier<'a>(&'a SimLink);
/// The emulated amplifier-enable line (ISR side of a [`SimLink`]).
pub struct SimEnable<'a>(&'a SimLink);
/// The emulated analog reference input (ISR side of a [`SimLink`]).
pub struct SimAnalog<'a>(&'a SimLink);

impl AnalogIn for SimAnalog<'_> {
    fn read_counts(&mut self) -> u16 {
        self.0.analog_counts.load(Ordering::Acquire) as u16
    }
    fn read_position(&mut self) -> u16 {
        self.0.position_code.load(Ordering::Acquire) as u16
    }
}

impl ForceSensor for SimSensor<'_> {
    fn read_force(&mut self) -> Newtons {
        let c = self.0.adc_counts.load(Ordering::Acquire) as u16;
        self.0.adc.to_force(c)
    }
}
impl Setpoint for SimAmplifier<'_> {
    fn write_voltage(&mut self, voltage: Volts) {
        let code = self.0.dac.to_code(voltage);
        self.0.dac_code.store(code as u32, Ordering::Release);
    }
}
impl ErrorType for SimEnable<'_> {
    type Error = Infallible;
}
impl OutputPin for SimEnable<'_> {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.enabled.store(false, Ordering::Release);
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        self.0.enabled.store(true, Ordering::Release);
        Ok(())
    }
}
