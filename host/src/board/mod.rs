//! Building the firmware for the Cortex-M4 and running it on the emulated board.
//!
//! Used by `cargo demo`, `cargo isr-bench` and the QEMU integration test. It
//! installs the rustup target if it is missing and asks, with the command to run,
//! for `qemu-system-arm` if that is missing. QEMU always runs under a timeout.

pub mod accuracy;
pub mod autotune;
pub mod axes;
pub mod bandwidth;
pub mod budget;
pub mod client;
pub mod closed_loop;
pub mod commands;
pub mod decoupling;
pub mod emulator;
pub mod fanout;
pub mod follow;
pub mod frf;
pub mod hub;
pub mod info;
pub mod inprocess;
pub mod live;
pub mod mass;
pub mod motion;
pub mod noise;
pub mod port;
pub mod protocol_page;
pub mod raster;
pub mod recording;
pub mod restore;
pub mod session;
pub mod settings;
pub mod step;
pub mod trial;
pub mod trigger;
pub mod twin;
pub mod variant;
pub mod warm;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use object::{Object, ObjectSection, SectionFlags};

/// The firmware's target triple.
pub const TARGET: &str = "thumbv7em-none-eabihf";

/// The emulated STM32F405 board.
pub const QEMU_MACHINE: &str = "netduinoplus2";

/// Virtual time of the benchmark: 2^10 ns per instruction, so SysTick differences
/// are exact instruction counts.
pub const ICOUNT_BENCH: &str = "shift=10,align=off,sleep=off";

pub use crate::data::project_root;

/// The cargo that runs us (`$CARGO`), else `cargo` from the path.
pub fn cargo() -> String {
    std::env::var("CARGO").unwrap_or_else(|_| "cargo".into())
}

/// Where cargo writes the project's builds: `$CARGO_TARGET_DIR`, else
/// `target/` under the project's root.
pub fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| project_root().join("target"))
}

/// Makes sure the Cortex-M target's standard library is installed (installing it
/// with `rustup target add` if needed).
pub fn ensure_target() -> Result<()> {
    let out = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output();
    match out {
        Ok(o)
            if String::from_utf8_lossy(&o.stdout)
                .lines()
                .any(|l| l.trim() == TARGET) =>
        {
            Ok(())
        }
        Ok(_) => {
            eprintln!("installing the Cortex-M4F target: rustup target add {TARGET}");
            let st = Command::new("rustup")
                .args(["target", "add", TARGET])
                .status()
                .context("running rustup")?;
            if !st.success() {
                bail!("`rustup target add {TARGET}` failed; run it by hand and retry");
            }
            Ok(())
        }
        Err(_) => bail!(
            "rustup was not found; install the {TARGET} standard library for your toolchain \
             (with rustup: `rustup target add {TARGET}`)"
        ),
    }
}

/// The `qemu-system-arm` to use (`$QEMU_SYSTEM_ARM` or the one on `PATH`), or a
/// clear request to install it.
pub fn qemu() -> Result<PathBuf> {
    if let Ok(p) = std::env::var("QEMU_SYSTEM_ARM") {
        let p = PathBuf::from(p);
        if !p.is_file() {
            bail!(
                "qemu-system-arm was not found: QEMU_SYSTEM_ARM names {}, which is not a file",
                p.display()
            );
        }
        return Ok(p);
    }
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join("qemu-system-arm"))
            .find(|p| p.is_file())
    });
    found.ok_or_else(|| {
        anyhow!(
            "qemu-system-arm was not found. It emulates the STM32F405 board. Install it, e.g.\n  \
             sudo apt-get install qemu-system-arm        (Debian, Ubuntu)\n  \
             sudo dnf install qemu-system-arm            (Fedora)\n  \
             brew install qemu                           (macOS)\n\
             then run the command again."
        )
    })
}

/// The Cargo profile of the firmware (`[profile.firmware]` in the workspace's
/// Cargo.toml: fat LTO, one codegen unit), also the folder of its ELFs under
/// `target/thumbv7em-none-eabihf/`. The host tools' `release` profile is cheaper.
pub const PROFILE: &str = "firmware";

/// Builds a firmware binary with the firmware's profile ([`PROFILE`]) for the
/// target and returns a copy of its ELF named after the feature set
/// (`fpi-firmware-qemu.elf`): cargo writes every feature set of a binary to the
/// same path, so callers in parallel (tests) would otherwise run each other's
/// builds. Builds within one process are serialised.
pub fn build(bin: &str, features: &str) -> Result<PathBuf> {
    static BUILD: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = BUILD.lock().unwrap_or_else(|p| p.into_inner());
    let root = project_root();
    if !root.join("firmware").join("Cargo.toml").is_file() {
        bail!(
            "the firmware's source tree is not at {} (where these tools were built from): \
             give the emulated board's firmware ELF instead (`fpi board emulate --firmware`, \
             Python's `Emulator(firmware=...)`)",
            root.display()
        );
    }
    ensure_target()?;
    let status = Command::new(cargo())
        .current_dir(&root)
        .args([
            "build",
            "--profile",
            PROFILE,
            "--target",
            TARGET,
            "-p",
            "fpi-firmware",
            "--bin",
            bin,
            "--features",
            features,
        ])
        .status()
        .context("running cargo build for the firmware")?;
    if !status.success() {
        bail!("building `{bin}` (features {features}) for {TARGET} failed");
    }
    let elf = target_dir().join(TARGET).join(PROFILE).join(bin);
    if !elf.is_file() {
        bail!(
            "the build reported success but {} is missing",
            elf.display()
        );
    }
    Ok(elf)
}

/// QEMU's command line for an ELF on the emulated board: the machine, no monitor,
/// semihosting (the firmware's output) and the `-icount` setting; the caller adds
/// the display and serial options.
pub fn qemu_command(qemu: &Path, elf: &Path, icount: &str) -> Command {
    let mut c = Command::new(qemu);
    c.args(["-machine", QEMU_MACHINE, "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-icount", icount, "-kernel"])
        .arg(elf);
    c
}

/// What a QEMU run printed and how it ended.
#[derive(Debug, Clone)]
pub struct QemuRun {
    /// Everything the firmware printed (semihosting stdout).
    pub stdout: String,
    /// QEMU's exit code (semihosting exit: 0 success, 1 failure).
    pub code: Option<i32>,
    /// Wall-clock time of the run.
    pub elapsed: Duration,
}

/// Runs an ELF on the emulated board with the given `-icount` setting, echoing its
/// output live if `echo`; kills QEMU after `timeout`.
pub fn run(elf: &Path, icount: &str, timeout: Duration, echo: bool) -> Result<QemuRun> {
    let qemu = qemu()?;
    let start = Instant::now();
    let mut child = qemu_command(&qemu, elf, icount)
        .args(["-nographic", "-serial", "null"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("starting {}", qemu.display()))?;
    let stdout = child.stdout.take().context("qemu stdout")?;
    let mut stderr = child.stderr.take().context("qemu stderr")?;
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stdout).lines().map_while(|l| l.ok()) {
            if echo {
                println!("{line}");
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let code = loop {
        if let Some(st) = child.try_wait()? {
            break st.code();
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            bail!(
                "QEMU did not finish within {} s ({}); killed",
                timeout.as_secs(),
                elf.display()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = reader.join().map_err(|_| anyhow!("reading QEMU output"))?;
    let mut err = String::new();
    let _ = stderr.read_to_string(&mut err);
    if !err.trim().is_empty() && code != Some(0) {
        eprintln!("{}", err.trim());
    }
    Ok(QemuRun {
        stdout: out,
        code,
        elapsed: start.elapsed(),
    })
}

/// Flash and static RAM of a firmware ELF, bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Footprint {
    /// Code, constants, vector table and the initial image of `.data`.
    pub flash: u64,
    /// SRAM: `.data`, `.bss`, `.uninit` and the emulated board's
    /// `.emulated_flash` (the stack is extra).
    pub ram: u64,
    /// Of `ram`, the emulated board's stand-in for the model's flash (none on
    /// the board).
    pub emulated_flash: u64,
    /// The CCM's `.ccm` (the model stores and the image buffer; of 64 KiB).
    pub ccm: u64,
}

impl Footprint {
    /// The SRAM the program would take on the board: without the emulated
    /// board's stand-in for the flash.
    pub const fn board_ram(&self) -> u64 {
        self.ram - self.emulated_flash
    }
}

/// Reads the allocated sections of an ELF (flash at 0x0800_0000, SRAM at
/// 0x2000_0000, the CCM's `.ccm` wherever it lies).
pub fn footprint(elf: &Path) -> Result<Footprint> {
    let data = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*data).with_context(|| format!("parsing {}", elf.display()))?;
    let mut f = Footprint {
        flash: 0,
        ram: 0,
        emulated_flash: 0,
        ccm: 0,
    };
    for s in file.sections() {
        let alloc = matches!(
            s.flags(),
            SectionFlags::Elf { sh_flags, .. } if sh_flags.0 & object::elf::SHF_ALLOC.0 != 0
        );
        if !alloc || s.size() == 0 {
            continue;
        }
        let a = s.address();
        let name = s.name().unwrap_or("");
        if name == ".ccm" {
            f.ccm += s.size();
        } else if (0x0800_0000..0x0810_0000).contains(&a) {
            f.flash += s.size();
        } else if (0x2000_0000..0x2003_0000).contains(&a) {
            f.ram += s.size();
            match name {
                // its initial values are copied from flash
                ".data" => f.flash += s.size(),
                ".emulated_flash" => f.emulated_flash += s.size(),
                _ => {}
            }
        }
    }
    Ok(f)
}
