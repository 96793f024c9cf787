//! The harness: the core run under `std` against the recorded datasets and the
//! board driven end to end, through the host tools (`fpi-host`, in `host/`) and
//! their `fpi` binary.
//!
//! * `tests/` — the tests: the method on the datasets, the fixed-point core
//!   against its f64 reference, the `fpi` commands, the firmware on the emulated
//!   board, the book's links, the Python package.
//! * `data/` — the project's copies of the recorded datasets (their provenance
//!   in `data/README.md`); the host tools read them from here too
//!   ([`fpi_host::data::data_dir`]).
//! * `fuzz/` — coverage-guided fuzzing of the readers and the link (a workspace
//!   of its own).
//!
//! This library holds what the test files share beyond `tests/common`: where the
//! harness is ([`dir`]), the `fpi` binary they run ([`fpi_bin`]), the board
//! the emulated-board tests drive ([`usb_board`]), the board the
//! behaviour's tests drive ([`behaviour_board`]), and the model
//! autotune tuned on the emulated board, shared between the test binaries of one
//! run ([`keep_tuned`], [`kept_tuned`]).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The harness's folder (`tests-host/`): the `fpi` commands of the tests run
/// here, so the datasets are `data/…`.
pub fn dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The `fpi` binary (package `fpi-host`), built once per test process with the
/// profile of the test itself: `release` when the test is built with
/// optimisations (no debug assertions: `cargo test --release`), else `dev`.
/// Cargo sets `CARGO_BIN_EXE_fpi` only for the binaries of a test's own package,
/// and `fpi` lives in `host/`; the build is the same as the firmware's for the
/// emulated board (`fpi_host::board::build`): cargo from the project's root,
/// into `CARGO_TARGET_DIR` or `target/`. Panics if the build fails.
pub fn fpi_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        let root = fpi_host::data::project_root();
        let release = !cfg!(debug_assertions);
        let mut build = Command::new(fpi_host::board::cargo());
        build
            .current_dir(&root)
            // Not `-p fpi-host`: the workspace's default members resolve the
            // crates' features as `cargo test` does, so this build reuses the
            // crates it compiled and only links `fpi` (with `-p` the features
            // differ and most of the host tools were compiled again).
            .args(["build", "--bin", "fpi"]);
        if release {
            build.arg("--release");
        }
        let status = build.status().expect("running cargo build for fpi");
        assert!(status.success(), "building the fpi binary failed");
        let bin = fpi_host::board::target_dir()
            .join(if release { "release" } else { "debug" })
            .join(format!("fpi{}", std::env::consts::EXE_SUFFIX));
        assert!(
            bin.is_file(),
            "the build reported success but {} is missing",
            bin.display()
        );
        bin
    })
}

/// The factory model (`firmware/model/stage-a.toml`: stage A, no loops), as
/// the board's build reads it. Panics if it does not parse.
pub fn factory_model() -> fpi_host::model_file::FirmwareModel {
    let path = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    fpi_host::model_file::FirmwareModel::parse(&text, "stage-a.toml")
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Where the model that `fpi board autotune` tuned (its defaults, the factory
/// model, the emulated stage as built) is kept for the other test binaries of
/// the same `cargo test` run: keyed by the emulated firmware's image and the
/// `cargo test` process (the test binaries' parent), so another run, or
/// another firmware, never reads it.
fn tuned_path() -> Option<PathBuf> {
    use std::hash::{Hash, Hasher};
    let elf = fpi_host::board::emulator::Emulator::firmware().ok()?;
    let mut h = std::hash::DefaultHasher::new();
    std::fs::read(&elf).ok()?.hash(&mut h);
    #[cfg(unix)]
    std::os::unix::process::parent_id().hash(&mut h);
    let dir = fpi_host::board::target_dir().join("tmp");
    std::fs::create_dir_all(&dir).ok()?;
    Some(dir.join(format!("tuned-{:016x}.toml", h.finish())))
}

/// Keeps the tuned model `m` for the other test binaries of this run
/// ([`kept_tuned`]; `tests/autotune.rs` tunes, `tests/governor.rs` reads: one
/// autotune on the emulated board instead of two).
pub fn keep_tuned(m: &fpi_host::model_file::FirmwareModel) {
    if let (Some(path), Ok(text)) = (tuned_path(), m.to_toml()) {
        let _ = fpi_host::output::write_atomic(&path, text.as_bytes());
    }
}

/// The tuned model another test binary of this run kept ([`keep_tuned`]).
pub fn kept_tuned() -> Option<fpi_host::model_file::FirmwareModel> {
    let path = tuned_path()?;
    let text = std::fs::read_to_string(&path).ok()?;
    fpi_host::model_file::FirmwareModel::parse(&text, &path.display().to_string()).ok()
}

/// The board for the tests of the control task's behaviour (autotune, the
/// loops, the watch, the governor's property): the firmware built for the host,
/// in-process, its link paced as USB, said so on stdout. It is the same control
/// task, virtual bench and fixed-point arithmetic as the emulated board's, at
/// the board's real-time pace, at a quarter of QEMU's wall time (QEMU runs the
/// 168 MHz core slower than real time on 2 cores). What only the Cortex-M build
/// has (its link over the USART, the timer interrupt, its memory) is the
/// emulated board's tests' ([`usb_board`]). `FPI_TESTS_BOARD=emulated` runs
/// them on the emulated board instead (the figures the book gives for QEMU).
pub fn behaviour_board(
    test: &str,
) -> (
    Option<fpi_host::board::emulator::Emulator>,
    fpi_host::board::client::Client,
) {
    if std::env::var("FPI_TESTS_BOARD").is_ok_and(|v| v == "emulated") {
        return usb_board(test);
    }
    println!("{test}: on the firmware built for the host (in-process)");
    (
        None,
        fpi_host::board::client::Client::open("virtual:usb")
            .unwrap_or_else(|e| panic!("{test}: the in-process board: {e:#}")),
    )
}

/// A board for the test `test`: the emulated one (QEMU) with its link paced as
/// USB (recordings of every tick), else the firmware built for the host,
/// in-process, said so on stdout. The emulator stops when its handle drops.
pub fn usb_board(
    test: &str,
) -> (
    Option<fpi_host::board::emulator::Emulator>,
    fpi_host::board::client::Client,
) {
    use fpi_host::board::client::Client;
    use fpi_host::board::emulator::{self, Emulator};
    if emulator::available_for(test) {
        let elf = Emulator::firmware().unwrap_or_else(|e| panic!("{e:#}"));
        let e = Emulator::start_elf(&elf, None).unwrap_or_else(|e| panic!("{e:#}"));
        let mut c = Client::open(e.port()).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
        c.pace_as(fpi_protocol::LinkKind::Usb)
            .unwrap_or_else(|err| panic!("{err:#}"));
        (Some(e), c)
    } else {
        println!("{test}: on the firmware built for the host (in-process)");
        (
            None,
            Client::open("virtual:usb").unwrap_or_else(|e| panic!("{e:#}")),
        )
    }
}
