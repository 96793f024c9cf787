//! The hardware-independent parts of the piezo driver board's firmware, compiled
//! for the board and tested on the host, in five rooms (listed from the top
//! down), each importing only from
//! the rooms below it (and from the core crate `piezo-fpi` and `fpi-protocol`):
//!
//! 1. [`emulation`] — the emulated board: its virtual I/O and, with the `sim`
//!    feature, the virtual bench the QEMU board and the host's twin run;
//! 2. [`link`] — the command link: the link task's command handler, the model
//!    upload, the link's pace and the USB byte pump, over `fpi-protocol`;
//! 3. [`control`] — the control task: the control ISR's tick, the loops, the
//!    reference sources and their governors, the loop watch, the analyser, the
//!    recorder, the model stores and what the ISR and the link task share;
//! 4. [`board`] — the board: its definition, capacity and analog channels, the
//!    converters' ports to the core, the factory model, the model's flash store
//!    and the watchdog's feeding rule;
//! 5. [`converters`] — the precision converters' drivers on SPI (AD5781/AD5791
//!    DAC, AD7606 ADC) and the schedule that keeps the tick deterministic around
//!    them; they import nothing of the application.
//!
//! The binaries (`src/bin/`) add the hardware and the tasks: the STM32F405 board
//! and the emulated board (one RTIC application), the instruction-count benchmark
//! and the no-panic proof.
#![cfg_attr(not(test), no_std)]
#![deny(clippy::panic, clippy::unwrap_used, clippy::expect_used)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod board;
pub mod control;
pub mod converters;
pub mod emulation;
pub mod link;
