//! The emulated board as a process: QEMU's `netduinoplus2` running the `qemu`
//! firmware, its USART1 bridged to a TCP port, so every host tool that talks to a
//! board talks to it unchanged (`tcp:127.0.0.1:PORT`).
//!
//! Virtual time: `-icount shift=0,sleep=on` — one instruction per nanosecond of
//! board time, and idle time (the firmware waits in `wfi` most of each 50 µs
//! period) kept in step with the host's clock. Board time therefore runs at real
//! time, or slower if the host cannot keep up; it never runs ahead, so the host's
//! heartbeats arrive as often in board time as in real time. Runs are
//! deterministic between two requests (the twin relies on it, see [`super::twin`]).

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{bail, Context, Result};

use super::port::tcp_address;
use super::{build, qemu, qemu_command, PROFILE, TARGET};

/// Where the emulated firmware takes its model flash's content from at start-up
/// (the board's stored-model sector; QEMU's `-device loader` puts a file there).
pub const FLASH_SEED: u32 = 0x080C_0000;

/// A file of the emulated board's model flash holding `images` stored one after
/// the other (generations 1, 2, …), with the images listed in `damage` damaged
/// afterwards (a byte cleared in the middle, as a flash fault would): for starting
/// the emulated board with models in its flash ([`Emulator::start_with_flash`]).
pub fn flash_file(path: &Path, images: &[&[u8]], damage: &[usize]) -> Result<()> {
    use fpi_firmware::board::storage::ModelFlash;
    use fpi_firmware::emulation::virtual_bench::{EmulatedFlash, FLASH_SLOTS};
    let mut flash = Box::new(EmulatedFlash::new());
    let mut f = ModelFlash::new(&mut *flash, FLASH_SLOTS);
    let mut stored = Vec::new();
    for image in images {
        stored.push(f.store(image).map_err(|e| anyhow::anyhow!(e.message()))?);
    }
    for &k in damage {
        if let Some(s) = stored.get(k) {
            f.damage(s, s.len / 2)
                .map_err(|e| anyhow::anyhow!(e.message()))?;
        }
    }
    crate::output::write_atomic(path, f.flash().as_bytes())
}

/// The most axes the emulated board on QEMU drives ([`Emulator::firmware_of`]).
pub const MOST_AXES: u8 = 2;

/// QEMU's virtual clock for the instrument: see the module docs.
pub const ICOUNT_INSTRUMENT: &str = "shift=0,align=off,sleep=on";

/// A running emulated board. Dropping it stops QEMU; so does the end of the
/// process that started it from its main thread, however it ends (on Linux:
/// QEMU gets `SIGKILL` when its parent dies, `PR_SET_PDEATHSIG`), so that no
/// QEMU is left listening on the port of an `fpi board emulate` that was
/// killed.
pub struct Emulator {
    child: Child,
    port: String,
    output: Arc<Mutex<String>>,
    elf: PathBuf,
}

/// How long [`Client::open`](super::client::Client::open) waits for the
/// board's hello, s (five tries of 0.8 s).
pub const HELLO_WAIT_S: f64 = 4.0;

/// Has QEMU, spawned by `cmd`, end with this process: on Linux, where the
/// thread that spawns it is the process's main thread (the parent-death
/// signal follows the spawning thread: one spawned by a test's thread, which
/// ends before its board is dropped elsewhere, is left to `Drop`).
fn ends_with_this_process(cmd: &mut std::process::Command) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: plain system calls; the main thread's id is the process's.
        let main_thread = unsafe { libc::gettid() == libc::getpid() };
        if !main_thread {
            return;
        }
        let parent = std::process::id();
        // SAFETY: the closure runs in the forked child before exec and calls
        // only async-signal-safe functions (prctl, getppid, raise).
        unsafe {
            cmd.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // The parent died before the prctl: the signal will not come.
                if libc::getppid() as u32 != parent {
                    libc::raise(libc::SIGKILL);
                }
                Ok(())
            });
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = cmd;
}

/// Refuses a listening address that another program holds, before QEMU is
/// started on it (QEMU would fail to bind, or the tools would reach the other
/// program's board).
fn port_free(addr: &str) -> Result<()> {
    match TcpListener::bind(addr) {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::AddrInUse => {
            let port = addr
                .rsplit_once(':')
                .and_then(|(_, p)| p.parse().ok())
                .unwrap_or(0);
            let by = super::port::listeners(port);
            bail!(
                "--listen {addr}: the port is busy: another program listens there{} (another \
                 `fpi board emulate`?); stop it or choose another port",
                if by.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", by.join(", "))
                }
            )
        }
        Err(e) => Err(e).with_context(|| format!("--listen {addr}: cannot listen there")),
    }
}

/// A free TCP port on the loopback interface.
fn free_port() -> Result<u16> {
    let l = TcpListener::bind("127.0.0.1:0").context("finding a free TCP port")?;
    Ok(l.local_addr()?.port())
}

impl Emulator {
    /// Builds the emulated firmware and starts it, its link on `listen`
    /// (`HOST:PORT`; a free loopback port if `None`).
    pub fn start(listen: Option<&str>) -> Result<Self> {
        let elf = build("fpi-firmware", "qemu")?;
        Self::start_elf(&elf, listen)
    }

    /// Starts a built emulated firmware.
    pub fn start_elf(elf: &Path, listen: Option<&str>) -> Result<Self> {
        Self::start_with_flash(elf, listen, None)
    }

    /// Starts a built emulated firmware whose model flash holds what `flash` (a
    /// file made by [`flash_file`]) holds: as a real board whose flash kept its
    /// models while it was off.
    pub fn start_with_flash(
        elf: &Path,
        listen: Option<&str>,
        flash: Option<&Path>,
    ) -> Result<Self> {
        if !elf.is_file() {
            bail!(
                "the emulated board's firmware {} is not a file (build it with `cargo build \
                 --profile {PROFILE} --target {TARGET} -p fpi-firmware --bin fpi-firmware \
                 --features qemu` in the project's source tree)",
                elf.display()
            );
        }
        let addr = match listen {
            Some(a) => {
                let (host, port) = tcp_address(a).context("--listen")?;
                if host.contains(':') {
                    format!("[{host}]:{port}")
                } else {
                    format!("{host}:{port}")
                }
            }
            None => format!("127.0.0.1:{}", free_port()?),
        };
        if listen.is_some() {
            port_free(&addr)?;
        }
        let qemu = qemu()?;
        let serial = format!("tcp:{addr},server=on,wait=off,nodelay=on");
        let mut cmd = qemu_command(&qemu, elf, ICOUNT_INSTRUMENT);
        cmd.args(["-display", "none", "-serial", &serial]);
        if let Some(f) = flash {
            let loader = format!(
                "loader,file={},addr={FLASH_SEED:#x},force-raw=on",
                f.display()
            );
            cmd.args(["-device", &loader]);
        }
        ends_with_this_process(&mut cmd);
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", qemu.display()))?;
        let output = Arc::new(Mutex::new(String::new()));
        for pipe in [
            child
                .stdout
                .take()
                .map(|p| Box::new(p) as Box<dyn std::io::Read + Send>),
            child
                .stderr
                .take()
                .map(|p| Box::new(p) as Box<dyn std::io::Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let out = Arc::clone(&output);
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines().map_while(|l| l.ok()) {
                    if let Ok(mut o) = out.lock() {
                        o.push_str(&line);
                        o.push('\n');
                    }
                }
            });
        }
        std::thread::sleep(Duration::from_millis(100));
        let mut e = Self {
            child,
            port: format!("tcp:{addr}"),
            output,
            elf: elf.to_path_buf(),
        };
        if let Some(st) = e.child.try_wait()? {
            bail!("QEMU stopped at once ({st}):\n{}", e.output());
        }
        e.check_alive()?;
        Ok(e)
    }

    /// Has the board pace its link as `link` (it starts paced as the UART).
    pub fn pace_as(&self, link: fpi_protocol::LinkKind) -> Result<()> {
        self.client()?.pace_as(link)
    }

    /// Has the board convert with the `kind` front end (it starts with the
    /// internal one).
    pub fn front_end(&self, kind: fpi_protocol::FrontEndKind) -> Result<()> {
        self.client()?.front_end(kind)
    }

    /// A client of the board; where the firmware does not answer on the link
    /// (QEMU runs, but not the emulated board's firmware), an error that says
    /// so.
    pub fn client(&self) -> Result<super::client::Client> {
        super::client::Client::open(&self.port).map_err(|e| {
            let out = self.output();
            e.context(format!(
                "the emulated board did not answer on its link {} within {HELLO_WAIT_S} s: QEMU \
                 runs {}, which is not the emulated board's firmware, most likely (a wrong \
                 firmware: `fpi-firmware` built with --features qemu is){}",
                self.port,
                self.elf.display(),
                if out.trim().is_empty() {
                    String::new()
                } else {
                    format!("; QEMU said:\n{}", out.trim())
                }
            ))
        })
    }

    /// Runs until QEMU exits or `stop` says so (polled every 50 ms; QEMU is
    /// then stopped): whether `stop` ended it.
    pub fn wait_until(mut self, stop: impl Fn() -> bool) -> Result<bool> {
        loop {
            if let Some(st) = self.child.try_wait()? {
                if stop() {
                    return Ok(true);
                }
                if !st.success() {
                    bail!("QEMU exited with {st}:\n{}", self.output());
                }
                return Ok(false);
            }
            if stop() {
                return Ok(true); // dropping it stops QEMU
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The port to open: `tcp:HOST:PORT`.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// What the firmware and QEMU printed so far.
    pub fn output(&self) -> String {
        self.output.lock().map(|o| o.clone()).unwrap_or_default()
    }

    /// An error if QEMU has stopped.
    pub fn check_alive(&mut self) -> Result<()> {
        if let Some(st) = self.child.try_wait()? {
            bail!("the emulated board stopped ({st}):\n{}", self.output());
        }
        Ok(())
    }

    /// Runs until QEMU exits (or is interrupted).
    pub fn wait(mut self) -> Result<()> {
        let st = self.child.wait()?;
        if !st.success() {
            bail!("QEMU exited with {st}:\n{}", self.output());
        }
        Ok(())
    }

    /// `fpi board emulate`: the emulated board of `axes` axes (its firmware
    /// `elf`, else [`firmware_of`](Self::firmware_of) built), its link on
    /// `listen`, paced as `link`, converting with `front` (a board of several
    /// axes has the internal front end only: another is refused before QEMU
    /// starts).
    pub fn start_board(
        elf: Option<&Path>,
        axes: u8,
        listen: Option<&str>,
        link: fpi_protocol::LinkKind,
        front: fpi_protocol::FrontEndKind,
    ) -> Result<Self> {
        if axes > 1 && front != fpi_protocol::FrontEndKind::Internal {
            bail!(
                "front end {}: the emulated board of several axes has the internal front end only",
                front.name()
            );
        }
        let elf = match elf {
            Some(f) => f.to_path_buf(),
            None => Self::firmware_of(axes)?,
        };
        let e = Self::start_elf(&elf, listen)?;
        e.pace_as(link)?;
        if axes == 1 {
            e.front_end(front)?;
        }
        Ok(e)
    }

    /// The firmware image it runs.
    pub fn firmware() -> Result<PathBuf> {
        Self::firmware_of(1)
    }

    /// The firmware image of the emulated board of `axes` axes (1: stage A,
    /// 2: the XY stage as designed), built if needed. Three axes are
    /// refused: see [`MOST_AXES`].
    pub fn firmware_of(axes: u8) -> Result<PathBuf> {
        match axes {
            1 => build("fpi-firmware", "qemu"),
            2 => build("fpi-firmware-xy", "qemu"),
            3 => bail!(
                "--axes 3: the emulated board of three axes does not fit QEMU's memory: QEMU's \
                 netduinoplus2 maps 192 KiB of SRAM and no CCM, and the RAM that stands in for \
                 the model's flash takes 26 KiB of it, which leaves the program 10 KiB of stack \
                 where it needs more than 14 KiB to start (on the board, without that RAM, it \
                 has 36 KiB); three axes run on the in-process board (--port virtual:xyz)"
            ),
            n => bail!("--axes {n}: 1, 2 or 3"),
        }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Whether the tests that run the emulated board can run: `qemu-system-arm` is
/// installed. Without it, under CI (`CI` set and not `false`/`0`) this panics with
/// how to install it, since CI must run them; elsewhere it prints a loud notice
/// naming `test` and returns `false`, and the test returns early (skipped).
///
/// The notice goes to the process's standard error itself, not through
/// `eprintln!`, which the test harness captures (and shows only for a failed
/// test or with `--nocapture`): plain `cargo test` shows it, so a run without
/// QEMU is not taken for a tested board.
pub fn available_for(test: &str) -> bool {
    let Err(e) = qemu() else {
        return true;
    };
    if under_ci() {
        panic!("{test}: CI must run the emulated board: {e:#}");
    }
    let first = format!("{e:#}");
    let first = first.lines().next().unwrap_or("");
    let notice = format!(
        "\n!!!!! SKIPPED {test}: it needs the emulated board, and {first}\n\
         !!!!! (install qemu-system-arm, or set QEMU_SYSTEM_ARM; under CI=true this is a failure)\n"
    );
    let _ = std::io::stderr().lock().write_all(notice.as_bytes());
    false
}

/// Whether this runs under CI (`CI` set to anything but `false` or `0`).
pub fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false" && v != "0")
}
