//! Arbitrary bytes as a model image into the board's store (see
//! `fpi_fuzz::image::raw`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::image::raw(data));
