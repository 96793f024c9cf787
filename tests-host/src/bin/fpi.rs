//! `fpi`: the FPI-FFEM method (Actuators 2025, 14(8):411, Table 1) as a command-line tool.
//!
//! ```text
//! fpi calibrate [--kind KIND] --rig FILE.csv... --out MODEL.toml [--operators N]
//! fpi predict   --model MODEL.toml --fem FEM.csv --drive RUN.csv --out PRED.csv
//! fpi compare   --fem FEM.csv --runs RUN.csv... --model A.toml --model B.toml ... --out DIR
//! fpi invert    --model MODEL.toml --fem FEM.csv --target TARGET.csv --out DRIVE.csv
//! fpi export    --model MODEL.toml --fem FEM.csv --out FIRMWARE.toml
//! fpi demo      [--out DIR]
//! fpi bench
//! ```
//!
//! Run from `tests-host/` as `cargo run --release --bin fpi -- …`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use fpi_host::method::model::Kind;
use fpi_host::{cli, method::model::HostModel};

#[derive(Parser)]
#[command(
    name = "fpi",
    version,
    about = "The FPI-FFEM method: calibrate, predict, compare, invert, export"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Part I: identify a model from Voltage–Force–Displacement recordings.
    Calibrate {
        /// Model kind: fpi (the paper's), pi, ldpi, efpi (extended FPI), gpi (PI with an
        /// output map, no force). Default: efpi, or gpi for recordings without force.
        #[arg(long)]
        kind: Option<String>,
        /// Recordings `t_s,voltage_V,force_N,displacement_um` (CSV, .gz allowed), or
        /// the micromanipulator's `.dat`.
        #[arg(long, required = true, num_args = 1..)]
        rig: Vec<PathBuf>,
        /// Where to write the model.
        #[arg(long)]
        out: PathBuf,
        /// Play operators, including the `r = 0` one (default 10; gpi 21).
        #[arg(long)]
        operators: Option<usize>,
        /// Stack compliance for efpi, µm/N (default: the datasheet's 0.02).
        #[arg(long)]
        compliance: Option<f64>,
        /// Fit only rows A-B (1-based, inclusive) of a single recording.
        #[arg(long, value_parser = parse_rows)]
        rows: Option<(usize, usize)>,
    },
    /// Parts II–III: predict a stage from a model, its FEM tables and a drive.
    Predict {
        /// A calibrated model.
        #[arg(long)]
        model: PathBuf,
        /// FEM export `x_pea_um,preload_N,x_fhps_um`.
        #[arg(long)]
        fem: PathBuf,
        /// Drive `t_s,voltage_V` (other columns ignored).
        #[arg(long)]
        drive: PathBuf,
        /// Where to write `t_s,voltage_V,x_pea_um,preload_N,x_fhps_um`.
        #[arg(long)]
        out: PathBuf,
    },
    /// Score models against measured stage runs; report with tables and plots.
    Compare {
        /// FEM export of the stage.
        #[arg(long)]
        fem: PathBuf,
        /// Measured runs `t_s,voltage_V,…,x_fhps_um`.
        #[arg(long, required = true, num_args = 1..)]
        runs: Vec<PathBuf>,
        /// Models; the first is the baseline the MAE reductions refer to.
        #[arg(long, required = true)]
        model: Vec<PathBuf>,
        /// Output folder for report.md and the plots.
        #[arg(long)]
        out: PathBuf,
    },
    /// Offline feedforward: the voltage that makes the stage follow a target.
    Invert {
        /// A calibrated model.
        #[arg(long)]
        model: PathBuf,
        /// FEM export of the stage.
        #[arg(long)]
        fem: PathBuf,
        /// Target `t_s,x_fhps_um`.
        #[arg(long)]
        target: PathBuf,
        /// Where to write `t_s,voltage_V`.
        #[arg(long)]
        out: PathBuf,
        /// Highest voltage the amplifier may apply, V.
        #[arg(long, default_value_t = 150.0)]
        u_max: f64,
    },
    /// The fixed-point parameters and tables the firmware embeds.
    Export {
        /// A calibrated model (fpi, efpi or pi).
        #[arg(long)]
        model: PathBuf,
        /// FEM export of the stage.
        #[arg(long)]
        fem: PathBuf,
        /// Where to write the firmware model file (`firmware/model/*.toml`).
        #[arg(long)]
        out: PathBuf,
        /// Control ISR rate, Hz.
        #[arg(long, default_value_t = 20_000)]
        rate: u32,
        /// Highest amplifier voltage, V.
        #[arg(long, default_value_t = 150.0)]
        u_max: f64,
        /// Largest setpoint slew, V/ms.
        #[arg(long, default_value_t = 100.0)]
        slew: f64,
        /// Highest voltage of the reachable stroke the reference may ask for, V
        /// (default: the calibrated range of the model).
        #[arg(long)]
        stroke_voltage: Option<f64>,
    },
    /// The whole chain on the datasets the project carries, into a folder.
    Demo {
        /// Output folder.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
    },
    /// Throughput of the host model and the calibration (figures, not a test).
    Bench,
}

fn parse_rows(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once('-')
        .ok_or_else(|| format!("{s:?}: expected A-B, e.g. 3152-3351"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("{v:?} is not a row number"))
    };
    Ok((p(a)?, p(b)?))
}

fn main() -> ExitCode {
    fpi_host::cli::exit_quietly_on_broken_pipe();
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> Result<()> {
    match args.command {
        Command::Calibrate {
            kind,
            rig,
            out,
            operators,
            compliance,
            rows,
        } => {
            let kind = kind.as_deref().map(Kind::parse).transpose()?;
            cli::calibrate(kind, &rig, &out, operators, compliance, rows)
        }
        Command::Predict {
            model,
            fem,
            drive,
            out,
        } => cli::predict(&model, &fem, &drive, &out),
        Command::Compare {
            fem,
            runs,
            model,
            out,
        } => cli::compare(&fem, &runs, &model, &out),
        Command::Invert {
            model,
            fem,
            target,
            out,
            u_max,
        } => cli::invert(&model, &fem, &target, &out, u_max),
        Command::Export {
            model,
            fem,
            out,
            rate,
            u_max,
            slew,
            stroke_voltage,
        } => {
            let m = HostModel::read(&model)?;
            cli::export(&m, &model, &fem, &out, rate, u_max, slew, stroke_voltage)
        }
        Command::Demo { out } => cli::demo(&out).context("demo"),
        Command::Bench => cli::bench(),
    }
}
