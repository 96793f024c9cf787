//! The STM32F405 driver board.
//!
//! | signal | pin | peripheral |
//! |---|---|---|
//! | force sensor (0–3.3 V = −5…507 N) | PA0 | ADC1 channel 0 |
//! | analog reference (0–3.3 V = the model's stroke) | PA1 | ADC2 channel 1 |
//! | stage-position sensor (0–3.3 V = −10…+70 µm) | PC0 | ADC3 channel 10 |
//! | amplifier setpoint (0–3.3 V = 0–150 V) | PA4 | DAC channel 1 |
//! | amplifier enable (high = on) | PB0 | GPIO |
//! | host link, USB (CDC-ACM, full speed) | PA11 D−, PA12 D+ | OTG_FS |
//! | host link, fallback (115 200 Bd, 8N1) | PA9 TX, PA10 RX | USART1 |
//!
//! The ADC conversions for tick k+1 are started at the end of tick k, so the ISR
//! reads finished results (3.4 µs conversions in a 50 µs period) instead of
//! waiting. The stored model lives in flash sectors 10 and 11 (reserved in
//! `memory.x`); erasing a sector stalls instruction fetch for up to 2 s, which the
//! firmware only does with the stage parked at its safe voltage.

use defmt_rtt as _;
use fpi_firmware::control_loop::ControlLoop;
use fpi_firmware::exchange::Exchange;
use fpi_firmware::frontend::{AnalogIn, FORCE_ADC, SETPOINT_DAC};
use fpi_firmware::link::protocol::BoardKind;
use fpi_firmware::link::protocol::ResetReason;
use fpi_firmware::slots::Running;
use fpi_firmware::storage::{ModelFlash, BOARD_SLOTS};
use fpi_firmware::watchdog::{Watchdog, PERIOD_MS};
use stm32f4xx_hal::watchdog::IndependentWatchdog;

use crate::supervisor::{was_reset_by_command, Supervisor};
use panic_probe as _;
use piezo_fpi::io::{ForceSensor, Hardware, Setpoint};
use piezo_fpi::q::{Newtons, Volts};
use stm32f4xx_hal::adc::config::{AdcConfig, SampleTime, Sequence};
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::dac::{DacOut, DacPin, C1};
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::gpio::{Analog, Output, PushPull, PA0, PA1, PB0, PC0};
use stm32f4xx_hal::otg_fs::{UsbBus, UsbBusType, USB};
use stm32f4xx_hal::pac::{self, ADC1, ADC2, ADC3, USART1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
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
pub const CORE_HZ: u32 = 168_000_000;

/// The force sensor on ADC1/PA0.
pub struct Sensor {
    adc: Adc<ADC1>,
    _pin: PA0<Analog>,
}

impl ForceSensor for Sensor {
    fn read_force(&mut self) -> Newtons {
        let counts = self.adc.current_sample();
        self.adc.start_conversion();
        FORCE_ADC.to_force(counts)
    }
}

/// The analog reference input on ADC2/PA1 and the stage-position sensor on
/// ADC3/PC0, driven through their registers: the HAL's `Adc::new` only takes ADC1
/// (its calibration needs ADC1's VREF channel).
pub struct Reference {
    adc: ADC2,
    _pin: PA1<Analog>,
    position: ADC3,
    _position_pin: PC0<Analog>,
}

/// Starts an ADC converting one channel (56-cycle sample time) on software start,
/// its first conversion started.
fn start_single(adc: &pac::adc1::RegisterBlock, channel: u8) {
    adc.smpr2().modify(|_, w| w.smp1().cycles56());
    adc.smpr1().modify(|_, w| w.smp10().cycles56());
    // SAFETY: the channels used (1, 10) are channels of ADC2/ADC3 (0–18).
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

impl Reference {
    /// ADC2 on channel 1 and ADC3 on channel 10, first conversions started.
    fn new(
        (adc, pin): (ADC2, PA1<Analog>),
        (position, position_pin): (ADC3, PC0<Analog>),
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> Self {
        <ADC2 as stm32f4xx_hal::rcc::Enable>::enable(rcc);
        <ADC2 as stm32f4xx_hal::rcc::Reset>::reset(rcc);
        <ADC3 as stm32f4xx_hal::rcc::Enable>::enable(rcc);
        <ADC3 as stm32f4xx_hal::rcc::Reset>::reset(rcc);
        start_single(&adc, 1);
        start_single(&position, 10);
        Self {
            adc,
            _pin: pin,
            position,
            _position_pin: position_pin,
        }
    }
}

impl AnalogIn for Reference {
    fn read_counts(&mut self) -> u16 {
        take_single(&self.adc)
    }
    fn read_position(&mut self) -> u16 {
        // 12 bits, left-aligned to the channel's 16-bit code.
        take_single(&self.position) << 4
    }
}

/// The amplifier setpoint on DAC channel 1 (PA4).
pub struct Amplifier(C1);

impl Setpoint for Amplifier {
    fn write_voltage(&mut self, voltage: Volts) {
        self.0.set_value(SETPOINT_DAC.to_code(voltage));
    }
}

/// The amplifier's enable line.
pub type Enable = PB0<Output<PushPull>>;

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
    let strings = StringDescriptors::default()
        .manufacturer("piezo-fpi")
        .product("FPI piezo driver board")
        .serial_number("FPI-0001");
    // pid.codes' test VID/PID for CDC-ACM, as the HAL's examples use: a
    // product needs its own.
    let Ok(builder) = UsbDeviceBuilder::new(bus, UsbVidPid(0x16c0, 0x27dd)).strings(&[strings])
    else {
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
    control: ControlLoop<Sensor, Amplifier, Enable, Reference>,
    supervisor: Supervisor<Iwdg>,
}

impl TickIo {
    /// One period.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_>) {
        let t = self.control.tick(x);
        self.control.record(x, &t, None);
        self.supervisor.after_tick(&mut self.control);
    }
}

/// What `init` hands on to the control task.
pub struct Io {
    hw: Hardware<Sensor, Amplifier, Enable>,
    reference: Reference,
    iwdg: IndependentWatchdog,
}

impl Io {
    /// The control task's hardware, running `model`; starts the watchdog.
    pub fn tick(self, model: Running) -> TickIo {
        let mut iwdg = Iwdg(self.iwdg);
        iwdg.set_period(PERIOD_MS);
        TickIo {
            control: ControlLoop::new(model, self.hw, self.reference),
            supervisor: Supervisor::new(iwdg),
        }
    }
}

/// Sets up the board: 168 MHz (and the USB's 48 MHz), converters with their
/// first conversions done, amplifier off at 0 V, USART1 with its receive
/// interrupt, the USB device on the queues `usb_queues`, the flash store.
pub fn init(
    dp: pac::Peripherals,
    usb_rx: Producer<'static, u8>,
    usb_tx: Consumer<'static, u8>,
) -> (ModelFlash<Flash>, Serial<USART1>, Usb, Io) {
    let mut rcc = dp
        .RCC
        .freeze(Config::hse(8.MHz()).sysclk(168.MHz()).require_pll48clk());
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);

    let mut enable = gpiob.pb0.into_push_pull_output();
    enable.set_low();
    let mut dac = dp.DAC.constrain(gpioa.pa4.into_analog(), &mut rcc);
    dac.enable();
    dac.set_value(0);

    let pa0 = gpioa.pa0.into_analog();
    let mut adc1 = Adc::<ADC1>::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
    adc1.configure_channel(&pa0, Sequence::One, SampleTime::Cycles_56);
    adc1.enable();
    let _ = adc1.convert(&pa0, SampleTime::Cycles_56);
    adc1.start_conversion();

    let gpioc = dp.GPIOC.split(&mut rcc);
    let reference = Reference::new(
        (dp.ADC2, gpioa.pa1.into_analog()),
        (dp.ADC3, gpioc.pc0.into_analog()),
        &mut rcc,
    );

    let Ok(mut serial) = Serial::new(dp.USART1, (gpioa.pa9, gpioa.pa10), 115_200.bps(), &mut rcc)
    else {
        halt("USART1 configuration")
    };
    serial.listen(Event::RxNotEmpty);

    let usb = usb(
        (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        (gpioa.pa11, gpioa.pa12),
        &rcc.clocks,
        (usb_rx, usb_tx),
    );

    let flash = ModelFlash::new(Flash(LockedFlash::new(dp.FLASH)), BOARD_SLOTS);
    let iwdg = IndependentWatchdog::new(dp.IWDG);
    iwdg.stop_on_debug(&dp.DBGMCU, true);
    let io = Io {
        hw: Hardware {
            sensor: Sensor {
                adc: adc1,
                _pin: pa0,
            },
            amplifier: Amplifier(dac),
            enable,
        },
        reference,
        iwdg,
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
