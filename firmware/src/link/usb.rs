//! The USB link's byte pump, between the link task's queues and the USB
//! CDC-ACM serial port that the board's USB interrupt polls.
//!
//! The link task never touches the USB device (only its interrupt does): it
//! queues a reply's bytes and pends the interrupt, which moves them into the
//! serial port as the endpoint takes them ([`TxPump::pump`]): a packet at a time,
//! held until accepted, so nothing is lost or reordered when the host is slow
//! to poll. When the host goes away (unplugged, or its program closed the port:
//! the device leaves the configured state or DTR drops) or a new one arrives,
//! what was held and queued is discarded ([`TxPump::connected`]), so the next
//! host never reads the tail of a reply meant for the last; the frame reader drops a request cut
//! short the same way, at the next frame delimiter.

use heapless::spsc::Consumer;

/// Bytes of one full-speed bulk packet.
pub const PACKET: usize = 64;

/// Bytes on their way from the link task's queue to the serial port (state).
#[derive(Debug, Clone)]
pub struct TxPump {
    held: [u8; PACKET],
    len: usize,
    at: usize,
    connected: bool,
}

impl Default for TxPump {
    fn default() -> Self {
        Self::new()
    }
}

impl TxPump {
    /// Nothing held, no host.
    pub const fn new() -> Self {
        Self {
            held: [0; PACKET],
            len: 0,
            at: 0,
            connected: false,
        }
    }

    /// Whether a host has the port open.
    pub const fn is_connected(&self) -> bool {
        self.connected
    }

    /// Tells the pump whether a host has the port open now. A host that goes
    /// away, or one that arrives, discards what was held and queued: it was for
    /// a host that is gone (a reply queued after its host left included).
    pub fn connected(&mut self, now: bool, queue: &mut Consumer<'_, u8>) {
        if self.connected != now {
            self.len = 0;
            self.at = 0;
            while queue.dequeue().is_some() {}
        }
        self.connected = now;
    }

    /// Moves queued bytes into `write` (the serial port's write: the bytes it
    /// accepted, `None` when it takes none now) until it takes no more or
    /// nothing is left; the bytes moved. Does nothing without a host.
    pub fn pump(
        &mut self,
        queue: &mut Consumer<'_, u8>,
        mut write: impl FnMut(&[u8]) -> Option<usize>,
    ) -> usize {
        let mut moved = 0;
        while self.connected {
            if self.at == self.len {
                self.len = 0;
                self.at = 0;
                while self.len < PACKET {
                    let Some(b) = queue.dequeue() else { break };
                    if let Some(slot) = self.held.get_mut(self.len) {
                        *slot = b;
                    }
                    self.len += 1;
                }
                if self.len == 0 {
                    break;
                }
            }
            let pending = self.held.get(self.at..self.len).unwrap_or(&[]);
            match write(pending) {
                Some(n) if n > 0 => {
                    let n = n.min(pending.len());
                    self.at += n;
                    moved += n;
                }
                _ => break,
            }
        }
        moved
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use heapless::spsc::Queue;

    /// A serial port that takes at most `room` bytes per poll.
    struct Port {
        room: usize,
        got: Vec<u8>,
    }

    impl Port {
        fn write(&mut self, b: &[u8]) -> Option<usize> {
            let n = b.len().min(self.room);
            self.room -= n;
            self.got.extend_from_slice(&b[..n]);
            (n > 0).then_some(n)
        }
    }

    #[test]
    fn bytes_arrive_whole_and_in_order_however_slowly_the_port_takes_them() {
        let mut q: Queue<u8, 1024> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut pump = TxPump::new();
        pump.connected(true, &mut rx);
        let reply: Vec<u8> = (0..700u32).map(|k| (k * 7 % 251) as u8).collect();
        for &b in &reply {
            tx.enqueue(b).unwrap();
        }
        let mut port = Port {
            room: 0,
            got: Vec::new(),
        };
        // The endpoint takes 0, 10, 20, … bytes at each poll.
        for poll in 0..40 {
            port.room = poll * 10 % 97;
            pump.pump(&mut rx, |b| port.write(b));
        }
        port.room = usize::MAX;
        pump.pump(&mut rx, |b| port.write(b));
        assert_eq!(port.got, reply);
    }

    #[test]
    fn a_host_that_unplugs_gets_nothing_and_the_next_host_a_whole_reply() {
        let mut q: Queue<u8, 256> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut pump = TxPump::new();
        let mut port = Port {
            room: 0,
            got: Vec::new(),
        };
        // No host yet: nothing moves; what was queued for no one is dropped
        // when a host arrives.
        tx.enqueue(1).unwrap();
        assert_eq!(pump.pump(&mut rx, |b| port.write(b)), 0);
        pump.connected(true, &mut rx);
        assert!(rx.dequeue().is_none());
        for b in 2..100 {
            tx.enqueue(b).unwrap();
        }
        port.room = 30;
        pump.pump(&mut rx, |b| port.write(b));
        assert_eq!(port.got, (2..32).collect::<Vec<u8>>());
        // Unplugged mid-reply: the rest is discarded.
        pump.connected(false, &mut rx);
        assert!(rx.dequeue().is_none());
        port.room = usize::MAX;
        assert_eq!(pump.pump(&mut rx, |b| port.write(b)), 0);
        // The next host reads the next reply from its first byte.
        pump.connected(true, &mut rx);
        port.got.clear();
        for b in [0xaa, 0xbb, 0] {
            tx.enqueue(b).unwrap();
        }
        pump.pump(&mut rx, |b| port.write(b));
        assert_eq!(port.got, [0xaa, 0xbb, 0]);
    }
}
