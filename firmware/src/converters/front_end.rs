//! The two converters as the control ISR uses them: at the start of a tick,
//! [`FrontEnd::sense`] reads the conversion CONVST started in the previous period
//! (force on V1, position on V2) and scales it; after the control step,
//! [`FrontEnd::drive`] writes the setpoint's code. See [`super::schedule`] for the
//! timing that makes both deterministic.

use super::ad579x::Ad579x;
use super::ad7606::Ad7606;
use super::scale::{offset_binary, PrecisionDacScale};
use super::schedule::Freshness;
use super::Error;
use embedded_hal::digital::InputPin;
use embedded_hal::spi::SpiDevice;
use piezo_fpi::io::AdcScale;
use piezo_fpi::q::{Micrometres, Newtons, Volts};

/// The scalings and the miss limit (configuration; the state is in [`FrontEnd`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrontEndConfig {
    /// The force channel (V1): offset-binary code to newtons.
    pub force: AdcScale,
    /// The position channel (V2): offset-binary code to micrometres.
    pub position: AdcScale,
    /// The setpoint: amplifier volts to DAC code.
    pub setpoint: PrecisionDacScale,
    /// Missed conversions in a row before [`Error::Stalled`] (at least 1).
    pub stale_limit: u16,
}

/// What one tick's sensing gives the control step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sensed {
    /// The force, N (`I16F16`).
    pub force: Newtons,
    /// The position channel's offset-binary code (what
    /// [`crate::board::analog_in::AnalogIn::read_position`] returns).
    pub position_code: u16,
    /// The position, µm (`I16F16`).
    pub position: Micrometres,
    /// 0: converted for this tick; k: the k-th tick in a row on the last good
    /// conversion.
    pub age: u16,
}

/// The ADC's half: the two channels and the state of their misses.
#[derive(Debug)]
pub struct Sensing<SA, B> {
    adc: Ad7606<SA, B, 2>,
    held: Freshness<2>,
}

impl<SA: SpiDevice, B: InputPin> Sensing<SA, B> {
    /// The ADC, set up, and its first conversion's codes (read at start-up).
    pub const fn new(adc: Ad7606<SA, B, 2>, first: [i16; 2]) -> Self {
        Self {
            adc,
            held: Freshness::new(first),
        }
    }

    /// The start of a tick: one look at the ADC (a 32-bit frame if BUSY is low),
    /// scaled; the last good codes while a run of misses is under the limit.
    #[inline]
    pub fn sense(&mut self, cfg: &FrontEndConfig) -> Result<Sensed, Error> {
        let held = self.held.take(self.adc.read(), cfg.stale_limit)?;
        let [force, position] = held.codes.map(offset_binary);
        Ok(Sensed {
            force: cfg.force.to_force(force),
            position_code: position,
            position: cfg.position.to_position(position),
            age: held.age,
        })
    }

    /// Misses in the current run and since start-up.
    pub const fn misses(&self) -> (u16, u32) {
        (self.held.missed(), self.held.missed_total())
    }
}

/// The DAC's half.
#[derive(Debug)]
pub struct Driving<SD> {
    dac: Ad579x<SD>,
}

impl<SD: SpiDevice> Driving<SD> {
    /// The DAC, set up.
    pub const fn new(dac: Ad579x<SD>) -> Self {
        Self { dac }
    }

    /// The end of a tick: the setpoint's code in one 24-bit frame. Returns the code.
    #[inline]
    pub fn drive(&mut self, cfg: &FrontEndConfig, voltage: Volts) -> Result<u32, Error> {
        let code = cfg.setpoint.to_code(voltage);
        self.dac.write_code(code)?;
        Ok(code)
    }

    /// The DAC, for its self-test or to clamp its output.
    pub fn dac(&mut self) -> &mut Ad579x<SD> {
        &mut self.dac
    }
}

/// The ADC (two channels) and the DAC, with the state of the ADC's misses: the
/// two halves together.
#[derive(Debug)]
pub struct FrontEnd<SA, B, SD> {
    /// The ADC's half.
    pub sensing: Sensing<SA, B>,
    /// The DAC's half.
    pub driving: Driving<SD>,
}

impl<SA: SpiDevice, B: InputPin, SD: SpiDevice> FrontEnd<SA, B, SD> {
    /// Both parts, set up, and the first conversion's codes (read at start-up).
    pub const fn new(adc: Ad7606<SA, B, 2>, dac: Ad579x<SD>, first: [i16; 2]) -> Self {
        Self {
            sensing: Sensing::new(adc, first),
            driving: Driving::new(dac),
        }
    }

    /// [`Sensing::sense`].
    #[inline]
    pub fn sense(&mut self, cfg: &FrontEndConfig) -> Result<Sensed, Error> {
        self.sensing.sense(cfg)
    }

    /// [`Driving::drive`].
    #[inline]
    pub fn drive(&mut self, cfg: &FrontEndConfig, voltage: Volts) -> Result<u32, Error> {
        self.driving.drive(cfg, voltage)
    }

    /// Misses in the current run and since start-up.
    pub const fn misses(&self) -> (u16, u32) {
        self.sensing.misses()
    }

    /// The DAC, for its self-test or to clamp its output.
    pub fn dac(&mut self) -> &mut Ad579x<SD> {
        self.driving.dac()
    }
}

/// One tick's converter work, as the ISR does it: [`FrontEnd::sense`], then
/// [`FrontEnd::drive`] with `voltage` (the control step runs between the two in the
/// ISR). The sensing's result; a failed DAC write's error takes precedence.
///
/// `cargo isr-bench` counts it on [`super::bench::front_end`], whose SPI devices
/// answer at once: the processor's share of the converter work, without the bus
/// time (see the module [`super`]).
#[inline(never)]
pub fn tick_frames<SA: SpiDevice, B: InputPin, SD: SpiDevice>(
    front: &mut FrontEnd<SA, B, SD>,
    cfg: &FrontEndConfig,
    voltage: Volts,
) -> Result<Sensed, Error> {
    let sensed = front.sense(cfg);
    front.drive(cfg, voltage)?;
    sensed
}

#[cfg(test)]
mod tests;
