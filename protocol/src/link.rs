//! The links a board talks over and what each carries: the rate at which the
//! emulated board paces its link (so a recording drops what a real board would),
//! and what `fpi board record` checks a recording's rate against.

crate::wire_enum! {
    /// The physical link a board answers on.
    pub enum LinkKind {
        /// USART1 at 115 200 Bd, 8N1: ten bits per byte, 11 520 B/s each way.
        Uart = 0,
        /// USB full-speed CDC-ACM on OTG_FS: a stated sustained 800 kB/s each way
        /// (bulk transfers of 64-byte packets; the bus carries at most about
        /// 1.2 MB/s of bulk data), and 1 ms from a reply's end to the host (the host
        /// polls the device once per 1 ms USB frame).
        Usb = 1,
    }
}

impl LinkKind {
    /// Sustained payload rate each way, bytes per second.
    pub const fn bytes_per_s(self) -> u32 {
        match self {
            Self::Uart => 11_520,
            Self::Usb => 800_000,
        }
    }

    /// Time from a reply's last byte leaving the board to the host having it, µs.
    pub const fn latency_us(self) -> u32 {
        match self {
            Self::Uart => 0,
            Self::Usb => 1_000,
        }
    }

    /// Its name as the command line spells it (`uart`, `usb`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Uart => "uart",
            Self::Usb => "usb",
        }
    }
}
