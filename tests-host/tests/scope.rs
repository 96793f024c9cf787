//! The scope in a real browser (`fpi scope`, `fpi_host::scope`): on the emulated
//! board, served to several clients (`fpi board serve`), the scope streams
//! every tick to its page, open in headless Chromium; a 200 Hz sine is started
//! from the CLI while the page is open. The page reports what it shows (its
//! `?report=` query): the test reads from it that the trace is live, that the
//! spectrum's peak is at 200 ± 2 Hz and that the triggered trace stands still.
//! It prints the page's frame rate and the samples it receives per second
//! (figures, not bounds).

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use fpi_host::board::client::Client;
use fpi_host::board::emulator::{self, Emulator};
use fpi_host::board::hub::Hub;
use fpi_host::scope::{self, Options};
use fpi_protocol::record::signal;
use fpi_protocol::LinkKind;
use serde_json::Value;

mod common;

/// Chromium from Debian's packages (or `CHROMIUM`), if there is one.
fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    let dirs: Vec<PathBuf> = std::env::split_paths(&path).collect();
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|name| dirs.iter().map(move |d| d.join(name)))
        .find(|p| p.is_file())
}

/// Whether the browser test can run: CI must have Chromium (the README's
/// install step); elsewhere its absence is said and the test skipped.
fn browser_for(test: &str) -> Option<PathBuf> {
    if !emulator::available_for(test) {
        return None;
    }
    let found = chromium();
    if found.is_none() {
        assert!(
            !emulator::under_ci(),
            "{test}: CI must run the scope in Chromium (apt install chromium)"
        );
        eprintln!(
            "\n!!!!! SKIPPED {test}: it needs Chromium (apt install chromium, or set CHROMIUM)\n"
        );
    }
    found
}

/// Headless Chromium on `url`, killed when dropped.
struct Browser(Child, PathBuf);

impl Browser {
    fn open(exe: &PathBuf, url: &str) -> Self {
        let profile = common::scratch("scope").join("chromium-profile");
        let child = Command::new(exe)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--disable-background-timer-throttling",
                "--disable-renderer-backgrounding",
                "--window-size=1400,900",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(url)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting Chromium");
        Self(child, profile)
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let _ = std::fs::remove_dir_all(&self.1);
    }
}

/// A plain HTTP GET of `path` on `addr`: the body, where the status is 200.
fn get(addr: &str, path: &str) -> Option<String> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").ok()?;
    let mut all = String::new();
    s.read_to_string(&mut all).ok()?;
    let (head, body) = all.split_once("\r\n\r\n")?;
    (head.split(' ').nth(1) == Some("200")).then(|| body.to_string())
}

/// The page's report, once it has one.
fn report(addr: &str) -> Option<Value> {
    serde_json::from_str(&get(addr, "/report")?).ok()
}

/// Waits (≤ `within`) for a report that `ok` takes; the last report seen.
fn until(addr: &str, within: Duration, ok: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    let mut last = Value::Null;
    while start.elapsed() < within {
        if let Some(r) = report(addr) {
            if ok(&r) {
                return r;
            }
            last = r;
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    panic!("the page did not report it within {within:?}; its last report: {last:#}");
}

fn num(r: &Value, path: &[&str]) -> f64 {
    let mut v = r;
    for k in path {
        v = &v[*k];
    }
    v.as_f64().unwrap_or(f64::NAN)
}

#[test]
fn the_page_shows_a_live_sine_with_its_spectrum_and_a_still_trigger() {
    const TEST: &str = "the_page_shows_a_live_sine_with_its_spectrum_and_a_still_trigger";
    let Some(exe) = browser_for(TEST) else {
        return;
    };
    // The CLI built first, so that the times below are the scope's.
    fpi_tests::fpi_bin();
    // The emulated board, its link paced as USB, served to several clients.
    let elf = Emulator::firmware().unwrap_or_else(|e| panic!("{e:#}"));
    let e = Emulator::start_elf(&elf, None).unwrap_or_else(|e| panic!("{e:#}"));
    e.pace_as(LinkKind::Usb).expect("the link paced as USB");
    let board = Client::open(e.port()).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = format!("tcp:{}", listener.local_addr().unwrap());
    let halt = Arc::new(AtomicBool::new(false));
    let hub = {
        let halt = halt.clone();
        std::thread::spawn(move || {
            Hub::new(board).serve(&listener, &|| halt.load(Ordering::Relaxed), &|_, _| {})
        })
    };

    // The scope, on the served board, the position and the voltage at every tick.
    let start = Instant::now();
    let o = Options {
        signals: signal::X_REF | signal::X_TRUE | signal::VOLTAGE,
        decimation: 1,
    };
    let c = Client::open(&port).expect("the scope's client");
    let bound = scope::bind(
        Arc::new(Mutex::new(c)),
        "the emulated board",
        "127.0.0.1:0",
        o,
    )
    .unwrap_or_else(|e| panic!("the scope: {e:#}"));
    let (url, addr) = (bound.url(), bound.addr().to_string());
    let scope_halt = Arc::new(AtomicBool::new(false));
    let scope = {
        let halt = scope_halt.clone();
        std::thread::spawn(move || bound.run(&|| halt.load(Ordering::Relaxed)))
    };

    // The page, triggered on the stage's true position rising through 20 µm;
    // its triggers panel sets the board's output to a pulse every 0.25 µm of
    // travel and its input to start recordings (`tout=`: as its Set button
    // does).
    let query = "?mode=normal&trigger=x_fhps_um&level=20&edge=rising&pre=0.5&span=0.02\
                 &spectrum=x_fhps_um&fft=16384&x=voltage_V&y=x_fhps_um&report=500\
                 &tout=travel,step_um=0.25,pulse_ticks=3,input=recorder";
    let browser = Browser::open(&exe, &format!("{url}{query}"));
    let first = until(&addr, Duration::from_secs(60), |r| {
        num(r, &["samples"]) > 0.0
    });
    println!(
        "the page streams after {:.1} s",
        start.elapsed().as_secs_f64()
    );
    let set = until(&addr, Duration::from_secs(60), |r| {
        r["trigger_output"]["settings"]["mode"] == "travel"
    });
    assert!(set["trigger_output"]["error"].is_null(), "{set:#}");
    let held = common::ok(&["board", "--port", &port, "get", "stage/0/trigger/step_nm"]);
    assert_eq!(held.trim(), "250", "the board holds what the page set");
    let held = common::ok(&[
        "board",
        "--port",
        &port,
        "get",
        "stage/0/trigger/pulse_ticks",
    ]);
    assert_eq!(held.trim(), "3");

    // A 200 Hz sine of ±2 µm about 20 µm (within what the governor passes on
    // the factory model), started from the CLI.
    common::ok(&["board", "--port", &port, "move", "20"]);
    common::ok(&[
        "board",
        "--port",
        &port,
        "wave",
        "--amplitude-um",
        "2",
        "--offset-um",
        "20",
        "--freq-hz",
        "200",
    ]);

    println!("the wave runs after {:.1} s", start.elapsed().as_secs_f64());

    // Live: more samples, newer ticks; the spectrum's peak at the wave's
    // frequency; triggered frames that stand still.
    let r = until(&addr, Duration::from_secs(240), |r| {
        num(r, &["trigger", "triggered_frames"]) >= 5.0
            && (num(r, &["spectrum", "peak_hz"]) - 200.0).abs() <= 2.0
            && num(r, &["trigger", "stillness"]) < 0.05
    });
    println!(
        "the page shows it after {:.1} s: {r:#}",
        start.elapsed().as_secs_f64()
    );
    assert!(r["error"].is_null(), "{r:#}");
    assert!(num(&r, &["samples"]) > num(&first, &["samples"]), "{r:#}");
    assert!(
        num(&r, &["last_tick"]) > num(&first, &["last_tick"]),
        "{r:#}"
    );
    let later = until(&addr, Duration::from_secs(30), |l| {
        num(l, &["samples"]) > num(&r, &["samples"]) && num(l, &["frames"]) > num(&r, &["frames"])
    });
    println!(
        "scope: {:.0} frames/s drawn, {:.0} samples/s received (board time runs at the emulation's pace), \
         {} gaps, {} dropped",
        num(&later, &["fps"]),
        num(&later, &["received_per_s"]),
        num(&later, &["gaps"]),
        num(&later, &["dropped"]),
    );

    drop(browser);
    scope_halt.store(true, Ordering::Relaxed);
    let t = scope.join().unwrap().expect("the scope's run");
    println!("{}", scope::closing(&t));
    halt.store(true, Ordering::Relaxed);
    hub.join().unwrap().expect("the hub");
    drop(e);
}

/// `fpi scope` refuses what it cannot do before it serves anything, naming the
/// option and its value: an unknown signal, a decimation the link cannot carry
/// for ever, an address already taken.
#[test]
fn the_scope_refuses_bad_options_by_name() {
    common::refused(
        &["scope", "--port", "virtual", "--signals", "x_ref_um,speed"],
        &["--signals speed: no such signal", "x_fhps_um"],
    );
    // The in-process board's link is paced as its UART (12 kB/s).
    common::refused(
        &[
            "scope",
            "--port",
            "virtual",
            "--listen",
            "127.0.0.1:0",
            "--decimation",
            "1",
        ],
        &[
            "--decimation 1: the stream needs about",
            "uart link carries",
        ],
    );
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let at = taken.local_addr().unwrap().to_string();
    common::refused(
        &["scope", "--port", "virtual", "--listen", &at],
        &[&format!("listening on {at}")],
    );
}
