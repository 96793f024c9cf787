//! `fpi axes …`: the method for several degrees of freedom
//! ([`crate::method::axes`]) on an XY or XYZ stage.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use piezo_sim::axes::AXIS_NAMES;

use crate::cli::write_columns;
use crate::data::columns::{axes_in_header, read_named_columns};
use crate::data::{strictly_increasing, DataError};
use crate::method::axes::grid::{column, FemGrid};
use crate::method::axes::predict::{self, AxesPrediction};
use crate::method::axes::record::{self, sample_period_s};
use crate::method::limits::AMPLIFIER_MAX_V;
use crate::method::model::HostModel;
use crate::output::{self, not_an_input};

/// The stages `fpi axes grid` writes the design of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Design {
    /// The XY stage.
    Xy,
    /// The XYZ stage.
    Xyz,
}

impl Design {
    fn axes(self) -> usize {
        match self {
            Self::Xy => 2,
            Self::Xyz => 3,
        }
    }
}

/// `fpi axes decoupling`: the board's matrices and preload coupling for a
/// grid's stage, with the cross gains they come from; printed.
pub fn decoupling(grid: &Path) -> Result<()> {
    let g = FemGrid::read(grid)?;
    let c = crate::method::axes::decouple::cross_gains(&g);
    let d = crate::method::axes::decouple::decoupling(&g)?;
    let n = g.axes();
    let names = &AXIS_NAMES[..n];
    let row = |name: &str, v: &mut dyn Iterator<Item = f64>| {
        let cells: Vec<String> = v.map(|x| format!("{x:>11.6}")).collect();
        println!("  {name}  {}", cells.join(" "));
    };
    let head = names.iter().map(|a| format!("{a:>11}")).collect::<Vec<_>>();
    println!(
        "{}: cross gains (µm of the row's axis per µm of the column's own output)",
        g.source
    );
    println!("     {}", head.join(" "));
    for (i, name) in names.iter().enumerate() {
        row(name, &mut c[i].iter().copied());
    }
    println!("output matrix (axes → stacks), (I + C)⁻¹ as the board takes it (I2F30):");
    println!("     {}", head.join(" "));
    for (i, name) in names.iter().enumerate() {
        row(
            name,
            &mut d.output.rows()[i][..n].iter().map(|e| e.to_num::<f64>()),
        );
    }
    let k = crate::method::axes::decouple::preload_coupling(&g);
    println!("preload coupling (N on the row's stack per µm of the column's extension):");
    println!("     {}", head.join(" "));
    for (i, name) in names.iter().enumerate() {
        row(name, &mut k[i].iter().copied());
    }
    println!("input matrix (sensors → axes): the identity (a grid knows nothing of the sensors)");
    Ok(())
}

/// `fpi axes grid`: the design's FEM grid.
pub fn grid(stage: Design, every: Option<usize>, out: &Path) -> Result<()> {
    output::prepare(out)?;
    let every = every.unwrap_or(match stage {
        Design::Xy => 1,
        Design::Xyz => 4,
    });
    let Some(g) = FemGrid::design(stage.axes(), every) else {
        bail!("--every {every}: the design's tables keep at least two points (1..=24)");
    };
    g.write(out)?;
    println!(
        "{}: {} of {} stacks, {} points per stack ({:.3}..{:.3} µm)",
        out.display(),
        g.source,
        g.axes(),
        g.knots(0).len(),
        g.knots(0)[0],
        g.knots(0)[g.knots(0).len() - 1]
    );
    Ok(())
}

/// A drive of every axis: `t_s,voltage_V@x,voltage_V@y[,voltage_V@z]`.
pub fn read_drive(path: &Path) -> Result<(Vec<f64>, Vec<Vec<f64>>), DataError> {
    let (t, mut per_axis) = read_axes(path, &["voltage_V"])?;
    Ok((t, per_axis.remove(0)))
}

/// Columns of every axis (`[axis][sample]`).
type PerAxis = Vec<Vec<f64>>;

/// `t_s` (strictly increasing) and, for each of `quantities`, its column of
/// every axis the file has `voltage_V@…` for, in one read of the file.
fn read_axes(path: &Path, quantities: &[&str]) -> Result<(Vec<f64>, Vec<PerAxis>), DataError> {
    let n = axes_in_header(path, "voltage_V")?;
    let mut names = vec!["t_s".to_string()];
    for q in quantities {
        names.extend((0..n).map(|i| column(q, i)));
    }
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut values = read_named_columns(path, &names)?.values.into_iter();
    let t = values.next().unwrap_or_default();
    strictly_increasing(path, "t_s", &t)?;
    let per_quantity = quantities
        .iter()
        .map(|_| values.by_ref().take(n).collect())
        .collect();
    Ok((t, per_quantity))
}

/// `fpi axes record`: the virtual stage as built under a drive.
pub fn record(stage: &str, drive: &Path, out: &Path, seed: u32) -> Result<()> {
    not_an_input("--out", out, &[("--drive", drive)])?;
    output::prepare(out)?;
    let (t, u) = read_drive(drive)?;
    let dt = sample_period_s();
    if let Some(k) = (1..t.len()).find(|&k| ((t[k] - t[k - 1]) / dt - 1.0).abs() > 1e-6) {
        bail!(
            "{}:{}: column t_s: a step of {} s; the virtual stage runs at {} s a sample",
            drive.display(),
            k + 2,
            t[k] - t[k - 1],
            dt
        );
    }
    for (i, ui) in u.iter().enumerate() {
        if let Some(k) = ui.iter().position(|v| !(0.0..=AMPLIFIER_MAX_V).contains(v)) {
            bail!(
                "{}:{}: column {}: {} V is outside the amplifier's 0..{AMPLIFIER_MAX_V} V",
                drive.display(),
                k + 2,
                column("voltage_V", i),
                ui[k]
            );
        }
    }
    let spec = crate::board::variant::parse_axes(stage)?;
    let r = record::record(&spec, &u, seed)?;
    let (names, cols) = r.columns();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    write_columns(out, &names, &cols)?;
    println!(
        "{}: {stage}, {} samples of axes {}",
        out.display(),
        t.len(),
        record::names(u.len())
    );
    Ok(())
}

/// The models of a grid's stacks: one file for every stack, or one per stack
/// ([`predict::model_of_each_stack`]), each file read once.
fn models(paths: &[PathBuf], axes: usize) -> Result<(Vec<HostModel>, Vec<String>)> {
    let of = predict::model_of_each_stack(paths.len(), axes, "--model")?;
    let read: Vec<HostModel> = paths
        .iter()
        .map(|p| HostModel::read(p))
        .collect::<Result<_>>()?;
    Ok((
        of.iter().map(|&k| read[k].clone()).collect(),
        of.iter().map(|&k| paths[k].display().to_string()).collect(),
    ))
}

/// `fpi axes predict`: every axis with the coupled preloads and outputs (or
/// each alone, `independent`).
pub fn predict(
    grid: &Path,
    model: &[PathBuf],
    drive: &Path,
    out: &Path,
    independent: bool,
) -> Result<()> {
    let mut given: Vec<(&str, &Path)> = vec![("--grid", grid), ("--drive", drive)];
    given.extend(model.iter().map(|m| ("--model", m.as_path())));
    not_an_input("--out", out, &given)?;
    output::prepare(out)?;
    let g = FemGrid::read(grid)?;
    let (models, names) = models(model, g.axes())?;
    let (t, u) = read_drive(drive)?;
    let p = run(&g, &models, &names, &t, &u, independent)
        .with_context(|| drive.display().to_string())?;
    let (header, cols): (Vec<String>, Vec<&[f64]>) = p.columns().into_iter().unzip();
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    write_columns(out, &header, &cols)?;
    println!(
        "{}: {} samples, {} ({:.2} model evaluations per sample and stack)",
        out.display(),
        t.len(),
        if independent {
            "each axis alone"
        } else {
            "coupled"
        },
        p.evaluations_per_sample()
    );
    Ok(())
}

fn run(
    g: &FemGrid,
    models: &[HostModel],
    names: &[String],
    t: &[f64],
    u: &[Vec<f64>],
    independent: bool,
) -> Result<AxesPrediction> {
    let refs: Vec<&HostModel> = models.iter().collect();
    predict::run(&refs, names, g, t, u, independent)
}

/// One run's figures of `fpi axes compare`.
#[derive(Debug, Clone, PartialEq)]
pub struct RunFigures {
    /// The run's file name.
    pub run: String,
    /// Per axis: coupled and independent RMSE and MTE, µm.
    pub axes: Vec<[f64; 4]>,
    /// Coupled and independent cost: µs per sample (all stacks).
    pub us_per_sample: [f64; 2],
    /// Coupled and independent model evaluations per sample and stack.
    pub evaluations: [f64; 2],
    /// Coupled sweeps per sample.
    pub sweeps: f64,
}

/// `fpi axes compare`: both predictions of every run, scored on its true outputs
/// (`x_fhps_um@…`), and their cost per sample; prints the table and returns it.
pub fn compare(grid: &Path, model: &[PathBuf], runs: &[PathBuf]) -> Result<Vec<RunFigures>> {
    let g = FemGrid::read(grid)?;
    let (models, names) = models(model, g.axes())?;
    let mut all = Vec::new();
    for r in runs {
        let (t, mut columns) = read_axes(r, &["voltage_V", "x_fhps_um"])?;
        let (x, u) = (columns.remove(1), columns.remove(0));
        let timed = |independent| -> Result<(AxesPrediction, f64)> {
            let start = Instant::now();
            let p = run(&g, &models, &names, &t, &u, independent)
                .with_context(|| r.display().to_string())?;
            Ok((p, start.elapsed().as_secs_f64() * 1e6 / t.len() as f64))
        };
        let (c, c_us) = timed(false)?;
        let (i, i_us) = timed(true)?;
        let (mc, mi) = (c.metrics(&x), i.metrics(&x));
        all.push(RunFigures {
            run: r
                .file_name()
                .map_or_else(|| r.display().to_string(), |n| n.to_string_lossy().into()),
            axes: mc
                .iter()
                .zip(&mi)
                .map(|(c, i)| [c.rmse, c.mte, i.rmse, i.mte])
                .collect(),
            us_per_sample: [c_us, i_us],
            evaluations: [c.evaluations_per_sample(), i.evaluations_per_sample()],
            sweeps: c.sweeps as f64 / t.len() as f64,
        });
    }
    print_figures(&g, &all);
    Ok(all)
}

fn print_figures(g: &FemGrid, all: &[RunFigures]) {
    println!("grid: {} ({} stacks)", g.source, g.axes());
    println!(
        "  {:<40} {:>4} {:>13} {:>12} {:>16} {:>15}",
        "run", "axis", "coupled RMSE", "coupled MTE", "independent RMSE", "independent MTE"
    );
    for f in all {
        for (i, a) in f.axes.iter().enumerate() {
            let name = if i == 0 { f.run.as_str() } else { "" };
            println!(
                "  {:<40} {:>4} {:>10.4} µm {:>9.4} µm {:>13.4} µm {:>12.4} µm",
                name, AXIS_NAMES[i], a[0], a[1], a[2], a[3]
            );
        }
        println!(
            "  {:<40} cost per sample: coupled {:.2} µs ({:.2} evaluations per stack, {:.2} sweeps), \
             independent {:.2} µs ({:.2} evaluations per stack)",
            "", f.us_per_sample[0], f.evaluations[0], f.sweeps, f.us_per_sample[1], f.evaluations[1]
        );
    }
}

/// `fpi axes refine`: every axis of `grid` corrected from measured runs of the
/// built stage (`t_s`, `voltage_V@…`, `force_N@…`, `x_fhps_um@…`), with the
/// stacks' models; each stack's model with its axis's `[fem_correction]` is
/// written to its `--out` (one per stack, in axis order). Prints the table and
/// returns the refinement.
pub fn refine(
    grid: &Path,
    model: &[PathBuf],
    runs: &[PathBuf],
    out: &[PathBuf],
) -> Result<crate::method::axes::refine::AxesRefinement> {
    use crate::method::axes::refine::{refine_models, AxesRun};
    let mut given: Vec<(&str, &Path)> = vec![("--grid", grid)];
    given.extend(model.iter().map(|m| ("--model", m.as_path())));
    given.extend(runs.iter().map(|r| ("--run", r.as_path())));
    for (k, o) in out.iter().enumerate() {
        not_an_input("--out", o, &given)?;
        if out[..k].contains(o) {
            bail!("--out {} is given twice: one file per stack", o.display());
        }
    }
    let g = FemGrid::read(grid)?;
    if out.len() != g.axes() {
        bail!(
            "--out: {} given for a grid of {} stacks; give one per stack (in the order {})",
            out.len(),
            g.axes(),
            record::names(g.axes())
        );
    }
    for o in out {
        output::prepare(o)?;
    }
    let (models, names) = models(model, g.axes())?;
    let data = runs
        .iter()
        .map(|r| {
            let (t, mut c) = read_axes(r, &["voltage_V", "force_N", "x_fhps_um"])?;
            let (x, f, u) = (c.remove(2), c.remove(1), c.remove(0));
            Ok(AxesRun {
                name: r.display().to_string(),
                t,
                u,
                f,
                x,
            })
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    let refs: Vec<&HostModel> = models.iter().collect();
    let start = Instant::now();
    let (refined, r) = refine_models(&refs, &names, &g, &data)?;
    let secs = start.elapsed().as_secs_f64();
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "grid {} refined on {} run(s) ({} rounds, {secs:.2} s):",
        grid.display(),
        data.len(),
        r.iterations
    );
    println!(
        "  {:<4} {:>13} {:>11} {:>15} {:>18} {:>17}  written to",
        "axis",
        "preload_scale",
        "stage_gain",
        "stage_offset_um",
        "RMSE before, µm",
        "RMSE after, µm"
    );
    for (i, (c, m)) in r.corrections.iter().zip(&refined).enumerate() {
        m.write(&out[i])?;
        println!(
            "  {:<4} {:>13.5} {:>11.5} {:>15.4} {:>18.4} {:>17.4}  {}",
            AXIS_NAMES[i],
            c.preload_scale,
            c.stage_gain,
            c.stage_offset_um,
            r.before[i].rmse,
            r.after[i].rmse,
            out[i].display()
        );
    }
    Ok(r)
}
