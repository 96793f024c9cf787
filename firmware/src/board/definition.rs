//! The board definition: everything one STM32F4 board has that another may not —
//! its clock, the amplifier's limits, which converters it senses and drives with,
//! their scaling, the pins and peripherals they sit on, and the link. A user with another STM32F4 board
//! edits this file only; the firmware's board code
//! (`src/bin/fpi-firmware/board/`) and the emulated board take what they need
//! from here.
//!
//! **Front end**, chosen by a cargo feature of `fpi-firmware`:
//!
//! * default — [`FrontEndKind::Internal`]: the STM32's own 12-bit ADCs and DAC
//!   ([`internal`]);
//! * `precision` — [`FrontEndKind::Precision`]: an AD7606 (16 bits, force and
//!   position sampled at one instant) and an AD5791 (20 bits) on SPI
//!   ([`precision`]), CONVST and LDAC̅ from timer compare outputs.
//!
//! The internal front end stays the default: it is what every board built so far
//! has, and the board needs no extra parts to start. The emulated board runs
//! either front end's scaling (the bench order `FrontEnd`).
//!
//! **Wiring** (the book's table, `docs/src/flashing.md`, is checked against
//! this one and this one against `pins::take` by `tests-host/tests/wiring.rs`;
//! the last column says which front end uses the pin):
//!
//! | signal | pin | peripheral | front end |
//! |---|---|---|---|
//! | force sensor (0–3.3 V = −5…507 N) | PA0 | ADC1 channel 0 | internal |
//! | analog reference (0–3.3 V = the model's stroke) | PA1 | ADC2 channel 1 | both |
//! | stage-position sensor (0–3.3 V = −10…+70 µm) | PC0 | ADC3 channel 10 | internal |
//! | amplifier setpoint (0–3.3 V = 0–150 V) | PA4 | DAC channel 1 | internal |
//! | AD7606 SCLK | PA5 | SPI1 SCK | precision |
//! | AD7606 DOUTA (V1 force ±10 V = −5…507 N, V2 position ±10 V = −10…+70 µm) | PA6 | SPI1 MISO | precision |
//! | AD7606 CS̅ | PC4 | GPIO | precision |
//! | AD7606 CONVST A and B | PB6 | TIM4 channel 1 (compare, 44 µs into the period) | precision |
//! | AD7606 BUSY | PB8 | GPIO input | precision |
//! | AD7606 RESET | PC5 | GPIO | precision |
//! | AD7606 OS0, OS1, OS2 | PC6, PC7, PC8 | GPIO | precision |
//! | AD7606 RANGE | PC9 | GPIO | precision |
//! | AD5791 SCLK | PB13 | SPI2 SCK | precision |
//! | AD5791 SDO | PB14 | SPI2 MISO | precision |
//! | AD5791 SDIN (0–10 V into the ×15 amplifier = 0–150 V) | PB15 | SPI2 MOSI | precision |
//! | AD5791 SYNC̅ | PB12 | GPIO | precision |
//! | AD5791 LDAC̅ | PB7 | TIM4 channel 2 (compare, the period's first µs) | precision |
//! | amplifier enable (high = on) | PB0 | GPIO | both |
//! | trigger output (high = the condition met; written at the tick's end) | PB1 | GPIO | both |
//! | trigger input (a rising edge starts what is armed; read at the tick's start) | PB9 | GPIO input, pulled down | both |
//! | host link, USB (CDC-ACM, full speed) | PA11 D−, PA12 D+ | OTG_FS | both |
//! | host link, fallback (115 200 Bd, 8N1) | PA9 TX, PA10 RX | USART1 | both |
//!
//! Q formats: scalings as in the core ([`AdcScale`]: offset `I16F16` in the
//! channel's unit, `per_count` `I4F28`; [`DacScale`]: `codes_per_volt` `I16F16`;
//! [`PrecisionDacScale`]: the same for 18/20-bit codes).

use crate::converters::ad579x::{self, Part, Span};
use crate::converters::ad7606::{self, Oversampling, Range};
use crate::converters::front_end::FrontEndConfig;
use crate::converters::scale::PrecisionDacScale;
use crate::converters::schedule::TickTiming;
use piezo_fpi::control::Interval;
use piezo_fpi::io::{AdcScale, DacScale};
use piezo_fpi::model::store::HardwareLimits;
use piezo_fpi::q::{Micrometres, Newtons, Volts};

pub use fpi_protocol::FrontEndKind;

/// The board build's front end (the cargo feature `precision`): the STM32's
/// 12-bit ADCs and DAC ([`internal`]), or AD7606 and AD5791 on SPI
/// ([`precision`]). The board's hello names it.
pub const FRONT_END: FrontEndKind = if cfg!(feature = "precision") {
    FrontEndKind::Precision
} else {
    FrontEndKind::Internal
};

/// The control rate, Hz: one control tick every 50 µs (a model's `rate_hz`
/// must be this).
pub const RATE_HZ: u32 = 20_000;

/// The high-voltage amplifier and the sensor channels, as far as a model may
/// use them (a model may narrow these limits, never widen them): 0–150 V, at
/// most 100 V/ms (5 V per control step: the amplifier's current limit into the
/// stack's capacitance); the safe voltage within 0–10 V, where the stack is at
/// rest under any preload; the sensor windows strictly inside the channels'
/// rails ([`POSITION`]: −10…70 µm; the force front ends': −5…506.9 N, the
/// lower of the two), where a broken wire reads.
pub const AMPLIFIER: HardwareLimits = HardwareLimits {
    u_min: Volts::ZERO,
    u_max: Volts::from_bits(150 << 16),
    max_step: Volts::from_bits(5 << 16),
    safe: Interval {
        lo: Volts::ZERO,
        hi: Volts::from_bits(10 << 16),
    },
    position: Interval {
        lo: Micrometres::from_raw(POSITION.offset),
        hi: Micrometres::from_bits(POSITION.offset.to_bits() + (80 << 16)),
    },
    force: Interval {
        lo: Newtons::from_raw(internal::FORCE.offset),
        hi: Newtons::from_bits(internal::FORCE.offset.to_bits() + (4095 << 13)),
    },
};

/// The board's crystal (HSE), Hz.
pub const HSE_HZ: u32 = 8_000_000;
/// The core clock, Hz (SysTick counts it; the control tick is
/// `CORE_HZ / RATE_HZ` of its cycles).
pub const CORE_HZ: u32 = 168_000_000;
/// The fallback link's line rate, Bd (USART1, 8N1).
pub const UART_BAUD: u32 = 115_200;
/// The USB device's vendor and product ID: pid.codes' test pair for CDC-ACM, as
/// the HAL's examples use. A product needs its own.
pub const USB_VID_PID: (u16, u16) = (0x16c0, 0x27dd);
/// The USB device's manufacturer, product and serial-number strings.
pub const USB_STRINGS: [&str; 3] = ["piezo-fpi", "FPI piezo driver board", "FPI-0001"];

/// The stage-position channel of either front end, as a 16-bit offset-binary code
/// over −10…+70 µm (1.22 nm per code): the AD7606's V2 (±10 V), or the 12-bit
/// ADC3 left-aligned (19.5 nm steps). A broken wire reads a rail. The control loop
/// converts the code with this whichever front end delivers it.
pub const POSITION: AdcScale = AdcScale {
    offset: fixed::types::I16F16::from_bits(-10 << 16), // µm
    per_count: fixed::types::I4F28::from_bits(80 << 12), // 80 µm / 65536
};
/// Largest code of the position channel.
pub const POSITION_MAX: u16 = u16::MAX;

/// The STM32's own converters: the scaling, and the ADC channels (the pins are in
/// `pins`, built for the board only).
pub mod internal {
    use super::*;

    /// The force-sensor front end on ADC1: 12 bits over −5…506.9 N (0.125 N per
    /// count), so a broken wire reads a rail.
    pub const FORCE: AdcScale = AdcScale {
        offset: fixed::types::I16F16::from_bits(-5 << 16), // N
        per_count: fixed::types::I4F28::from_bits(1 << 25),
    };
    /// The setpoint: the STM32's 12-bit DAC behind a 0–150 V (150 V / 3.3 V)
    /// amplifier.
    pub const SETPOINT: DacScale = DacScale {
        codes_per_volt: fixed::types::I16F16::from_bits(1_789_132), // 4095 / 150
        max_code: 4095,
    };
    /// Largest code of the 12-bit ADCs (force, analog reference input).
    pub const ADC_MAX: u16 = 4095;
    /// ADC1's channel of the force sensor.
    pub const FORCE_CHANNEL: u8 = 0;
    /// ADC2's channel of the analog reference input (used by both front ends).
    pub const REFERENCE_CHANNEL: u8 = 1;
    /// ADC3's channel of the position sensor.
    pub const POSITION_CHANNEL: u8 = 10;
}

/// The precision converters: which parts, how they are strapped, their scaling,
/// buses and timing (the pins are in `pins`, built for the board only).
pub mod precision {
    use super::*;

    /// The setpoint DAC: an AD5791 with V_REFN = 0 V and V_REFP = 10 V (a 10 V
    /// span) and a unity-gain buffer, into the ×15 high-voltage amplifier.
    pub const DAC: ad579x::Config = ad579x::Config {
        part: Part::Ad5791,
        span: Span::UpTo10V,
        gain_of_two: false,
    };
    /// The sensor ADC: an AD7606 on ±10 V, no averaging (a result 4.15 µs after
    /// CONVST at most); force on V1, position on V2.
    pub const ADC: ad7606::Config = ad7606::Config {
        range: Range::PlusMinus10V,
        oversampling: Oversampling::Off,
    };
    /// The setpoint: the AD5791's 20 bits over 0–150 V (143 µV per code).
    pub const SETPOINT: PrecisionDacScale = PrecisionDacScale {
        codes_per_volt: fixed::types::I16F16::from_bits(458_129_408), // 1 048 575 / 150, exact
        max_code: (1 << 20) - 1,
    };
    /// The force sensor on V1: ±10 V = −5…507 N (0.0078 N per code), the span of
    /// the internal force channel ([`internal::FORCE`]) in 16 bits, so a broken
    /// wire still reads a rail outside the plausible range.
    pub const FORCE: AdcScale = AdcScale {
        offset: fixed::types::I16F16::from_bits(-5 << 16), // N
        per_count: fixed::types::I4F28::from_bits(1 << 21), // 512 N / 65 536
    };
    /// Missed conversions in a row the board tolerates before the converter fault:
    /// 3 ticks (150 µs) on the last good sample.
    pub const STALE_LIMIT: u16 = 3;
    /// Both channels' scalings and the miss limit, as the ISR uses them.
    pub const FRONT_END: FrontEndConfig = FrontEndConfig {
        force: FORCE,
        position: POSITION,
        setpoint: SETPOINT,
        stale_limit: STALE_LIMIT,
    };
    /// The period's phases: 50 µs (20 kHz), CONVST at 44 µs, the AD7606 without
    /// averaging, the ISR's read done within 44 µs of its start. The sample is
    /// 6 µs old when the tick starts.
    pub const TIMING: TickTiming = TickTiming {
        period_ns: 1_000_000_000 / RATE_HZ,
        convst_ns: 44_000,
        conversion_max_ns: ADC.oversampling.conversion_max_ns(),
        read_done_ns: 44_000,
    };
    const _: () = assert!(TIMING.check().is_ok(), "the board's converter timing");
    /// LDAC̅'s low pulse at the start of each period, ns (the AD5791 loads the code
    /// the previous tick wrote on its falling edge).
    pub const LDAC_PULSE_NS: u32 = 1_000;
    /// The ADC's SCLK (SPI1 on the 84 MHz APB2: 84 / 8), Hz.
    pub const ADC_SCLK_HZ: u32 = 10_500_000;
    /// The DAC's SCLK (SPI2 on the 42 MHz APB1: 42 / 4), Hz.
    pub const DAC_SCLK_HZ: u32 = 10_500_000;
}

/// The pins and peripherals (the board build only: the HAL's types).
#[cfg(target_os = "none")]
pub mod pins {
    use crate::converters::ad7606::ConfigPins;
    use stm32f4xx_hal::gpio::{self, alt, Analog, AnyPin, Input, Output, PushPull};
    use stm32f4xx_hal::pac;
    use stm32f4xx_hal::rcc::{Config, Rcc};

    /// The ADC for the force sensor ([`super::internal::FORCE_CHANNEL`]).
    pub type ForceAdc = pac::ADC1;
    /// The ADC for the analog reference input.
    pub type ReferenceAdc = pac::ADC2;
    /// The ADC for the position sensor (internal front end).
    pub type PositionAdc = pac::ADC3;
    /// The SPI of the AD7606 (mode 2).
    pub type AdcSpi = pac::SPI1;
    /// The SPI of the AD5791 (mode 1).
    pub type DacSpi = pac::SPI2;
    /// The timer whose channel 1 drives CONVST and channel 2 LDAC̅ (a 16-bit
    /// general-purpose timer: TIM3 or TIM4).
    pub type ConvTimer = pac::TIM4;
    /// The fallback link's USART.
    pub type Uart = pac::USART1;
    /// The pins both front ends use.
    pub struct Common {
        /// The amplifier's enable, low (off).
        pub enable: gpio::PB0<Output<PushPull>>,
        /// The trigger output, low.
        pub trigger_out: gpio::PB1<Output<PushPull>>,
        /// The trigger input, pulled down.
        pub trigger_in: gpio::PB9<gpio::Input>,
        /// The analog reference input ([`ReferenceAdc`]).
        pub reference: gpio::PA1<Analog>,
        /// USB D−, D+.
        pub usb: (gpio::PA11, gpio::PA12),
        /// USART TX, RX.
        pub uart: (gpio::PA9, gpio::PA10),
    }

    /// The internal front end's pins.
    pub struct Internal {
        /// The force sensor ([`ForceAdc`]).
        pub force: gpio::PA0<Analog>,
        /// The position sensor ([`PositionAdc`]).
        pub position: gpio::PC0<Analog>,
        /// DAC channel 1.
        pub setpoint: gpio::PA4<Analog>,
    }

    /// The precision front end's pins.
    pub struct Precision {
        /// AD7606 SCLK and DOUTA ([`AdcSpi`]).
        pub adc_spi: (alt::spi1::Sck, alt::spi1::Miso),
        /// AD7606 CS̅, high.
        pub adc_cs: AnyPin<Output<PushPull>>,
        /// AD7606 BUSY.
        pub busy: AnyPin<Input>,
        /// AD7606 OS0–OS2, RANGE, RESET.
        pub adc_config: ConfigPins<AnyPin<Output<PushPull>>>,
        /// CONVST A/B on [`ConvTimer`] channel 1 (alternate function 2).
        pub convst: gpio::PB6<gpio::Alternate<2>>,
        /// AD5791 SCLK, SDO, SDIN ([`DacSpi`]).
        pub dac_spi: (alt::spi2::Sck, alt::spi2::Miso, alt::spi2::Mosi),
        /// AD5791 SYNC̅, high.
        pub dac_cs: AnyPin<Output<PushPull>>,
        /// LDAC̅ on [`ConvTimer`] channel 2 (alternate function 2).
        pub ldac: gpio::PB7<gpio::Alternate<2>>,
    }

    /// The clock tree: 168 MHz from the 8 MHz crystal, and the USB's 48 MHz.
    pub fn clocks() -> Config {
        use stm32f4xx_hal::time::Hertz;
        Config::hse(Hertz::Hz(super::HSE_HZ))
            .sysclk(Hertz::Hz(super::CORE_HZ))
            .require_pll48clk()
    }

    /// A pin as a push-pull output at `high`.
    #[cfg(feature = "precision")]
    fn out<const P: char, const N: u8, M>(p: gpio::Pin<P, N, M>, high: bool) -> AnyPin<Output>
    where
        M: gpio::PinMode,
    {
        let state = if high {
            gpio::PinState::High
        } else {
            gpio::PinState::Low
        };
        p.into_push_pull_output_in_state(state).erase()
    }

    /// The build's front end's pins.
    #[cfg(not(feature = "precision"))]
    pub type FrontPins = Internal;
    /// The build's front end's pins.
    #[cfg(feature = "precision")]
    pub type FrontPins = Precision;

    /// The board's pins, in their modes (outputs at their idle levels), from the
    /// GPIO ports: the ones both front ends use, and the build's front end's.
    pub fn take(
        (a, b, c): (pac::GPIOA, pac::GPIOB, pac::GPIOC),
        rcc: &mut Rcc,
    ) -> (Common, FrontPins) {
        use stm32f4xx_hal::gpio::GpioExt;
        let (a, b, c) = (a.split(rcc), b.split(rcc), c.split(rcc));
        let common = Common {
            enable: b.pb0.into_push_pull_output_in_state(gpio::PinState::Low),
            trigger_out: b.pb1.into_push_pull_output_in_state(gpio::PinState::Low),
            trigger_in: b.pb9.into_pull_down_input(),
            reference: a.pa1.into_analog(),
            usb: (a.pa11, a.pa12),
            uart: (a.pa9, a.pa10),
        };
        #[cfg(not(feature = "precision"))]
        let front = Internal {
            force: a.pa0.into_analog(),
            position: c.pc0.into_analog(),
            setpoint: a.pa4.into_analog(),
        };
        #[cfg(feature = "precision")]
        let front = Precision {
            adc_spi: (a.pa5.into(), a.pa6.into()),
            adc_cs: out(c.pc4, true),
            busy: b.pb8.into_floating_input().erase(),
            adc_config: ConfigPins {
                os: [out(c.pc6, false), out(c.pc7, false), out(c.pc8, false)],
                range: out(c.pc9, false),
                reset: out(c.pc5, false),
            },
            convst: b.pb6.into_alternate(),
            dac_spi: (b.pb13.into(), b.pb14.into(), b.pb15.into()),
            dac_cs: out(b.pb12, true),
            ldac: b.pb7.into_alternate(),
        };
        (common, front)
    }
}
