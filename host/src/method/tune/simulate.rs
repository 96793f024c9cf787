//! The board's loops on the linear plant model, simulated tick by tick: the
//! response of the position to a reference through the damping, the PI and a
//! feedforward input — what the feedforward's design fits, and what the tuner
//! predicts a step or a scan to do.

use piezo_fpi::stability::{Laws, Plant};

/// The loops at rest on `p` under `l`.
#[derive(Debug, Clone)]
pub struct Loops<'a> {
    p: &'a Plant,
    l: Laws,
    y: [f64; 3],
    rs: f64,
    w: [f64; 2],
    integral: f64,
}

impl<'a> Loops<'a> {
    /// At rest.
    pub fn new(p: &'a Plant, l: &Laws) -> Self {
        Self {
            p,
            l: *l,
            y: [0.0; 3],
            rs: 0.0,
            w: [0.0; 2],
            integral: 0.0,
        }
    }

    /// One tick: the position read this tick, then the command `u_ff + PI(r − x)
    /// − damping` drives the plant to the next; the damping leaves `lead` (N)
    /// out of the dynamic force it damps (the shaped reference's own force,
    /// see `fpi_firmware::control::tracking`). `pi_on`: whether the PI runs.
    pub fn tick(&mut self, r: f64, u_ff: f64, lead: f64, pi_on: bool) -> f64 {
        let (p, l) = (self.p, &self.l);
        let x = self.y[1];
        let force = p.force_gain * (self.y[0] - self.y[1]);
        let rd = if l.split > 0.0 {
            self.rs += l.split * (force - self.rs);
            force - self.rs - lead
        } else {
            0.0
        };
        let [b0, b1, b2, a1, a2] = l.damping;
        let w = rd - a1 * self.w[0] - a2 * self.w[1];
        let damping = b0 * w + b1 * self.w[0] + b2 * self.w[1];
        self.w = [w, self.w[0]];
        let pi = if pi_on {
            let e = r - x;
            let out = l.kp * e + self.integral;
            self.integral += l.ki * e;
            out
        } else {
            0.0
        };
        let u = u_ff + pi - damping;
        let mut n = [0.0; 3];
        for (i, ni) in n.iter_mut().enumerate() {
            *ni = (0..3).map(|j| p.phi[i][j] * self.y[j]).sum::<f64>() + p.gamma[i] * u;
        }
        self.y = n;
        x
    }
}

/// The positions the loops give for the reference `r` with the feedforward
/// input `u_ff` (same length), read each tick.
pub fn respond(p: &Plant, l: &Laws, r: &[f64], u_ff: &[f64], pi_on: bool) -> Vec<f64> {
    respond_led(p, l, r, u_ff, &vec![0.0; r.len()], pi_on)
}

/// [`respond`] with the force `lead` (N, same length) left out of the damping's
/// input each tick.
pub fn respond_led(
    p: &Plant,
    l: &Laws,
    r: &[f64],
    u_ff: &[f64],
    lead: &[f64],
    pi_on: bool,
) -> Vec<f64> {
    let mut s = Loops::new(p, l);
    r.iter()
        .zip(u_ff)
        .zip(lead)
        .map(|((&ri, &ui), &fi)| s.tick(ri, ui, fi, pi_on))
        .collect()
}

/// `x` filtered by `b(z⁻¹)/a(z⁻¹)` (`a[0] = 1`), from rest.
pub fn filter(b: &[f64], a: &[f64], x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; x.len()];
    for n in 0..x.len() {
        let mut acc = 0.0;
        for (k, bk) in b.iter().enumerate() {
            if n >= k {
                acc += bk * x[n - k];
            }
        }
        for (k, ak) in a.iter().enumerate().skip(1) {
            if n >= k {
                acc -= ak * y[n - k];
            }
        }
        y[n] = acc;
    }
    y
}

/// A raised-cosine step of `amplitude` over `ticks`, after `lead` ticks at 0, held
/// for `hold` more.
pub fn step(amplitude: f64, ticks: usize, lead: usize, hold: usize) -> Vec<f64> {
    let mut r = vec![0.0; lead];
    for k in 1..=ticks {
        let c = (std::f64::consts::PI * k as f64 / ticks as f64).cos();
        r.push(amplitude * 0.5 * (1.0 - c));
    }
    r.extend(std::iter::repeat_n(amplitude, hold));
    r
}

/// A triangle of half-swing `amplitude` at `period` ticks for `periods`, from 0
/// going up (as the board's generator, around its offset).
pub fn triangle(amplitude: f64, period: usize, periods: usize) -> Vec<f64> {
    (0..period * periods)
        .map(|k| {
            let p = (k % period) as f64 / period as f64;
            let q = (p + 0.25).rem_euclid(1.0);
            amplitude * (1.0 - 4.0 * (q - 0.5).abs())
        })
        .collect()
}
