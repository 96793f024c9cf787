//! A forward PI model specialised for throughput (host simulations, the benchmark).
//!
//! The same algorithm as the firmware's bank: operators stored side by side, the
//! direction of the input tested once per sample so each operator needs one
//! compare (when the input rises `min(u, y) = y`; when it falls the max is a
//! no-op), `N` a compile-time constant so the loop unrolls.

/// A forward PI with `N` operators (`w0` apart), f64.
#[derive(Debug, Clone, PartialEq)]
pub struct FastPi<const N: usize> {
    w0: f64,
    r: [f64; N],
    w: [f64; N],
    y: [f64; N],
    last: f64,
}

impl<const N: usize> FastPi<N> {
    /// A model at rest; `r` sorted.
    pub fn new(w0: f64, r: [f64; N], w: [f64; N]) -> Self {
        Self {
            w0,
            r,
            w,
            y: [0.0; N],
            last: 0.0,
        }
    }

    /// One sample: advances the operators with `u` and returns `Y[u]`.
    #[inline(always)]
    pub fn step(&mut self, u: f64) -> f64 {
        let mut acc = self.w0 * u;
        if u >= self.last {
            for i in 0..N {
                let d = u - self.r[i];
                let v = if d > self.y[i] { d } else { self.y[i] };
                self.y[i] = v;
                acc += self.w[i] * v;
            }
        } else {
            for i in 0..N {
                let v = if u < self.y[i] { u } else { self.y[i] };
                self.y[i] = v;
                acc += self.w[i] * v;
            }
        }
        self.last = u;
        acc
    }

    /// Runs a whole input sequence into `out`.
    pub fn run(&mut self, u: &[f64], out: &mut [f64]) {
        for (o, &v) in out.iter_mut().zip(u) {
            *o = self.step(v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::{BankF64, PiF64};

    #[test]
    fn equals_the_reference_pi() {
        let r = [10.0, 20.0, 40.0, 80.0];
        let w = [0.01, 0.012, 0.004, 0.012];
        let mut fast = FastPi::new(0.06, r, w);
        let slow = PiF64 {
            w0: 0.06,
            r: r.to_vec(),
            w: w.to_vec(),
            input_max: 150.0,
        };
        let mut bank = BankF64::new(4);
        for k in 0..5000 {
            let u = 75.0 + 70.0 * (k as f64 * 0.013).sin() * (k as f64 * 0.0007).cos();
            assert_eq!(fast.step(u), slow.apply(&mut bank, u), "sample {k}");
        }
    }
}
