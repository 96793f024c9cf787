//! What the board does around each control tick besides the loop itself, the same
//! on both boards: detect a late tick, feed the watchdog only while both tasks are
//! alive, and remember why the board last reset.
//!
//! The link task counts its loop passes in [`LINK_PASSES`] and announces a long
//! operation in [`LONG`]; the control task reads both every tick
//! ([`Supervisor::after_tick`]). A reset by command is marked in a word of RAM that
//! start-up code does not clear (`.uninit`), so the next start can tell it.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embedded_hal::digital::OutputPin;
use fpi_firmware::board::analog_in::AnalogIn;
use fpi_firmware::board::watchdog::{Liveness, Watchdog, LONG_PERIOD_MS, PERIOD_MS};
use fpi_firmware::control::task::ControlLoop;
use piezo_fpi::io::{ForceSensor, Setpoint};

/// The link task's loop passes.
pub static LINK_PASSES: AtomicU32 = AtomicU32::new(0);
/// The link task runs a long operation (a flash erase).
pub static LONG: AtomicBool = AtomicBool::new(false);
/// The control task has set the watchdog's period for [`LONG`].
pub static LONG_APPLIED: AtomicBool = AtomicBool::new(false);

/// The watchdog rule and the watchdog.
pub struct Supervisor<W> {
    liveness: Liveness,
    wdg: W,
    long: bool,
}

impl<W: Watchdog> Supervisor<W> {
    /// Around a started watchdog.
    pub fn new(wdg: W) -> Self {
        Self {
            liveness: Liveness::new(),
            wdg,
            long: false,
        }
    }

    /// After the control tick: whether the next tick is already due (the tick
    /// overran its period), the watchdog's period and its feeding.
    #[inline]
    pub fn after_tick<S: ForceSensor, A: Setpoint, E: OutputPin, R: AnalogIn, const N: usize>(
        &mut self,
        lp: &mut ControlLoop<S, A, E, R, N>,
    ) {
        lp.late(cortex_m::peripheral::SCB::is_pendst_pending());
        let long = LONG.load(Ordering::Acquire);
        if long != self.long {
            self.wdg
                .set_period(if long { LONG_PERIOD_MS } else { PERIOD_MS });
            self.long = long;
            LONG_APPLIED.store(long, Ordering::Release);
        }
        if self
            .liveness
            .tick(LINK_PASSES.load(Ordering::Relaxed), long)
        {
            self.wdg.feed();
        }
    }
}

/// Marks a reset the board does on command.
const BY_COMMAND: u32 = 0xC0DE_5E75;

#[link_section = ".uninit.fpi_reset"]
static mut RESET_MARK: MaybeUninit<u32> = MaybeUninit::uninit();

/// Whether the last reset was one [`reset_by_command`] did; clears the mark.
pub fn was_reset_by_command() -> bool {
    let p = &raw mut RESET_MARK;
    // SAFETY: `.uninit` RAM holds some bit pattern after any reset, and every
    // pattern is a valid `u32`; volatile, because no Rust code wrote it in this run.
    unsafe {
        let mark = core::ptr::read_volatile(p.cast::<u32>());
        core::ptr::write_volatile(p.cast::<u32>(), 0);
        mark == BY_COMMAND
    }
}

/// Resets the board, marking it as a reset by command.
pub fn reset_by_command() -> ! {
    let p = &raw mut RESET_MARK;
    // SAFETY: a plain word of RAM only this module touches.
    unsafe { core::ptr::write_volatile(p.cast::<u32>(), BY_COMMAND) };
    cortex_m::peripheral::SCB::sys_reset()
}
