//! The boundary between the core and a board: a force sensor in, an amplifier setpoint out.
//!
//! The firmware implements these traits on top of its HAL (the STM32 ADC and DAC,
//! or the emulator's simulated stage); the core never sees a peripheral.
//! embedded-hal 1.0 has no ADC or DAC trait, so these two small traits are ours.

use crate::control::{ControllerConfig, ControllerState, Forces, Mode, StepOutput};
use crate::fpi::Shape;
use crate::q::{within, Micrometres, Newtons, Volts, GAIN_FRAC, SIGNAL_FRAC};
use embedded_hal::digital::OutputPin;
use fixed::types::{I16F16, I4F28};

/// Reads the force between stack and hinge.
pub trait ForceSensor {
    /// The latest reading, N. A broken sensor should read outside its plausible
    /// range (e.g. the ADC rails); the controller turns that into a fault.
    fn read_force(&mut self) -> Newtons;
}

/// Drives the high-voltage amplifier.
pub trait Setpoint {
    /// Commands the amplifier output, V.
    fn write_voltage(&mut self, voltage: Volts);
}

/// The hardware one control loop drives: force sensor, amplifier setpoint and the
/// amplifier's enable line (an embedded-hal [`OutputPin`]; high = amplifier on).
pub struct Hardware<S, A, E> {
    /// The force sensor between stack and hinge.
    pub sensor: S,
    /// The high-voltage amplifier's setpoint.
    pub amplifier: A,
    /// The amplifier's enable (or shutdown-not) line.
    pub enable: E,
}

/// What one [`Hardware::tick`] did: the step's result and the force it read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// The control step's output (the voltage written, the estimate, the fault).
    pub out: StepOutput,
    /// The force reading the step was given, N.
    pub force: Newtons,
}

impl<S: ForceSensor, A: Setpoint, E: OutputPin> Hardware<S, A, E> {
    /// One control period, the body of the ISR: read the force, run the step, write
    /// the setpoint ([`sense`](Self::sense), then [`drive`](Self::drive)).
    #[inline]
    pub fn tick<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
        st: &mut ControllerState<N, C>,
        mode: &Mode,
        x_ref: Micrometres,
    ) -> Tick {
        let forces = self.sense(cfg, st);
        self.drive(cfg, st, mode, x_ref, &forces)
    }

    /// The first half of a period: read the force sensor and its channel
    /// ([`ControllerConfig::sense`]: the feedforward force, the dynamic force, the
    /// force faults), before the application computes its command.
    #[inline]
    pub fn sense<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
        st: &mut ControllerState<N, C>,
    ) -> Forces {
        self.sense_coupled(cfg, st, Newtons::ZERO)
    }

    /// [`sense`](Self::sense) with the preload the other stacks put on this
    /// one, N ([`ControllerConfig::sense_coupled`]).
    #[inline]
    pub fn sense_coupled<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
        st: &mut ControllerState<N, C>,
        coupled: Newtons,
    ) -> Forces {
        let force = self.sensor.read_force();
        cfg.sense_coupled(st, force, coupled)
    }

    /// The second half: run the step on the forces read, write the setpoint. Once
    /// a fault's ramp has reached the safe voltage the amplifier is switched off;
    /// otherwise it is on.
    #[inline]
    pub fn drive<'a, const N: usize, const C: usize, G: Shape<'a>, H: Shape<'a>>(
        &mut self,
        cfg: &ControllerConfig<'a, N, C, G, H>,
        st: &mut ControllerState<N, C>,
        mode: &Mode,
        x_ref: Micrometres,
        forces: &Forces,
    ) -> Tick {
        let force = forces.reading;
        let out = match mode {
            Mode::Compensated => cfg.step_sensed(st, x_ref, forces),
            Mode::Uncompensated(drive) => cfg.step_uncompensated_sensed(st, drive, x_ref, forces),
        };
        self.amplifier.write_voltage(out.voltage);
        // A pin error cannot be handled in the ISR; the next tick writes it again.
        let _ = if out.fault.is_some() && out.voltage == cfg.safe_voltage() {
            self.enable.set_low()
        } else {
            self.enable.set_high()
        };
        Tick { out, force }
    }
}

/// ADC counts to newtons (or, for a position channel, micrometres):
/// `F = offset + per_count · counts`.
///
/// * `offset` — N (µm) at zero counts, `I16F16` in the channel's unit: one
///   scaling serves both channels, so its unit is the reading's
///   ([`to_force`](Self::to_force), [`to_position`](Self::to_position)).
/// * `per_count` — N (µm) per count, `I4F28` (12-bit ADC over 0–500 N: 0.122 N/count).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AdcScale {
    /// The value at zero counts, N or µm.
    pub offset: I16F16,
    /// Newtons (micrometres) per count.
    pub per_count: I4F28,
}

impl AdcScale {
    /// The force for a raw conversion result.
    #[inline]
    pub fn to_force(&self, counts: u16) -> Newtons {
        Newtons::from_raw(self.to_value(counts))
    }

    /// The position for a raw conversion result (a position channel's scaling).
    #[inline]
    pub fn to_position(&self, counts: u16) -> Micrometres {
        Micrometres::from_raw(self.to_value(counts))
    }

    /// The value for a raw conversion result, in the channel's unit (`I16F16`: N
    /// for the force sensor, µm for a position sensor). The product is exact in
    /// 64 bits and rounded to nearest once (a 16-bit code does not fit `I16F16`).
    #[inline]
    pub fn to_value(&self, counts: u16) -> I16F16 {
        let wide = self.per_count.to_bits() as i64 * counts as i64;
        let shift = GAIN_FRAC - SIGNAL_FRAC;
        let v = (wide + (1 << (shift - 1))) >> shift;
        I16F16::from_bits(v as i32).saturating_add(self.offset)
    }

    /// The conversion result nearest to a force, saturated to `0..=max_code`
    /// (for simulated sensors and tests).
    pub fn to_counts(&self, force: f32, max_code: u16) -> u16 {
        let c = (force - self.offset.to_num::<f32>()) / self.per_count.to_num::<f32>() + 0.5;
        if c <= 0.0 {
            0
        } else if c >= max_code as f32 {
            max_code
        } else {
            c as u16
        }
    }
}

/// Volts to DAC codes: `code = round(u · codes_per_volt)`, saturated to `0..=max_code`.
///
/// * `codes_per_volt` — `I16F16` (16-bit DAC over 0–150 V: 436.9; 12-bit STM32 DAC
///   behind a 150 V / 3.3 V amplifier: 27.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DacScale {
    /// Codes per volt of amplifier output.
    pub codes_per_volt: I16F16,
    /// Largest code (4095 for 12 bits, 65535 for 16 bits).
    pub max_code: u16,
}

impl DacScale {
    /// The DAC code for an amplifier voltage. No panic, no division.
    #[inline]
    pub fn to_code(&self, voltage: Volts) -> u16 {
        let u = within(voltage, Volts::ZERO, Volts::MAX);
        let c = (u.to_bits() as i64 * self.codes_per_volt.to_bits() as i64 + (1 << 31)) >> 32;
        if c > self.max_code as i64 {
            self.max_code
        } else {
            c as u16
        }
    }

    /// The amplifier voltage a code produces (for simulated stages and tests).
    pub fn to_voltage(&self, code: u16) -> f32 {
        code as f32 / self.codes_per_volt.to_num::<f32>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit;
    use core::convert::Infallible;
    use embedded_hal::digital::ErrorType;

    /// A sensor that reads what the test sets, an amplifier and an enable line
    /// that remember what the tick wrote.
    struct Bench {
        force: Newtons,
        written: Option<Volts>,
        enabled: Option<bool>,
    }
    struct Sensor<'a>(&'a core::cell::RefCell<Bench>);
    struct Amp<'a>(&'a core::cell::RefCell<Bench>);
    struct Enable<'a>(&'a core::cell::RefCell<Bench>);
    impl ForceSensor for Sensor<'_> {
        fn read_force(&mut self) -> Newtons {
            self.0.borrow().force
        }
    }
    impl Setpoint for Amp<'_> {
        fn write_voltage(&mut self, v: Volts) {
            self.0.borrow_mut().written = Some(v);
        }
    }
    impl ErrorType for Enable<'_> {
        type Error = Infallible;
    }
    impl OutputPin for Enable<'_> {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().enabled = Some(false);
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().enabled = Some(true);
            Ok(())
        }
    }

    #[test]
    fn a_tick_writes_the_setpoint_and_switches_off_only_at_the_safe_voltage() {
        let cfg = testkit::controller();
        let mut st = cfg.initial_state();
        let bench = core::cell::RefCell::new(Bench {
            force: Newtons::from_num(60),
            written: None,
            enabled: None,
        });
        let mut hw = Hardware {
            sensor: Sensor(&bench),
            amplifier: Amp(&bench),
            enable: Enable(&bench),
        };
        // Up the stroke: the setpoint the step computed reaches the amplifier,
        // which stays on.
        for k in 0..300 {
            let x = Micrometres::from_num(15.0 * k as f64 / 300.0);
            let f = Newtons::from_raw(cfg.f_f().eval(st.x_pea_est().raw()));
            bench.borrow_mut().force = f;
            let Tick { out, force } = hw.tick(&cfg, &mut st, &Mode::Compensated, x);
            assert_eq!(force, f, "the reading is reported");
            let b = bench.borrow();
            assert_eq!(b.written, Some(out.voltage));
            assert_eq!(b.enabled, Some(true));
        }
        assert!(st.voltage() > Volts::from_num(50));
        // A broken wire: the output ramps down with the amplifier on, and only at
        // the safe voltage is it switched off.
        bench.borrow_mut().force = Newtons::from_num(999);
        loop {
            let out = hw
                .tick(&cfg, &mut st, &Mode::Compensated, Micrometres::from_num(15))
                .out;
            let b = bench.borrow();
            assert_eq!(b.written, Some(out.voltage));
            if out.voltage == cfg.safe_voltage() {
                assert_eq!(b.enabled, Some(false));
                break;
            }
            assert_eq!(b.enabled, Some(true), "off only at the safe voltage");
        }
    }

    #[test]
    fn adc_scale_round_trips() {
        let s = AdcScale {
            offset: I16F16::from_num(-5),
            per_count: I4F28::from_num(0.125),
        };
        assert_eq!(s.to_force(0), Newtons::from_num(-5));
        assert_eq!(s.to_force(4095), Newtons::from_num(506.875));
        assert_eq!(s.to_counts(60.0, 4095), 520);
        assert_eq!(s.to_counts(-50.0, 4095), 0);
        assert_eq!(s.to_counts(1e9, 4095), 4095);
        // A 16-bit code over 80 µm: the whole code range, exactly.
        let p = AdcScale {
            offset: I16F16::from_num(-10),
            per_count: I4F28::from_bits(80 << 12),
        };
        assert_eq!(p.to_position(0), Micrometres::from_num(-10));
        assert_eq!(p.to_position(32768), Micrometres::from_num(30));
        assert_eq!(
            p.to_position(65535),
            Micrometres::from_num(70.0 - 80.0 / 65536.0)
        );
        assert_eq!(p.to_counts(30.0, u16::MAX), 32768);
    }

    #[test]
    fn dac_scale_is_within_half_a_code() {
        let s = DacScale {
            codes_per_volt: I16F16::from_num(65535.0 / 150.0),
            max_code: 65535,
        };
        assert_eq!(s.to_code(Volts::ZERO), 0);
        assert_eq!(s.to_code(Volts::from_num(150)), 65535);
        assert_eq!(s.to_code(Volts::from_num(-3)), 0);
        assert_eq!(s.to_code(Volts::from_num(200)), 65535);
        for k in 0..=1500 {
            let u = k as f64 * 0.1;
            let code = s.to_code(Volts::from_num(u)) as f64;
            assert!((code - u * 65535.0 / 150.0).abs() <= 0.5 + 1e-3, "u={u}");
        }
    }
}
