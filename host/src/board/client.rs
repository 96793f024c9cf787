//! The host's side of the command link: requests out, replies in, the log of
//! what the board did when.
//!
//! [`Client`] speaks the protocol crate's types (`fpi_protocol`, the firmware's own), so
//! the host and the board cannot disagree on a message. Every request the board
//! read is kept in [`Client::log`] with the tick its reply names (the first tick
//! that saw it); the twin ([`super::twin`]) replays that log to reproduce the run.

use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use fixed::types::I16F16;
use fpi_firmware::control::recorder::Sample;
use fpi_protocol::frame::{self, FrameReader, Push};
use fpi_protocol::FrontEndKind;
use fpi_protocol::LoopMode;
use fpi_protocol::Shape;
use fpi_protocol::{
    Analysis, Batch, BenchOrder, Command, Counters, Header, Hello, LinkKind, ModelReport, Refusal,
    Reply, ReplyHeader, Status, AXIS_NAMES, MAX_CHUNK, MAX_FRAME, MAX_POINTS, NO_SEQ, VERSION,
};
use piezo_fpi::control::Fault;
use piezo_fpi::model::image::CRC32;
use piezo_fpi::q;

use super::inprocess;
use super::port::{self, Port};
use crate::data::Num;

/// How long a reply may take (a model commit with a flash write: much longer).
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(3);
/// How long a model's commit may take: it validates the model and builds its
/// tables before it replies, and one that stores the model in flash erases a
/// 128 KiB sector (up to 2 s on a board; the emulated board validates at a
/// fifth of real time, and slower on a loaded host: a commit without the store
/// once took over 3 s there).
pub const STORE_TIMEOUT: Duration = Duration::from_secs(10);

/// A request the board read, with the first tick that saw it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Logged {
    /// The tick.
    pub tick: u32,
    /// The request's frame as sent (without its delimiter).
    pub frame: Vec<u8>,
}

/// The board refused a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refused {
    /// The request, by name.
    pub what: String,
    /// The refusal's kind.
    pub code: Refusal,
    /// The board's reason.
    pub reason: String,
}

impl Refused {
    /// The error of the board's refusal of `what`.
    fn by(what: String, code: Refusal, reason: &str) -> anyhow::Error {
        Self {
            what,
            code,
            reason: reason.to_string(),
        }
        .into()
    }
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the board refused {}: {} ({:?})",
            self.what, self.reason, self.code
        )
    }
}

impl std::error::Error for Refused {}

/// A command the board took, and faulted on: the fault it latched at or after
/// the tick the command took effect.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Faulted {
    /// The command, by name.
    pub what: String,
    /// The tick the fault latched.
    pub tick: u32,
    /// The fault, for people.
    pub reason: &'static str,
}

impl std::fmt::Display for Faulted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the board took {} and faulted at tick {}: {}; the stage is parking \
             (`status` shows it, `clear-fault` clears it)",
            self.what, self.tick, self.reason
        )
    }
}

impl std::error::Error for Faulted {}

/// How long [`Client::order`] watches the board after a command for a fault
/// it caused, s of board time.
pub const ORDER_WATCH_S: f64 = 0.05;

/// How long a wait for the board's state ([`Client::park`], [`Client::order`])
/// may take.
const PATIENCE: Duration = Duration::from_secs(60);

/// An open link to a board.
pub struct Client {
    port: Box<dyn Port>,
    name: String,
    seq: u16,
    reader: FrameReader<MAX_FRAME>,
    hello: Hello,
    /// The axis its per-axis requests address (0: x).
    axis: u8,
    /// Every request the board read, in order.
    pub log: Vec<Logged>,
}

/// A link by its name on the command line (`uart`, `usb`).
pub fn link_kind(name: &str) -> Option<LinkKind> {
    LinkKind::ALL.iter().copied().find(|l| l.name() == name)
}

/// The largest magnitude of a value the link carries as `I16F16` (µm, V, N,
/// µm/s).
pub const LINK_ABS_MAX: f64 = 32767.999;

/// µm (or V, N, µm/s) as the board's `I16F16` bits, rounded to nearest by the
/// core's conversion ([`q::quantize`]); beyond [`LINK_ABS_MAX`] it saturates
/// (the board then refuses it with its range), NaN is 0. [`to_link`] refuses
/// such values instead.
pub fn bits(x: f64) -> i32 {
    match q::quantize(x, q::SIGNAL_FRAC, LINK_ABS_MAX) {
        Some(b) => b,
        None if x > 0.0 => i32::MAX,
        None if x < 0.0 => i32::MIN,
        None => 0,
    }
}

/// The board's `I16F16` bits as µm (or V, N).
pub fn real(bits: i32) -> f64 {
    I16F16::from_bits(bits).to_num()
}

/// The `I16F16` bits of the value `x` of `what` (for messages, e.g. `--speed`)
/// in `unit`, or why the link cannot carry it: not finite, beyond
/// [`LINK_ABS_MAX`], or not zero but below the format's resolution (it would
/// reach the board as 0).
pub fn to_link(what: &str, x: f64, unit: &str) -> Result<i32> {
    let Some(b) = q::quantize(x, q::SIGNAL_FRAC, LINK_ABS_MAX) else {
        bail!(
            "{what} {} {unit}: not a finite value within ±{LINK_ABS_MAX} {unit} (what the link \
             carries)",
            Num(x)
        );
    };
    if b == 0 && x != 0.0 {
        bail!(
            "{what} {} {unit}: below the link's resolution of {:.3e} {unit} (it would reach the \
             board as 0)",
            Num(x),
            1.0 / f64::from(1u32 << q::SIGNAL_FRAC)
        );
    }
    Ok(b)
}

/// Axis `i`'s name (`x`, `y`, `z`; its number beyond).
pub fn axis_name(i: u8) -> String {
    AXIS_NAMES
        .get(usize::from(i))
        .map_or_else(|| i.to_string(), |n| (*n).to_string())
}

/// The number of the axis named `name` (`x`, `y`, `z`).
pub fn axis_number(name: &str) -> Option<u8> {
    AXIS_NAMES.iter().position(|n| *n == name).map(|i| i as u8)
}

/// A command's name for messages.
fn name_of(c: &Command<'_>) -> String {
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    match c {
        Command::SettingGet { path } => return format!("get {}", text(path)),
        Command::SettingSet { path, value } => {
            return format!("set {} = {}", text(path), text(value))
        }
        _ => {}
    }
    let dbg = format!("{c:?}");
    let end = dbg.find([' ', '(', '{']).unwrap_or(dbg.len());
    dbg[..end].to_string()
}

impl Client {
    /// Opens `port` (a serial device, `tcp:HOST:PORT`, or `virtual`: the board in this
    /// process) and greets the board; refuses a board that speaks another protocol version.
    pub fn open(port: &str) -> Result<Self> {
        let spec = inprocess::spec(port)?;
        let p: Box<dyn Port> = match spec {
            Some(s) => Box::new(inprocess::InProcess::start(s.stage)?),
            None => port::open(port, Duration::from_secs(10))?,
        };
        let link = spec.and_then(|s| s.link);
        let mut c = Self {
            port: p,
            name: port.to_string(),
            seq: 0,
            reader: FrameReader::new(),
            hello: Hello {
                protocol: 0,
                firmware: Default::default(),
                board: fpi_protocol::BoardKind::Driver,
                rate_hz: 0,
                capacity: [0; 4],
                buffers: [0; 2],
                limits: [0; 5],
                reset: fpi_protocol::ResetReason::Unknown,
                link: fpi_protocol::LinkKind::Uart,
                axes: 0,
                front_end: fpi_protocol::FrontEndKind::Internal,
            },
            axis: 0,
            log: Vec::new(),
        };
        let greeted = c.greet().map_err(|e| match c.port.silence() {
            Some(why) => e.context(why),
            None => e,
        })?;
        match greeted {
            (_, Reply::Hello(h)) if h.protocol == VERSION => c.hello = h,
            (_, Reply::Hello(h)) => bail!(
                "the board on {port} speaks protocol {}, these tools {VERSION}: update one of them",
                h.protocol
            ),
            (_, r) => bail!("the board on {port} answered hello with {r:?}"),
        }
        if let Some(link) = link {
            c.pace_as(link)?;
        }
        Ok(c)
    }

    /// Says hello until the board answers: a board that is still starting (or an
    /// emulator whose USART is not enabled yet) drops what it receives, and the
    /// start of a frame lost that way makes the next one unreadable.
    fn greet(&mut self) -> Result<(u32, Reply)> {
        let mut last = None;
        for _ in 0..5 {
            match self.request_within(&Command::Hello, Duration::from_millis(800)) {
                Ok(r) => return Ok(r),
                Err(e) => last = Some(e),
            }
        }
        Err(last.unwrap_or_else(|| anyhow!("no answer to hello")))
    }

    /// The port it was opened on (e.g. `tcp:127.0.0.1:4545`, `virtual`).
    pub fn port_name(&self) -> &str {
        &self.name
    }

    /// The board's identity and capacity.
    pub const fn hello(&self) -> &Hello {
        &self.hello
    }

    /// The tick of the last reply the board sent (its header's), if any.
    pub fn last_tick(&self) -> Option<u32> {
        self.log.last().map(|l| l.tick)
    }

    /// Has the emulated board pace its link as `link` from now on (a real board
    /// refuses: its link is what it is).
    pub fn pace_as(&mut self, link: LinkKind) -> Result<()> {
        self.bench(BenchOrder::Link(link))?;
        self.hello.link = link;
        Ok(())
    }

    /// Has the emulated board convert with the `kind` front end from now on: the
    /// virtual stage's converters (resolution, noise) and the firmware's scales
    /// together (a real board refuses: its converters are what it has).
    pub fn front_end(&mut self, kind: FrontEndKind) -> Result<()> {
        self.bench(BenchOrder::FrontEnd(kind)).map(|_| ())
    }

    /// The axis its per-axis requests address from now on (0: x, 1: y,
    /// 2: z); refused for an axis the board does not have.
    pub fn on_axis(&mut self, axis: u8) -> Result<()> {
        let n = self.hello.axes;
        if axis >= n {
            let names: Vec<&str> = AXIS_NAMES.iter().take(n.into()).copied().collect();
            bail!(
                "the board on {} has {n} axis{} ({}): there is no axis {}",
                self.name,
                if n == 1 { "" } else { "es" },
                names.join(", "),
                axis_name(axis)
            );
        }
        self.axis = axis;
        Ok(())
    }

    /// The axis its per-axis requests address (0: x).
    pub const fn axis(&self) -> u8 {
        self.axis
    }

    /// The control rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        self.hello.rate_hz as f64
    }

    /// Sends a request and waits for its reply: the reply's tick and the reply.
    pub fn request(&mut self, cmd: &Command<'_>) -> Result<(u32, Reply)> {
        self.request_within(cmd, Self::timeout_for(cmd))
    }

    /// How long the board may take to answer `cmd`.
    pub fn timeout_for(cmd: &Command<'_>) -> Duration {
        match cmd {
            Command::ModelCommit { .. } | Command::ModelFactory { .. } => STORE_TIMEOUT,
            _ => REPLY_TIMEOUT,
        }
    }

    /// The port it was opened on.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Passes another client's request frame (`frame`, delimiter included, as
    /// it came: the hub's, [`super::hub`]) to the board and waits for the reply
    /// to request `seq` (any reply where `None`).
    pub fn forward(
        &mut self,
        frame: &[u8],
        seq: Option<u16>,
        timeout: Duration,
    ) -> Result<(ReplyHeader, Reply)> {
        self.exchange(frame, seq, timeout)
    }

    fn request_within(&mut self, cmd: &Command<'_>, timeout: Duration) -> Result<(u32, Reply)> {
        self.seq = self.seq.wrapping_add(1) % NO_SEQ;
        let header = Header {
            version: VERSION,
            seq: self.seq,
        };
        let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
        let n = frame::encode(&header, cmd, &mut scratch, &mut out)
            .map_err(|e| anyhow!("encoding {}: {}", name_of(cmd), e.message()))?;
        let frame = out[..n].to_vec();
        let (h, reply) = self
            .exchange(&frame, Some(self.seq), timeout)
            .with_context(|| format!("request {} ({})", self.seq, name_of(cmd)))?;
        let read = !matches!(
            reply,
            Reply::Refused {
                code: Refusal::Malformed | Refusal::Version | Refusal::Unknown,
                ..
            }
        );
        if read {
            self.log.push(Logged {
                tick: h.tick,
                frame: frame[..n - 1].to_vec(),
            });
        }
        Ok((h.tick, reply))
    }

    /// Sends raw bytes (for tests of the link itself) and reads the next reply.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(ReplyHeader, Reply)> {
        self.exchange(bytes, None, REPLY_TIMEOUT)
    }

    fn exchange(
        &mut self,
        bytes: &[u8],
        seq: Option<u16>,
        timeout: Duration,
    ) -> Result<(ReplyHeader, Reply)> {
        self.port
            .send(bytes)
            .with_context(|| format!("writing to {}", self.name))?;
        let start = Instant::now();
        let mut buf = [0u8; 4096];
        while start.elapsed() < timeout {
            let n = self
                .port
                .recv(&mut buf, Duration::from_millis(20))
                .with_context(|| format!("reading from {}", self.name))?;
            for &b in &buf[..n] {
                if self.reader.push(b) != Push::Frame {
                    continue;
                }
                let Ok((h, body)) = frame::decode::<ReplyHeader>(self.reader.frame()) else {
                    continue;
                };
                let Ok(reply) = frame::body::<Reply>(body) else {
                    continue;
                };
                if seq.is_none_or(|s| s == h.seq) {
                    return Ok((h, reply));
                }
            }
        }
        bail!(
            "no reply from the board on {} within {:.1} s",
            self.name,
            timeout.as_secs_f64()
        )
    }

    /// Sends a request that must be acknowledged; its tick.
    pub fn ack(&mut self, cmd: &Command<'_>) -> Result<u32> {
        match self.request(cmd)? {
            (tick, Reply::Ack) => Ok(tick),
            (_, Reply::Refused { code, reason }) => Err(Refused::by(name_of(cmd), code, &reason)),
            (_, r) => bail!("unexpected reply to {}: {r:?}", name_of(cmd)),
        }
    }

    /// Sends a command that must be acknowledged and checks its effect: a fault
    /// the board latched from the tick it took the command on, within
    /// [`ORDER_WATCH_S`] of board time, is an error ([`Faulted`]); else the tick.
    pub fn order(&mut self, cmd: &Command<'_>) -> Result<u32> {
        let tick = self.ack(cmd)?;
        let settled = tick.saturating_add((self.rate_hz() * ORDER_WATCH_S) as u32);
        let s = self.wait_for(&format!("tick {settled}"), |s| s.tick >= settled)?;
        match s.fault {
            Some(f) if f.at >= tick && f.code != Fault::Stopped as u8 => Err(Faulted {
                what: name_of(cmd),
                tick: f.at,
                reason: Fault::from_code(f.code).map_or("an unknown fault", |f| f.message()),
            }
            .into()),
            _ => Ok(tick),
        }
    }

    /// Opens the addressed axis's loop, parks every axis (each ramps to its
    /// safe voltage, amplifier off) and waits until each is at its safe
    /// voltage; the tick the last got there.
    pub fn park(&mut self) -> Result<u32> {
        self.ack(&Command::Loop {
            axis: self.axis,
            mode: LoopMode::Open,
        })?;
        self.ack(&Command::Safe)?;
        // `safe` parks every axis: each at its safe voltage.
        let here = self.axis;
        let mut at = 0;
        for axis in 0..self.hello.axes.max(1) {
            self.axis = axis;
            let s = self.wait_for("the safe voltage", |s| {
                s.fault.is_some_and(|f| f.safe_at.is_some())
            });
            self.axis = here;
            let s = s?;
            at = at.max(s.fault.and_then(|f| f.safe_at).unwrap_or(s.tick));
        }
        Ok(at)
    }

    /// Polls the status until `done` says so (for up to a minute); that status.
    fn wait_for(&mut self, what: &str, done: impl Fn(&Status) -> bool) -> Result<Status> {
        let start = Instant::now();
        loop {
            let s = self.status()?;
            if done(&s) {
                return Ok(s);
            }
            if start.elapsed() > PATIENCE {
                bail!(
                    "the board on {} did not reach {what} within {} s (tick {})",
                    self.name,
                    PATIENCE.as_secs(),
                    s.tick
                );
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Resets the board and greets it again once it has started; its new hello
    /// (which says why it started). The log starts afresh with the new run.
    pub fn reset(&mut self) -> Result<&Hello> {
        self.ack(&Command::Reset)?;
        std::thread::sleep(Duration::from_millis(300));
        self.log.clear();
        match self.greet()? {
            (_, Reply::Hello(h)) => self.hello = h,
            (_, r) => bail!("unexpected reply to hello after a reset: {r:?}"),
        }
        Ok(&self.hello)
    }

    /// The loop's state.
    pub fn status(&mut self) -> Result<Status> {
        match self.request(&Command::Status { axis: self.axis })? {
            (_, Reply::Status(s)) => Ok(s),
            (_, r) => bail!("unexpected reply to status: {r:?}"),
        }
    }

    /// The running model.
    pub fn model(&mut self) -> Result<ModelReport> {
        match self.request(&Command::ModelInfo { axis: self.axis })? {
            (_, Reply::Model(m)) => Ok(m),
            (_, r) => bail!("unexpected reply to model info: {r:?}"),
        }
    }

    /// One runtime setting's value, JSON, by key path (`/stage/0/damping`; see
    /// [`fpi_protocol::Settings`] and [`super::settings`]).
    pub fn setting(&mut self, path: &str) -> Result<String> {
        let cmd = Command::SettingGet {
            path: path.as_bytes(),
        };
        match self.request(&cmd)? {
            (_, Reply::Setting(v)) => Ok(String::from_utf8_lossy(&v).into_owned()),
            (_, Reply::Refused { code, reason }) => Err(Refused::by(name_of(&cmd), code, &reason)),
            (_, r) => bail!("unexpected reply to a setting's get: {r:?}"),
        }
    }

    /// Sets one runtime setting to `value` (JSON): the board carries it out as
    /// the named command that makes the change, with its checks, and watches
    /// its effect as [`Self::order`] does; the tick.
    pub fn set_setting(&mut self, path: &str, value: &str) -> Result<u32> {
        self.order(&Command::SettingSet {
            path: path.as_bytes(),
            value: value.as_bytes(),
        })
    }

    /// The link's counters.
    pub fn counters(&mut self) -> Result<Counters> {
        match self.request(&Command::Counters)? {
            (_, Reply::Counters(c)) => Ok(c),
            (_, r) => bail!("unexpected reply to counters: {r:?}"),
        }
    }

    /// Ramps to `target_um` at `speed_um_s`, then holds; the tick it started.
    pub fn move_to(&mut self, target_um: f64, speed_um_s: f64) -> Result<u32> {
        self.ack(&Command::Move {
            axis: self.axis,
            target: bits(target_um),
            speed: bits(speed_um_s),
        })
    }

    /// Runs a waveform (`cycles` 0: continuous); the tick its approach started.
    pub fn wave(
        &mut self,
        shape: Shape,
        amplitude_um: f64,
        offset_um: f64,
        freq_hz: f64,
        cycles: u32,
    ) -> Result<u32> {
        self.ack(&Command::Wave {
            axis: self.axis,
            shape,
            offset: bits(offset_um),
            amplitude: bits(amplitude_um),
            freq_mhz: (freq_hz * 1000.0).round() as u32,
            cycles,
        })
    }

    /// An order for the emulated board's virtual bench.
    pub fn bench(&mut self, order: BenchOrder) -> Result<u32> {
        self.ack(&Command::Bench(order))
    }

    /// Uploads a model image and commits it (`store`: also to flash); the tick
    /// the board started running it. Refused (and the old model kept) unless the
    /// stage is parked and the image is valid.
    pub fn upload(
        &mut self,
        image: &[u8],
        store: bool,
        mut progress: impl FnMut(usize),
    ) -> Result<u32> {
        self.ack(&Command::ModelBegin {
            len: image.len() as u32,
            crc: CRC32.checksum(image),
        })?;
        for (k, chunk) in image.chunks(MAX_CHUNK).enumerate() {
            self.ack(&Command::ModelChunk {
                offset: (k * MAX_CHUNK) as u32,
                data: chunk,
            })?;
            progress((k * MAX_CHUNK + chunk.len()).min(image.len()));
        }
        self.ack(&Command::ModelCommit {
            axis: self.axis,
            store,
        })
    }

    /// Takes one batch of recorded samples.
    pub fn read_batch(&mut self) -> Result<Batch> {
        self.read_batch_at().map(|(_, b)| b)
    }

    /// Takes one batch of recorded samples, with the board's tick at its reply.
    pub fn read_batch_at(&mut self) -> Result<(u32, Batch)> {
        match self.request(&Command::ReadRecord { max: u16::MAX })? {
            (tick, Reply::Record(b)) => Ok((tick, b)),
            (_, r) => bail!("unexpected reply to read record: {r:?}"),
        }
    }

    /// Takes the recorded samples waiting when it starts (not those recorded
    /// meanwhile: a recording faster than the link would keep it reading for
    /// ever); the samples and the dropped count so far.
    pub fn drain(&mut self) -> Result<(Vec<Sample>, u32)> {
        let mut out = Vec::new();
        let mut due = None;
        loop {
            let b = self.read_batch()?;
            out.extend(Sample::batch(b.signals, &b.values));
            let due = *due.get_or_insert(out.len() + b.waiting as usize);
            if b.waiting == 0 || out.len() >= due {
                return Ok((out, b.dropped));
            }
        }
    }

    /// Steps to `target_um` along a raised cosine lasting `duration_ms`, then
    /// holds; the tick it started.
    pub fn step(&mut self, target_um: f64, duration_ms: f64) -> Result<u32> {
        self.ack(&Command::Step {
            axis: self.axis,
            target: bits(target_um),
            duration_us: (duration_ms * 1e3).round() as u32,
        })
    }

    /// Switches the model's active damping on or off (bumpless).
    pub fn damping(&mut self, on: bool) -> Result<u32> {
        self.ack(&Command::Damping {
            axis: self.axis,
            on,
        })
    }

    /// Switches the model's reference shaping on or off (bumpless).
    pub fn shaping(&mut self, on: bool) -> Result<u32> {
        self.ack(&Command::Shaping {
            axis: self.axis,
            on,
        })
    }

    /// The last frequency-response analysis (`None` while one runs).
    pub fn analysis(&mut self) -> Result<Option<Analysis>> {
        match self.request(&Command::AnalysisResult { axis: self.axis })? {
            (_, Reply::Analysis(a)) => Ok(a),
            (_, r) => bail!("unexpected reply to analysis result: {r:?}"),
        }
    }

    /// The running model's image, read back in pieces.
    pub fn read_model(&mut self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        loop {
            let offset = out.len() as u32;
            match self.request(&Command::ModelRead {
                axis: self.axis,
                offset,
            })? {
                (
                    _,
                    Reply::ModelBytes {
                        total,
                        offset: o,
                        data,
                    },
                ) => {
                    if o != offset || data.is_empty() && (out.len() as u32) < total {
                        bail!("model read: piece at {o} for a request at {offset}");
                    }
                    out.extend_from_slice(&data);
                    if out.len() as u32 >= total {
                        out.truncate(total as usize);
                        return Ok(out);
                    }
                }
                (_, Reply::Refused { code, reason }) => {
                    return Err(Refused::by("model read".into(), code, &reason))
                }
                (_, r) => bail!("unexpected reply to model read: {r:?}"),
            }
        }
    }

    /// Queues streamed points (µm) from index `first`, as many as fit in one request.
    pub fn points(&mut self, first: u32, points_um: &[f64]) -> Result<u32> {
        let pts: heapless::Vec<i32, MAX_POINTS> = points_um
            .iter()
            .take(MAX_POINTS)
            .map(|&x| bits(x))
            .collect();
        self.ack(&Command::Points {
            axis: self.axis,
            first,
            points: pts,
        })
    }
}

/// The refusal inside an error, if the board refused.
pub fn refusal(e: &anyhow::Error) -> Option<&Refused> {
    e.downcast_ref::<Refused>()
}

/// How a streamed trajectory went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamReport {
    /// Points sent.
    pub points: usize,
    /// The tick the board took the stream order: where the stream started
    /// (its approach to the first point), or, for a stream [`armed`](Self::armed)
    /// for the trigger input, where it was armed (it started on the input's
    /// edge, later).
    pub started: u32,
    /// The stream waited for the trigger input's edge (`fpi board trigger
    /// --start motion`) before it played.
    pub armed: bool,
    /// Ticks the board held a point for want of the next one.
    pub underruns: u32,
}

impl Client {
    /// Streams `points_um` (one every `interval` ticks): fills the board's
    /// buffer, starts the stream, keeps the buffer topped up, ends the stream and
    /// waits until the last point has been played. `progress` gets the number of
    /// points sent; `idle` runs after each batch of points sent and while the
    /// host waits for room (e.g. to read the recorder, whose ring fills in
    /// 26 ms at every tick). The board supervises the host while it streams (500 ms unless
    /// `supervise` set a timeout); supervision the stream switched on is switched
    /// off again when it ends.
    pub fn stream(
        &mut self,
        points_um: &[f64],
        interval: u16,
        mut progress: impl FnMut(usize),
        mut idle: impl FnMut(&mut Self) -> Result<()>,
    ) -> Result<StreamReport> {
        let supervised = self.status()?.supervision[0] != 0;
        self.ack(&Command::StreamClear { axis: self.axis })?;
        let capacity = self.hello.buffers[1] as usize;
        let mut sent = 0;
        while sent < points_um.len() && sent + MAX_POINTS <= capacity {
            sent += self.send_points(sent, points_um)?;
            progress(sent);
            idle(self)?;
        }
        let armed = self.waits_for_trigger()?;
        let started = self.ack(&Command::Stream {
            axis: self.axis,
            interval,
        })?;
        loop {
            let s = self.status()?;
            let free = s.stream[1] as usize;
            // A fault (or anything else) that ended the stream: no more
            // room will come.
            if let Some(f) = s.fault {
                bail!(
                    "the stream ended with {} of the {} points sent still queued: fault {} ({}) at tick {}",
                    s.stream[0],
                    sent,
                    f.code,
                    Fault::from_code(f.code).map_or("an unknown fault", |f| f.message()),
                    f.at
                );
            }
            if sent == points_um.len() {
                self.ack(&Command::StreamEnd { axis: self.axis })?;
                break;
            }
            if free >= MAX_POINTS.min(points_um.len() - sent) {
                sent += self.send_points(sent, points_um)?;
                progress(sent);
                idle(self)?;
            } else {
                idle(self)?;
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        // Until the board has played the last point (and holds it); a
        // stream armed for the trigger input has not started yet.
        let underruns = loop {
            let s = self.status()?;
            let playing = s.source == fpi_protocol::SourceKind::Stream || s.armed[0];
            if !playing || s.fault.is_some() {
                break s.stream[3];
            }
            idle(self)?;
            std::thread::sleep(Duration::from_millis(10));
        };
        if !supervised {
            self.ack(&Command::Supervise { timeout_ms: 0 })?;
        }
        Ok(StreamReport {
            points: sent,
            started,
            armed,
            underruns,
        })
    }

    /// Whether a wave or stream order now waits for the trigger input's edge
    /// (the board's `/stage/0/trigger_in` starts motion).
    pub fn waits_for_trigger(&mut self) -> Result<bool> {
        let v = self.setting("/stage/0/trigger_in")?;
        let starts: fpi_protocol::TriggerStart = serde_json::from_str(&v)
            .with_context(|| format!("the board's /stage/0/trigger_in {v}"))?;
        Ok(starts.motion())
    }

    fn send_points(&mut self, from: usize, points_um: &[f64]) -> Result<usize> {
        let chunk = &points_um[from..points_um.len().min(from + MAX_POINTS)];
        self.points(from as u32, chunk)?;
        Ok(chunk.len())
    }
}
