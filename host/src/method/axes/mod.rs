//! The method for several degrees of freedom: an XY or XYZ stage whose stacks
//! load each other through the flexure (the first paper's stated limitation,
//! "multi-degree-of-freedom stages").
//!
//! * [`decouple`] — the board's output matrix from a grid's cross gains;
//! * [`grid`] — the stage's FEM tables as grids over every stack's extension
//!   (the preload on each stack, the output of each axis);
//! * [`predict`] — every axis predicted with the coupled preloads and outputs
//!   (the coupled equation solved for all stacks at each sample), and the
//!   independent one-axis predictions a one-axis method gives, for comparison;
//! * [`record`] — recordings of the virtual XY(Z) stage as built;
//! * [`refine`] — a built stage's grid corrected, axis by axis, from measured
//!   runs (the preload on each stack, the gain and offset of each axis).

pub mod decouple;
pub mod grid;
pub mod predict;
pub mod record;
pub mod refine;
