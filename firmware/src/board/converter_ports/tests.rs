//! The control loop on the precision front end's ports, its converters answering
//! at once: a stalled ADC and a failing DAC latch `Fault::Converter`, and the
//! output parks.

use super::*;
use crate::board::capacity::Store;
use crate::board::definition::precision::{DAC, FRONT_END};
use crate::board::factory_model::MODEL_IMAGE;
use crate::control::exchange::{Exchange, Order, Posted};
use crate::control::recorder::Recorder;
use crate::control::reference::stream::Points;
use crate::control::reference::SourceOrder;
use crate::control::slots::{Origin, Spare};
use crate::control::task::ControlLoop;
use crate::converters::ad579x::Ad579x;
use crate::converters::ad7606::Ad7606;
use crate::converters::bench::Canned;
use core::convert::Infallible;
use embedded_hal::digital::OutputPin;
use embedded_hal::{digital, spi};
use piezo_fpi::io::Hardware;
use std::cell::Cell;
use std::rc::Rc;

/// A line the test sets (BUSY) or reads (the amplifier's enable).
#[derive(Clone, Default)]
struct Line(Rc<Cell<bool>>);

impl digital::ErrorType for Line {
    type Error = Infallible;
}

impl InputPin for Line {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.0.get())
    }
    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(!self.0.get())
    }
}

impl OutputPin for Line {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.0.set(false);
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        self.0.set(true);
        Ok(())
    }
}

/// An SPI device that answers as [`Canned`] until the test breaks it.
#[derive(Clone)]
struct Spi(Canned, Rc<Cell<bool>>);

impl spi::ErrorType for Spi {
    type Error = spi::ErrorKind;
}

impl SpiDevice for Spi {
    fn transaction(&mut self, ops: &mut [spi::Operation<'_, u8>]) -> Result<(), Self::Error> {
        if self.1.get() {
            return Err(spi::ErrorKind::ModeFault);
        }
        let _ = self.0.transaction(ops);
        Ok(())
    }
}

/// The analog reference input at mid-scale.
struct MidScale;

impl ReferenceIn for MidScale {
    fn read_counts(&mut self) -> u16 {
        2048
    }
}

type Loop = ControlLoop<
    Force<'static, Spi, Line>,
    Amplifier<'static, Spi>,
    Line,
    Analog<'static, MidScale>,
>;

/// The loop, the exchange, the health, and the test's handles: BUSY, the ADC
/// broken, the DAC broken, the enable line.
struct Rig {
    lp: Loop,
    x: Exchange<'static>,
    health: &'static Health,
    busy: Rc<Cell<bool>>,
    dac_broken: Rc<Cell<bool>>,
    enable: Rc<Cell<bool>>,
}

fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

fn rig() -> Rig {
    let mut spare = Spare::new(leak(Store::new()));
    spare.load(MODEL_IMAGE).unwrap();
    let running = spare
        .activate(MODEL_IMAGE, Origin::Factory)
        .unwrap_or_else(|_| panic!("the factory model"));
    let health: &'static Health = leak(Health::new(0x8000));
    let (busy, enable) = (Line::default(), Line::default());
    let dac_broken = Rc::new(Cell::new(false));
    let adc = Spi(Canned::ADC, Rc::new(Cell::new(false)));
    let dac = Spi(Canned::DAC, dac_broken.clone());
    let sensing = Sensing::new(Ad7606::new(adc, busy.clone()), [0, 0]);
    let hw = Hardware {
        sensor: Force::new(sensing, &FRONT_END, health, Newtons::ZERO),
        amplifier: Amplifier::new(Driving::new(Ad579x::new(dac, DAC)), &FRONT_END, health),
        enable: enable.clone(),
    };
    let lp = ControlLoop::new([(running, hw, Analog::new(MidScale, health))]);
    let x = Exchange::new(leak(Recorder::new()), leak(Points::new()));
    Rig {
        lp,
        x,
        health,
        busy: busy.0,
        dac_broken,
        enable: enable.0,
    }
}

impl Rig {
    /// One tick as the board runs it: the loop, then the converters' health.
    fn tick(&mut self) -> Option<(Device, u8)> {
        self.lp.tick(&mut self.x);
        latch(self.health, |f| self.lp.fail(f))
    }

    fn fault(&self) -> Option<Fault> {
        self.lp.axes()[0].state().fault()
    }

    /// Armed (holding where the stage rests), then `n` good ticks.
    fn armed(mut self, n: usize) -> Self {
        self.x.order = Some(Posted::all(1, Order::Source(SourceOrder::Hold)));
        for _ in 0..n {
            assert_eq!(self.tick(), None);
        }
        assert_eq!(self.fault(), None, "armed");
        assert!(self.enable.get(), "amplifier on");
        self
    }

    /// Ticks until the amplifier is off, at most `limit`.
    fn ticks_to_park(&mut self, limit: usize) -> usize {
        (1..=limit)
            .find(|_| {
                self.tick();
                !self.enable.get()
            })
            .unwrap_or_else(|| panic!("not parked within {limit} ticks"))
    }
}

#[test]
fn the_ports_read_force_and_position_from_one_frame() {
    let mut r = rig().armed(10);
    let [t] = r.lp.tick(&mut r.x);
    // The canned frame: 60 N on V1, 20 µm on V2 (offset-binary 24 576).
    assert_eq!(t.force, Newtons::from_num(60));
    assert_eq!(t.x_sensor, piezo_fpi::q::Micrometres::from_num(20));
    assert_eq!(r.health.position(), 24_576);
}

#[test]
fn a_stalled_adc_latches_the_converter_fault_and_the_output_parks() {
    let mut r = rig().armed(20);
    r.busy.set(true);
    // Misses under the limit run on the last good sample.
    let latched = (1..=10)
        .find(|_| {
            r.tick();
            r.fault().is_some()
        })
        .unwrap();
    assert_eq!(latched as u16, FRONT_END.stale_limit, "ticks to latch");
    assert_eq!(r.fault(), Some(Fault::Converter));
    assert_eq!(
        r.health.failure(),
        Some((Device::Adc, Error::Stalled.code()))
    );
    let parked = r.ticks_to_park(4000);
    assert_eq!(
        r.lp.axes()[0].state().voltage(),
        r.lp.axes()[0].model().get().safe_voltage()
    );
    println!("stalled ADC: latched after {latched} ticks, amplifier off {parked} ticks later");
    // The converter back: the fault can be cleared, and stays cleared.
    r.busy.set(false);
    r.x.order = Some(Posted::all(2, Order::ClearFault));
    for _ in 0..5 {
        assert_eq!(r.tick(), None);
    }
    assert_eq!(
        r.fault(),
        Some(Fault::Stopped),
        "cleared into the parked state"
    );
}

#[test]
fn a_failing_dac_latches_the_converter_fault_at_once() {
    let mut r = rig().armed(20);
    r.dac_broken.set(true);
    let failure = r.tick();
    assert_eq!(failure.map(|f| f.0), Some(Device::Dac));
    assert_eq!(r.fault(), Some(Fault::Converter));
    let parked = r.ticks_to_park(4000);
    println!("failing DAC: latched in the tick it failed, amplifier off {parked} ticks later");
}
