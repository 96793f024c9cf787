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

use piezo_sim::maps::{dead_zone, dead_zone_inverse};

use crate::data::fem::FemMaps;
use crate::method::limits::{within, AMPLIFIER_MAX_SLEW_V_PER_MS, AMPLIFIER_MAX_V, RATE_RANGE_HZ};
use crate::method::model::{HostModel, OutputMap};
use crate::method::predict::reachable_top;

use crate::data::project_relative;
use crate::model_file::{
    ControllerSection, CouplingSection, CreepSection, FirmwareModel, MapSection, PiSection,
    Provenance, TableSection, Tables, FORMAT,
};

/// Most knots a resampled table may have (the firmware's tables hold at most 4096;
/// grids finer than this are not tried, and never allocated).
pub const MAX_KNOTS: usize = 4000;

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

/// The loop settings as `fpi export` and `fpi board load` take them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExportOptions {
    /// Control rate, Hz.
    pub rate_hz: u32,
    /// Highest amplifier voltage, V.
    pub u_max: f64,
    /// Largest slew, V/ms.
    pub slew: f64,
    /// Highest voltage of the reachable stroke, V (default: the calibrated range).
    pub stroke_voltage: Option<f64>,
}

impl LoopSettings {
    /// The settings for model `m`: by default the reference may use the stroke the
    /// model's calibrated voltage range reaches (capped at `u_max`); a
    /// `stroke_voltage` given is kept as it is ([`check`](Self::check) refuses one
    /// above `u_max`).
    pub fn for_model(m: &HostModel, o: &ExportOptions) -> Self {
        let (rate_hz, u_max, slew, stroke) = (o.rate_hz, o.u_max, o.slew, o.stroke_voltage);
        let calibrated = m.pi.thresholds_v.last().copied().unwrap_or(0.0)
            * (m.operators() + 1) as f64
            / m.operators().max(1) as f64;
        let default = if calibrated > 0.0 { calibrated } else { u_max };
        Self {
            rate_hz,
            u_max,
            slew_v_per_ms: slew,
            stroke_voltage: stroke.unwrap_or(default.min(u_max)),
            force_tolerance: 15.0,
        }
    }

    /// Refuses settings the board cannot run, naming the option and its value: a
    /// rate outside [`RATE_RANGE_HZ`], a `u_max` outside `(0, AMPLIFIER_MAX_V]`, a
    /// slew outside `(0, AMPLIFIER_MAX_SLEW_V_PER_MS]`, a stroke voltage outside
    /// `(0, u_max]`, a force tolerance that is not positive (all finite).
    pub fn check(&self) -> Result<()> {
        if !RATE_RANGE_HZ.contains(&self.rate_hz) {
            bail!(
                "--rate {} Hz: the firmware runs at {}..={} Hz",
                self.rate_hz,
                RATE_RANGE_HZ.start(),
                RATE_RANGE_HZ.end()
            );
        }
        within(
            "--u-max",
            self.u_max,
            "V",
            AMPLIFIER_MAX_V,
            "the board's amplifier span",
        )?;
        within(
            "--slew",
            self.slew_v_per_ms,
            "V/ms",
            AMPLIFIER_MAX_SLEW_V_PER_MS,
            "the amplifier's largest slew",
        )?;
        within(
            "--stroke-voltage",
            self.stroke_voltage,
            "V",
            self.u_max,
            "--u-max",
        )?;
        within(
            "force tolerance",
            self.force_tolerance,
            "N",
            f64::MAX,
            "any finite force",
        )
    }
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

/// Knots of a grid of spacing `step` from `x0` covering `x1`; `None` beyond
/// [`MAX_KNOTS`] (checked before anything is allocated).
fn knots(x0: f64, x1: f64, step: f64) -> Option<usize> {
    let intervals = ((x1 - x0) / step).ceil();
    (intervals.is_finite() && (0.0..MAX_KNOTS as f64).contains(&intervals))
        .then_some(intervals as usize + 1)
}

/// Samples `f` on `[x0, x0 + k·2^step_log2]` covering `x1`; `None` when that takes
/// more than [`MAX_KNOTS`] knots.
fn sample(x0: f64, x1: f64, step_log2: i32, f: impl Fn(f64) -> f64) -> Option<TableSection> {
    let step = 2f64.powi(step_log2);
    let n = knots(x0, x1, step)?;
    Some(TableSection {
        x0,
        step_log2,
        values: (0..n).map(|k| f(x0 + k as f64 * step)).collect(),
    })
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
    if !(x0.is_finite() && x1.is_finite() && x0 <= x1) {
        bail!("{name}: the range [{x0}, {x1}] to tabulate is not a finite interval");
    }
    for step_log2 in (-10..=0).rev() {
        let Some(t) = sample(x0, x1, step_log2, f) else {
            continue;
        };
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
        let Some(curve) = t.curve() else { continue };
        let mut err = 0.0f64;
        for k in 0..t.values.len() - 1 {
            for j in 1..8 {
                let x = t.x0 + (k as f64 + j as f64 / 8.0) * step;
                err = err.max((curve.held(x) - f(x)).abs() * weight(x));
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
    bail!(
        "{name}: no power-of-two grid over [{x0}, {x1}] with at most {MAX_KNOTS} knots meets \
         the knot-rise and error limits"
    )
}

/// The FEM maps on the stack-extension grid, `f_K⁻¹` on the stage-output grid.
fn fem_tables(fem: &FemMaps, reports: &mut Vec<TableReport>) -> Result<Tables> {
    let x_max = fem.x_pea_max();
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
    Ok(Tables { f_f, f_k, f_k_inv })
}

/// The soft dead zone of softness `s`: `g` on `[-13 s, 13 s]` (beyond: 0 below,
/// the identity above, within 5e-6 s); its inverse from where it is too steep for
/// the grid.
fn dead_zone_tables(s: f64, reports: &mut Vec<TableReport>) -> Result<MapSection> {
    let e_max = (13.0 * s).ceil();
    let one = |_: f64| 1.0;
    let (forward, r) = tabulate(
        "dead_zone.forward",
        -e_max,
        e_max,
        1e-4,
        |e| dead_zone(s, e).0,
        one,
    )?;
    reports.push(r);
    // g⁻¹ has slope 1 + exp(-e/s): with knots 2^-5 apart the rise stays below
    // 0.45 above e = -s·ln(0.45·32 - 1).
    let h = 2f64.powi(-5);
    let e_lo = -s * (0.45 / h - 1.0).ln();
    let uh_lo = (dead_zone(s, e_lo).0 / h).ceil() * h;
    // An error in g⁻¹ (volts of setpoint) drives the stack through g' = 1 - e^(-û/s):
    // weigh it by that, i.e. bound the error of the effective voltage (0.5 mV: ~30 pm
    // of stack, the order of the fixed-point rounding).
    let (inverse, r) = tabulate(
        "dead_zone.inverse",
        uh_lo,
        e_max,
        5e-4,
        |uh| dead_zone_inverse(s, uh),
        |uh| -(-uh / s).exp_m1(),
    )?;
    reports.push(r);
    Ok(MapSection { forward, inverse })
}

/// The output saturation over the PI's whole output range (creep included, 5 %
/// margin).
fn saturation_tables(
    model: &HostModel,
    map: OutputMap,
    reports: &mut Vec<TableReport>,
) -> Result<MapSection> {
    let m = model.model();
    let u = m.pi.input_max;
    let creep: f64 = m.creep.iter().map(|c| c.gain * u).sum();
    let y_top = (m.pi.output_max() + creep) * 1.05;
    let one = |_: f64| 1.0;
    let (forward, r) = tabulate(
        "saturation.forward",
        0.0,
        y_top,
        1e-4,
        |y| map.apply(y).0,
        one,
    )?;
    reports.push(r);
    let (inverse, r) = tabulate(
        "saturation.inverse",
        0.0,
        map.apply(y_top).0,
        1e-4,
        |z| map.invert(z),
        one,
    )?;
    reports.push(r);
    Ok(MapSection { forward, inverse })
}

/// The coupling section: the model's (none for a kind without one), with the
/// FEM's rest preload as the compliance reference.
fn coupling_section(model: &HostModel, f_rest: f64) -> CouplingSection {
    let c = &model.coupling;
    let none = !model.kind.coupled();
    let pick = |v: f64| if none { 0.0 } else { v };
    CouplingSection {
        offset_v: pick(c.offset_v),
        k_f_v_per_n: pick(c.k_f_v_per_n),
        k_q_v_per_n2: pick(c.k_q_v_per_n2),
        force_q_n: pick(c.force_q_n),
        compliance_um_per_n: pick(c.compliance_um_per_n),
        force_ref_n: Some(f_rest),
    }
}

/// The loop settings: limits, the reachable stroke as the reference range, and
/// the plausible forces (a quarter of the rest preload to 1.5 times the largest).
fn controller_section(s: &LoopSettings, fem: &FemMaps, stroke: f64) -> ControllerSection {
    let y_lo = fem.stage_at(0.0);
    let (ref_lo, ref_hi) = (y_lo.min(stroke), y_lo.max(stroke));
    ControllerSection {
        rate_hz: s.rate_hz,
        u_min_v: 0.0,
        u_max_v: s.u_max,
        slew_v_per_ms: s.slew_v_per_ms,
        reference_min_um: (ref_lo * 1000.0).ceil() / 1000.0,
        reference_max_um: (ref_hi * 1000.0).floor() / 1000.0,
        force_min_n: (0.25 * fem.rest_preload()).floor(),
        force_max_n: (1.5 * fem.preload_at(fem.x_pea_max())).ceil(),
        force_tolerance_n: s.force_tolerance,
        safe_voltage_v: 0.0,
        force_source: "measured".into(),
        current_limit_ma: None,
        capacitance_uf: None,
        force_split_hz: None,
        force_dynamic_limit_n: None,
    }
}

/// Builds the firmware model file for a calibrated model and a stage, and checks it
/// with the core's validator (the check `build.rs` and the board run).
pub fn export(
    model: &HostModel,
    model_path: &Path,
    fem: &FemMaps,
    s: &LoopSettings,
) -> Result<Export> {
    model
        .kind
        .export(model)
        .map_err(|e| anyhow::anyhow!("a {} model cannot run in the firmware: {e:#}", model.kind))?;
    if model.offset_um != 0.0 {
        bail!(
            "the model has an output offset ({} µm) the firmware does not support",
            model.offset_um
        );
    }
    s.check()?;
    let mut reports = Vec::new();
    let tables = fem_tables(fem, &mut reports)?;
    let softness = model.dead_zone_softness_v;
    let dead_zone = (model.kind.coupled() && softness > 0.0)
        .then(|| dead_zone_tables(softness, &mut reports))
        .transpose()?;
    let saturation = match model.output {
        OutputMap::Quadratic { .. } => bail!("a quadratic output map is not exportable"),
        map if map.is_identity() => None,
        map => Some(saturation_tables(model, map, &mut reports)?),
    };
    let stroke = reachable_top(model, fem, s.stroke_voltage, 1.0 / s.rate_hz as f64)?;
    let fm = FirmwareModel {
        format: FORMAT.into(),
        provenance: Provenance {
            model: project_relative(model_path),
            fem: project_relative(Path::new(&fem.source)),
            created_by: format!("fpi export {}", env!("CARGO_PKG_VERSION")),
            notes: format!(
                "{} model calibrated on {} recording(s), output RMSE {:.4} µm ({}); reference range \
                 = the stroke the model reaches at {} V{}",
                model.kind,
                model.calibration.files.len(),
                model.calibration.rmse_um,
                model.calibration.method,
                s.stroke_voltage,
                correction_note(model)
            ),
        },
        pi: PiSection {
            w0_um_per_v: model.pi.w0_um_per_v,
            thresholds_v: model.pi.thresholds_v.clone(),
            weights_um_per_v: model.pi.weights_um_per_v.clone(),
            input_max_v: model.pi.input_max_v,
        },
        coupling: coupling_section(model, fem.rest_preload()),
        dead_zone,
        saturation,
        creep: model
            .creep
            .iter()
            .map(|cr| CreepSection {
                tau_s: cr.tau_s,
                gain_um_per_v: cr.gain_um_per_v,
            })
            .collect(),
        controller: controller_section(s, fem, stroke),
        tables,
        feedback: None,
        shaping: None,
        dynamics: None,
        damping: None,
    };
    fm.check().map_err(|e| {
        anyhow::anyhow!(
            "{}: its export does not meet the firmware's formats: {e}",
            model_path.display()
        )
    })?;
    Ok(Export {
        model: fm,
        tables: reports,
    })
}

/// The provenance of a model's `[fem_correction]` (the tables `fem` holds are
/// already corrected: [`HostModel::stage_maps`]), empty without one.
fn correction_note(model: &HostModel) -> String {
    model.fem_correction.as_ref().map_or_else(String::new, |c| {
        format!(
            "; FEM tables corrected (fpi refine on {} run(s)): stage gain {}, stage offset {} \
                 µm, preload scale {}",
            c.refined_on.len(),
            c.stage_gain,
            c.stage_offset_um,
            c.preload_scale
        )
    })
}
