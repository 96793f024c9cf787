//! The control loop's modes and sources that the link names: the waveform's
//! shape, how the loop is closed, which source drives the reference.

crate::wire_enum! {
    /// The shape of a periodic reference.
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub enum Shape {
        /// `sin 2πφ`.
        Sine = 0,
        /// A symmetric triangle in phase with the sine.
        Triangle = 1,
        /// `−cos 2πφ`: from the bottom of the swing, with zero speed at the turning points.
        RaisedCosine = 2,
    }
}

impl Shape {
    /// Name for logs and the host tools.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Sine => "sine",
            Self::Triangle => "triangle",
            Self::RaisedCosine => "cosine",
        }
    }
}

crate::wire_enum! {
    /// How the loop is closed.
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub enum LoopMode {
        /// Feedforward only: the reference through the inverse FPI (or the straight line).
        Open = 0 as "open",
        /// PI feedback on the position sensor plus the inverse FPI as feedforward.
        Closed = 1 as "closed",
        /// PI feedback alone, its output through the straight-line drive (no model).
        FeedbackOnly = 2 as "feedback",
    }
}

crate::wire_enum! {
    /// Which source drives the reference.
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub enum SourceKind {
        /// Standing still.
        Hold = 0,
        /// Ramping to a position.
        Move = 1,
        /// The waveform generator.
        Wave = 2,
        /// The host's streamed trajectory.
        Stream = 3,
        /// The analog reference input.
        Analog = 4,
    }
}

crate::wire_enum! {
    /// What drives a stage's trigger output (see `piezo_fpi::trigger`).
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub enum TriggerMode {
        /// The line stays low.
        Off = 0 as "off",
        /// A pulse every `step_um` of travel, either way.
        Travel = 1 as "travel",
        /// High while the position is within `band_um` of the reference.
        OnTarget = 2 as "on_target",
        /// High while the position lies in `low_um … high_um`.
        Window = 3 as "window",
        /// A pulse at each point a streamed trajectory takes.
        Point = 4 as "point",
    }
}

crate::wire_enum! {
    /// What a rising edge on a stage's trigger input starts: the wave or
    /// stream ordered last (held until the edge), the recording ordered last,
    /// or both.
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub enum TriggerStart {
        /// Nothing: orders start at once.
        Nothing = 0 as "off",
        /// A wave or stream order waits for the edge.
        Motion = 1 as "motion",
        /// A record order waits for the edge.
        Recorder = 2 as "recorder",
        /// Both wait for the same edge.
        Both = 3 as "both",
    }
}

impl TriggerStart {
    /// A wave or stream order waits for the edge.
    pub const fn motion(self) -> bool {
        matches!(self, Self::Motion | Self::Both)
    }

    /// A record order waits for the edge.
    pub const fn recorder(self) -> bool {
        matches!(self, Self::Recorder | Self::Both)
    }
}
