//! The input as the byte stream on the board's link (see `fpi_fuzz::link::bytes`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::link::bytes(data));
