//! The emulated board's analog world: the ISR's sensor, DAC, enable line and analog
//! reference input on one side, the virtual stage (stepped after each tick) on the
//! other.
//!
//! Its converters are those of the selected front end ([`FrontEndKind`], the bench
//! order `FrontEnd`): both the quantisation the virtual stage's readings and the
//! amplifier's voltage go through, and the scale the ISR converts codes with,
//! switch together.
//!
//! * [`FrontEndKind::Internal`] (at start): force [`FORCE_ADC`](crate::board::definition::internal::FORCE)-style 12-bit
//!   counts (`SimLink::adc`, 0.125 N a count), setpoint `SimLink::dac` (the
//!   12-bit DAC: 36.6 mV a code, about 10 nm of stage), position [`POSITION_ADC`]
//!   (16-bit code, 1.22 nm). No converter noise is added: the behaviour of before
//!   the front end could be chosen, bit for bit.
//! * [`FrontEndKind::Precision`]: force [`precision::FORCE`] (AD7606, 16 bits over
//!   −5…507 N, 7.8 mN a code), position [`crate::board::definition::POSITION`] (the same 16-bit code
//!   as [`POSITION_ADC`]), setpoint [`precision::SETPOINT`] (AD5791, 20 bits over
//!   0–150 V, 143 µV a code, about 0.04 nm of stage). The ADC's transition noise is
//!   added by the bench (`emulated::Bench`), [`PRECISION_ADC_NOISE_LSB`].
//!
//! Q formats as in the core: codes are `u16` (ADC) and `u32` (DAC; the 12-bit
//! DAC's `u16` widened), values `I16F16` (N, µm, V), gains `I4F28`/`I16F16`.

use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use embedded_hal::digital::{ErrorType, OutputPin};
use piezo_fpi::io::{AdcScale, DacScale, ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Newtons, Volts};

use crate::board::analog_in::{AnalogIn, ADC_MAX, POSITION_ADC, POSITION_MAX};
use crate::board::definition::precision;
use crate::link::protocol::FrontEndKind;

/// The AD7606's transition noise the precision front end adds to each of its
/// conversions (force and position), standard deviation in codes (LSB) at 16 bits.
///
/// The AD7606 data sheet (Rev. C, ±10 V range, no oversampling) gives an SNR of
/// 95.5 dB typical for a full-scale sine: 7.07 V rms / 10^(95.5/20) = 119 µV rms,
/// 0.39 LSB of 305 µV, of which the quantisation's own 0.29 LSB (1/√12) leaves
/// about 0.26 LSB of input noise. The bench uses 1 LSB rms, the conservative end
/// of a 16-bit converter's typical 1–2 LSB code spread on a board (reference and
/// driver noise included); quantisation comes on top. The AD5791's setpoint is
/// modelled by its quantisation alone (±1 LSB INL, 7.5 nV/√Hz output noise: far
/// below a code of 143 µV over the control bandwidth).
pub const PRECISION_ADC_NOISE_LSB: f32 = 1.0;

/// The emulated board's analog world: the ADC result the virtual stage leaves for
/// the ISR, the DAC code and enable line the ISR leaves for the virtual stage.
/// Atomics, because the ISR and thread mode share it.
pub struct SimLink {
    adc_counts: AtomicU32,
    analog_counts: AtomicU32,
    position_code: AtomicU32,
    dac_code: AtomicU32,
    enabled: AtomicBool,
    precision: AtomicBool,
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
            precision: AtomicBool::new(false),
            adc,
            dac,
        }
    }
    /// Thread mode: converts with `kind` from now on. The amplifier keeps its
    /// voltage (to the new DAC's resolution); the sensors' next readings are the
    /// new ADC's.
    pub fn select(&self, kind: FrontEndKind) {
        let (voltage, _) = self.output();
        self.precision
            .store(kind == FrontEndKind::Precision, Ordering::Release);
        let v = piezo_fpi::q::signal(f64::from(voltage)).map_or(Volts::ZERO, Volts::from_raw);
        self.dac_code.store(self.dac_code_of(v), Ordering::Release);
    }
    /// The front end it converts with.
    pub fn front_end(&self) -> FrontEndKind {
        if self.precision.load(Ordering::Acquire) {
            FrontEndKind::Precision
        } else {
            FrontEndKind::Internal
        }
    }
    /// The setpoint DAC's code for `voltage` with the selected front end.
    #[inline]
    fn dac_code_of(&self, voltage: Volts) -> u32 {
        if self.precision.load(Ordering::Acquire) {
            precision::SETPOINT.to_code(voltage)
        } else {
            u32::from(self.dac.to_code(voltage))
        }
    }
    /// Thread mode: the force the sensor reads from now on, N.
    pub fn set_force(&self, force_n: f32) {
        let c = if self.precision.load(Ordering::Acquire) {
            precision::FORCE.to_counts(force_n, u16::MAX)
        } else {
            self.adc.to_counts(force_n, ADC_MAX)
        };
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
        let code = self.dac_code.load(Ordering::Acquire);
        let voltage = if self.precision.load(Ordering::Acquire) {
            precision::SETPOINT.to_voltage(code)
        } else {
            self.dac.to_voltage(code as u16)
        };
        (voltage, self.enabled.load(Ordering::Acquire))
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
        if self.0.precision.load(Ordering::Acquire) {
            precision::FORCE.to_force(c)
        } else {
            self.0.adc.to_force(c)
        }
    }
}
impl Setpoint for SimAmplifier<'_> {
    fn write_voltage(&mut self, voltage: Volts) {
        let code = self.0.dac_code_of(voltage);
        self.0.dac_code.store(code, Ordering::Release);
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
