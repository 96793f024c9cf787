//! What the fuzz targets run (`fuzz_targets/*.rs` are one line each), kept in a
//! library so the seed generator (`examples/seeds.rs`) and the unit tests here use
//! the same code.
//!
//! * [`csv`] — the datasets' readers (`fpi_host::data::read_*`, `FemMaps::read`,
//!   `read_points`) on a scratch file, and the FEM maps they build;
//! * [`toml`] — the model files: `HostModel::parse` (`fpi calibrate`'s output) and
//!   `FirmwareModel::parse` → `check` → `image`, then that image on the board;
//! * [`image`] — model images into the board's store (`ModelStore::load`), as raw
//!   bytes or as edits of the factory image with the CRC fixed up, and a loaded
//!   model's controller stepped as the ISR steps it;
//! * [`link`] — the board's link: bytes into `FrameReader`, every frame into the
//!   handler of one emulated board per process (never reset), every reply checked.
//!
//! Every target panics (a crash for libFuzzer) when an invariant the code promises
//! does not hold; each `assert!` says which.
#![deny(clippy::unwrap_used)]

pub mod csv;
pub mod image;
pub mod link;
pub mod toml;

/// Reads a little-endian `u16` at `at` (0 past the end).
pub(crate) fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([
        b.get(at).copied().unwrap_or(0),
        b.get(at + 1).copied().unwrap_or(0),
    ])
}
