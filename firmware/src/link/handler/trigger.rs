//! The trigger output's settings: the handler keeps every mode's levels (a
//! change of mode keeps the others) and hands the control task the one
//! condition that drives the line, checked ([`piezo_fpi::trigger`]).

use piezo_fpi::q::Micrometres;
use piezo_fpi::trigger::{Condition, Trigger};

use crate::link::protocol::{Refusal, TriggerMode, TriggerSettings};
use crate::link::refusal::{refuse, Refuse};

/// The largest level, nm (`I16F16` µm hold ±32 768 µm).
const LIMIT_NM: i64 = 32_767_000;

/// The condition `s` asks for, or the refusal naming the level and its rule.
pub(super) fn condition(s: &TriggerSettings) -> Result<Trigger, Refuse> {
    // nm to `I16F16` µm: 65 536 / 1000 of a bit each (truncated: within
    // one bit, 15 pm).
    let um = |name: &str, nm: i64| {
        if nm.abs() > LIMIT_NM {
            return Err(refuse(
                Refusal::OutOfRange,
                format_args!("trigger {name} = {nm}: outside ±{LIMIT_NM} nm"),
            ));
        }
        Ok(Micrometres::from_bits((nm * 65_536 / 1000) as i32))
    };
    let c = match s.mode {
        TriggerMode::Off => Condition::Off,
        TriggerMode::Travel => Condition::Travel {
            step: um("step_nm", s.step_nm.into())?,
        },
        TriggerMode::OnTarget => Condition::OnTarget {
            band: um("band_nm", s.band_nm.into())?,
        },
        TriggerMode::Window => Condition::Window {
            low: um("low_nm", s.low_nm.into())?,
            high: um("high_nm", s.high_nm.into())?,
        },
        TriggerMode::Point => Condition::Point,
    };
    Trigger::new(c, s.pulse_ticks)
        .map_err(|e| refuse(Refusal::OutOfRange, format_args!("{}", e.rule())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_mode_takes_its_levels_and_a_broken_rule_is_named() {
        let mut s = TriggerSettings::DEFAULT;
        assert_eq!(condition(&s).unwrap().condition(), Condition::Off);
        s.mode = TriggerMode::Window;
        s.low_nm = 10_000;
        s.high_nm = 12_500;
        let t = condition(&s).unwrap();
        assert_eq!(
            t.condition(),
            Condition::Window {
                low: Micrometres::from_num(10),
                high: Micrometres::from_num(12.5)
            }
        );
        s.low_nm = 13_000;
        let (code, why) = condition(&s).unwrap_err();
        assert_eq!(code, Refusal::OutOfRange);
        assert!(why.contains("low edge"), "{why}");
        s.mode = TriggerMode::Travel;
        s.step_nm = 40_000_000;
        let (_, why) = condition(&s).unwrap_err();
        assert!(why.contains("step_nm = 40000000: outside"), "{why}");
        s.step_nm = 0;
        let (_, why) = condition(&s).unwrap_err();
        assert!(why.contains("above 0"), "{why}");
    }
}
