//! `fpi export`: the firmware model file — the calibrated model, the stage's FEM
//! maps resampled onto the firmware's power-of-two grids, the soft dead zone and
//! saturation tabulated, and the loop settings — checked against the core's
//! formats before it is written (`build.rs` checks it again).
//!
//! Grids: the largest power-of-two knot spacing (at most one unit) whose knot
//! rise stays below 0.45 units (the core needs < 0.5 for its 32-bit
//! interpolation) and that keeps the interpolation error of the smooth maps
//! below ~0.1 mV / 0.1 nm. Each table's resampling error against the exact map is
//! reported.

use std::path::Path;

use anyhow::{bail, Result};

use crate::fem::FemMaps;
use crate::hmodel::{dead_zone, dead_zone_inverse, HostModel, Kind, OutputMap};
use crate::invert::reachable_top;
use crate::model_file::{
    ControllerSection, CouplingSection, CreepSection, FirmwareModel, MapSection, PiSection,
    Provenance, TableSection, Tables, FORMAT,
};

/// Loop settings of an export.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopSettings {
    /// ISR rate, Hz.
    pub rate_hz: u32,
    /// Highest amplifier voltage, V.
    pub u_max: f64,
    /// Largest slew, V/ms.
    pub slew_v_per_ms: f64,
    /// Highest voltage of the reference's reachable stroke, V.
    pub stroke_voltage: f64,
    /// Tolerated disagreement between the force reading and `f_F`, N.
    pub force_tolerance: f64,
}

/// One table's grid and how far it is from the map it samples.
#[derive(Debug, Clone, PartialEq)]
pub struct TableReport {
    /// The table's key.
    pub name: String,
    /// Knots.
    pub knots: usize,
    /// Knot spacing, input units.
    pub step: f64,
    /// Largest difference from the exact map between the knots, output units.
    pub max_error: f64,
}

/// A written export.
#[derive(Debug, Clone, PartialEq)]
pub struct Export {
    /// The file's content.
    pub model: FirmwareModel,
    /// Per table.
    pub tables: Vec<TableReport>,
}

/// Samples `f` on `[x0, x0 + k·2^step_log2]` covering `x1`; returns the table.
fn sample(x0: f64, x1: f64, step_log2: i32, f: impl Fn(f64) -> f64) -> TableSection {
    let step = 2f64.powi(step_log2);
    let n = ((x1 - x0) / step).ceil() as usize;
    TableSection {
        x0,
        step_log2,
        values: (0..=n).map(|k| f(x0 + k as f64 * step)).collect(),
    }
}

/// The coarsest grid (≤ one unit, ≥ 2^-10) over `[x0, x1]` whose knot rise stays
/// below 0.45 and whose linear-interpolation error against `f`, weighted by
/// `weight(x)` (how much an error at `x` matters), stays below `tol`.
fn tabulate(
    name: &str,
    x0: f64,
    x1: f64,
    tol: f64,
    f: impl Fn(f64) -> f64 + Copy,
    weight: impl Fn(f64) -> f64 + Copy,
) -> Result<(TableSection, TableReport)> {
    for step_log2 in (-10..=0).rev() {
        let t = sample(x0, x1, step_log2, f);
        if t.values.len() > 4000 {
            continue;
        }
        let rise = t
            .values
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        if rise >= 0.45 {
            continue;
        }
        // Error at 8 points inside every interval.
        let step = t.step();
        let mut err = 0.0f64;
        for k in 0..t.values.len() - 1 {
            for j in 1..8 {
                let x = t.x0 + (k as f64 + j as f64 / 8.0) * step;
                err = err.max((t.eval(x) - f(x)).abs() * weight(x));
            }
        }
        if err <= tol {
            let report = TableReport {
                name: name.into(),
                knots: t.values.len(),
                step,
                max_error: err,
            };
            return Ok((t, report));
        }
    }
    bail!("{name}: no power-of-two grid over [{x0}, {x1}] meets the knot-rise and error limits")
}

/// Builds the firmware model file for a calibrated model and a stage.
pub fn export(
    model: &HostModel,
    model_path: &Path,
    fem: &FemMaps,
    s: &LoopSettings,
) -> Result<Export> {
    if !matches!(model.kind, Kind::Pi | Kind::Fpi | Kind::Efpi) {
        bail!(
            "a {} model cannot run in the firmware: export pi, fpi or efpi models (ldpi's weights \
             depend on the force, gpi needs an offset the firmware does not have)",
            model.kind
        );
    }
    if model.offset_um != 0.0 {
        bail!(
            "the model has an output offset ({} µm) the firmware does not support",
            model.offset_um
        );
    }
    let mut reports = Vec::new();
    let x_max = fem.x_pea_max();
    // FEM maps on the stack-extension grid; f_K⁻¹ on the stage-output grid.
    let one = |_: f64| 1.0;
    let (f_f, r) = tabulate("tables.f_f", 0.0, x_max, 1e-4, |x| fem.preload_at(x), one)?;
    reports.push(r);
    let (f_k, r) = tabulate("tables.f_k", 0.0, x_max, 1e-4, |x| fem.stage_at(x), one)?;
    reports.push(r);
    let (y_lo, y_hi) = (fem.stage_at(0.0), fem.stage_at(x_max));
    let (f_k_inv, r) = tabulate(
        "tables.f_k_inv",
        y_lo.min(y_hi),
        y_lo.max(y_hi),
        1e-4,
        |y| fem.stack_for(y),
        one,
    )?;
    reports.push(r);

    // The soft dead zone: g on [-13 s, 13 s] (beyond: 0 below, the identity above,
    // within 5e-6 s); its inverse from where it is too steep for the grid.
    let s_dz = model.dead_zone_softness_v;
    let dead_zone_map = if model.kind == Kind::Efpi && s_dz > 0.0 {
        let e_max = (13.0 * s_dz).ceil();
        let (fwd, r) = tabulate(
            "dead_zone.forward",
            -e_max,
            e_max,
            1e-4,
            |e| dead_zone(s_dz, e).0,
            one,
        )?;
        reports.push(r);
        // g⁻¹ has slope 1 + exp(-e/s): with knots 2^-5 apart the rise stays below
        // 0.45 above e = -s·ln(0.45·32 - 1).
        let h = 2f64.powi(-5);
        let e_lo = -s_dz * (0.45 / h - 1.0).ln();
        let uh_lo = (dead_zone(s_dz, e_lo).0 / h).ceil() * h;
        // An error in g⁻¹ (volts of setpoint) drives the stack through g' = 1 - e^(-û/s):
        // weigh it by that, i.e. bound the error of the effective voltage (0.5 mV: ~30 pm
        // of stack, the order of the fixed-point rounding).
        let (inv, r) = tabulate(
            "dead_zone.inverse",
            uh_lo,
            e_max,
            5e-4,
            |uh| dead_zone_inverse(s_dz, uh),
            |uh| -(-uh / s_dz).exp_m1(),
        )?;
        reports.push(r);
        Some(MapSection {
            forward: fwd,
            inverse: inv,
        })
    } else {
        None
    };
    // The output saturation over the PI's whole output range (creep included).
    let saturation = match model.output {
        OutputMap::Identity => None,
        OutputMap::Quadratic { .. } => bail!("a quadratic output map is not exportable"),
        OutputMap::Saturation { beta_per_um: 0.0 } => None,
        map @ OutputMap::Saturation { .. } => {
            let u = model.pi.input_max_v;
            let y_top = (model.pi.w0_um_per_v * u
                + model
                    .pi
                    .thresholds_v
                    .iter()
                    .zip(&model.pi.weights_um_per_v)
                    .map(|(r, w)| w * (u - r).max(0.0))
                    .sum::<f64>()
                + model.creep.iter().map(|c| c.gain_um_per_v * u).sum::<f64>())
                * 1.05;
            let (fwd, r) = tabulate(
                "saturation.forward",
                0.0,
                y_top,
                1e-4,
                |y| map.apply(y).0,
                one,
            )?;
            reports.push(r);
            let z_top = map.apply(y_top).0;
            let (inv, r) = tabulate(
                "saturation.inverse",
                0.0,
                z_top,
                1e-4,
                |z| map.invert(z),
                one,
            )?;
            reports.push(r);
            Some(MapSection {
                forward: fwd,
                inverse: inv,
            })
        }
    };

    let c = &model.coupling;
    let f_rest = fem.rest_preload();
    let f_top = fem.preload_at(x_max);
    let dt = 1.0 / s.rate_hz as f64;
    let stroke = reachable_top(model, fem, s.stroke_voltage, dt)?;
    let (ref_lo, ref_hi) = (y_lo.min(stroke), y_lo.max(stroke));
    let fm = FirmwareModel {
        format: FORMAT.into(),
        provenance: Provenance {
            model: project_relative(model_path),
            fem: project_relative(Path::new(&fem.source)),
            created_by: format!("fpi export {}", env!("CARGO_PKG_VERSION")),
            notes: format!(
                "{} model calibrated on {} recording(s), output RMSE {:.4} µm ({}); reference range \
                 = the stroke the model reaches at {} V",
                model.kind,
                model.calibration.files.len(),
                model.calibration.rmse_um,
                model.calibration.method,
                s.stroke_voltage
            ),
        },
        pi: PiSection {
            w0_um_per_v: model.pi.w0_um_per_v,
            thresholds_v: model.pi.thresholds_v.clone(),
            weights_um_per_v: model.pi.weights_um_per_v.clone(),
            input_max_v: model.pi.input_max_v,
        },
        coupling: if model.kind == Kind::Pi {
            CouplingSection {
                offset_v: 0.0,
                k_f_v_per_n: 0.0,
                k_q_v_per_n2: 0.0,
                force_q_n: 0.0,
                compliance_um_per_n: 0.0,
                force_ref_n: f_rest,
            }
        } else {
            CouplingSection {
                offset_v: c.offset_v,
                k_f_v_per_n: c.k_f_v_per_n,
                k_q_v_per_n2: c.k_q_v_per_n2,
                force_q_n: c.force_q_n,
                compliance_um_per_n: c.compliance_um_per_n,
                force_ref_n: f_rest,
            }
        },
        dead_zone: dead_zone_map,
        saturation,
        creep: model
            .creep
            .iter()
            .map(|cr| CreepSection {
                tau_s: cr.tau_s,
                gain_um_per_v: cr.gain_um_per_v,
            })
            .collect(),
        controller: ControllerSection {
            rate_hz: s.rate_hz,
            u_min_v: 0.0,
            u_max_v: s.u_max,
            slew_v_per_ms: s.slew_v_per_ms,
            reference_min_um: (ref_lo * 1000.0).ceil() / 1000.0,
            reference_max_um: (ref_hi * 1000.0).floor() / 1000.0,
            force_min_n: (0.25 * f_rest).floor(),
            force_max_n: (1.5 * f_top).ceil(),
            force_tolerance_n: s.force_tolerance,
            safe_voltage_v: 0.0,
            force_source: "measured".into(),
        },
        tables: Tables { f_f, f_k, f_k_inv },
    };
    fm.validate()
        .map_err(|e| anyhow::anyhow!("the export does not meet the firmware's formats: {e}"))?;
    check_core(&fm)?;
    Ok(Export {
        model: fm,
        tables: reports,
    })
}

/// A path relative to the project root when it lies inside it (provenance that
/// means the same on every machine), else as given.
pub fn project_relative(p: &Path) -> String {
    let root = crate::firmware::project_root();
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(p))
            .unwrap_or_else(|_| p.to_path_buf())
    };
    match abs.strip_prefix(&root) {
        Ok(r) => r.display().to_string(),
        Err(_) => p.display().to_string(),
    }
}

/// Builds the core's fixed-point PI, its inverse with the creep folded in, and
/// every table from the file, so a model the firmware would reject fails here with
/// the core's own message (`build.rs` checks the same at compile time).
fn check_core(m: &FirmwareModel) -> Result<()> {
    use fixed::types::I16F16;
    use piezo_fpi::pi::PiModel;
    use piezo_fpi::table::Segment;
    use piezo_fpi::{InversePi, Table};
    let n = m.pi.thresholds_v.len();
    let rate = m.controller.rate_hz as f64;
    let w0p = m.pi.w0_um_per_v
        + m.creep
            .iter()
            .map(|c| c.gain_um_per_v * c.rate(rate))
            .sum::<f64>();
    macro_rules! check {
        ($($n:literal),*) => {
            match n {
                $($n => {
                    let mut r = [0.0; $n];
                    let mut w = [0.0; $n];
                    r.copy_from_slice(&m.pi.thresholds_v);
                    w.copy_from_slice(&m.pi.weights_um_per_v);
                    let pi = PiModel::<$n>::from_f64(w0p, &r, &w, m.pi.input_max_v)
                        .map_err(|e| anyhow::anyhow!("pi (with this sample's creep): {e}"))?;
                    InversePi::from_forward(&pi).map_err(|e| anyhow::anyhow!("inverse pi: {e}"))?;
                })*
                _ => bail!("{n} operators: the firmware supports up to 32"),
            }
        };
    }
    check!(
        0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24,
        25, 26, 27, 28, 29, 30, 31, 32
    );
    let mut tables = vec![
        ("tables.f_f", &m.tables.f_f),
        ("tables.f_k", &m.tables.f_k),
        ("tables.f_k_inv", &m.tables.f_k_inv),
    ];
    for (name, map) in [("dead_zone", &m.dead_zone), ("saturation", &m.saturation)] {
        if let Some(map) = map {
            tables.push((
                if name == "dead_zone" {
                    "dead_zone.forward"
                } else {
                    "saturation.forward"
                },
                &map.forward,
            ));
            tables.push((
                if name == "dead_zone" {
                    "dead_zone.inverse"
                } else {
                    "saturation.inverse"
                },
                &map.inverse,
            ));
        }
    }
    for (name, t) in tables {
        let bits: Vec<I16F16> = t.values.iter().map(|v| I16F16::from_num(*v)).collect();
        let segs: Vec<Segment> = bits
            .windows(2)
            .map(|w| Segment::new(w[0], w[1] - w[0]))
            .collect();
        let shift = (t.step_log2 + 16) as u32;
        Table::new(I16F16::from_num(t.x0), shift, &segs)
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    }
    Ok(())
}
