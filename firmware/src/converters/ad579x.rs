//! The AD5781 (18-bit) and AD5791 (20-bit) voltage-output DACs: the amplifier's
//! setpoint.
//!
//! # Data-sheet facts relied on
//!
//! From the AD5791 and AD5781 data sheets (Rev. D) unless marked otherwise:
//!
//! * **Frame.** 24 bits, MSB first, one frame per SYNC̅ low (the [`SpiDevice`]'s chip
//!   select): DB23 = R/W̅ (1 = read), DB22–DB20 = register address, DB19–DB0 =
//!   register data (AD5791 Table 7, "Input Shift Register Format").
//! * **Registers.** 000 no operation, 001 DAC, 010 control, 011 clearcode, 100
//!   software control (write only). The DAC register holds the AD5791's 20-bit code
//!   in DB19–DB0 (Table 10), the AD5781's 18-bit code in DB19–DB2 with DB1–DB0
//!   don't care (AD5781 Table 10).
//! * **Transfer function.** `V_OUT = (V_REFP − V_REFN)·D / (2^N − 1) + V_REFN`
//!   (Table 10's equation) with offset-binary coding (BIN/2sC = 1); V_REFP from 5 V
//!   to V_DD − 2.5 V, V_REFN from V_SS + 2.5 V to 0 V (the Linux binding's notes).
//! * **Control register** (Table 11): DB1 RBUF, DB2 OPGND, DB3 DACTRI, DB4 BIN/2sC,
//!   DB5 SDODIS, DB9–DB6 LIN COMP; DB0 and DB19–DB10 reserved, written 0.
//!   RBUF = 1 (default): internal amplifier A1 off, R_FB and R1 in parallel, for an
//!   external unity-gain buffer; RBUF = 0: A1 on, for an external gain-of-two stage.
//! * **Power-on state** ("Power-On to 0 V"): OPGND and DACTRI set, the output
//!   clamped to AGND through ~6 kΩ and the DAC tristated until the control register
//!   clears both; the output then goes to V_REFN unless the DAC register was
//!   written first. [`Ad579x::init`] writes the code first.
//! * **Linearity compensation.** LIN COMP = 0000 for reference spans up to 10 V,
//!   1100 for a 20 V span ("Linearity Compensation"). Codes for the AD5791's
//!   intermediate spans (10–19 V) differ between sources seen; they are not offered.
//! * **Write SCLK** up to 50 MHz ("Serial Interface").
//! * **Readback.** A frame with R/W̅ = 1 and the address; the register comes out on
//!   SDO during the next frame, which sends a no-operation. This is how ADI's
//!   Linux and no-OS drivers read; the data sheet's readback figure was **not
//!   seen**. Only DB19–DB0 of the word read are used: what DB23–DB20 carry was
//!   **not verified**. Readback has a lower SCLK limit than writes; its value was
//!   **not verified** here: run the DAC's bus at 10.5 MHz (or slow it for the
//!   self-test).
//! * **Software control register** DB0 LDAC, DB1 CLR, DB2 RESET: from ADI's drivers,
//!   **not verified** in the data sheet; not used.
//! * **SPI mode 1** (CPOL 0, CPHA 1): input latched on SCLK falling edges, SDO
//!   changing on rising edges. From the timing diagram as remembered, **not
//!   verified**; public AD5791 code also uses mode 2 for writes (same latching
//!   edge, SCLK idling high).
//! * **LDAC̅.** Held low, the output follows each DAC-register write at SYNC̅'s rising
//!   edge; held high, it waits for LDAC̅'s falling edge. From the pin description
//!   as remembered, **not verified**; only the timed-output option of
//!   [`super::schedule`] depends on it.
//!
//! [`SpiDevice`]: embedded_hal::spi::SpiDevice

use super::{spi_error, Device, Error};
use embedded_hal::spi::{Mode, SpiDevice, MODE_1};

/// The SPI mode the parts are driven in (see the module's notes).
pub const SPI_MODE: Mode = MODE_1;
/// Fastest SCLK for writes, Hz.
pub const MAX_WRITE_SCLK_HZ: u32 = 50_000_000;

/// R/W̅ (DB23): 1 = read.
const READ: u32 = 1 << 23;
/// DB19–DB0: the data bits of a frame.
const DATA_MASK: u32 = 0xF_FFFF;
/// Control register: RBUF, internal amplifier off (unity-gain external buffer).
const RBUF: u32 = 1 << 1;
/// Control register: output clamped to AGND through ~6 kΩ.
const OPGND: u32 = 1 << 2;
/// Control register: DAC tristated.
const DACTRI: u32 = 1 << 3;
/// Control register: offset-binary coding of the DAC register.
const BIN_2SC: u32 = 1 << 4;
/// Control register: position of LIN COMP (DB9–DB6).
const LIN_COMP_SHIFT: u32 = 6;
/// Control register bits this driver sets and checks (DB9–DB1).
const CONTROL_MASK: u32 = 0x3FE;

/// A no-operation frame: clocks a register out during a readback.
pub const NOP: [u8; 3] = [0; 3];

/// The registers (address bits DB22–DB20).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Register {
    /// No operation.
    Nop = 0,
    /// The DAC code.
    Dac = 1,
    /// The control register (output state, coding, span).
    Control = 2,
    /// The code the CLR̅ pin loads.
    ClearCode = 3,
    /// Software LDAC, CLR and RESET (write only).
    SoftwareControl = 4,
}

/// Which part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// AD5781: 18 bits, code in DB19–DB2.
    Ad5781,
    /// AD5791: 20 bits, code in DB19–DB0.
    Ad5791,
}

impl Part {
    /// Resolution, bits.
    pub const fn bits(self) -> u32 {
        match self {
            Part::Ad5781 => 18,
            Part::Ad5791 => 20,
        }
    }

    /// The largest code (2^bits − 1).
    pub const fn max_code(self) -> u32 {
        (1 << self.bits()) - 1
    }

    /// Left shift of the code within DB19–DB0.
    const fn shift(self) -> u32 {
        20 - self.bits()
    }
}

/// The reference span V_REFP − V_REFN, for the linearity compensation (LIN COMP).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Span {
    /// Up to 10 V (LIN COMP 0000).
    UpTo10V = 0b0000,
    /// 20 V, e.g. ±10 V references (LIN COMP 1100).
    Span20V = 0b1100,
}

/// Whether the output is driven or held at ground.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// Normal operation: the output follows the DAC register.
    On,
    /// Clamped to AGND through ~6 kΩ, the DAC tristated (the power-on state).
    Clamped,
}

/// How a DAC is wired: the part, its reference span and its output stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// The part.
    pub part: Part,
    /// The reference span.
    pub span: Span,
    /// `true`: an external amplifier in gain of two on R_FB/INV (RBUF = 0);
    /// `false`: an external unity-gain buffer (RBUF = 1).
    pub gain_of_two: bool,
}

impl Config {
    /// The control register's data bits: offset-binary coding, the span's LIN COMP,
    /// RBUF for the output stage, SDO enabled (for readback), and `output`.
    pub const fn control(&self, output: Output) -> u32 {
        let rbuf = if self.gain_of_two { 0 } else { RBUF };
        let word = BIN_2SC | rbuf | ((self.span as u32) << LIN_COMP_SHIFT);
        match output {
            Output::On => word,
            Output::Clamped => word | OPGND | DACTRI,
        }
    }
}

/// The frame that writes `data` (DB19–DB0) to `register` (R/W̅ = 0).
pub const fn write_frame(register: Register, data: u32) -> [u8; 3] {
    frame(((register as u32) << 20) | (data & DATA_MASK))
}

/// The frame that asks for `register` to come out on SDO during the next frame
/// (R/W̅ = 1).
pub const fn read_frame(register: Register) -> [u8; 3] {
    frame(READ | ((register as u32) << 20))
}

/// The low 24 bits of `word`, MSB first.
const fn frame(word: u32) -> [u8; 3] {
    let [_, a, b, c] = word.to_be_bytes();
    [a, b, c]
}

/// The data bits (DB19–DB0) of a frame read on SDO.
const fn data_bits(frame: [u8; 3]) -> u32 {
    let [a, b, c] = frame;
    u32::from_be_bytes([0, a, b, c]) & DATA_MASK
}

/// An AD5781/AD5791 on an SPI device.
#[derive(Debug)]
pub struct Ad579x<S> {
    spi: S,
    config: Config,
}

impl<S: SpiDevice> Ad579x<S> {
    /// The DAC on `spi` (SPI mode [`SPI_MODE`]), wired as `config`. Sends nothing.
    pub const fn new(spi: S, config: Config) -> Self {
        Self { spi, config }
    }

    /// How it is wired.
    pub const fn config(&self) -> &Config {
        &self.config
    }

    /// Start-up, with the amplifier disabled: the coding and span with the output
    /// still clamped, then `first_code` (the safe voltage's code), then the output
    /// on; finally the control register is read back. Four frames and a readback.
    pub fn init(&mut self, first_code: u32) -> Result<(), Error> {
        self.write(Register::Control, self.config.control(Output::Clamped))?;
        self.write_code(first_code)?;
        self.set_output(Output::On)?;
        self.check_control(Output::On)
    }

    /// Writes a code to the DAC register: one 24-bit frame, the code saturated to
    /// the part's range. With LDAC̅ low the output follows at once.
    #[inline]
    pub fn write_code(&mut self, code: u32) -> Result<(), Error> {
        let max = self.config.part.max_code();
        let code = if code > max { max } else { code };
        self.write(Register::Dac, code << self.config.part.shift())
    }

    /// Drives the output or clamps it to ground (the control register).
    pub fn set_output(&mut self, output: Output) -> Result<(), Error> {
        self.write(Register::Control, self.config.control(output))
    }

    /// A register's data bits (DB19–DB0): the read frame, then a no-operation frame
    /// during which the register comes out on SDO. Two chip-select frames.
    pub fn read_register(&mut self, register: Register) -> Result<u32, Error> {
        let mut out = [0; 3];
        self.spi
            .write(&read_frame(register))
            .map_err(spi_error(Device::Dac))?;
        self.spi
            .transfer(&mut out, &NOP)
            .map_err(spi_error(Device::Dac))?;
        Ok(data_bits(out))
    }

    /// The code in the DAC register.
    pub fn read_code(&mut self) -> Result<u32, Error> {
        Ok(self.read_register(Register::Dac)? >> self.config.part.shift())
    }

    /// Self-test: the control register reads back as configured with the output
    /// on, and the DAC register holds `code` (saturated as [`write_code`] does).
    ///
    /// [`write_code`]: Self::write_code
    pub fn self_test(&mut self, code: u32) -> Result<(), Error> {
        self.check_control(Output::On)?;
        let max = self.config.part.max_code();
        let wrote = if code > max { max } else { code };
        let read = self.read_code()?;
        if read != wrote {
            return Err(Error::Readback {
                register: Register::Dac,
                wrote,
                read,
            });
        }
        Ok(())
    }

    /// Gives the SPI device back.
    pub fn release(self) -> S {
        self.spi
    }

    /// Checks the control register's bits against the configuration.
    fn check_control(&mut self, output: Output) -> Result<(), Error> {
        let wrote = self.config.control(output) & CONTROL_MASK;
        let read = self.read_register(Register::Control)? & CONTROL_MASK;
        if read != wrote {
            return Err(Error::Readback {
                register: Register::Control,
                wrote,
                read,
            });
        }
        Ok(())
    }

    /// One write frame.
    fn write(&mut self, register: Register, data: u32) -> Result<(), Error> {
        self.spi
            .write(&write_frame(register, data))
            .map_err(spi_error(Device::Dac))
    }
}

#[cfg(test)]
mod tests;
