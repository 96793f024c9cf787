//! The `fpi board` commands as a new user tried them (issue 22), each defect as
//! it was found and what the command says now:
//!
//! * on the in-process board (`--port virtual`, no QEMU): the state it starts in;
//!   `load` of a file that is no model, of another format version, or of tables
//!   that break the model's assumptions; options out of range named with the value
//!   given; `--port` and `--listen` that are no `HOST:PORT`;
//! * on the emulated board (QEMU): a stream ends the supervision it switched on;
//!   a command the board faulted on fails with the fault; Ctrl-C during `record`
//!   keeps what was recorded; a busy port is named busy, with who holds it;
//! * without QEMU, the emulated tests' `SKIPPED` notice is in the default output.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use fpi_host::board::emulator::{self, Emulator};
use piezo_sim::file::FirmwareModel;

mod common;
use common::{fails, ok, refused, s};

fn tmp() -> PathBuf {
    common::scratch("board-commands")
}

const FEM: &str = "data/stage-a/fem.csv.gz";

/// The factory model's file, changed by `change`, written to `dir/name`.
fn firmware_file(dir: &Path, name: &str, change: impl Fn(&mut FirmwareModel)) -> PathBuf {
    let path = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut m = FirmwareModel::parse(&text, "stage-a.toml").unwrap();
    change(&mut m);
    let out = dir.join(name);
    std::fs::write(&out, m.to_toml().unwrap()).unwrap();
    out
}

/// `fpi board --port PORT ARGS…`.
fn board<'a>(port: &'a str, args: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["board", "--port", port];
    a.extend_from_slice(args);
    a
}

/// It reported "running, uncompensated drive", force 0 N before its first tick,
/// while its recording said parked.
#[test]
fn the_virtual_board_reports_the_state_it_starts_in() {
    let out = ok(&board("virtual", &["status"]));
    assert!(out.contains("state: parked"), "{out}");
    assert!(out.contains("compensated drive (inverse FPI)"), "{out}");
    assert!(
        !out.contains("force 0.00 N") && !out.contains("state: running"),
        "{out}"
    );
}

/// `load` said "is a calibrated model: give the stage's FEM tables with --fem"
/// of an FEM table, of a TOML with only `hello = 1`, and of a firmware model of
/// format version 99; and it loaded a firmware model whose f_F falls or whose f_K
/// is constant (exit 0; the board then faulted on the first move).
#[test]
fn load_says_what_a_file_is_and_why_it_is_refused() {
    let d = tmp();
    refused(
        &board("virtual", &["load", FEM]),
        &[
            "fem.csv.gz: a CSV table",
            "not a model",
            "an FEM table goes with --fem",
        ],
    );
    let hello = d.join("hello.toml");
    std::fs::write(&hello, "hello = 1\n").unwrap();
    refused(
        &board("virtual", &["load", s(&hello)]),
        &["hello.toml: no `format` key, so not a model file"],
    );
    let v99 = firmware_file(&d, "v99.toml", |m| {
        m.format = "piezo-fpi-firmware/99".into()
    });
    refused(
        &board("virtual", &["load", s(&v99)]),
        &["format = \"piezo-fpi-firmware/99\": a version these tools do not read"],
    );
    let falling = firmware_file(&d, "falling.toml", |m| {
        let v = &mut m.tables.f_f.values;
        let first = v[0];
        for (k, x) in v.iter_mut().enumerate() {
            *x = first - 0.125 * k as f64;
        }
    });
    refused(
        &board("virtual", &["load", s(&falling)]),
        &["tables.f_f.values[1] = 61.675: the preload falls as the stack extends"],
    );
    let constant = firmware_file(&d, "constant.toml", |m| {
        m.tables.f_k.values.iter_mut().for_each(|x| *x = 20.0)
    });
    refused(
        &board("virtual", &["load", s(&constant)]),
        &[
            "tables.f_k.values[1] = 20: the stage output does not rise",
            "no inverse",
        ],
    );
}

/// `wave --freq-hz 1e30` answered with a clamped 4294967295 mHz and no word of
/// which field; `move --speed 1e-30` with "speed 0.000 µm/s"; `tune --limit-um 0`
/// with "not finite or does not fit its Q format"; `--port tcp:…:99999` retried
/// for 10 s; `bench --analog-v -1` was "unexpected argument '-1'".
#[test]
fn options_out_of_range_are_named_with_the_value_given() {
    let wave = [
        "wave",
        "--amplitude-um",
        "5",
        "--offset-um",
        "20",
        "--freq-hz",
        "1e30",
    ];
    refused(
        &board("virtual", &wave),
        &["--freq-hz 1e30: at or above half the board's control rate (10000 Hz)"],
    );
    refused(
        &board("virtual", &["move", "20", "--speed", "1e-30"]),
        &["--speed 1e-30 µm/s: below the link's resolution"],
    );
    refused(
        &board("virtual", &["bench", "--analog-v", "-1"]),
        &["--analog-v -1: the input spans 0–3.3 V"],
    );
    let fw = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let out = tmp().join("tuned.toml");
    refused(
        &[
            "tune",
            "--firmware",
            s(&fw),
            "--limit-um",
            "0",
            "--out",
            s(&out),
        ],
        &["--limit-um", "0 µm: must be > 0 µm"],
    );
    let start = Instant::now();
    refused(
        &board("tcp:127.0.0.1:99999", &["status"]),
        &["--port \"tcp:127.0.0.1:99999\": port \"99999\" is not a TCP port (1–65535)"],
    );
    assert!(start.elapsed() < Duration::from_secs(2), "refused at once");
}

/// `--listen "127.0.0.1:P,logfile=/tmp/x"` reached QEMU's options: it created the
/// log file and advertised the injected option.
#[test]
fn listen_is_host_and_port_and_nothing_else() {
    let log = tmp().join("injected.log");
    let listen = format!("127.0.0.1:45999,logfile={}", log.display());
    refused(
        &["board", "emulate", "--listen", &listen],
        &["--listen", "is not a TCP port"],
    );
    assert!(
        !log.exists(),
        "QEMU was not started with the injected option"
    );
    refused(
        &["board", "emulate", "--listen", "host name:4545"],
        &["--listen", "not HOST:PORT"],
    );
}

/// Runs `fpi` with `args` until `stop` after starting it, then sends it SIGINT
/// (Ctrl-C); its exit code, stdout and stderr.
#[cfg(unix)]
fn interrupted(args: &[&str], stop: Duration) -> (Option<i32>, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fpi"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(stop);
    // SAFETY: sends a signal to a child process of ours that has not been waited for.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGINT);
    }
    let (mut out, mut err) = (String::new(), String::new());
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (child.wait().unwrap().code(), out, err)
}

/// On the emulated board, as a user with `F=fpi` and one board across commands:
/// a stream left the 500 ms supervision on (the board latched "host link lost"
/// half a second later, and again after each move until `supervise 0`); `move`
/// printed "moving to …" and exited 0 while the board faulted in that tick;
/// Ctrl-C during `record` exited 130 with no message and no CSV, the recorder
/// left running; a second, silent client blocked every other one, which got only
/// "no reply within 0.8 s".
#[test]
fn a_session_on_the_emulated_board() {
    if !emulator::available_for("a_session_on_the_emulated_board") {
        return;
    }
    let e = Emulator::start(None).unwrap_or_else(|e| panic!("{e:#}"));
    let port = e.port().to_string();
    let run = |args: &[&str]| ok(&board(&port, args));
    let d = tmp();
    // A stream ends the supervision it switched on.
    run(&["move", "10"]);
    let points = d.join("points.csv");
    let mut csv = String::from("x_ref_um\n");
    for k in 0..400 {
        csv.push_str(&format!("{}\n", 10.0 + 5.0 * (k as f64 / 50.0).sin()));
    }
    std::fs::write(&points, csv).unwrap();
    run(&["stream", s(&points)]);
    let status = run(&["status"]);
    assert!(status.contains("host supervision off"), "{status}");
    let tick = |status: &str| -> u32 {
        let t = status
            .split("tick ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap();
        t.parse().unwrap()
    };
    let until = tick(&status) + 12_000; // 600 ms of board time
    let status = loop {
        let st = run(&["status"]);
        if tick(&st) > until {
            break st;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(!status.contains("FAULT"), "{status}");
    // Supervision the user set stays set.
    run(&["supervise", "3000"]);
    run(&["stream", s(&points)]);
    assert!(run(&["status"]).contains("host supervision 3000 ms"));
    run(&["supervise", "0"]);
    // A command the board took and faulted on says so.
    run(&["safe"]);
    run(&["bench", "--sensor", "open"]);
    let err = fails(&board(&port, &["move", "10"]));
    assert!(
        err.contains("the board took Move and faulted at tick")
            && err.contains("force reading outside the sensor range"),
        "{err}"
    );
    run(&["bench", "--sensor", "ok"]);
    run(&["clear-fault"]);
    run(&["move", "10"]);
    // Ctrl-C keeps what was recorded.
    #[cfg(unix)]
    {
        let rec = d.join("interrupted.csv");
        let args = board(
            &port,
            &[
                "record",
                "--seconds",
                "3600",
                "--decimation",
                "20",
                "--out",
                s(&rec),
            ],
        );
        let (code, _, err) = interrupted(&args, Duration::from_secs(4));
        assert_eq!(code, Some(130), "{err}");
        assert!(
            err.contains("interrupted:") && err.contains("written to"),
            "{err}"
        );
        let run_file = fpi_host::data::read_stage(&rec).unwrap_or_else(|e| panic!("{e}"));
        assert!(run_file.t.len() > 10, "{} samples", run_file.t.len());
        let status = run(&["status"]);
        assert!(
            status.contains("recorder: idle") && !status.contains("FAULT"),
            "{status}"
        );
    }
    // A busy port is named busy, with who holds it.
    let silent = std::net::TcpStream::connect(port.trim_start_matches("tcp:")).unwrap();
    let err = fails(&board(&port, &["status"]));
    assert!(err.contains("the port is busy"), "{err}");
    assert!(
        err.contains(&format!("(pid {})", std::process::id())),
        "{err}"
    );
    drop(silent);
}

/// The emulated tests' notice when QEMU is missing reaches the terminal in plain
/// `cargo test`, past the harness's capture: this runs the emulated test above
/// with QEMU made unavailable and without `--nocapture`.
#[test]
fn the_skip_notice_is_seen_without_nocapture() {
    let exe = std::env::current_exe().unwrap();
    let o = Command::new(exe)
        .args([
            "--exact",
            "a_session_on_the_emulated_board",
            "--test-threads",
            "1",
        ])
        .env("QEMU_SYSTEM_ARM", "/nonexistent/qemu-system-arm")
        .env_remove("CI")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("!!!!! SKIPPED a_session_on_the_emulated_board: it needs the emulated board"),
        "stderr:\n{err}\nstdout:\n{}",
        String::from_utf8_lossy(&o.stdout)
    );
}
