//! The byte pipe to a board: a serial device (the driver board's USART through a
//! USB-serial adapter, via the `serialport` crate) or a TCP socket (the emulated
//! board, whose USART QEMU bridges to a TCP port).
//!
//! A port is named by a string: `tcp:HOST:PORT` for a socket, anything else for a
//! serial device (`/dev/ttyUSB0`, `COM3`). (The client also opens `virtual`, the
//! firmware built for the host and run in this process, [`super::inprocess`],
//! which is a [`Port`] too.)

use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use piezo_sim::quote::Quoted;

/// The link's baud rate (the firmware's USART1).
pub const BAUD: u32 = 115_200;

/// A bidirectional byte stream to a board.
pub trait Port: Send {
    /// Writes all of `bytes`.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what is available within `timeout` into `buf`: the number of bytes
    /// (0 when nothing came).
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
    /// Why a board that does not answer at all may be silent, if the port can
    /// tell (a TCP port held by another client).
    fn silence(&self) -> Option<String> {
        None
    }
}

struct Tcp(TcpStream);

impl Port for Tcp {
    fn silence(&self) -> Option<String> {
        let peer = self.0.peer_addr().ok()?;
        let mine = self.0.local_addr().ok()?;
        let by = holders(peer.port(), mine.port());
        let told = std::path::Path::new("/proc/net/tcp").exists();
        Some(if by.is_empty() && !told {
            format!(
                "{peer} took the connection but nothing answers: the port is busy (the emulated \
                 board serves one client at a time, and another may hold it), or what listens \
                 there does not speak the board's link (a wrong firmware)"
            )
        } else if by.is_empty() {
            format!(
                "{peer} took the connection but nothing answers, and no other client holds it: \
                 what listens there does not speak the board's link (the emulated board running \
                 a wrong firmware, or no board at all)"
            )
        } else {
            format!(
                "{peer} took the connection but nothing answers: the port is busy (the emulated \
                 board serves one client at a time, and another holds it: {})",
                by.join(", ")
            )
        })
    }

    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.0.write_all(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.0
            .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
        match self.0.read(buf) {
            Ok(0) => Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "the board closed the connection",
            )),
            Ok(n) => Ok(n),
            // A signal (Ctrl-C, which `fpi board record` catches) interrupts the
            // wait: nothing came.
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock
                        | io::ErrorKind::TimedOut
                        | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }
}

struct Serial(Box<dyn serialport::SerialPort>);

impl Port for Serial {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.0.write_all(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.0
            .set_timeout(timeout.max(Duration::from_millis(1)))
            .map_err(io::Error::other)?;
        match self.0.read(buf) {
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }
}

/// The processes of this machine with an established TCP connection to `port`
/// other than from the local port `mine`, as `NAME (pid N)` (Linux: from
/// `/proc`; elsewhere, or where `/proc` does not tell, none).
pub fn holders(port: u16, mine: u16) -> Vec<String> {
    processes_with(|local, remote, state| {
        state == "01" && remote == Some(port) && local != Some(mine)
    })
}

/// The processes of this machine listening on the TCP port `port`, as
/// [`holders`] names them.
pub fn listeners(port: u16) -> Vec<String> {
    processes_with(|local, _, state| state == "0A" && local == Some(port))
}

/// The processes holding a TCP socket for which `wanted(local port, remote
/// port, state)` (the state as `/proc/net/tcp` writes it: `01` established,
/// `0A` listening).
fn processes_with(wanted: impl Fn(Option<u16>, Option<u16>, &str) -> bool) -> Vec<String> {
    let mut inodes = Vec::new();
    for table in ["/proc/net/tcp", "/proc/net/tcp6"] {
        let text = std::fs::read_to_string(table).unwrap_or_default();
        for line in text.lines().skip(1) {
            let f: Vec<&str> = line.split_whitespace().collect();
            let port_of = |a: &str| {
                a.rsplit(':')
                    .next()
                    .and_then(|p| u16::from_str_radix(p, 16).ok())
            };
            let (Some(local), Some(remote), Some(state), Some(inode)) =
                (f.get(1), f.get(2), f.get(3), f.get(9))
            else {
                continue;
            };
            if wanted(port_of(local), port_of(remote), state) {
                inodes.push(format!("socket:[{inode}]"));
            }
        }
    }
    let mut found = Vec::new();
    if inodes.is_empty() {
        return found;
    }
    for proc in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let fds = std::fs::read_dir(proc.path().join("fd"))
            .into_iter()
            .flatten()
            .flatten();
        let holds = fds
            .filter_map(|fd| std::fs::read_link(fd.path()).ok())
            .any(|l| {
                inodes
                    .iter()
                    .any(|i| l.as_os_str() == std::ffi::OsStr::new(i))
            });
        if holds {
            let name = std::fs::read_to_string(proc.path().join("comm")).unwrap_or_default();
            found.push(format!(
                "{} (pid {})",
                name.trim(),
                proc.file_name().to_string_lossy()
            ));
        }
    }
    found
}

/// The host and port of a TCP address `HOST:PORT` (`[V6]:PORT` for an IPv6
/// address): a host name or address of letters, digits, `.`, `-` and `_` (or
/// within brackets `:`), and a port 1–65535. Anything else is refused, so that it
/// never reaches the socket layer, or QEMU's options, as it is.
pub fn tcp_address(addr: &str) -> Result<(String, u16)> {
    let bad = || {
        anyhow!("not HOST:PORT (a host name or address, and a port 1–65535; e.g. 127.0.0.1:4545)")
    };
    let (host, port) = addr.rsplit_once(':').ok_or_else(bad)?;
    let name = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_');
    let host_ok = match host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        Some(v6) => !v6.is_empty() && v6.chars().all(|c| c.is_ascii_hexdigit() || c == ':'),
        None => !host.is_empty() && host.chars().all(name),
    };
    if !host_ok {
        return Err(bad());
    }
    match port.parse::<u16>() {
        Ok(p) if p > 0 => Ok((host.trim_matches(['[', ']']).to_string(), p)),
        _ => Err(anyhow!("port {} is not a TCP port (1–65535)", Quoted(port))),
    }
}

/// Opens a port by name; a TCP port is retried for up to `patience` while it
/// refuses connections (an emulator that is still starting).
pub fn open(name: &str, patience: Duration) -> Result<Box<dyn Port>> {
    if let Some(addr) = name.strip_prefix("tcp:") {
        let (host, port) = tcp_address(addr)?;
        let start = Instant::now();
        loop {
            match TcpStream::connect((host.as_str(), port)) {
                Ok(s) => {
                    s.set_nodelay(true).ok();
                    return Ok(Box::new(Tcp(s)));
                }
                Err(e)
                    if e.kind() == io::ErrorKind::ConnectionRefused
                        && start.elapsed() < patience =>
                {
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => return Err(e).with_context(|| format!("connecting to {addr}")),
            }
        }
    }
    if name.is_empty() {
        bail!("no port given: a serial device (/dev/ttyUSB0, COM3) or tcp:HOST:PORT");
    }
    let p = serialport::new(name, BAUD)
        .timeout(Duration::from_millis(100))
        .open()
        .with_context(|| format!("opening the serial port {name}"))?;
    Ok(Box::new(Serial(p)))
}
