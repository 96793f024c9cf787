//! The Python package (`python/`, module `piezo_fpi`) as part of `cargo test`:
//! builds it with `pip install` into a virtual environment under the target
//! folder (with the `dev` profile, so it shares this build's compiled crates),
//! and runs its pytest tests (`python/tests`): the package against the
//! in-process board and the emulated board, the method against this `fpi`
//! (`FPI_BIN`) on the shared datasets, every error path, and an example.
//!
//! Without `python3` (or its `pip` and `venv`), or without maturin, pytest and
//! numpy where pip cannot install them, it prints a loud `SKIPPED` notice past
//! the test harness's capture and passes; under CI (`CI=true`) that is a
//! failure, as CI must run them. `.ci/run` installs what it needs.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use fpi_host::board::emulator::under_ci;
use fpi_host::data::project_root;

/// The Python to build with: `$PYTHON`, else `python3`.
fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

/// A notice past the harness's capture, or a failure under CI.
fn skip(why: &str) {
    if under_ci() {
        panic!("CI must run the Python package's tests: {why}");
    }
    let notice = format!(
        "\n!!!!! SKIPPED the Python package's tests (python/tests): {why}\n\
         !!!!! (install python3 with pip and venv; under CI=true this is a failure)\n"
    );
    let _ = std::io::stderr().lock().write_all(notice.as_bytes());
}

fn run(cmd: &mut Command) -> std::io::Result<Output> {
    cmd.output()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The virtual environment's Python, the environment made if need be (with the
/// system's packages visible: numpy, pytest, maturin where installed).
fn venv(dir: &Path) -> Result<PathBuf, String> {
    let bin = if cfg!(windows) {
        dir.join("Scripts").join("python.exe")
    } else {
        dir.join("bin").join("python")
    };
    if !bin.is_file() {
        let o = run(Command::new(python())
            .args(["-m", "venv", "--system-site-packages"])
            .arg(dir))
        .map_err(|e| format!("{} not found ({e})", python()))?;
        if !o.status.success() {
            return Err(format!("`{} -m venv` failed:\n{}", python(), text(&o)));
        }
    }
    let has = |b: &Path| {
        run(Command::new(b).args(["-c", "import maturin, pytest, numpy, matplotlib"]))
            .is_ok_and(|o| o.status.success())
    };
    if !has(&bin) {
        let o = run(Command::new(&bin).args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "maturin",
            "pytest",
            "numpy",
            "matplotlib",
        ]))
        .map_err(|e| format!("pip: {e}"))?;
        if !o.status.success() {
            return Err(format!(
                "maturin, pytest, numpy and matplotlib are not installed, and pip could not \
                 install them:\n{}",
                text(&o)
            ));
        }
    }
    Ok(bin)
}

#[test]
fn the_python_package_builds_and_passes_its_tests() {
    let root = project_root();
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("python-venv");
    let py = match venv(&dir) {
        Ok(p) => p,
        Err(why) => return skip(&why),
    };
    let started = std::time::Instant::now();
    let o = run(Command::new(&py)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-build-isolation",
            "--no-deps",
            "--force-reinstall",
        ])
        .arg(root.join("python"))
        .env("MATURIN_PEP517_ARGS", "--profile dev"))
    .expect("running pip");
    assert!(
        o.status.success(),
        "pip install ./python failed:\n{}",
        text(&o)
    );
    let built = started.elapsed().as_secs_f64();
    let o = run(Command::new(&py)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs"])
        .arg(root.join("python").join("tests"))
        .current_dir(root.join("python"))
        .env("FPI_BIN", env!("CARGO_BIN_EXE_fpi"))
        .env("MPLBACKEND", "Agg"))
    .expect("running pytest");
    let out = text(&o);
    let summary = out.lines().last().unwrap_or("").to_string();
    // Past the harness's capture: the summary, and every skip with its reason.
    let skipped: String = out
        .lines()
        .filter(|l| l.starts_with("SKIPPED"))
        .map(|l| format!("!!!!! python/tests: {l}\n"))
        .collect();
    let _ = std::io::stderr().lock().write_all(
        format!("\npython/tests: built in {built:.0} s; pytest: {summary}\n{skipped}").as_bytes(),
    );
    assert!(o.status.success(), "pytest failed:\n{out}");
    assert!(summary.contains(" passed"), "pytest ran no test:\n{out}");
}
