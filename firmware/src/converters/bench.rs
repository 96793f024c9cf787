//! SPI devices and a BUSY line that answer at once, so that `cargo isr-bench` can
//! count the processor's share of a tick's converter work ([`super::tick_frames`])
//! on the emulated board, which has no converters. What they are given and answer
//! goes through [`black_box`], so the optimiser keeps the frames' encoding and
//! decoding.

use super::ad579x::{self, Ad579x};
use super::ad7606::Ad7606;
use super::front_end::FrontEnd;
use core::convert::Infallible;
use core::hint::black_box;
use embedded_hal::digital::{self, InputPin};
use embedded_hal::spi::{self, Operation, SpiDevice};

/// An SPI device that takes any frame and answers every read with `reply`,
/// repeated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Canned {
    /// The bytes read back, in turn.
    pub reply: [u8; 4],
}

impl Canned {
    /// The ADC's answer: V1 = 60 N (offset-binary code 8320), V2 = 20 µm (24 576),
    /// on the board's scalings.
    pub const ADC: Canned = Canned {
        reply: [0xA0, 0x80, 0xE0, 0x00],
    };
    /// The DAC's (unused: the tick only writes to it).
    pub const DAC: Canned = Canned { reply: [0; 4] };

    /// Fills a read buffer with the reply.
    fn fill(&self, buf: &mut [u8]) {
        for (b, r) in buf.iter_mut().zip(self.reply.iter().cycle()) {
            *b = black_box(*r);
        }
    }
}

impl spi::ErrorType for Canned {
    type Error = Infallible;
}

impl SpiDevice for Canned {
    fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), Infallible> {
        for op in operations {
            match op {
                Operation::Read(buf) | Operation::TransferInPlace(buf) => self.fill(buf),
                Operation::Transfer(read, write) => {
                    black_box(&**write);
                    self.fill(read);
                }
                Operation::Write(words) => {
                    black_box(&**words);
                }
                Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}

/// A BUSY line at a fixed level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Busy(pub bool);

impl digital::ErrorType for Busy {
    type Error = Infallible;
}

impl InputPin for Busy {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(black_box(self.0))
    }
    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(!black_box(self.0))
    }
}

/// The front end the benchmark drives.
pub type BenchFrontEnd = FrontEnd<Canned, Busy, Canned>;

/// A front end on canned devices, BUSY low (every conversion ready), its DAC
/// configured as `dac` (the board's, from the board definition).
pub const fn front_end(dac: ad579x::Config) -> BenchFrontEnd {
    FrontEnd::new(
        Ad7606::new(Canned::ADC, Busy(false)),
        Ad579x::new(Canned::DAC, dac),
        [0, 0],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::definition::precision::{DAC, FRONT_END as BOARD};
    use crate::converters::tick_frames;
    use piezo_fpi::q::{Micrometres, Newtons, Volts};

    #[test]
    fn the_bench_front_end_reads_its_canned_sample() {
        let mut fe = front_end(DAC);
        let s = tick_frames(&mut fe, &BOARD, Volts::from_num(75)).unwrap();
        assert_eq!(s.force, Newtons::from_num(60));
        assert_eq!(s.position, Micrometres::from_num(20));
        assert_eq!((s.position_code, s.age), (24_576, 0));
    }
}
