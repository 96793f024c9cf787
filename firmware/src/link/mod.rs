//! The command link: messages ([`protocol`]), their framing ([`frame`]) and the
//! link task's command handler ([`handler`], with the model upload in `upload`).

pub mod frame;
pub mod handler;
pub mod protocol;
mod upload;
