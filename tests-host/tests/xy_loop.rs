//! Two axes of the board's control loop in closed loop on the virtual XY stage
//! as built (`piezo_sim::axes::xy_built`: X like stage A as built, Y its own
//! flexure at 1 000 Hz, cross gains 1.5 % and 2 %, the stacks' preloads coupled
//! by 0.5 N/µm, each sensor reading 0.2 % of the other axis), scored on the
//! true outputs. Each axis's model is tuned and the decoupling measured by
//! `fpi board autotune` of every axis on the in-process board of that stage
//! (`--port virtual:usb:xy-built`; `fpi_host::board::axes::autotune`: each
//! axis tuned in turn, then each moved while the other holds, every axis
//! recorded), given the sensors' calibration (their cross-talk, 0.2 %: the
//! position sensors cannot tell it from the parasitic motion).
//!
//! The raster runs twice: on the board over its link (`fpi board raster`,
//! every axis recorded, the loops closed and warmed up as a board's scoring
//! does) and on the board's control loop driven here tick by tick (the
//! step and the floor at rest too).
//!
//! The figures of the item 5 are printed (`--nocapture`) with and
//! without the decoupling; generous bounds are asserted:
//! * a raster, X a 100 Hz triangle over 5–35 µm, Y a ramp over 5–35 µm in 20
//!   lines: X's RMS error over the central 80 % of each line in % of the span,
//!   Y's against its own reference over the same windows in % of X's span;
//! * a 10 → 20 µm step of X (`fpi board step`'s: a raised cosine of 1.5 ms):
//!   Y's peak deviation (low-passed at 2 kHz) and each axis's settling within
//!   ±0.1 µm, from the step's start.

use std::sync::{Mutex, OnceLock};

use fpi_firmware::board::capacity::Store;
use fpi_firmware::board::definition::internal::{FORCE, SETPOINT};
use fpi_firmware::control::exchange::{AxisSet, Exchange, Order, Posted, Refused};
use fpi_firmware::control::recorder::Recorder;
use fpi_firmware::control::reference::raster::Raster;
use fpi_firmware::control::reference::stream::Points;
use fpi_firmware::control::reference::wave::{Shape, Wave};
use fpi_firmware::control::reference::{step_phase_for, SourceOrder};
use fpi_firmware::control::slots::{Origin, Running, Spare};
use fpi_firmware::control::task::ControlLoop;
use fpi_firmware::control::tracking::LoopMode;
use fpi_firmware::emulation::virtual_axes;
use fpi_firmware::emulation::virtual_io::{SimAmplifier, SimAnalog, SimEnable, SimLink, SimSensor};
use fpi_host::board::client::Client;
use fpi_host::board::{autotune, axes, decoupling, raster, warm};
use fpi_host::method::tune::TuneOptions;
use piezo_fpi::decoupling::Decoupling;
use piezo_fpi::q::Micrometres;
use piezo_sim::axes::{Axes, AxesSpec, XY_COUPLING};
use piezo_sim::file::FirmwareModel;

/// The control rate, Hz.
const RATE_HZ: f64 = 20_000.0;

fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

/// The in-process board of the XY stage as built, every axis tuned and the
/// coupling measured by `fpi board autotune` (each axis left running its
/// tuned model, the decoupling set); the tuned models and the coupling.
struct Tuned {
    board: Client,
    models: [FirmwareModel; 2],
    /// The coupling measured through the board, the sensors' calibration
    /// given.
    coupling: decoupling::Measured,
}

/// The board with every axis tuned and the coupling measured by `fpi board
/// autotune` (its defaults, the sensors' calibration given), once for this
/// test binary.
fn tuned() -> &'static Mutex<Tuned> {
    static TUNED: OnceLock<Mutex<Tuned>> = OnceLock::new();
    TUNED.get_or_init(|| {
        let mut board = Client::open("virtual:usb:xy-built").unwrap();
        let fw = fpi_tests::factory_model();
        let coupling = decoupling::Settings {
            sensor_crosstalk: f64::from(XY_COUPLING.sensor_crosstalk),
            ..decoupling::Settings::default()
        };
        let a = axes::autotune(
            &mut board,
            &[fw.clone(), fw],
            &TuneOptions::default(),
            (&autotune::Settings::default(), &coupling),
            false,
            &mut |_| Ok(()),
            |_| {},
        )
        .unwrap_or_else(|e| panic!("autotune of every axis: {e:#}"));
        for (name, t) in ["x", "y"].iter().zip(&a.axes) {
            println!(
                "autotune, axis {name}: {}",
                t.tuning.summary(&TuneOptions::default())
            );
        }
        print!("{}", decoupling::table(&a.coupling));
        println!("the stage's true coupling: {XY_COUPLING:?}");
        Mutex::new(Tuned {
            board,
            models: [a.file.x, a.file.y],
            coupling: a.coupling,
        })
    })
}

/// X's and Y's tuned models.
fn models() -> [FirmwareModel; 2] {
    tuned()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .models
        .clone()
}

/// `fw` running from a store of its own.
fn running(fw: &FirmwareModel) -> Running {
    let image: &'static [u8] = leak(fw.image().unwrap());
    let mut spare = Spare::new(leak(Store::new()));
    spare.load(image).unwrap();
    spare
        .activate(image, Origin::Received)
        .unwrap_or_else(|_| panic!("the tuned model"))
}

type Loop = ControlLoop<
    SimSensor<'static>,
    SimAmplifier<'static>,
    SimEnable<'static>,
    SimAnalog<'static>,
    2,
>;

/// The board's two axes on the XY stage as built, and the stage's true
/// outputs after the last tick.
struct Xy {
    lp: Loop,
    x: Exchange<'static, 2>,
    links: [&'static SimLink; 2],
    stage: Axes<'static, 2>,
    truth: [f64; 2],
}

impl Xy {
    /// Both axes parked on their tuned models, `stage` at rest.
    fn on(mut stage: Axes<'static, 2>) -> Self {
        let links = [(); 2].map(|_| &*leak(SimLink::new(FORCE, SETPOINT)));
        virtual_axes::prime(&mut stage, &links);
        let [mx, my] = models();
        let lp = ControlLoop::new([
            (running(&mx), links[0].hardware(), links[0].analog()),
            (running(&my), links[1].hardware(), links[1].analog()),
        ]);
        let x = Exchange::new(leak(Recorder::new()), leak(Points::new()));
        Self {
            lp,
            x,
            links,
            stage,
            truth: [0.0; 2],
        }
    }

    /// One tick, then one sample of the stage; the references the loops
    /// tracked this tick and the true outputs at the instant this tick's
    /// sensors were read (the emulated board's recording pairs them so).
    fn tick(&mut self) -> ([f64; 2], [f64; 2]) {
        let read = self.truth;
        self.lp.tick(&mut self.x);
        let s = virtual_axes::step(&mut self.stage, &self.links);
        self.truth = s.map(|s| f64::from(s.x_fhps_um));
        (
            self.x.snapshot.axes.map(|a| a.now.x_ref.to_num::<f64>()),
            read,
        )
    }

    fn order(&mut self, axes: AxisSet, order: Order) -> Result<(), Refused> {
        self.x.order = Some(Posted {
            seq: 1,
            axes,
            order,
        });
        self.tick();
        self.x.applied.take().map_or(Ok(()), |a| a.result)
    }

    fn faults(&self) -> [Option<piezo_fpi::control::Fault>; 2] {
        self.x.snapshot.axes.map(|a| a.fault.map(|(f, _)| f))
    }

    /// Each axis moves slowly to its `at` µm.
    fn move_to(&mut self, at: [f64; 2]) {
        for (i, to) in at.into_iter().enumerate() {
            let to = SourceOrder::Move {
                target: Micrometres::from_num(to),
                step: Micrometres::from_num(0.002),
            };
            assert_eq!(self.order(AxisSet::one(i), Order::Source(to)), Ok(()));
        }
    }

    /// Both axes at `at` µm with their loops closed (damping, PI, preview),
    /// decoupled by `d`, settled.
    fn closed_at(d: Option<Decoupling<3>>, at: [f64; 2]) -> Self {
        Self::closed_on(as_built(), d, at)
    }

    /// [`Xy::closed_at`] on `stage`.
    fn closed_on(stage: Axes<'static, 2>, d: Option<Decoupling<3>>, at: [f64; 2]) -> Self {
        let mut r = Self::on(stage);
        if let Some(d) = d {
            assert_eq!(r.order(AxisSet::ALL, Order::Decoupling(d)), Ok(()));
        }
        r.move_to(at);
        for _ in 0..30_000 {
            r.tick();
        }
        for o in [
            Order::Damping(true),
            Order::Shaping(true),
            Order::Loop(LoopMode::Closed),
        ] {
            assert_eq!(r.order(AxisSet::ALL, o), Ok(()));
        }
        // The warm-up a board's scoring runs (`fpi_host::board::warm`): ten
        // 5 Hz sines over 5–35 µm on both axes, over which each force
        // channel learns its stage's preload map.
        let warm = Wave {
            shape: Shape::Sine,
            offset: Micrometres::from_num(20),
            amplitude: Micrometres::from_num(15),
            phase_step: Wave::phase_step_for(5_000, 20_000),
            cycles: 10,
        };
        assert_eq!(
            r.order(AxisSet::ALL, Order::Source(SourceOrder::Wave(warm))),
            Ok(())
        );
        for _ in 0..50_000 {
            r.tick();
        }
        r.move_to(at);
        for _ in 0..20_000 {
            r.tick();
        }
        assert_eq!(r.faults(), [None, None]);
        r
    }
}

/// The stage's true couplings as the board takes them.
/// The XY stage as built, at rest.
fn as_built() -> Axes<'static, 2> {
    piezo_sim::axes::xy_built(0x5EED).unwrap()
}

/// The decoupling measured through the board (`decoupling::measure`, the
/// sensors' calibration given).
fn measured_decoupling() -> Decoupling<3> {
    tuned()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .coupling
        .decoupling
}

/// A raster's figures: X's RMS error in % of its span, Y's against its own
/// reference in % of X's span, over the central 80 % of every line.
#[derive(Debug)]
struct RasterFigures {
    x_rms_pct: f64,
    y_rms_pct: f64,
    faults: [Option<piezo_fpi::control::Fault>; 2],
}

/// 20 lines of a 100 Hz triangle on X over 5–35 µm (100 ticks a line), Y a
/// ramp over 5–35 µm, decoupled by `d`.
fn raster(d: Option<Decoupling<3>>) -> RasterFigures {
    raster_on(as_built(), d)
}

/// [`raster`] on `stage`.
fn raster_on(stage: Axes<'static, 2>, d: Option<Decoupling<3>>) -> RasterFigures {
    let mut r = Xy::closed_on(stage, d, [5.0, 5.0]);
    let span = (Micrometres::from_num(5), Micrometres::from_num(35));
    let (ticks, lines) = (100u16, 20u16);
    let raster = Raster::new((0, span), (1, span), ticks, lines, false).unwrap();
    assert_eq!(r.order(AxisSet::ALL, Order::Raster(raster)), Ok(()));
    let mut log = Vec::new();
    for _ in 0..(2000 + usize::from(ticks) * usize::from(lines)) {
        log.push(r.tick());
    }
    let faults = r.faults();
    let go = log
        .windows(2)
        .position(|w| w[0].0 == [5.0, 5.0] && w[1].0 != [5.0, 5.0])
        .expect("the lines start");
    let t = usize::from(ticks);
    let (mut ex, mut ey, mut n) = (0.0, 0.0, 0.0);
    for line in 0..usize::from(lines) {
        let start = go + 1 + line * t;
        for (refs, truth) in &log[start + t / 10..start + t * 9 / 10] {
            ex += (truth[0] - refs[0]).powi(2);
            ey += (truth[1] - refs[1]).powi(2);
            n += 1.0;
        }
    }
    RasterFigures {
        x_rms_pct: (ex / n).sqrt() / 30.0 * 100.0,
        y_rms_pct: (ey / n).sqrt() / 30.0 * 100.0,
        faults,
    }
}

/// A step's figures: Y's peak deviation from where it rested (its true
/// output low-passed at 2 kHz), µm; each axis's settling within ±0.1 µm of
/// its target, ms.
#[derive(Debug)]
struct StepFigures {
    y_peak_um: f64,
    settle_ms: [f64; 2],
}

/// X steps 10 → 20 µm while Y holds 10 µm, decoupled by `d`: the step of
/// `fpi board step` (a raised cosine of 1.5 ms, settling counted from its
/// start).
fn step(d: Option<Decoupling<3>>) -> StepFigures {
    let mut r = Xy::closed_at(d, [10.0, 10.0]);
    let rest = r.truth;
    let to = SourceOrder::Step {
        target: Micrometres::from_num(20),
        phase_step: step_phase_for((1.5e-3 * RATE_HZ) as u32),
    };
    assert_eq!(r.order(AxisSet::one(0), Order::Source(to)), Ok(()));
    // A first-order low pass at 2 kHz.
    let a = 1.0 - (-2.0 * std::f64::consts::PI * 2000.0 / RATE_HZ).exp();
    let (mut y_lp, mut y_peak) = (rest[1], 0.0f64);
    let mut outside = [0usize; 2];
    let target = [20.0, 10.0];
    for tick in 1..=400 {
        r.tick();
        y_lp += a * (r.truth[1] - y_lp);
        y_peak = y_peak.max((y_lp - rest[1]).abs());
        for i in 0..2 {
            if (r.truth[i] - target[i]).abs() > 0.1 {
                outside[i] = tick;
            }
        }
    }
    assert_eq!(r.faults(), [None, None]);
    StepFigures {
        y_peak_um: y_peak,
        settle_ms: outside.map(|t| t as f64 / RATE_HZ * 1000.0),
    }
}

/// Each axis's RMS error holding 20 µm (both axes still, decoupled), in %
/// of 30 µm: the floor the stage's sensor noise leaves under the raster's
/// figures.
fn holding() -> [f64; 2] {
    let mut r = Xy::closed_at(Some(measured_decoupling()), [20.0, 20.0]);
    let mut e = [0.0; 2];
    let n = 4000;
    for _ in 0..n {
        let (refs, truth) = r.tick();
        for i in 0..2 {
            e[i] += (truth[i] - refs[i]).powi(2);
        }
    }
    e.map(|e| (e / f64::from(n)).sqrt() / 30.0 * 100.0)
}

#[test]
fn a_raster_on_the_xy_stage_as_built_in_closed_loop() {
    let coupled = raster(None);
    let decoupled = raster(Some(measured_decoupling()));
    let floor = holding();
    println!("raster, closed loop, without the decoupling: {coupled:.3?}");
    println!("raster, closed loop, decoupled: {decoupled:.3?}");
    println!(
        "holding 20 µm, decoupled: X {:.3} %, Y {:.3} % RMS of 30 µm",
        floor[0], floor[1]
    );
    println!("target: X ≤ 0.2 %, Y ≤ 0.1 % of X's span");
    // Without the decoupling X's sweep drags Y by 1.5 % at 100 Hz, which
    // Y's loop watch takes for an oscillation: it parks both axes. With it,
    // the raster runs: generous bounds around the figures.
    assert_eq!(decoupled.faults, [None, None], "{decoupled:?}");
    assert!(decoupled.x_rms_pct < 0.5, "{decoupled:?}");
    assert!(decoupled.y_rms_pct < 0.3, "{decoupled:?}");
}

#[test]
fn a_step_of_x_on_the_xy_stage_as_built_in_closed_loop() {
    let coupled = step(None);
    let decoupled = step(Some(measured_decoupling()));
    println!("10 → 20 µm step of X, closed loop, without the decoupling: {coupled:.3?}");
    println!("10 → 20 µm step of X, closed loop, decoupled: {decoupled:.3?}");
    println!("target: Y ≤ 0.1 µm, each axis settled within ±0.1 µm in ≤ 3 ms");
    assert!(decoupled.y_peak_um < 0.15, "{decoupled:?}");
    assert!(
        decoupled.y_peak_um < coupled.y_peak_um,
        "{decoupled:?} {coupled:?}"
    );
    assert!(
        decoupled.settle_ms[0] < 6.0 && decoupled.settle_ms[1] < 6.0,
        "{decoupled:?}"
    );
}

/// The raster `fpi board raster --fast x --slow y --freq-hz 100 --lines 20
/// --from-um 5 --to-um 35` on the tuned board over its link, decoupled by
/// `d` (set with every axis parked), the loops closed and warmed up axis by
/// axis; its figures, or the fault that parked it.
fn raster_over_the_link(d: Option<Decoupling<3>>) -> Result<raster::RasterFigures, String> {
    let mut t = tuned().lock().unwrap_or_else(|e| e.into_inner());
    let c = &mut t.board;
    c.on_axis(0).unwrap();
    c.park().unwrap();
    // A fault a raster before latched (the board parked on it).
    c.ack(&fpi_protocol::Command::ClearFault).unwrap();
    let none = Decoupling::<3> {
        input: piezo_fpi::decoupling::Matrix::IDENTITY,
        output: piezo_fpi::decoupling::Matrix::IDENTITY,
        preload: piezo_fpi::decoupling::Preload::NONE,
    };
    decoupling::set(c, &d.unwrap_or(none)).unwrap();
    for axis in [0, 1] {
        c.on_axis(axis).unwrap();
        warm::close_and_warm_up(c).unwrap_or_else(|e| panic!("axis {axis}: {e:#}"));
    }
    let spec = raster::RasterSpec {
        fast: 0,
        slow: 1,
        fast_um: (5.0, 35.0),
        slow_um: (5.0, 35.0),
        freq_hz: 100.0,
        lines: 20,
        staircase: false,
    };
    let (m, rec) = raster::run(c, &spec).unwrap();
    if let Some(f) = m.fault {
        return Err(format!("{f:#}"));
    }
    let f = raster::figures(&spec, &rec).expect("whole lines recorded");
    println!("  {}", raster::describe(&spec, &f));
    Ok(f)
}

#[test]
fn a_raster_over_the_link_of_the_tuned_xy_board() {
    let said = |r: &Result<raster::RasterFigures, String>| match r {
        Ok(f) => format!(
            "X {:.3} %, Y {:.3} % of X's span",
            f.fast_rms_pct, f.slow_rms_pct
        ),
        Err(e) => e.clone(),
    };
    let coupled = raster_over_the_link(None);
    println!(
        "fpi board raster, without the decoupling: {}",
        said(&coupled)
    );
    let decoupled = raster_over_the_link(Some(measured_decoupling()));
    println!("fpi board raster, decoupled: {}", said(&decoupled));
    println!("target: X ≤ 0.2 %, Y ≤ 0.1 % of X's span");
    let f = decoupled.expect("the decoupled raster runs without a fault");
    assert!(f.on_truth && f.missing == 0, "{f:?}");
    assert!(f.fast_rms_pct < 0.5, "{f:?}");
    assert!(f.slow_rms_pct < 0.3, "{f:?}");
}

/// The XY stage as built with its couplings times `coupling` and each
/// axis's mode times `mode`.
fn variant(coupling: f32, mode: f32) -> AxesSpec {
    let mut v = AxesSpec::base("xy-built").unwrap();
    v.coupling_scale = coupling;
    let params = v.params();
    for (o, p) in v.overrides.iter_mut().zip(params.iter()) {
        o.mode_hz = Some(p.mode_hz * mode);
    }
    v
}

/// The tuning made on the XY stage as built (each axis's model, the
/// decoupling of its true couplings) on variants of the stage: its couplings
/// halved and doubled, both modes 20 % lower and higher. The target
/// (no fault, X ≤ 0.3 %, Y ≤ 0.2 %) is printed against the figures; it is
/// not met yet.
#[test]
fn the_tuning_on_the_stage_as_built_holds_on_its_variants() {
    let variants = [
        ("couplings ×0.5", variant(0.5, 1.0)),
        ("couplings ×2", variant(2.0, 1.0)),
        ("modes −20 %", variant(1.0, 0.8)),
        ("modes +20 %", variant(1.0, 1.2)),
    ];
    let mut all = Vec::new();
    for (name, v) in variants {
        let f = raster_on(v.build(0x5EED).unwrap(), Some(measured_decoupling()));
        println!(
            "raster on the variant {name}, tuned and decoupled as built: X {:.3} %, Y {:.3} % of \
             X's span, faults {:?}",
            f.x_rms_pct, f.y_rms_pct, f.faults
        );
        all.push((name, f));
    }
    println!("target: no fault, X ≤ 0.3 %, Y ≤ 0.2 %");
    // Not met yet (the figures above): what is asserted is what holds, that
    // the board stays safe. A variant either runs with its error bounded, or
    // a loop watch parks the board (the couplings' residual, 0.75 % or 1.5 %
    // of X's output in Y, is a forced swing Y's watch takes for an
    // oscillation).
    use piezo_fpi::control::Fault;
    for (name, f) in all {
        let parked = f.faults.contains(&Some(Fault::Oscillation))
            && f.faults
                .iter()
                .all(|x| matches!(x, Some(Fault::Oscillation | Fault::Stopped)));
        let ran = f.faults == [None, None] && f.x_rms_pct < 2.5 && f.y_rms_pct < 0.5;
        assert!(parked || ran, "{name}: {f:?}");
    }
}

/// The coupling measured through the board (`fpi board autotune` of every
/// axis: drive each axis, measure all) against the stage's true coupling.
#[test]
fn the_coupling_measured_through_the_board_is_the_stages() {
    let m = tuned()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .coupling
        .clone();
    let truth = XY_COUPLING;
    for (i, j) in [(0, 1), (1, 0)] {
        let seen = truth.cross_um_per_um[i][j] + truth.sensor_crosstalk;
        println!(
            "axis {i} per µm of axis {j}: sensors see {:.4} % (true {:.4} %), parasitic {:.4} % \
             (true {:.4} %), preload {:.4} N/µm (true {:.4})",
            m.seen[i][j] * 100.0,
            f64::from(seen) * 100.0,
            m.coupling.parasitic[i][j] * 100.0,
            f64::from(truth.cross_um_per_um[i][j]) * 100.0,
            m.coupling.preload_n_per_um[i][j],
            truth.preload_n_per_um[i][j]
        );
        // The parasitic motion within 0.2 % of the axis's motion; the preload
        // coupling per µm of the extension the board estimates (its model's
        // gain, 4 % low here, included) within 0.1 N/µm.
        let parasitic = f64::from(truth.cross_um_per_um[i][j]);
        assert!(
            (m.coupling.parasitic[i][j] - parasitic).abs() < 0.002,
            "{m:?}"
        );
        let preload = f64::from(truth.preload_n_per_um[i][j]);
        assert!(
            (m.coupling.preload_n_per_um[i][j] - preload).abs() < 0.1,
            "{m:?}"
        );
    }
}
