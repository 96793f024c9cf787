//! `fpi scope`: the board's recorder, streamed live to a page in the browser.
//!
//! The scope arms a live recording on the board ([`Live`]) and serves, on a
//! local HTTP port, a page whose assets are inside the binary (nothing from the
//! internet): a roll-mode and triggered time view, a spectrum, an X–Y view and
//! export to CSV and PNG. Every sample the board records reaches the page: the
//! page decimates for display, never the stream.
//!
//! **Endpoints**
//!
//! | path | what |
//! |---|---|
//! | `GET /` | the page (`index.html`, `scope.js`, `scope.css`) |
//! | `GET /info` | JSON: `rate_hz`, `decimation`, `channels` (`name`, `unit`), `board` |
//! | `GET /stream` | the samples, a never-ending chunked response of messages (below) |
//! | `GET /trigger` | JSON: the board's trigger output settings (`stage/0/trigger/…`) and what its input starts (`input`) |
//! | `POST /trigger` | sets them: a JSON body `{"mode": …, "step_um": …, "input": …}` as `fpi board trigger` and `trigger-in` take them (each optional); the settings the board then holds, or 400 with why |
//! | `POST /report`, `GET /report` | what the page last said it shows (`?report=MS`; for tests) |
//!
//! **A stream message**, little-endian: seven `u32` — the magic `"SCP1"`, the
//! samples in the message, the first sample's tick, the decimation, then the
//! gaps, the missing samples and the board's dropped samples so far — and then
//! the samples' values as `f32`, sample by sample, in `/info`'s channel order.
//! A viewer too slow to take its messages (a tab in the background) loses the
//! messages it could not take, counted in its gaps and missing samples: never
//! silently.

pub mod bench;

use std::io::{Read, Write};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use fpi_firmware::control::recorder::Sample;
use serde_json::json;
use tiny_http::{Header, Method, Request, Response, Server, StatusCode};

use crate::board::client::Client;
use crate::board::live::{Counts, Live, SharedClient};
use crate::board::recording;

/// The page and its assets, inside the binary.
const ASSETS: [(&str, &str, &str); 3] = [
    ("/", "text/html; charset=utf-8", include_str!("index.html")),
    (
        "/scope.js",
        "text/javascript; charset=utf-8",
        include_str!("scope.js"),
    ),
    (
        "/scope.css",
        "text/css; charset=utf-8",
        include_str!("scope.css"),
    ),
];

/// A stream message's first word: `"SCP1"`.
pub const MAGIC: u32 = u32::from_le_bytes(*b"SCP1");
/// A stream message's header: seven `u32`.
pub const HEADER_BYTES: usize = 28;
/// How often the recording is read and its samples sent, at most.
const PUMP: Duration = Duration::from_millis(5);
/// Messages a viewer may have waiting (about 20 s of a stream read every
/// 5 ms); beyond, its messages are lost and counted.
const QUEUE: usize = 4096;
/// The largest report body the page may post, bytes.
const REPORT_MAX: usize = 64 * 1024;

/// What the scope records: the recorder's signals (`signal` bits) and ticks
/// between samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// Signals.
    pub signals: u8,
    /// Ticks between samples.
    pub decimation: u16,
}

/// The channels of a stream of `signals`: their names and units.
pub fn channels(signals: u8) -> Vec<(&'static str, &'static str)> {
    recording::columns_of(signals)
        .map(|(_, name)| (name, unit(name)))
        .collect()
}

/// A column's unit, from its name.
fn unit(name: &str) -> &'static str {
    if name.ends_with("_um") {
        "µm"
    } else if name.ends_with("_V") {
        "V"
    } else if name.ends_with("_N") {
        "N"
    } else {
        "bits"
    }
}

/// A stream message's header: `count` samples from tick `first`, with the
/// counts so far.
fn header(count: usize, first: u32, decimation: u16, counts: &Counts) -> [u8; HEADER_BYTES] {
    let words = [
        MAGIC,
        count as u32,
        first,
        u32::from(decimation),
        counts.gaps,
        u32::try_from(counts.missing).unwrap_or(u32::MAX),
        counts.dropped,
    ];
    let mut out = [0; HEADER_BYTES];
    for (bytes, word) in out.chunks_exact_mut(4).zip(words) {
        bytes.copy_from_slice(&word.to_le_bytes());
    }
    out
}

/// A stream message's values: `samples` of `signals` as `f32`, sample by
/// sample, in the channels' order.
fn values(signals: u8, samples: &[Sample]) -> Vec<u8> {
    let columns: Vec<u8> = recording::columns_of(signals).map(|(bit, _)| bit).collect();
    let mut out = Vec::with_capacity(samples.len() * columns.len() * 4);
    for s in samples {
        for &bit in &columns {
            out.extend_from_slice(&(recording::value(bit, s) as f32).to_le_bytes());
        }
    }
    out
}

/// A message queued for a viewer: its header (its own counts) and the values,
/// encoded once for every viewer.
type Message = ([u8; HEADER_BYTES], Arc<Vec<u8>>);

/// One open `/stream`: its queue, and what it lost of it.
struct Viewer {
    queue: SyncSender<Message>,
    lost_messages: u32,
    lost_samples: u64,
}

/// What the scope serves and the stream's state.
struct Scope {
    /// The board's link, shared with the recording (the trigger panel).
    link: Arc<Mutex<Client>>,
    info: String,
    signals: u8,
    decimation: u16,
    viewers: Mutex<Vec<Viewer>>,
    report: Mutex<Option<String>>,
}

/// What a scope run streamed, for its closing line.
#[derive(Debug, Clone, Copy, Default)]
pub struct Throughput {
    /// Samples read from the board.
    pub samples: u64,
    /// Seconds the stream ran.
    pub seconds: f64,
    /// The stream's counts at its end.
    pub counts: Counts,
}

impl std::fmt::Display for Throughput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} samples in {:.1} s ({:.0} samples/s)",
            self.samples,
            self.seconds,
            self.samples as f64 / self.seconds.max(1e-9)
        )?;
        if !self.counts.whole() {
            write!(f, "; {}", self.counts.losses())?;
        }
        Ok(())
    }
}

/// A scope bound to its address, its recording armed: [`Self::run`] serves it.
pub struct Bound {
    server: Server,
    live: Live,
    scope: Scope,
    addr: String,
}

/// Binds the scope of the board behind `link` to `listen` (HOST:PORT; port 0
/// for any free one) and arms its recording. Refused before anything is
/// served where the address is taken or the recording cannot start (the link
/// cannot carry it, a bad decimation, no signal).
pub fn bind(link: Arc<Mutex<Client>>, board: &str, listen: &str, o: Options) -> Result<Bound> {
    let server = Server::http(listen).map_err(|e| anyhow!("listening on {listen}: {e}"))?;
    let addr = server
        .server_addr()
        .to_ip()
        .ok_or_else(|| anyhow!("listening on {listen}: not an IP address"))?;
    let shared: Arc<dyn SharedClient> = link.clone();
    let live = Live::start(shared, o.signals, o.decimation, false)?;
    let scope = Scope {
        link,
        info: info(&live, board),
        signals: live.signals,
        decimation: live.decimation,
        viewers: Mutex::default(),
        report: Mutex::default(),
    };
    Ok(Bound {
        server,
        live,
        scope,
        addr: addr.to_string(),
    })
}

impl Bound {
    /// Where it listens (`HOST:PORT`).
    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// The page's address (`http://HOST:PORT/`).
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Serves the page and the stream until `halt` (or the recording fails),
    /// then stops the recording; what it streamed.
    pub fn run(self, halt: &(dyn Fn() -> bool + Sync)) -> Result<Throughput> {
        let Self {
            server,
            live,
            scope,
            ..
        } = self;
        let started = Instant::now();
        let pumped = std::thread::scope(|s| {
            let pump = s.spawn(|| pump(&live, &scope, halt));
            while !halt() && !pump.is_finished() {
                if let Ok(Some(request)) = server.recv_timeout(Duration::from_millis(100)) {
                    if request.url() == "/stream" && *request.method() == Method::Get {
                        let queue = scope.subscribe();
                        s.spawn(move || stream(request, queue));
                    } else {
                        scope.answer(request);
                    }
                }
            }
            scope.close();
            pump.join()
                .map_err(|_| anyhow!("the scope's reader panicked"))?
        });
        let (_, counts) = live.stop()?;
        let samples = pumped?;
        Ok(Throughput {
            samples,
            seconds: started.elapsed().as_secs_f64(),
            counts,
        })
    }
}

/// `/info`'s JSON.
fn info(live: &Live, board: &str) -> String {
    let channels: Vec<_> = channels(live.signals)
        .into_iter()
        .map(|(name, unit)| json!({ "name": name, "unit": unit }))
        .collect();
    json!({
        "rate_hz": live.rate_hz,
        "decimation": live.decimation,
        "channels": channels,
        "board": board,
    })
    .to_string()
}

/// Reads the recording every [`PUMP`] and hands each block to the viewers,
/// until `halt` or the recording fails; the samples read.
fn pump(live: &Live, scope: &Scope, halt: &(dyn Fn() -> bool + Sync)) -> Result<u64> {
    let mut samples = 0;
    while !halt() {
        let block = live.read()?;
        if !block.samples.is_empty() {
            samples += block.samples.len() as u64;
            scope.hand_out(&block.samples, &block.counts);
        }
        std::thread::sleep(PUMP);
    }
    Ok(samples)
}

impl Scope {
    /// A new viewer's queue.
    fn subscribe(&self) -> Receiver<Message> {
        let (tx, rx) = mpsc::sync_channel(QUEUE);
        if let Ok(mut v) = self.viewers.lock() {
            v.push(Viewer {
                queue: tx,
                lost_messages: 0,
                lost_samples: 0,
            });
        }
        rx
    }

    /// Ends every viewer's stream.
    fn close(&self) {
        if let Ok(mut v) = self.viewers.lock() {
            v.clear();
        }
    }

    /// Queues `samples` for every viewer, each with the counts it has seen:
    /// the board's and the messages its own queue could not take. A viewer
    /// that has gone is forgotten.
    fn hand_out(&self, samples: &[Sample], counts: &Counts) {
        let Ok(mut v) = self.viewers.lock() else {
            return;
        };
        let first = samples.first().map_or(0, |s| s.tick);
        let body = Arc::new(values(self.signals, samples));
        v.retain_mut(|viewer| {
            let seen = Counts {
                gaps: counts.gaps + viewer.lost_messages,
                missing: counts.missing + viewer.lost_samples,
                ..*counts
            };
            let head = header(samples.len(), first, self.decimation, &seen);
            match viewer.queue.try_send((head, body.clone())) {
                Ok(()) => true,
                Err(TrySendError::Full(_)) => {
                    viewer.lost_messages += 1;
                    viewer.lost_samples += samples.len() as u64;
                    true
                }
                Err(TrySendError::Disconnected(_)) => false,
            }
        });
    }

    /// Answers a request other than `/stream`.
    fn answer(&self, mut request: Request) {
        let path = request.url().split('?').next().unwrap_or("/").to_string();
        let response = match (request.method(), path.as_str()) {
            (Method::Get, "/info") => text(200, "application/json", self.info.clone()),
            (Method::Get, "/trigger") => self.trigger(None),
            (Method::Post, "/trigger") => {
                let mut body = String::new();
                match request.as_reader().take(4096).read_to_string(&mut body) {
                    Ok(_) => self.trigger(Some(&body)),
                    Err(e) => text(400, "text/plain", format!("the trigger's settings: {e}")),
                }
            }
            (Method::Get, "/report") => match self.report.lock().ok().and_then(|r| r.clone()) {
                Some(r) => text(200, "application/json", r),
                None => text(404, "text/plain", "no report yet".into()),
            },
            (Method::Post, "/report") => {
                let mut body = String::new();
                let read = request
                    .as_reader()
                    .take(REPORT_MAX as u64)
                    .read_to_string(&mut body);
                match read {
                    Ok(_) => {
                        if let Ok(mut r) = self.report.lock() {
                            *r = Some(body);
                        }
                        text(204, "text/plain", String::new())
                    }
                    Err(e) => text(400, "text/plain", format!("the report: {e}")),
                }
            }
            (Method::Get, p) => match ASSETS.iter().find(|(at, _, _)| *at == p) {
                Some((_, kind, body)) => text(200, kind, (*body).to_string()),
                None if p == "/index.html" => text(200, ASSETS[0].1, ASSETS[0].2.to_string()),
                None => text(404, "text/plain", format!("{p}: no such page")),
            },
            _ => text(405, "text/plain", "GET, or POST /report or /trigger".into()),
        };
        let _ = request.respond(response);
    }
}

impl Scope {
    /// `GET /trigger` (`body` none) or `POST /trigger`: the board's trigger
    /// output settings and what its input starts (`input`) after the change
    /// the body asks for, as JSON; 400 with why a change was refused (by the
    /// host's checks or the board's).
    fn trigger(&self, body: Option<&str>) -> Response<std::io::Cursor<Vec<u8>>> {
        let Ok(mut c) = self.link.lock() else {
            return text(500, "text/plain", "the board's link failed".into());
        };
        match trigger_request(&mut c, body) {
            Ok(json) => text(200, "application/json", json),
            Err(e) => text(400, "text/plain", format!("{e:#}")),
        }
    }
}

/// `POST /trigger`'s body: the output's mode and levels, what the input
/// starts; each optional.
#[derive(serde::Deserialize)]
struct TriggerRequest {
    mode: Option<String>,
    input: Option<String>,
    #[serde(flatten)]
    levels: crate::board::trigger::Levels,
}

/// Carries out `body` (none: reads only); the board's trigger settings, JSON.
fn trigger_request(c: &mut Client, body: Option<&str>) -> Result<String> {
    use crate::board::trigger;
    if let Some(b) = body {
        let r: TriggerRequest =
            serde_json::from_str(b).map_err(|e| anyhow!("the trigger's settings {b}: {e}"))?;
        if let Some(mode) = r.mode {
            trigger::set(c, trigger::mode(&mode)?, &r.levels)?;
        }
        if let Some(input) = r.input {
            trigger::set_input(c, trigger::starts(&input)?)?;
        }
    }
    let mut v = serde_json::to_value(trigger::settings(c)?)?;
    let input: String = serde_json::from_str(&c.setting("/stage/0/trigger_in")?)?;
    v["input"] = input.into();
    Ok(v.to_string())
}

/// A whole response of `body` with its type.
fn text(code: u16, kind: &str, body: String) -> Response<std::io::Cursor<Vec<u8>>> {
    let mut r = Response::from_data(body.into_bytes()).with_status_code(StatusCode(code));
    if let Ok(h) = Header::from_bytes("Content-Type", kind) {
        r.add_header(h);
    }
    if let Ok(h) = Header::from_bytes("Cache-Control", "no-store") {
        r.add_header(h);
    }
    r
}

/// Writes `queue`'s messages to a `/stream` request as one chunked response,
/// each message a chunk sent at once, until the viewer or the scope goes.
fn stream(request: Request, queue: Receiver<Message>) {
    let mut w = request.into_writer();
    let head = "HTTP/1.1 200 OK\r\nContent-Type: application/octet-stream\r\n\
                Cache-Control: no-store\r\nTransfer-Encoding: chunked\r\n\
                Connection: close\r\n\r\n";
    if w.write_all(head.as_bytes())
        .and_then(|_| w.flush())
        .is_err()
    {
        return;
    }
    while let Ok((head, body)) = queue.recv() {
        let sent = write!(w, "{:X}\r\n", head.len() + body.len())
            .and_then(|_| w.write_all(&head))
            .and_then(|_| w.write_all(&body))
            .and_then(|_| w.write_all(b"\r\n"))
            .and_then(|_| w.flush());
        if sent.is_err() {
            return;
        }
    }
    let _ = w.write_all(b"0\r\n\r\n").and_then(|_| w.flush());
}

/// The scope's closing words: what it streamed.
pub fn closing(t: &Throughput) -> String {
    format!("scope stopped: {t}")
}
