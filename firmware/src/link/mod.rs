//! The command link, the link task's side: the command handler ([`handler`]),
//! the model upload's buffer (`upload`, below the handler) and the refusal both
//! answer with (`refusal`), the pace of the emulated board's link ([`pace`]) and
//! the USB link's byte pump ([`usb`]). The messages and their framing are the
//! `fpi-protocol` crate's, re-exported here as [`protocol`] and [`frame`]. The
//! link sits on the control task ([`crate::control`]: the exchange, the model
//! stores) and the board ([`crate::board`]: capacity, flash store).

pub use fpi_protocol as protocol;
pub use fpi_protocol::frame;

pub mod handler;
pub mod pace;
mod refusal;
mod upload;
pub mod usb;
