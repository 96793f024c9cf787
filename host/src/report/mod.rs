//! The Markdown report of a comparison, with SVG plots: the paper's Table 4 (MAE
//! of every method on every run and its reduction against the first), Fig. 16
//! (measured and predicted loops of the stage), the error curves, and Figs. 12–13
//! (the predicted stack loop on the preload–voltage surface, and its projection).

pub mod closed_loop;
pub mod demo;
pub mod identify;
pub mod plots;

use std::collections::HashSet;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::{bail, Result};

use crate::data::fem::FemMaps;
use crate::method::compare::Comparison;
use crate::method::model::HostModel;
use crate::method::predict::Prediction;

/// The stack's hysteresis loops at constant preloads (the FPI surface of the
/// paper's Fig. 5b/12): for each preload, `u` from 0 to `u_top` and back.
pub fn surface_family(
    model: &HostModel,
    preloads: &[f64],
    u_top: f64,
    f_ref: f64,
) -> Vec<(f64, Vec<(f64, f64)>)> {
    let n = 200;
    preloads
        .iter()
        .map(|&f| {
            let m = model.model();
            let mut st = m.state(1e-3);
            let pts = (0..=2 * n)
                .map(|k| {
                    let u = u_top
                        * if k <= n {
                            k as f64 / n as f64
                        } else {
                            (2 * n - k) as f64 / n as f64
                        };
                    (u, m.step(&mut st, u, f, f_ref))
                })
                .collect();
            (f, pts)
        })
        .collect()
}

/// Markdown table of a comparison: per run, MAE / RMSE / MTE and the MAE
/// reduction against the first model.
pub fn table(c: &Comparison) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| method | model | run | MAE (µm) | RMSE (µm) | MTE (µm) | MAE reduction vs {} |",
        c.models[0].1.kind.method()
    );
    let _ = writeln!(s, "|---|---|---|---:|---:|---:|---:|");
    for (m, (name, model)) in c.models.iter().enumerate() {
        for r in 0..c.runs.len() {
            let x = &c.scores[r][m].metrics;
            let (red, note) = c.row_cells(r, m);
            let in_sample = note.map_or(String::new(), |n| format!(" {n}"));
            let _ = writeln!(
                s,
                "| {} | `{}` | {}{in_sample} | {:.3} | {:.3} | {:.3} | {} |",
                model.kind.method(),
                name,
                c.run_name(r),
                x.mae,
                x.rmse,
                x.mte,
                red
            );
        }
    }
    s
}

/// The paper's Table 4 layout: methods as rows, the runs' MAE as columns.
pub fn table4(c: &Comparison) -> String {
    let mut s = String::from("| Method |");
    for r in 0..c.runs.len() {
        let _ = write!(s, " MAE, {} (µm) |", c.run_name(r));
    }
    s.push_str("\n|---|");
    for _ in 0..c.runs.len() {
        s.push_str("---:|");
    }
    s.push('\n');
    for (m, (_, model)) in c.models.iter().enumerate() {
        let _ = write!(s, "| {} |", model.kind.method());
        for r in 0..c.runs.len() {
            let _ = write!(s, " {:.3} |", c.scores[r][m].metrics.mae);
        }
        s.push('\n');
    }
    s
}

/// Whether [`write()`] writes a file of this name into its folder (`report.md` and
/// the `.svg` plots), for [`crate::output::folder_spares_inputs`].
pub fn writes(name: &str) -> bool {
    name == "report.md" || name.ends_with(".svg")
}

/// Refuses a plot file name used before in this report (two inputs named alike
/// would otherwise overwrite each other's plots).
fn claim(written: &mut HashSet<String>, file: &str) -> Result<()> {
    if !written.insert(file.to_string()) {
        bail!(
            "two plots of the report would be named {file}: give the runs or the models \
             different file names"
        );
    }
    Ok(())
}

/// Writes the plots of a comparison into `out` (created if missing; every file
/// atomically); returns Markdown that shows them.
pub fn figures(c: &Comparison, fem: &FemMaps, out: &Path) -> Result<String> {
    crate::output::prepare_folder(out)?;
    let mut md = String::new();
    let mut written = HashSet::new();
    for r in 0..c.runs.len() {
        run_figures(c, r, out, &mut md, &mut written)?;
        for ((name, m), s) in c.models.iter().zip(&c.scores[r]) {
            // The models whose effective voltage the preload moves: the FPI surface.
            if m.kind.uses_force() && m.kind.coupled() {
                let to = (out, &mut md, &mut written);
                stack_figures(c, r, (name, m), &s.prediction, fem, to)?;
            }
        }
    }
    Ok(md)
}

/// Fig. 16 and the error curves of run `r`: every model's prediction against the
/// measured stage output.
fn run_figures(
    c: &Comparison,
    r: usize,
    out: &Path,
    md: &mut String,
    written: &mut HashSet<String>,
) -> Result<()> {
    let run = &c.runs[r];
    let name = c.run_name(r);
    let stem = name.trim_end_matches(".csv");
    let predictions = c.models.iter().zip(&c.scores[r]);
    let series: Vec<(&str, &[f64])> = predictions
        .clone()
        .map(|((_, m), s)| (m.kind.method(), s.prediction.x_fhps.as_slice()))
        .collect();
    let f = format!("loops_{stem}.svg");
    claim(written, &f)?;
    plots::loops(
        &out.join(&f),
        &format!("Stage output vs voltage, {stem} (Fig. 16)"),
        "voltage (V)",
        "stage output x_fhps (µm)",
        &run.u,
        Some(&run.x),
        &series,
    )?;
    let _ = writeln!(md, "![loops {name}]({f})\n");
    let errors: Vec<Vec<f64>> = predictions
        .clone()
        .map(|(_, s)| {
            s.prediction
                .x_fhps
                .iter()
                .zip(&run.x)
                .map(|(p, q)| p - q)
                .collect()
        })
        .collect();
    let es: Vec<(&str, &[f64])> = series
        .iter()
        .zip(&errors)
        .map(|((n, _), e)| (*n, e.as_slice()))
        .collect();
    let f = format!("errors_{stem}.svg");
    claim(written, &f)?;
    plots::curves(
        &out.join(&f),
        &format!("Prediction error, {stem}"),
        "error (µm)",
        &run.t,
        &es,
    )?;
    let _ = writeln!(md, "![errors {name}]({f})\n");
    Ok(())
}

/// Figs. 12–13 of one FPI model on run `r`: the predicted stack loop on the
/// preload–voltage surface, and on its own.
fn stack_figures(
    c: &Comparison,
    r: usize,
    (mname, m): (&str, &HostModel),
    p: &Prediction,
    fem: &FemMaps,
    (out, md, written): (&Path, &mut String, &mut HashSet<String>),
) -> Result<()> {
    let name = c.run_name(r);
    let stem = name.trim_end_matches(".csv");
    let (f_lo, f_hi) = p
        .preload
        .iter()
        .fold((f64::MAX, f64::MIN), |a, &v| (a.0.min(v), a.1.max(v)));
    let u_top = c.runs[r].u.iter().cloned().fold(0.0, f64::max);
    let preloads: Vec<f64> = (0..6)
        .map(|k| (f_lo - 10.0) + (f_hi - f_lo + 20.0) * k as f64 / 5.0)
        .collect();
    let family = surface_family(m, &preloads, u_top, fem.rest_preload());
    let path3d: Vec<(f64, f64, f64)> = (0..p.u.len())
        .map(|k| (p.u[k], p.preload[k], p.x_pea[k]))
        .collect();
    let method = m.kind.method();
    let f = format!("surface_{stem}_{mname}.svg");
    claim(written, &f)?;
    plots::surface(
        &out.join(&f),
        &format!("{method}, {stem}: stack loop on the preload surface (Fig. 12)"),
        &family,
        &path3d,
    )?;
    let _ = writeln!(md, "![surface {name} {mname}]({f})\n");
    let f = format!("stack_{stem}_{mname}.svg");
    claim(written, &f)?;
    plots::loops(
        &out.join(&f),
        &format!("{method}, {stem}: predicted stack loop (Fig. 13)"),
        "voltage (V)",
        "stack extension x_pea (µm)",
        &p.u,
        None,
        &[(method, p.x_pea.as_slice())],
    )?;
    let _ = writeln!(md, "![stack loop {name} {mname}]({f})\n");
    Ok(())
}

/// Writes `report.md` and its plots into `out` (`fpi compare`), every file
/// atomically ([`crate::output::write_atomic`]).
pub fn write(c: &Comparison, fem: &FemMaps, out: &Path) -> Result<()> {
    let mut md = String::from("# Stage prediction: measured vs predicted\n\n");
    let _ = writeln!(md, "FEM maps: `{}`.\n", fem.source);
    let _ = writeln!(
        md,
        "## MAE by method (Actuators 2025, 14(8):411, Table 4)\n\n{}",
        table4(c)
    );
    let _ = writeln!(md, "## All figures\n\n{}", table(c));
    let held = crate::method::compare::held_out_summary(c);
    if !held.is_empty() {
        let _ = writeln!(
            md,
            "## Held-out runs (refined models scored where they were not refined)\n\n```\n{}\n```\n",
            held.join("\n")
        );
    }
    md.push_str("\n## Figures\n\n");
    md.push_str(&figures(c, fem, out)?);
    crate::output::write_atomic(&out.join("report.md"), md.as_bytes())
}
