//! The link's pace in board time: the emulated board carries its link no
//! faster than the link it emulates (QEMU's USART and the in-process board move
//! bytes as fast as the host allows), so its recorder drops exactly what a real
//! board's would, and a command's effect comes no sooner. A real board's link
//! paces itself: there [`Pace`] only names the link.
//!
//! The model: each direction is a line that carries [`LinkKind::bytes_per_s`].
//! A request is taken up when its last byte would have arrived; its reply reaches
//! the host when its last byte would have left, plus [`LinkKind::latency_us`]
//! (a USB host polls once per frame). Times are board ticks in Q16.16, kept
//! modulo 2⁴⁸ (the tick counter's 2³² ticks).

use fpi_protocol::LinkKind;

use crate::board::capacity::RATE_HZ;

/// Board ticks, Q16.16, modulo 2⁴⁸.
type Time = u64;
const WRAP: u64 = (1 << 48) - 1;

/// A link and, on the emulated board, when each direction is next free.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pace {
    link: LinkKind,
    /// Pace the link (the emulated board), or leave it to the hardware.
    paced: bool,
    /// Ticks per byte, Q16.16.
    per_byte: u64,
    /// Latency of a reply, ticks Q16.16.
    latency: u64,
    /// When the host-to-board line is next free (`None`: not used yet).
    rx_free: Option<Time>,
    /// When the board-to-host line is next free.
    tx_free: Option<Time>,
}

impl Pace {
    /// A real board's link: named, not paced (its hardware paces it).
    pub const fn hardware(link: LinkKind) -> Self {
        Self {
            paced: false,
            ..Self::emulating(link)
        }
    }

    /// The emulated board's link, paced as `link`.
    pub const fn emulating(link: LinkKind) -> Self {
        Self {
            link,
            paced: true,
            // Rounded up: never faster than the link.
            per_byte: ((RATE_HZ as u64) << 16).div_ceil(link.bytes_per_s() as u64),
            latency: ((RATE_HZ as u64 * link.latency_us() as u64) << 16) / 1_000_000,
            rx_free: None,
            tx_free: None,
        }
    }

    /// The same pacing (or none) for another link, its lines free.
    pub const fn relinked(&self, link: LinkKind) -> Self {
        Self {
            paced: self.paced,
            ..Self::emulating(link)
        }
    }

    /// The link.
    pub const fn link(&self) -> LinkKind {
        self.link
    }

    /// Whether the link is paced here (the emulated board).
    pub const fn paced(&self) -> bool {
        self.paced
    }

    /// A request of `bytes` (framed) was read at tick `now`: the tick at which
    /// its last byte would have arrived, when it may be taken up.
    pub fn received(&mut self, now: u32, bytes: usize) -> u32 {
        let t = self.carry(self.rx_free, now, bytes);
        self.rx_free = Some(t);
        ticks(t)
    }

    /// A reply of `bytes` (framed), ready at tick `now`: the tick at which the
    /// host has it (the link task sends it then).
    pub fn sent(&mut self, now: u32, bytes: usize) -> u32 {
        let t = self.carry(self.tx_free, now, bytes);
        self.tx_free = Some(t);
        ticks(t.wrapping_add(self.latency) & WRAP)
    }

    /// When a line free at `free` has carried `bytes` handed to it at tick `now`.
    fn carry(&self, free: Option<Time>, now: u32, bytes: usize) -> Time {
        let now = u64::from(now) << 16;
        let start = match free {
            Some(f) if later(f, now) => f,
            _ => now,
        };
        start.wrapping_add(self.per_byte.saturating_mul(bytes as u64)) & WRAP
    }
}

/// `a` after `b` (modulo 2⁴⁸): by less than 2²⁴ ticks (14 min), more than any
/// line is ever booked ahead; a time further "ahead" is one long past.
fn later(a: Time, b: Time) -> bool {
    let d = a.wrapping_sub(b) & WRAP;
    d != 0 && d < 1 << 40
}

/// The first whole tick at or after `t`.
fn ticks(t: Time) -> u32 {
    (t.wrapping_add(0xffff) >> 16) as u32
}

/// Whether tick `now` has reached tick `due` (the counter wraps).
pub const fn reached(now: u32, due: u32) -> bool {
    (now.wrapping_sub(due) as i32) >= 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uart_carries_11520_bytes_a_second_each_way() {
        let mut p = Pace::emulating(LinkKind::Uart);
        // 1 152 bytes = 0.1 s = 2 000 ticks (and a tick for the rounding up),
        // whether sent at once or in pieces.
        assert_eq!(p.sent(100, 1152), 2_101);
        let mut q = Pace::emulating(LinkKind::Uart);
        let mut due = 0;
        for _ in 0..16 {
            due = q.sent(100, 72);
        }
        assert_eq!(due, 2_101);
        // The other direction is another line.
        assert_eq!(p.received(100, 576), 1_101);
        // A line left idle starts again from now.
        assert_eq!(p.sent(10_000, 576), 11_001);
    }

    #[test]
    fn usb_adds_a_frame_of_latency_and_carries_800_kb_a_second() {
        let mut p = Pace::emulating(LinkKind::Usb);
        // 40 bytes a tick; 1 ms = 20 ticks of latency.
        assert_eq!(p.sent(0, 40_000), 1_001 + 20);
        assert_eq!(p.sent(0, 40), 1_002 + 20);
    }

    #[test]
    fn the_tick_counter_may_wrap() {
        let mut p = Pace::emulating(LinkKind::Uart);
        let due = p.sent(u32::MAX - 10, 1152);
        assert_eq!(due, 1_990);
        assert!(reached(due, due) && reached(due.wrapping_add(1), due));
        assert!(!reached(u32::MAX - 10, due));
        // Still after the wrap, a line free in the past starts from now.
        assert_eq!(p.sent(5_000, 576), 6_001);
    }

    #[test]
    fn a_real_board_is_not_paced_but_names_its_link() {
        let p = Pace::hardware(LinkKind::Uart);
        assert!(!p.paced());
        assert_eq!(p.link(), LinkKind::Uart);
    }
}
