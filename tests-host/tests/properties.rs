//! Property tests of the fixed-point core (proptest).
//!
//! * inverse ∘ forward and forward ∘ inverse are the identity within the stated
//!   bounds over the whole input range, on the embedded model and on random models;
//! * nothing overflows anywhere in range: these tests run with overflow checks on
//!   (the dev/test profile), so any overflow would panic; the control step gets
//!   arbitrary `I16F16` references and forces, including the extremes.

use fpi_firmware::board::factory_model::{CONTROLLER, CREEP_TERMS, OPERATORS};
use fpi_host::board::accuracy::{BOUND_U_V, BOUND_X_UM};
use piezo_fpi::fpi::CreepMemory;
use piezo_fpi::inverse::InversePi;
use piezo_fpi::pi::PiModel;
use piezo_fpi::play::PlayBank;
use piezo_fpi::process::SplitProcess;
use piezo_fpi::q::{Micrometres, Newtons, Volts};
use proptest::prelude::*;

/// A history of fractions of a range, with reversals of every size.
fn history(len: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(0.0f64..=1.0, 1..len)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Forward then inverse PI of the embedded model recovers the voltage within
    /// one 16-bit LSB over 0–150 V, on any history over the whole input domain.
    #[test]
    fn inverse_after_forward_is_identity(h in history(400)) {
        let pi = CONTROLLER.fpi().pi();
        let inv = InversePi::from_forward(pi).unwrap();
        let (mut fb, mut ib) = (PlayBank::<OPERATORS>::new(), PlayBank::<OPERATORS>::new());
        let top = pi.input_max().to_num::<f64>();
        for s in h {
            let u = Volts::from_num(s * top);
            let x = pi.process(&mut fb, u);
            let back = inv.process(&mut ib, x);
            prop_assert!((back - u).to_num::<f64>().abs() <= BOUND_U_V, "u {} -> {}", u, back);
        }
    }

    /// Inverse then forward FPI (force coupling, dead zone, creep, saturation,
    /// compliance: the whole embedded model) reproduces the target extension
    /// within 1 nm wherever the target is reachable, with the creep memory shared
    /// as in the control step (read by the inverse, advanced by the forward model).
    ///
    /// "Reachable": below 90 % of the saturated output range `h(Y_max)` (near the
    /// top the creep memories can ask for more than the PI's range), and not in the
    /// foot of the soft dead zone, which the inverse reports: there the effective
    /// voltage asked for is below the dead zone's inverse table (0.125 V for stage
    /// A), or negative because the creep memories still hold the stack up after a
    /// long excursion; the stack then sits a few nm above the target, the inverse
    /// memory is realigned (as the control step does) and the virtual sensor says
    /// where it is. The histories pass through the foot; most targets are reachable.
    #[test]
    fn forward_after_inverse_is_identity(h in history(400), forces in prop::collection::vec(20.0f64..200.0, 400)) {
        let fpi = CONTROLLER.fpi();
        let y_max = fpi.pi().output_max();
        let x_max = 0.9 * match fpi.saturation() {
            Some(h) => h.apply(y_max),
            None => y_max,
        }
        .to_num::<f64>();
        let (mut fb, mut ib) = (PlayBank::<OPERATORS>::new(), PlayBank::<OPERATORS>::new());
        let mut creep = CreepMemory::<CREEP_TERMS>::new();
        let (mut checked, mut total) = (0usize, 0usize);
        for (s, f) in h.iter().zip(&forces) {
            let force = Newtons::from_num(*f);
            let t = fpi.force_terms(force);
            // Targets whose saturated PI output x + c (F - F_ref) lies in [0, x_max].
            let comp = t.compression.to_num::<f64>();
            let x = (s * x_max - comp).clamp(-comp, x_max - comp);
            let (u, in_foot) = fpi.inverse_checked(&mut ib, &creep, Micrometres::from_num(x), &t);
            let back = fpi.forward(&mut fb, &mut creep, u, &t).to_num::<f64>();
            total += 1;
            if in_foot {
                fpi.resync(&fb, &mut ib); // as the control step does
            } else {
                checked += 1;
                prop_assert!((back - x).abs() <= BOUND_X_UM, "x {} -> {}", x, back);
            }
        }
        // Uniform targets: only those near the bottom fall in the foot.
        prop_assert!(total < 10 || checked * 4 >= total * 3, "{checked} of {total} reachable");
    }

    /// Random models: any accepted weight set inverts within a bound that follows
    /// from the formats: half an LSB of x through the steepest inverse slope
    /// (`1/S_min`); through each inverse weight (`Σ|w'_j|`), half an LSB on its
    /// threshold and half an LSB of the x its state was last dragged by; the
    /// inverse weights' quantisation over the output range; the final rounding.
    #[test]
    fn random_models_invert_within_the_format_bound(
        w0 in 0.005f64..0.5,
        raw in prop::collection::vec((0.0f64..1.0, -0.5f64..1.0), 1..32),
        top in 20.0f64..1000.0,
        h in history(200),
    ) {
        let n = raw.len();
        let mut r: Vec<f64> = raw.iter().map(|p| p.0 * top).collect();
        r.sort_by(f64::total_cmp);
        let w: Vec<f64> = raw.iter().map(|p| p.1 * w0).collect();
        // Fixed-size arrays for the const-generic core: pad to 32 with zero weights
        // at the top of the domain (operators that never contribute).
        let mut ra = [top; 32];
        let mut wa = [0.0; 32];
        ra[..n].copy_from_slice(&r);
        wa[..n].copy_from_slice(&w);
        // Weight sets the core rejects (a partial sum <= 0, an inverse weight
        // beyond I10F22) are discarded; proptest fails if that happens too often.
        let pi = PiModel::<32>::from_f64(w0, &ra, &wa, top);
        prop_assume!(pi.is_ok());
        let pi = pi.unwrap();
        let inv = InversePi::from_forward(&pi);
        prop_assume!(inv.is_ok());
        let inv = inv.unwrap();
        let mut s = w0;
        let mut s_min = w0;
        for wi in &w { s += wi; s_min = s_min.min(s); }
        let lsb = 1.0 / 65536.0;
        let x_max = pi.output_max().to_num::<f64>();
        let sum_wp: f64 = inv.weights().iter().map(|w| w.to_num::<f64>().abs()).sum();
        let bound = 0.5 * lsb * (1.0 / s_min + 2.0 * sum_wp) + 33.0 * 2f64.powi(-23) * x_max + lsb;
        let (mut fb, mut ib) = (PlayBank::<32>::new(), PlayBank::<32>::new());
        for f in h {
            let u = Volts::from_num(f * top);
            let x = pi.process(&mut fb, u);
            let back = inv.process(&mut ib, x);
            prop_assert!((back - u).to_num::<f64>().abs() <= bound, "n={n} u {u} -> {back} (bound {bound})");
        }
    }

    /// The control step takes anything the ADC path or a caller can hand it —
    /// any `I16F16` reference and force, extremes included — without overflow or
    /// panic, and its output stays inside the actuator limits.
    #[test]
    fn control_step_never_overflows(
        inputs in prop::collection::vec((any::<i32>(), any::<i32>()), 1..300),
        clear in any::<bool>(),
    ) {
        let mut st = CONTROLLER.initial_state();
        let lim = CONTROLLER.limits();
        for (x, f) in inputs {
            let out = CONTROLLER.step(&mut st, Micrometres::from_bits(x), Newtons::from_bits(f));
            prop_assert!(out.voltage >= lim.min() && out.voltage <= lim.max());
            if clear {
                st.clear_fault(&CONTROLLER);
            }
        }
    }

    /// Same, with plausible inputs so the compensation path (not the safe state)
    /// runs: references inside the stroke, forces near the FEM preload.
    #[test]
    fn compensation_path_never_overflows(h in history(600), noise in prop::collection::vec(-5.0f64..5.0, 600)) {
        let mut st = CONTROLLER.initial_state();
        let r = CONTROLLER.reference();
        let (lo, hi) = (r.lo.to_num::<f64>(), r.hi.to_num::<f64>());
        for (s, e) in h.iter().zip(&noise) {
            let x = Micrometres::from_num(lo + s * (hi - lo));
            let f = CONTROLLER.preload(st.x_pea_est()) + Newtons::from_num(*e);
            let out = CONTROLLER.step(&mut st, x, f);
            prop_assert!(out.fault.is_none(), "{:?}", out.fault);
        }
    }
}
