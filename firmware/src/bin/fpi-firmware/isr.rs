//! The control interrupt (TIM2), generic over the board's I/O, and its two
//! mailboxes.
//!
//! The ISR owns an [`Isr`] (moved in once at start-up): the control loop with the
//! board's sensor, amplifier and enable line, the timer, and the telemetry queue.
//! Thread mode sends [`Command`]s through a one-slot mailbox and reads
//! [`Telemetry`] from a lock-free SPSC queue. The ISR never blocks and never
//! allocates. A board binds its concrete I/O types to the interrupt with
//! [`bind_tim2!`](crate::bind_tim2): the boards depend on this module, not the
//! reverse.
//!
//! **Deadline.** One period of the control rate (50 µs at 20 kHz). The control step
//! and the whole tick are measured by `cargo isr-bench` (instructions under QEMU;
//! the README lists the current figures): a few µs at 168 MHz.

use core::cell::Cell;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::{free, Mutex};
use embedded_hal::digital::OutputPin;
use fpi_firmware::model::{self, DeadZone, Saturation, CREEP_TERMS, OPERATORS};
use fpi_firmware::runner::{Command, ControlLoop, Telemetry};
use heapless::spsc::Producer;
use piezo_fpi::io::{ForceSensor, Setpoint};
use stm32f4xx_hal::pac::TIM2;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::timer::{CounterHz, Flag};

/// The control loop of the embedded model on a board's I/O.
pub type Loop<S, A, E> =
    ControlLoop<'static, OPERATORS, CREEP_TERMS, DeadZone, Saturation, S, A, E>;

/// Telemetry slots between the ISR and thread mode.
pub const TELEMETRY_DEPTH: usize = 64;

/// The control rate of the embedded model, Hz.
pub const RATE_HZ: u32 = model::CONTROL_RATE_HZ;

/// What the ISR owns.
pub struct Isr<S, A, E> {
    /// The control loop (controller state, hardware, reference).
    pub control: Loop<S, A, E>,
    /// The timer whose update event is this interrupt.
    pub timer: CounterHz<TIM2>,
    /// Telemetry to thread mode.
    pub telemetry: Producer<'static, Telemetry>,
}

impl<S: ForceSensor, A: Setpoint, E: OutputPin> Isr<S, A, E> {
    /// One control period: acknowledge the timer, take a pending command, run the
    /// loop, queue the telemetry (counted as dropped if thread mode fell behind).
    #[inline]
    pub fn tick(&mut self) {
        self.timer.clear_flags(Flag::Update);
        if let Some(c) = free(|cs| MAILBOX.borrow(cs).take()) {
            self.control.apply(c);
        }
        let t = self.control.run();
        if self.telemetry.enqueue(t).is_err() {
            DROPPED.fetch_add(1, Ordering::Relaxed);
        }
    }
}

static MAILBOX: Mutex<Cell<Option<Command>>> = Mutex::new(Cell::new(None));
static DROPPED: AtomicU32 = AtomicU32::new(0);

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

/// Binds TIM2 to an [`Isr`] over a board's sensor, amplifier and enable types,
/// and defines `start(isr)`, which hands it to the interrupt and unmasks TIM2.
#[macro_export]
macro_rules! bind_tim2 {
    ($sensor:ty, $amplifier:ty, $enable:ty) => {
        use stm32f4xx_hal::pac::interrupt;

        type BoardIsr = $crate::isr::Isr<$sensor, $amplifier, $enable>;

        static HANDOFF: cortex_m::interrupt::Mutex<core::cell::Cell<Option<BoardIsr>>> =
            cortex_m::interrupt::Mutex::new(core::cell::Cell::new(None));

        /// Hands the loop to the ISR and unmasks TIM2. Call once, with the timer running.
        pub fn start(isr: BoardIsr) {
            cortex_m::interrupt::free(|cs| HANDOFF.borrow(cs).set(Some(isr)));
            // SAFETY: the handler only uses state it owns or that is behind `Mutex`/atomics.
            unsafe { cortex_m::peripheral::NVIC::unmask(stm32f4xx_hal::pac::Interrupt::TIM2) };
        }

        #[interrupt]
        fn TIM2() {
            static mut ISR: Option<BoardIsr> = None;
            if ISR.is_none() {
                *ISR = cortex_m::interrupt::free(|cs| HANDOFF.borrow(cs).take());
            }
            if let Some(isr) = ISR.as_mut() {
                isr.tick();
            }
        }
    };
}
