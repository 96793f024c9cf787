//! The reference's preview: a delay line that lets the feedforward see the
//! reference a few ticks before the loops track it.
//!
//! A stage's damped dynamics (its mode, the amplifier's lag, the tick of delay)
//! cannot be inverted causally: a feedforward that only knows the reference up
//! to now lags it. Where the reference is generated on the board (waves, steps,
//! moves, streams), its next ticks are known; the loops then track the reference
//! `n` ticks late while the feedforward ([`Fir`], taps on this line in place of
//! the biquad sections of `crate::biquad`) reaches the newest value, `n` ticks
//! ahead of what is tracked. The cost is `n` ticks of
//! latency between a command and the stage's motion (50 µs a tick at 20 kHz),
//! the same for every reference source, so that switching sources never jumps.
//!
//! **The feedforward on the line** ([`Fir`]): `S_k = Σ_j h_j·r_{k+n−j}` over
//! the line's [`TAPS`] newest references (`n` ticks ahead of the tracked one
//! down to `TAPS − 1 − n` behind it), its taps designed on the host to invert
//! the damped stage (`fpi tune`, `fpi board autotune`).
//!
//! | quantity | format | range |
//! |---|---|---|
//! | references, `S_k` | µm, `I16F16` | input clamped to ±4096 µm, output saturated to ±4096 µm |
//! | taps `h_j` | `I8F24` | ±32, `Σ h_j = 1` exactly (in raw bits: a held reference is never moved), `Σ |h_j| ≤ 32` ([`TAPS_GAIN_MAX`]) |
//! | accumulator | raw `i64`, `I24F40` | `|Σ| ≤ Σ|h_j|·4096 µm`: at most `2²⁹·2²⁸ = 2⁵⁷` raw, no overflow |
//!
//! The output is rounded to nearest (±½ LSB, 15 pm); there is no recursion,
//! so no error accumulates. The delay `n` is `1..=PREVIEW_MAX` ticks.

use crate::error::{Field, Invalid, ModelError};
use crate::process::SplitProcess;
use crate::q::{Micrometres, COEFF_FRAC, SIGNAL_ABS_MAX_BITS};

/// Taps of the feedforward on the line (its length).
pub const TAPS: usize = 16;

/// The most the feedforward may amplify the reference: `Σ |h_j|` (an inverse
/// of a damped stage designed by the host's tools sums to about 6, and up to
/// 20 for a stage with a noisy force sensor; the reference governor's envelope
/// of taps far beyond would leave a stage all but still).
pub const TAPS_GAIN_MAX: i64 = 32;

/// The longest preview the board keeps, ticks.
pub const PREVIEW_MAX: u8 = crate::fields::Field::PreviewTicks.decl().bits().1 as u8;
/// Slots of the delay line: a power of two (the index is masked), above
/// [`PREVIEW_MAX`] and holding every tap's reference.
const SLOTS: usize = 16;
/// Index mask of the delay line.
const MASK: u8 = SLOTS as u8 - 1;
const _: () = assert!(
    SLOTS.is_power_of_two() && SLOTS > PREVIEW_MAX as usize && SLOTS >= TAPS && SLOTS <= 256
);

/// The feedforward on the line (configuration): the delay and the taps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fir {
    ticks: u8,
    taps: [i32; TAPS],
}

impl Fir {
    /// The feedforward running `ticks` ahead with raw `I8F24` `taps` (newest
    /// first), checked: `1..=PREVIEW_MAX` ticks, `Σ taps = 1` exactly, and
    /// `Σ |taps| ≤` [`TAPS_GAIN_MAX`] (also the accumulator's bound). The one
    /// check, for the model validator and the firmware.
    pub const fn new(ticks: u8, taps: [i32; TAPS]) -> Result<Self, Invalid> {
        if ticks == 0 || ticks > PREVIEW_MAX {
            return Err(Invalid::at(Field::Preview, ModelError::OverCapacity));
        }
        let (mut sum, mut abs) = (0i64, 0i64);
        let mut j = 0;
        while j < TAPS {
            sum += taps[j] as i64;
            abs += (taps[j] as i64).abs();
            j += 1;
        }
        if abs > TAPS_GAIN_MAX << COEFF_FRAC {
            return Err(Invalid::at(Field::Preview, ModelError::FeedforwardTooLarge));
        }
        if sum != 1i64 << COEFF_FRAC {
            return Err(Invalid::at(Field::Preview, ModelError::FilterStaticGain));
        }
        Ok(Self { ticks, taps })
    }

    /// Ticks it runs ahead of the tracked reference.
    pub const fn ticks(&self) -> u8 {
        self.ticks
    }

    /// Its raw `I8F24` taps, newest first.
    pub const fn taps(&self) -> &[i32; TAPS] {
        &self.taps
    }
}

/// The delay line (state): the last `SLOTS` references, µm, each written
/// twice (at `i` and `i + SLOTS`), so that the newest `SLOTS` lie in one run
/// `ring[at + 1 ..= at + SLOTS]` whatever `at` is: the taps read it at fixed
/// offsets from one base, without wrapping each index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Preview {
    ring: [Micrometres; 2 * SLOTS],
    at: u8,
    /// The delay it was filled for ([`EMPTY`] before the first value): a new
    /// delay refills it.
    ticks: u8,
}

/// [`Preview::ticks`] of a line never filled.
const EMPTY: u8 = u8::MAX;

impl Default for Preview {
    fn default() -> Self {
        Self::new()
    }
}

impl Preview {
    /// Empty: the first [`push`](Self::push) fills it.
    pub const fn new() -> Self {
        Self {
            ring: [Micrometres::ZERO; 2 * SLOTS],
            at: 0,
            ticks: EMPTY,
        }
    }

    /// Forgets the line: the next [`push`](Self::push) fills it with its value
    /// (a reference that started afresh, leaving a park: its past is not the
    /// one the line holds).
    pub fn restart(&mut self) {
        self.ticks = EMPTY;
    }

    /// Takes the newest reference `ahead` (µm) and gives the one `ticks` ticks
    /// older, which the loops track (`ticks` in `0..=PREVIEW_MAX`, as the model
    /// validator ensures; a longer one reads the line modulo its length). The
    /// first value, and the first after the delay changes, fills the line: the
    /// reference then holds for `ticks` ticks instead of jumping.
    #[inline]
    pub fn push(&mut self, ahead: Micrometres, ticks: u8) -> Micrometres {
        if ticks != self.ticks {
            self.refill(ahead, ticks);
        }
        let at = self.at.wrapping_add(1) & MASK;
        self.at = at;
        self.ring[at as usize] = ahead;
        self.ring[at as usize + SLOTS] = ahead;
        self.ring[(at.wrapping_sub(ticks) & MASK) as usize]
    }

    #[cold]
    #[inline(never)]
    fn refill(&mut self, x: Micrometres, ticks: u8) {
        self.ring = [x; 2 * SLOTS];
        self.ticks = ticks;
    }

    /// The delay in use, ticks.
    pub const fn ticks(&self) -> u8 {
        self.ticks
    }
}

/// The preview feedforward: the reference ahead in, the tracked reference
/// and the feedforward out.
impl SplitProcess<Micrometres, (Micrometres, Micrometres), Preview> for Fir {
    /// Takes the newest reference `ahead` (µm) through the taps: the reference the
    /// loops track this tick (their delay older) and the feedforward `S_k` (µm,
    /// see the module docs). No division, no panic.
    #[inline]
    fn process(&self, p: &mut Preview, ahead: Micrometres) -> (Micrometres, Micrometres) {
        let x = ahead
            .to_bits()
            .clamp(-SIGNAL_ABS_MAX_BITS, SIGNAL_ABS_MAX_BITS);
        let tracked = p.push(Micrometres::from_bits(x), self.ticks);
        let mut acc = 1i64 << (COEFF_FRAC - 1);
        // The newest TAPS values, oldest first, in one run of the mirrored line.
        let newest = (p.at & MASK) as usize + SLOTS;
        if let Some(w) = p.ring.get(newest + 1 - TAPS..=newest) {
            for (h, x) in self.taps.iter().zip(w.iter().rev()) {
                acc += *h as i64 * x.to_bits() as i64;
            }
        }
        let y =
            (acc >> COEFF_FRAC).clamp(-(SIGNAL_ABS_MAX_BITS as i64), SIGNAL_ABS_MAX_BITS as i64);
        (tracked, Micrometres::from_bits(y as i32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_feedforward_is_the_taps_over_the_line_against_f64_and_holds_exactly() {
        let one = 1 << COEFF_FRAC;
        // Unit sum exactly; refused otherwise, and a delay of 0 or beyond the line.
        let taps = padded(&[one * 3 / 2, -one / 4, -one / 2, one / 8, one / 8]);
        let f = Fir::new(4, taps).unwrap();
        let mut off = taps;
        off[TAPS - 1] += 1;
        assert_eq!(
            Fir::new(4, off).unwrap_err().error,
            ModelError::FilterStaticGain
        );
        // Taps that amplify the reference more than 32 times (60 and −59: a
        // hand-edited model that threw the stage across its stroke): refused.
        let wild = padded(&[60 * one, -59 * one]);
        assert_eq!(
            Fir::new(4, wild).unwrap_err().error,
            ModelError::FeedforwardTooLarge
        );
        let most = padded(&[16 * one + one / 2, -31 * one / 2]);
        assert!(Fir::new(4, most).is_ok(), "a sum of 32 is allowed");
        for t in [0, PREVIEW_MAX + 1] {
            assert_eq!(
                Fir::new(t, taps).unwrap_err().error,
                ModelError::OverCapacity
            );
        }
        let mut p = Preview::new();
        let r = |k: i32| 10.0 + 5.0 * (0.05 * k as f64).sin() + 0.3 * (k % 7) as f64;
        let mut worst: f64 = 0.0;
        let mut past = [r(0); TAPS];
        for k in 0..400 {
            let ahead = Micrometres::from_num(r(k));
            let (tracked, ff) = f.process(&mut p, ahead);
            past.rotate_right(1);
            past[0] = ahead.to_num::<f64>();
            let want: f64 = taps
                .iter()
                .zip(past)
                .map(|(h, x)| f64::from(*h) / f64::from(one) * x)
                .sum();
            worst = worst.max((ff.to_num::<f64>() - want).abs());
            assert_eq!(tracked.to_num::<f64>(), past[4]);
        }
        // Rounded to nearest: within half an LSB of the exact sum of the
        // quantised products (plus the f64 sum's own rounding).
        assert!(worst <= 0.5 / 65536.0 + 1e-9, "{worst}");
        // A held reference comes out exactly.
        let held = Micrometres::from_num(17.123_4);
        for _ in 0..TAPS {
            f.process(&mut p, held);
        }
        assert_eq!(f.process(&mut p, held), (held, held));
        // Rails: saturated, no overflow.
        let mut q = Preview::new();
        let big = Fir::new(1, padded(&[one * 8, -one * 7])).unwrap();
        let (_, y) = big.process(&mut q, Micrometres::MAX);
        assert_eq!(y.to_bits(), SIGNAL_ABS_MAX_BITS);
        let (_, y) = big.process(&mut q, Micrometres::MIN);
        assert_eq!(y.to_bits(), -SIGNAL_ABS_MAX_BITS);
    }

    /// `taps`, then zeros to the line's length.
    fn padded(taps: &[i32]) -> [i32; TAPS] {
        let mut out = [0; TAPS];
        out[..taps.len()].copy_from_slice(taps);
        out
    }

    fn um(v: i32) -> Micrometres {
        Micrometres::from_num(v)
    }

    #[test]
    fn the_reference_comes_out_the_delay_later_and_a_new_delay_refills() {
        let mut p = Preview::new();
        // The first value fills the line: no zeros come out.
        assert_eq!(p.push(um(5), 3), um(5));
        assert_eq!(p.push(um(6), 3), um(5));
        assert_eq!(p.push(um(7), 3), um(5));
        assert_eq!(p.push(um(8), 3), um(5));
        for k in 9..40 {
            assert_eq!(p.push(um(k), 3), um(k - 3));
        }
        // No delay: the value itself.
        assert_eq!(p.push(um(100), 0), um(100));
        assert_eq!(p.push(um(101), 0), um(101));
        // The longest.
        assert_eq!(p.push(um(1), PREVIEW_MAX), um(1));
        for k in 2..20 {
            let out = p.push(um(k), PREVIEW_MAX);
            assert_eq!(out, um((k - i32::from(PREVIEW_MAX)).max(1)));
        }
        assert_eq!(p.ticks(), PREVIEW_MAX);
        // Beyond it (a model the validator refuses): no panic, a value pushed.
        for k in 0..20 {
            let out = p.push(um(k), 200);
            assert!(out >= um(0) && out < um(20));
        }
    }
}
