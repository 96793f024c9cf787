//! A three-axis loop on three virtual I/O links (the stage held still: each
//! axis's force and position sensors read constants): orders address axes, a
//! motion armed on several axes starts on one tick, a fault on one axis parks
//! all of them and is named, and an order one addressed axis refuses changes
//! none.

use super::*;
use crate::board::capacity::Store;
use crate::board::definition::internal::{FORCE, SETPOINT};
use crate::board::factory_model::{CONTROLLER, MODEL_IMAGE};
use crate::control::recorder::Recorder;
use crate::control::reference::stream::Points;
use crate::control::reference::wave::{Shape, Wave};
use crate::control::slots::{Origin, Spare};
use crate::emulation::virtual_io::{SimAmplifier, SimAnalog, SimEnable, SimLink, SimSensor};
use fpi_protocol::TriggerStart;

type Three = ControlLoop<
    SimSensor<'static>,
    SimAmplifier<'static>,
    SimEnable<'static>,
    SimAnalog<'static>,
    3,
>;

fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

/// The factory model, running from a store of its own.
fn running() -> Running {
    let mut spare = Spare::new(leak(Store::new()));
    spare.load(MODEL_IMAGE).unwrap();
    spare
        .activate(MODEL_IMAGE, Origin::Factory)
        .unwrap_or_else(|_| panic!("the factory model"))
}

/// A parked three-axis loop, each axis on a link of its own, and the links.
struct Rig {
    lp: Three,
    x: Exchange<'static, 3>,
    links: [&'static SimLink; 3],
}

/// A parked three-axis loop whose sensors follow the stage each estimates
/// (force at rest: the preload).
fn three() -> Rig {
    let links = [(); 3].map(|_| &*leak(SimLink::new(FORCE, SETPOINT)));
    for link in links {
        link.set_force(CONTROLLER.preload(Micrometres::ZERO).to_num::<f32>());
        link.set_position(0.0);
    }
    let lp = ControlLoop::new(links.map(|link| (running(), link.hardware(), link.analog())));
    let x = Exchange::new(leak(Recorder::new()), leak(Points::new()));
    Rig { lp, x, links }
}

impl Rig {
    /// One tick; then each axis's sensors read what its estimate says (a
    /// stage that does as the model predicts).
    fn tick(&mut self) -> [Telemetry; 3] {
        let t = self.lp.tick(&mut self.x);
        for (axis, link) in self.lp.axes().iter().zip(self.links) {
            let f = CONTROLLER.preload(axis.state().x_pea_est());
            link.set_force(f.to_num::<f32>());
        }
        for (t, link) in t.iter().zip(self.links) {
            link.set_position(t.x_est.to_num::<f32>());
        }
        t
    }

    /// Posts `order` to `axes`, runs one tick; its outcome.
    fn order(&mut self, axes: AxisSet, order: Order) -> Result<(), Refused> {
        self.x.order = Some(Posted {
            seq: 1,
            axes,
            order,
        });
        self.tick();
        self.x.applied.take().map_or(Ok(()), |a| a.result)
    }

    fn run(&mut self, ticks: usize) {
        for _ in 0..ticks {
            self.tick();
        }
    }

    fn faults(&self) -> [Option<Fault>; 3] {
        self.x.snapshot.axes.map(|a| a.fault.map(|(f, _)| f))
    }
}

/// A ramp to `target` µm at `step` µm a tick.
fn move_to(target: f64, step: f64) -> SourceOrder {
    SourceOrder::Move {
        target: Micrometres::from_num(target),
        step: Micrometres::from_num(step),
    }
}

fn wave() -> SourceOrder {
    SourceOrder::Wave(Wave {
        shape: Shape::RaisedCosine,
        offset: Micrometres::from_num(20),
        amplitude: Micrometres::from_num(5),
        phase_step: Wave::phase_step_for(1_000, 20_000),
        cycles: 0,
    })
}

#[test]
fn a_move_on_one_axis_leaves_the_others_parked() {
    let mut r = three();
    let to = move_to(10.0, 0.01);
    assert_eq!(r.order(AxisSet::one(1), Order::Source(to)), Ok(()));
    r.run(10);
    assert_eq!(
        r.faults(),
        [Some(Fault::Stopped), None, Some(Fault::Stopped)]
    );
    assert_eq!(r.x.snapshot.axes[1].source, SourceKind::Move);
    assert!(r.x.snapshot.axes[1].now.amplifier_on());
    assert!(!r.x.snapshot.axes[0].now.amplifier_on());
}

#[test]
fn waves_armed_on_two_axes_start_on_the_trigger_edges_tick() {
    let mut r = three();
    // x and z first move to one point (on one tick: one order for both).
    let xz = AxisSet::one(0).with(2);
    let to = move_to(15.0, 0.01);
    assert_eq!(r.order(xz, Order::Source(to)), Ok(()));
    r.run(3000);
    let t = r.tick();
    assert_eq!(t[0].x_ref, Micrometres::from_num(15));
    assert_eq!(t[2].x_ref, Micrometres::from_num(15));
    let starts = Order::TriggerIn(TriggerStart::Motion);
    assert_eq!(r.order(AxisSet::ALL, starts), Ok(()));
    for i in [0, 2] {
        assert_eq!(r.order(AxisSet::one(i), Order::Source(wave())), Ok(()));
    }
    r.run(200);
    let armed = r.x.snapshot.axes.map(|a| (a.motion_armed, a.source));
    assert_eq!(armed[0], (true, SourceKind::Hold));
    assert_eq!(armed[1], (false, SourceKind::Hold), "y stays parked");
    assert_eq!(armed[2], (true, SourceKind::Hold));
    r.x.trigger_in = true;
    let edge = r.lp.next_tick();
    r.tick();
    let after = r.x.snapshot.axes.map(|a| (a.motion_armed, a.source));
    assert_eq!(
        after[0],
        (false, SourceKind::Wave),
        "x starts on tick {edge}"
    );
    assert_eq!(after[1], (false, SourceKind::Hold), "y was not armed");
    assert_eq!(
        after[2],
        (false, SourceKind::Wave),
        "z starts on the same tick"
    );
    // Both follow one phase from one point: their references agree tick by
    // tick, through the approach and the wave.
    let (mut lo, mut hi) = (Micrometres::MAX, Micrometres::MIN);
    for _ in 0..40_000 {
        let t = r.tick();
        assert_eq!(t[0].x_ref, t[2].x_ref);
        (lo, hi) = (lo.min(t[0].x_ref), hi.max(t[0].x_ref));
    }
    // The wave ran: 1 Hz, 20 ± 5 µm, over two periods.
    let (lo, hi) = (lo.to_num::<f64>(), hi.to_num::<f64>());
    assert!(lo < 15.1 && hi > 24.9, "{lo}..{hi} µm");
    assert_eq!(r.faults(), [None, Some(Fault::Stopped), None]);
}

#[test]
fn a_fault_on_one_axis_parks_every_axis_and_names_it() {
    let mut r = three();
    let hold = Order::Source(SourceOrder::Hold);
    assert_eq!(r.order(AxisSet::ALL, hold), Ok(()));
    r.run(5);
    assert_eq!(r.faults(), [None; 3]);
    // A source beyond y's window (the link task checks a move against the
    // stroke; the ISR catches what comes past it).
    let beyond = move_to(1000.0, 100.0);
    assert_eq!(r.order(AxisSet::one(1), Order::Source(beyond)), Ok(()));
    r.run(2);
    assert_eq!(
        r.faults(),
        [
            Some(Fault::Stopped),
            Some(Fault::ReferenceUnreachable),
            Some(Fault::Stopped)
        ]
    );
    assert_eq!(r.x.snapshot.fault_axis, Some(1));
    // Every output ramps to its safe voltage, the amplifiers go off.
    r.run(2000);
    assert!(r.x.snapshot.axes.iter().all(|a| a.safe_at.is_some()));
    assert!(r.x.snapshot.axes.iter().all(|a| !a.now.amplifier_on()));
    // Clearing y's fault parks it; the board's fault is gone.
    assert_eq!(r.order(AxisSet::one(1), Order::ClearFault), Ok(()));
    r.run(1);
    assert_eq!(r.faults(), [Some(Fault::Stopped); 3]);
    assert_eq!(r.x.snapshot.fault_axis, None);
    assert!(r.lp.is_parked());
}

#[test]
fn an_order_one_axis_refuses_changes_none() {
    let mut r = three();
    let hold = Order::Source(SourceOrder::Hold);
    assert_eq!(r.order(AxisSet::ALL, hold), Ok(()));
    let beyond = move_to(1000.0, 100.0);
    assert_eq!(r.order(AxisSet::one(2), Order::Source(beyond)), Ok(()));
    r.run(2000);
    // z's fault is latched: a hold for every axis is refused by name, and
    // x and y stay parked.
    let refused = r.order(AxisSet::ALL, Order::Source(SourceOrder::Hold));
    assert_eq!(refused, Err(Refused::Fault(Fault::ReferenceUnreachable)));
    r.run(1);
    assert_eq!(
        r.faults(),
        [
            Some(Fault::Stopped),
            Some(Fault::Stopped),
            Some(Fault::ReferenceUnreachable)
        ]
    );
}

#[test]
fn a_stream_a_swap_and_an_analysis_take_one_axis() {
    let mut r = three();
    let stream = Order::Source(SourceOrder::Stream { interval: 1 });
    assert_eq!(r.order(AxisSet::ALL, stream), Err(Refused::Axes));
    assert_eq!(r.order(AxisSet::ALL, Order::Swap), Err(Refused::Axes));
    let stream = Order::Source(SourceOrder::Stream { interval: 1 });
    assert_eq!(r.order(AxisSet::one(0), stream), Ok(()));
    // One stream at a time: the buffer is x's.
    let stream = Order::Source(SourceOrder::Stream { interval: 1 });
    assert_eq!(r.order(AxisSet::one(1), stream), Err(Refused::Axes));
    // A move on y leaves x's stream and its points alone.
    let to = move_to(10.0, 0.01);
    r.x.points.push(Micrometres::from_num(1));
    let queued = r.x.points.len();
    assert_eq!(r.order(AxisSet::one(1), Order::Source(to)), Ok(()));
    assert_eq!(r.x.snapshot.axes[0].source, SourceKind::Stream);
    assert_eq!(r.x.snapshot.ended_points, 0);
    assert!(queued > 0);
    // An order for an axis the board lacks addresses none.
    assert_eq!(r.order(AxisSet::one(5), Order::Safe), Err(Refused::Axes));
}
