//! The factory model image edited by the input, its CRC fixed up, into the board's
//! store (see `fpi_fuzz::image::edited`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::image::edited(data));
