//! Several clients, one link (`fpi board serve`, `fpi_host::board::hub`): on
//! the in-process board, a client drives the stage while another watches it and
//! the CLI records it; the motion is held by one client, the others refused
//! naming the holder, hold never is; every client records at once, each its own
//! decimation and signals, whole; what a client that went held is free again.

use std::net::TcpListener;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use fpi_host::board::client::Client;
use fpi_host::board::commands;
use fpi_host::board::hub::Hub;
use fpi_host::board::live::{Live, SharedClient};
use fpi_protocol::record::signal;
use fpi_protocol::{Command, SourceKind};

mod common;

/// A hub over a fresh in-process board (its link paced as USB), serving on a
/// free port until the returned flag is set: the port's name for clients.
fn hub() -> (String, &'static AtomicBool) {
    let board = Client::open("virtual:usb").expect("the in-process board");
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = format!("tcp:{}", listener.local_addr().unwrap());
    let halt: &'static AtomicBool = Box::leak(Box::new(AtomicBool::new(false)));
    std::thread::spawn(move || {
        let hub = Hub::new(board);
        hub.serve(&listener, &|| halt.load(Ordering::Relaxed), &|_, _| {})
            .unwrap();
    });
    (port, halt)
}

fn wave(c: &mut Client) -> u32 {
    commands::wave(c, "sine", 2.0, 12.0, 40.0, 0).expect("the wave")
}

/// Moves to `um` and waits until the stage is there.
fn move_to(c: &mut Client, um: f64) {
    commands::move_to(c, um, 1000.0).expect("the move");
    commands::wait_on_target(c, 0.1, 10.0, || false).expect("on target");
}

fn move_command(um: f64) -> Command<'static> {
    commands::move_command(0, um, 1000.0).unwrap()
}

#[test]
fn one_client_drives_while_others_watch_and_record() {
    let (port, halt) = hub();
    let mut driver = Client::open(&port).unwrap();
    let mut watcher = Client::open(&port).unwrap();
    move_to(&mut driver, 12.0);
    wave(&mut driver);

    // The watcher sees the wave, and may record it (the recorder is free).
    assert_eq!(watcher.status().unwrap().source, SourceKind::Wave);
    let out = common::ok(&[
        "board",
        "--port",
        &port,
        "record",
        "--seconds",
        "0.05",
        "--out",
        common::scratch("hub").join("wave.csv").to_str().unwrap(),
    ]);
    assert!(out.contains("samples"), "{out}");

    // The watcher's motion is refused while the driver's runs, naming the driver.
    let e = watcher
        .order(&move_command(5.0))
        .expect_err("a second client's move");
    let msg = format!("{e:#}");
    assert!(
        msg.contains("the motion is held by client 1") && msg.contains("Held"),
        "{msg}"
    );
    assert_eq!(driver.status().unwrap().source, SourceKind::Wave);

    // Everyone records: the driver's live recording (every 20th tick) and the
    // watcher's own (every 40th, the position only) run at once, each whole.
    let shared: std::sync::Arc<dyn SharedClient> =
        std::sync::Arc::new(std::sync::Mutex::new(driver));
    let live = Live::start(shared.clone(), signal::ALL, 20, true).unwrap();
    let armed = watcher
        .ack(&Command::Record {
            axis: 0,
            decimation: 40,
            signals: signal::X_REF,
        })
        .unwrap();
    let mut mine = Vec::new();
    while mine.len() < 40 {
        std::thread::sleep(Duration::from_millis(20));
        let b = watcher.read_batch().unwrap();
        assert!(b.active && b.dropped == 0, "{b:?}");
        mine.extend(fpi_protocol::record::Sample::batch(b.signals, &b.values));
    }
    watcher.ack(&Command::RecordStop).unwrap();
    let (rec, counts) = live.stop().unwrap();
    assert!(counts.whole(), "{counts:?}");
    assert!(rec.samples.len() > 50, "{}", rec.samples.len());
    assert!(rec.samples.windows(2).all(|w| w[1].tick - w[0].tick == 20));
    assert!(
        mine[0].tick > armed && mine[0].tick <= armed + 40,
        "{} after {armed}",
        mine[0].tick
    );
    assert!(mine.windows(2).all(|w| w[1].tick - w[0].tick == 40));
    assert!(mine.iter().all(|s| s.voltage == 0 && s.x_ref != 0));

    // Anyone may stop the stage; then the motion is anyone's.
    watcher.order(&Command::Hold { axis: 0 }).expect("hold");
    watcher
        .order(&move_command(5.0))
        .expect("the watcher's move once the stage holds");
    halt.store(true, Ordering::Relaxed);
}

#[test]
fn what_a_client_that_went_held_is_free_again() {
    let (port, halt) = hub();
    let mut other = Client::open(&port).unwrap();
    {
        let mut gone = Client::open(&port).unwrap();
        move_to(&mut gone, 12.0);
        wave(&mut gone);
        gone.ack(&Command::Record {
            axis: 0,
            decimation: 20,
            signals: signal::ALL,
        })
        .unwrap();
    }
    // The hub sees it go (its session reads every 50 ms), frees the motion
    // and ends its recording: the board's recorder stops with the last one.
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        other.status().unwrap().recorder[0],
        0,
        "the board's recorder still runs"
    );
    assert_eq!(other.status().unwrap().source, SourceKind::Wave);
    wave(&mut other);
    halt.store(true, Ordering::Relaxed);
}
