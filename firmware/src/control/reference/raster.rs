//! The raster: a fast axis's triangle over `lines` lines (up, down, up, …)
//! while a slow axis steps from line to line (a staircase) or ramps along
//! them, both started on one tick; what an XY scanner images with.
//!
//! Each axis's part is a [`RasterAxis`] (configuration), its position in the
//! raster a [`RasterPhase`] (state). A line lasts `ticks` ticks (a fast axis
//! at `f` Hz runs `rate / 2f` ticks a line; at most 65 535, 3.3 s at 20 kHz),
//! and a raster has at most 65 535 lines. The values are exact to one LSB
//! of `I16F16` µm at every tick and end exactly on the span's ends: each
//! axis's slope is precomputed when the raster is made (µm per tick or per
//! line in 2⁻³² LSB, `i64`), so the tick multiplies and never divides.
//!
//! | axis | during line `L`, tick `j` | after the last line |
//! |---|---|---|
//! | fast | `from + span·j/T` on even lines, `to − span·j/T` on odd ones | holds where the last line ended |
//! | slow, staircase | `from + span·L/(N − 1)` | holds at `to` |
//! | slow, ramp | `from + span·(L·T + j)/(N·T)` | holds at `to` |

use piezo_fpi::q::Micrometres;

/// How an axis moves in the raster.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// Along each line, up and down.
    Fast,
    /// A step at each line's start.
    Staircase,
    /// A ramp over the whole raster.
    Ramp,
}

/// One axis's part of a raster (configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RasterAxis {
    from: Micrometres,
    to: Micrometres,
    /// Ticks a line.
    ticks: u16,
    /// Lines.
    lines: u16,
    role: Role,
    /// The slope: `I16F16` LSB per tick (fast, ramp) or per line
    /// (staircase), in 2⁻³² LSB (an `i64` kept as two words, so that the
    /// reference's state keeps the 4-byte alignment of the rest).
    per: [u32; 2],
}

/// An `i64` as its low and high words.
const fn words(v: i64) -> [u32; 2] {
    [v as u32, (v >> 32) as u32]
}

/// Where an axis is in its raster (state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RasterPhase {
    line: u16,
    tick: u16,
}

/// The widest span a raster axis takes, `I16F16` LSB (16 384 µm): its
/// slope times any tick count of the raster then fits `i64`.
const SPAN_MAX: i64 = 1 << 30;

/// The span of `from` → `to`, LSB, if it is narrower than [`SPAN_MAX`].
fn span(from: Micrometres, to: Micrometres) -> Option<i64> {
    let span = i64::from(to.to_bits()) - i64::from(from.to_bits());
    (span.abs() < SPAN_MAX).then_some(span)
}

impl RasterAxis {
    /// The fast axis: `lines` lines of `ticks` ticks between `from` and
    /// `to`, µm; `None` for a line shorter than two ticks, no line, or a
    /// span of 16 384 µm or more.
    pub fn fast(from: Micrometres, to: Micrometres, ticks: u16, lines: u16) -> Option<Self> {
        Self::new(from, to, ticks, lines, Role::Fast)
    }

    /// The slow axis from `from` to `to`, µm, over the same lines: a step at
    /// each line's start (`staircase`, at least two lines), or a ramp.
    pub fn slow(
        from: Micrometres,
        to: Micrometres,
        ticks: u16,
        lines: u16,
        staircase: bool,
    ) -> Option<Self> {
        let role = if staircase {
            Role::Staircase
        } else {
            Role::Ramp
        };
        if staircase && lines < 2 {
            return None;
        }
        Self::new(from, to, ticks, lines, role)
    }

    fn new(from: Micrometres, to: Micrometres, ticks: u16, lines: u16, role: Role) -> Option<Self> {
        let span = span(from, to)?;
        if ticks < 2 || lines == 0 {
            return None;
        }
        let steps = match role {
            Role::Fast => u64::from(ticks),
            Role::Staircase => u64::from(lines - 1),
            Role::Ramp => u64::from(ticks) * u64::from(lines),
        };
        Some(Self {
            from,
            to,
            ticks,
            lines,
            role,
            // |span| < 2³⁰: span·2³² fits i64, and so does per·n for n ≤ steps.
            per: words((span << 32) / i64::try_from(steps).ok()?.max(1)),
        })
    }

    /// Where the raster starts, µm.
    pub const fn start_value(&self) -> Micrometres {
        self.from
    }

    /// Where the axis holds after the last line, µm.
    pub const fn end_value(&self) -> Micrometres {
        match self.role {
            Role::Fast if self.lines.is_multiple_of(2) => self.from,
            _ => self.to,
        }
    }

    /// Lines.
    pub const fn lines(&self) -> u16 {
        self.lines
    }

    /// Ticks a line.
    pub const fn line_ticks(&self) -> u16 {
        self.ticks
    }

    /// The value at tick `j` of line `line`, µm.
    #[inline]
    fn value(&self, line: u16, j: u16) -> Micrometres {
        let (base, n) = match self.role {
            Role::Fast if line % 2 == 1 => (self.to, -i64::from(j)),
            Role::Fast => (self.from, i64::from(j)),
            Role::Staircase => (self.from, i64::from(line)),
            Role::Ramp => (
                self.from,
                i64::from(line) * i64::from(self.ticks) + i64::from(j),
            ),
        };
        // Rounded to nearest; |per·n| ≤ |span|·2³².
        let per = (i64::from(self.per[1] as i32) << 32) | i64::from(self.per[0]);
        let d = (per.wrapping_mul(n).wrapping_add(1 << 31)) >> 32;
        Micrometres::from_bits((i64::from(base.to_bits()) + d) as i32)
    }

    /// This tick's value, µm, and the phase advanced; `None` once every
    /// line has run.
    #[inline]
    pub fn next(&self, p: &mut RasterPhase) -> Option<Micrometres> {
        if p.line >= self.lines {
            return None;
        }
        let x = self.value(p.line, p.tick);
        p.tick += 1;
        if p.tick >= self.ticks {
            p.tick = 0;
            p.line += 1;
        }
        Some(x)
    }
}

/// Ticks of a raster's line at `rate_hz` for a fast axis's triangle of
/// `freq_mhz` (a line is half its period, rounded to the nearest tick), if
/// 2 – 65 535: what the board runs, and what the host scores its lines by.
pub fn line_ticks(freq_mhz: u32, rate_hz: u32) -> Option<u16> {
    if freq_mhz == 0 {
        return None;
    }
    let f = u64::from(freq_mhz);
    let ticks = (u64::from(rate_hz) * 1000 + f) / (2 * f);
    u16::try_from(ticks).ok().filter(|&t| t >= 2)
}

/// A raster over two axes (configuration): which is fast, which slow, and
/// each one's part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Raster {
    /// The fast axis's index and its part.
    pub fast: (usize, RasterAxis),
    /// The slow axis's index and its part.
    pub slow: (usize, RasterAxis),
}

impl Raster {
    /// `lines` lines of `ticks` ticks: axis `fast` over `fast_span` (µm,
    /// from, to) on every line, axis `slow` over `slow_span` by steps or a
    /// ramp; `None` if the axes are one, a line is shorter than two ticks,
    /// there is no line, or a staircase has fewer than two lines.
    pub fn new(
        (fast, fast_span): (usize, (Micrometres, Micrometres)),
        (slow, slow_span): (usize, (Micrometres, Micrometres)),
        ticks: u16,
        lines: u16,
        staircase: bool,
    ) -> Option<Self> {
        if fast == slow {
            return None;
        }
        Some(Self {
            fast: (
                fast,
                RasterAxis::fast(fast_span.0, fast_span.1, ticks, lines)?,
            ),
            slow: (
                slow,
                RasterAxis::slow(slow_span.0, slow_span.1, ticks, lines, staircase)?,
            ),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn um(x: f64) -> Micrometres {
        Micrometres::from_num(x)
    }

    fn run(a: &RasterAxis) -> Vec<f64> {
        let mut p = RasterPhase::default();
        core::iter::from_fn(|| a.next(&mut p))
            .map(|x| x.to_num::<f64>())
            .collect()
    }

    /// The f64 reference of each role, within one LSB at every tick, and the
    /// raster's length.
    #[test]
    fn every_tick_is_within_one_lsb_of_the_f64_raster() {
        let (from, to, t, n) = (5.0, 35.0, 100u16, 20u16);
        let lsb = 1.0 / 65536.0;
        let fast = run(&RasterAxis::fast(um(from), um(to), t, n).unwrap());
        let stairs = run(&RasterAxis::slow(um(from), um(to), t, n, true).unwrap());
        let ramp = run(&RasterAxis::slow(um(from), um(to), t, n, false).unwrap());
        let ticks = usize::from(t) * usize::from(n);
        assert_eq!(fast.len(), ticks);
        for k in 0..ticks {
            let (line, j) = (k / t as usize, (k % t as usize) as f64);
            let s = (to - from) * j / f64::from(t);
            let want = if line % 2 == 0 { from + s } else { to - s };
            assert!(
                (fast[k] - want).abs() <= lsb,
                "fast {k}: {} vs {want}",
                fast[k]
            );
            let want = from + (to - from) * line as f64 / f64::from(n - 1);
            assert!((stairs[k] - want).abs() <= lsb, "stairs {k}");
            let want = from + (to - from) * k as f64 / ticks as f64;
            assert!((ramp[k] - want).abs() <= lsb, "ramp {k}");
        }
        // The last line of the staircase is at `to` exactly.
        assert_eq!(stairs[stairs.len() - 1], to);
    }

    #[test]
    fn a_raster_ends_where_its_axes_hold() {
        let a = RasterAxis::fast(um(5.0), um(35.0), 10, 3).unwrap();
        assert_eq!(a.end_value(), um(35.0));
        let b = RasterAxis::fast(um(5.0), um(35.0), 10, 4).unwrap();
        assert_eq!(b.end_value(), um(5.0));
        assert_eq!(
            RasterAxis::slow(um(5.0), um(35.0), 10, 4, false)
                .unwrap()
                .end_value(),
            um(35.0)
        );
        // A downward span runs the same way.
        let down = run(&RasterAxis::fast(um(30.0), um(10.0), 4, 2).unwrap());
        assert_eq!(down, [30.0, 25.0, 20.0, 15.0, 10.0, 15.0, 20.0, 25.0]);
    }

    #[test]
    fn a_raster_that_cannot_run_is_not_made() {
        let span = (um(5.0), um(35.0));
        assert!(Raster::new((0, span), (0, span), 100, 20, true).is_none());
        assert!(Raster::new((0, span), (1, span), 1, 20, true).is_none());
        assert!(Raster::new((0, span), (1, span), 100, 0, false).is_none());
        assert!(Raster::new((0, span), (1, span), 100, 1, true).is_none());
        assert!(Raster::new((0, span), (1, span), 100, 1, false).is_some());
    }
}
