//! The firmware on the emulated board, driven through its command link by the
//! same host code a user runs (`fpi_host::board`), as part of `cargo test`.
//!
//! Each test starts its own QEMU `netduinoplus2` with the `qemu` firmware and its
//! USART on a free TCP port:
//!
//! * the scripted session (`fpi_host::board::session`) with a model calibrated
//!   here from the rig recordings and exported with stage A's FEM tables: upload,
//!   stroke without and with compensation, streamed minor loops, broken sensor
//!   wire, unreachable position, bad frames — every check passes and the twin
//!   reproduces every recorded sample within `TWIN_BOUND` (0.5 nm);
//! * the paper's FPI with ten operators as a model received at run time, a 15 Hz
//!   sine over most of the stroke recorded and reproduced by the twin;
//! * corrupted, incomplete and misplaced model uploads are refused with their
//!   reasons and the running model is kept;
//! * a host that falls silent mid-stream parks the stage within its timeout.
//!
//! Also builds the board firmware (flash and RAM within budget) and the
//! link-time no-panic proof of the control path. Needs `qemu-system-arm` and the
//! thumbv7em-none-eabihf target (`cargo demo` installs the target and says how to
//! install QEMU).

use std::path::Path;
use std::time::{Duration, Instant};

use fpi_firmware::control::recorder::{signal, status};
use fpi_host::board::client::{self, refusal, Client};
use fpi_host::board::emulator::Emulator;
use fpi_host::board::recording::Recording;
use fpi_host::board::{self, session, twin};
use fpi_host::data::{self, fem::FemMaps};
use fpi_host::method::calibrate::{self, Options};
use fpi_host::method::export::{self, ExportOptions, LoopSettings};
use fpi_host::method::model::Kind;
use fpi_protocol::Origin;
use fpi_protocol::Shape;
use fpi_protocol::SourceKind;
use fpi_protocol::{Command, Refusal};
use piezo_fpi::control::Fault;
use piezo_fpi::model::image::{CRC32, HEADER_LEN};

/// A model of `kind` with `operators` play operators (the `r = 0` one included)
/// calibrated on the rig and exported with stage A's FEM tables, as an image for
/// the board.
fn image_of(kind: Kind, operators: usize) -> Vec<u8> {
    let rig = calibrate::load(&data::datasets_in("pea-rig"), None).unwrap();
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let opt = Options {
        operators,
        ..Options::for_kind(kind)
    };
    let m = calibrate::calibrate(&rig, &opt).unwrap();
    let settings = LoopSettings::for_model(
        &m,
        &ExportOptions {
            rate_hz: 20_000,
            u_max: 150.0,
            slew: 100.0,
            stroke_voltage: Some(100.0),
        },
    );
    let e = export::export(&m, Path::new("in-test"), &fem, &settings).unwrap();
    e.model.image().unwrap()
}

fn start() -> (Emulator, Client) {
    let e = Emulator::start(None).unwrap_or_else(|e| panic!("{e:#}"));
    let c = Client::open(e.port()).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    (e, c)
}

#[test]
fn the_session_passes_every_check_and_the_twin_reproduces_its_recording() {
    if !fpi_host::board::emulator::available_for(
        "the_session_passes_every_check_and_the_twin_reproduces_its_recording",
    ) {
        return;
    }
    let image = image_of(Kind::Efpi, 10);
    let (e, mut c) = start();
    let r = session::run(&mut c, &image).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    for p in &r.phases {
        println!(
            "{:<44} rms {:>7.1} nm max {:>7.1} nm  {}  {}",
            p.name,
            p.tracking.rms() * 1e3,
            p.tracking.max_abs() * 1e3,
            if p.pass { "ok" } else { "FAILED" },
            p.note
        );
    }
    println!("{:?}", r.twin);
    for p in &r.phases {
        assert!(p.pass, "{}: {}", p.name, p.note);
    }
    let on = r.phase("compensated 5 Hz").unwrap();
    assert!(on.tracking.max_abs() < session::MAX_ERROR_UM);
    let sine = r.phase("15 Hz sine while bad frames arrive").unwrap();
    assert!(sine.tracking.count() > 100, "recorded the 15 Hz sine");
    assert!(sine.tracking.max_abs() < session::MAX_ERROR_UM);
    assert!(r.twin.within(twin::TWIN_BOUND), "{:?}", r.twin);
    assert!(r.twin.samples > 1000);
    assert_eq!(r.recording.dropped, 0);
    // The three bad frames (a frame cut by the board's start-up may add one).
    assert!((3..=4).contains(&r.counters.malformed), "{:?}", r.counters);
    let m = c.model().unwrap();
    assert_eq!(m.crc, CRC32.checksum(&image));
    assert_eq!(m.origin, Origin::Received);
    assert_eq!(
        m.stored.map(|s| s.0),
        Some(1),
        "stored in flash, generation 1"
    );
    let k = c.counters().unwrap();
    println!("stack high-water mark: {} bytes", k.stack_bytes);
    assert!(k.stack_bytes > 0 && k.stack_bytes < 24 * 1024);
}

#[test]
fn the_papers_fpi_with_ten_operators_runs_as_a_received_model() {
    if !fpi_host::board::emulator::available_for(
        "the_papers_fpi_with_ten_operators_runs_as_a_received_model",
    ) {
        return;
    }
    // Ten thresholded operators and the linear one: the board's capacity.
    let image = image_of(Kind::Fpi, 11);
    let (e, mut c) = start();
    let mut run = || -> anyhow::Result<(Recording, u32)> {
        c.upload(&image, false, |_| {})?;
        let m = c.model()?;
        assert_eq!(
            (m.size, m.maps),
            ([10, 0], [false, false]),
            "n = 10, bare FPI"
        );
        // 400 samples/s: what the UART the board is paced as carries.
        c.ack(&Command::Record {
            axis: 0,
            decimation: 50,
            signals: signal::ALL,
        })?;
        c.move_to(3.0, 1000.0)?;
        let from = c.wave(Shape::Sine, 16.0, 19.0, 15.0, 4)?;
        let mut rec = Recording {
            rate_hz: c.rate_hz(),
            signals: signal::ALL,
            ..Recording::default()
        };
        loop {
            let (s, d) = c.drain()?;
            rec.samples.extend(s);
            rec.dropped = d;
            let st = c.status()?;
            if st.source == SourceKind::Hold && st.tick > from + 100 {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let (s, _) = c.drain()?;
        rec.samples.extend(s);
        Ok((rec, from))
    };
    let (rec, from) = run().unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    let last = rec.samples.last().unwrap().tick;
    let trace = twin::replay(&c.log, last).unwrap();
    let a = twin::compare(&rec.samples, rec.signals, &trace);
    let track = rec.tracking(from + 2000, last);
    println!("paper FPI, 15 Hz: {track:?}; twin {a:?}");
    assert!(a.within(twin::TWIN_BOUND), "{a:?}");
    assert!(track.count() > 50);
    // The paper's FPI leaves more error than efpi on stage A, but tracks.
    assert!(track.max_abs() < 3.0, "{}", track.max_abs());
}

#[test]
fn bad_model_uploads_are_refused_with_reasons_and_the_old_model_kept() {
    if !fpi_host::board::emulator::available_for(
        "bad_model_uploads_are_refused_with_reasons_and_the_old_model_kept",
    ) {
        return;
    }
    let good = fpi_firmware::board::factory_model::MODEL_IMAGE.to_vec();
    let (e, mut c) = start();
    let before = c.model().unwrap();
    let check = |c: &mut Client, what: &str, result: anyhow::Result<u32>, want: Refusal| {
        let err = result.expect_err(what);
        let r = refusal(&err).unwrap_or_else(|| panic!("{what}: {err:#}"));
        println!("{what}: {r}");
        assert_eq!(r.code, want, "{what}");
        let now = c.model().unwrap();
        assert_eq!(
            (now.crc, now.origin),
            (before.crc, before.origin),
            "{what}: model kept"
        );
    };
    // Bytes damaged on the way: the image no longer matches the CRC announced.
    let mut damaged = good.clone();
    damaged[HEADER_LEN + 100] ^= 0x10;
    c.ack(&Command::ModelBegin {
        len: good.len() as u32,
        crc: CRC32.checksum(&good),
    })
    .unwrap();
    for (k, chunk) in damaged.chunks(256).enumerate() {
        c.ack(&Command::ModelChunk {
            offset: (k * 256) as u32,
            data: chunk,
        })
        .unwrap();
    }
    let r = c.ack(&Command::ModelCommit {
        axis: 0,
        store: true,
    });
    check(&mut c, "damaged in transit", r, Refusal::Model);
    // A model the validator refuses: a negative PI weight, every CRC consistent.
    let mut invalid = good.clone();
    let w0 = HEADER_LEN + 4;
    invalid[w0..w0 + 4].copy_from_slice(&(-100i32).to_le_bytes());
    let body = CRC32.checksum(&invalid[HEADER_LEN..]);
    invalid[12..16].copy_from_slice(&body.to_le_bytes());
    let r = c.upload(&invalid, true, |_| {});
    check(&mut c, "invalid model", r, Refusal::Model);
    // An upload cut short.
    c.ack(&Command::ModelBegin {
        len: good.len() as u32,
        crc: CRC32.checksum(&good),
    })
    .unwrap();
    let r = c.ack(&Command::ModelCommit {
        axis: 0,
        store: false,
    });
    check(&mut c, "incomplete upload", r, Refusal::Upload);
    // A good model while the stage moves.
    c.move_to(10.0, 1000.0).unwrap();
    let r = c.upload(&good, false, |_| {});
    check(&mut c, "while moving", r, Refusal::NotAtRest);
    // Parked, the same model is taken.
    c.ack(&Command::Safe).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    c.upload(&good, true, |_| {})
        .unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    let m = c.model().unwrap();
    assert_eq!(
        (m.origin, m.stored.map(|s| s.0)),
        (Origin::Received, Some(1))
    );
}

#[test]
fn a_silent_host_parks_a_streaming_stage_within_its_timeout() {
    if !fpi_host::board::emulator::available_for(
        "a_silent_host_parks_a_streaming_stage_within_its_timeout",
    ) {
        return;
    }
    let (e, mut c) = start();
    let timeout_ms = 200;
    c.ack(&Command::Supervise { timeout_ms }).unwrap();
    c.move_to(5.0, 1000.0).unwrap();
    // Three seconds of a slow sine at 1 kHz: more than the buffer holds.
    let points: Vec<f64> = (0..3000)
        .map(|k| 15.0 + 10.0 * (k as f64 * 0.004).sin())
        .collect();
    c.ack(&Command::StreamClear { axis: 0 }).unwrap();
    for k in (0..1024).step_by(64) {
        c.points(k as u32, &points[k..k + 64]).unwrap();
    }
    // One sample every 40 ticks: the ring (512 samples) holds a second of board
    // time from the stream's start, the fault included, until the new host
    // reads it (started here, not before the points' upload, whose length in
    // board ticks grows with the board's pace).
    c.ack(&Command::Record {
        axis: 0,
        decimation: 40,
        signals: signal::ALL,
    })
    .unwrap();
    c.ack(&Command::Stream {
        axis: 0,
        interval: 20,
    })
    .unwrap();
    let mut last = c.status().unwrap().tick;
    // Stream for 6 000 ticks of board time, then the host goes away mid-stream:
    // the recording's start, the stream, the timeout and the park fit in the
    // ring's second however fast the board runs (600 ms of wall-clock time
    // did not at 10 000 ticks/s).
    let t = Instant::now();
    let first = c.status().unwrap().tick;
    let mut sent = 1024;
    while last < first + 6_000 {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the board's clock stalled"
        );
        let s = c.status().unwrap();
        last = s.tick;
        if s.stream[1] >= 64 && sent + 64 <= points.len() {
            c.points(sent as u32, &points[sent..sent + 64]).unwrap();
            sent += 64;
        }
    }
    let last_request = c.log.last().unwrap().tick.max(last);
    // Board ticks per wall-clock second (30–40 % of real time on two cores, less
    // when the tests share them).
    let pace = (last - first) as f64 / t.elapsed().as_secs_f64();
    drop(c);
    // The board runs on, unattended; a new host comes back later. Any request is a
    // heartbeat, so it must not look before the board has had time to notice:
    // twice the time the timeout and the ramp take at the pace measured.
    let rate = 20_000.0;
    let timeout_ticks = (timeout_ms as f64 * rate / 1000.0) as u32;
    let wait = 2.0 * (timeout_ticks + 2000) as f64 / pace.max(500.0);
    println!("board pace {pace:.0} ticks/s: waiting {wait:.1} s");
    std::thread::sleep(Duration::from_secs_f64(wait.clamp(1.0, 60.0)));
    let mut c = Client::open(e.port()).unwrap();
    let s = c.status().unwrap();
    assert!(
        s.tick > last_request + timeout_ticks + 100,
        "the board's clock ran too slowly to tell (tick {}, last request {last_request})",
        s.tick
    );
    let f = s.fault.expect("a fault is latched");
    println!(
        "last request at tick {last_request}, fault {} at tick {}, safe at {:?}",
        f.code, f.at, f.safe_at
    );
    assert_eq!(f.code, Fault::LinkLost as u8);
    let safe = f.safe_at.expect("the output reached the safe voltage");
    assert!(
        f.at > last_request + timeout_ticks - 1,
        "not before the timeout"
    );
    // Within the timeout plus the park (over 150 V at most) and a few ticks of
    // slack for the request's own handling.
    let park = piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150));
    assert!(
        safe <= last_request + timeout_ticks + park + 4,
        "safe at {safe}, last request {last_request}, timeout {timeout_ticks} ticks"
    );
    assert!(!s.amplifier_on);
    // The recording shows it: moving before, parked after.
    let (samples, _) = c.drain().unwrap();
    let after: Vec<_> = samples
        .iter()
        .filter(|s| s.tick > safe && s.tick < safe + 10_000)
        .collect();
    assert!(!after.is_empty());
    assert!(after.iter().all(|s| s.status & status::FAULT != 0
        && s.status & status::AMPLIFIER_ON == 0
        && s.voltage == 0));
    println!(
        "recorded ticks {:?}..{:?}, largest reference {:.3} µm",
        samples.first().map(|s| s.tick),
        samples.last().map(|s| s.tick),
        samples
            .iter()
            .map(|s| client::real(s.x_ref))
            .fold(0.0, f64::max)
    );
    let moving = samples
        .iter()
        .filter(|s| s.tick < f.at)
        .any(|s| client::real(s.x_ref) > 5.5 && s.status & status::FAULT == 0);
    assert!(moving, "the stream was running when the link was lost");
}

/// 768 KiB of program flash; 128 KiB of RAM, of which the stack needs ~12 KiB
/// (the emulated board reports its high-water mark over the link). 160 KiB of
/// flash until the damping, the analyser and the loops' stability check (f64, in
/// software) came: 168 KiB then; 191 KiB before the reference governor, whose
/// analysis of a model's loops (their simulation, the envelopes' fit, the
/// limits of each set of loops) took it to 204 KiB; the runtime settings tree
/// (miniconf's key paths, serde-json-core's JSON values) to 224 KiB; the link
/// of a board of several axes (an axis in the model commands and the
/// recorder, the raster, the decoupling and the moves of several axes, a
/// recording of every axis), from 236 KiB to 240.5 KiB: a budget of 248 KiB.
/// The model stores and the image buffer lie in the CCM (64 KiB).
fn budget(f: &board::Footprint) {
    assert!(f.flash <= 248 * 1024, "flash budget 248 KiB");
    assert!(
        f.ram <= 100 * 1024,
        "static RAM budget 100 KiB (28 KiB left for the stack)"
    );
    assert!(f.ccm <= 64 * 1024, "the CCM's 64 KiB");
}

#[test]
fn board_firmware_fits_its_budget_and_the_control_path_cannot_panic() {
    // The default front end's build and the precision one's, to one budget.
    for features in ["defmt", "defmt,precision"] {
        let elf = board::build("fpi-firmware", features).unwrap_or_else(|e| panic!("{e:#}"));
        let f = board::footprint(&elf).unwrap_or_else(|e| panic!("{e:#}"));
        println!(
            "board firmware ({features}): {} B flash, {} B static RAM, {} B CCM",
            f.flash, f.ram, f.ccm
        );
        budget(&f);
    }
    // Three axes' models and their loops fit the F405 with 16 KiB of stack:
    // the emulated board of three axes' build, less its stand-in for the
    // model's flash (and with its virtual stage, which the board has not).
    let elf = board::build("fpi-firmware-xyz", "qemu").unwrap_or_else(|e| panic!("{e:#}"));
    let f = board::footprint(&elf).unwrap_or_else(|e| panic!("{e:#}"));
    println!(
        "three axes: {} B static RAM on the board, {} B CCM: {} B left for the stack",
        f.board_ram(),
        f.ccm,
        128 * 1024 - f.board_ram()
    );
    assert!(f.board_ram() <= 112 * 1024 && f.ccm <= 64 * 1024, "{f:?}");

    // Links only if no panic branch is reachable from the control task or the
    // model loading.
    board::build("no-panic", "qemu").unwrap_or_else(|e| panic!("{e:#}"));
}

/// `fpi board emulate --axes 2`: the emulated board of two axes on QEMU (the
/// XY stage as designed) answers as a board of two, moves both axes from one
/// tick and rasters over them, every axis recorded; three axes are refused
/// with the reason (they do not fit QEMU's memory). The late control ticks
/// (the virtual stage of two axes computed in the same period) are printed.
#[test]
fn the_emulated_board_of_two_axes_moves_and_rasters_both() {
    if !fpi_host::board::emulator::available_for("emulated board of two axes") {
        return;
    }
    let err = Emulator::firmware_of(3).unwrap_err().to_string();
    assert!(err.contains("does not fit QEMU's memory"), "{err}");
    let elf = Emulator::firmware_of(2).unwrap_or_else(|e| panic!("{e:#}"));
    let e = Emulator::start_elf(&elf, None).unwrap_or_else(|e| panic!("{e:#}"));
    let mut c = Client::open(e.port()).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    c.pace_as(fpi_protocol::LinkKind::Usb).unwrap();
    assert_eq!(c.hello().axes, 2);
    let err = c
        .front_end(fpi_protocol::FrontEndKind::Precision)
        .unwrap_err();
    assert!(format!("{err:#}").contains("several axes"), "{err:#}");
    c.order(&Command::MoveAxes {
        mask: 0b11,
        targets: [client::bits(10.0), client::bits(20.0), 0],
        speed: client::bits(1000.0),
    })
    .unwrap();
    for (axis, um) in [(0, 10.0), (1, 20.0)] {
        c.on_axis(axis).unwrap();
        board::follow::Follow::new(&mut c, 0).until_hold().unwrap();
        let at = client::real(c.status().unwrap().signals[0]);
        assert!((at - um).abs() < 1e-3, "axis {axis}: {at}");
    }
    c.on_axis(0).unwrap();
    let spec = board::raster::RasterSpec {
        fast: 0,
        slow: 1,
        fast_um: (5.0, 35.0),
        slow_um: (5.0, 35.0),
        freq_hz: 50.0,
        lines: 4,
        staircase: false,
    };
    let (m, rec) = board::raster::run(&mut c, &spec).unwrap_or_else(|e| panic!("{e:#}"));
    assert!(m.fault.is_none(), "{:?}", m.fault);
    assert_eq!(rec.axes.len(), 2);
    let f = board::raster::figures(&spec, &rec).expect("whole lines recorded");
    println!(
        "emulated board of two axes: {}",
        board::raster::describe(&spec, &f)
    );
    // Open loop on the factory model, the stage as designed.
    assert!(f.on_truth && f.fast_rms_pct < 10.0, "{f:?}");
    let s = c.status().unwrap();
    println!(
        "emulated board of two axes: {} late control ticks of {}",
        s.overruns, s.tick
    );
}
