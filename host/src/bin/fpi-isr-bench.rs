//! `cargo isr-bench`: instructions per control step on the emulated Cortex-M4, and
//! the flash and static RAM of the release firmware.
//!
//! Builds `isr-bench` (one axis, as the board builds it) and `isr-bench-axes`
//! (a three-axis control task) for the emulated board and runs each under
//! `-icount shift=10,align=off,sleep=off` (SysTick differences are then exact
//! instruction counts), printing `control_step_instructions n=<N>: <count>` for
//! n = 4, 10, 16, 32; then builds the board firmware (`--features defmt`, and
//! `defmt,precision` for the precision front end) and the emulated one and reads
//! their section sizes.
//!
//! Fails (exit 1, after printing every figure) when a budget is passed: the
//! worst whole control tick above [`TICK_BUDGET`] instructions, the worst
//! three-axis tick above [`THREE_AXES_BUDGET`], or the n = 10 step, compiled
//! in or received at run time, above [`STEP_BUDGET`] (issue 19's item 3).
//! Prints the three-axis tick against its target ([`THREE_AXES_TARGET`]),
//! met or missed. Instruction counts under `-icount` are exact and repeatable,
//! so the check is not a timing test; a compiler that lays the code out
//! differently can move them by a few instructions.

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

/// The worst whole control tick's budget, instructions (20 kHz on a 168 MHz
/// Cortex-M4 leaves 8 400 cycles; the budget keeps the tick well inside). The
/// tick that the reference governor departs from in closed loop is measured
/// against it too. It was 1 600 until the trigger output, which costs the
/// tick up to 55 instructions (its travel condition; 14 while it is off).
const TICK_BUDGET: u32 = 1700;
/// The worst three-axis closed-loop tick's budget, instructions: it must
/// stay well inside the 8 400 cycles of a 20 kHz period on a 168 MHz M4
/// (71 %, leaving room for the interrupt's entry, the converters' bus time
/// and the link task).
const THREE_AXES_BUDGET: u32 = 6000;
/// What issue 44 asks of the three-axis tick, instructions (about 55 % of
/// the period): printed as met or missed, not a failure.
const THREE_AXES_TARGET: u32 = 4500;
/// The n = 10 step's budget (inverse, forward, two lookups, limits),
/// instructions.
const STEP_BUDGET: u32 = 300;

fn run() -> Result<()> {
    board::qemu()?;
    let mut out = String::new();
    for bin in ["isr-bench", "isr-bench-axes"] {
        let bench = board::build(bin, "qemu")?;
        let q = board::run(&bench, board::ICOUNT_BENCH, Duration::from_secs(300), true)?;
        if q.code != Some(0) {
            bail!("the benchmark firmware `{bin}` failed (exit {:?})", q.code);
        }
        out.push_str(&q.stdout);
    }
    let over = over_budget(&out)?;
    // Program flash: 768 KiB (sectors 10 and 11 hold the stored model); SRAM:
    // the chip's 128 KiB (the emulated board keeps its model "flash" in it
    // too); CCM: 64 KiB (the model stores and the image buffer).
    for (name, bin, features) in [
        ("board", "fpi-firmware", "defmt"),
        ("board_precision", "fpi-firmware", "defmt,precision"),
        ("emulated", "fpi-firmware", "qemu"),
        ("emulated_two_axes", "fpi-firmware-xy", "qemu"),
        ("three_axes", "fpi-firmware-xyz", "qemu"),
    ] {
        let elf = board::build(bin, features)?;
        let f = board::footprint(&elf)?;
        println!(
            "firmware_{name}_flash_bytes: {} ({:.1} KiB of 768 KiB)",
            f.flash,
            f.flash as f64 / 1024.0
        );
        println!(
            "firmware_{name}_static_ram_bytes: {} ({:.1} KiB of 128 KiB, stack not included; \
             {} B of it the emulated board's flash); ccm_bytes: {} ({:.1} KiB of 64 KiB); \
             stack: {:.1} KiB on the board{}",
            f.ram,
            f.ram as f64 / 1024.0,
            f.emulated_flash,
            f.ccm,
            f.ccm as f64 / 1024.0,
            (128 * 1024 - f.board_ram() as i64) as f64 / 1024.0,
            if f.emulated_flash > 0 {
                format!(
                    ", {:.1} KiB on QEMU",
                    (128 * 1024 - f.ram as i64) as f64 / 1024.0
                )
            } else {
                String::new()
            }
        );
    }
    if !over.is_empty() {
        bail!("over budget: {}", over.join("; "));
    }
    Ok(())
}

/// A budget: what it covers, which output lines give its figures, its
/// instructions.
type Budget = (&'static str, fn(&str) -> bool, u32);

/// The figures in the benchmark's output that pass their budget (named, with
/// the budget); an error if one the budgets cover is missing. Prints each
/// budget's worst figure and its margin.
fn over_budget(out: &str) -> Result<Vec<String>> {
    let figure =
        |line: &str| -> Option<u32> { line.split(": ").nth(1)?.split(' ').next()?.parse().ok() };
    let mut over = Vec::new();
    let budgets: [Budget; 3] = [
        (
            "the worst control tick",
            |l| {
                l.starts_with("isr_tick")
                    && l.contains("_instructions")
                    && !l.starts_with("isr_tick_three_axes")
            },
            TICK_BUDGET,
        ),
        (
            THREE_AXES,
            |l| l.starts_with("isr_tick_three_axes_instructions"),
            THREE_AXES_BUDGET,
        ),
        (
            "the n = 10 step",
            |l| {
                (l.starts_with("control_step_instructions")
                    || l.starts_with("runtime_model_step_instructions"))
                    && l.contains(" n=10")
            },
            STEP_BUDGET,
        ),
    ];
    for (what, matches, budget) in budgets {
        let mut worst: Option<(u32, &str)> = None;
        for line in out.lines().filter(|l| matches(l)) {
            let Some(n) = figure(line) else {
                bail!("cannot read the figure in `{line}`");
            };
            let name = line.split(':').next().unwrap_or(line);
            if worst.is_none_or(|(w, _)| n > w) {
                worst = Some((n, name));
            }
            if n > budget {
                over.push(format!("{name} = {n} > {budget}"));
            }
        }
        let Some((n, name)) = worst else {
            bail!("the benchmark printed no figure for {what}");
        };
        println!(
            "budget: {what}: {n} of {budget} instructions ({name}; margin {})",
            budget as i64 - n as i64
        );
        if what == THREE_AXES {
            let verdict = if n <= THREE_AXES_TARGET {
                "met"
            } else {
                "MISSED"
            };
            println!(
                "target: {what}: {n} of {THREE_AXES_TARGET} instructions: {verdict} (by {})",
                (i64::from(THREE_AXES_TARGET) - i64::from(n)).abs()
            );
        }
    }
    Ok(over)
}

/// The three-axis tick's budget and target name it so.
const THREE_AXES: &str = "the worst three-axis control tick";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_figure_over_its_budget_is_named_and_a_missing_one_refused() {
        let out = "control_step_instructions n=10: 290\n\
                   runtime_model_step_instructions n=10 creep=0: 301\n\
                   isr_tick_instructions n=9: 1080 (open)\n\
                   isr_tick_closed_loop_stepping_instructions n=9: 1701 (stepping)\n\
                   isr_tick_three_axes_instructions n=9: 6001 (three)\n";
        let over = over_budget(out).expect("every figure present");
        assert_eq!(
            over,
            [
                "isr_tick_closed_loop_stepping_instructions n=9 = 1701 > 1700",
                "isr_tick_three_axes_instructions n=9 = 6001 > 6000",
                "runtime_model_step_instructions n=10 creep=0 = 301 > 300",
            ]
        );
        assert!(over_budget("control_step_instructions n=10: 290\n").is_err());
    }
}
