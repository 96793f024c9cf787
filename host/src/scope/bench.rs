//! The stream's throughput, for `fpi bench`: the in-process board (board time
//! at wall-clock pace, 20 000 ticks per second, its link paced as USB) served by
//! the hub ([`crate::board::hub`]), streamed by the scope at every tick with
//! every signal, and read over HTTP as the page reads it. A figure, not a test:
//! it says whether the whole way from the board's recorder to the page keeps
//! up with a real board's rate.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use fpi_protocol::record::signal;

use super::{bind, Options, HEADER_BYTES, MAGIC};
use crate::board::client::Client;
use crate::board::hub::Hub;

/// What reached the reader of `/stream`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StreamFigures {
    /// Wall-clock seconds the reader read.
    pub seconds: f64,
    /// Samples received.
    pub samples: u64,
    /// Board ticks between the first sample received and the last.
    pub ticks: u64,
    /// Bytes of messages received.
    pub bytes: u64,
    /// Channels per sample.
    pub channels: usize,
    /// Gaps, missing and dropped samples, as the last message counted them.
    pub gaps: u32,
    /// Samples the gaps miss.
    pub missing: u32,
    /// Samples the board's ring dropped.
    pub dropped: u32,
}

impl std::fmt::Display for StreamFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "scope_stream_samples_per_s decimation=1 channels={}: {:.0} ({} samples in {:.2} s \
             of wall time covering {} board ticks; {:.0} kB/s to the page; {} gaps, {} missing, \
             {} dropped; the in-process board through the hub and the scope's HTTP stream)",
            self.channels,
            self.samples as f64 / self.seconds,
            self.samples,
            self.seconds,
            self.ticks,
            self.bytes as f64 / self.seconds / 1e3,
            self.gaps,
            self.missing,
            self.dropped
        )
    }
}

/// Streams every tick of every signal of an in-process board for `seconds`
/// of wall time, through the hub and the scope, and counts what arrived.
pub fn stream(seconds: f64) -> Result<StreamFigures> {
    let board = Client::open("virtual:usb").context("the in-process board")?;
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let port = format!("tcp:{}", listener.local_addr()?);
    let hub_halt = AtomicBool::new(false);
    let scope_halt = AtomicBool::new(false);
    std::thread::scope(|s| {
        let hub = s.spawn(|| {
            Hub::new(board).serve(&listener, &|| hub_halt.load(Ordering::Relaxed), &|_, _| {})
        });
        let scoped = Client::open(&port).and_then(|c| {
            let o = Options {
                signals: signal::ALL,
                decimation: 1,
            };
            bind(
                Arc::new(Mutex::new(c)),
                "the in-process board",
                "127.0.0.1:0",
                o,
            )
        });
        let read = scoped.and_then(|bound| {
            let addr = bound.addr().to_string();
            let scope = s.spawn(|| bound.run(&|| scope_halt.load(Ordering::Relaxed)));
            let read = read_stream(&addr, seconds);
            scope_halt.store(true, Ordering::Relaxed);
            let ran = scope.join().map_err(|_| anyhow!("the scope panicked"))?;
            ran?;
            read
        });
        hub_halt.store(true, Ordering::Relaxed);
        let served = hub.join().map_err(|_| anyhow!("the hub panicked"))?;
        let figures = read?;
        served?;
        Ok(figures)
    })
}

/// Reads `/stream` on `addr` for `seconds` and counts its messages.
fn read_stream(addr: &str, seconds: f64) -> Result<StreamFigures> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_millis(100)))?;
    write!(s, "GET /stream HTTP/1.1\r\nHost: {addr}\r\n\r\n")?;
    let start = Instant::now();
    let mut raw = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    while start.elapsed().as_secs_f64() < seconds {
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => raw.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e.into()),
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    let body = dechunk(&raw)?;
    let mut f = count(&body)?;
    f.seconds = seconds;
    Ok(f)
}

/// The body of a chunked response (its head skipped), whole chunks only.
fn dechunk(raw: &[u8]) -> Result<Vec<u8>> {
    let head = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or_else(|| anyhow!("no response from the scope"))?;
    let mut at = head + 4;
    let mut body = Vec::with_capacity(raw.len());
    while let Some(eol) = raw[at..].windows(2).position(|w| w == b"\r\n") {
        let size = std::str::from_utf8(&raw[at..at + eol])?;
        let size = usize::from_str_radix(size.trim(), 16)
            .with_context(|| format!("a chunk's size {size:?}"))?;
        let data = at + eol + 2;
        if size == 0 || data + size + 2 > raw.len() {
            break;
        }
        body.extend_from_slice(&raw[data..data + size]);
        at = data + size + 2;
    }
    Ok(body)
}

/// Counts the whole messages in `body`.
fn count(body: &[u8]) -> Result<StreamFigures> {
    let word = |at: usize| u32::from_le_bytes([body[at], body[at + 1], body[at + 2], body[at + 3]]);
    let channels = super::channels(signal::ALL).len();
    let mut f = StreamFigures {
        channels,
        ..StreamFigures::default()
    };
    let (mut at, mut first, mut last) = (0, None, 0u32);
    while at + HEADER_BYTES <= body.len() {
        if word(at) != MAGIC {
            bail!("a stream message without its magic at byte {at}");
        }
        let n = word(at + 4) as usize;
        let size = HEADER_BYTES + n * channels * 4;
        if at + size > body.len() {
            break;
        }
        if n > 0 {
            let tick = word(at + 8);
            first.get_or_insert(tick);
            last = tick.wrapping_add((n as u32 - 1).wrapping_mul(word(at + 12)));
        }
        f.samples += n as u64;
        f.bytes += size as u64;
        (f.gaps, f.missing, f.dropped) = (word(at + 16), word(at + 20), word(at + 24));
        at += size;
    }
    f.ticks = first.map_or(0, |t| u64::from(last.wrapping_sub(t)) + 1);
    Ok(f)
}
