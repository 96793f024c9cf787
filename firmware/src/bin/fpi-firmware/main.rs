//! Firmware of the STM32F405 piezo driver board: FPI hysteresis compensation in
//! the control interrupt, a command link on USART1, a data recorder and model
//! upload — one RTIC application for the board and the emulated board.
//!
//! | task | priority | runs |
//! |---|---|---|
//! | `control` (SysTick, 20 kHz) | 3 | one control tick: order, reference, sensor, step, DAC, recorder |
//! | `usart1` (USART1 RX) | 2 | moves received bytes into a queue |
//! | `otg_fs` (OTG_FS) | 2 | polls the USB device: received bytes into a queue, queued replies out ([`TxPump`]) |
//! | `idle` (link task) | 0 | frames from either link, commands, replies (on the link the request came over), model loading, flash |
//!
//! [`TxPump`]: fpi_firmware::link::usb::TxPump
//!
//! The control task and the link task share one [`Exchange`], which the control
//! task reaches without a lock (it is the highest-priority user) and the link
//! task locks briefly; a new model reaches the control task by value
//! ([`fpi_firmware::control::slots`]). So parsing, validation and flash writes never delay
//! a tick, as in quartiq's Stabilizer, where settings are rebuilt at low priority
//! and swapped in.
//!
//! * Board build (`cargo fw`): the board definition's
//!   ([`fpi_firmware::board::definition`]) clock (168 MHz from the 8 MHz HSE crystal),
//!   front end (the STM32's 12-bit ADCs and DAC; with `--features precision` an
//!   AD7606 and an AD5791 on SPI), pins and link (USB CDC-ACM on OTG_FS and, as
//!   the fallback, USART1 at 115 200 Bd); stored model in flash sectors 10/11,
//!   defmt logs over RTT.
//! * Emulated build (feature `qemu`, run by `fpi board emulate`): the same
//!   application on QEMU's `netduinoplus2` (an STM32F405 memory map) with USART1
//!   bridged to a TCP port (QEMU has no OTG model: its USB never connects; the
//!   link is paced as the one it emulates, see `fpi_firmware::link::pace`). QEMU models no PLL, DAC, analog world or flash
//!   programming, so the clock stays on the 16 MHz HSI, the ADCs and DAC are the
//!   virtual stage's ([`fpi_firmware::emulation::virtual_bench`]) and the model store is
//!   RAM-backed.
//!
//! On the host this binary only explains how to build it.
//!
//! [`Exchange`]: fpi_firmware::control::exchange::Exchange
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
#[macro_use]
mod log;

#[cfg(target_os = "none")]
mod supervisor;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod board;
#[cfg(all(target_os = "none", not(feature = "qemu")))]
use board as io;

#[cfg(all(target_os = "none", feature = "qemu"))]
mod qemu_board;
#[cfg(all(target_os = "none", feature = "qemu"))]
use qemu_board as io;

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use core::sync::atomic::Ordering;
    use cortex_m::peripheral::syst::SystClkSource;
    use embedded_hal_nb::serial::Read as _;
    use embedded_io::Write as _;
    use fpi_firmware::board::capacity::{
        Store, IMAGE_BYTES, RATE_HZ, RECORDER_SAMPLES, STREAM_POINTS,
    };
    use fpi_firmware::board::factory_model::MODEL_IMAGE;
    use fpi_firmware::control::exchange::Exchange;
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::slots::Spare;
    use fpi_firmware::link::frame::{FrameReader, Push};
    use fpi_firmware::link::handler::{Board, Handler};
    use fpi_firmware::link::protocol::{LinkKind, MAX_FRAME};
    use heapless::spsc::{Consumer, Producer, Queue};
    use rtic::Mutex;
    use stm32f4xx_hal::pac::USART1;
    use stm32f4xx_hal::serial::{Rx, Tx};

    use super::io;

    /// Received bytes between the USART interrupt and the link task.
    const RX_QUEUE: usize = 2048;
    /// Bytes between the USB interrupt and the link task, each way (a request
    /// is at most 1 280 bytes, and the link task takes bytes as they come; a
    /// reply waits for room).
    const USB_QUEUE: usize = 1024;

    #[shared]
    struct Shared {
        exchange: Exchange<'static>,
    }

    #[local]
    struct Local {
        tick: io::TickIo,
        rx: Rx<USART1>,
        rx_in: Producer<'static, u8>,
        rx_out: Consumer<'static, u8>,
        tx: Tx<USART1>,
        usb: io::Usb,
        usb_in: Consumer<'static, u8>,
        usb_out: Producer<'static, u8>,
        handler: Handler<io::Flash>,
    }

    #[init(local = [
        store_a: Store = Store::new(),
        store_b: Store = Store::new(),
        image: [u8; IMAGE_BYTES] = [0; IMAGE_BYTES],
        recorder: Recorder<RECORDER_SAMPLES> = Recorder::new(),
        points: Points<STREAM_POINTS> = Points::new(),
        rx_queue: Queue<u8, RX_QUEUE> = Queue::new(),
        usb_rx: Queue<u8, USB_QUEUE> = Queue::new(),
        usb_tx: Queue<u8, USB_QUEUE> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let reset = io::reset_reason(&cx.device);
        let (usb_rx_in, usb_in) = cx.local.usb_rx.split();
        let (usb_out, usb_tx_out) = cx.local.usb_tx.split();
        let (flash, serial, usb, board) = io::init(cx.device, usb_rx_in, usb_tx_out);
        let Some((mut handler, running)) = Handler::boot(
            io::KIND,
            Spare::new(cx.local.store_a),
            Spare::new(cx.local.store_b),
            cx.local.image,
            flash,
            MODEL_IMAGE,
            reset,
        ) else {
            io::halt("the factory model does not load")
        };
        if let Some(link) = io::kept_link() {
            handler.pace_as(link);
        }
        let summary = *running.summary();
        say!(
            "fpi-firmware: control at {} Hz, model crc {} ({} operators), link on USB and USART1",
            RATE_HZ,
            summary.crc,
            summary.shape.operators as u32
        );
        let tick = board.tick(running);

        let mut syst = cx.core.SYST;
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(io::CORE_HZ / RATE_HZ - 1);
        syst.clear_current();
        syst.enable_counter();
        syst.enable_interrupt();

        let (rx_in, rx_out) = cx.local.rx_queue.split();
        let (tx, rx) = serial.split();
        (
            Shared {
                exchange: Exchange::new(cx.local.recorder, cx.local.points),
            },
            Local {
                tick,
                rx,
                rx_in,
                rx_out,
                tx,
                usb,
                usb_in,
                usb_out,
                handler,
            },
        )
    }

    /// The control tick. Deadline: one period (50 µs); `cargo isr-bench` counts
    /// its instructions.
    #[task(binds = SysTick, priority = 3, local = [tick], shared = [exchange])]
    fn control(mut cx: control::Context) {
        let tick = cx.local.tick;
        cx.shared.exchange.lock(|x| tick.tick(x));
    }

    /// Received bytes into the queue (dropped, and then seen as a malformed frame,
    /// if the link task has fallen 2 KiB behind).
    #[task(binds = USART1, priority = 2, local = [rx, rx_in])]
    fn usart1(cx: usart1::Context) {
        while let Ok(b) = cx.local.rx.read() {
            let _ = cx.local.rx_in.enqueue(b);
        }
    }

    /// The USB device: received bytes into their queue, queued replies out.
    /// Fires on the device's events and when the link task has queued bytes.
    #[task(binds = OTG_FS, priority = 2, local = [usb])]
    fn otg_fs(cx: otg_fs::Context) {
        cx.local.usb.poll();
    }

    /// The link task: frames in from either link, each reply out on the link
    /// its request came over.
    #[idle(
        local = [
            rx_out, tx, usb_in, usb_out, handler,
            reader: FrameReader<MAX_FRAME> = FrameReader::new(),
            usb_reader: FrameReader<MAX_FRAME> = FrameReader::new(),
            scratch: [u8; MAX_FRAME] = [0; MAX_FRAME],
            out: [u8; MAX_FRAME] = [0; MAX_FRAME],
        ],
        shared = [exchange]
    )]
    fn idle(cx: idle::Context) -> ! {
        let l = cx.local;
        let mut board = Link(cx.shared.exchange);
        loop {
            super::supervisor::LINK_PASSES.fetch_add(1, Ordering::Relaxed);
            let (b, link, reader) = if let Some(b) = l.usb_in.dequeue() {
                (b, LinkKind::Usb, &mut *l.usb_reader)
            } else if let Some(b) = l.rx_out.dequeue() {
                (b, LinkKind::Uart, &mut *l.reader)
            } else {
                cortex_m::asm::wfi();
                continue;
            };
            let push = reader.push(b);
            if push == Push::Pending {
                continue;
            }
            l.handler.arrived_on(link);
            let n = match push {
                Push::Frame => l
                    .handler
                    .handle(&mut board, reader.frame(), l.scratch, l.out),
                _ => l.handler.overlong(l.scratch, l.out),
            };
            let reply = l.out.get(..n).unwrap_or(&[]);
            match link {
                // A write error leaves the host without a reply; it times out and retries.
                LinkKind::Uart => {
                    let _ = l.tx.write_all(reply);
                }
                LinkKind::Usb => usb_send(l.usb_out, reply),
            }
            if l.handler.reset_requested() {
                let _ = l.tx.flush();
                // The reply leaves before the reset (the USB interrupt empties the
                // queue unless the host has gone).
                while !l.usb_out.is_empty() && io::usb_connected() {
                    rtic::pend(stm32f4xx_hal::pac::Interrupt::OTG_FS);
                    cortex_m::asm::wfi();
                }
                io::keep_link(l.handler.link());
                super::supervisor::reset_by_command();
            }
        }
    }

    /// Queues `bytes` for the USB interrupt, waiting while the queue is full;
    /// drops them if no host has the port open (it left mid-reply).
    fn usb_send(q: &mut Producer<'static, u8>, bytes: &[u8]) {
        for &b in bytes {
            while q.enqueue(b).is_err() {
                if !io::usb_connected() {
                    return;
                }
                rtic::pend(stm32f4xx_hal::pac::Interrupt::OTG_FS);
                cortex_m::asm::wfi();
            }
        }
        rtic::pend(stm32f4xx_hal::pac::Interrupt::OTG_FS);
    }

    /// The handler's view of the board: the exchange behind the RTIC lock.
    struct Link<M>(M);

    impl<M: Mutex<T = Exchange<'static>>> Board for Link<M> {
        fn exchange<R>(&mut self, f: impl FnOnce(&mut Exchange<'_>) -> R) -> R {
            self.0.lock(|x| f(x))
        }
        fn wait(&mut self) {
            cortex_m::asm::wfi();
        }
        fn stack_high_water(&self) -> Option<u32> {
            Some(super::stack_used())
        }
        fn long_operation(&mut self, on: bool) {
            use super::supervisor::{LONG, LONG_APPLIED};
            LONG.store(on, Ordering::Release);
            // The control task sets the watchdog's period at its next tick.
            while LONG_APPLIED.load(Ordering::Acquire) != on {
                cortex_m::asm::wfi();
            }
        }
    }
}

#[cfg(target_os = "none")]
extern "C" {
    static mut _stack_start: u32;
    static mut __euninit: u32;
}

/// The deepest the stack has been since reset, bytes: cortex-m-rt's
/// `paint-stack` fills the free RAM with a pattern before `main`.
#[cfg(target_os = "none")]
pub fn stack_used() -> u32 {
    // SAFETY: reads (only) the free region between the statics and the stack
    // top, word by word, until the first word the stack has written.
    unsafe {
        let top = &raw const _stack_start as usize;
        let mut p = &raw const __euninit as usize;
        while p < top && core::ptr::read_volatile(p as *const u32) == 0xCCCC_CCCC {
            p += 4;
        }
        (top - p) as u32
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "fpi-firmware runs on the STM32F405 driver board or on the emulated board:\n  \
         cargo fw                  build and flash the board (probe-rs)\n  \
         fpi board emulate         run it on QEMU's netduinoplus2, link on a TCP port\n\
         The host tools live in host/ (cargo run -p fpi-host --bin fpi)."
    );
    std::process::exit(2);
}
