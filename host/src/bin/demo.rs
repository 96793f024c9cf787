//! The main job (`cargo demo`): the FPI-FFEM method on the host, then the
//! compensation loop on the emulated Cortex-M4, driven through its command link as
//! a user would drive a real board.
//!
//! 1. Runs the method on the host (`fpi demo`): calibration on the rig, prediction
//!    of stage A, the micromanipulator, feedforward, export of the efpi model for
//!    the firmware; the report goes to `tests-host/out/demo/report.md`.
//! 2. Measures the fixed-point core against its f64 reference on every recording.
//! 3. Builds the firmware for the emulated STM32F405, starts it on QEMU's
//!    `netduinoplus2` with its USART bridged to a TCP port, and runs a session over
//!    the link ([`fpi_host::board::session`]): uploads the model just exported,
//!    records, tracks the stroke without and with FPI compensation, streams nested
//!    minor loops, breaks the force sensor's wire, asks for an unreachable
//!    position, sends bad frames. Each phase is scored from the board's recording
//!    (written to `tests-host/out/demo/board-session.csv`), and the session is
//!    replayed on the host twin, which must reproduce every recorded sample.
//!
//! 4. On a fresh board with the virtual stage *as built* (a few percent off the
//!    model, an 850 Hz mode, a position sensor): identifies the dynamics from stage
//!    A's chirp, tunes and shapes the exported model, and scores open loop,
//!    feedback alone and feedback plus FPI feedforward on 15 and 100 Hz sines and
//!    a step, then the reference shaping ([`fpi_host::report::closed_loop`]).
//!
//! Exits non-zero if a target of the method, the accuracy bounds, a phase's check,
//! the twin or the closed-loop checks fail.

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use fpi_host::board::accuracy::{self, BOUND_U_V, BOUND_X_UM};
use fpi_host::board::client::Client;
use fpi_host::board::emulator::{self, Emulator};
use fpi_host::board::inprocess;
use fpi_host::board::session::{self, SessionReport};
use fpi_host::board::{self, twin};
use piezo_sim::file::FirmwareModel;

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
    // Ask for QEMU before spending time on anything else.
    let qemu = board::qemu();
    if let Err(e) = &qemu {
        if emulator::under_ci() {
            bail!("CI must run the emulated board: {e:#}");
        }
        println!("NOTE: {e:#}\n  The board session will run on the firmware built for this host instead.\n");
    }
    println!("== 1. FPI-FFEM method on the host (fpi demo) ==");
    let out = fpi_host::data::project_root().join("tests-host/out/demo");
    let chain = fpi_host::report::demo::run(&out)?;
    for l in &chain.lines {
        println!("  {l}");
    }
    println!("\n== 2. Fixed-point core against its f64 reference ==");
    let acc_ok = accuracy()?;

    let emulated = qemu.is_ok();
    let report = board_session(&out, emulated)?;
    let looped = closed_loop(&out, emulated)?;
    println!(
        "\nreport with tables and plots: {}",
        fpi_host::data::project_relative(&chain.report)
    );
    let ok = chain.ok && acc_ok && report.pass() && looped;
    if !emulated {
        println!(
            "\nSKIPPED: the firmware on the emulated Cortex-M4 (qemu-system-arm is not installed); \
             the session above ran the same firmware code built for this host. Install QEMU \
             (sudo apt-get install qemu-system-arm) and run `cargo demo` again."
        );
    }
    println!(
        "RESULT {}{}",
        if ok { "PASS" } else { "FAIL" },
        if emulated {
            ""
        } else {
            " (without the emulated Cortex-M4)"
        }
    );
    if !ok {
        bail!("see the report above");
    }
    Ok(())
}

/// Step 4: closed loop and dynamic compensation on the stage as built, on a fresh
/// board; whether its checks passed.
fn closed_loop(out: &Path, emulated: bool) -> Result<bool> {
    println!("\n== 4. Damping, tracking and autotune on the stage as built ==");
    let (emulator, port) = if emulated {
        let e = Emulator::start_elf(&Emulator::firmware()?, None)?;
        let port = e.port().to_string();
        (Some(e), port)
    } else {
        (None, inprocess::PORT_NAME.to_string())
    };
    let d = fpi_host::report::closed_loop::run(out, &out.join("firmware-stage-a.toml"), &port)?;
    drop(emulator);
    for l in &d.lines {
        println!("  {l}");
    }
    println!(
        "  check (damping + PI + feedforward beats the PI alone on the triangle and settles \
         the step sooner): {}",
        if d.ok { "ok" } else { "FAILED" }
    );
    Ok(d.ok)
}

/// Step 3: the session over the link, on the emulated board (QEMU) or, without
/// QEMU, on the firmware built for the host ([`inprocess`]); its recording and
/// its part of the report written.
fn board_session(out: &Path, emulated: bool) -> Result<SessionReport> {
    let exported = out.join("firmware-stage-a.toml");
    let text = std::fs::read_to_string(&exported)
        .with_context(|| format!("reading {}", exported.display()))?;
    let image = FirmwareModel::parse(&text, &exported.display().to_string())
        .and_then(|m| m.image())
        .map_err(anyhow::Error::msg)?;
    let (emulator, port) = if emulated {
        println!("\n== 3. The emulated board, driven over its link ==");
        let e = Emulator::start_elf(&Emulator::firmware()?, None)?;
        println!(
            "QEMU {} running the firmware, link on {}",
            board::QEMU_MACHINE,
            e.port()
        );
        let port = e.port().to_string();
        (Some(e), port)
    } else {
        println!("\n== 3. The board's firmware built for this host, driven over its link ==");
        (None, inprocess::PORT_NAME.to_string())
    };
    let mut c = Client::open(&port)?;
    let report = session::run(&mut c, &image).context("the board session")?;
    drop(c);
    drop(emulator);
    print_session(&report);
    let csv = out.join("board-session.csv");
    report.recording.write_csv(&csv)?;
    append_report(&out.join("report.md"), &report, emulated)?;
    println!(
        "  recording: {} ({} samples)",
        fpi_host::data::project_relative(&csv),
        report.recording.samples.len()
    );
    Ok(report)
}

fn print_session(r: &SessionReport) {
    println!(
        "  {:<42} {:>10} {:>10} {:>12}  check",
        "phase", "rms nm", "max nm", "sensor nm"
    );
    for p in &r.phases {
        let [rms, max, est] = p.figures_nm();
        println!(
            "  {:<42} {:>10} {:>10} {:>12}  {}",
            p.name,
            rms,
            max,
            est,
            if p.pass { "ok" } else { "FAILED" }
        );
        if !p.note.is_empty() {
            println!("      {}", p.note);
        }
    }
    let a = &r.twin;
    println!(
        "  host twin (the session's requests replayed at their ticks on the same code): {} \
         samples, positions within {:.3} nm, setpoint within {:.3} mV, force within {:.3} mN, \
         {} status differences (bound {} nm/mV/mN): {}",
        a.samples,
        a.position_um * 1e3,
        a.voltage_v * 1e3,
        a.force_n * 1e3,
        a.status,
        twin::TWIN_BOUND * 1e3,
        if a.within(twin::TWIN_BOUND) {
            "ok"
        } else {
            "DIFFERS"
        }
    );
    let k = &r.counters;
    println!(
        "  link: {} requests, {} refused ({} malformed); recorder: {} samples, {} dropped; board \
         time ran at {:.0} ticks/s of wall-clock time ({:.0} % of real time), session {:.1} s",
        k.requests,
        k.refused,
        k.malformed,
        r.recording.samples.len(),
        r.recording.dropped,
        r.ticks_per_second,
        r.ticks_per_second / 200.0,
        r.elapsed.as_secs_f64()
    );
}

/// Adds the board session to the report.
fn append_report(path: &Path, r: &SessionReport, emulated: bool) -> Result<()> {
    let mut md = std::fs::read_to_string(path).unwrap_or_default();
    let _ = writeln!(md, "\n## 7. The emulated board, driven over its link\n");
    let _ = writeln!(
        md,
        "The firmware {} with its virtual stage; the efpi model exported \
         above uploaded over the link; every figure from the board's own recording \
         (`board-session.csv`, one sample every {} ticks).\n",
        if emulated {
            "on QEMU's netduinoplus2"
        } else {
            "built for the host (QEMU was not installed: not the emulated Cortex-M4)"
        },
        session::DECIMATION
    );
    let _ = writeln!(
        md,
        "| phase | RMS nm | max nm | virtual sensor nm | check | notes |"
    );
    let _ = writeln!(md, "|---|---:|---:|---:|---|---|");
    for p in &r.phases {
        let [rms, max, est] = p.figures_nm();
        let _ = writeln!(
            md,
            "| {} | {rms} | {max} | {est} | {} | {} |",
            p.name,
            if p.pass { "ok" } else { "FAILED" },
            p.note
        );
    }
    let _ = writeln!(
        md,
        "\nTwin: {} samples replayed on the host, largest difference {:.3} nm.",
        r.twin.samples,
        r.twin.position_um * 1e3
    );
    fpi_host::output::write_atomic(path, md.as_bytes())
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
        "  on {} recordings ({} samples): stack extension within {:.3} nm (bound 1 nm); setpoint \
         within {:.3} mV where the stack responds and effective voltage within {:.3} mV \
         everywhere (bound {:.3} mV = 1 LSB of 16 bits over 150 V): {}",
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
