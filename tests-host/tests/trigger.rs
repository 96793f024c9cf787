//! The trigger output on the emulated board (QEMU, else the firmware built for
//! the host): set from the client as `fpi board trigger` and Python set it,
//! recorded in the `trigger` column, and checked against the position sensor's
//! readings of the same ticks (the latency from condition to edge is 0 ticks:
//! the line is written at the end of the tick whose reading met it).

use fpi_firmware::control::recorder::{lines, signal, Sample};
use fpi_host::board::client::{real, Client};
use fpi_host::board::follow::Follow;
use fpi_host::board::trigger::{self, Levels};
use fpi_protocol::{TriggerMode, TriggerSettings};
use fpi_tests::usb_board as board;
use piezo_fpi::process::SplitProcess;
use piezo_fpi::q::Micrometres;
use piezo_fpi::trigger::{Condition, Readings, Trigger, TriggerState};

const SIGNALS: u8 = signal::X_SENSOR | signal::X_REF | signal::TRIGGER;

fn high(s: &Sample) -> bool {
    s.lines & lines::TRIGGER_OUT != 0
}

/// The ticks at which the line rose.
fn rising(samples: &[Sample]) -> Vec<usize> {
    (1..samples.len())
        .filter(|&k| high(&samples[k]) && !high(&samples[k - 1]))
        .collect()
}

/// Records every tick while the trigger is set to `mode` with `levels` and
/// the stage moves to `to_um`; the trigger's settings, the tick they took
/// effect on, and the samples.
fn moved(
    c: &mut Client,
    mode: TriggerMode,
    levels: &Levels,
    to_um: f64,
) -> (TriggerSettings, u32, Vec<Sample>) {
    let s = trigger::with(trigger::settings(c).unwrap(), mode, levels).unwrap();
    let mut f = Follow::new(c, SIGNALS);
    f.record(1).unwrap();
    f.rec.samples.clear();
    let set_at = f.c.ack(&trigger::command(f.c.axis(), s)).unwrap();
    f.c.move_to(to_um, 200.0).unwrap();
    f.until_hold().unwrap();
    let end = f.c.status().unwrap().tick + f.ticks(0.005);
    f.until_tick(end).unwrap();
    f.c.ack(&fpi_protocol::Command::RecordStop).unwrap();
    f.drain().unwrap();
    assert_eq!(f.rec.dropped, 0, "every tick recorded");
    (s, set_at, f.rec.samples)
}

/// The line the core's trigger gives on the recorded readings from the tick
/// it was set on (its memory from the reading before: the order is taken at
/// the tick's start, before the sensor is read).
fn replayed(t: &Trigger, set_at: u32, rec: &[Sample]) -> Vec<(u32, bool)> {
    let k0 = rec
        .iter()
        .position(|s| s.tick + 1 == set_at)
        .expect("the tick before the set");
    let mut state = TriggerState::at(Micrometres::from_bits(rec[k0].x_sensor), 0);
    rec[k0 + 1..]
        .iter()
        .map(|s| {
            let r = Readings {
                x: Micrometres::from_bits(s.x_sensor),
                x_ref: Micrometres::from_bits(s.x_ref),
                points: 0,
            };
            (s.tick, t.process(&mut state, r))
        })
        .collect()
}

/// The recorded line from `set_at` on.
fn recorded(set_at: u32, rec: &[Sample]) -> Vec<(u32, bool)> {
    rec.iter()
        .filter(|s| s.tick >= set_at)
        .map(|s| (s.tick, high(s)))
        .collect()
}

#[test]
fn travel_pulses_every_step_and_a_window_is_high_exactly_inside_it() {
    let (_e, mut c) = board("trigger output");
    Follow::new(&mut c, 0).rest_at(10.0, "the start").unwrap();

    // Travel: a 2-tick pulse every 0.5 µm of a 10 → 20 µm move, the line
    // the core's rule gives on the same readings, tick for tick (latency 0).
    let levels = Levels {
        step_um: Some(0.5),
        pulse_ticks: Some(2),
        ..Levels::default()
    };
    let (s, set_at, rec) = moved(&mut c, TriggerMode::Travel, &levels, 20.0);
    assert_eq!((s.step_nm, s.pulse_ticks), (500, 2));
    let step = Condition::Travel {
        step: Micrometres::from_num(0.5),
    };
    let want = replayed(&Trigger::new(step, 2).unwrap(), set_at, &rec);
    assert_eq!(recorded(set_at, &rec), want);
    let edges = rising(&rec);
    println!(
        "travel 0.5 µm over {:.3} → {:.3} µm: {} pulses, each where the core's rule puts it",
        real(rec[0].x_sensor),
        real(rec[rec.len() - 1].x_sensor),
        edges.len()
    );
    // 10 µm in 0.5 µm steps (the sensor's noise may add a pulse back and
    // forth where the stage rests on a boundary).
    assert!((19..=21).contains(&edges.len()), "{edges:?}");

    // Window: high on exactly the ticks whose reading lies in 14–16 µm.
    let levels = Levels {
        low_um: Some(14.0),
        high_um: Some(16.0),
        ..Levels::default()
    };
    let (s, set_at, rec) = moved(&mut c, TriggerMode::Window, &levels, 10.0);
    assert_eq!((s.low_nm, s.high_nm, s.step_nm), (14_000, 16_000, 500));
    let inside = |s: &Sample| (14.0..=16.0).contains(&real(s.x_sensor));
    let want: Vec<(u32, bool)> = rec
        .iter()
        .filter(|s| s.tick >= set_at)
        .map(|s| (s.tick, inside(s)))
        .collect();
    let highs = want.iter().filter(|(_, h)| *h).count();
    println!(
        "window 14–16 µm on a 20 → 10 µm move: high {highs} of {} ticks, each where the reading is inside",
        want.len()
    );
    assert_eq!(recorded(set_at, &rec), want);
    assert!(highs > 100, "{highs}");

    // Off: low throughout.
    let (_, _, rec) = moved(&mut c, TriggerMode::Off, &Levels::default(), 15.0);
    assert!(rec.iter().all(|s| !high(s)));
}

#[test]
fn a_stream_pulses_at_each_point_and_bad_levels_are_refused_by_name() {
    let (_e, mut c) = board("trigger on points");
    Follow::new(&mut c, 0).rest_at(10.0, "the start").unwrap();
    let (_, s) = trigger::set(
        &mut c,
        TriggerMode::Point,
        &Levels {
            pulse_ticks: Some(3),
            ..Levels::default()
        },
    )
    .unwrap();
    assert_eq!(s.mode, TriggerMode::Point);
    let points: Vec<f64> = (0..40).map(|k| 10.0 + 0.05 * k as f64).collect();
    let mut samples = Vec::new();
    c.ack(&fpi_protocol::Command::Record {
        axis: 0,
        decimation: 1,
        signals: SIGNALS,
    })
    .unwrap();
    let report = c
        .stream(
            &points,
            20,
            |_| {},
            |c| {
                samples.extend(c.drain()?.0);
                Ok(())
            },
        )
        .unwrap();
    c.ack(&fpi_protocol::Command::RecordStop).unwrap();
    samples.extend(c.drain().unwrap().0);
    let edges = rising(&samples);
    println!(
        "a stream of {} points: {} pulses ({report:?})",
        points.len(),
        edges.len()
    );
    // Not armed: it started when ordered. One pulse per point taken, the
    // first included, 20 ticks apart.
    assert!(!report.armed, "{report:?}");
    assert_eq!(edges.len(), points.len(), "{edges:?}");
    assert!(edges
        .windows(2)
        .all(|w| samples[w[1]].tick - samples[w[0]].tick == 20));

    // Levels the board cannot hold are refused, naming the argument.
    let mut bad = |l: Levels, mode: TriggerMode| {
        let e = trigger::set(&mut c, mode, &l).unwrap_err();
        format!("{e:#}")
    };
    let e = bad(
        Levels {
            step_um: Some(0.0),
            ..Levels::default()
        },
        TriggerMode::Travel,
    );
    assert!(e.contains("--step-um 0: above 0 µm"), "{e}");
    let e = bad(
        Levels {
            low_um: Some(5.0),
            high_um: Some(4.0),
            ..Levels::default()
        },
        TriggerMode::Window,
    );
    assert!(
        e.contains("low edge must not lie above its high edge"),
        "{e}"
    );
    let e = format!("{:#}", trigger::mode("sometimes").unwrap_err());
    assert!(e.contains("off, travel, on_target, window or point"), "{e}");
    // What was refused changed nothing.
    assert_eq!(trigger::settings(&mut c).unwrap(), s);
}

#[test]
fn the_trigger_input_starts_an_armed_wave_and_recording_on_its_edge() {
    use fpi_protocol::{BenchOrder, Command, Shape, SourceKind, TriggerStart};
    let (_e, mut c) = board("trigger input");
    Follow::new(&mut c, 0).rest_at(20.0, "the start").unwrap();
    trigger::set_input(&mut c, TriggerStart::Both).unwrap();
    assert_eq!(
        c.setting("/stage/0/trigger_in").unwrap(),
        "\"both\"",
        "the setting says it"
    );
    // Armed: a recording and a 100 Hz wave (2 cycles) are ordered, and neither
    // starts while the input stays low.
    c.ack(&Command::Record {
        axis: 0,
        decimation: 1,
        signals: signal::X_REF | signal::TRIGGER,
    })
    .unwrap();
    let ordered = c.wave(Shape::Sine, 1.0, 20.0, 100.0, 2).unwrap();
    // (The follower reads the recorder while it waits: what it read is in
    // its recording.)
    let mut f = Follow::new(&mut c, signal::X_REF | signal::TRIGGER);
    let later = ordered + f.ticks(0.01);
    f.until_tick(later).unwrap();
    let st = f.c.status().unwrap();
    assert_eq!(st.source, SourceKind::Hold, "the wave waits: {st:?}");
    f.drain().unwrap();
    assert!(
        f.rec.samples.is_empty(),
        "the recording waits: {} samples",
        f.rec.samples.len()
    );

    // A 5-tick pulse on the input: both start on its rising edge's tick.
    let edge = f.c.bench(BenchOrder::TriggerIn(5)).unwrap();
    let end = edge + f.ticks(0.025);
    f.until_tick(end).unwrap();
    assert_eq!(
        f.c.status().unwrap().source,
        SourceKind::Hold,
        "two cycles ran"
    );
    f.c.ack(&Command::RecordStop).unwrap();
    f.drain().unwrap();
    assert_eq!(f.rec.dropped, 0);
    let rec = std::mem::take(&mut f.rec.samples);
    let first = rec[0];
    let input_high: Vec<u32> = rec
        .iter()
        .filter(|s| s.lines & lines::TRIGGER_IN != 0)
        .map(|s| s.tick)
        .collect();
    let moved = rec
        .iter()
        .find(|s| (real(s.x_ref) - 20.0).abs() > 1e-3)
        .map(|s| s.tick);
    let peak = rec.iter().map(|s| real(s.x_ref)).fold(f64::MIN, f64::max);
    println!(
        "armed wave and recording: the input rose at tick {edge}; the recording's first \
         sample is tick {}, the reference left 20 µm at tick {moved:?} (peak {peak:.3} µm); \
         input high at ticks {input_high:?}",
        first.tick
    );
    assert_eq!(first.tick, edge, "the recording starts on the edge's tick");
    assert_eq!(input_high, (edge..edge + 5).collect::<Vec<_>>());
    assert!(
        moved.is_some_and(|t| t > edge && t <= edge + 2),
        "{moved:?}"
    );
    assert!((peak - 21.0).abs() < 0.01, "{peak}");

    // Back to off: a wave starts at once.
    trigger::set_input(&mut c, TriggerStart::Nothing).unwrap();
    c.wave(Shape::Sine, 1.0, 20.0, 100.0, 1).unwrap();
    assert_eq!(c.status().unwrap().source, SourceKind::Wave);
    let e = format!("{:#}", trigger::starts("always").unwrap_err());
    assert!(e.contains("off, motion, recorder or both"), "{e}");
}

#[test]
fn an_armed_stream_is_played_whole_once_the_input_rises() {
    use fpi_protocol::{BenchOrder, SourceKind, TriggerStart};
    let (_e, mut c) = board("an armed stream");
    Follow::new(&mut c, 0).rest_at(10.0, "the start").unwrap();
    trigger::set_input(&mut c, TriggerStart::Motion).unwrap();
    // 40 points fit the board's queue: the client sends them all, then
    // waits for the armed stream to be played, pulsing the input (as an
    // external device would) once it sees the stream armed.
    let points: Vec<f64> = (0..40).map(|k| 10.0 + 0.05 * k as f64).collect();
    let mut edge = None;
    let report = c
        .stream(
            &points,
            20,
            |_| {},
            |c| {
                if edge.is_none() && c.status()?.armed[0] {
                    edge = Some(c.bench(BenchOrder::TriggerIn(3))?);
                }
                Ok(())
            },
        )
        .unwrap();
    let st = c.status().unwrap();
    println!("an armed stream: {report:?}, the input rose at tick {edge:?}; then {st:?}");
    let edge = edge.expect("the stream was seen armed");
    assert!(
        report.armed && edge > report.started,
        "armed at {}, started at {edge}: {report:?}",
        report.started
    );
    assert_eq!(st.source, SourceKind::Hold);
    assert!(!st.armed[0]);
    assert_eq!((report.points, report.underruns), (40, 0));
    assert!((real(st.signals[0]) - points[39]).abs() < 1e-3, "{st:?}");
}
