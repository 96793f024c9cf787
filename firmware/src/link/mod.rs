//! The command link: the link task's command handler ([`handler`], with the
//! model upload in `upload`) the pace of the emulated board's link ([`pace`]) and the USB link's byte pump
//! ([`usb`]). The messages and their framing are the
//! `fpi-protocol` crate's, re-exported here as [`protocol`] and [`frame`].

pub use fpi_protocol as protocol;
pub use fpi_protocol::frame;

pub mod handler;
pub mod pace;
mod upload;
pub mod usb;
