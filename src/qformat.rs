// The fixed-point contract in numbers: fractional bits of every stored quantity.
//
// This file is plain `const` items with no imports so that `build.rs` can
// `include!` it and quantise the model file with exactly the formats the core
// uses. `q.rs` turns these into `fixed` types and asserts they agree.

/// Fractional bits of every physical signal: volts, micrometres, newtons (`I16F16`).
pub const SIGNAL_FRAC: u32 = 16;
/// Fractional bits of forward gains: um/V (PI weights) (`I4F28`).
pub const GAIN_FRAC: u32 = 28;
/// Fractional bits of the force couplings: V/N (`k_f`), um/N (compliance) (`I0F32`).
pub const COUPLING_FRAC: u32 = 32;
/// Largest magnitude of a force coupling (V/N or um/N): `I0F32` holds [-0.5, 0.5).
pub const COUPLING_ABS_MAX: f64 = 0.499_999;
/// Fractional bits of inverse-PI weights in V/um (`I10F22`).
pub const INV_GAIN_FRAC: u32 = 22;
/// Largest magnitude of a physical signal the core accepts anywhere: volts, um or N.
/// Inputs are clamped to domains well inside this, so every intermediate fits `I16F16`.
pub const SIGNAL_ABS_MAX: f64 = 4096.0;
/// Largest magnitude of a forward gain (um/V, V/N, um/N).
pub const GAIN_ABS_MAX: f64 = 7.999;
/// Largest magnitude of an inverse-PI weight (V/um).
pub const INV_GAIN_ABS_MAX: f64 = 511.999;
/// Fractional bits of the feedback gains (dimensionless: µm/µm, per tick) (`I8F24`).
pub const LOOP_GAIN_FRAC: u32 = 24;
/// Fractional bits of the feedback integrator (µm, raw `i64`: `I24F40`).
pub const INTEGRAL_FRAC: u32 = 40;
/// Most play operators in one bank.
pub const MAX_OPERATORS: usize = 32;
/// Most knots in one lookup table.
pub const MAX_TABLE_LEN: usize = 4096;
/// Most creep terms in one model.
pub const MAX_CREEP_TERMS: usize = 8;
