//! `FirmwareModel::parse`, `check`, `image`, and the image on the board (see
//! `fpi_fuzz::toml::firmware`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::toml::firmware(data));
