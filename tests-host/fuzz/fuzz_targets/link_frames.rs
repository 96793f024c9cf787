//! A script of link operations: raw bytes, framed payloads, idle ticks, model
//! uploads (see `fpi_fuzz::link::ops`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::link::ops(data));
