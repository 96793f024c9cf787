//! A small synthetic stage for the core's unit tests: the paper's FPI with three
//! operators and compliance, and linear FEM maps on power-of-two grids.
//!
//! * PI: `w0 = 0.12 µm/V`, `r = 10, 30, 60 V`, `w = 0.020, 0.016, 0.008 µm/V`, 0–150 V.
//! * Coupling: `k_f = 0.1 V/N`, compliance 0.02 µm/N about `F_ref = 60 N`.
//! * `f_F(x) = 60 + 4·x` N and `f_K(x) = 1.4·x` µm for `x` in 0–32 µm (knots 1/16 µm
//!   apart), `f_K⁻¹` on 0–44.8 µm (knots 1/4 µm apart).
//! * Limits 0–150 V, 2 V per step; references 0–25 µm; forces 20–200 N, tolerance
//!   15 N; safe voltage 0 V.

use crate::control::{
    split_rate, ControllerConfig, ControllerParts, ForceChannel, ForceSource, Interval,
    Supervision, DEFAULT_SPLIT_HZ,
};
use crate::fpi::{Coupling, Fpi, Identity};
use crate::limits::OutputLimits;
use crate::model::{CreepSpec, ModelSpec, TableSpec};
use crate::pi::PiModel;
use crate::q::{coupling, signal, Micrometres, Newtons, Signal, Volts};
use crate::table::{Segment, Table};
use fixed::types::I16F16;

/// The test stage's controller type.
pub type TestController = ControllerConfig<'static, 3>;

/// `x` in the unit the context asks for (or bare `I16F16`).
pub fn v<S: Signal>(x: f64) -> S {
    S::from_bits(signal(x).unwrap().to_bits())
}

/// A table of `f` on `x0 + k·2^step_log2`, `k = 0..=n`, leaked for `'static`.
pub fn table(x0: f64, step_log2: i32, n: usize, f: impl Fn(f64) -> f64) -> Table<'static> {
    let h = 2f64.powi(step_log2);
    let values: Vec<I16F16> = (0..=n).map(|k| v(f(x0 + k as f64 * h))).collect();
    let segs: Vec<Segment> = values
        .windows(2)
        .map(|w| Segment::new(w[0], w[1] - w[0]))
        .collect();
    Table::new(v::<I16F16>(x0), (step_log2 + 16) as u32, Vec::leak(segs)).unwrap()
}

/// The test stage's FPI model.
pub fn fpi() -> Fpi<'static, 3> {
    let pi = PiModel::from_f64(0.12, &[10.0, 30.0, 60.0], &[0.02, 0.016, 0.008], 150.0).unwrap();
    let cp = Coupling {
        compliance: coupling(0.02).unwrap(),
        force_ref: v(60.0),
        ..Coupling::paper(coupling(0.1).unwrap())
    };
    Fpi::new(pi, cp, Identity, Identity, []).unwrap()
}

/// The parts of the test stage's controller, to vary one at a time.
pub fn parts(source: ForceSource) -> ControllerParts<'static, 3> {
    ControllerParts {
        fpi: fpi(),
        f_f: table(0.0, -4, 512, |x| 60.0 + 4.0 * x),
        f_k: table(0.0, -4, 512, |x| 1.4 * x),
        f_k_inv: table(0.0, -2, 179, |y| y / 1.4),
        limits: OutputLimits::new(Volts::ZERO, v(150.0), v(2.0)).unwrap(),
        supervision: Supervision {
            reference: Interval {
                lo: Micrometres::ZERO,
                hi: v(25.0),
            },
            force: Interval {
                lo: v(20.0),
                hi: v(200.0),
            },
            force_tolerance: v(15.0),
            safe_voltage: Volts::ZERO,
            force_source: source,
            channel: ForceChannel {
                split: split_rate(DEFAULT_SPLIT_HZ, 20_000),
                dynamic_limit: v(15.0),
            },
        },
    }
}

/// The test stage's controller with a measured force.
pub fn controller() -> TestController {
    ControllerConfig::new(parts(ForceSource::Measured)).unwrap()
}

/// The force the test stage puts on the stack at an estimated extension, N.
pub fn force_at(c: &TestController, x_pea: Micrometres) -> Newtons {
    Newtons::from_raw(c.f_f().eval(x_pea.raw()))
}

/// The model of a controller's parts in the core's format, at 20 kHz, with the
/// given creep terms (the parts' model has none).
pub fn spec<'a>(p: &'a ControllerParts<'static, 3>, creep: &'a [CreepSpec]) -> ModelSpec<'a> {
    let pi = p.fpi.pi();
    let t = |t: &Table<'static>| TableSpec {
        x0: t.x_min(),
        shift: t.shift(),
        segments: t.segments(),
    };
    ModelSpec {
        rate_hz: 20_000,
        w0: pi.w0(),
        operators: pi.operators(),
        input_max: pi.input_max(),
        coupling: *p.fpi.coupling(),
        dead_zone: None,
        saturation: None,
        creep,
        f_f: t(&p.f_f),
        f_k: t(&p.f_k),
        f_k_inv: t(&p.f_k_inv),
        u_min: p.limits.min(),
        u_max: p.limits.max(),
        max_step: p.limits.max_step(),
        supervision: p.supervision,
        feedback: None,
        shaping: None,
        dynamics: None,
        damping: None,
        lead_baseline: None,
        watch_swing: None,
    }
}
