//! The main job (`cargo demo`): the compensation loop on the emulated Cortex-M4,
//! then the host report.
//!
//! 1. Builds the firmware for the emulated STM32F405 (`--features qemu`) and runs it
//!    on QEMU's `netduinoplus2`: the real control ISR tracks a reference on the
//!    virtual stage without and with FPI compensation, then survives a broken
//!    force-sensor wire and an unreachable reference.
//! 2. Runs the same scripted run on the host (same core, same virtual stage) and
//!    checks that every figure the emulator printed is reproduced exactly.
//! 3. Measures the fixed-point core against its f64 reference on every recording.
//! 4. Runs the FPI-FFEM method on the host (`fpi demo`): calibration on the rig,
//!    prediction of stage A, the micromanipulator, feedforward, export; the report
//!    goes to `tests-host/out/demo/report.md`.
//!
//! Exits non-zero if the firmware's self-checks, the host twin, the accuracy
//! bounds or a target of the method fail.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Result};
use fpi_firmware::selftest::TWIN_BOUND_UM;
use fpi_host::board;
use fpi_host::board::accuracy::{self, BOUND_U_V, BOUND_X_UM};

fn main() -> ExitCode {
    fpi_host::cli::exit_quietly_on_broken_pipe();
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("demo failed: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    // Ask for QEMU before spending time on a build.
    board::qemu()?;
    println!("== 1. Building the firmware for the emulated STM32F405 ==");
    let elf = board::build("fpi-firmware", "qemu")?;
    println!(
        "\n== 2. Compensation loop on the emulated Cortex-M4 (QEMU {}) ==",
        board::QEMU_MACHINE
    );
    let q = board::run(&elf, board::ICOUNT_DEMO, Duration::from_secs(300), true)?;
    println!(
        "(emulation took {:.1} s of wall-clock time)",
        q.elapsed.as_secs_f64()
    );
    println!("\n== 3. Host report ==");
    let twin_ok = twin(&q.stdout)?;
    let acc_ok = accuracy()?;
    println!("\nFPI-FFEM method on the host (fpi demo):");
    let out = board::project_root().join("tests-host/out/demo");
    let chain = fpi_host::report::demo::run(&out)?;
    for l in &chain.lines {
        println!("  {l}");
    }
    println!(
        "  report with tables and plots: {}",
        fpi_host::method::export::project_relative(&chain.report)
    );
    let fw_ok = q.code == Some(0);
    println!(
        "\nemulated firmware self-checks: {}",
        if fw_ok { "PASS" } else { "FAIL (exit status)" }
    );
    if !(fw_ok && twin_ok && acc_ok && chain.ok) {
        bail!("see the report above");
    }
    Ok(())
}

/// The emulator's figures against the host twin's; whether they agree.
fn twin(stdout: &str) -> Result<bool> {
    let emulated = board::parse_phases(stdout);
    let host = board::host_phases()?;
    let differences = board::twin_differences(&emulated, &host);
    let ok = !emulated.is_empty() && differences.is_empty();
    let worst = emulated
        .iter()
        .zip(&host)
        .flat_map(|(e, h)| {
            [
                (e.rms_um - h.rms_um).abs(),
                (e.max_um - h.max_um).abs(),
                (e.est_rms_um - h.est_rms_um).abs(),
            ]
        })
        .fold(0.0f32, f32::max);
    println!(
        "host twin (same core, same virtual stage, no interrupts): {} phases, {}",
        host.len(),
        if ok {
            format!(
                "events and ticks identical to the emulator's, error figures within {:.3} nm \
                 (bound {} nm)",
                worst * 1e3,
                TWIN_BOUND_UM * 1e3
            )
        } else {
            "DIFFERS from the emulator".to_string()
        }
    );
    for d in &differences {
        println!("  {d}");
    }
    Ok(ok)
}

/// The fixed-point core against its f64 reference on every recording; whether it
/// meets the bounds.
fn accuracy() -> Result<bool> {
    let files = accuracy::all_files()?;
    let worst = |f: fn(&accuracy::FileAccuracy) -> f64| files.iter().map(f).fold(0.0, f64::max);
    let (dx, du, duh) = (
        worst(|f| f.max_dx_um),
        worst(|f| f.max_du_v),
        worst(|f| f.max_duh_v),
    );
    let samples: usize = files.iter().map(|f| f.samples).sum();
    let ok = dx <= BOUND_X_UM && du <= BOUND_U_V && duh <= BOUND_U_V;
    println!(
        "fixed-point core vs f64 reference on {} recordings ({} samples): stack extension within \
         {:.3} nm (bound 1 nm); setpoint within {:.3} mV where the stack responds and effective \
         voltage within {:.3} mV everywhere (bound {:.3} mV = 1 LSB of 16 bits over 150 V): {}",
        files.len(),
        samples,
        dx * 1e3,
        du * 1e3,
        duh * 1e3,
        BOUND_U_V * 1e3,
        if ok { "ok" } else { "FAILED" }
    );
    Ok(ok)
}
