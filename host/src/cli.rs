//! The `fpi` commands (the binary only parses arguments and calls these).
//!
//! Every command checks its outputs before it works (an output that is one of its
//! inputs is refused, the output's folder must take a file: [`crate::output`]),
//! refuses numbers outside what the model and the board take, naming the option,
//! file or line and the value, and writes every file atomically.

pub mod axes;
pub mod board;
pub mod scope;

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::data::fem::FemMaps;
use crate::data::{self, read_drive, read_target, Num};
use crate::method::calibrate::{self, Options};
use crate::method::compare::{note_renamed, unique_names};
use crate::method::limits::AMPLIFIER_MAX_V;
use crate::method::model::{HostModel, Kind};
use crate::method::predict;
use crate::output::{self, not_an_input};

pub use crate::method::calibrate::{min_fit_rows, MIN_FIT_ROWS};

/// Writes a CSV with a header and `f64` columns of equal length, atomically
/// ([`output::write_atomic_with`]). Refuses columns of different lengths and
/// non-finite values (naming the column and the line it would have had) before
/// anything is written.
pub fn write_columns(path: &Path, header: &[&str], columns: &[&[f64]]) -> Result<()> {
    let n = columns.first().map_or(0, |c| c.len());
    if header.len() != columns.len() || columns.iter().any(|c| c.len() != n) {
        bail!(
            "{}: not written: columns of different lengths",
            path.display()
        );
    }
    for (name, c) in header.iter().zip(columns) {
        if let Some(k) = c.iter().position(|v| !v.is_finite()) {
            bail!(
                "{}: not written: column {name}, line {}: {} is not a finite number",
                path.display(),
                k + 2,
                c[k]
            );
        }
    }
    output::write_atomic_with(path, |w| {
        let mut csv = csv::Writer::from_writer(w);
        csv.write_record(header)?;
        let mut rec = Vec::with_capacity(columns.len());
        for k in 0..n {
            rec.clear();
            rec.extend(columns.iter().map(|c| format!("{:.6}", c[k])));
            csv.write_record(&rec)?;
        }
        csv.flush()
    })
}

/// Reads an FEM export and prints its plausibility warnings (each with the
/// number, line and column that triggered it) to stderr as `warning: …`.
pub fn read_fem(path: &Path) -> Result<FemMaps> {
    let maps = FemMaps::read(path)?;
    for w in maps.warnings() {
        eprintln!("warning: {w}");
    }
    Ok(maps)
}

/// Warns when `model` (file `model_path`) was refined against another FEM file
/// than `fem` (by file name: its correction is meant for the tables it was
/// estimated on).
fn warn_other_fem(model: &HostModel, model_path: &Path, fem: &Path) {
    let Some(c) = &model.fem_correction else {
        return;
    };
    let stored = Path::new(&c.fem);
    if !c.fem.is_empty() && stored.file_name() != fem.file_name() {
        eprintln!(
            "warning: {}: its [fem_correction] was estimated against {}, and is applied to {}",
            model_path.display(),
            c.fem,
            fem.display()
        );
    }
}

/// The stage maps a model runs with: the FEM file `fem` read ([`read_fem`]) and
/// corrected by the model's `[fem_correction]` when it has one
/// ([`HostModel::stage_maps`]). Every command that pairs a model with FEM tables
/// (predict, invert, export, `board load`; compare through
/// [`Comparison::run`](crate::method::compare::Comparison::run)) gets them here.
pub fn stage_maps(model: &HostModel, model_path: &Path, fem: &Path) -> Result<FemMaps> {
    let maps = read_fem(fem)?;
    warn_other_fem(model, model_path, fem);
    model
        .stage_maps(&maps)
        .with_context(|| model_path.display().to_string())
}

/// Refuses a drive (`voltage_V` of file `path`) outside the model's input range,
/// naming the file, the line and the voltage.
fn drive_in_range(path: &Path, model: &HostModel, u: &[f64]) -> Result<()> {
    if let Some((k, v)) = predict::outside_range(model, u) {
        let (lo, hi) = predict::input_range(model);
        bail!(
            "{}:{}: column voltage_V: {} V is outside the model's input range {lo}..{hi} V \
             (the amplifier spans 0..{AMPLIFIER_MAX_V} V); the model would clamp it",
            path.display(),
            k + 2,
            Num(v),
        );
    }
    Ok(())
}

/// `(option, path)` pairs of the inputs given as one option.
fn inputs<'a>(option: &'a str, paths: &'a [PathBuf]) -> Vec<(&'a str, &'a Path)> {
    paths.iter().map(|p| (option, p.as_path())).collect()
}

/// `fpi calibrate`.
pub fn calibrate(
    kind: Option<Kind>,
    rig: &[PathBuf],
    out: &Path,
    operators: Option<usize>,
    compliance: Option<f64>,
    rows: Option<(usize, usize)>,
    axis: Option<usize>,
) -> Result<()> {
    not_an_input("--out", out, &inputs("--rig", rig))?;
    output::prepare(out)?;
    let data = match axis {
        Some(a) => calibrate::load_stack(rig, a, rows)?,
        None => calibrate::load(rig, rows)?,
    };
    let (opt, note) = calibrate::settle(&data, kind, operators, compliance, rows)?;
    if let Some(note) = note {
        eprintln!("note: {note}");
    }
    let kind = opt.kind;
    let start = std::time::Instant::now();
    let mut model = calibrate::calibrate(&data, &opt)?;
    model.calibration.rows = rows.map(|(a, b)| [a, b]);
    model.calibration.files = rig.iter().map(|p| p.display().to_string()).collect();
    let secs = start.elapsed().as_secs_f64();
    let structure = kind.structure(&model);
    println!(
        "{kind} model, {structure}, calibrated on {} recording(s) in {secs:.2} s",
        data.len()
    );
    print_fit(&model);
    if rows.is_some() {
        print_held_out(&model, &data[0]);
    }
    model.write(out)?;
    println!("model written to {}", out.display());
    Ok(())
}

/// The model's prediction of the rest of a recording fitted on a window of it, in
/// windows of [`calibrate::HELD_OUT_WINDOW`] samples ([`calibrate::held_out`]).
fn print_held_out(m: &HostModel, d: &calibrate::CalibData) {
    let windows = calibrate::held_out(m, d, calibrate::HELD_OUT_WINDOW);
    if windows.is_empty() {
        return;
    }
    println!(
        "  beyond the fitted rows, each window with its mean error removed (the recording's drift):"
    );
    println!(
        "  {:<34} {:>8} {:>10} {:>10}",
        "rows", "samples", "RMSE µm", "offset µm"
    );
    for w in &windows {
        println!(
            "  {:<34} {:>8} {:>10.4} {:>10.4}",
            format!("{}-{}", w.rows.0, w.rows.1),
            w.rows.1 + 1 - w.rows.0,
            w.rmse_um,
            w.offset_um
        );
    }
}

/// Prints a model's parameters and its per-file fit.
pub fn print_fit(m: &HostModel) {
    if let Some(p) = m.kind.parameters(m) {
        println!("  {p}");
    }
    println!(
        "  {:<34} {:>8} {:>10} {:>10}",
        "file", "samples", "RMSE µm", "MTE µm"
    );
    for f in &m.calibration.per_file {
        println!(
            "  {:<34} {:>8} {:>10.4} {:>10.4}",
            f.file, f.samples, f.rmse_um, f.mte_um
        );
    }
    println!(
        "  {:<34} {:>8} {:>10.4} {:>10.4}",
        "all",
        m.calibration
            .per_file
            .iter()
            .map(|f| f.samples)
            .sum::<usize>(),
        m.calibration.rmse_um,
        m.calibration.mte_um
    );
    for w in &m.calibration.warnings {
        eprintln!("warning: {w}");
    }
}

/// `fpi predict`.
pub fn predict(model: &Path, fem: &Path, drive: &Path, out: &Path) -> Result<()> {
    predict_with(model, fem, drive, out, None)
}

/// `fpi predict [--dynamics DYN.toml]`: with dynamics, the rate-independent
/// prediction runs through the identified linear dynamics
/// ([`crate::method::dynamics`], Hammerstein): `x_fhps_um` is then the
/// rate-dependent output and a last column `x_fhps_static_um` the
/// rate-independent one.
pub fn predict_with(
    model: &Path,
    fem: &Path,
    drive: &Path,
    out: &Path,
    dynamics: Option<&Path>,
) -> Result<()> {
    let mut given = vec![("--model", model), ("--fem", fem), ("--drive", drive)];
    given.extend(dynamics.map(|d| ("--dynamics", d)));
    not_an_input("--out", out, &given)?;
    output::prepare(out)?;
    let m = HostModel::read(model)?;
    let dynamics = dynamics
        .map(crate::method::dynamics::Dynamics::read)
        .transpose()?;
    let maps = stage_maps(&m, model, fem)?;
    let (t, u) = read_drive(drive)?;
    drive_in_range(drive, &m, &u)?;
    let start = std::time::Instant::now();
    let p = predict::predict(&m, &maps, &t, &u).with_context(|| drive.display().to_string())?;
    let secs = start.elapsed().as_secs_f64();
    if let Some(d) = &dynamics {
        let rated = rate_dependent(d, drive, &t, &p.x_fhps)?;
        write_columns(
            out,
            &[
                "t_s",
                "voltage_V",
                "x_pea_um",
                "preload_N",
                "x_fhps_um",
                "x_fhps_static_um",
            ],
            &[&p.t, &p.u, &p.x_pea, &p.preload, &rated, &p.x_fhps],
        )?;
        println!(
            "rate-dependent: the prediction run through the identified dynamics (modes {:?} Hz)",
            d.natural_frequency_hz
        );
    } else {
        write_columns(
            out,
            &["t_s", "voltage_V", "x_pea_um", "preload_N", "x_fhps_um"],
            &[&p.t, &p.u, &p.x_pea, &p.preload, &p.x_fhps],
        )?;
    }
    println!(
        "{} ({}): {} samples predicted in {:.1} ms ({:.2} solver iterations per sample); written to {}",
        m.kind.method(),
        model.display(),
        t.len(),
        secs * 1e3,
        p.iterations as f64 / t.len() as f64,
        out.display()
    );
    let _ = std::io::stdout().flush();
    Ok(())
}

/// The models of `fpi compare`, named by their file stems made unique.
fn read_models(paths: &[PathBuf]) -> Result<Vec<(String, HostModel)>> {
    let stems: Vec<String> = paths
        .iter()
        .map(|p| {
            p.file_stem()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default()
        })
        .collect();
    let names = unique_names(&stems);
    let refs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    note_renamed("model", &refs, &stems, &names);
    paths
        .iter()
        .zip(names)
        .map(|(p, name)| Ok((name, HostModel::read(p)?)))
        .collect()
}

/// `fpi compare`.
pub fn compare(fem: &Path, runs: &[PathBuf], models: &[PathBuf], out: &Path) -> Result<()> {
    compare_with(fem, runs, models, out, None)
}

/// `fpi compare [--dynamics DYN.toml]`: with dynamics, every model is scored
/// twice, as it is (rate-independent) and followed by the identified dynamics
/// (named `MODEL+dyn`).
pub fn compare_with(
    fem: &Path,
    runs: &[PathBuf],
    models: &[PathBuf],
    out: &Path,
    dynamics: Option<&Path>,
) -> Result<()> {
    let mut given = vec![("--fem", fem)];
    given.extend(inputs("--runs", runs));
    given.extend(inputs("--model", models));
    given.extend(dynamics.map(|d| ("--dynamics", d)));
    output::folder_spares_inputs("--out", out, &given, crate::report::writes)?;
    output::prepare_folder(out)?;
    let maps = read_fem(fem)?;
    let paths = models;
    let models = read_models(models)?;
    for (p, (_, m)) in paths.iter().zip(&models) {
        warn_other_fem(m, p, fem);
    }
    let runs: Vec<data::StageRun> = runs
        .iter()
        .map(|p| data::read_stage(p))
        .collect::<Result<_, _>>()?;
    for r in &runs {
        for (_, m) in &models {
            drive_in_range(&r.path, m, &r.u)?;
        }
    }
    let mut cmp = crate::method::compare::Comparison::run(&maps, &runs, &models)?;
    if let Some(d) = dynamics {
        let dynamics = crate::method::dynamics::Dynamics::read(d)?;
        cmp.add_dynamics(&dynamics)?;
    }
    crate::method::compare::print_table(&cmp);
    crate::report::write(&cmp, &maps, out)?;
    println!("report written to {}", out.join("report.md").display());
    Ok(())
}

/// `fpi invert`: `u_max` (V) must be finite, > 0 and within the model's input range
/// (and so the amplifier's span).
pub fn invert(model: &Path, fem: &Path, target: &Path, out: &Path, u_max: f64) -> Result<()> {
    let given = [("--model", model), ("--fem", fem), ("--target", target)];
    not_an_input("--out", out, &given)?;
    output::prepare(out)?;
    let m = HostModel::read(model)?;
    let maps = stage_maps(&m, model, fem)?;
    let (t, x) = read_target(target)?;
    let inv = crate::method::invert::invert(&m, &maps, &t, &x, u_max)
        .with_context(|| target.display().to_string())?;
    write_columns(out, &["t_s", "voltage_V"], &[&inv.t, &inv.u])?;
    println!(
        "{} inverse ({}): {} samples written to {}; reachable stroke {:.3}..{:.3} µm at 0..{} V",
        m.kind,
        model.display(),
        t.len(),
        out.display(),
        inv.reachable.0,
        inv.reachable.1,
        u_max
    );
    if inv.clamped_targets > 0 {
        eprintln!(
            "warning: {} of {} target samples lie outside the reachable stroke and were clamped to it",
            inv.clamped_targets,
            t.len()
        );
    }
    if inv.clamped_voltage > 0 {
        eprintln!(
            "warning: {} samples needed a voltage outside 0..{u_max} V and were clamped",
            inv.clamped_voltage
        );
    }
    Ok(())
}

/// `fpi refine`: estimates the correction of the FEM tables `fem` from measured
/// `runs` of the built stage ([`crate::method::refine`]) and writes `model` with
/// it as its `[fem_correction]` to `out`.
pub fn refine(model: &Path, fem: &Path, runs: &[PathBuf], out: &Path) -> Result<()> {
    let mut given = vec![("--model", model), ("--fem", fem)];
    given.extend(inputs("--run", runs));
    not_an_input("--out", out, &given)?;
    output::prepare(out)?;
    let m = HostModel::read(model)?;
    if m.fem_correction.is_some() {
        eprintln!(
            "note: {} already has a [fem_correction]: it is estimated anew against {} as it is",
            model.display(),
            fem.display()
        );
    }
    let maps = read_fem(fem)?;
    let data: Vec<data::StageRun> = runs
        .iter()
        .map(|p| data::read_stage(p))
        .collect::<Result<_, _>>()?;
    for r in &data {
        drive_in_range(&r.path, &m, &r.u)?;
    }
    let start = std::time::Instant::now();
    let (refined, r) = crate::method::refine::refine_model(&m, &maps, &data)?;
    let secs = start.elapsed().as_secs_f64();
    let c = &r.correction;
    println!(
        "FEM tables {} refined for the {} model {} on {} run(s) ({} rounds, {:.2} s):",
        fem.display(),
        m.kind,
        model.display(),
        data.len(),
        r.iterations,
        secs
    );
    println!(
        "  stage_gain      {:.5}  (stage output = stage_gain·f_K(x_pea) + stage_offset_um)",
        c.stage_gain
    );
    println!("  stage_offset_um {:.4} µm", c.stage_offset_um);
    println!(
        "  preload_scale   {:.5}  (preload = preload_scale·f_F(x_pea); rest preload {:.2} N -> {:.2} N)",
        c.preload_scale,
        maps.rest_preload(),
        c.preload_scale * maps.rest_preload()
    );
    let w = r
        .runs
        .iter()
        .map(|f| f.file.chars().count())
        .fold(34, usize::max);
    println!(
        "  {:<w$} {:>8} {:>12} {:>12} {:>12} {:>12} {:>18}",
        "run", "samples", "RMSE before", "RMSE after", "MAE before", "MAE after", "force RMSE N"
    );
    for f in &r.runs {
        println!(
            "  {:<w$} {:>8} {:>12.4} {:>12.4} {:>12.4} {:>12.4} {:>8.3} -> {:.3}",
            f.file,
            f.samples,
            f.before.rmse,
            f.after.rmse,
            f.before.mae,
            f.after.mae,
            f.force_rmse_before_n,
            f.force_rmse_after_n
        );
    }
    if data.len() > 1 {
        println!(
            "  {:<w$} {:>8} {:>12.4} {:>12.4} {:>12.4} {:>12.4}",
            "all",
            r.runs.iter().map(|f| f.samples).sum::<usize>(),
            r.before.rmse,
            r.after.rmse,
            r.before.mae,
            r.after.mae
        );
    }
    println!(
        "  (µm; these are the runs it was refined on: score it on other runs with \
         fpi compare --model {} --model {})",
        model.display(),
        out.display()
    );
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    refined.write(out)?;
    println!("refined model written to {}", out.display());
    Ok(())
}

/// `fpi export`.
pub fn export(
    m: &HostModel,
    model: &Path,
    fem: &Path,
    out: &Path,
    o: &crate::method::export::ExportOptions,
    dynamics: Option<(&Path, crate::method::shaping::ShapingOptions)>,
) -> Result<()> {
    let mut inputs = vec![("--model", model), ("--fem", fem)];
    if let Some((d, _)) = dynamics {
        inputs.push(("--dynamics", d));
    }
    not_an_input("--out", out, &inputs)?;
    output::prepare(out)?;
    let maps = stage_maps(m, model, fem)?;
    let settings = crate::method::export::LoopSettings::for_model(m, o);
    let mut e = crate::method::export::export(m, model, &maps, &settings)?;
    if let Some((d, so)) = dynamics {
        let d = crate::method::dynamics::Dynamics::read(d)?;
        e.model = crate::method::shaping::with_dynamics(&e.model, &d, &so)?;
        println!("{}", crate::method::shaping::describe(&e.model));
    }
    let text = e.model.to_toml().map_err(|e| anyhow::anyhow!(e))?;
    output::write_atomic(out, text.as_bytes())?;
    println!(
        "firmware model for the {} model written to {}",
        m.kind,
        out.display()
    );
    print_export(&e);
    Ok(())
}

/// `fpi tune`: the position loop's gains, written into the firmware model.
///
/// With `frf`, the plant fitted to a measured response: one that is not the
/// stage's own (measured with the damping on or the loop closed) or that the fit
/// misses ([`tune::frf::problems`](crate::method::tune::frf::problems)) is
/// refused, or with `accept_misfit` written with a warning for each problem.
pub fn tune(
    firmware: &Path,
    dynamics: Option<&Path>,
    frf: Option<&Path>,
    out: &Path,
    o: &crate::method::tune::TuneOptions,
    accept_misfit: bool,
) -> Result<()> {
    use crate::method::tune;
    let mut inputs = vec![("--firmware", firmware)];
    if let Some(d) = dynamics {
        inputs.push(("--dynamics", d));
    }
    if let Some(f) = frf {
        inputs.push(("--frf", f));
    }
    not_an_input("--out", out, &inputs)?;
    output::prepare(out)?;
    let shown = firmware.display().to_string();
    let text = std::fs::read_to_string(firmware).with_context(|| format!("reading {shown}"))?;
    let fw = piezo_sim::file::FirmwareModel::parse(&text, &shown).map_err(anyhow::Error::msg)?;
    let dyn_model = dynamics
        .map(crate::method::dynamics::Dynamics::read)
        .transpose()?;
    let t = match frf {
        Some(path) => {
            let measured = tune::frf::read_csv(path)?;
            let rate = fw.controller.rate_hz;
            let split = fw
                .controller
                .force_split_hz
                .unwrap_or(piezo_fpi::control::DEFAULT_SPLIT_HZ as f64);
            let fit = tune::frf::fit(&measured.points, rate, tune::split_rate_f64(split, rate))?;
            println!("{}", tune::frf::describe(&fit));
            let shown = path.display();
            if measured.conditions.is_none() {
                eprintln!(
                    "note: {shown} does not say how it was measured (no \"# measured with:\" \
                     line; `fpi board frf` writes one): a plant fit needs the stage's own \
                     response, with the damping off and the loop open"
                );
            }
            let problems = tune::frf::problems(&fit, measured.conditions.as_ref());
            if !problems.is_empty() && !accept_misfit {
                bail!(
                    "{shown}: no plant to design the loops on: {}; {}; nothing is written \
                     (--accept-misfit writes the model anyway)",
                    problems.join("; "),
                    tune::frf::REMEASURE
                );
            }
            if !problems.is_empty() {
                eprintln!(
                    "warning: {shown}: {}; the loops are designed on this fit as \
                     --accept-misfit asks: check them with `fpi board step` before use",
                    problems.join("; ")
                );
            }
            tune::tune_measured(&fw, fit.spec, o)?
        }
        None => tune::tune(&fw, dyn_model.as_ref(), o)?,
    };
    let tuned = tune::with_tuning(&fw, &t, o)?;
    let text = tuned.to_toml().map_err(anyhow::Error::msg)?;
    output::write_atomic(out, text.as_bytes())?;
    println!(
        "loops for {shown} written to {}: kp {:.3}, ki {:.1}/s{}",
        out.display(),
        t.kp,
        t.ki_per_s,
        if t.damping_gain > 0.0 {
            format!(", damping {:.0} µm/(N·s)", t.damping_gain)
        } else {
            String::new()
        }
    );
    for line in t.summary(o).lines() {
        println!("  {line}");
    }
    Ok(())
}

/// The tables and loop settings of an export.
fn print_export(e: &crate::method::export::Export) {
    println!(
        "  {:<20} {:>6} {:>12} {:>14}",
        "table", "knots", "step", "max error"
    );
    for t in &e.tables {
        println!(
            "  {:<20} {:>6} {:>12} {:>14.3e}",
            t.name, t.knots, t.step, t.max_error
        );
    }
    let k = &e.model.controller;
    println!(
        "  loop: {} Hz, 0..{} V, {} V/ms; references {}..{} µm; forces {}..{} N (tolerance {} N)",
        k.rate_hz,
        k.u_max_v,
        k.slew_v_per_ms,
        k.reference_min_um,
        k.reference_max_um,
        k.force_min_n,
        k.force_max_n,
        k.force_tolerance_n
    );
}

/// `fpi demo`.
pub fn demo(out: &Path) -> Result<()> {
    output::prepare_folder(out)?;
    let s = crate::report::demo::run(out)?;
    for l in &s.lines {
        println!("{l}");
    }
    println!("report: {}", s.report.display());
    if !s.ok {
        bail!("a target was missed (see above)");
    }
    Ok(())
}

/// `fpi bench`: throughput figures (measured, printed; not a test).
pub fn bench() -> Result<()> {
    use std::hint::black_box;
    use std::time::Instant;
    // Forward PI, 10 operators (w0 + 9), one core.
    let n = 20_000_000usize;
    let u: Vec<f64> = (0..n)
        .map(|k| 50.0 + 45.0 * (k as f64 * 1.3e-3).sin() * (k as f64 * 7.1e-6).cos())
        .collect();
    let mut y = vec![0.0; n];
    let r = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0];
    let w = [
        0.0126, 0.0075, 0.006, 0.0038, 0.0026, 0.0012, 0.0012, 0.0007, 0.0011,
    ];
    let pi = piezo_sim::play::Pi::new(0.0626, &r, &w, 150.0).context("the bench model")?;
    let mut bank = pi.at_rest();
    let t0 = Instant::now();
    pi.run(&mut bank, black_box(&u), &mut y);
    black_box(&y);
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "forward_pi_samples_per_s n=10: {:.1} M ({} samples in {:.3} s, one core)",
        n as f64 / secs / 1e6,
        n,
        secs
    );
    // Their 320 MB would count in the scaling figures' peak below.
    drop((u, y));

    // The coupled solve (Part III, Step 4a) on stage A's FEM maps, one core.
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv"))?;
    let rig = calibrate::load(&data::datasets_in("pea-rig"), None)?;
    for kind in [Kind::Fpi, Kind::Efpi] {
        let t0 = Instant::now();
        let m = calibrate::calibrate(&rig, &Options::for_kind(kind))?;
        let cal = t0.elapsed().as_secs_f64();
        println!(
            "calibration_seconds kind={kind}: {:.2} ({} pea-rig recordings, {} samples, {} threads)",
            cal,
            rig.len(),
            rig.iter().map(|d| d.u.len()).sum::<usize>(),
            rayon::current_num_threads()
        );
        let n = 1_000_000usize;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 2e-4).collect();
        let drive: Vec<f64> = t
            .iter()
            .map(|t| 50.0 - 50.0 * (std::f64::consts::TAU * 5.0 * t).cos())
            .collect();
        let t0 = Instant::now();
        let p = predict::predict(&m, &fem, &t, &drive)?;
        let secs = t0.elapsed().as_secs_f64();
        black_box(&p);
        println!(
            "coupled_solve_samples_per_s kind={kind}: {:.2} M ({:.2} solver iterations per sample, one core)",
            n as f64 / secs / 1e6,
            p.iterations as f64 / n as f64
        );
        if kind == Kind::Efpi {
            bench_axes(&m, &t[..200_000], &drive[..200_000])?;
        }
    }

    // Calibration on 5 million samples: linear in time and memory (the default
    // kind within 30 s and 300 MB on two cores).
    print!(
        "{}",
        crate::method::bench::scaling(crate::method::bench::SAMPLES)?
    );

    // The live stream from the board's recorder to the scope's page, at a real
    // board's rate (the in-process board keeps board time with wall time).
    println!("{}", crate::scope::bench::stream(3.0)?);
    Ok(())
}

/// The several-axis method's cost (`fpi axes`): every stack of the XY and XYZ
/// grids driven by `drive` (each axis phase-shifted), coupled and each axis
/// alone, one core.
fn bench_axes(m: &HostModel, t: &[f64], drive: &[f64]) -> Result<()> {
    use crate::method::axes::{grid::FemGrid, predict as axes};
    for stage in ["xy", "xyz"] {
        let grid = FemGrid::read(&data::dataset(&format!("{stage}/fem_grid.csv")))?;
        let n = grid.axes();
        let u: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                let shift = i * drive.len() / 7;
                (0..drive.len())
                    .map(|k| drive[(k + shift) % drive.len()])
                    .collect()
            })
            .collect();
        let models = vec![m; n];
        let t0 = std::time::Instant::now();
        let c = axes::coupled(&models, &grid, t, &u);
        let coupled = t0.elapsed().as_secs_f64();
        let t0 = std::time::Instant::now();
        let i = axes::independent_axes(&models, &grid, t, &u)?;
        let alone = t0.elapsed().as_secs_f64();
        std::hint::black_box((&c, &i));
        let samples = t.len() as f64;
        println!(
            "coupled_solve_samples_per_s axes={n} kind=efpi: {:.2} M coupled ({:.2} evaluations per stack, \
             {:.2} sweeps per sample), {:.2} M each axis alone; {:.2} µs against {:.2} µs a sample, one core",
            samples / coupled / 1e6,
            c.evaluations_per_sample(),
            c.sweeps as f64 / samples,
            samples / alone / 1e6,
            coupled / samples * 1e6,
            alone / samples * 1e6
        );
    }
    Ok(())
}

/// The rate-independent stage output `x` (µm) of drive file `drive` (time `t`,
/// s) through the identified dynamics `d`; refuses a drive not sampled
/// uniformly, naming the file and the line.
fn rate_dependent(
    d: &crate::method::dynamics::Dynamics,
    drive: &Path,
    t: &[f64],
    x: &[f64],
) -> Result<Vec<f64>> {
    let dt = crate::method::dynamics::uniform_step(t).map_err(|(k, step, dt)| {
        anyhow::anyhow!(
            "{}:{}: column t_s: step {} s differs from the mean {} s by more than 1 %: \
             the dynamics need a uniformly sampled drive",
            drive.display(),
            k + 3,
            Num(step),
            Num(dt)
        )
    })?;
    d.apply(x, dt).with_context(|| drive.display().to_string())
}

/// `fpi identify`: the stage's dynamics from chirps
/// ([`crate::method::identify`]), written to `out` (`DYN.toml`), with the Bode
/// figure in `plots` when given.
pub fn identify(chirps: &[PathBuf], out: &Path, plots: Option<&Path>, min_hz: f64) -> Result<()> {
    use crate::method::identify as id;
    let given = inputs("--chirp", chirps);
    not_an_input("--out", out, &given)?;
    output::prepare(out)?;
    if let Some(dir) = plots {
        output::folder_spares_inputs("--plots", dir, &given, |n| n == "bode.svg")?;
        output::prepare_folder(dir)?;
    }
    let data: Vec<id::Chirp> = chirps
        .iter()
        .map(|p| id::read_chirp(p))
        .collect::<Result<_, _>>()?;
    let start = std::time::Instant::now();
    let result = id::identify(&data, min_hz)?;
    println!(
        "dynamics identified from {} chirp(s) in {:.2} s:",
        data.len(),
        start.elapsed().as_secs_f64()
    );
    for line in id::summary(&result) {
        println!("{line}");
    }
    result.dynamics.write(out)?;
    println!("dynamics written to {}", out.display());
    if let Some(dir) = plots {
        for p in crate::report::identify::plots(&result, dir)? {
            println!("plot written to {}", p.display());
        }
    }
    Ok(())
}

/// Lets a closed stdout end the process quietly, as command-line tools do
/// (`fpi calibrate … | head`), instead of `println!` panicking on the broken pipe.
pub fn exit_quietly_on_broken_pipe() {
    #[cfg(unix)]
    // SAFETY: restores the default disposition of SIGPIPE before any thread starts;
    // no signal handler of ours is involved.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
