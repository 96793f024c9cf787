//! The analog channels the control loop reads besides the force sensor, and the
//! board's scalings under the names the loop and the host tools use. The scalings
//! themselves live in the board definition ([`crate::board::definition`]); the driver
//! board and the emulated board share them.

pub use crate::board::definition::internal::{
    ADC_MAX, FORCE as FORCE_ADC, SETPOINT as SETPOINT_DAC,
};
pub use crate::board::definition::{POSITION as POSITION_ADC, POSITION_MAX};

/// The board's further analog channels: the analog reference input
/// (`crate::control::reference::analog` scales it) and the stage-position sensor.
pub trait AnalogIn {
    /// The reference input's latest conversion, 12-bit counts.
    fn read_counts(&mut self) -> u16;
    /// The position sensor's latest conversion, a 16-bit code ([`POSITION_ADC`]).
    fn read_position(&mut self) -> u16;
}
