//! The emulated board (QEMU `netduinoplus2`): the virtual stage stands in for the
//! analog world and RAM for the model's flash sectors.
//!
//! The control task runs [`fpi_firmware::emulation::virtual_bench::tick`]: the same control loop as
//! the board's, then one step of the virtual stage, whose force reading the next
//! tick reads. QEMU ignores the clock tree, so SysTick counts QEMU's 168 MHz core
//! clock whatever the RCC says; the firmware stays on the 16 MHz HSI (no PLL to
//! wait for). Run with `-icount shift=0,sleep=on` (one instruction per
//! nanosecond, idle time in step with the host's clock), as `fpi board emulate`
//! does.

use cortex_m_semihosting::debug::{self, EXIT_FAILURE};
use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
use fpi_firmware::board::storage::ModelFlash;
use fpi_firmware::board::watchdog::Watchdog;
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::slots::Running;
use fpi_firmware::emulation::virtual_bench::{tick, Bench, EmulatedFlash, Loop, FLASH_SLOTS};
use fpi_firmware::emulation::virtual_io::SimLink;
use fpi_firmware::link::protocol::BoardKind;
use fpi_firmware::link::protocol::ResetReason;

use crate::supervisor::{was_reset_by_command, Supervisor};
use core::mem::MaybeUninit;
use fpi_firmware::link::protocol::LinkKind;
use heapless::spsc::{Consumer, Producer};
use stm32f4xx_hal::pac::{self, USART1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::serial::{Event, Serial};

/// Which board this is.
pub const KIND: BoardKind = BoardKind::Emulated;
/// SysTick's clock: QEMU's core clock, whatever the RCC says.
pub const CORE_HZ: u32 = 168_000_000;

/// The emulated flash: two slots in RAM (QEMU cannot program its flash).
pub type Flash = &'static mut EmulatedFlash;

static LINK: SimLink = SimLink::new(FORCE_ADC, SETPOINT_DAC);

/// QEMU models no watchdog: this one counts the feeds the rule allows.
#[derive(Default)]
pub struct NoWatchdog {
    feeds: u32,
}

impl Watchdog for NoWatchdog {
    fn feed(&mut self) {
        self.feeds = self.feeds.wrapping_add(1);
    }
    fn set_period(&mut self, _ms: u32) {}
}

/// QEMU models no USB controller: the link stays on the USART and this port
/// never connects (its interrupt never fires).
pub struct Usb {
    _queues: (Producer<'static, u8>, Consumer<'static, u8>),
}

impl Usb {
    /// Nothing to poll.
    pub fn poll(&mut self) {}
}

/// The link the bench paces the board's as, kept across a reset by command in
/// a word of RAM that start-up code does not clear (`.uninit`): the emulated
/// board stays the board it was started as.
#[link_section = ".uninit.fpi_link"]
static mut LINK_MARK: MaybeUninit<u32> = MaybeUninit::uninit();
/// [`LINK_MARK`]'s tag; the link's wire number in its low byte.
const LINK_TAG: u32 = 0x4c4e_4b00;

/// Keeps `link` for the next start (just before a reset by command).
pub fn keep_link(link: LinkKind) {
    let p = &raw mut LINK_MARK;
    // SAFETY: a plain word of RAM only this module touches.
    unsafe { core::ptr::write_volatile(p.cast::<u32>(), LINK_TAG | u32::from(link.to_u8())) };
}

/// The link kept by [`keep_link`] before this start, if any; clears it.
pub fn kept_link() -> Option<LinkKind> {
    let p = &raw mut LINK_MARK;
    // SAFETY: `.uninit` RAM holds some bit pattern after any reset, and every
    // pattern is a valid `u32`; volatile, because no Rust code wrote it in this run.
    let mark = unsafe {
        let m = core::ptr::read_volatile(p.cast::<u32>());
        core::ptr::write_volatile(p.cast::<u32>(), 0);
        m
    };
    (mark & !0xff == LINK_TAG)
        .then(|| LinkKind::from_u8(mark as u8))
        .flatten()
}

/// No host on a USB port QEMU does not have.
pub fn usb_connected() -> bool {
    false
}

/// The control task's hardware: the loop on the [`SimLink`], the virtual stage,
/// the supervisor.
pub struct TickIo {
    control: Loop,
    bench: Bench,
    supervisor: Supervisor<NoWatchdog>,
}

impl TickIo {
    /// One period.
    #[inline]
    pub fn tick(&mut self, x: &mut Exchange<'_>) {
        tick(&mut self.control, &mut self.bench, &LINK, x);
        self.supervisor.after_tick(&mut self.control);
    }
}

/// The board's axes.
pub const AXES: usize = 1;

/// What `init` hands on to the control task.
pub struct Io {
    bench: Bench,
}

impl Io {
    /// The control task's hardware, running `model`.
    pub fn tick(self, [model]: [Running; AXES]) -> TickIo {
        TickIo {
            control: Loop::new([(model, LINK.hardware(), LINK.analog())]),
            bench: self.bench,
            supervisor: Supervisor::new(NoWatchdog { feeds: 0 }),
        }
    }
}

/// Sets up the emulated board: clock, USART1 with its receive interrupt, the
/// virtual stage at rest, the RAM-backed flash.
pub fn init(
    dp: pac::Peripherals,
    usb_rx: Producer<'static, u8>,
    usb_tx: Consumer<'static, u8>,
) -> (ModelFlash<Flash>, Serial<USART1>, Usb, Io) {
    let (flash, serial, usb) = init_link(dp, usb_rx, usb_tx);
    let Some(mut bench) = Bench::new() else {
        halt("the virtual stage's parameters")
    };
    bench.prime(&LINK);
    (flash, serial, usb, Io { bench })
}

/// What every emulated board sets up before its stage: the clock, USART1
/// with its receive interrupt, the USB port QEMU does not have, the
/// RAM-backed flash.
pub fn init_link(
    dp: pac::Peripherals,
    usb_rx: Producer<'static, u8>,
    usb_tx: Consumer<'static, u8>,
) -> (ModelFlash<Flash>, Serial<USART1>, Usb) {
    let usb = Usb {
        _queues: (usb_rx, usb_tx),
    };
    let mut rcc = dp.RCC.freeze(Config::hsi());
    let gpioa = dp.GPIOA.split(&mut rcc);
    let Ok(mut serial) = Serial::new(dp.USART1, (gpioa.pa9, gpioa.pa10), 115_200.bps(), &mut rcc)
    else {
        halt("USART1 configuration")
    };
    serial.listen(Event::RxNotEmpty);
    let ram = emulated_flash();
    seed(ram);
    (ModelFlash::new(ram, FLASH_SLOTS), serial, usb)
}

/// The RAM standing in for the stored-model flash (`memory.x`'s
/// `.emulated_flash`): it takes its room from the real board's 128 KiB, so
/// the program has less RAM and stack than on the real board, never more.
#[link_section = ".emulated_flash"]
static mut EMULATED_FLASH: core::mem::MaybeUninit<EmulatedFlash> = core::mem::MaybeUninit::uninit();

/// The emulated flash, erased; called once, from `init`.
fn emulated_flash() -> &'static mut EmulatedFlash {
    // SAFETY: `init` runs once, before any task; nothing else names the static.
    unsafe { (*core::ptr::addr_of_mut!(EMULATED_FLASH)).write(EmulatedFlash::new()) }
}

/// Where the host may put the emulated flash's content (`-device loader` at the
/// board's stored-model sector): what a real board's flash kept while it was off.
const SEED_ADDRESS: usize = 0x080C_0000;

/// Takes the flash content QEMU loaded at [`SEED_ADDRESS`], if any (QEMU's
/// unprogrammed flash reads as zeros).
fn seed(ram: &mut EmulatedFlash) {
    let len = ram.as_bytes().len();
    // SAFETY: the address is inside the STM32F405's flash (sector 10), which
    // memory.x keeps out of the program; it is read-only memory QEMU maps.
    let rom = unsafe { core::slice::from_raw_parts(SEED_ADDRESS as *const u8, len) };
    if rom.iter().any(|b| *b != 0) {
        ram.load(rom);
    }
}

/// Why the emulated board started: by command, or else (QEMU cannot tell) power-on.
pub fn reset_reason(_dp: &pac::Peripherals) -> ResetReason {
    if was_reset_by_command() {
        ResetReason::Command
    } else {
        ResetReason::PowerOn
    }
}

/// Stops with a message (semihosting exit status 1).
pub fn halt(what: &str) -> ! {
    cortex_m_semihosting::hprintln!("fpi-firmware: cannot start: {}", what);
    debug::exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    cortex_m_semihosting::hprintln!(
        "fpi-firmware: HardFault at pc {:#010x} (lr {:#010x})",
        frame.pc(),
        frame.lr()
    );
    halt("HardFault")
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m_semihosting::hprintln!("panic: {}", info);
    debug::exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
