//! `cargo isr-bench`: instructions per control step on the emulated Cortex-M4, and
//! the flash and static RAM of the release firmware.
//!
//! Builds `isr-bench` for the emulated board and runs it under
//! `-icount shift=10,align=off,sleep=off` (SysTick differences are then exact
//! instruction counts), printing `control_step_instructions n=<N>: <count>` for
//! n = 4, 10, 16, 32; then builds the board firmware (`--features defmt`, and
//! `defmt,precision` for the precision front end) and the emulated one and reads
//! their section sizes.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Result};
use fpi_host::board;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("isr-bench failed: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    board::qemu()?;
    let bench = board::build("isr-bench", "qemu")?;
    let q = board::run(&bench, board::ICOUNT_BENCH, Duration::from_secs(300), true)?;
    if q.code != Some(0) {
        bail!("the benchmark firmware failed (exit {:?})", q.code);
    }
    // Program flash: 768 KiB (sectors 10 and 11 hold the stored model); RAM: the
    // chip's 128 KiB, and the 192 KiB of QEMU's netduinoplus2 for the emulated
    // board, which keeps its model "flash" in RAM.
    for (name, features, ram_kib) in [
        ("board", "defmt", 128),
        ("board_precision", "defmt,precision", 128),
        ("emulated", "qemu", 192),
    ] {
        let elf = board::build("fpi-firmware", features)?;
        let f = board::footprint(&elf)?;
        println!(
            "firmware_{name}_flash_bytes: {} ({:.1} KiB of 768 KiB)",
            f.flash,
            f.flash as f64 / 1024.0
        );
        println!(
            "firmware_{name}_static_ram_bytes: {} ({:.1} KiB of {ram_kib} KiB, stack not included)",
            f.ram,
            f.ram as f64 / 1024.0
        );
    }
    Ok(())
}
