//! The emulated board's firmware compiled for the host and run in this process:
//! the control loop, the virtual stage and the link handler
//! ([`fpi_firmware::emulation::virtual_bench::Virtual`]) in a thread that keeps board time with
//! wall-clock time (20 000 ticks per second), behind a [`Port`].
//!
//! It is what `cargo demo` drives where `qemu-system-arm` is not installed, and
//! what `--port virtual` opens: the same firmware code and the same link, but
//! built by the host's compiler, not run on the emulated Cortex-M4. It also boots
//! the host twin ([`super::twin`]).
//!
//! `--port virtual:xy` (or `xyz`, `xy-built`, `xyz-built`) opens a board of
//! two or three axes on that stage of `piezo_sim::axes`
//! ([`fpi_firmware::emulation::virtual_axes::VirtualAxes`]): the XY(Z)
//! stage as designed, or as built. `virtual:usb:xy` paces its link as USB.

use std::collections::VecDeque;
use std::io;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use fpi_firmware::board::capacity::{Store, IMAGE_BYTES, RATE_HZ};
use fpi_firmware::board::definition::internal::{FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC};
use fpi_firmware::board::storage::ModelFlash;
use fpi_firmware::control::exchange::Exchange;
use fpi_firmware::control::recorder::Recorder;
use fpi_firmware::control::reference::stream::Points;
use fpi_firmware::emulation::virtual_axes::VirtualAxes;
use fpi_firmware::emulation::virtual_bench::{EmulatedFlash, Virtual, FLASH_SLOTS};
use fpi_firmware::emulation::virtual_io::SimLink;
use fpi_firmware::emulation::Emulated;
use fpi_firmware::link::handler::Handler;
use fpi_protocol::frame::{FrameReader, Push};
use fpi_protocol::{LinkKind, MAX_FRAME};
use piezo_sim::axes::AxesSpec;

use super::client::link_kind;
use super::port::Port;

/// The port name that opens an in-process board (`virtual:usb` or `virtual:uart`
/// paces its link as that link; plain `virtual` as the UART, as a board boots;
/// `virtual:xy`, `virtual:usb:xyz`… a board of several axes on that stage).
pub const PORT_NAME: &str = "virtual";

/// Whether `port` names an in-process board.
pub fn is_in_process(port: &str) -> bool {
    port.split(':').next() == Some(PORT_NAME)
}

/// An in-process board as its port names it: the link it paces as, and the
/// stage of several axes it drives (none: stage A, one axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spec {
    /// The link it paces as (none: the UART, as a board boots).
    pub link: Option<LinkKind>,
    /// The stage of several axes (`xy`, `xyz`, `xy-built`, `xyz-built`).
    pub stage: Option<AxesSpec>,
}

/// The in-process board `port` names (`virtual[:LINK][:STAGE]`), or why it
/// names none; `None` for a port that is not in-process.
pub fn spec(port: &str) -> Result<Option<Spec>> {
    let mut parts = port.split(':');
    if parts.next() != Some(PORT_NAME) {
        return Ok(None);
    }
    let mut spec = Spec {
        link: None,
        stage: None,
    };
    for part in parts {
        if let (None, Some(l)) = (spec.link, link_kind(part)) {
            spec.link = Some(l);
        } else if let (None, Some(s)) = (spec.stage, AxesSpec::base(part)) {
            spec.stage = Some(s);
        } else {
            return Err(anyhow!(
                "--port {port}: `{part}` is neither a link (uart, usb) nor a stage of several \
                 axes ({}), each named once at most",
                AxesSpec::BASES.join(", ")
            ));
        }
    }
    Ok(Some(spec))
}

/// The handler of an in-process board (its flash is the emulated board's, in RAM).
pub type VirtualHandler = Handler<&'static mut EmulatedFlash>;

fn leak<T>(v: T) -> &'static mut T {
    Box::leak(Box::new(v))
}

/// Boots a virtual board as the emulated board boots: the factory model, empty
/// flash, parked. Its buffers live as long as the process (a few hundred KiB).
pub fn boot() -> Result<(Virtual, VirtualHandler)> {
    let link: &'static SimLink = leak(SimLink::new(FORCE_ADC, SETPOINT_DAC));
    let exchange = Exchange::new(leak(Recorder::new()), leak(Points::new()));
    Virtual::boot(
        link,
        [leak(Store::new()), leak(Store::new())],
        leak([0; IMAGE_BYTES]),
        exchange,
        ModelFlash::new(leak(EmulatedFlash::new()), FLASH_SLOTS),
    )
    .ok_or_else(|| anyhow!("the virtual board does not boot"))
}

/// What the board's thread serves: a board of one axis or several and its
/// link handler.
trait Served: Send {
    /// One control period.
    fn tick(&mut self);
    /// The number of the next tick.
    fn next_tick(&self) -> u32;
    /// Handles a received frame; the reply's length in `out`.
    fn handle(&mut self, frame: &mut [u8], scratch: &mut [u8], out: &mut [u8]) -> usize;
    /// Refuses an overlong frame; the reply's length in `out`.
    fn overlong(&mut self, scratch: &mut [u8], out: &mut [u8]) -> usize;
    /// Whether a `Reset` was answered.
    fn reset_requested(&self) -> bool;
}

impl<B: Emulated<N> + Send, const N: usize> Served for (B, Handler<&'static mut EmulatedFlash, N>) {
    fn tick(&mut self) {
        self.0.period();
    }
    fn next_tick(&self) -> u32 {
        self.0.next_tick()
    }
    fn handle(&mut self, frame: &mut [u8], scratch: &mut [u8], out: &mut [u8]) -> usize {
        self.1.handle(&mut self.0, frame, scratch, out)
    }
    fn overlong(&mut self, scratch: &mut [u8], out: &mut [u8]) -> usize {
        self.1.overlong(scratch, out)
    }
    fn reset_requested(&self) -> bool {
        self.1.reset_requested()
    }
}

/// The handler of an in-process board of `N` axes.
pub type AxesHandler<const N: usize> = Handler<&'static mut EmulatedFlash, N>;

/// Boots a virtual board of `N` axes on `stage`, as [`boot`] boots one.
pub fn boot_axes<const N: usize>(stage: &AxesSpec) -> Result<(VirtualAxes<N>, AxesHandler<N>)> {
    let axes = stage
        .build::<N>(fpi_firmware::emulation::virtual_bench::SEED)
        .ok_or_else(|| anyhow!("the virtual stage of {N} axes does not build"))?;
    let links = [(); N].map(|_| &*leak(SimLink::new(FORCE_ADC, SETPOINT_DAC)));
    let exchange = Exchange::new(leak(Recorder::new()), leak(Points::new()));
    VirtualAxes::boot(
        links,
        [(); N].map(|_| leak(Store::new())),
        leak(Store::new()),
        leak([0; IMAGE_BYTES]),
        exchange,
        ModelFlash::new(leak(EmulatedFlash::new()), FLASH_SLOTS),
        axes,
    )
    .ok_or_else(|| anyhow!("the virtual board of {N} axes does not boot"))
}

/// Boots the board `stage` names (none: stage A, one axis).
fn boot_served(stage: Option<&AxesSpec>) -> Result<Box<dyn Served>> {
    Ok(match stage {
        None => Box::new(boot()?),
        Some(s) if s.axes == 2 => Box::new(boot_axes::<2>(s)?),
        Some(s) => Box::new(boot_axes::<3>(s)?),
    })
}

/// A board in a thread of this process, reached through its byte link.
pub struct InProcess {
    to_board: Option<Sender<Vec<u8>>>,
    from_board: Receiver<Vec<u8>>,
    pending: VecDeque<u8>,
    thread: Option<JoinHandle<()>>,
}

impl InProcess {
    /// Boots a board (stage A, or the stage of several axes `stage`) and
    /// starts its clock.
    pub fn start(stage: Option<AxesSpec>) -> Result<Self> {
        let board = boot_served(stage.as_ref())?;
        let (to_board, requests) = mpsc::channel();
        let (replies, from_board) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("virtual-board".into())
            .spawn(move || serve(board, stage, &requests, &replies))?;
        Ok(Self {
            to_board: Some(to_board),
            from_board,
            pending: VecDeque::new(),
            thread: Some(thread),
        })
    }
}

impl Drop for InProcess {
    fn drop(&mut self) {
        self.to_board = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn stopped() -> io::Error {
    io::Error::new(io::ErrorKind::BrokenPipe, "the in-process board stopped")
}

impl Port for InProcess {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let tx = self.to_board.as_ref().ok_or_else(stopped)?;
        tx.send(bytes.to_vec()).map_err(|_| stopped())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if self.pending.is_empty() {
            match self.from_board.recv_timeout(timeout) {
                Ok(bytes) => self.pending.extend(bytes),
                Err(RecvTimeoutError::Timeout) => return Ok(0),
                Err(RecvTimeoutError::Disconnected) => return Err(stopped()),
            }
        }
        let n = buf.len().min(self.pending.len());
        for (b, p) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *b = p;
        }
        Ok(n)
    }
}

/// The board's thread: ticks as wall-clock time passes, and answers each frame
/// that arrives, as the firmware's link task does. Ends when the host hangs up.
/// A `Reset` boots a fresh board (the in-process board keeps no flash across it).
/// The first control tick runs before the first frame is read, as on a board
/// (its control task starts before its link answers): the status never shows
/// the blank state of before that tick.
fn serve(
    mut board: Box<dyn Served>,
    stage: Option<AxesSpec>,
    requests: &Receiver<Vec<u8>>,
    replies: &Sender<Vec<u8>>,
) {
    let mut reader = FrameReader::<MAX_FRAME>::new();
    let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
    board.tick();
    let mut clock = (Instant::now(), board.next_tick());
    loop {
        let due = clock.1 + (clock.0.elapsed().as_secs_f64() * f64::from(RATE_HZ)) as u32;
        while board.next_tick() < due {
            board.tick();
        }
        let bytes = match requests.recv_timeout(Duration::from_micros(500)) {
            Ok(bytes) => bytes,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        for b in bytes {
            let n = match reader.push(b) {
                Push::Pending => continue,
                Push::Frame => board.handle(reader.frame(), &mut scratch, &mut out),
                Push::Overlong => board.overlong(&mut scratch, &mut out),
            };
            if replies.send(out[..n].to_vec()).is_err() {
                return;
            }
            if board.reset_requested() {
                let Ok(fresh) = boot_served(stage.as_ref()) else {
                    return;
                };
                board = fresh;
                board.tick();
                clock = (Instant::now(), board.next_tick());
            }
        }
    }
}
