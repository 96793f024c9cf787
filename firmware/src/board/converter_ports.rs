//! The precision front end behind the core's boundary, so that the control loop
//! runs on it unchanged:
//!
//! * [`Force`] is the [`ForceSensor`]: at the start of a tick it reads the AD7606's
//!   frame ([`Sensing::sense`]), returns the force (N, `I16F16`) and leaves the
//!   position's 16-bit code in the [`Health`];
//! * [`Analog`] is the loop's [`AnalogIn`]: the position code from that same frame
//!   (the loop reads it after the force, in the same tick), and the analog
//!   reference input from the board's own ADC ([`ReferenceIn`]);
//! * [`Amplifier`] is the [`Setpoint`]: it writes the AD5791 ([`Driving::drive`]).
//!
//! **The converter fault.** Neither trait can return an error, so each side notes
//! its converter's present failure in the [`Health`] they share, and [`latch`],
//! run after each tick, turns one into [`Fault::Converter`]: the output ramps to
//! the safe voltage from the next tick and the amplifier is switched off at its
//! end, as for the other sensor faults. A stalled ADC ([`Error::Stalled`]: BUSY
//! still high at the read of [`FrontEndConfig::stale_limit`] ticks in a row) or a
//! failed ADC transaction makes the force sensor hold its last good reading (the
//! park's ramp does not depend on it); a failed DAC write keeps the ramp going
//! (the next write may succeed), and the enable line drops at the ramp's end
//! whatever the DAC did. The failure is cleared by the next good conversion or
//! write, so a host can clear the fault once the converter works again; while it
//! fails, every tick latches the fault anew.

use crate::board::analog_in::AnalogIn;
use crate::converters::front_end::{Driving, FrontEndConfig, Sensing};
use crate::converters::{Device, Error};
use core::sync::atomic::{AtomicU32, AtomicU8, Ordering};
use embedded_hal::digital::InputPin;
use embedded_hal::spi::SpiDevice;
use piezo_fpi::control::Fault;
use piezo_fpi::io::{ForceSensor, Setpoint};
use piezo_fpi::q::{Newtons, Volts};

/// What the ports share within a tick: the position code the ADC's frame brought,
/// and each converter's present failure ([`Error::code`], 0 = none). Atomics, so
/// that a `static` can hold it; only the control ISR touches it.
#[derive(Debug)]
pub struct Health {
    position: AtomicU32,
    adc: AtomicU8,
    dac: AtomicU8,
}

impl Health {
    /// Both converters working, the position at `position_code` (the first
    /// conversion's).
    pub const fn new(position_code: u16) -> Self {
        Self {
            position: AtomicU32::new(position_code as u32),
            adc: AtomicU8::new(0),
            dac: AtomicU8::new(0),
        }
    }

    /// The failing converter and its error's code ([`Error::code`]), the ADC's
    /// first; `None` while both work.
    pub fn failure(&self) -> Option<(Device, u8)> {
        let adc = self.adc.load(Ordering::Relaxed);
        let dac = self.dac.load(Ordering::Relaxed);
        match (adc, dac) {
            (0, 0) => None,
            (0, e) => Some((Device::Dac, e)),
            (e, _) => Some((Device::Adc, e)),
        }
    }

    /// The position channel's latest code.
    fn position(&self) -> u16 {
        self.position.load(Ordering::Relaxed) as u16
    }

    fn sensed(&self, position_code: u16) {
        self.position
            .store(u32::from(position_code), Ordering::Relaxed);
        self.adc.store(0, Ordering::Relaxed);
    }

    fn note(cell: &AtomicU8, e: Option<Error>) {
        cell.store(e.map_or(0, |e| e.code()), Ordering::Relaxed);
    }
}

/// The analog reference input on the board's own ADC (12-bit counts).
pub trait ReferenceIn {
    /// The latest conversion, 12-bit counts.
    fn read_counts(&mut self) -> u16;
}

/// The AD7606 as the core's force sensor.
#[derive(Debug)]
pub struct Force<'a, SA, B> {
    sensing: Sensing<SA, B>,
    cfg: &'a FrontEndConfig,
    health: &'a Health,
    force: Newtons,
}

impl<'a, SA: SpiDevice, B: InputPin> Force<'a, SA, B> {
    /// The ADC's half, its scalings, the shared health; `force` until the first
    /// read (N, `I16F16`).
    pub const fn new(
        sensing: Sensing<SA, B>,
        cfg: &'a FrontEndConfig,
        health: &'a Health,
        force: Newtons,
    ) -> Self {
        Self {
            sensing,
            cfg,
            health,
            force,
        }
    }

    /// Misses in the current run and since start-up.
    pub const fn misses(&self) -> (u16, u32) {
        self.sensing.misses()
    }
}

impl<SA: SpiDevice, B: InputPin> ForceSensor for Force<'_, SA, B> {
    /// This tick's force; the last good one if the ADC failed (see the module).
    #[inline]
    fn read_force(&mut self) -> Newtons {
        match self.sensing.sense(self.cfg) {
            Ok(s) => {
                self.force = s.force;
                self.health.sensed(s.position_code);
            }
            Err(e) => Health::note(&self.health.adc, Some(e)),
        }
        self.force
    }
}

/// The AD5791 as the core's amplifier setpoint.
#[derive(Debug)]
pub struct Amplifier<'a, SD> {
    driving: Driving<SD>,
    cfg: &'a FrontEndConfig,
    health: &'a Health,
}

impl<'a, SD: SpiDevice> Amplifier<'a, SD> {
    /// The DAC's half (initialised), its scaling, the shared health.
    pub const fn new(driving: Driving<SD>, cfg: &'a FrontEndConfig, health: &'a Health) -> Self {
        Self {
            driving,
            cfg,
            health,
        }
    }
}

impl<SD: SpiDevice> Setpoint for Amplifier<'_, SD> {
    #[inline]
    fn write_voltage(&mut self, voltage: Volts) {
        let e = self.driving.drive(self.cfg, voltage).err();
        Health::note(&self.health.dac, e);
    }
}

/// The position channel from the ADC's frame, the reference input from `R`.
#[derive(Debug)]
pub struct Analog<'a, R> {
    reference: R,
    health: &'a Health,
}

impl<'a, R: ReferenceIn> Analog<'a, R> {
    /// The reference input and the shared health.
    pub const fn new(reference: R, health: &'a Health) -> Self {
        Self { reference, health }
    }
}

impl<R: ReferenceIn> AnalogIn for Analog<'_, R> {
    #[inline]
    fn read_counts(&mut self) -> u16 {
        self.reference.read_counts()
    }
    #[inline]
    fn read_position(&mut self) -> u16 {
        self.health.position()
    }
}

/// After a tick: a converter failing now latches [`Fault::Converter`] through
/// `fail` (the control loop's own latch, which keeps a fault latched already).
/// Returns the failure.
#[inline]
pub fn latch(health: &Health, fail: impl FnOnce(Fault)) -> Option<(Device, u8)> {
    let failure = health.failure();
    if failure.is_some() {
        fail(Fault::Converter);
    }
    failure
}

#[cfg(test)]
mod tests;
