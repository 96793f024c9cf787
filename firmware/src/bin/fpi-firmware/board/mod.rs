//! The STM32F405 driver board: the board definition's
//! ([`fpi_firmware::board::definition`]) clock, pins, converters and link brought up, and
//! the control task's hardware.
//!
//! The front end is the board definition's: [`internal`] (the STM32's 12-bit
//! ADCs and DAC, the default) or, with the cargo feature `precision`,
//! [`precision`] (AD7606 and AD5791 on SPI). The analog reference input is on
//! ADC2 with either. The stored model lives in flash sectors 10 and 11 (reserved
//! in `memory.x`); erasing a sector stalls instruction fetch for up to 2 s, which
//! the firmware only does with the stage parked at its safe voltage.

#[cfg(not(feature = "precision"))]
mod internal;
#[cfg(not(feature = "precision"))]
use internal as front;
#[cfg(feature = "precision")]
mod precision;
#[cfg(feature = "precision")]
use precision as front;

use defmt_rtt as _;
use fpi_firmware::board::converter_ports::ReferenceIn;
use fpi_firmware::board::definition::pins::{self, ReferenceAdc as Adc2};
use fpi_firmware::board::definition::{
    internal::REFERENCE_CHANNEL, UART_BAUD, USB_STRINGS, USB_VID_PID,
};
use fpi_firmware::board::storage::{ModelFlash, BOARD_SLOTS};
use fpi_firmware::board::watchdog::{Watchdog, PERIOD_MS};
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::recorder::lines;
use fpi_firmware::control::slots::Running;
use fpi_firmware::link::protocol::BoardKind;
use fpi_firmware::link::protocol::ResetReason;
use stm32f4xx_hal::watchdog::IndependentWatchdog;

use crate::supervisor::{was_reset_by_command, Supervisor};
use panic_probe as _;
use piezo_fpi::io::Hardware;
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::gpio::{Analog, Input, Output, PushPull, PA1, PB0, PB1, PB9};
use stm32f4xx_hal::otg_fs::{UsbBus, UsbBusType, USB};
use stm32f4xx_hal::pac::{self, USART1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Enable as _, Rcc, Reset as _};
use stm32f4xx_hal::serial::{Event, Serial};

use core::sync::atomic::{AtomicBool, Ordering};
use fpi_firmware::link::usb::TxPump;
use heapless::spsc::{Consumer, Producer};
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usbd_serial::SerialPort;

/// Which board this is.
pub const KIND: BoardKind = BoardKind::Driver;
/// The core clock SysTick counts, Hz.
pub const CORE_HZ: u32 = fpi_firmware::board::definition::CORE_HZ;

/// The analog reference input on ADC2, driven through its registers: the HAL's
/// `Adc::new` only takes ADC1 (its calibration needs ADC1's VREF channel).
pub struct ReferenceAdc {
    adc: Adc2,
    _pin: PA1<Analog>,
}

/// Starts an ADC converting one channel (56-cycle sample time) on software start,
/// its first conversion started.
fn start_single(adc: &pac::adc1::RegisterBlock, channel: u8) {
    adc.smpr2().modify(|_, w| w.smp1().cycles56());
    adc.smpr1().modify(|_, w| w.smp10().cycles56());
    // SAFETY: the board definition's channels (1, 10) are channels of ADC2/ADC3 (0–18).
    adc.sqr3().write(|w| unsafe { w.sq1().bits(channel) });
    adc.cr2().modify(|_, w| w.adon().set_bit());
    adc.cr2().modify(|_, w| w.swstart().set_bit());
}

/// The finished conversion, the next one started.
fn take_single(adc: &pac::adc1::RegisterBlock) -> u16 {
    let counts = adc.dr().read().data().bits();
    adc.cr2().modify(|_, w| w.swstart().set_bit());
    counts
}

impl ReferenceAdc {
    /// ADC2 on the reference input's channel, its first conversion started.
    fn new(adc: Adc2, pin: PA1<Analog>, rcc: &mut Rcc) -> Self {
        Adc2::enable(rcc);
        Adc2::reset(rcc);
        start_single(&adc, REFERENCE_CHANNEL);
        Self { adc, _pin: pin }
    }
}

impl ReferenceIn for ReferenceAdc {
    fn read_counts(&mut self) -> u16 {
        take_single(&self.adc)
    }
}

/// The amplifier's enable line.
pub type Enable = PB0<Output<PushPull>>;
/// The trigger output.
pub type TriggerOut = PB1<Output<PushPull>>;
/// The trigger input.
pub type TriggerIn = PB9<Input>;

/// The model's flash sectors: each erase or write unlocks the flash only for
/// its own duration.
pub struct Flash(LockedFlash);

impl embedded_storage::nor_flash::ErrorType for Flash {
    type Error = stm32f4xx_hal::flash::Error;
}

impl embedded_storage::nor_flash::ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        embedded_storage::nor_flash::ReadNorFlash::read(&mut self.0, offset, bytes)
    }
    fn capacity(&self) -> usize {
        embedded_storage::nor_flash::ReadNorFlash::capacity(&self.0)
    }
}

impl embedded_storage::nor_flash::NorFlash for Flash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 128 * 1024;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        embedded_storage::nor_flash::NorFlash::erase(&mut self.0.unlocked(), from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        embedded_storage::nor_flash::NorFlash::write(&mut self.0.unlocked(), offset, bytes)
    }
}

/// A host has the USB port open (set by the USB interrupt).
static USB_CONNECTED: AtomicBool = AtomicBool::new(false);

/// Whether a host has the USB port open: the device configured and DTR set.
pub fn usb_connected() -> bool {
    USB_CONNECTED.load(Ordering::Relaxed)
}

/// A board's link is what it is: nothing to keep across a reset.
pub fn keep_link(_link: fpi_firmware::link::protocol::LinkKind) {}

/// Nothing kept (see [`keep_link`]).
pub fn kept_link() -> Option<fpi_firmware::link::protocol::LinkKind> {
    None
}

/// The USB link: the device, its CDC-ACM port and the link task's queues.
pub struct Usb {
    dev: UsbDevice<'static, UsbBusType>,
    serial: SerialPort<'static, UsbBusType>,
    rx: Producer<'static, u8>,
    tx: Consumer<'static, u8>,
    pump: TxPump,
}

impl Usb {
    /// One poll of the device (the USB interrupt): received bytes into their
    /// queue (dropped if the link task is 2 KiB behind, then seen as a malformed
    /// frame), queued bytes out as the endpoint takes them.
    pub fn poll(&mut self) {
        let _ = self.dev.poll(&mut [&mut self.serial]);
        let connected = self.dev.state() == UsbDeviceState::Configured && self.serial.dtr();
        self.pump.connected(connected, &mut self.tx);
        USB_CONNECTED.store(connected, Ordering::Relaxed);
        let mut buf = [0u8; 64];
        while let Ok(n @ 1..) = self.serial.read(&mut buf) {
            for &b in buf.get(..n).unwrap_or(&[]) {
                let _ = self.rx.enqueue(b);
            }
        }
        let serial = &mut self.serial;
        self.pump.pump(&mut self.tx, |b| serial.write(b).ok());
    }
}

/// The USB device on OTG_FS (PA11/PA12) with one CDC-ACM port.
fn usb(
    (global, device, pwrclk): (pac::OTG_FS_GLOBAL, pac::OTG_FS_DEVICE, pac::OTG_FS_PWRCLK),
    pins: (stm32f4xx_hal::gpio::PA11, stm32f4xx_hal::gpio::PA12),
    clocks: &stm32f4xx_hal::rcc::Clocks,
    (rx, tx): (Producer<'static, u8>, Consumer<'static, u8>),
) -> Usb {
    // The OUT endpoints' buffers: EP0 and the CDC data endpoint, 64 bytes each,
    // with room to spare.
    let Some(ep_memory) = cortex_m::singleton!(: [u32; 256] = [0; 256]) else {
        halt("USB endpoint memory")
    };
    let usb = USB::new((global, device, pwrclk), pins, clocks);
    let Some(bus) =
        cortex_m::singleton!(: UsbBusAllocator<UsbBusType> = UsbBus::new(usb, ep_memory))
    else {
        halt("USB bus")
    };
    let serial = SerialPort::new(bus);
    let [manufacturer, product, serial_number] = USB_STRINGS;
    let strings = StringDescriptors::default()
        .manufacturer(manufacturer)
        .product(product)
        .serial_number(serial_number);
    let (vid, pid) = USB_VID_PID;
    let Ok(builder) = UsbDeviceBuilder::new(bus, UsbVidPid(vid, pid)).strings(&[strings]) else {
        halt("USB descriptors")
    };
    let dev = builder.device_class(usbd_serial::USB_CLASS_CDC).build();
    Usb {
        dev,
        serial,
        rx,
        tx,
        pump: TxPump::new(),
    }
}

/// The independent watchdog (40 kHz LSI; it keeps running through a reset).
pub struct Iwdg(IndependentWatchdog);

impl Watchdog for Iwdg {
    fn feed(&mut self) {
        self.0.feed();
    }
    fn set_period(&mut self, ms: u32) {
        self.0.start(ms.millis());
    }
}

/// The control task's hardware: the loop on the board's converters, the
/// supervisor with the independent watchdog.
pub struct TickIo {
    control: front::Control,
    supervisor: Supervisor<Iwdg>,
    trigger_out: TriggerOut,
    trigger_in: TriggerIn,
}

impl TickIo {
    /// One period.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_>) {
        front::before_tick();
        x.trigger_in = self.trigger_in.is_high();
        let [t] = *self.control.tick(x);
        front::after_tick(&mut self.control);
        self.trigger_out
            .set_state((t.lines & lines::TRIGGER_OUT != 0).into());
        self.control.record(x, &t, None);
        self.supervisor.after_tick(&mut self.control);
    }
}

/// The board's axes.
pub const AXES: usize = 1;

/// What `init` hands on to the control task.
pub struct Io {
    hw: Hardware<front::Sensor, front::Amplifier, Enable>,
    analog: front::Analog,
    iwdg: IndependentWatchdog,
    trigger_out: TriggerOut,
    trigger_in: TriggerIn,
}

impl Io {
    /// The control task's hardware, running `model`; starts the watchdog.
    pub fn tick(self, [model]: [Running; AXES]) -> TickIo {
        let mut iwdg = Iwdg(self.iwdg);
        iwdg.set_period(PERIOD_MS);
        TickIo {
            control: front::Control::new([(model, self.hw, self.analog)]),
            supervisor: Supervisor::new(iwdg),
            trigger_out: self.trigger_out,
            trigger_in: self.trigger_in,
        }
    }
}

/// Sets up the board: the board definition's clocks (168 MHz, the USB's 48 MHz)
/// and pins, the front end's converters ready (first conversions done,
/// amplifier off at 0 V), USART1 with its receive interrupt, the USB device on
/// the queues `usb_queues`, the flash store.
pub fn init(
    dp: pac::Peripherals,
    usb_rx: Producer<'static, u8>,
    usb_tx: Consumer<'static, u8>,
) -> (ModelFlash<Flash>, Serial<USART1>, Usb, Io) {
    let mut rcc = dp.RCC.freeze(pins::clocks());
    let (common, front_pins) = pins::take((dp.GPIOA, dp.GPIOB, dp.GPIOC), &mut rcc);
    let reference = ReferenceAdc::new(dp.ADC2, common.reference, &mut rcc);
    #[cfg(not(feature = "precision"))]
    let peripherals = (dp.ADC1, dp.ADC3, dp.DAC);
    #[cfg(feature = "precision")]
    let peripherals = (dp.SPI1, dp.SPI2, dp.TIM4);
    let (hw, analog) = front::init(front_pins, peripherals, reference, common.enable, &mut rcc);

    let Ok(mut serial) = Serial::new(dp.USART1, common.uart, UART_BAUD.bps(), &mut rcc) else {
        halt("USART1 configuration")
    };
    serial.listen(Event::RxNotEmpty);

    let usb = usb(
        (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        common.usb,
        &rcc.clocks,
        (usb_rx, usb_tx),
    );

    let flash = ModelFlash::new(Flash(LockedFlash::new(dp.FLASH)), BOARD_SLOTS);
    let iwdg = IndependentWatchdog::new(dp.IWDG);
    iwdg.stop_on_debug(&dp.DBGMCU, true);
    let io = Io {
        hw,
        analog,
        iwdg,
        trigger_out: common.trigger_out,
        trigger_in: common.trigger_in,
    };
    (flash, serial, usb, io)
}

/// Why the board started, from the reset flags (then cleared) and the mark of a
/// reset by command.
pub fn reset_reason(dp: &pac::Peripherals) -> ResetReason {
    let csr = dp.RCC.csr().read();
    let by_command = was_reset_by_command();
    let reason = if csr.wdgrstf().bit_is_set() || csr.wwdgrstf().bit_is_set() {
        ResetReason::Watchdog
    } else if csr.sftrstf().bit_is_set() && by_command {
        ResetReason::Command
    } else if csr.borrstf().bit_is_set() {
        ResetReason::BrownOut
    } else if csr.porrstf().bit_is_set() {
        ResetReason::PowerOn
    } else if csr.padrstf().bit_is_set() {
        ResetReason::Pin
    } else {
        ResetReason::Unknown
    };
    dp.RCC.csr().modify(|_, w| w.rmvf().set_bit());
    reason
}

/// Stops with the amplifier off, saying why over RTT.
pub fn halt(what: &str) -> ! {
    defmt::panic!("fpi-firmware: cannot start: {=str}", what)
}
