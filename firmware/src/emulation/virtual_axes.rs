//! A virtual stage of several axes (`piezo_sim::axes`: each axis its stack,
//! mode and sensors, the flexure's couplings between them) behind one virtual
//! I/O link per axis: what each link's sensors read at rest, and one sample
//! of the stage after each control tick with the amplifiers' outputs.
//!
//! The firmware's multi-axis tests and the host's closed-loop XY measurements
//! drive the control loop's axes through it, and [`VirtualAxes`] is the
//! emulated board of several axes: that stage, the control loop and the link
//! handler in one thread, as [`super::virtual_bench::Virtual`] is for one
//! axis.

use embedded_storage::nor_flash::NorFlash;
use heapless::Vec;
use piezo_fpi::decoupling::Decoupling;
use piezo_fpi::q::Micrometres;
use piezo_sim::axes::{Axes, AxisSample, Coupling, MAX_AXES};

use crate::board::capacity::{Store, IMAGE_BYTES};
use crate::board::factory_model::MODEL_IMAGE;
use crate::board::storage::ModelFlash;
use crate::control::exchange::{Applied, Exchange, Order, Posted, Refused};
use crate::control::slots::Spare;
use crate::control::task::ControlLoop;
use crate::emulation::virtual_io::{SimAmplifier, SimAnalog, SimEnable, SimLink, SimSensor};
use crate::link::handler::{Board, Handler};
use crate::link::protocol::{BoardKind, ResetReason};

/// Leaves the stage's readings at rest on `links` (axis `i` on `links[i]`).
pub fn prime<const N: usize>(stage: &mut Axes<'_, N>, links: &[&SimLink; N]) {
    for (i, link) in links.iter().enumerate() {
        let rest = stage.stages()[i].rest_force();
        link.set_force(stage.sense_force(i, rest));
        link.set_position(stage.sense_position(i));
    }
}

/// One sample of the stage with each link's amplifier output (0 V where its
/// amplifier is off); each link's sensors then read it. Each axis's sample.
pub fn step<const N: usize>(stage: &mut Axes<'_, N>, links: &[&SimLink; N]) -> [AxisSample; N] {
    let u = links.map(|l| match l.output() {
        (v, true) => v,
        (_, false) => 0.0,
    });
    let s = stage.step(u);
    for (i, link) in links.iter().enumerate() {
        link.set_force(stage.sense_force(i, s[i].stack.force_n));
        link.set_position(stage.sense_position(i));
    }
    s
}

/// A stage's true couplings as the board takes them (`Order::Decoupling`):
/// the input matrix undoing its sensors' cross-talk among its first `n`
/// axes, the output matrix undoing its cross gains, its stacks' preload
/// coupling. What a measurement of the coupling would find; `None` where the
/// board would refuse an entry.
pub fn true_decoupling(c: &Coupling, n: usize) -> Option<Decoupling<MAX_AXES>> {
    let as64 = |m: [[f32; MAX_AXES]; MAX_AXES]| m.map(|r| r.map(f64::from));
    Decoupling::of_coupling(
        f64::from(c.sensor_crosstalk),
        as64(c.cross_um_per_um),
        as64(c.preload_n_per_um),
        n,
    )
    .ok()
}

/// One period of an emulated board of `N` axes: a bench order refused
/// ([`Refused::BenchOfAxes`]), the control tick, the stage's step on
/// `links`, the recorder (the recorded axis or every axis, with the true
/// positions). `x_true` holds each axis's true output at the instant this
/// tick's sensors read it (the last step's), µm.
pub fn tick<const N: usize>(
    control: &mut AxesLoop<N>,
    stage: &mut Axes<'_, N>,
    links: &[&SimLink; N],
    x_true: &mut [Micrometres; N],
    x: &mut Exchange<'_, N>,
) {
    if let Some(Posted {
        seq,
        order: Order::Bench(_),
        ..
    }) = x.order
    {
        x.order = None;
        x.applied = Some(Applied {
            seq,
            tick: control.next_tick(),
            result: Err(Refused::BenchOfAxes),
        });
    }
    let seen = x_true.map(Some);
    control.tick(x);
    let s = step(stage, links);
    *x_true = s.map(|a| Micrometres::from_num(a.x_fhps_um));
    control.record_axes(x, &seen);
}

/// The control loop of an emulated board of `N` axes (axis `i`'s I/O is
/// its own [`SimLink`]).
pub type AxesLoop<const N: usize> = ControlLoop<
    SimSensor<'static>,
    SimAmplifier<'static>,
    SimEnable<'static>,
    SimAnalog<'static>,
    N,
>;

/// The emulated board of `N` axes in one thread: the control loop, the
/// stage of several axes and the exchange, advanced one tick whenever the
/// link handler waits.
///
/// Its recorder records the axis the last record order named, or every
/// axis (with the true positions). It takes
/// no bench order but its link's pace ([`Refused::BenchOfAxes`]).
pub struct VirtualAxes<const N: usize> {
    /// Each axis's virtual analog world.
    pub links: [&'static SimLink; N],
    /// The control loop.
    pub control: AxesLoop<N>,
    /// The virtual stage.
    pub stage: Axes<'static, N>,
    /// What the loop shares with the link handler.
    pub exchange: Exchange<'static, N>,
    /// Each axis's true output at the instant this tick's sensors are read
    /// (the last step's), µm.
    x_true: [Micrometres; N],
}

impl<const N: usize> VirtualAxes<N> {
    /// Boots the board as the emulated board boots: each axis's model (the
    /// first axis's stored in `flash`, else the factory model), a parked
    /// loop, `stage` at rest. The handler that serves its link comes with
    /// it; `None` if the factory model does not load.
    pub fn boot<F: NorFlash>(
        links: [&'static SimLink; N],
        stores: [&'static mut Store; N],
        spare: &'static mut Store,
        image: &'static mut [u8; IMAGE_BYTES],
        exchange: Exchange<'static, N>,
        flash: ModelFlash<F>,
        mut stage: Axes<'static, N>,
    ) -> Option<(Self, Handler<F, N>)> {
        let mut stores = stores.into_iter().map(Spare::new);
        let (mut handler, first) = Handler::boot(
            BoardKind::Emulated,
            stores.next()?,
            Spare::new(spare),
            image,
            flash,
            MODEL_IMAGE,
            ResetReason::PowerOn,
        )?;
        prime(&mut stage, &links);
        let mut running: Vec<_, N> = Vec::new();
        running.push(first).ok()?;
        for (i, store) in stores.enumerate() {
            running
                .push(handler.boot_axis(i + 1, store, MODEL_IMAGE)?)
                .ok()?;
        }
        let mut running = running.into_iter();
        let axes: Vec<_, N> = links
            .iter()
            .filter_map(|l| Some((running.next()?, l.hardware(), l.analog())))
            .collect();
        let control = ControlLoop::new(axes.into_array().ok()?);
        Some((
            Self {
                links,
                control,
                stage,
                exchange,
                x_true: [Micrometres::ZERO; N],
            },
            handler,
        ))
    }

    /// One period ([`tick`]).
    pub fn tick(&mut self) {
        tick(
            &mut self.control,
            &mut self.stage,
            &self.links,
            &mut self.x_true,
            &mut self.exchange,
        );
    }

    /// Each axis's true output now, µm (where this tick's sensors read it).
    pub const fn true_positions(&self) -> &[Micrometres; N] {
        &self.x_true
    }
}

impl<const N: usize> crate::emulation::Emulated<N> for VirtualAxes<N> {
    fn period(&mut self) {
        self.tick();
    }
    fn next_tick(&self) -> u32 {
        self.control.next_tick()
    }
}

impl<const N: usize> Board<N> for VirtualAxes<N> {
    fn exchange<T>(&mut self, f: impl FnOnce(&mut Exchange<'_, N>) -> T) -> T {
        f(&mut self.exchange)
    }
    fn wait(&mut self) {
        self.tick();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
    use crate::control::recorder::Recorder;
    use crate::control::reference::stream::Points;
    use crate::emulation::link_host::{leak, um, Host};
    use crate::emulation::virtual_bench::{EmulatedFlash, BROKEN_WIRE_N, FLASH_SLOTS};
    use crate::link::protocol::{Command, RasterOrder, Refusal, Reply};
    use piezo_fpi::control::Fault;
    use piezo_sim::axes::AxesSpec;

    /// The emulated board of the XY stage as built, booted.
    fn xy() -> Host<VirtualAxes<2>, 2> {
        let stage = AxesSpec::base("xy-built").unwrap().build(0x5EED).unwrap();
        let (board, handler) = VirtualAxes::boot(
            [(); 2].map(|_| &*leak(SimLink::new(FORCE_ADC, SETPOINT_DAC))),
            [(); 2].map(|_| leak(Store::new())),
            leak(Store::new()),
            leak([0; IMAGE_BYTES]),
            Exchange::new(leak(Recorder::new()), leak(Points::new())),
            ModelFlash::new(EmulatedFlash::new(), FLASH_SLOTS),
            stage,
        )
        .unwrap();
        Host::new(board, handler)
    }

    fn move_y(h: &mut Host<VirtualAxes<2>, 2>, to: f64) -> u32 {
        h.ack(Command::Move {
            axis: 1,
            target: um(to),
            speed: um(1000.0),
        })
    }

    #[test]
    fn each_axis_is_addressed_by_its_number_and_an_axis_the_board_lacks_is_refused_by_name() {
        let mut h = xy();
        h.run(10);
        match h.send(Command::Hello) {
            Reply::Hello(hello) => assert_eq!(hello.axes, 2),
            r => panic!("{r:?}"),
        }
        match h.send(Command::Status { axis: 2 }) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::Axis);
                assert!(
                    reason.contains("axis z") && reason.contains("(x, y)"),
                    "{reason}"
                );
            }
            r => panic!("{r:?}"),
        }
        // Y moves; X stays parked where it rests (the flexure drags it a
        // little: 1.5 % of Y's output is X's parasitic motion).
        move_y(&mut h, 10.0);
        h.run(2_000);
        let (x, y) = (h.status_of(0), h.status_of(1));
        assert_eq!(y.axis, 1);
        assert_eq!(y.fault, None, "Y armed by its move");
        assert_eq!(y.signals[0], um(10.0));
        // Open loop, the factory model on the stage as built: within 0.6 µm.
        assert!((y.signals[4] - um(10.0)).abs() < um(0.6), "{y:?}");
        assert_eq!(x.fault.map(|f| f.code), Some(Fault::Stopped as u8));
        assert_eq!(x.signals[0], 0, "X's reference untouched");
        let x_true = h.board.true_positions()[0].to_num::<f64>();
        assert!((0.1..0.3).contains(&x_true), "X dragged by Y: {x_true} µm");
    }

    #[test]
    fn each_axis_runs_its_own_model_and_the_flash_keeps_the_first_axis_s() {
        let mut h = xy();
        h.run(10);
        assert!(matches!(h.upload(1, MODEL_IMAGE, false), Reply::Ack));
        let origin =
            |h: &mut Host<VirtualAxes<2>, 2>, axis| match h.send(Command::ModelInfo { axis }) {
                Reply::Model(m) => m.origin,
                r => panic!("{r:?}"),
            };
        use crate::link::protocol::Origin as O;
        assert_eq!(origin(&mut h, 1), O::Received);
        assert_eq!(origin(&mut h, 0), O::Factory, "X's model unchanged");
        // Read back: Y's image, which the link's buffer still holds.
        match h.send(Command::ModelRead { axis: 1, offset: 0 }) {
            Reply::ModelBytes { total, .. } => assert_eq!(total as usize, MODEL_IMAGE.len()),
            r => panic!("{r:?}"),
        }
        match h.upload(1, MODEL_IMAGE, true) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::Storage);
                assert!(reason.contains("axis y"), "{reason}");
            }
            r => panic!("{r:?}"),
        }
        assert!(matches!(h.upload(0, MODEL_IMAGE, true), Reply::Ack));
        assert!(matches!(h.send(Command::ModelInfo { axis: 0 }),
            Reply::Model(m) if m.stored.is_some()));
    }

    #[test]
    fn a_fault_on_one_axis_parks_both_and_the_status_names_it() {
        let mut h = xy();
        h.run(10);
        h.ack(Command::Move {
            axis: 0,
            target: um(10.0),
            speed: um(1000.0),
        });
        move_y(&mut h, 5.0);
        h.run(500);
        assert_eq!(h.status_of(0).fault, None);
        // Y's force sensor's wire breaks.
        for _ in 0..200 {
            h.board.tick();
            h.board.links[1].set_force(BROKEN_WIRE_N);
        }
        let park = piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150));
        h.run(park + 2);
        let (x, y) = (h.status_of(0), h.status_of(1));
        assert_eq!(y.fault.map(|f| f.code), Some(Fault::ForceOutOfRange as u8));
        assert_eq!(x.fault.map(|f| f.code), Some(Fault::Stopped as u8), "{x:?}");
        for s in [x, y] {
            assert_eq!(s.fault_axis, Some(1), "{s:?}");
            assert!(!s.amplifier_on);
        }
    }

    #[test]
    fn the_recorder_records_the_axis_its_order_names() {
        let mut h = xy();
        h.run(10);
        move_y(&mut h, 8.0);
        h.run(2_000);
        h.ack(Command::Record {
            axis: 1,
            decimation: 1,
            signals: crate::control::recorder::signal::ALL,
        });
        h.run(10);
        let first = h.board.exchange.recorder.take().unwrap();
        assert_eq!(first.x_ref, um(8.0), "Y's reference, not X's 0");
        let x_true = h.board.true_positions()[1].to_bits();
        assert!(
            (first.x_true - x_true).abs() < um(0.05),
            "Y's true position"
        );
        // A bench order is refused by name on a board of several axes.
        match h.send(Command::Bench(
            crate::link::protocol::BenchOrder::SensorOpen(true),
        )) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::NotEmulated);
                assert!(reason.contains("several axes"), "{reason}");
            }
            r => panic!("{r:?}"),
        }
    }

    fn raster(fast: u8, slow: u8, from: f64, to: f64) -> Command<'static> {
        Command::Raster(RasterOrder {
            fast,
            slow,
            fast_span: [um(from), um(to)],
            slow_span: [um(from), um(to)],
            freq_mhz: 100_000,
            lines: 4,
            staircase: false,
        })
    }

    #[test]
    fn a_raster_over_the_link_is_checked_then_runs_its_lines_on_both_axes() {
        let mut h = xy();
        h.run(10);
        let reason = |r: Reply| match r {
            Reply::Refused { reason, .. } => reason.to_string(),
            r => panic!("{r:?}"),
        };
        assert!(reason(h.send(raster(0, 0, 5.0, 35.0))).contains("two"));
        assert!(reason(h.send(raster(0, 2, 5.0, 35.0))).contains("axis z"));
        let r = reason(h.send(raster(0, 1, 5.0, 45.0)));
        assert!(r.contains("fast axis's end") && r.contains("45.000"), "{r}");
        h.ack(Command::Record {
            axis: crate::link::protocol::EVERY_AXIS,
            decimation: 1,
            signals: crate::control::recorder::signal::ALL,
        });
        h.ack(raster(0, 1, 5.0, 35.0));
        // The approach (5 µm at 1 mm/s: 100 ticks), then 4 lines of 100
        // (the governor takes the references within what the stage can
        // follow), then the hold.
        h.run(2_000);
        let (x, y) = (h.status_of(0), h.status_of(1));
        assert_eq!((x.fault, y.fault), (None, None));
        assert_eq!(x.signals[0], um(5.0), "4 lines: X back at its start");
        assert_eq!(y.signals[0], um(35.0), "Y ramped to its end");
        // Every axis recorded: two samples a tick, X's then Y's.
        let (a, b) = (
            h.board.exchange.recorder.take().unwrap(),
            h.board.exchange.recorder.take().unwrap(),
        );
        assert_eq!(a.tick, b.tick);
    }

    #[test]
    fn a_decoupling_is_taken_parked_and_its_entries_are_checked() {
        let mut h = xy();
        h.run(10);
        let identity = |k: i32| {
            let mut m = [[0; 3]; 3];
            for (i, row) in m.iter_mut().enumerate() {
                row[i] = k;
            }
            m
        };
        let one = 1 << 30;
        let mut output = identity(one);
        output[1][0] = -(one / 66); // −1.5 %
        let ok = Command::Decoupling {
            input: identity(one),
            output,
            preload: [[0; 3]; 3],
        };
        move_y(&mut h, 5.0);
        assert_eq!(h.refused(ok.clone()), Refusal::NotAtRest);
        h.ack(Command::Safe);
        h.run(piezo_fpi::limits::park_ticks(piezo_fpi::q::Volts::const_from_int(150)) + 2);
        h.ack(ok);
        let mut far = identity(one);
        far[0][1] = one / 5; // 20 %
        match h.send(Command::Decoupling {
            input: identity(one),
            output: far,
            preload: [[0; 3]; 3],
        }) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::BadArgument);
                assert!(
                    reason.contains("output matrix [x][y] = 200/1000"),
                    "{reason}"
                );
            }
            r => panic!("{r:?}"),
        }
        let mut z = identity(one);
        z[2][0] = one / 100;
        assert_eq!(
            h.refused(Command::Decoupling {
                input: identity(one),
                output: z,
                preload: [[0; 3]; 3],
            }),
            Refusal::Axis
        );
    }

    #[test]
    fn a_move_of_several_axes_starts_on_one_tick_or_not_at_all() {
        let mut h = xy();
        h.run(10);
        let moves = |x: f64, y: f64, mask: u8| Command::MoveAxes {
            mask,
            targets: [um(x), um(y), 0],
            speed: um(1000.0),
        };
        match h.send(moves(10.0, 45.0, 0b011)) {
            Reply::Refused { code, reason } => {
                assert_eq!(code, Refusal::OutOfRange);
                assert!(reason.contains("y's target"), "{reason}");
            }
            r => panic!("{r:?}"),
        }
        assert_eq!(h.refused(moves(10.0, 20.0, 0b111)), Refusal::Axis);
        assert_eq!(
            h.status_of(0).fault.map(|f| f.code),
            Some(Fault::Stopped as u8)
        );
        h.ack(moves(10.0, 20.0, 0b011));
        h.run(1);
        let (x, y) = (h.status_of(0), h.status_of(1));
        assert_eq!((x.fault, y.fault), (None, None), "both armed on one tick");
        use crate::link::protocol::SourceKind;
        assert!(
            x.source == SourceKind::Move && y.source == SourceKind::Move,
            "both moving from one tick: {x:?} {y:?}"
        );
        h.run(1_000);
        assert_eq!(h.status_of(0).signals[0], um(10.0));
        assert_eq!(h.status_of(1).signals[0], um(20.0));
    }
}
