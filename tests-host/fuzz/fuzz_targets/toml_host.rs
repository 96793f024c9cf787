//! `HostModel::parse` (see `fpi_fuzz::toml::host`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::toml::host(data));
