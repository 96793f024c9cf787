//! The Python package (`python/`, module `piezo_fpi`) as part of `cargo test`:
//! builds it with `pip install` into a virtual environment of its own under the
//! target folder (with the `dev` profile, so it shares this build's compiled
//! crates), and runs its pytest tests (`python/tests`): the package against the
//! in-process board and the emulated board, the method against this `fpi`
//! (`FPI_BIN`) on the shared datasets, every error path, and an example; then
//! checks the stubs (`piezo_fpi.pyi`) against the built module (mypy's stubtest).
//!
//! It needs only `python3` with its `venv` module (`$PYTHON` names another
//! Python): everything else — the build backend (maturin), numpy, pytest,
//! matplotlib and mypy, as `python/pyproject.toml` lists them — pip installs into the
//! environment from PyPI the first time (later runs find them there, offline).
//! Every tool of the environment runs from its `bin/` (which is put first on
//! `PATH`: the build backend calls `maturin` by name), never from the system's.
//!
//! Without a usable Python, or where pip cannot install what the package needs,
//! it prints a loud `SKIPPED` notice, naming the fix, past the test harness's
//! capture and passes; under CI (`CI=true`) that is a failure, as CI must run
//! them.

use std::ffi::OsString;
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
         !!!!! (under CI=true this is a failure)\n"
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

/// A virtual environment: its folder, its `bin/` (`Scripts\` on Windows) and
/// its Python.
struct Venv {
    dir: PathBuf,
    bin: PathBuf,
    python: PathBuf,
}

impl Venv {
    fn at(dir: &Path) -> Self {
        let bin = if cfg!(windows) {
            dir.join("Scripts")
        } else {
            dir.join("bin")
        };
        let python = bin.join(if cfg!(windows) {
            "python.exe"
        } else {
            "python"
        });
        Venv {
            dir: dir.to_path_buf(),
            bin,
            python,
        }
    }

    /// A command running `program` (a tool of the environment, by name, or any
    /// path) with the environment's `bin/` first on `PATH`, as its activation
    /// script would, so that what the build backend calls by name (`maturin`)
    /// is the environment's.
    fn command(&self, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut paths = vec![self.bin.clone()];
        paths.extend(std::env::split_paths(
            &std::env::var_os("PATH").unwrap_or_default(),
        ));
        let path = std::env::join_paths(paths).unwrap_or_else(|_| OsString::from(&self.bin));
        let mut c = Command::new(program);
        c.env("PATH", path)
            .env("VIRTUAL_ENV", &self.dir)
            .env_remove("PYTHONHOME")
            .env("PIP_DISABLE_PIP_VERSION_CHECK", "1");
        c
    }

    /// Its pip works (a folder left by a `venv` that failed half-way has a
    /// Python but no pip).
    fn usable(&self) -> bool {
        self.python.is_file()
            && run(self.command(&self.python).args(["-m", "pip", "--version"]))
                .is_ok_and(|o| o.status.success())
    }
}

/// How to get a Python whose `venv` module works, for the messages.
const VENV_FIX: &str = "install Python 3.9 or later with its venv module (Debian/Ubuntu: \
    `sudo apt-get install python3-venv`, or python3.X-venv for the python3 in use), or set \
    PYTHON to such a Python";

/// The environment at `dir`, made (again) if it is missing or broken.
fn make_venv(dir: &Path) -> Result<Venv, String> {
    let v = Venv::at(dir);
    if v.usable() {
        return Ok(v);
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .map_err(|e| format!("removing the broken environment {}: {e}", dir.display()))?;
    }
    let o = run(Command::new(python()).args(["-m", "venv"]).arg(dir))
        .map_err(|e| format!("`{}` not found ({e}): {VENV_FIX}", python()))?;
    let out = text(&o);
    if !o.status.success() || !v.usable() {
        let _ = std::fs::remove_dir_all(dir);
        let why = if out.contains("ensurepip") {
            "its venv module has no ensurepip, so the environment has no pip"
        } else {
            "the environment it made has no working pip"
        };
        return Err(format!(
            "`{} -m venv {}` failed ({why}): {VENV_FIX}\n{out}",
            python(),
            dir.display()
        ));
    }
    Ok(v)
}

/// What `python/pyproject.toml` says the package needs to be built and tested:
/// the build system's requirements (maturin), the package's dependencies
/// (numpy) and its `test` extra (pytest, matplotlib, mypy).
fn requirements(pyproject: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(pyproject)
        .unwrap_or_else(|e| panic!("reading {}: {e}", pyproject.display()));
    let doc: toml::Table = text
        .parse()
        .unwrap_or_else(|e| panic!("parsing {}: {e}", pyproject.display()));
    let list = |v: Option<&toml::Value>| -> Vec<String> {
        v.and_then(toml::Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|s| s.as_str().map(str::to_string))
                    .collect()
            })
            .unwrap_or_default()
    };
    let build = doc.get("build-system").and_then(|b| b.get("requires"));
    let project = doc.get("project");
    let deps = project.and_then(|p| p.get("dependencies"));
    let test = project
        .and_then(|p| p.get("optional-dependencies"))
        .and_then(|o| o.get("test"));
    let mut all = list(build);
    all.extend(list(deps));
    all.extend(list(test));
    all
}

/// The environment for the package: made if need be, with what it needs to be
/// built and tested installed (pip leaves what is already there).
fn venv(dir: &Path, pyproject: &Path) -> Result<Venv, String> {
    let v = make_venv(dir)?;
    let needs = requirements(pyproject);
    assert!(
        needs.iter().any(|r| r.starts_with("maturin")),
        "{} names no maturin among its requirements: {needs:?}",
        pyproject.display()
    );
    let o = run(v
        .command(&v.python)
        .args(["-m", "pip", "install", "--quiet"])
        .args(&needs))
    .map_err(|e| format!("running pip: {e}"))?;
    if !o.status.success() {
        return Err(format!(
            "pip could not install {} into the test's environment {} (the first run needs \
             PyPI, or pip configured for a mirror):\n{}",
            needs.join(" "),
            dir.display(),
            text(&o)
        ));
    }
    Ok(v)
}

#[test]
fn the_python_package_builds_and_passes_its_tests() {
    let root = project_root();
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("python-venv");
    let started = std::time::Instant::now();
    let v = match venv(&dir, &root.join("python").join("pyproject.toml")) {
        Ok(v) => v,
        Err(why) => return skip(&why),
    };
    let ready = started.elapsed().as_secs_f64();
    let started = std::time::Instant::now();
    let o = run(v
        .command(&v.python)
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
    let o = run(v
        .command(&v.python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs"])
        .arg(root.join("python").join("tests"))
        .current_dir(root.join("python"))
        .env("FPI_BIN", fpi_tests::fpi_bin())
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
        format!(
            "\npython/tests: environment ready in {ready:.0} s, package built in {built:.0} s; \
             pytest: {summary}\n{skipped}"
        )
        .as_bytes(),
    );
    assert!(o.status.success(), "pytest failed:\n{out}");
    assert!(summary.contains(" passed"), "pytest ran no test:\n{out}");
    // The stubs (`piezo_fpi.pyi`) say what the built module has: every class,
    // method, argument and default (mypy's stubtest).
    let o = run(v
        .command(&v.python)
        .args(["-m", "mypy.stubtest", "piezo_fpi", "--allowlist"])
        .arg(root.join("python").join("stubtest-allowlist.txt"))
        .current_dir(root.join("python")))
    .expect("running stubtest");
    assert!(
        o.status.success(),
        "python/piezo_fpi.pyi differs from the built module (mypy.stubtest):\n{}",
        text(&o)
    );
}

#[test]
fn the_requirements_come_from_pyproject() {
    let needs = requirements(&project_root().join("python").join("pyproject.toml"));
    for name in ["maturin", "numpy", "pytest", "matplotlib", "mypy"] {
        assert!(
            needs.iter().any(|r| r.starts_with(name)),
            "{name} missing from {needs:?}"
        );
    }
}
