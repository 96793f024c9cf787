//! The control task: what the control ISR does each tick, and what only it and
//! the link task's hand-over to it use. Nothing here knows the board's pins or
//! the link's wire; it sits on the board room ([`crate::board`]: capacity,
//! analog channels) and on the core crate.
//!
//! * [`task`] — the control ISR's whole job, one [`task::ControlLoop`] tick: take
//!   an order, supervise the link, run every axis's control step, report;
//! * [`axis`] — one axis's part of the tick: its model, reference, governor,
//!   loops, sensors, amplifier and faults;
//! * [`tracking`] — how the command follows the reference: open loop, or feedback
//!   on the position sensor, active damping and the feedforward;
//! * [`watch`] — the loops watched in the ISR (an oscillating or saturating loop
//!   caught); not the independent watchdog, which is the board's
//!   ([`crate::board::watchdog`]);
//! * [`reference`](mod@reference) — the reference sources: hold, move, waveform,
//!   streamed trajectory, analog input; [`governors`] — the reference governor
//!   every source passes, one per set of loops a model runs;
//! * [`cosine`] — the raised-cosine table the waveforms and the analyser share;
//! * [`analyser`] — the frequency-response analyser (a lock-in in the ISR);
//! * [`recorder`] — the data recorder's ring;
//! * [`slots`] — the two model stores and the hand-over of a model between tasks;
//!   [`baseline`] — the uncompensated mode's straight-line drive;
//! * [`exchange`] — what the control ISR and the link task share.

pub mod analyser;
pub mod axis;
pub mod baseline;
pub mod cosine;
pub mod exchange;
pub mod governors;
pub mod recorder;
pub mod reference;
pub mod slots;
pub mod task;
pub mod tracking;
pub mod watch;
