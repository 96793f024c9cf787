//! The byte pipe to a board: a serial device (the driver board's USART through a
//! USB-serial adapter, via the `serialport` crate) or a TCP socket (the emulated
//! board, whose USART QEMU bridges to a TCP port).
//!
//! A port is named by a string: `tcp:HOST:PORT` for a socket, `virtual` for the
//! firmware built for the host and run in this process
//! ([`super::inprocess`]), anything else for a serial device (`/dev/ttyUSB0`, `COM3`).

use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// The link's baud rate (the firmware's USART1).
pub const BAUD: u32 = 115_200;

/// A bidirectional byte stream to a board.
pub trait Port: Send {
    /// Writes all of `bytes`.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what is available within `timeout` into `buf`: the number of bytes
    /// (0 when nothing came).
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
}

struct Tcp(TcpStream);

impl Port for Tcp {
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
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
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
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }
}

/// Opens a port by name; a TCP port is retried for up to `patience` (an emulator
/// that is still starting).
pub fn open(name: &str, patience: Duration) -> Result<Box<dyn Port>> {
    if let Some(addr) = name.strip_prefix("tcp:") {
        let start = Instant::now();
        loop {
            match TcpStream::connect(addr) {
                Ok(s) => {
                    s.set_nodelay(true).ok();
                    return Ok(Box::new(Tcp(s)));
                }
                Err(e) if start.elapsed() < patience => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => return Err(e).with_context(|| format!("connecting to {addr}")),
            }
        }
    }
    if name == super::inprocess::PORT_NAME {
        return Ok(Box::new(super::inprocess::InProcess::start()?));
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
