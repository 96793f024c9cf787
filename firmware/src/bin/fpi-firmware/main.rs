//! Firmware of the STM32F405 piezo driver board: FPI hysteresis compensation in
//! the control interrupt, a command link on USART1, a data recorder and model
//! upload — one RTIC application for the board and the emulated board.
//!
//! | task | priority | runs |
//! |---|---|---|
//! | `control` (SysTick, 20 kHz) | 3 | one control tick: order, reference, sensor, step, DAC, recorder |
//! | `usart1` (USART1 RX) | 2 | moves received bytes into a queue |
//! | `otg_fs` (OTG_FS) | 2 | polls the USB device: received bytes into a queue, queued replies out ([`TxPump`]) |
//! | `idle` (link task) | 0 | frames from either link, commands, replies (on the link the request came over), model loading, flash |
//!
//! [`TxPump`]: fpi_firmware::link::usb::TxPump
//!
//! The control task and the link task share one [`Exchange`], which the control
//! task reaches without a lock (it is the highest-priority user) and the link
//! task locks briefly; a new model reaches the control task by value
//! ([`fpi_firmware::control::slots`]). So parsing, validation and flash writes never delay
//! a tick, as in quartiq's Stabilizer, where settings are rebuilt at low priority
//! and swapped in.
//!
//! * Board build (`cargo fw`): the board definition's
//!   ([`fpi_firmware::board::definition`]) clock (168 MHz from the 8 MHz HSE crystal),
//!   front end (the STM32's 12-bit ADCs and DAC; with `--features precision` an
//!   AD7606 and an AD5791 on SPI), pins and link (USB CDC-ACM on OTG_FS and, as
//!   the fallback, USART1 at 115 200 Bd); stored model in flash sectors 10/11,
//!   defmt logs over RTT.
//! * Emulated build (feature `qemu`, run by `fpi board emulate`): the same
//!   application on QEMU's `netduinoplus2` (an STM32F405 memory map) with USART1
//!   bridged to a TCP port (QEMU has no OTG model: its USB never connects; the
//!   link is paced as the one it emulates, see `fpi_firmware::link::pace`). QEMU models no PLL, DAC, analog world or flash
//!   programming, so the clock stays on the 16 MHz HSI, the ADCs and DAC are the
//!   virtual stage's ([`fpi_firmware::emulation::virtual_bench`]) and the model store is
//!   RAM-backed.
//!
//! On the host this binary only explains how to build it.
//!
//! [`Exchange`]: fpi_firmware::control::exchange::Exchange
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
#[macro_use]
mod log;

#[cfg(target_os = "none")]
mod supervisor;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod board;
#[cfg(all(target_os = "none", not(feature = "qemu")))]
use board as io;

#[cfg(all(target_os = "none", feature = "qemu"))]
mod qemu_board;
#[cfg(all(target_os = "none", feature = "qemu"))]
use qemu_board as io;

include!("app.rs");
