//! The control interrupt (TIM2) and its two mailboxes, shared by both builds.
//!
//! The ISR owns the control loop (moved in once at start-up); thread mode sends
//! [`Command`]s through a one-slot mailbox and reads [`Telemetry`] from a
//! lock-free SPSC queue. The ISR never blocks and never allocates.
//!
//! **Deadline.** One period of the control rate (50 µs at 20 kHz). The control step
//! costs at most 295 instructions for 10 paper-FPI operators and 427 for the
//! embedded model (`cargo isr-bench`), about 2–3 µs at 168 MHz; the whole tick with
//! reference, ADC, DAC and enable line at most 701.

use core::cell::Cell;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::{free, Mutex};
use heapless::spsc::Producer;
use piezo_fpi::model::{self, DeadZone, Saturation, CREEP_TERMS, OPERATORS};
use piezo_fpi::runner::{Command, ControlLoop, Telemetry};
use stm32f4xx_hal::pac::{interrupt, Interrupt, TIM2};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::timer::{CounterHz, Flag};

#[cfg(not(feature = "qemu"))]
use crate::board::{Amplifier, Enable, Sensor};
#[cfg(feature = "qemu")]
use crate::emulated::{Amplifier, Enable, Sensor};

/// The control loop of this build.
pub type Loop =
    ControlLoop<'static, OPERATORS, CREEP_TERMS, DeadZone, Saturation, Sensor, Amplifier, Enable>;

/// Telemetry slots between the ISR and thread mode.
pub const TELEMETRY_DEPTH: usize = 64;

/// What the ISR owns.
pub struct Context {
    /// The control loop (controller state, hardware, reference).
    pub control: Loop,
    /// The timer whose update event is this interrupt.
    pub timer: CounterHz<TIM2>,
    /// Telemetry to thread mode.
    pub telemetry: Producer<'static, Telemetry>,
}

static HANDOFF: Mutex<Cell<Option<Context>>> = Mutex::new(Cell::new(None));
static MAILBOX: Mutex<Cell<Option<Command>>> = Mutex::new(Cell::new(None));
static DROPPED: AtomicU32 = AtomicU32::new(0);

/// Hands the loop to the ISR and unmasks TIM2. Call once, with the timer running.
pub fn start(ctx: Context) {
    free(|cs| HANDOFF.borrow(cs).set(Some(ctx)));
    // SAFETY: the handler only uses state it owns or that is behind `Mutex`/atomics.
    unsafe { cortex_m::peripheral::NVIC::unmask(Interrupt::TIM2) };
}

/// Sends a command; it takes effect at the start of the next control period.
/// (The board build has no command source yet: it runs its self-test trajectory.)
#[cfg_attr(not(feature = "qemu"), allow(dead_code))]
pub fn post(c: Command) {
    free(|cs| MAILBOX.borrow(cs).set(Some(c)));
}

/// Telemetry records lost because thread mode fell behind.
pub fn dropped() -> u32 {
    DROPPED.load(Ordering::Relaxed)
}

#[interrupt]
fn TIM2() {
    static mut CTX: Option<Context> = None;
    if CTX.is_none() {
        *CTX = free(|cs| HANDOFF.borrow(cs).take());
    }
    let Some(ctx) = CTX.as_mut() else {
        return;
    };
    ctx.timer.clear_flags(Flag::Update);
    if let Some(c) = free(|cs| MAILBOX.borrow(cs).take()) {
        ctx.control.apply(c);
    }
    let t = ctx.control.run();
    if ctx.telemetry.enqueue(t).is_err() {
        DROPPED.fetch_add(1, Ordering::Relaxed);
    }
}

/// The control rate of the embedded model, Hz.
pub const RATE_HZ: u32 = model::CONTROL_RATE_HZ;
