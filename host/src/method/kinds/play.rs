//! What the kinds built on play operators share (pi, ldpi, fpi, efpi, gpi, epi):
//! a kind of this family is a [`Recipe`] — its columns and its search of the
//! nonlinear parameters on the least squares of [`crate::method::fit`] — and
//! gets the rest of [`ModelKind`] here: it is evaluated, predicted and inverted as
//! the project's float model ([`HostModel::model`]), and its sections are checked
//! alike.

use anyhow::{bail, Result};
use piezo_fpi::q::COUPLING_ABS_MAX;
use piezo_sim::model::MAX_CREEP;
use piezo_sim::play::MAX_OPERATORS;

use crate::data::fem::FemMaps;
use crate::data::Num;
use crate::method::fit::{self, Fit, Layout, Nonlinear, Problem};
use crate::method::invert::{self, Inverse};
use crate::method::model::{is_no_pi, Calibration, HostModel, ModelKind, Options, OutputMap};
use crate::method::predict;
use crate::method::sections::finite;
use crate::method::series::{CalibData, Inversion, Prediction};

/// A kind built on play operators: what it is, its columns and its search. The
/// rest of [`ModelKind`] comes with it.
pub trait Recipe: Sync {
    /// Its name on the command line and in model files.
    const NAME: &'static str;
    /// The name of the paper's method with it.
    const METHOD: &'static str;
    /// Whether calibration identifies a part of it from the preload.
    const USES_FORCE: bool = false;
    /// What the preload identifies, if not `k_f` ([`ModelKind::force_part`]).
    const FORCE_PART: Option<&'static str> = None;
    /// Whether its effective voltage runs through `[coupling]` and the dead zone.
    const COUPLED: bool = false;
    /// Whether the paper identifies it at one preload.
    const ONE_PRELOAD: bool = false;
    /// Whether it takes a stack compliance.
    const TAKES_COMPLIANCE: bool = false;
    /// How it is inverted.
    const INVERSE: Inverse = Inverse::ClosedForm;

    /// Its calibration defaults.
    fn defaults(&self) -> Options;
    /// The columns of its least squares for `opt` on `data`.
    fn layout(&self, opt: &Options, data: &[CalibData]) -> Layout;
    /// Its nonlinear parameters searched on `pr`, the fit at them, and how it was
    /// fitted (the model file's `calibration.method`).
    fn search(&self, pr: &Problem<'_>, opt: &Options) -> Result<(Nonlinear, Fit, String)>;
    /// Whether the firmware can run it, or why not (the output offset and an
    /// output map the firmware cannot tabulate are refused for every kind).
    fn firmware(&self, m: &HostModel) -> Result<()>;
    /// What its model file needs beyond the family's sections.
    fn check(&self, _m: &HostModel) -> Result<()> {
        Ok(())
    }
    /// Its identified nonlinear parameters on one line, if it has any.
    fn identified(&self, _m: &HostModel) -> Option<String> {
        None
    }
}

impl<R: Recipe> ModelKind for R {
    fn name(&self) -> &'static str {
        R::NAME
    }
    fn method(&self) -> &'static str {
        R::METHOD
    }
    fn uses_force(&self) -> bool {
        R::USES_FORCE
    }
    fn force_part(&self) -> String {
        match R::FORCE_PART {
            Some(p) => p.to_string(),
            None => format!("k_f, the force coupling of the {} model,", R::NAME),
        }
    }
    fn coupled(&self) -> bool {
        R::COUPLED
    }
    fn one_preload(&self) -> bool {
        R::ONE_PRELOAD
    }
    fn takes_compliance(&self) -> bool {
        R::TAKES_COMPLIANCE
    }
    fn options(&self) -> Options {
        self.defaults()
    }
    fn calibrate(
        &self,
        data: &[CalibData],
        opt: &Options,
        warnings: Vec<String>,
    ) -> Result<HostModel> {
        let pr = Problem::new(self.layout(opt, data), data);
        let (params, best, method) = self.search(&pr, opt)?;
        let input_max = opt.input_max.max(fit::voltage_span(data));
        let mut model = fit::unpack(opt.kind, &pr.layout, &params, &best.w, input_max);
        let files = data.iter().map(|d| d.name.clone()).collect();
        model.calibration = Calibration::new(files, best.rmse, best.per_file, method, warnings);
        Ok(model)
    }
    fn validate(&self, m: &HostModel) -> Result<()> {
        check(m, R::INVERSE)?;
        self.check(m)
    }
    fn simulate(&self, m: &HostModel, d: &CalibData) -> Vec<f64> {
        fit::simulate(m, d)
    }
    fn predict(&self, m: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Result<Prediction> {
        predict::coupled(m, fem, t, u)
    }
    fn invert(
        &self,
        m: &HostModel,
        fem: &FemMaps,
        t: &[f64],
        target: &[f64],
        u_max: f64,
    ) -> Result<Inversion> {
        invert::by_model(m, fem, t, target, u_max, R::INVERSE)
    }
    fn export(&self, m: &HostModel) -> Result<()> {
        self.firmware(m)
    }
    fn structure(&self, m: &HostModel) -> String {
        format!("{} operators", m.operators() + 1)
    }
    fn parameters(&self, m: &HostModel) -> Option<String> {
        self.identified(m)
    }
}

/// The creep time constants of the extended models, s.
pub const CREEP_TAUS_S: [f64; 4] = [0.01, 0.03, 0.3, 3.0];

/// The fewest sample periods a creep lag's time constant may span to be fitted
/// ([`resolved_lags`]).
pub const MIN_LAG_SAMPLES: f64 = 10.0;

/// The creep time constants `taus` (s) that span at least [`MIN_LAG_SAMPLES`]
/// sample periods of every recording. A faster lag follows the voltage within a
/// few samples: in the least squares its column is the effective voltage's
/// own (`w0`'s), and the non-negative fit may give it the whole immediate slope,
/// leaving `w0 = 0` and a model without an inverse (the micromanipulator's
/// 200 Hz cycle and the 10 ms lag: two samples).
pub fn resolved_lags(taus: &[f64], data: &[CalibData]) -> Vec<f64> {
    let dt = data.iter().map(|d| d.dt).fold(0.0, f64::max);
    taus.iter()
        .copied()
        .filter(|&t| t >= MIN_LAG_SAMPLES * dt)
        .collect()
}

/// The weights alone, for no nonlinear parameters (pi, ldpi).
pub fn weights_alone(pr: &Problem<'_>) -> Result<(Nonlinear, Fit, String)> {
    let p = Nonlinear::default();
    let f = pr.fit_all(&p)?;
    Ok((
        p,
        f,
        "weights by least squares (NNLS for pi; signed for ldpi)".into(),
    ))
}

/// The coupling of a model whose effective voltage the preload moves, on one line.
pub fn coupling_line(m: &HostModel) -> String {
    let c = &m.coupling;
    format!(
        "k_f {:.5} V/N, k_q {:.3e} V/N² about {} N, k0 {:.3} V, dead-zone softness {:.3} V, compliance {} µm/N",
        c.k_f_v_per_n, c.k_q_v_per_n2, c.force_q_n, c.offset_v, m.dead_zone_softness_v, c.compliance_um_per_n
    )
}

/// The sections of a model of this family: its `[pi]` (and no `[branch]`), sizes,
/// operators, motion (with an inverse where it is inverted in closed form), the
/// coupling, the dead zone and output map, `[ldpi]` and the creep lags.
pub fn check(m: &HostModel, inverse: Inverse) -> Result<()> {
    if m.branch.is_some() {
        bail!(
            "branch: a {} model has no [branch] section (only kind = \"branch\")",
            m.kind
        );
    }
    if is_no_pi(&m.pi) {
        bail!("pi: missing: a {} model needs its [pi] section", m.kind);
    }
    sizes(m)?;
    pi(m)?;
    motion(m, inverse)?;
    coupling(m)?;
    maps(m)?;
    ldpi(m)?;
    for (j, c) in m.creep.iter().enumerate() {
        if !(c.tau_s.is_finite() && c.tau_s > 0.0 && c.gain_um_per_v.is_finite()) {
            bail!("creep[{j}]: tau_s must be > 0 and gain_um_per_v finite");
        }
    }
    Ok(())
}

/// Counts: one weight per threshold, at most [`MAX_OPERATORS`] and [`MAX_CREEP`].
fn sizes(m: &HostModel) -> Result<()> {
    let p = &m.pi;
    if p.thresholds_v.len() != p.weights_um_per_v.len() {
        bail!(
            "pi.weights_um_per_v has {} values for {} thresholds",
            p.weights_um_per_v.len(),
            p.thresholds_v.len()
        );
    }
    if p.thresholds_v.len() > MAX_OPERATORS {
        bail!(
            "pi.thresholds_v has {} values: at most {MAX_OPERATORS} operators",
            p.thresholds_v.len()
        );
    }
    if m.creep.len() > MAX_CREEP {
        bail!("creep has {} terms: at most {MAX_CREEP}", m.creep.len());
    }
    Ok(())
}

/// The PI part: finite numbers, a positive input range, thresholds sorted in
/// `[0, input_max_v]`.
fn pi(m: &HostModel) -> Result<()> {
    let p = &m.pi;
    finite("pi.w0_um_per_v", p.w0_um_per_v)?;
    finite("pi.input_max_v", p.input_max_v)?;
    if p.input_max_v <= 0.0 {
        bail!("pi.input_max_v = {}: must be > 0", Num(p.input_max_v));
    }
    let mut prev = 0.0;
    for (i, (&r, &w)) in p.thresholds_v.iter().zip(&p.weights_um_per_v).enumerate() {
        finite(&format!("pi.thresholds_v[{i}]"), r)?;
        finite(&format!("pi.weights_um_per_v[{i}]"), w)?;
        if r < 0.0 {
            bail!(
                "pi.thresholds_v[{i}] = {}: thresholds are voltages ≥ 0 V",
                Num(r)
            );
        }
        if r < prev {
            bail!(
                "pi.thresholds_v[{i}] = {}: thresholds must be sorted",
                Num(r)
            );
        }
        if r > p.input_max_v {
            bail!(
                "pi.thresholds_v[{i}] = {}: above pi.input_max_v = {} (the operator never moves)",
                Num(r),
                Num(p.input_max_v)
            );
        }
        prev = r;
    }
    Ok(())
}

/// The model can produce motion, within the signal range, and, where it is
/// inverted in closed form, has an inverse: `w0 > 0` and every partial sum
/// `S_j = w0 + w_1 + … + w_j > 0` (its output rises with the voltage).
fn motion(m: &HostModel, inverse: Inverse) -> Result<()> {
    let p = &m.pi;
    let slopes = m.ldpi.as_ref();
    let all_zero = p.w0_um_per_v == 0.0
        && p.weights_um_per_v.iter().all(|&w| w == 0.0)
        && slopes.is_none_or(|l| l.w0_per_n == 0.0 && l.weights_per_n.iter().all(|&w| w == 0.0));
    if all_zero {
        bail!(
            "pi.w0_um_per_v and pi.weights_um_per_v are all 0: the model cannot produce \
             motion (was it calibrated on data without motion, e.g. a few rows or a \
             constant voltage?)"
        );
    }
    output_range(m)?;
    if inverse == Inverse::Search {
        return Ok(());
    }
    if p.w0_um_per_v <= 0.0 {
        bail!(
            "pi.w0_um_per_v = {}: must be > 0 µm/V (the model's slope at rest; without it \
             the model has no inverse)",
            Num(p.w0_um_per_v)
        );
    }
    let mut sum = p.w0_um_per_v;
    for (j, &w) in p.weights_um_per_v.iter().enumerate() {
        sum += w;
        if sum <= 0.0 {
            let terms = if j == 0 {
                "w0 + w_1".to_string()
            } else {
                format!("w0 + w_1 + … + w_{}", j + 1)
            };
            bail!(
                "pi.weights_um_per_v[{j}] = {}: the slope {terms} = {} µm/V is not \
                 positive (the output would fall as the voltage rises; no inverse)",
                Num(w),
                Num(sum)
            );
        }
    }
    Ok(())
}

/// The most a model's output may reach over its input range, µm: a metre, far
/// beyond any piezo stage's stroke (a model calibrated on 0–3.6 V keeps the
/// amplifier's 150 V as its input range, so its bound is no stroke).
pub const MAX_OUTPUT_UM: f64 = 1e6;

/// The model's output stays within [`MAX_OUTPUT_UM`] over its input range: the
/// weights' and creep gains' magnitudes times `pi.input_max_v` (a weight of
/// `1e308` µm/V is refused by its key, not predicted from). The largest term is
/// named.
fn output_range(m: &HostModel) -> Result<()> {
    let p = &m.pi;
    let terms = std::iter::once(("pi.w0_um_per_v".to_string(), p.w0_um_per_v))
        .chain(
            p.weights_um_per_v
                .iter()
                .enumerate()
                .map(|(i, &w)| (format!("pi.weights_um_per_v[{i}]"), w)),
        )
        .chain(
            m.creep
                .iter()
                .enumerate()
                .map(|(j, c)| (format!("creep[{j}].gain_um_per_v"), c.gain_um_per_v)),
        );
    let (mut top, mut largest) = (0.0, (String::new(), 0.0_f64));
    for (key, w) in terms {
        top += w.abs() * p.input_max_v;
        if w.abs() >= largest.1.abs() {
            largest = (key, w);
        }
    }
    if top <= MAX_OUTPUT_UM {
        return Ok(());
    }
    bail!(
        "{} = {}: the model's output over its input range (the magnitudes of its weights and \
         creep gains times pi.input_max_v = {} V) reaches {} µm, beyond {} µm (a metre: no \
         piezo stage's motion)",
        largest.0,
        Num(largest.1),
        Num(p.input_max_v),
        Num(top),
        Num(MAX_OUTPUT_UM)
    )
}

/// The coupling: finite, and a stack compliance within `[0, 0.5)` µm/N (a stack
/// yields under load; stacks: 0.005–0.1 µm/N; the firmware's `I0F32` holds less
/// than 0.5).
fn coupling(m: &HostModel) -> Result<()> {
    let c = &m.coupling;
    finite("coupling.offset_v", c.offset_v)?;
    finite("coupling.k_f_v_per_n", c.k_f_v_per_n)?;
    finite("coupling.k_q_v_per_n2", c.k_q_v_per_n2)?;
    finite("coupling.force_q_n", c.force_q_n)?;
    finite("coupling.compliance_um_per_n", c.compliance_um_per_n)?;
    if let Some(f) = c.force_ref_n {
        finite("coupling.force_ref_n", f)?;
    }
    if !(0.0..=COUPLING_ABS_MAX).contains(&c.compliance_um_per_n) {
        bail!(
            "coupling.compliance_um_per_n = {}: must be within 0–{COUPLING_ABS_MAX} µm/N (a \
             stack yields under load, by 0.005–0.1 µm/N; the firmware holds less than 0.5)",
            Num(c.compliance_um_per_n)
        );
    }
    Ok(())
}

/// The dead zone's softness (≥ 0; 0 is hard), the output offset and map.
fn maps(m: &HostModel) -> Result<()> {
    let s = m.dead_zone_softness_v;
    finite("dead_zone_softness_v", s)?;
    if s < 0.0 {
        bail!(
            "dead_zone_softness_v = {}: must be ≥ 0 V (0: the hard dead zone)",
            Num(s)
        );
    }
    finite("offset_um", m.offset_um)?;
    match m.output {
        OutputMap::Identity => Ok(()),
        OutputMap::Saturation { beta_per_um: b } => {
            finite("output.beta_per_um", b)?;
            let top = m.model().pi.output_max();
            if 1.0 + 4.0 * b * top <= 0.0 {
                bail!(
                    "output.beta_per_um = {}: the saturation folds over below the model's \
                     largest output {} µm",
                    Num(b),
                    Num(top)
                );
            }
            Ok(())
        }
        OutputMap::Quadratic { gamma_per_um: g } => finite("output.gamma_per_um", g),
    }
}

/// The ldpi section, if any: one finite slope per threshold.
fn ldpi(m: &HostModel) -> Result<()> {
    let Some(l) = &m.ldpi else {
        return Ok(());
    };
    if l.weights_per_n.len() != m.pi.thresholds_v.len() {
        bail!(
            "ldpi.weights_per_n has {} values for {} thresholds",
            l.weights_per_n.len(),
            m.pi.thresholds_v.len()
        );
    }
    finite("ldpi.w0_per_n", l.w0_per_n)?;
    for (i, &b) in l.weights_per_n.iter().enumerate() {
        finite(&format!("ldpi.weights_per_n[{i}]"), b)?;
    }
    Ok(())
}
