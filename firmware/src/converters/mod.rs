//! The precision converters' drivers on SPI: an 18/20-bit DAC for the amplifier setpoint and a
//! 16-bit simultaneous-sampling ADC for the force and position sensors, and the
//! schedule that keeps the control tick deterministic around them.
//!
//! * [`ad579x`] — the AD5781 (18-bit) / AD5791 (20-bit) voltage-output DAC;
//! * [`ad7606`] — the AD7606 (-6, -4) 16-bit simultaneous-sampling ADC, serial mode;
//! * [`scale`] — codes in volts, newtons and micrometres (Q formats stated there);
//! * [`schedule`] — where in the period each converter acts, and what a conversion
//!   that is not ready does;
//! * [`front_end`] — both parts as the control ISR uses them, and [`tick_frames`],
//!   one tick's converter work (for `cargo isr-bench`);
//! * [`bench`](mod@bench) — SPI devices that answer at once, for counting that work.
//!
//! The drivers are generic over embedded-hal 1.0's [`SpiDevice`] (it frames each
//! transaction with the part's chip select) and [`InputPin`]/[`OutputPin`]. They
//! allocate nothing and have no panic path; each error is an [`Error`]. They
//! import nothing of the application, nor of the board: the board definition
//! configures them, and the board's ports ([`crate::board::converter_ports`])
//! put them behind the core's force sensor and setpoint.
//! Each part's module lists the data-sheet facts it relies on, marking the ones
//! that could not be checked against the data sheet.
//!
//! # One control tick
//!
//! Timer phases within the 50 µs period (the board's values, [`crate::board::definition::precision::TIMING`]):
//!
//! ```text
//! phase  0 µs   timer update: the control ISR starts; LDAC̅ pulse (optional, timer
//!               compare): the DAC output takes the code the previous ISR wrote
//!        0–~8   ISR: BUSY low? read V1, V2 (one 32-bit frame), control step,
//!               write the DAC code (one 24-bit frame)
//!       44 µs   CONVST↑ (timer output compare, no software involved): V1 and V2
//!               sampled at the same instant; BUSY high
//!    ≤ 48.2 µs  BUSY↓ (t_CONV ≤ 4.15 µs): the result waits for the next ISR
//! ```
//!
//! So the sample the ISR of tick k uses was taken exactly 6 µs before the tick
//! started, whatever the ISR's latency: the sensor delay is fixed. The ISR never
//! waits for BUSY. If BUSY is still high when it looks, the tick runs on the last
//! good sample and counts a miss; [`schedule::Freshness`] turns a run of misses
//! into [`Error::Stalled`], which the application latches as a fault.
//!
//! # Cost per tick
//!
//! On the bus (blocking SPI): the ADC frame is 32 SCLK, 3.05 µs at 10.5 MHz; the DAC
//! frame is 24 SCLK, 1.14 µs at 21 MHz (2.29 µs at 10.5 MHz); with the board's
//! 10.5 MHz on both buses ([`crate::board::definition::precision`]) and chip-select
//! edges, about 5.6 µs of the 50 µs period. The processor's share (framing,
//! decoding, scaling) is what `cargo isr-bench` counts through [`tick_frames`] on
//! the [`bench`](mod@bench) devices: `converter_tick_instructions` 150 on the
//! emulated Cortex-M4 (min 144, mean 149.5 over 4 000 ticks; the isr-bench's
//! SysTick method, release build), under 1 µs at 168 MHz, without the HAL's own
//! loop over the SPI registers.
//!
//! [`SpiDevice`]: embedded_hal::spi::SpiDevice
//! [`InputPin`]: embedded_hal::digital::InputPin
//! [`OutputPin`]: embedded_hal::digital::OutputPin

pub mod ad579x;
pub mod ad7606;
pub mod bench;
pub mod front_end;
pub mod scale;
pub mod schedule;
#[cfg(test)]
mod testkit;

pub use front_end::{tick_frames, FrontEnd, FrontEndConfig, Sensed};

use embedded_hal::spi::ErrorKind;

/// Which converter an [`Error`] concerns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Device {
    /// The setpoint DAC (AD5781/AD5791).
    Dac,
    /// The sensor ADC (AD7606).
    Adc,
}

/// What went wrong with a converter: small and `Copy`, for an ISR to keep or report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Error {
    /// The ADC's BUSY line was high at the read of too many ticks in a row:
    /// conversions no longer complete (a dead converter, no CONVST, a stopped
    /// timer). The application should latch it as a fault.
    Stalled,
    /// An SPI transaction failed; the HAL's error as embedded-hal's kind.
    Spi(Device, ErrorKind),
    /// A status or configuration pin (BUSY, RESET, OS, RANGE) could not be read or
    /// driven.
    Pin(Device),
    /// The DAC read a register back other than it was written (self-test).
    Readback {
        /// The register read.
        register: ad579x::Register,
        /// Its data bits as written (DB19–DB0).
        wrote: u32,
        /// Its data bits as read back.
        read: u32,
    },
}

impl Error {
    /// A stable number for the error, for status words and logs: 1 stalled, 2 SPI,
    /// 3 pin, 4 readback.
    pub const fn code(&self) -> u8 {
        match self {
            Error::Stalled => 1,
            Error::Spi(..) => 2,
            Error::Pin(_) => 3,
            Error::Readback { .. } => 4,
        }
    }
}

/// The [`Error`] for a failed SPI transaction on `device`.
fn spi_error<E: embedded_hal::spi::Error>(device: Device) -> impl Fn(E) -> Error {
    move |e| Error::Spi(device, e.kind())
}
