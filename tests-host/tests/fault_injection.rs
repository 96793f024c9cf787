//! Fault injection on the emulated board, through the same client a user runs:
//! each fault must end in the safe state (output ramped to the safe voltage,
//! amplifier off, fault latched). The test prints, for each, how many ticks the
//! board took to notice and to reach the safe voltage (50 µs per tick).
//!
//! * the force sensor's wire breaks mid-run (the reading sits on a rail);
//! * the force sensor freezes while the stage moves (the reading stops agreeing
//!   with the preload the FEM map gives for the estimated position);
//! * the force reading steps by 40 N (a loose connector);
//! * a reference beyond the stroke reaches the loop (points buffered for a wider
//!   model, then a narrower one loaded);
//! * control ticks overrun their period;
//! * the stored model is damaged (the board starts with the older one, or the
//!   factory model, and says so), and a reset by command is reported as such.
//!
//! The lost host link is in `emulated_board.rs`.

use std::path::Path;
use std::time::{Duration, Instant};

use fpi_host::board::client::{bits, Client};
use fpi_host::board::emulator::{flash_file, Emulator};
use fpi_host::data::{self, fem::FemMaps};
use fpi_host::method::export::{self, ExportOptions, LoopSettings};
use fpi_protocol::Origin;
use fpi_protocol::Shape;
use fpi_protocol::{BenchOrder, Command, FaultReport, ResetReason, SlotReport};
use piezo_fpi::control::Fault;

/// How the board dealt with one fault.
struct Outcome {
    what: &'static str,
    injected: u32,
    fault: FaultReport,
}

impl Outcome {
    fn print(&self) {
        let safe = self.fault.safe_at.unwrap_or(0);
        println!(
            "{:<44} fault {:<44} noticed after {:>4} ticks, safe voltage after {:>4} ticks ({:.2} ms)",
            self.what,
            Fault::from_code(self.fault.code).map_or("?", |f| f.message()),
            self.fault.at.saturating_sub(self.injected),
            safe.saturating_sub(self.injected),
            safe.saturating_sub(self.injected) as f64 * 0.05
        );
    }
}

fn start(flash: Option<&Path>) -> (Emulator, Client) {
    let elf = Emulator::firmware().unwrap_or_else(|e| panic!("{e:#}"));
    let e = Emulator::start_with_flash(&elf, None, flash).unwrap_or_else(|e| panic!("{e:#}"));
    let c = Client::open(e.port()).unwrap_or_else(|err| panic!("{err:#}\n{}", e.output()));
    (e, c)
}

/// The longest park: over the amplifier's whole 150 V range, ticks.
const FULL_PARK: u32 = piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150));

/// Waits until a fault has latched and the output reached the safe voltage.
fn safe(c: &mut Client) -> FaultReport {
    let start = Instant::now();
    loop {
        let s = c.status().unwrap();
        if let Some(f) = s
            .fault
            .filter(|f| f.safe_at.is_some() && f.code != Fault::Stopped as u8)
        {
            assert!(!s.amplifier_on, "the amplifier is off in the safe state");
            return f;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no safe state: {s:?}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Waits `ticks` board ticks.
fn wait_ticks(c: &mut Client, ticks: u32) {
    let until = c.status().unwrap().tick + ticks;
    while c.status().unwrap().tick < until {
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A 15 Hz sine over 1–39 µm, running: nearly the whole stroke, so that the
/// preload swings by 33 N, more than twice the 15 N tolerance, and the FEM map's
/// preload moves by more than half the tolerance (the stuck-sensor check) away
/// from a frozen reading within half a cycle, wherever it froze.
fn running(c: &mut Client) {
    c.move_to(20.0, 2000.0).unwrap();
    c.wave(Shape::Sine, 19.0, 20.0, 15.0, 0).unwrap();
    wait_ticks(c, 3000);
    assert_eq!(c.status().unwrap().fault, None);
}

/// Back to normal: the bench restored, the fault cleared.
fn recover(c: &mut Client) {
    for o in [
        BenchOrder::SensorOpen(false),
        BenchOrder::SensorStuck(false),
        BenchOrder::SensorOffset(0),
    ] {
        c.bench(o).unwrap();
    }
    c.ack(&Command::ClearFault).unwrap();
}

#[test]
fn every_injected_fault_ends_in_the_safe_state() {
    if !fpi_host::board::emulator::available_for("every_injected_fault_ends_in_the_safe_state") {
        return;
    }
    let (e, mut c) = start(None);
    let mut out = Vec::new();
    let inject = |c: &mut Client, what: &'static str, order: BenchOrder, want: Fault| {
        running(c);
        let injected = c.bench(order).unwrap();
        let fault = safe(c);
        assert_eq!(fault.code, want as u8, "{what}: {fault:?}");
        let o = Outcome {
            what,
            injected,
            fault,
        };
        o.print();
        recover(c);
        o
    };
    out.push(inject(
        &mut c,
        "force sensor wire breaks",
        BenchOrder::SensorOpen(true),
        Fault::ForceOutOfRange,
    ));
    out.push(inject(
        &mut c,
        "force sensor freezes",
        BenchOrder::SensorStuck(true),
        Fault::ForceImplausible,
    ));
    // A step within the dynamic limit (4 × the 15 N tolerance: a mode's ringing
    // is not a fault) is seen when the reading's slow part (10 Hz) passes the
    // tolerance; one beyond it at once.
    out.push(inject(
        &mut c,
        "force reading steps by 40 N",
        BenchOrder::SensorOffset(bits(40.0)),
        Fault::ForceImplausible,
    ));
    out.push(inject(
        &mut c,
        "force reading steps by 70 N",
        BenchOrder::SensorOffset(bits(70.0)),
        Fault::ForceImplausible,
    ));
    out.push(inject(
        &mut c,
        "control ticks overrun their period",
        BenchOrder::Stall(60),
        Fault::Overrun,
    ));
    // The sensor faults are seen at the next tick's reading; an overrun after a
    // run of late ticks (1 ms). All reach the safe voltage within the gentle park
    // over the whole 150 V range (642 ticks) of being noticed.
    for o in &out {
        let noticed = o.fault.at - o.injected;
        let ramp = o.fault.safe_at.unwrap() - o.fault.at;
        assert!(ramp <= FULL_PARK, "{}: {ramp} ticks of ramp", o.what);
        match o.what {
            // The preload moves by half the tolerance under the frozen reading
            // within half a cycle of the 15 Hz wave (667 ticks), wherever in the
            // cycle it froze.
            "force sensor freezes" => assert!(noticed < 667, "{noticed}"),
            // 15 N of a 40 N step through the 10 Hz low-pass: 0.47 τ, 150 ticks.
            "force reading steps by 40 N" => assert!(noticed <= 200, "{noticed}"),
            "control ticks overrun their period" => {
                assert!((20..=25).contains(&noticed), "{noticed}")
            }
            _ => assert!(noticed <= 1, "{}: {noticed}", o.what),
        }
    }
    let s = c.status().unwrap();
    assert!(s.overruns >= 20, "late ticks counted: {}", s.overruns);
    drop(e);
}

/// A model of stage A (fpi, calibrated on the pea-rig recordings) whose reachable
/// stroke stops at the voltage `stroke_v`.
fn narrow_model(stroke_v: f64) -> Vec<u8> {
    use fpi_host::method::calibrate::{self, Options};
    use fpi_host::method::model::Kind;
    let rig = calibrate::load(&data::datasets_in("pea-rig"), None).unwrap();
    let m = calibrate::calibrate(&rig, &Options::for_kind(Kind::Fpi)).unwrap();
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let o = ExportOptions {
        rate_hz: 20_000,
        u_max: 150.0,
        slew: 100.0,
        stroke_voltage: Some(stroke_v),
    };
    let settings = LoopSettings::for_model(&m, &o);
    let e = export::export(&m, Path::new("fpi"), &fem, &settings).unwrap();
    e.model.image().unwrap()
}

#[test]
fn a_reference_beyond_the_stroke_reaches_the_safe_state() {
    if !fpi_host::board::emulator::available_for(
        "a_reference_beyond_the_stroke_reaches_the_safe_state",
    ) {
        return;
    }
    let narrow = narrow_model(60.0);
    let (_e, mut c) = start(None);
    // Points for the factory model's stroke (0–40 µm), up to 30 µm.
    c.move_to(5.0, 2000.0).unwrap();
    c.ack(&Command::StreamClear { axis: 0 }).unwrap();
    let points: Vec<f64> = (0..640).map(|k| 5.0 + 25.0 * k as f64 / 639.0).collect();
    for k in (0..640).step_by(64) {
        c.points(k as u32, &points[k..k + 64]).unwrap();
    }
    // A narrower model, loaded at rest, then the stream.
    c.ack(&Command::Safe).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    c.upload(&narrow, false, |_| {}).unwrap();
    let top = c.model().unwrap().window[1];
    println!(
        "narrow model: stroke up to {:.3} µm",
        fpi_host::board::client::real(top)
    );
    assert!(top < bits(30.0));
    c.ack(&Command::Stream {
        axis: 0,
        interval: 20,
    })
    .unwrap();
    let f = safe(&mut c);
    assert_eq!(f.code, Fault::ReferenceUnreachable as u8);
    // The stream crosses the stroke's top at point k: 20 ticks a point.
    let k = points.iter().position(|x| bits(*x) > top).unwrap() as u32;
    let o = Outcome {
        what: "reference beyond the stroke",
        injected: f.at,
        fault: f,
    };
    o.print();
    assert!(f.safe_at.unwrap() - f.at <= FULL_PARK);
    assert!(k > 0);
}

#[test]
fn a_damaged_stored_model_is_refused_at_start_up_and_resets_are_told() {
    if !fpi_host::board::emulator::available_for(
        "a_damaged_stored_model_is_refused_at_start_up_and_resets_are_told",
    ) {
        return;
    }
    let dir = std::env::temp_dir().join(format!("fpi-faults-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = fpi_firmware::board::factory_model::MODEL_IMAGE;
    // Generation 1 intact, generation 2 damaged: the board starts with generation 1.
    let two = dir.join("two.flash");
    flash_file(&two, &[good, good], &[1]).unwrap();
    let (_e, mut c) = start(Some(&two));
    let m = c.model().unwrap();
    println!(
        "flash with generations 1 and 2 (2 damaged): runs {:?}, slots {:?}",
        m.origin, m.slots
    );
    assert_eq!(m.origin, Origin::Stored(1));
    assert!(m.slots.contains(&SlotReport::Damaged));
    assert!(m.slots.contains(&SlotReport::Valid(1)));
    let s = c.status().unwrap();
    assert_eq!(
        s.fault.map(|f| f.code),
        Some(Fault::Stopped as u8),
        "parked"
    );
    assert!(!s.amplifier_on);
    assert_eq!(c.hello().reset, ResetReason::PowerOn);
    // A reset by command is told as such, and the board starts parked again.
    let h = c.reset().unwrap().clone();
    assert_eq!(h.reset, ResetReason::Command);
    assert_eq!(c.model().unwrap().origin, Origin::Stored(1));
    drop(c);
    // Only a damaged model: the factory model runs.
    let one = dir.join("one.flash");
    flash_file(&one, &[good], &[0]).unwrap();
    let (_e, mut c) = start(Some(&one));
    let m = c.model().unwrap();
    println!(
        "flash with one damaged model: runs {:?}, slots {:?}",
        m.origin, m.slots
    );
    assert_eq!(m.origin, Origin::Factory);
    assert_eq!(m.slots[0], SlotReport::Damaged);
}
