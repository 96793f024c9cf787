//! One logging macro for both builds: defmt over RTT on the board, plain text over
//! semihosting in the emulator (no host-side decoder needed there).
//!
//! Arguments must format with both `defmt` and `core::fmt` (`&str`, integers, `f32`);
//! figures are printed as integers in nm or mV so both render them the same.

#[cfg(not(feature = "qemu"))]
macro_rules! say {
    ($($arg:tt)*) => { defmt::info!($($arg)*) };
}

#[cfg(feature = "qemu")]
macro_rules! say {
    ($($arg:tt)*) => { cortex_m_semihosting::hprintln!($($arg)*) };
}
