//! The AD7606 (and AD7606-6, AD7606-4): a 16-bit ADC that samples all its channels
//! at one instant, read over its serial interface on DOUTA. The board samples the
//! force sensor on V1 and the position sensor on V2.
//!
//! # Data-sheet facts relied on
//!
//! From the AD7606/AD7606-6/AD7606-4 data sheet (Rev. C–F) and, where marked, the
//! same family's AD7607/AD7609 data sheets, whose interface text is identical:
//!
//! * **Serial mode**: PAR̅/SER/BYTE SEL = 1 with DB15/BYTE SEL = 0 (Table 8).
//! * **Frame.** The falling edge of CS̅ takes DOUTA out of three-state and clocks out
//!   the MSB; SCLK's rising edges clock out the following bits; data is valid on
//!   SCLK's falling edges (AD7607/AD7609: "MSB valid on the first falling edge of
//!   SCLK after the CS̅ falling edge"). Hence **SPI mode 2** (CPOL 1, CPHA 0): SCLK
//!   idles high, the first edge is a falling one. 16 SCLK per channel, MSB first;
//!   on DOUTA alone the channels come in ascending order V1, V2, …, and one CS̅ may
//!   frame several channels ("Serial Interface"). Raising CS̅ after the first N
//!   channels instead of all of them: the text allows each channel to be framed
//!   by its own CS̅ pulse; that a read may stop after V2 is inferred, **not
//!   stated**.
//! * **Coding**: two's complement, 1 LSB = FSR / 65 536 (±10 V range: 305 µV; ±5 V:
//!   153 µV). From the transfer characteristic as remembered; **not verified** in
//!   the text seen.
//! * **Conversion.** A rising edge on CONVST A/B samples the inputs and starts the
//!   conversion; BUSY goes high and falls when the results are in the output
//!   registers. The falling edge of BUSY updates the output registers, so a read
//!   must not fall on that edge (AD7607, "Digital Filter"). Reading the previous
//!   result while BUSY is high is allowed ("Reading During Conversion"); this
//!   driver does not need it.
//! * **t_CONV** without oversampling: 3.45 µs minimum (the figure ADI's support
//!   forum quotes from the data sheet), 4.15 µs maximum (remembered, **not
//!   verified**). With oversampling about 4, 19 and 39 µs at OS = 1, 4 and 8
//!   (AD7607 Figure 51); the maxima in [`Oversampling::conversion_max_ns`] for
//!   other ratios are remembered values, **not verified**.
//! * **Oversampling**: OS2–OS0 pins, latched at BUSY's falling edge for the next
//!   conversion; CONVST A and B must be driven together when it is on (AD7607,
//!   AD7609 "Digital Filter").
//! * **RANGE** pin high = ±10 V, low = ±5 V; **RESET** a high pulse of at least
//!   50 ns after power-up before the first conversion. Remembered, **not
//!   verified**; [`configure`] pulses RESET for 1 µs and waits 1 µs after it.
//! * **Maximum SCLK**: remembered as 23.5 MHz at V_DRIVE ≥ 4.75 V and less at
//!   3.3 V, **not verified**; the board's 10.5 MHz is below either.

use super::{spi_error, Device, Error};
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{InputPin, OutputPin};
use embedded_hal::spi::{Mode, SpiDevice, MODE_2};

/// The SPI mode of the serial interface (see the module's notes).
pub const SPI_MODE: Mode = MODE_2;
/// Length of the RESET pulse and the wait after it, µs.
pub const RESET_US: u32 = 1;

/// The analog input range, set by the RANGE pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Range {
    /// ±5 V (RANGE low): 152.6 µV per code.
    PlusMinus5V,
    /// ±10 V (RANGE high): 305.2 µV per code.
    PlusMinus10V,
}

impl Range {
    /// The positive full scale, V (the input range is ± this).
    pub const fn full_scale_volts(self) -> f64 {
        match self {
            Range::PlusMinus5V => 5.0,
            Range::PlusMinus10V => 10.0,
        }
    }

    /// The RANGE pin's level: `true` = high.
    const fn pin_high(self) -> bool {
        matches!(self, Range::PlusMinus10V)
    }
}

/// The on-chip averaging, set by the OS2–OS0 pins (the discriminant is their code).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Oversampling {
    /// One conversion per CONVST.
    Off = 0,
    /// Average of 2.
    X2 = 1,
    /// Average of 4.
    X4 = 2,
    /// Average of 8.
    X8 = 3,
    /// Average of 16.
    X16 = 4,
    /// Average of 32.
    X32 = 5,
    /// Average of 64.
    X64 = 6,
}

impl Oversampling {
    /// The longest BUSY-high time after CONVST, ns (see the module's notes on
    /// which values are verified).
    pub const fn conversion_max_ns(self) -> u32 {
        match self {
            Oversampling::Off => 4_150,
            Oversampling::X2 => 9_100,
            Oversampling::X4 => 18_800,
            Oversampling::X8 => 39_000,
            Oversampling::X16 => 78_000,
            Oversampling::X32 => 158_000,
            Oversampling::X64 => 315_000,
        }
    }
}

/// How the ADC is set up: its pins' levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// The input range.
    pub range: Range,
    /// The averaging.
    pub oversampling: Oversampling,
}

/// The ADC's configuration pins, driven by the processor.
#[derive(Debug)]
pub struct ConfigPins<P> {
    /// OS0, OS1, OS2.
    pub os: [P; 3],
    /// RANGE.
    pub range: P,
    /// RESET (active high).
    pub reset: P,
}

/// Sets the range and oversampling pins, then resets the ADC (a 1 µs RESET pulse
/// and 1 µs before the first CONVST may come). The OS pins take effect for the
/// conversion after the next BUSY falling edge.
pub fn configure<P: OutputPin, D: DelayNs>(
    config: &Config,
    pins: &mut ConfigPins<P>,
    delay: &mut D,
) -> Result<(), Error> {
    let os = config.oversampling as u8;
    for (bit, pin) in pins.os.iter_mut().enumerate() {
        level(pin, os & (1 << bit) != 0)?;
    }
    level(&mut pins.range, config.range.pin_high())?;
    level(&mut pins.reset, true)?;
    delay.delay_us(RESET_US);
    level(&mut pins.reset, false)?;
    delay.delay_us(RESET_US);
    Ok(())
}

/// Drives a configuration pin.
fn level<P: OutputPin>(pin: &mut P, high: bool) -> Result<(), Error> {
    let r = if high { pin.set_high() } else { pin.set_low() };
    r.map_err(|_| Error::Pin(Device::Adc))
}

/// One look at the ADC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Conversion<const N: usize> {
    /// BUSY was low: the results of channels V1…VN, two's complement codes.
    Ready([i16; N]),
    /// BUSY was still high: nothing was read.
    Busy,
}

/// An AD7606 on an SPI device (the CS̅ and SCLK pins, DOUTA on MISO), with its BUSY
/// output; reads channels V1…VN (1 ≤ N ≤ 8).
#[derive(Debug)]
pub struct Ad7606<S, B, const N: usize> {
    spi: S,
    busy: B,
}

impl<S: SpiDevice, B: InputPin, const N: usize> Ad7606<S, B, N> {
    /// The ADC on `spi` (SPI mode [`SPI_MODE`]) with its BUSY line. Reads nothing.
    pub const fn new(spi: S, busy: B) -> Self {
        const { assert!(N >= 1 && N <= 8, "the AD7606 has 8 channels") };
        Self { spi, busy }
    }

    /// The finished conversion: if BUSY is low, one CS̅ frame of 16·N SCLK reads
    /// V1…VN; if it is still high, nothing is sent ([`Conversion::Busy`]). Never
    /// waits.
    #[inline]
    pub fn read(&mut self) -> Result<Conversion<N>, Error> {
        if self.busy.is_high().map_err(|_| Error::Pin(Device::Adc))? {
            return Ok(Conversion::Busy);
        }
        let mut frame = [[0u8; 2]; N];
        self.spi
            .read(frame.as_flattened_mut())
            .map_err(spi_error(Device::Adc))?;
        Ok(Conversion::Ready(frame.map(i16::from_be_bytes)))
    }

    /// Gives the SPI device and the BUSY pin back.
    pub fn release(self) -> (S, B) {
        (self.spi, self.busy)
    }
}

#[cfg(test)]
mod tests;
