//! Firmware of the STM32F405 piezo driver board: FPI hysteresis compensation in a
//! timer ISR.
//!
//! * Board build (`cargo fw`): 168 MHz from the HSE crystal, TIM2 interrupts at the
//!   model's control rate (20 kHz), force sensor on ADC1/PA0, amplifier setpoint on
//!   DAC1/PA4, amplifier enable on PB0, defmt logs over RTT.
//! * Emulated build (`cargo qemu`, feature `qemu`): the same ISR on QEMU's
//!   `netduinoplus2` (an STM32F405 memory map). QEMU models no PLL, DAC or analog
//!   world, so the clock stays on the 16 MHz HSI and the ADC/DAC are replaced by
//!   the core's virtual stage, stepped in thread mode between interrupts. Plain
//!   text over semihosting; the exit status says whether the self-checks passed.
//!
//! On the host this binary only explains how to build it.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
#[macro_use]
mod log;

#[cfg(target_os = "none")]
mod isr;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod board;

#[cfg(all(target_os = "none", feature = "qemu"))]
mod emulated;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "fpi-firmware runs on the STM32F405 driver board or on the emulated board:\n  \
         cargo fw      build and flash the board (probe-rs)\n  \
         cargo qemu    run it on QEMU's netduinoplus2\n\
         The host tools live in tests-host (cargo run -p fpi-host --bin fpi)."
    );
    std::process::exit(2);
}
