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

/// `fpi board info` tells what the board has, as PI's `qHLP`/`HasCMD` do:
/// its axes, front end, link and protocol from its hello, the features its
/// running model gives it (the factory model: open loop, no dynamics, no
/// damping), the commands it takes (the bench's on the emulated board) and
/// the runtime settings it has with that model.
#[test]
fn info_tells_what_the_board_has() {
    let out = ok(&board("virtual", &["info"]));
    let v = fpi_protocol::VERSION;
    assert!(
        out.starts_with(&format!(
            "board: virtual (firmware {}), protocol {v}, axes 1, front end internal, link ",
            env!("CARGO_PKG_VERSION")
        )),
        "{out}"
    );
    assert!(
        out.contains(
            "features: bench; without: closed_loop, dynamics, damping, shaping, mass_ratio"
        ),
        "{out}"
    );
    let commands = &line(&out, "commands: ")["commands: ".len()..];
    assert!(
        commands.contains(" Move ") && commands.contains(" Bench "),
        "{out}"
    );
    assert_eq!(
        commands.split(' ').count(),
        fpi_protocol::CommandKind::ALL.len(),
        "{out}"
    );
    // The factory model has no damping or shaping: their settings are absent.
    assert_eq!(
        line(&out, "settings: "),
        "settings: /stage/0/loop_mode, /stage/0/compensated, /stage/0/trigger/mode, \
         /stage/0/trigger/step_nm, /stage/0/trigger/band_nm, /stage/0/trigger/low_nm, \
         /stage/0/trigger/high_nm, /stage/0/trigger/pulse_ticks, /stage/0/trigger_in, \
         /supervise_ms",
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
    let mut child = Command::new(fpi_tests::fpi_bin())
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

// ---------------------------------------------------------------------------
// The safety issue's items 7, 8, 13 and 15 and the motions' `--record`.

/// An emulated board paced as USB (every tick can be recorded), and its port.
fn usb_board(test: &str) -> Option<(Emulator, String)> {
    if !emulator::available_for(test) {
        return None;
    }
    let e = Emulator::start(None).unwrap_or_else(|e| panic!("{e:#}"));
    e.pace_as(fpi_protocol::LinkKind::Usb)
        .unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    let port = e.port().to_string();
    Some((e, port))
}

/// The line of `status` that starts with `head`.
fn line<'a>(status: &'a str, head: &str) -> &'a str {
    status
        .lines()
        .find(|l| l.starts_with(head))
        .unwrap_or_else(|| panic!("no line {head:?} in:\n{status}"))
}

/// The factory model's file, as `fpi` (run in `tests-host/`) names it.
const FACTORY: &str = "../firmware/model/stage-a.toml";

/// Item 7: `autotune --out /a/file/under/a/file.toml` measured for 47 s,
/// loaded the new model, then failed to write it; `step`, `frf`, `record`
/// and the motions' `--record` likewise checked their output only after the
/// board had worked. Now every output is checked before the board is touched:
/// the command fails at once, naming the option, and the board runs the model
/// it ran, parked as it was.
#[test]
fn outputs_that_cannot_be_written_are_refused_before_the_board_is_touched() {
    let Some((_e, port)) = usb_board("outputs_refused_before_the_board_is_touched") else {
        return;
    };
    let d = tmp().join("outputs");
    std::fs::create_dir_all(&d).unwrap();
    let blocker = d.join("a-file");
    std::fs::write(&blocker, "in the way").unwrap();
    let bad = blocker.join("under-a-file.toml");
    let good = d.join("good.toml");
    let points = d.join("points.csv");
    std::fs::write(&points, "x_ref_um\n10\n11\n").unwrap();
    let before = ok(&board(&port, &["status"]));
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["autotune", FACTORY, "--out", s(&bad)], "--out"),
        (
            vec!["autotune", FACTORY, "--out", s(&good), "--frf-out", s(&bad)],
            "--frf-out",
        ),
        (
            vec!["autotune", FACTORY, "--out", FACTORY],
            "is the input the model",
        ),
        (
            vec!["step", "--from", "10", "--to", "20", "--out", s(&bad)],
            "--out",
        ),
        (vec!["frf", "--out", s(&bad)], "--out"),
        (vec!["record", "--seconds", "1", "--out", s(&bad)], "--out"),
        (vec!["move", "10", "--record", s(&bad)], "--record"),
        (
            vec![
                "wave",
                "--amplitude-um",
                "2",
                "--offset-um",
                "12",
                "--freq-hz",
                "10",
                "--record",
                s(&bad),
                "--seconds",
                "1",
            ],
            "--record",
        ),
        (vec!["stream", s(&points), "--record", s(&bad)], "--record"),
    ];
    for (args, named) in cases {
        let start = Instant::now();
        let err = fails(&board(&port, &args));
        println!("{args:?}: {err}");
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "{args:?} took {:?}",
            start.elapsed()
        );
        assert!(err.contains(named), "{args:?}: {named:?} not in {err}");
        if named != "is the input the model" {
            assert!(
                err.contains("under-a-file.toml") && err.contains("is a file"),
                "{err}"
            );
        }
    }
    assert_eq!(std::fs::read_to_string(&blocker).unwrap(), "in the way");
    assert!(!good.exists(), "no empty file left behind");
    let after = ok(&board(&port, &["status"]));
    assert_eq!(line(&before, "model:"), line(&after, "model:"));
    assert!(after.contains("state: parked"), "{after}");
    assert!(after.contains("recorder: idle"), "{after}");
}

/// Item 7, the write failing anyway at the end (the folder checked at the
/// start replaced by a file while the board is measured): the board does not
/// keep a model nobody has a copy of; it runs the model it ran, parked, and
/// the next `autotune` finds it.
#[test]
fn an_autotune_whose_model_cannot_be_written_puts_the_board_back() {
    let Some((e, port)) = usb_board("autotune_whose_model_cannot_be_written") else {
        return;
    };
    let d = tmp().join("autotune-unwritable");
    let _ = std::fs::remove_dir_all(&d);
    let folder = d.join("models");
    let out = folder.join("tuned.toml");
    // The stage as built (a mode autotune can fit).
    ok(&board(&port, &["bench", "--stage", "built"]));
    let before = ok(&board(&port, &["status"]));
    let args = board(
        &port,
        &["autotune", FACTORY, "--trials", "0", "--out", s(&out)],
    );
    let mut child = Command::new(fpi_tests::fpi_bin())
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        use std::io::BufRead;
        let mut all = String::new();
        for l in std::io::BufReader::new(stderr)
            .lines()
            .map_while(|l| l.ok())
        {
            if l.contains("measuring the frequency response") {
                let _ = tx.send(());
            }
            all.push_str(&l);
            all.push('\n');
        }
        all
    });
    rx.recv_timeout(Duration::from_secs(120))
        .unwrap_or_else(|_| panic!("autotune did not start measuring\n{}", e.output()));
    // The folder it checked is gone, a file in its place.
    assert!(folder.is_dir(), "the check made the folder");
    std::fs::remove_dir_all(&folder).unwrap();
    std::fs::write(&folder, "in the way").unwrap();
    let status = child.wait().unwrap();
    let err = reader.join().unwrap();
    println!("{err}");
    assert!(!status.success(), "{err}");
    assert!(
        err.contains("tuned.toml") && err.contains("is a file"),
        "the write failed: {err}"
    );
    let after = ok(&board(&port, &["status"]));
    // The same model (its CRC), loaded again over the link.
    let crc = |s: &str| line(s, "model:").split(',').next().unwrap().to_string();
    assert_eq!(crc(&before), crc(&after), "{after}");
    assert!(after.contains("state: parked"), "{after}");
    // Byte for byte the model autotune was given (the next autotune finds it).
    let path = fpi_host::data::project_root().join("firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let image = FirmwareModel::parse(&text, "stage-a.toml")
        .unwrap()
        .image()
        .unwrap();
    let mut c = fpi_host::board::client::Client::open(&port).unwrap();
    assert!(
        c.read_model().unwrap() == image,
        "the board runs another model"
    );
}

/// Item 8: an autotune that failed (a latched fault) left the loop open and
/// damping and shaping off. Now the loop mode, the damping and the shaping are
/// as they were (the board parked, the fault still latched: it says why).
#[test]
fn a_failed_autotune_leaves_the_loops_as_they_were() {
    let Some((e, port)) = usb_board("a_failed_autotune_leaves_the_loops") else {
        return;
    };
    let run = |args: &[&str]| ok(&board(&port, args));
    let d = tmp().join("failed-autotune");
    std::fs::create_dir_all(&d).unwrap();
    let dynamics = d.join("dyn.toml");
    ok(&[
        "identify",
        "--chirp",
        "data/stage-a/chirp_small_1Hz-3kHz.csv.gz",
        "--out",
        s(&dynamics),
    ]);
    let tuned = d.join("tuned.toml");
    ok(&[
        "tune",
        "--firmware",
        FACTORY,
        "--dynamics",
        s(&dynamics),
        "--out",
        s(&tuned),
    ]);
    run(&["load", s(&tuned)]);
    run(&["loop", "closed"]);
    run(&["shaping", "off"]);
    run(&["move", "20"]);
    run(&["bench", "--sensor", "open"]);
    let start = Instant::now();
    while !run(&["status"]).contains("FAULT") {
        assert!(start.elapsed() < Duration::from_secs(10), "{}", e.output());
        std::thread::sleep(Duration::from_millis(50));
    }
    run(&["bench", "--sensor", "ok"]);
    let before = run(&["status"]);
    println!("before:\n{before}");
    let loops = line(&before, "damping ");
    assert!(loops.contains("damping on, shaping off"), "{before}");
    let never = d.join("never.toml");
    let err = fails(&board(&port, &["autotune", s(&tuned), "--out", s(&never)]));
    println!("{err}");
    assert!(!never.exists());
    let after = run(&["status"]);
    println!("after:\n{after}");
    assert_eq!(line(&after, "damping "), loops);
    let mode = |s: &str| line(s, "source: ").split(", ").nth(1).unwrap().to_string();
    assert_eq!(mode(&after), mode(&before));
    assert!(mode(&after).starts_with("closed loop"), "{after}");
    assert_eq!(line(&before, "model:"), line(&after, "model:"));
    assert!(after.contains("state: FAULT"), "{after}");
}

/// Runs `fpi` with `args` until `stop` after starting it, then sends it
/// `signal`; its exit code, stdout and stderr.
#[cfg(unix)]
fn signalled(args: &[&str], stop: Duration, signal: i32) -> (Option<i32>, String, String) {
    let child = Command::new(fpi_tests::fpi_bin())
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(stop);
    // SAFETY: sends a signal to a child process of ours that has not been waited for.
    unsafe {
        libc::kill(child.id() as libc::pid_t, signal);
    }
    let o = child.wait_with_output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

/// The rows of a CSV by column: its header and its values.
fn csv_columns(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let mut cols = vec![Vec::new(); head.len()];
    for l in lines {
        for (k, v) in l.split(',').enumerate() {
            cols[k].push(v.parse::<f64>().unwrap());
        }
    }
    (head, cols)
}

/// Item 13: SIGTERM during `record` wrote nothing and left the recorder
/// running. Now it keeps what was recorded, as Ctrl-C does. SIGKILL cannot be
/// caught: the recorder is left running, and the next `record` restarts it
/// afresh (every sample of its own, none of the old run's).
#[cfg(unix)]
#[test]
fn sigterm_during_record_keeps_what_was_recorded_and_sigkill_is_recovered() {
    let Some((_e, port)) = usb_board("sigterm_during_record") else {
        return;
    };
    let run = |args: &[&str]| ok(&board(&port, args));
    let d = tmp().join("sigterm");
    std::fs::create_dir_all(&d).unwrap();
    run(&["move", "10"]);
    let rec = d.join("terminated.csv");
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
    let (code, _, err) = signalled(&args, Duration::from_secs(4), libc::SIGTERM);
    assert_eq!(code, Some(130), "{err}");
    assert!(
        err.contains("interrupted:") && err.contains("written to"),
        "{err}"
    );
    let (_, cols) = csv_columns(&rec);
    assert!(cols[0].len() > 10, "{} samples", cols[0].len());
    assert!(run(&["status"]).contains("recorder: idle"));
    // SIGKILL: nothing written, the recorder left running.
    let killed = d.join("killed.csv");
    let args = board(
        &port,
        &[
            "record",
            "--seconds",
            "3600",
            "--decimation",
            "20",
            "--out",
            s(&killed),
        ],
    );
    let (code, _, _) = signalled(&args, Duration::from_secs(4), libc::SIGKILL);
    assert_eq!(code, None, "killed by the signal");
    assert!(!killed.exists());
    assert!(run(&["status"]).contains("recorder: recording"));
    // The next record restarts it afresh.
    let again = d.join("again.csv");
    run(&[
        "record",
        "--seconds",
        "0.2",
        "--decimation",
        "20",
        "--out",
        s(&again),
    ]);
    let (_, cols) = csv_columns(&again);
    assert_eq!(cols[0].len(), 200, "0.2 s at 1 kHz");
    for w in cols[0].windows(2) {
        assert!((w[1] - w[0] - 0.001).abs() < 1e-7, "{w:?}");
    }
    assert!(run(&["status"]).contains("recorder: idle"));
}

/// Every row of a `--record` CSV: one per tick from the first, consecutive,
/// with a finite true position; the columns of `fpi board record`.
fn every_tick(path: &Path) -> Vec<Vec<f64>> {
    let (head, cols) = csv_columns(path);
    assert_eq!(
        head.join(","),
        "t_s,voltage_V,force_N,x_ref_um,x_est_um,status,x_fhps_um,x_sensor_um"
    );
    let t = &cols[0];
    assert!(t.len() > 100, "{} rows", t.len());
    for w in t.windows(2) {
        assert!(
            (w[1] - w[0] - 5e-5).abs() < 2e-6,
            "ticks not consecutive: {w:?}"
        );
    }
    assert!(cols[6].iter().all(|x| x.is_finite()), "x_fhps_um");
    cols
}

/// Item "every motion can record itself": `move`, `wave` and `stream` with
/// `--record` record every tick of what they do, the true position included,
/// from the tick the board takes the command; a wave without --cycles needs
/// --seconds; a link that cannot carry every tick is refused before anything
/// moves.
#[test]
fn motions_record_every_tick_of_what_they_do() {
    let Some((e, port)) = usb_board("motions_record_every_tick") else {
        return;
    };
    let run = |args: &[&str]| ok(&board(&port, args));
    let d = tmp().join("motions");
    std::fs::create_dir_all(&d).unwrap();
    // A move: from the park to 10 µm, until it holds there, and 50 ms more.
    let m = d.join("move.csv");
    let out = run(&["move", "10", "--speed", "2000", "--record", s(&m)]);
    assert!(out.contains("recorded to"), "{out}");
    let cols = every_tick(&m);
    let x_ref = &cols[3];
    assert!(
        (x_ref.last().unwrap() - 10.0).abs() < 1e-3,
        "{:?}",
        x_ref.last()
    );
    assert!(
        (cols[6].last().unwrap() - 10.0).abs() < 0.5,
        "true position"
    );
    assert!(
        x_ref.len() >= 1000,
        "50 ms at rest at least: {}",
        x_ref.len()
    );
    // A finite wave: its approach, two periods at 40 Hz (50 ms), 50 ms more.
    let w = d.join("wave.csv");
    run(&[
        "wave",
        "--amplitude-um",
        "2",
        "--offset-um",
        "12",
        "--freq-hz",
        "40",
        "--cycles",
        "2",
        "--record",
        s(&w),
    ]);
    let cols = every_tick(&w);
    assert!(cols[0].len() >= 2000, "{} rows", cols[0].len());
    let top = cols[3].iter().cloned().fold(f64::MIN, f64::max);
    assert!((top - 14.0).abs() < 0.01, "the wave's top {top}");
    // A wave until the next command: for --seconds exactly.
    let w2 = d.join("endless.csv");
    run(&[
        "wave",
        "--amplitude-um",
        "2",
        "--offset-um",
        "12",
        "--freq-hz",
        "40",
        "--record",
        s(&w2),
        "--seconds",
        "0.1",
    ]);
    assert_eq!(every_tick(&w2)[0].len(), 2000);
    run(&["hold"]);
    refused(
        &board(
            &port,
            &[
                "wave",
                "--amplitude-um",
                "2",
                "--offset-um",
                "12",
                "--freq-hz",
                "40",
                "--record",
                s(&w2),
            ],
        ),
        &["--seconds", "--cycles 0"],
    );
    // A stream of 150 points, one every 20 ticks: 3 000 ticks and the rest
    // (short: the link has little to spare at every tick while the stage
    // moves, and the board's ring absorbs a loaded host's pauses).
    let points = d.join("points.csv");
    let mut csv = String::from("x_ref_um\n");
    for k in 0..150 {
        csv.push_str(&format!("{}\n", 12.0 + 3.0 * (k as f64 / 50.0).sin()));
    }
    std::fs::write(&points, csv).unwrap();
    let st = d.join("stream.csv");
    run(&["stream", s(&points), "--record", s(&st)]);
    let cols = every_tick(&st);
    assert!(cols[0].len() >= 3000 + 1000, "{} rows", cols[0].len());
    assert!(run(&["status"]).contains("recorder: idle"));
    // The UART cannot carry every tick: refused before the board moves.
    e.pace_as(fpi_protocol::LinkKind::Uart).unwrap();
    let before = run(&["status"]);
    let err = refused(
        &board(&port, &["move", "20", "--record", s(&d.join("uart.csv"))]),
        &["--record", "USB"],
    );
    println!("{err}");
    let after = run(&["status"]);
    assert_eq!(
        line(&before, "tick ")
            .split(", estimate")
            .next()
            .unwrap()
            .split("reference")
            .nth(1),
        line(&after, "tick ")
            .split(", estimate")
            .next()
            .unwrap()
            .split("reference")
            .nth(1),
        "the reference did not move"
    );
}

/// A free TCP port on the loopback interface.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The pids of the processes whose parent is `pid` (Linux, from `/proc`).
#[cfg(target_os = "linux")]
fn children(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for p in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(stat) = std::fs::read_to_string(p.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ppid …: the comm may hold spaces.
        let after = &stat[stat.rfind(')').unwrap_or(0) + 1..];
        let f: Vec<&str> = after.split_whitespace().collect();
        if f.get(1).and_then(|s| s.parse().ok()) == Some(pid) {
            if let Ok(k) = p.file_name().to_string_lossy().parse() {
                out.push(k);
            }
        }
    }
    out
}

/// Whether process `pid` runs (neither gone nor a zombie).
#[cfg(target_os = "linux")]
fn running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => {
            let after = &stat[stat.rfind(')').unwrap_or(0) + 1..];
            !after.trim_start().starts_with('Z')
        }
        Err(_) => false,
    }
}

/// Whether something listens on the loopback port `port`.
fn listening(port: u16) -> bool {
    std::net::TcpStream::connect(("127.0.0.1", port)).is_ok()
}

/// Item 15: `kill -INT` of `fpi board emulate` (its process, not its group)
/// ended `fpi` but left its QEMU running and listening; so did SIGTERM and
/// SIGKILL. Now QEMU ends with `fpi` however `fpi` ends, and the port is free.
#[cfg(target_os = "linux")]
#[test]
fn the_emulator_s_qemu_ends_with_fpi_however_fpi_ends() {
    if !emulator::available_for("the_emulator_s_qemu_ends_with_fpi") {
        return;
    }
    let elf = Emulator::firmware().unwrap_or_else(|e| panic!("{e:#}"));
    for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGKILL] {
        let port = free_port();
        let listen = format!("127.0.0.1:{port}");
        let mut child = Command::new(fpi_tests::fpi_bin())
            .args([
                "board",
                "emulate",
                "--listen",
                &listen,
                "--firmware",
                s(&elf),
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut stdout = child.stdout.take().unwrap();
        let mut first = [0u8; 24];
        stdout.read_exact(&mut first).unwrap();
        assert!(
            String::from_utf8_lossy(&first).starts_with("emulated board running"),
            "{}",
            String::from_utf8_lossy(&first)
        );
        let qemu = children(child.id());
        assert_eq!(qemu.len(), 1, "one QEMU: {qemu:?}");
        let qemu = qemu[0];
        assert!(listening(port) && running(qemu));
        // SAFETY: a signal to our child, not yet waited for.
        unsafe {
            libc::kill(child.id() as libc::pid_t, signal);
        }
        child.wait().unwrap();
        let start = Instant::now();
        while running(qemu) || listening(port) {
            assert!(
                start.elapsed() < Duration::from_secs(5),
                "signal {signal}: QEMU (pid {qemu}) still runs, the port {}",
                if listening(port) { "listening" } else { "free" }
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// Item 14: with a wrong firmware under QEMU, `emulate` said "the port is
/// busy, most likely". Now it says the firmware did not answer on the link;
/// a port another program listens on is named busy, with who holds it; and
/// no QEMU is left behind.
#[test]
fn emulate_tells_a_wrong_firmware_from_a_busy_port() {
    if !emulator::available_for("emulate_tells_a_wrong_firmware_from_a_busy_port") {
        return;
    }
    let d = tmp();
    // A vector table whose reset handler loops for ever (`b .`): QEMU runs it,
    // and nothing answers on the link.
    let bad = d.join("not-the-firmware.bin");
    let mut image = Vec::new();
    image.extend_from_slice(&0x2000_1000u32.to_le_bytes());
    image.extend_from_slice(&0x0000_0009u32.to_le_bytes());
    image.extend_from_slice(&[0xFE, 0xE7]);
    std::fs::write(&bad, image).unwrap();
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let err = fails(&[
        "board",
        "emulate",
        "--listen",
        &listen,
        "--firmware",
        s(&bad),
    ]);
    println!("{err}");
    assert!(
        err.contains("did not answer on its link") && err.contains("not-the-firmware.bin"),
        "{err}"
    );
    assert!(!err.contains("busy"), "{err}");
    assert!(!listening(port), "QEMU stopped with fpi");
    // A port that another program listens on.
    let taken = std::net::TcpListener::bind(("127.0.0.1", 0)).unwrap();
    let listen = format!("127.0.0.1:{}", taken.local_addr().unwrap().port());
    let elf = Emulator::firmware().unwrap_or_else(|e| panic!("{e:#}"));
    let err = fails(&[
        "board",
        "emulate",
        "--listen",
        &listen,
        "--firmware",
        s(&elf),
    ]);
    println!("{err}");
    assert!(err.contains("the port is busy"), "{err}");
    #[cfg(target_os = "linux")]
    assert!(
        err.contains(&format!("(pid {})", std::process::id())),
        "{err}"
    );
}

/// `record` without `--seconds` records until stopped, the CSV written as it
/// comes: Ctrl-C is its normal end (exit 0), every sample on the grid, nothing
/// lost; a decimation the link cannot carry for ever is refused before the
/// recorder starts.
#[test]
fn record_without_seconds_runs_until_stopped() {
    let dir = tmp();
    let out = dir.join("until-stopped.csv");
    let o = out.to_str().unwrap();
    let (code, stdout, stderr) = interrupted(
        &board("virtual:usb", &["record", "--out", o, "--decimation", "20"]),
        Duration::from_secs(3),
    );
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert!(stdout.contains("until stopped"), "{stdout}");
    assert!(stdout.contains("nothing lost"), "{stdout}");
    let (head, cols) = csv_columns(&out);
    assert_eq!(head[0], "t_s");
    assert!(cols[0].len() > 500, "{} samples", cols[0].len());
    assert!(
        cols[0]
            .windows(2)
            .all(|w| ((w[1] - w[0]) - 0.001).abs() < 1e-7),
        "a sample off the 1 ms grid"
    );
    let e = fails(&board(
        "virtual",
        &["record", "--out", o, "--decimation", "1"],
    ));
    assert!(
        e.contains("--decimation 1: recording until stopped: the stream needs about"),
        "{e}"
    );
}
