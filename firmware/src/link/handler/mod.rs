//! The link task's command handler: reads a request, checks it against the running
//! model and the board, turns it into an [`Order`] for the control ISR or answers
//! it from the shared state, and writes the reply.
//!
//! It runs at the lowest priority (the board's idle loop), so parsing, validation,
//! model loading and flash writes never delay a control tick. It reaches the ISR
//! only through the [`Exchange`], briefly locked, and waits for an order to be
//! applied (one tick) so every acknowledgement carries the tick at which it took
//! effect. Everything a request carries is checked here before the ISR sees it:
//! positions against the model's stroke, frequencies against the control rate,
//! upload steps against their order, models against the shared validator.

use core::fmt::Write as _;

use embedded_storage::nor_flash::NorFlash;
use heapless::Vec;
use piezo_fpi::lead::LeadGain;
use piezo_fpi::q::{LeadRatio, Micrometres};

use super::frame::{self, FrameError};
use super::pace::{reached, Pace};
use super::protocol::{
    Analysis, Batch, BenchOrder, BoardKind, Command, Counters, FaultReport, FrontEndKind, Header,
    Hello, LinkKind, Refusal, Reply, ReplyHeader, ResetReason, SlotReport, Status, Text,
    TriggerSettings, EVERY_AXIS, MAX_FRAME, MAX_MODEL_BYTES, NO_SEQ, VERSION,
};
use super::refusal::{refuse, Refuse};
use super::upload::Upload;
use crate::board::capacity::{
    BOARD, CREEP_TERMS, IMAGE_BYTES, OPERATORS, RATE_HZ, RECORDER_SAMPLES, STREAM_POINTS,
    TABLE_INTERVALS,
};
use crate::board::storage::{ModelFlash, Slot, Stored};
use crate::control::analyser::AnalyseOrder;
use crate::control::exchange::{AxisSet, Exchange, Order, Posted, Refused};
use crate::control::recorder::{signal, Packer};
use crate::control::reference::wave::Wave;
use crate::control::reference::SourceOrder;
use crate::control::slots::{Origin, Running, Spare, Summary};
use crate::control::tracking::LoopMode;

mod axes;
mod models;
mod settings;
mod trigger;

/// What the handler needs from the board it runs on (of `N` axes).
pub trait Board<const N: usize = 1> {
    /// Runs `f` with the exchange locked (the control ISR waits meanwhile).
    fn exchange<R>(&mut self, f: impl FnOnce(&mut Exchange<'_, N>) -> R) -> R;
    /// Waits a little: at least until the next control tick has run.
    fn wait(&mut self);
    /// The deepest the stack has been since start-up, bytes, where the board can
    /// tell (a painted stack).
    fn stack_high_water(&self) -> Option<u32> {
        None
    }
    /// A long operation of the link task begins (`true`) or ends: a flash erase,
    /// which stalls the STM32F405 for up to 2 s. The board runs its watchdog with
    /// a longer period meanwhile.
    fn long_operation(&mut self, _on: bool) {}
}

/// Waits until the board's tick reaches `due`.
fn wait_until<const N: usize>(board: &mut impl Board<N>, due: u32) {
    while !reached(board.exchange(|x| x.snapshot.tick), due) {
        board.wait();
    }
}

/// Ticks the handler waits for an order to be applied before giving up.
const APPLY_TIMEOUT_WAITS: u32 = 100_000;
/// Fastest move, µm/s (a 40 µm stroke in 1.3 ms; the top of the `I16F16` range).
const MAX_SPEED_UM_S: i64 = 30_000;

/// µm (or V, N) with three decimals, for reasons.
pub(super) struct Milli(pub(super) i32);

impl Milli {
    /// `x` (µm, V, N, ms…) held to the `I16F16` range: fixed-point text, no
    /// float formatting in the firmware.
    pub(super) fn of(x: f32) -> Self {
        Self((x.clamp(-32_767.0, 32_767.0) * 65_536.0) as i32)
    }
}

impl core::fmt::Display for Milli {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let m = (self.0 as i64 * 1000 + (1 << 15)).div_euclid(1 << 16);
        let sign = if m < 0 { "-" } else { "" };
        write!(f, "{sign}{}.{:03}", m.abs() / 1000, m.abs() % 1000)
    }
}

/// The link task's state (its configuration is the board kind and the flash)
/// on a board of `N` axes.
///
/// Each axis runs its own model; the board holds one spare model store,
/// which receives the next model for whichever axis, and keeps the model
/// it replaces. The flash keeps the first axis's model (the other axes
/// start with the factory model).
pub struct Handler<F, const N: usize = 1> {
    pub(super) kind: BoardKind,
    /// Each axis's running model.
    pub(super) summary: [Summary; N],
    /// The axis the request being handled addresses (0 for one that
    /// addresses none).
    pub(super) axis: usize,
    /// The axes its orders go to.
    axes: AxisSet,
    pub(super) spare: Option<Spare>,
    pub(super) upload: Upload,
    pub(super) flash: ModelFlash<F>,
    pub(super) stored: Option<Stored>,
    /// What the flash slots held at start-up.
    pub(super) slots: [SlotReport; 2],
    /// Why the board last started.
    reset: ResetReason,
    /// A `Reset` was answered.
    reset_requested: bool,
    pub(super) signals: u8,
    /// Axes whose samples alternate in the recording (every axis recorded),
    /// else 1.
    stride: u8,
    pub(super) timeout_ms: u32,
    /// The trigger output's settings, every mode's levels kept.
    pub(super) trigger: TriggerSettings,
    pub(super) counters: Counters,
    /// The tick of the request being handled (see [`ReplyHeader::tick`]).
    pub(super) tick: Option<u32>,
    /// The axis and length of the running model's image that the upload
    /// buffer still holds (a model received, stored or restored since no
    /// upload began).
    pub(super) image_len: Option<(usize, usize)>,
    /// The link and, on the emulated board, its pace.
    pace: Pace,
    /// The analog front end: the build's, or the one the emulated board's
    /// bench was last set to (the hello names it).
    front_end: FrontEndKind,
}

impl<F: NorFlash, const N: usize> Handler<F, N> {
    /// Starts the board's model on the first axis: the newest stored model
    /// that is intact and that the validator takes, else the older one, else
    /// the factory default `factory`, in `store`; what each flash slot held is
    /// kept for `ModelInfo`. Returns the handler (holding `spare`) and the
    /// first axis's running model for the control loop; every other axis's
    /// comes from [`Handler::boot_axis`] (until then it reads as the first
    /// axis's). `None` only if not even the factory image loads (a firmware
    /// built with a model that does not fit).
    pub fn boot(
        kind: BoardKind,
        store: Spare,
        spare: Spare,
        image: &'static mut [u8; IMAGE_BYTES],
        mut flash: ModelFlash<F>,
        factory: &[u8],
        reset: ResetReason,
    ) -> Option<(Self, Running)> {
        let mut a = Some(store);
        let survey = flash.survey().unwrap_or([Slot::Damaged; 2]);
        let mut slots = survey.map(|s| match s {
            Slot::Empty => SlotReport::Empty,
            Slot::Holds(st) => SlotReport::Valid(st.generation),
            Slot::Damaged => SlotReport::Damaged,
        });
        // The newest intact model the validator takes, else the older, else the
        // factory model.
        let mut candidates = survey.map(|s| match s {
            Slot::Holds(st) => Some(st),
            _ => None,
        });
        candidates.sort_unstable_by_key(|c| core::cmp::Reverse(c.map(|s| s.generation)));
        let mut chosen = None;
        for s in candidates.into_iter().flatten() {
            let Some(store) = a.take() else { break };
            match Self::stored(store, &mut flash, s, image) {
                Ok(r) => {
                    chosen = Some((r, s));
                    break;
                }
                Err(back) => {
                    a = Some(back);
                    if let Some(r) = slots.get_mut(s.slot as usize) {
                        *r = SlotReport::Refused(s.generation);
                    }
                }
            }
        }
        let image_len = chosen.as_ref().map(|(_, s)| (0, s.len as usize));
        let (first, stored) = match chosen {
            Some((r, s)) => (r, Some(s)),
            None => (factory_running(a?, factory)?, None),
        };
        let handler = Self {
            kind,
            summary: [*first.summary(); N],
            axis: 0,
            axes: AxisSet::ALL,
            spare: Some(spare),
            upload: Upload {
                image,
                expected: None,
                received: 0,
            },
            flash,
            stored,
            slots,
            reset,
            reset_requested: false,
            signals: signal::ALL,
            stride: 1,
            timeout_ms: 0,
            trigger: TriggerSettings::DEFAULT,
            counters: Counters::default(),
            tick: None,
            image_len,
            pace: match kind {
                BoardKind::Emulated => Pace::emulating(LinkKind::Uart),
                BoardKind::Driver => Pace::hardware(LinkKind::Uart),
            },
            front_end: crate::board::definition::FRONT_END,
        };
        Some((handler, first))
    }

    /// Starts axis `axis`'s model (after [`Handler::boot`], on a board of
    /// several axes): the factory default `factory`, in `store`; `None` if it
    /// does not load or the board has no such axis.
    pub fn boot_axis(&mut self, axis: usize, store: Spare, factory: &[u8]) -> Option<Running> {
        let running = factory_running(store, factory)?;
        *self.summary.get_mut(axis)? = *running.summary();
        Some(running)
    }

    /// The stored model `s`, read into `image` and loaded into `a`; `a` back if it
    /// does not read back or does not load.
    fn stored(
        a: Spare,
        flash: &mut ModelFlash<F>,
        s: Stored,
        image: &mut [u8; IMAGE_BYTES],
    ) -> Result<Running, Spare> {
        let Ok(n) = flash.read(&s, image) else {
            return Err(a);
        };
        let img = image.get(..n).unwrap_or(&[]);
        running_from(a, img, Origin::Stored(s.generation))
    }

    /// Whether a `Reset` command was answered: the board resets once the reply
    /// has gone out.
    pub fn reset_requested(&self) -> bool {
        self.reset_requested
    }

    /// The link's counters.
    pub const fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The first axis's running model's summary.
    pub const fn summary(&self) -> &Summary {
        &self.summary[0]
    }

    /// Each axis's running model's summary.
    pub const fn summaries(&self) -> &[Summary; N] {
        &self.summary
    }

    /// The running model of the axis the request addresses.
    pub(super) fn model(&self) -> &Summary {
        self.summary.get(self.axis).unwrap_or(&self.summary[0])
    }

    /// The axes an order of the request goes to: the one it addresses, or
    /// every axis for an order that addresses none.
    fn addressed(&self, cmd: &Command<'_>) -> AxisSet {
        match cmd.axis() {
            None | Some(EVERY_AXIS) => AxisSet::ALL,
            Some(a) => AxisSet::one(a as usize),
        }
    }

    /// Counts a frame the reader dropped for being longer than the buffer and
    /// writes the refusal into `out`; its length.
    pub fn overlong(&mut self, scratch: &mut [u8], out: &mut [u8]) -> usize {
        self.counters.overlong = self.counters.overlong.wrapping_add(1);
        self.counters.malformed = self.counters.malformed.wrapping_add(1);
        self.counters.refused = self.counters.refused.wrapping_add(1);
        let reply = Reply::Refused {
            code: Refusal::Malformed,
            reason: refuse(
                Refusal::Malformed,
                format_args!("frame longer than {MAX_FRAME} bytes"),
            )
            .1,
        };
        let header = ReplyHeader {
            version: VERSION,
            seq: NO_SEQ,
            tick: 0,
        };
        frame::encode(&header, &reply, scratch, out).unwrap_or(0)
    }

    /// Handles one received frame (decoded in place) and writes the reply frame
    /// into `out` (`scratch` is working space); the reply's length.
    pub fn handle(
        &mut self,
        board: &mut impl Board<N>,
        request: &mut [u8],
        scratch: &mut [u8],
        out: &mut [u8],
    ) -> usize {
        self.tick = None;
        if self.pace.paced() {
            let now = board.exchange(|x| x.snapshot.tick);
            // Framed: a delimiter and about one COBS byte per 254.
            let due = self.pace.received(now, request.len() + 2);
            wait_until(board, due);
        }
        let (seq, reply) = match frame::decode::<Header>(request) {
            Ok((h, _)) if h.version != VERSION => {
                self.counters.version = self.counters.version.wrapping_add(1);
                let reason = format_args!(
                    "protocol {} requested, this firmware speaks {VERSION}",
                    h.version
                );
                (h.seq, Err(refuse(Refusal::Version, reason)))
            }
            Ok((h, body)) => match frame::body::<Command<'_>>(body) {
                Ok(cmd) => {
                    self.counters.requests = self.counters.requests.wrapping_add(1);
                    let reply = self.command(board, h.seq, cmd);
                    if self.tick.is_none() {
                        // Refused before it reached the exchange: still a heartbeat.
                        self.locked(board, |_| ());
                    }
                    (h.seq, reply)
                }
                Err(e) => (h.seq, Err(self.unreadable(e))),
            },
            Err(e) => (NO_SEQ, Err(self.unreadable(e))),
        };
        let reply = reply.unwrap_or_else(|(code, reason)| {
            self.counters.refused = self.counters.refused.wrapping_add(1);
            Reply::Refused { code, reason }
        });
        let tick = match self.tick {
            Some(t) => t,
            None => board.exchange(|x| x.snapshot.tick.wrapping_add(1)),
        };
        let header = ReplyHeader {
            version: VERSION,
            seq,
            tick,
        };
        let n = frame::encode(&header, &reply, scratch, out).unwrap_or(0);
        if self.pace.paced() {
            let now = board.exchange(|x| x.snapshot.tick);
            let due = self.pace.sent(now, n);
            wait_until(board, due);
        }
        n
    }

    /// The link this board answers on (the emulated board: the link it paces
    /// its own as).
    pub const fn link(&self) -> LinkKind {
        self.pace.link()
    }

    /// The emulated board paces its link as `link` from now on (a board's
    /// link is what it is: there this only names it).
    pub fn pace_as(&mut self, link: LinkKind) {
        self.pace = self.pace.relinked(link);
    }

    /// The next frame came over `link` (a board with more than one link): its
    /// hello names it. The emulated board's pace stays what the bench set.
    pub fn arrived_on(&mut self, link: LinkKind) {
        if !self.pace.paced() {
            self.pace = Pace::hardware(link);
        }
    }

    /// Stops pacing the link: for a replay of requests at the ticks a paced
    /// board took them up (the host's twin), which must not wait again.
    pub fn unpaced(&mut self) {
        self.pace = Pace::hardware(self.pace.link());
    }

    /// Runs `f` on the exchange and counts the request as a heartbeat in the same
    /// lock; the request's tick is the next one (the first to see its effect).
    fn locked<R>(
        &mut self,
        board: &mut impl Board<N>,
        f: impl FnOnce(&mut Exchange<'_, N>) -> R,
    ) -> R {
        let (r, tick) = board.exchange(|x| {
            x.heartbeats = x.heartbeats.wrapping_add(1);
            (f(x), x.snapshot.tick.wrapping_add(1))
        });
        self.tick = Some(tick);
        r
    }

    fn unreadable(&mut self, e: FrameError) -> Refuse {
        let c = &mut self.counters;
        match e {
            FrameError::UnknownKind => c.unknown = c.unknown.wrapping_add(1),
            FrameError::Crc => {
                c.crc_errors = c.crc_errors.wrapping_add(1);
                c.malformed = c.malformed.wrapping_add(1);
            }
            _ => c.malformed = c.malformed.wrapping_add(1),
        }
        refuse(e.refusal(), format_args!("{}", e.message()))
    }

    // Out of line: one copy of the dispatch, wherever the frame came from.
    #[inline(never)]
    fn command(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        cmd: Command<'_>,
    ) -> Result<Reply, Refuse> {
        // A setting's change is the named command that makes it, handled below
        // with that command's checks (translated first: no recursion, so the
        // handler stays one inlined function).
        let cmd = match cmd {
            Command::SettingSet { path, value } => match self.setting_change(board, path, value)? {
                Some(named) => named,
                None => return self.ack(board),
            },
            cmd => cmd,
        };
        // `record` alone takes every axis at once.
        let every = matches!(
            cmd,
            Command::Record {
                axis: EVERY_AXIS,
                ..
            }
        );
        match cmd.axis() {
            Some(EVERY_AXIS) if !every => {
                return Err(refuse(
                    Refusal::Axis,
                    format_args!("only `record` addresses every axis at once: name one axis"),
                ))
            }
            Some(axis) if axis as usize >= N && !every => {
                return Err(refuse(
                    Refusal::Axis,
                    format_args!(
                        "axis {} does not exist: this board has {N} ({})",
                        axis_name(axis as usize),
                        AxisNames(N)
                    ),
                ))
            }
            _ => {}
        }
        self.axis = cmd.axis().filter(|_| !every).map_or(0, usize::from);
        self.axes = self.addressed(&cmd);
        match cmd {
            Command::Hello => self.ack(board).map(|_| Reply::Hello(self.hello())),
            Command::Status { axis } => {
                let summary = *self.model();
                Ok(Reply::Status(
                    self.locked(board, |x| status(x, &summary, axis)),
                ))
            }
            Command::Ping => self.ack(board),
            Command::Move { target, speed, .. } => {
                let target = self.in_stroke("target", target)?;
                let step = move_step(speed)?;
                self.order(
                    board,
                    seq,
                    Order::Source(SourceOrder::Move { target, step }),
                )
            }
            Command::MoveAxes {
                mask,
                targets,
                speed,
            } => self.move_axes(board, seq, mask, &targets, speed),
            Command::Step {
                target,
                duration_us,
                ..
            } => {
                let target = self.in_stroke("target", target)?;
                if !(1..=1_000_000).contains(&duration_us) {
                    return Err(refuse(
                        Refusal::BadArgument,
                        format_args!("step duration {duration_us} µs outside 1 µs – 1 s"),
                    ));
                }
                let ticks = (duration_us as u64 * RATE_HZ as u64).div_ceil(1_000_000) as u32;
                let phase_step = crate::control::reference::step_phase_for(ticks);
                self.order(
                    board,
                    seq,
                    Order::Source(SourceOrder::Step { target, phase_step }),
                )
            }
            Command::Wave {
                shape,
                offset,
                amplitude,
                freq_mhz,
                cycles,
                ..
            } => {
                let wave = self.wave(shape, offset, amplitude, freq_mhz, cycles)?;
                self.order(board, seq, Order::Source(SourceOrder::Wave(wave)))
            }
            Command::Points { first, points, .. } => self.points(board, first, &points),
            Command::Stream { interval, .. } => self.stream(board, seq, interval),
            Command::StreamEnd { .. } => {
                self.locked(board, |x| x.points.end());
                Ok(Reply::Ack)
            }
            Command::StreamClear { .. } => {
                self.locked(board, |x| x.points.clear());
                Ok(Reply::Ack)
            }
            Command::Analog { .. } => self.order(board, seq, Order::Source(SourceOrder::Analog)),
            Command::Hold { .. } => self.order(board, seq, Order::Source(SourceOrder::Hold)),
            Command::Safe => self.order(board, seq, Order::Safe),
            Command::ClearFault => self.order(board, seq, Order::ClearFault),
            Command::Drive { compensated, .. } => {
                self.order(board, seq, Order::Drive { compensated })
            }
            Command::Loop { mode, .. } => {
                let axis = self.axis;
                let damping_on = board.exchange(|x| x.snapshot.axis(axis).damping_on);
                if mode != LoopMode::Open {
                    self.stable_with(damping_on, mode)?;
                }
                self.order(board, seq, Order::Loop(mode))
            }
            Command::Damping { on, .. } => {
                let axis = self.axis;
                let mode = board.exchange(|x| x.snapshot.axis(axis).loop_mode);
                if !on && mode != LoopMode::Open {
                    self.stable_with(false, mode)?;
                }
                self.order(board, seq, Order::Damping(on))
            }
            Command::Shaping { on, .. } => self.order(board, seq, Order::Shaping(on)),
            Command::TriggerIn { starts, .. } => self.order(board, seq, Order::TriggerIn(starts)),
            Command::Trigger { settings, .. } => {
                let t = trigger::condition(&settings)?;
                let reply = self.order(board, seq, Order::Trigger(t))?;
                self.trigger = settings;
                Ok(reply)
            }
            Command::LeadRatio { ratio, .. } => {
                let gain = self.lead_start(ratio)?;
                self.order(board, seq, Order::LeadRatio(gain))
            }
            Command::Analyse {
                freq_mhz,
                amplitude,
                settle,
                cycles,
                ..
            } => {
                let o = self.analyse_order(board, freq_mhz, amplitude, settle, cycles)?;
                self.order(board, seq, Order::Analyse(o))
            }
            Command::AnalysisResult { .. } => {
                let r = self.locked(board, |x| x.analysis);
                Ok(Reply::Analysis(r.map(|a| Analysis {
                    freq_mhz: a.freq_mhz,
                    ticks: a.ticks,
                    sums: a.sums,
                    faulted: a.faulted,
                    governed: a.governed,
                })))
            }
            Command::ModelRead { offset, .. } => self.model_bytes(board, offset),
            Command::SettingGet { path } => self.setting_get(board, path),
            // Translated into its named command above.
            Command::SettingSet { .. } => self.ack(board),
            Command::Supervise { timeout_ms } => {
                self.timeout_ms = timeout_ms;
                self.supervise(board, seq, timeout_ms)
            }
            Command::Record {
                decimation,
                signals,
                ..
            } => {
                if decimation == 0 {
                    return Err(refuse(
                        Refusal::BadArgument,
                        format_args!("decimation {decimation}: keep one tick in 1 or more"),
                    ));
                }
                let done = self.order(board, seq, Order::Record { decimation })?;
                self.signals = signals;
                self.stride = if every { N as u8 } else { 1 };
                Ok(done)
            }
            Command::RecordStop => self.order(board, seq, Order::StopRecording),
            Command::Raster(r) => self.raster(board, seq, &r),
            Command::Decoupling {
                input,
                output,
                preload,
            } => self.decoupling(board, seq, &input, &output, &preload),
            Command::ReadRecord { max } => {
                let b = batch(board, Packer::interleaved(self.signals, self.stride), max);
                self.locked(board, |_| ());
                Ok(Reply::Record(b))
            }
            Command::ModelBegin { len, crc } => self.begin(board, len, crc),
            Command::ModelChunk { offset, data } => self.chunk(board, offset, data),
            Command::ModelCommit { store, .. } => self.commit(board, seq, store),
            Command::ModelInfo { .. } => self.ack(board).map(|_| Reply::Model(self.model_report())),
            Command::ModelFactory { .. } => self.factory(board, seq),
            Command::Counters => {
                self.counters.stack_bytes = board.stack_high_water().unwrap_or(0);
                self.ack(board).map(|_| Reply::Counters(self.counters))
            }
            Command::Reset => {
                self.reset_requested = true;
                self.ack(board)
            }
            Command::Bench(BenchOrder::DamageStored) if self.kind == BoardKind::Emulated => {
                self.damage_stored(board)
            }
            Command::Bench(BenchOrder::Stage(v)) if self.kind == BoardKind::Emulated => {
                if let Err((key, value, (lo, hi))) = v.check() {
                    let given = if value.is_finite() {
                        ""
                    } else {
                        " (not a number)"
                    };
                    return Err(refuse(
                        Refusal::BadArgument,
                        format_args!(
                            "stage {key} = {}{given}: outside {}–{}",
                            Milli::of(value),
                            Milli::of(lo),
                            Milli::of(hi)
                        ),
                    ));
                }
                self.order(board, seq, Order::Bench(BenchOrder::Stage(v)))
            }
            Command::Bench(BenchOrder::Link(link)) if self.kind == BoardKind::Emulated => {
                // This reply already leaves at the new pace.
                self.pace_as(link);
                self.ack(board)
            }
            Command::Bench(b) => match self.kind {
                BoardKind::Emulated => {
                    let done = self.order(board, seq, Order::Bench(b));
                    if let (Ok(_), BenchOrder::FrontEnd(kind)) = (&done, b) {
                        self.front_end = kind;
                    }
                    done
                }
                BoardKind::Driver => Err(refuse(
                    Refusal::NotEmulated,
                    format_args!("bench orders exist only on the emulated board"),
                )),
            },
        }
    }

    /// Clears a byte of the newest stored model (a fault-injection aid of the
    /// emulated board).
    fn damage_stored(&mut self, board: &mut impl Board<N>) -> Result<Reply, Refuse> {
        let Some(s) = self.flash.newest().ok().flatten() else {
            return Err(refuse(Refusal::Storage, format_args!("no model is stored")));
        };
        self.flash
            .damage(&s, s.len / 2)
            .map_err(|e| refuse(Refusal::Storage, format_args!("{}", e.message())))?;
        self.ack(board)
    }

    /// Acknowledges a request that only counts as a heartbeat.
    pub(super) fn ack(&mut self, board: &mut impl Board<N>) -> Result<Reply, Refuse> {
        self.locked(board, |_| ());
        Ok(Reply::Ack)
    }

    /// Posts an order (the request's heartbeat with it), waits until the ISR has
    /// applied it, and acknowledges it; the request's tick is the one it took
    /// effect at.
    fn order(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        order: Order,
    ) -> Result<Reply, Refuse> {
        self.post(board, seq, order).map(|_| Reply::Ack)
    }

    pub(super) fn post(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        order: Order,
    ) -> Result<u32, Refuse> {
        let mut order = Some(order);
        let axes = self.axes;
        board.exchange(|x| {
            x.heartbeats = x.heartbeats.wrapping_add(1);
            x.applied = None;
            x.order = order.take().map(|order| Posted { seq, axes, order });
        });
        for _ in 0..APPLY_TIMEOUT_WAITS {
            board.wait();
            let applied = board.exchange(|x| x.applied.filter(|a| a.seq == seq));
            if let Some(a) = applied {
                self.tick = Some(a.tick);
                return a.result.map(|_| a.tick).map_err(refused);
            }
        }
        Err(refuse(
            Refusal::Fault,
            format_args!("the control loop did not take the order"),
        ))
    }

    fn in_stroke(&self, what: &str, x: i32) -> Result<Micrometres, Refuse> {
        self.in_stroke_of(self.axis, what, x)
    }

    /// [`Handler::in_stroke`] of axis `axis`'s model (an order of several
    /// axes checks each).
    pub(super) fn in_stroke_of(
        &self,
        axis: usize,
        what: &str,
        x: i32,
    ) -> Result<Micrometres, Refuse> {
        let r = self.summary.get(axis).unwrap_or(&self.summary[0]).reference;
        if x < r.lo.to_bits() || x > r.hi.to_bits() {
            return Err(refuse(
                Refusal::OutOfRange,
                format_args!(
                    "{what} {} µm outside the stroke {}–{} µm",
                    Milli(x),
                    Milli(r.lo.to_bits()),
                    Milli(r.hi.to_bits())
                ),
            ));
        }
        Ok(Micrometres::from_bits(x))
    }

    /// Refuses a closed loop that the model's dynamics make unstable with the
    /// damping as given (the model was validated with its damping on).
    fn stable_with(&self, damping_on: bool, mode: LoopMode) -> Result<(), Refuse> {
        let s = self.model();
        let damping = if damping_on {
            s.damping.map(|d| *d.spec())
        } else {
            None
        };
        let feedback = s.feedback.map(|f| *f.spec());
        let checked = match (mode, s.dynamics) {
            (LoopMode::Open, _) | (_, None) => Ok(()),
            (_, Some(d)) => piezo_fpi::stability::check(
                RATE_HZ,
                Some(&d),
                s.channel.split.to_bits(),
                damping.as_ref(),
                feedback.as_ref(),
            ),
        };
        checked.map_err(|_| {
            refuse(
                Refusal::BadArgument,
                format_args!(
                    "unstable on the {} Hz mode without damping: keep it on or load gains \
                     tuned without",
                    Milli(
                        s.dynamics
                            .map_or(0, |d| (((d.mode_mhz as u64) << 16) / 1000) as i32)
                    )
                ),
            )
        })
    }

    /// The learned mass ratio to start from, `ratio` (`I2F30` bits): the
    /// running model must apply the lead, and `ratio` lie in `[1/2, 2)`.
    fn lead_start(&self, ratio: i32) -> Result<LeadGain, Refuse> {
        if !self.model().lead.is_some_and(|l| l.applied) {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("the running model applies no learned mass ratio: load a tuning"),
            ));
        }
        LeadGain::starting_at(LeadRatio::from_bits(ratio)).ok_or_else(|| {
            refuse(
                Refusal::BadArgument,
                format_args!(
                    "mass ratio {}/1000: from 500/1000 up to 2",
                    (i64::from(ratio) * 1000) >> 30
                ),
            )
        })
    }

    /// An analysis order, checked: a frequency below a quarter of the control
    /// rate, an excitation of at most 5 µm that keeps the stage in its stroke, and
    /// at most [`crate::control::analyser::MAX_TICKS`] correlated.
    fn analyse_order(
        &mut self,
        board: &mut impl Board<N>,
        freq_mhz: u32,
        amplitude: i32,
        settle: u16,
        cycles: u16,
    ) -> Result<AnalyseOrder, Refuse> {
        let top_mhz = RATE_HZ / 4 * 1000;
        if freq_mhz == 0 || freq_mhz >= top_mhz {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("analysis frequency {freq_mhz} mHz: between 0 and {top_mhz} mHz"),
            ));
        }
        if amplitude <= 0 || amplitude > 5 << 16 {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("excitation {} µm: above 0, at most 5 µm", Milli(amplitude)),
            ));
        }
        if cycles == 0 {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("an analysis correlates at least one period"),
            ));
        }
        let axis = self.axis;
        let at = board.exchange(|x| x.snapshot.axis(axis).now.x_ref);
        self.in_stroke(
            "excitation's low point",
            at.to_bits().saturating_sub(amplitude),
        )?;
        self.in_stroke(
            "excitation's high point",
            at.to_bits().saturating_add(amplitude),
        )?;
        let phase_step = Wave::phase_step_for(freq_mhz, RATE_HZ);
        let period = (1u64 << 32).div_ceil(phase_step.max(1) as u64);
        let ticks = |n: u16| (n as u64 * period).min(u32::MAX as u64) as u32;
        let measure_ticks = ticks(cycles);
        if measure_ticks > crate::control::analyser::MAX_TICKS {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!(
                    "{cycles} periods at {freq_mhz} mHz: more than {} ticks",
                    crate::control::analyser::MAX_TICKS
                ),
            ));
        }
        Ok(AnalyseOrder {
            freq_mhz,
            phase_step,
            amplitude: Micrometres::from_bits(amplitude),
            settle_ticks: ticks(settle),
            measure_ticks,
        })
    }

    /// A piece of the running model's image: the factory image, or the upload
    /// buffer while it still holds the running model's.
    fn model_bytes(&mut self, board: &mut impl Board<N>, offset: u32) -> Result<Reply, Refuse> {
        let image: &[u8] = match (self.model().origin, self.image_len) {
            (Origin::Factory, _) => crate::board::factory_model::MODEL_IMAGE,
            (_, Some((axis, n))) if axis == self.axis && self.upload.expected.is_none() => {
                self.upload.image.get(..n).unwrap_or(&[])
            }
            _ => {
                return Err(refuse(
                    Refusal::Upload,
                    format_args!(
                        "an upload has begun since this model was loaded: its image is gone \
                         from the link's buffer (load the model again to read it back)"
                    ),
                ))
            }
        };
        if piezo_fpi::model::image::CRC32.checksum(image) != self.model().crc {
            return Err(refuse(
                Refusal::Upload,
                format_args!("the running model's image is not in the link's buffer"),
            ));
        }
        let start = (offset as usize).min(image.len());
        let end = (start + MAX_MODEL_BYTES).min(image.len());
        let mut data = Vec::new();
        let _ = data.extend_from_slice(image.get(start..end).unwrap_or(&[]));
        let total = image.len() as u32;
        self.ack(board)?;
        Ok(Reply::ModelBytes {
            total,
            offset: start as u32,
            data,
        })
    }

    fn wave(
        &self,
        shape: crate::control::reference::wave::Shape,
        offset: i32,
        amplitude: i32,
        freq_mhz: u32,
        cycles: u32,
    ) -> Result<Wave, Refuse> {
        let nyquist_mhz = RATE_HZ / 2 * 1000;
        if amplitude < 0 {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("amplitude {} µm: must be ≥ 0", Milli(amplitude)),
            ));
        }
        if freq_mhz == 0 || freq_mhz >= nyquist_mhz {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("frequency {freq_mhz} mHz: must lie in 0 < f < {nyquist_mhz} mHz"),
            ));
        }
        self.in_stroke("lowest point", offset.saturating_sub(amplitude))?;
        self.in_stroke("highest point", offset.saturating_add(amplitude))?;
        Ok(Wave {
            shape,
            offset: Micrometres::from_bits(offset),
            amplitude: Micrometres::from_bits(amplitude),
            phase_step: Wave::phase_step_for(freq_mhz, RATE_HZ),
            cycles,
        })
    }

    fn points(
        &mut self,
        board: &mut impl Board<N>,
        first: u32,
        points: &[i32],
    ) -> Result<Reply, Refuse> {
        for (i, &p) in points.iter().enumerate() {
            let mut what = Text::new();
            let _ = write!(what, "point {}", first.wrapping_add(i as u32));
            self.in_stroke(&what, p)?;
        }
        self.locked(board, |x| {
            let q = &mut x.points;
            if first != q.received() {
                return Err(refuse(
                    Refusal::Stream,
                    format_args!("point {first} sent, point {} expected", q.received()),
                ));
            }
            if points.len() > q.free() {
                return Err(refuse(
                    Refusal::Stream,
                    format_args!("{} points sent, room for {}", points.len(), q.free()),
                ));
            }
            for &p in points {
                q.push(Micrometres::from_bits(p));
            }
            Ok(Reply::Ack)
        })
    }

    fn stream(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        interval: u16,
    ) -> Result<Reply, Refuse> {
        if interval == 0 {
            return Err(refuse(
                Refusal::BadArgument,
                format_args!("interval 0 (≥ 1 tick)"),
            ));
        }
        if board.exchange(|x| x.points.is_empty()) {
            return Err(refuse(
                Refusal::Stream,
                format_args!("no points buffered: send points first"),
            ));
        }
        self.order(board, seq, Order::Source(SourceOrder::Stream { interval }))
    }

    fn supervise(
        &mut self,
        board: &mut impl Board<N>,
        seq: u16,
        timeout_ms: u32,
    ) -> Result<Reply, Refuse> {
        let ticks = (timeout_ms as u64 * RATE_HZ as u64 / 1000).min(u32::MAX as u64) as u32;
        self.order(
            board,
            seq,
            Order::Supervise {
                timeout_ticks: ticks,
            },
        )
    }

    fn hello(&self) -> Hello {
        let mut firmware = Text::new();
        let _ = firmware.push_str(env!("CARGO_PKG_VERSION"));
        let l = &BOARD.limits;
        Hello {
            protocol: VERSION,
            firmware,
            board: self.kind,
            rate_hz: RATE_HZ,
            capacity: [
                OPERATORS as u32,
                CREEP_TERMS as u32,
                TABLE_INTERVALS as u32,
                IMAGE_BYTES as u32,
            ],
            buffers: [RECORDER_SAMPLES as u32, STREAM_POINTS as u32],
            limits: [
                l.u_min.to_bits(),
                l.u_max.to_bits(),
                l.max_step.to_bits(),
                l.safe.lo.to_bits(),
                l.safe.hi.to_bits(),
            ],
            reset: self.reset,
            link: self.pace.link(),
            axes: N as u8,
            front_end: self.front_end,
        }
    }
}

/// The step a tick of a move at `speed` (µm/s, `I16F16` bits), or the
/// refusal of a speed outside 0 – [`MAX_SPEED_UM_S`].
pub(super) fn move_step(speed: i32) -> Result<Micrometres, Refuse> {
    if speed <= 0 || speed as i64 > MAX_SPEED_UM_S << 16 {
        return Err(refuse(
            Refusal::BadArgument,
            format_args!("speed {} µm/s outside 0–{MAX_SPEED_UM_S}", Milli(speed)),
        ));
    }
    Ok(Micrometres::from_bits((speed / RATE_HZ as i32).max(1)))
}

/// A running model from the factory image, in `store`.
fn factory_running(store: Spare, factory: &[u8]) -> Option<Running> {
    running_from(store, factory, Origin::Factory).ok()
}

/// `image` loaded into `store` and running, from `origin`; `store` back if
/// it does not load. Out of line: a model's loading and validation is
/// large, and the boot loads the stored model and the factory model of
/// every axis through it.
#[inline(never)]
fn running_from(mut store: Spare, image: &[u8], origin: Origin) -> Result<Running, Spare> {
    if store.load(image).is_err() {
        return Err(store);
    }
    store.activate(image, origin).map_err(|(back, _)| back)
}

/// An axis's name (`x`, `y`, `z`; a number beyond).
pub(super) const fn axis_name(i: usize) -> AxisName {
    AxisName(i)
}

/// An axis's name as text.
pub(super) struct AxisName(usize);

impl core::fmt::Display for AxisName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match crate::link::protocol::AXIS_NAMES.get(self.0) {
            Some(name) => f.write_str(name),
            None => write!(f, "{}", self.0),
        }
    }
}

/// The names of a board's `n` axes, as a list (`x, y`).
struct AxisNames(usize);

impl core::fmt::Display for AxisNames {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        for i in 0..self.0 {
            let sep = if i == 0 { "" } else { ", " };
            write!(f, "{sep}{}", AxisName(i))?;
        }
        Ok(())
    }
}

/// The reason the ISR gave, as a refusal.
pub(super) fn refused(r: Refused) -> Refuse {
    match r {
        Refused::Fault(f) => refuse(
            Refusal::Fault,
            format_args!("fault latched ({}): clear it first", f.message()),
        ),
        Refused::StillRamping => refuse(
            Refusal::StillRamping,
            format_args!("the output is still ramping to the safe voltage"),
        ),
        Refused::NotAtRest => refuse(
            Refusal::NotAtRest,
            format_args!("a new model needs the stage parked: send `safe` first"),
        ),
        Refused::StageNotParked => refuse(
            Refusal::NotAtRest,
            format_args!(
                "the bench swaps the stage only under a parked board (its loops are tuned for \
                 the stage they run on): send `safe` first"
            ),
        ),
        Refused::NoFeedback => refuse(
            Refusal::BadArgument,
            format_args!("the running model has no [feedback] section: load one from `fpi tune`"),
        ),
        Refused::NotHolding => refuse(
            Refusal::BadArgument,
            format_args!("an analysis needs the stage armed and holding still (`move` first)"),
        ),
        Refused::Unstable => refuse(
            Refusal::BadArgument,
            format_args!("that would leave the loop unstable on the stage's mode"),
        ),
        Refused::BenchOfAxes => refuse(
            Refusal::NotEmulated,
            format_args!(
                "the emulated board of several axes takes no bench order but `link` yet (its \
                 stage's faults and variants are one axis's)"
            ),
        ),
        Refused::Axes => refuse(
            Refusal::Axis,
            format_args!(
                "the order addresses no axis of this board, or several where it takes one \
                 (a model swap, an analysis, a stream)"
            ),
        ),
    }
}

/// The status of `axis` (`summary`: its running model's).
fn status<const N: usize>(x: &Exchange<'_, N>, summary: &Summary, axis: u8) -> Status {
    let (b, s) = (&x.snapshot, x.snapshot.axis(axis as usize));
    let (q, r) = (&x.points, &x.recorder);
    Status {
        axis,
        tick: b.tick,
        signals: [
            s.now.x_ref.to_bits(),
            s.now.x_est.to_bits(),
            s.now.voltage.to_bits(),
            s.now.force.to_bits(),
            s.now.x_sensor.to_bits(),
        ],
        fault: s.fault.map(|(f, at)| FaultReport {
            code: f as u8,
            at,
            safe_at: s.safe_at,
        }),
        fault_axis: b.fault_axis,
        amplifier_on: s.now.amplifier_on(),
        source: s.source,
        // The source holding while the governed reference has not reached
        // it yet (a governed move's end) is still on its way: a client
        // waiting for the hold waits for the stage.
        approaching: s.approaching
            || (s.source == fpi_protocol::SourceKind::Hold
                && s.now.status & crate::control::recorder::status::GOVERNED != 0),
        compensated: s.compensated,
        loop_mode: s.loop_mode,
        damping: summary.damping.map(|_| s.damping_on),
        // Sections or taps on the preview's line: either is the model's shaping.
        shaping: (summary.shaping.is_some() || summary.preview.is_some()).then_some(s.shaping_on),
        lead_ratio: summary.lead.map(|l| (s.lead_ratio.to_bits(), l.applied)),
        analysing: s.analysing,
        supervision: [b.timeout_ticks, b.silent_ticks],
        stream: [q.len() as u32, q.free() as u32, q.received(), s.underruns],
        recorder: [r.active() as u32, r.kept(), r.dropped(), r.len() as u32],
        limited_steps: s.limited_steps,
        governed_ticks: s.governed_ticks,
        ended_points: b.ended_points,
        overruns: b.overruns,
        model_crc: summary.crc,
        armed: [s.motion_armed, b.record_armed],
    }
}

/// Up to `max` recorded samples, the `signals` of each.
/// Up to `max` recorded samples, as a batch fills a frame (see [`Batch`]). The
/// exchange is locked for one sample at a time, so the control ISR waits at
/// most a sample's copy however long the batch.
fn batch<const N: usize>(board: &mut impl Board<N>, mut packer: Packer, max: u16) -> Batch {
    let signals = packer.signals();
    for _ in 0..max {
        let Some(next) = board.exchange(|x| x.recorder.peek()) else {
            break;
        };
        if !packer.push(&next) {
            break;
        }
        board.exchange(|x| x.recorder.take());
    }
    let values = packer.values();
    board.exchange(|x| Batch {
        signals,
        decimation: x.recorder.decimation(),
        active: x.recorder.active(),
        dropped: x.recorder.dropped(),
        waiting: x.recorder.len() as u32,
        values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reason_longer_than_the_text_is_cut_not_lost() {
        let long = "é".repeat(60); // 120 bytes
        let (code, t) = refuse(Refusal::BadArgument, format_args!("{long}"));
        assert_eq!(code, Refusal::BadArgument);
        assert_eq!(t.as_str(), "é".repeat(48));
    }
}
