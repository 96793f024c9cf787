//! When the board's independent (hardware) watchdog may be fed: only while the
//! control task and the link task are both alive. (Not the loop watch, which
//! catches an oscillating loop: that is [`crate::control::watch`].)
//!
//! The control task runs the rule every tick ([`Liveness::tick`]); being called at
//! all shows the control task is alive. The link task shows it is alive by
//! counting its loop passes (a counter the rule reads). The watchdog is fed once
//! per window of [`WINDOW_TICKS`] ticks, and only if the link counter has moved
//! during that window — or the link task has announced a long operation (a flash
//! erase, during which the board also runs the watchdog with a longer period, see
//! the firmware's board module). If either task hangs, feeding stops and the
//! watchdog resets the board, whose reset leaves the amplifier's enable line low.
//!
//! The emulated board has no watchdog (QEMU models none): the rule is tested here,
//! on the host.

/// Ticks per feeding window (10 ms at 20 kHz).
pub const WINDOW_TICKS: u32 = 200;
/// The watchdog's period in normal operation, ms: several windows.
pub const PERIOD_MS: u32 = 100;
/// The watchdog's period during a long operation of the link task (a flash sector
/// erase stalls the STM32F405 for up to 2 s), ms.
pub const LONG_PERIOD_MS: u32 = 4000;

// The period leaves room for several feeding windows, and the long one for a
// sector erase (up to 2 s on the STM32F405).
const _: () = assert!(PERIOD_MS * crate::board::capacity::RATE_HZ / 1000 >= 4 * WINDOW_TICKS);
const _: () = assert!(LONG_PERIOD_MS > 2000);

/// A watchdog the control task feeds.
pub trait Watchdog {
    /// Restarts its countdown.
    fn feed(&mut self);
    /// Runs it with another period, ms.
    fn set_period(&mut self, ms: u32);
}

/// The feeding rule (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Liveness {
    ticks: u32,
    link_seen: u32,
    link_moved: bool,
    fed: u32,
}

impl Liveness {
    /// Nothing seen yet.
    pub const fn new() -> Self {
        Self {
            ticks: 0,
            link_seen: 0,
            link_moved: false,
            fed: 0,
        }
    }

    /// One control tick: `link` is the link task's pass counter, `long` whether
    /// it has announced a long operation. Whether to feed the watchdog now.
    #[inline]
    pub fn tick(&mut self, link: u32, long: bool) -> bool {
        if link != self.link_seen {
            self.link_seen = link;
            self.link_moved = true;
        }
        self.ticks += 1;
        if self.ticks < WINDOW_TICKS {
            return false;
        }
        self.ticks = 0;
        let feed = self.link_moved || long;
        self.link_moved = false;
        self.fed = self.fed.wrapping_add(feed as u32);
        feed
    }

    /// Times the rule said to feed.
    pub const fn feeds(&self) -> u32 {
        self.fed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `ticks` ticks with the link counter advancing every `link_every`
    /// ticks (0: never); the feeds.
    fn run(l: &mut Liveness, link: &mut u32, ticks: u32, link_every: u32, long: bool) -> u32 {
        let mut feeds = 0;
        for t in 0..ticks {
            if link_every != 0 && t % link_every == 0 {
                *link += 1;
            }
            feeds += l.tick(*link, long) as u32;
        }
        feeds
    }

    #[test]
    fn both_tasks_alive_feed_once_per_window() {
        let (mut l, mut link) = (Liveness::new(), 0);
        assert_eq!(run(&mut l, &mut link, 20 * WINDOW_TICKS, 1, false), 20);
        // A link task that passes its loop only now and then still counts.
        assert_eq!(
            run(
                &mut l,
                &mut link,
                20 * WINDOW_TICKS,
                WINDOW_TICKS / 2,
                false
            ),
            20
        );
        assert_eq!(l.feeds(), 40);
    }

    #[test]
    fn a_hung_link_task_stops_the_feeding() {
        let (mut l, mut link) = (Liveness::new(), 0);
        run(&mut l, &mut link, 5 * WINDOW_TICKS, 1, false);
        // The link task hangs: at most the window in progress is fed, then nothing.
        let feeds = run(&mut l, &mut link, 50 * WINDOW_TICKS, 0, false);
        assert!(feeds <= 1, "{feeds}");
        // Nothing the control task does alone revives it.
        assert_eq!(run(&mut l, &mut link, 50 * WINDOW_TICKS, 0, false), 0);
    }

    #[test]
    fn a_long_operation_is_covered_and_ends() {
        let (mut l, mut link) = (Liveness::new(), 0);
        assert_eq!(run(&mut l, &mut link, 10 * WINDOW_TICKS, 0, true), 10);
        assert_eq!(run(&mut l, &mut link, 10 * WINDOW_TICKS, 0, false), 0);
    }
}
