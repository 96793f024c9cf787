//! Several clients, one link: `fpi board serve` owns a board's link (a serial
//! port, the emulated board or the in-process one) and serves local clients on
//! a TCP port, each speaking the board's own protocol (`--port tcp:HOST:PORT`,
//! `piezo_fpi.Board("tcp:HOST:PORT")`), so a scope, the CLI and a script can
//! use one board at once.
//!
//! **One request at a time.** Each client's request is passed to the board
//! whole and its reply returned to that client; requests from different
//! clients are taken in turn, never interleaved.
//!
//! **Who holds the motion.** The client whose command started the running
//! motion (a move, wave, stream, step, the analog input, an analysis) holds it
//! while the board's source runs; another client's motion command is refused
//! ([`Refusal::Held`], naming the holder). `hold` and `safe` are never refused:
//! anyone may stop the stage. The motion is free again once the board holds
//! (the reference at rest) or its holder has gone.
//!
//! **Everyone records.** The recorder is the hub's ([`super::fanout`]): every
//! client that arms it gets a recording of its own, with its decimation and
//! signals, cut from one recording of the board, so a scope, the CLI and a
//! script can each watch the stage at once. A client that goes ends its
//! recording.
//!
//! Everything else (status, settings, the model, the bench) is anyone's.

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use fpi_protocol::frame::{self, FrameReader, Push};
use fpi_protocol::{
    Command, Header, Refusal, Reply, ReplyHeader, SourceKind, Text, MAX_FRAME, VERSION,
};

use super::client::{Client, REPLY_TIMEOUT};
use super::fanout::Fanout;

/// A client of the hub: its number (from 1, in the order they connected) and
/// its address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Peer {
    /// Its number.
    pub id: u32,
    /// Its TCP address.
    pub addr: String,
}

impl std::fmt::Display for Peer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "client {} ({})", self.id, self.addr)
    }
}

/// Whether `cmd` starts a motion (which one client holds at a time).
fn moves(cmd: &Command<'_>) -> bool {
    matches!(
        cmd,
        Command::Move { .. }
            | Command::Wave { .. }
            | Command::Points { .. }
            | Command::Stream { .. }
            | Command::StreamEnd { .. }
            | Command::StreamClear { .. }
            | Command::Analog { .. }
            | Command::Step { .. }
            | Command::Analyse { .. }
    )
}

/// The hub: the board's client, who holds the motion, and the recordings.
pub struct Hub {
    board: Arc<Mutex<Client>>,
    motion: Mutex<Option<Peer>>,
    recorder: Mutex<Fanout>,
    next: AtomicU32,
}

impl Hub {
    /// A hub over `board`'s link.
    pub fn new(board: Client) -> Self {
        let board = Arc::new(Mutex::new(board));
        Self {
            recorder: Mutex::new(Fanout::new(board.clone())),
            board,
            motion: Mutex::new(None),
            next: AtomicU32::new(1),
        }
    }

    /// Serves the clients that connect to `listener` until `halt` says so
    /// (asked every 50 ms); each on a thread of its own. `connected` hears of
    /// each client that comes (true) or goes (false).
    pub fn serve(
        &self,
        listener: &TcpListener,
        halt: &(dyn Fn() -> bool + Sync),
        connected: &(dyn Fn(&Peer, bool) + Sync),
    ) -> Result<()> {
        listener.set_nonblocking(true)?;
        let halted = AtomicBool::new(false);
        let halted = &halted;
        std::thread::scope(|scope| {
            let r = self.accept(scope, listener, halt, halted, connected);
            halted.store(true, Ordering::Relaxed);
            r
        })
    }

    fn accept<'s, 'e: 's>(
        &'e self,
        scope: &'s std::thread::Scope<'s, 'e>,
        listener: &TcpListener,
        halt: &(dyn Fn() -> bool + Sync),
        halted: &'e AtomicBool,
        connected: &'e (dyn Fn(&Peer, bool) + Sync),
    ) -> Result<()> {
        {
            while !halt() {
                match listener.accept() {
                    Ok((stream, addr)) => {
                        let peer = Peer {
                            id: self.next.fetch_add(1, Ordering::Relaxed),
                            addr: addr.to_string(),
                        };
                        scope.spawn(move || {
                            connected(&peer, true);
                            self.session(stream, &peer, halted);
                            self.gone(&peer);
                            connected(&peer, false);
                        });
                    }
                    Err(e) if e.kind() == ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    Err(e) => return Err(anyhow!(e).context("accepting a client")),
                }
            }
            Ok(())
        }
    }

    /// One client's requests until it goes (or `halt`).
    fn session(&self, mut stream: TcpStream, peer: &Peer, halt: &AtomicBool) {
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
        let mut reader = FrameReader::<MAX_FRAME>::new();
        let mut buf = [0u8; 4096];
        while !halt.load(Ordering::Relaxed) {
            let n = match stream.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    continue
                }
                Err(_) => return,
            };
            for &b in &buf[..n] {
                if reader.push(b) != Push::Frame {
                    continue;
                }
                let mut raw = reader.frame().to_vec();
                raw.push(0);
                // A board that no longer answers ends the session: the client
                // sees its link fail, as it would on the board's own link.
                let Some(reply) = self.answer(peer, &raw) else {
                    return;
                };
                if stream.write_all(&reply).is_err() {
                    return;
                }
            }
        }
    }

    /// The reply frame to a client's request frame `raw` (delimiter
    /// included); `None` where the board did not answer.
    fn answer(&self, peer: &Peer, raw: &[u8]) -> Option<Vec<u8>> {
        let mut copy = raw[..raw.len() - 1].to_vec();
        let decoded = frame::decode::<Header>(&mut copy)
            .ok()
            .and_then(|(h, body)| frame::body::<Command>(body).ok().map(|c| (h, c)));
        let Some((header, cmd)) = decoded else {
            // Unreadable here: the board says why, as it would directly.
            return self
                .exchange(raw, None, REPLY_TIMEOUT)
                .map(|(bytes, _)| bytes);
        };
        if let Some(r) = self.record(peer, &cmd) {
            return match r {
                Ok((tick, reply)) => Some(encode(&reply_header(header.seq, tick), &reply)),
                Err(e) => Some(refused(header.seq, Refusal::BadArgument, &format!("{e:#}"))),
            };
        }
        let moving = moves(&cmd);
        if moving {
            if let Some(holder) = self.holder_other_than(peer) {
                return Some(refused(
                    header.seq,
                    Refusal::Held,
                    &format!(
                        "the motion is held by {holder} of this board's hub: wait, or stop it there"
                    ),
                ));
            }
        }
        let (bytes, accepted) = self.exchange(raw, Some(header.seq), Client::timeout_for(&cmd))?;
        if accepted {
            self.took(peer, &cmd, moving);
        }
        Some(bytes)
    }

    /// A recorder command, answered by the hub's recorder.
    fn record(&self, peer: &Peer, cmd: &Command<'_>) -> Option<Result<(u32, Reply)>> {
        let mut f = self.recorder.lock().ok()?;
        f.answer(peer.id, cmd)
    }

    /// Passes `raw` to the board: the reply's frame, and whether the board
    /// carried the command out (not refused); `None` where it did not answer.
    fn exchange(&self, raw: &[u8], seq: Option<u16>, timeout: Duration) -> Option<(Vec<u8>, bool)> {
        let (h, reply) = self
            .lock_board()
            .and_then(|mut b| b.forward(raw, seq, timeout))
            .ok()?;
        let accepted = !matches!(reply, Reply::Refused { .. });
        Some((encode(&h, &reply), accepted))
    }

    /// Who other than `peer` holds the motion, where one does.
    fn holder_other_than(&self, peer: &Peer) -> Option<Peer> {
        let mut h = self.motion.lock().ok()?;
        let other = h.clone().filter(|p| p != peer)?;
        // Free again once the board holds.
        if self.board_holds() {
            *h = None;
            return None;
        }
        Some(other)
    }

    /// The board's reference is at rest (its source holds).
    fn board_holds(&self) -> bool {
        self.lock_board()
            .and_then(|mut b| b.status())
            .map(|s| s.source == SourceKind::Hold)
            .unwrap_or(false)
    }

    /// `peer`'s command `cmd`, carried out, takes or frees the motion.
    fn took(&self, peer: &Peer, cmd: &Command<'_>, moving: bool) {
        let Ok(mut h) = self.motion.lock() else {
            return;
        };
        if moving {
            *h = Some(peer.clone());
        } else if matches!(cmd, Command::Hold { .. } | Command::Safe) {
            *h = None;
        }
    }

    /// `peer` went: the motion is free if it held it, and its recording ends.
    fn gone(&self, peer: &Peer) {
        if let Ok(mut h) = self.motion.lock() {
            if h.as_ref() == Some(peer) {
                *h = None;
            }
        }
        if let Ok(mut f) = self.recorder.lock() {
            f.gone(peer.id);
        }
    }

    fn lock_board(&self) -> Result<MutexGuard<'_, Client>> {
        self.board
            .lock()
            .map_err(|_| anyhow!("the hub's link failed in another thread"))
    }
}

/// A reply as its frame (delimiter included).
fn encode(h: &ReplyHeader, reply: &Reply) -> Vec<u8> {
    let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
    match frame::encode(h, reply, &mut scratch, &mut out) {
        Ok(n) => out[..n].to_vec(),
        Err(_) => Vec::new(),
    }
}

/// The header of the hub's own reply to request `seq`, at `tick`.
fn reply_header(seq: u16, tick: u32) -> ReplyHeader {
    ReplyHeader {
        version: VERSION,
        seq,
        tick,
    }
}

/// The hub's own refusal of request `seq` (the reason cut to what a refusal
/// carries).
fn refused(seq: u16, code: Refusal, reason: &str) -> Vec<u8> {
    let mut text = Text::new();
    for c in reason.chars() {
        if text.push(c).is_err() {
            break;
        }
    }
    encode(
        &reply_header(seq, 0),
        &Reply::Refused { code, reason: text },
    )
}

/// Serves `board` on `listen` (`HOST:PORT`) until `halt` says so, printing
/// each client that comes and goes (`fpi board serve`).
pub fn serve(board: Client, listen: &str, halt: &(dyn Fn() -> bool + Sync)) -> Result<()> {
    let (host, port) = super::port::tcp_address(listen)?;
    let listener = TcpListener::bind((host.as_str(), port))
        .with_context(|| format!("listening on {listen}"))?;
    let name = board.name().to_string();
    let hub = Hub::new(board);
    println!(
        "serving {name} on tcp:{} (clients: --port tcp:{}); Ctrl-C ends",
        listener.local_addr()?,
        listener.local_addr()?
    );
    hub.serve(&listener, halt, &|p, came| {
        println!("{p} {}", if came { "connected" } else { "left" });
    })
}
