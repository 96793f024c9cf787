//! The streamed trajectory: points the host sends, buffered on the board and
//! played back one per `interval` ticks, linearly interpolated in between.
//!
//! [`Points`] is a ring of `N` (a power of two) positions in µm (`I16F16`), filled
//! by the link task and emptied by the control ISR (shared under a lock that costs
//! the ISR nothing: see `crate::control::exchange`). [`Playback`] is the ISR's side: when
//! the next point is missing (the host fell behind) it holds the last one, raises
//! the underrun flag and counts; when the host has said the stream ends, the last
//! point is held without a flag.

use piezo_fpi::q::Micrometres;

/// A ring of streamed points (positions in µm).
#[derive(Debug, Clone)]
pub struct Points<const N: usize> {
    buf: [Micrometres; N],
    /// Points taken (free-running).
    head: u32,
    /// Points put (free-running).
    tail: u32,
    /// The host has sent the last point.
    ended: bool,
}

impl<const N: usize> Default for Points<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Points<N> {
    const MASK: u32 = {
        assert!(N.is_power_of_two() && N <= 1 << 16);
        N as u32 - 1
    };

    /// An empty ring.
    pub const fn new() -> Self {
        Self {
            buf: [Micrometres::ZERO; N],
            head: 0,
            tail: 0,
            ended: false,
        }
    }

    /// Points waiting.
    pub const fn len(&self) -> usize {
        self.tail.wrapping_sub(self.head) as usize
    }

    /// No point waiting.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Room for more points.
    pub const fn free(&self) -> usize {
        N - self.len()
    }

    /// Points taken since the last [`clear`](Self::clear) (free-running): a
    /// stream's point trigger pulses when it moves.
    pub const fn taken(&self) -> u32 {
        self.head
    }

    /// Points put since the last [`clear`](Self::clear): the index the host's next point gets.
    pub const fn received(&self) -> u32 {
        self.tail
    }

    /// Appends a point; `false` (and nothing changes) if the ring is full.
    pub fn push(&mut self, x: Micrometres) -> bool {
        if self.len() >= N {
            return false;
        }
        if let Some(slot) = self.buf.get_mut((self.tail & Self::MASK) as usize) {
            *slot = x;
        }
        self.tail = self.tail.wrapping_add(1);
        self.ended = false;
        true
    }

    /// The oldest point, removed.
    #[inline]
    pub fn pop(&mut self) -> Option<Micrometres> {
        if self.head == self.tail {
            return None;
        }
        let x = self.buf.get((self.head & Self::MASK) as usize).copied();
        self.head = self.head.wrapping_add(1);
        x
    }

    /// The oldest point, left in place.
    pub fn peek(&self) -> Option<Micrometres> {
        if self.head == self.tail {
            return None;
        }
        self.buf.get((self.head & Self::MASK) as usize).copied()
    }

    /// Marks the stream complete: running dry after this is the end, not an underrun.
    pub fn end(&mut self) {
        self.ended = true;
    }

    /// The host has sent its last point.
    pub const fn ended(&self) -> bool {
        self.ended
    }

    /// Drops every point and starts counting from 0.
    pub fn clear(&mut self) {
        // Field by field: a whole new ring would be built on the stack first.
        self.head = 0;
        self.tail = 0;
        self.ended = false;
    }
}

/// The ISR's playback of a stream (state): the segment between two points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Playback {
    from: Micrometres,
    to: Micrometres,
    /// Ticks into the segment.
    k: u16,
    /// Ticks per point (≥ 1).
    interval: u16,
    /// `2³² / interval` (0 for an interval of 1: no interpolation).
    reciprocal: u32,
    /// The last point is held because the next one was missing.
    underrun: bool,
    /// The stream has ended (its last point is held).
    done: bool,
}

impl Playback {
    /// A playback starting at `first` with `interval` ticks per point (0 reads as 1).
    pub fn new(first: Micrometres, interval: u16) -> Self {
        let interval = interval.max(1);
        Self {
            from: first,
            to: first,
            k: interval,
            interval,
            reciprocal: if interval > 1 {
                ((1u64 << 32) / interval as u64) as u32
            } else {
                0
            },
            underrun: false,
            done: false,
        }
    }

    /// The next reference, µm; takes the next point from `points` at each segment's end.
    #[inline]
    pub fn next<const N: usize>(&mut self, points: &mut Points<N>) -> Micrometres {
        if self.k >= self.interval {
            self.from = self.to;
            self.k = 0;
            match points.pop() {
                Some(x) => {
                    self.to = x;
                    self.underrun = false;
                }
                None => {
                    self.done = points.ended();
                    self.underrun = !self.done;
                    // Hold: try again next tick.
                    self.k = self.interval;
                    return self.from;
                }
            }
        }
        let d = self.to.to_bits().wrapping_sub(self.from.to_bits()) as i64;
        let step = (d * self.k as i64 * self.reciprocal as i64) >> 32;
        self.k += 1;
        Micrometres::from_bits(self.from.to_bits().wrapping_add(step as i32))
    }

    /// The host fell behind: the last point is being held.
    pub const fn underrun(&self) -> bool {
        self.underrun
    }

    /// The stream has ended and its last point is held.
    pub const fn done(&self) -> bool {
        self.done
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    #[test]
    fn the_ring_keeps_order_and_refuses_when_full() {
        let mut p = Points::<4>::new();
        for k in 0..4 {
            assert!(p.push(um(k as f64)));
        }
        assert!(!p.push(um(9.0)), "full");
        assert_eq!(p.pop(), Some(um(0.0)));
        assert!(p.push(um(4.0)));
        let got: Vec<f64> = core::iter::from_fn(|| p.pop())
            .map(|x| x.to_num())
            .collect();
        assert_eq!(got, [1.0, 2.0, 3.0, 4.0]);
        assert_eq!(p.received(), 5);
    }

    #[test]
    fn playback_interpolates_between_points() {
        let mut p = Points::<8>::new();
        p.push(um(1.0));
        p.push(um(5.0));
        let mut s = Playback::new(um(1.0), 4);
        let xs: Vec<f64> = (0..8).map(|_| s.next(&mut p).to_num()).collect();
        // First segment 1 → 1 (the start point), then 1 → 5 in four ticks.
        assert_eq!(xs, [1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 3.0, 4.0]);
        assert!(!s.underrun());
    }

    #[test]
    fn an_underrun_holds_the_last_point_and_resumes() {
        let mut p = Points::<8>::new();
        p.push(um(2.0));
        let mut s = Playback::new(um(2.0), 1);
        assert_eq!(s.next(&mut p), um(2.0));
        assert_eq!(s.next(&mut p), um(2.0));
        assert!(s.underrun(), "no point left, stream not ended");
        p.push(um(3.0));
        // A segment starts at the previous point: one interval of delay.
        assert_eq!(s.next(&mut p), um(2.0));
        assert!(!s.underrun());
        assert_eq!(s.next(&mut p), um(3.0));
        p.end();
        assert_eq!(s.next(&mut p), um(3.0));
        assert!(
            s.done() && !s.underrun(),
            "an ended stream is not an underrun"
        );
    }
}
