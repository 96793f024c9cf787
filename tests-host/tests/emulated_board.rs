//! The firmware on the emulated board, as part of `cargo test`.
//!
//! Builds the `qemu` firmware, runs it on QEMU's netduinoplus2 and requires: exit
//! status 0 (every self-check of the scripted run passed) and figures that agree
//! with the host twin's value by value (events and ticks exactly, error figures
//! within `TWIN_BOUND_UM`, 0.5 nm). Also builds the board firmware (flash and RAM within budget) and
//! the link-time no-panic proof of the control path.
//!
//! Needs `qemu-system-arm` and the thumbv7em-none-eabihf target (`cargo demo`
//! installs the target and says how to install QEMU).

use std::time::Duration;

use fpi_host::board;

#[test]
fn emulated_firmware_passes_its_self_checks_and_matches_the_host_twin() {
    let elf = board::build("fpi-firmware", "qemu").unwrap_or_else(|e| panic!("{e:#}"));
    let run = board::run(&elf, board::ICOUNT_DEMO, Duration::from_secs(300), false)
        .unwrap_or_else(|e| panic!("{e:#}"));
    println!("{}", run.stdout);
    assert!(
        run.stdout.contains("RESULT PASS"),
        "the firmware reported a failure"
    );
    assert_eq!(run.code, Some(0), "semihosting exit status");
    let emulated = board::parse_phases(&run.stdout);
    let host = board::host_phases().unwrap_or_else(|e| panic!("{e:#}"));
    assert_eq!(emulated.len(), 5, "every phase printed its values");
    let differences = board::twin_differences(&emulated, &host);
    assert!(
        differences.is_empty(),
        "the host twin must reproduce the emulator within {} nm:\n{}",
        fpi_firmware::selftest::TWIN_BOUND_UM * 1e3,
        differences.join("\n")
    );
}

#[test]
fn board_firmware_fits_its_budget_and_the_control_path_cannot_panic() {
    let board = board::build("fpi-firmware", "defmt").unwrap_or_else(|e| panic!("{e:#}"));
    let f = board::footprint(&board).unwrap_or_else(|e| panic!("{e:#}"));
    println!(
        "board firmware: {} B flash, {} B static RAM",
        f.flash, f.ram
    );
    assert!(f.flash <= 64 * 1024, "flash budget 64 KiB");
    assert!(f.ram <= 16 * 1024, "static RAM budget 16 KiB");
    // Links only if no panic branch is reachable from the control step or the ISR body.
    board::build("no-panic", "qemu").unwrap_or_else(|e| panic!("{e:#}"));
}
