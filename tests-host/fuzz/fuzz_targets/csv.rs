//! `fpi_host::data::parse_csv` for every record type (see `fpi_fuzz::csv`).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| fpi_fuzz::csv::run(data));
