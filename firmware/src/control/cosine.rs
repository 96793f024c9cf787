//! The cosine the control ISR computes with: cos 2πφ for a phase φ in 2⁻³² turns,
//! from a 256-interval table generated at build time (`build.rs`), linearly
//! interpolated (worst error 7.5·10⁻⁵), so host and board compute bit-identical
//! values. The waveforms ([`crate::control::reference::wave`]) and the
//! frequency-response analyser ([`crate::control::analyser`]) share it.

include!(concat!(env!("OUT_DIR"), "/cosine.rs"));

/// cos(2π·phase) for a phase in 2⁻³² turns, `I2F30` raw, linearly interpolated.
#[inline]
pub fn cos_turns(phase: u32) -> i32 {
    let k = (phase >> 24) as usize;
    let frac = ((phase >> 8) & 0xFFFF) as i64;
    match (COSINE.get(k), COSINE.get(k + 1)) {
        (Some(&a), Some(&b)) => a + (((b - a) as i64 * frac + (1 << 15)) >> 16) as i32,
        _ => COSINE[0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_table_is_accurate() {
        for k in 0..4096u32 {
            let phase = k.wrapping_mul(1_048_573 * 997);
            let want = (phase as f64 / 4_294_967_296.0 * core::f64::consts::TAU).cos();
            let got = cos_turns(phase) as f64 / (1u64 << 30) as f64;
            assert!((got - want).abs() < 8e-5, "phase {phase}: {got} vs {want}");
        }
    }
}
