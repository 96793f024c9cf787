//! The command link: messages ([`protocol`]), their framing ([`frame`]) and the
//! link task's command handler ([`handler`]).

pub mod frame;
pub mod handler;
pub mod protocol;
