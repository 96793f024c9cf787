//! The emulated board of several axes (QEMU `netduinoplus2`, `fpi board
//! emulate --axes 2|3`): the stage of that many axes as designed
//! (`piezo_sim::axes`, `xy` or `xyz`: each axis stage A's design, coupled
//! through the flexure) stands in for the analog world, each axis on its own
//! [`SimLink`]; the rest is the one-axis emulated board's ([`crate::qemu_board`]).
//!
//! The control task runs [`virtual_axes::tick`]: the control loop of every
//! axis, then one step of the stage. It takes no bench order but its link's
//! pace (`Refused::BenchOfAxes`).

use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
use fpi_firmware::board::storage::ModelFlash;
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::slots::Running;
use fpi_firmware::control::task::ControlLoop;
use fpi_firmware::emulation::virtual_axes::{self, AxesLoop};
use fpi_firmware::emulation::virtual_bench::SEED;
use fpi_firmware::emulation::virtual_io::SimLink;
use heapless::spsc::{Consumer, Producer};
use piezo_fpi::q::Micrometres;
use piezo_sim::axes::{Axes, AxesSpec};
use stm32f4xx_hal::pac::{self, USART1};
use stm32f4xx_hal::serial::Serial;

pub use crate::qemu_board::{
    halt, keep_link, kept_link, reset_reason, usb_connected, Flash, Usb, CORE_HZ, KIND,
};
use crate::qemu_board::{init_link, NoWatchdog};
use crate::supervisor::Supervisor;

/// The board's axes (the program's, `fpi-firmware-xy` or `-xyz`).
pub const AXES: usize = crate::AXES;

/// The stage of [`AXES`] axes as designed (`piezo_sim::axes::AxesSpec::BASES`).
const STAGE: &str = if AXES == 2 { "xy" } else { "xyz" };

/// Each axis's virtual analog world.
static LINKS: [SimLink; AXES] = [const { SimLink::new(FORCE_ADC, SETPOINT_DAC) }; AXES];

/// [`LINKS`] as the loop and the stage take them.
fn links() -> [&'static SimLink; AXES] {
    core::array::from_fn(|i| &LINKS[i])
}

/// The control task's hardware: the loop of every axis, the stage, the
/// supervisor.
pub struct TickIo {
    control: AxesLoop<AXES>,
    stage: Axes<'static, AXES>,
    /// Each axis's true output where this tick's sensors read it, µm.
    x_true: [Micrometres; AXES],
    supervisor: Supervisor<NoWatchdog>,
}

impl TickIo {
    /// One period.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_, AXES>) {
        virtual_axes::tick(
            &mut self.control,
            &mut self.stage,
            &links(),
            &mut self.x_true,
            x,
        );
        self.supervisor.after_tick(&mut self.control);
    }
}

/// What `init` hands on to the control task.
pub struct Io {
    stage: Axes<'static, AXES>,
}

impl Io {
    /// The control task's hardware, each axis running its model.
    pub fn tick(self, models: [Running; AXES]) -> TickIo {
        let mut models = models.into_iter();
        let axes = links().map(|l| {
            let Some(m) = models.next() else {
                halt("a model for every axis")
            };
            (m, l.hardware(), l.analog())
        });
        TickIo {
            control: ControlLoop::new(axes),
            stage: self.stage,
            x_true: [Micrometres::ZERO; AXES],
            supervisor: Supervisor::new(NoWatchdog::default()),
        }
    }
}

/// Sets up the emulated board of several axes: the link and flash as the
/// one-axis board's ([`init_link`]), the stage at rest.
pub fn init(
    dp: pac::Peripherals,
    usb_rx: Producer<'static, u8>,
    usb_tx: Consumer<'static, u8>,
) -> (ModelFlash<Flash>, Serial<USART1>, Usb, Io) {
    let (flash, serial, usb) = init_link(dp, usb_rx, usb_tx);
    let Some(mut stage) = AxesSpec::base(STAGE).and_then(|s| s.build::<AXES>(SEED)) else {
        halt("the virtual stage's parameters")
    };
    virtual_axes::prime(&mut stage, &links());
    (flash, serial, usb, Io { stage })
}
