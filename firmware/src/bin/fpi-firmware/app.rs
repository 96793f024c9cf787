#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use core::sync::atomic::Ordering;
    use cortex_m::peripheral::syst::SystClkSource;
    use embedded_hal_nb::serial::Read as _;
    use embedded_io::Write as _;
    use fpi_firmware::board::capacity::{RATE_HZ, RECORDER_SAMPLES, STREAM_POINTS};
    use fpi_firmware::board::factory_model::MODEL_IMAGE;
    use fpi_firmware::control::exchange::Exchange;
    use fpi_firmware::control::recorder::Recorder;
    use fpi_firmware::control::reference::stream::Points;
    use fpi_firmware::control::slots::{Running, Spare};
    use fpi_firmware::link::frame::{FrameReader, Push};
    use fpi_firmware::link::handler::{Board, Handler};
    use fpi_firmware::link::protocol::{LinkKind, MAX_FRAME};
    use heapless::spsc::{Consumer, Producer, Queue};
    use rtic::Mutex;
    use stm32f4xx_hal::pac::USART1;
    use stm32f4xx_hal::serial::{Rx, Tx};

    use super::io;
    use super::io::AXES;

    /// Received bytes between the USART interrupt and the link task.
    const RX_QUEUE: usize = 2048;
    /// Bytes between the USB interrupt and the link task, each way (a request
    /// is at most 1 280 bytes, and the link task takes bytes as they come; a
    /// reply waits for room).
    const USB_QUEUE: usize = 1024;

    #[shared]
    struct Shared {
        exchange: Exchange<'static, AXES>,
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
        handler: Handler<io::Flash, AXES>,
    }

    #[init(local = [
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
        let (stores, spare, image) = super::models::take();
        let mut stores = stores.into_iter().map(Spare::new);
        let (Some(first), Some(spare)) = (stores.next(), Some(Spare::new(spare))) else {
            io::halt("no model store")
        };
        let Some((mut handler, running)) = Handler::boot(
            io::KIND, first, spare, image, flash, MODEL_IMAGE, reset,
        ) else {
            io::halt("the factory model does not load")
        };
        // The other axes' models (a const condition: a board of one axis links
        // no `boot_axis`).
        let mut first = Some(running);
        let mut rest = stores.enumerate();
        let models: [Running; AXES] = core::array::from_fn(|_| {
            let next = match first.take() {
                Some(r) => Some(r),
                None if AXES > 1 => rest
                    .next()
                    .and_then(|(i, store)| handler.boot_axis(i + 1, store, MODEL_IMAGE)),
                None => None,
            };
            next.unwrap_or_else(|| io::halt("the factory model does not load on every axis"))
        });
        if let Some(link) = io::kept_link() {
            handler.pace_as(link);
        }
        let summary = *models[0].summary();
        say!(
            "fpi-firmware: {} axes, control at {} Hz, model crc {} ({} operators), link on USB and USART1",
            AXES as u32,
            RATE_HZ,
            summary.crc,
            summary.shape.operators as u32
        );
        let tick = board.tick(models);

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

    impl<M: Mutex<T = Exchange<'static, AXES>>> Board<AXES> for Link<M> {
        fn exchange<R>(&mut self, f: impl FnOnce(&mut Exchange<'_, AXES>) -> R) -> R {
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

/// The model stores and the model image's buffer (`Handler::boot`): each
/// axis's running model and the spare. The first [`models::IN_CCM`] stores
/// and the buffer lie in the CCM (the core's own 64 KiB at `0x1000_0000`,
/// which no DMA reaches and none of them needs), the others in SRAM.
#[cfg(target_os = "none")]
mod models {
    use core::mem::MaybeUninit;
    use fpi_firmware::board::capacity::{Store, IMAGE_BYTES};

    use super::io::AXES;

    /// Stores in the CCM: two (50 KiB) and the buffer (12.5 KiB) fill it.
    pub const IN_CCM: usize = if AXES + 1 < 2 { AXES + 1 } else { 2 };

    /// What the CCM holds.
    struct Ccm {
        stores: [Store; IN_CCM],
        image: [u8; IMAGE_BYTES],
    }

    /// `NOLOAD` (`memory.x`'s `.ccm`): start-up code leaves it as it is;
    /// [`take`] writes it before anything reads it.
    #[link_section = ".ccm.models"]
    static mut CCM: MaybeUninit<Ccm> = MaybeUninit::uninit();

    /// The stores beyond the CCM's, in SRAM (`.bss`: an empty store is all
    /// zero bytes).
    static mut SRAM_STORES: [Store; AXES + 1 - IN_CCM] = [const { Store::new() }; AXES + 1 - IN_CCM];

    /// Each axis's store, the spare and the image buffer, empty; called
    /// once, from `init`.
    pub fn take() -> (
        [&'static mut Store; AXES],
        &'static mut Store,
        &'static mut [u8; IMAGE_BYTES],
    ) {
        // SAFETY: `init` calls this once, before any task runs and before
        // anything else names the statics; each field of the CCM is written
        // (in place, from constants) before a reference to it is made.
        let (ccm, sram) = unsafe {
            let p = (*core::ptr::addr_of_mut!(CCM)).as_mut_ptr();
            for i in 0..IN_CCM {
                core::ptr::addr_of_mut!((*p).stores[i]).write(Store::new());
            }
            core::ptr::addr_of_mut!((*p).image).write_bytes(0, 1);
            (&mut *p, &mut *core::ptr::addr_of_mut!(SRAM_STORES))
        };
        let mut all = ccm.stores.iter_mut().chain(sram.iter_mut());
        let stores: [&'static mut Store; AXES] = core::array::from_fn(|_| {
            all.next().unwrap_or_else(|| super::io::halt("a store for every axis"))
        });
        let spare = all.next().unwrap_or_else(|| super::io::halt("a spare store"));
        (stores, spare, &mut ccm.image)
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
