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
//! **Who holds what.** Two things cannot be shared, and the hub gives each to
//! one client at a time:
//!
//! * **the motion**: the client whose command started the running motion (a
//!   move, wave, stream, step, the analog input, an analysis) holds it while the
//!   board's source runs; another client's motion command is refused
//!   ([`Refusal::Held`], naming the holder). `hold` and `safe` are never
//!   refused: anyone may stop the stage. The motion is free again once the
//!   board holds (the reference at rest) or its holder has gone.
//! * **the recorder**: the client that armed it holds it until it stops it;
//!   another client's `record`, `record-stop` or read is refused the same way.
//!   When a holder goes, the hub stops the recorder it left running.
//!
//! Everything else (status, settings, the model, the bench) is anyone's.

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use fpi_protocol::frame::{self, FrameReader, Push};
use fpi_protocol::{
    Command, Header, Refusal, Reply, ReplyHeader, SourceKind, Text, MAX_FRAME, VERSION,
};

use super::client::{Client, REPLY_TIMEOUT};

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

/// Who holds the motion and the recorder.
#[derive(Debug, Default)]
struct Holders {
    motion: Option<Peer>,
    recorder: Option<Peer>,
}

/// What a command needs that only one client may hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Needs {
    Motion,
    Recorder,
    Nothing,
}

/// What `cmd` needs.
fn needs(cmd: &Command<'_>) -> Needs {
    match cmd {
        Command::Move { .. }
        | Command::Wave { .. }
        | Command::Points { .. }
        | Command::Stream { .. }
        | Command::StreamEnd { .. }
        | Command::StreamClear { .. }
        | Command::Analog { .. }
        | Command::Step { .. }
        | Command::Analyse { .. } => Needs::Motion,
        Command::Record { .. } | Command::RecordStop | Command::ReadRecord { .. } => {
            Needs::Recorder
        }
        _ => Needs::Nothing,
    }
}

/// The hub: the board's client and who holds what.
pub struct Hub {
    board: Mutex<Client>,
    holders: Mutex<Holders>,
    next: AtomicU32,
}

impl Hub {
    /// A hub over `board`'s link.
    pub fn new(board: Client) -> Self {
        Self {
            board: Mutex::new(board),
            holders: Mutex::new(Holders::default()),
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
        let need = needs(&cmd);
        if let Some(holder) = self.holder_other_than(peer, need) {
            let what = if need == Needs::Motion {
                "the motion"
            } else {
                "the recorder"
            };
            return Some(refusal(
                header.seq,
                &format!("{what} is held by {holder} of this board's hub: wait, or stop it there"),
            ));
        }
        let (bytes, accepted) = self.exchange(raw, Some(header.seq), Client::timeout_for(&cmd))?;
        if accepted {
            self.took(peer, &cmd, need);
        }
        Some(bytes)
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

    /// Who other than `peer` holds what `need` needs, where it is held.
    fn holder_other_than(&self, peer: &Peer, need: Needs) -> Option<Peer> {
        let mut h = self.holders.lock().ok()?;
        match need {
            Needs::Nothing => None,
            Needs::Recorder => h.recorder.clone().filter(|p| p != peer),
            Needs::Motion => {
                let other = h.motion.clone().filter(|p| p != peer)?;
                // Free again once the board holds.
                if self.board_holds() {
                    h.motion = None;
                    return None;
                }
                Some(other)
            }
        }
    }

    /// The board's reference is at rest (its source holds).
    fn board_holds(&self) -> bool {
        self.lock_board()
            .and_then(|mut b| b.status())
            .map(|s| s.source == SourceKind::Hold)
            .unwrap_or(false)
    }

    /// `peer`'s command `cmd`, carried out, takes or frees what it needs.
    fn took(&self, peer: &Peer, cmd: &Command<'_>, need: Needs) {
        let Ok(mut h) = self.holders.lock() else {
            return;
        };
        match (need, cmd) {
            (Needs::Motion, _) => h.motion = Some(peer.clone()),
            (Needs::Recorder, Command::Record { .. }) => h.recorder = Some(peer.clone()),
            (Needs::Recorder, Command::RecordStop) => h.recorder = None,
            (Needs::Nothing, Command::Hold { .. } | Command::Safe) => h.motion = None,
            _ => {}
        }
    }

    /// `peer` went: what it held is free, and a recorder it left running is
    /// stopped.
    fn gone(&self, peer: &Peer) {
        let recorder = {
            let Ok(mut h) = self.holders.lock() else {
                return;
            };
            if h.motion.as_ref() == Some(peer) {
                h.motion = None;
            }
            let held = h.recorder.as_ref() == Some(peer);
            if held {
                h.recorder = None;
            }
            held
        };
        if recorder {
            if let Ok(mut b) = self.lock_board() {
                let _ = b.ack(&Command::RecordStop);
            }
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

/// The hub's own refusal of request `seq`.
fn refusal(seq: u16, reason: &str) -> Vec<u8> {
    let mut text = Text::new();
    for c in reason.chars() {
        if text.push(c).is_err() {
            break;
        }
    }
    let h = ReplyHeader {
        version: VERSION,
        seq,
        tick: 0,
    };
    encode(
        &h,
        &Reply::Refused {
            code: Refusal::Held,
            reason: text,
        },
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
