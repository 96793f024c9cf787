//! `fpi`: the FPI-FFEM method (Actuators 2025, 14(8):411, Table 1) as a command-line tool.
//!
//! ```text
//! fpi calibrate [--kind KIND] --rig FILE.csv... --out MODEL.toml [--operators N]
//! fpi predict   --model MODEL.toml --fem FEM.csv --drive RUN.csv --out PRED.csv
//! fpi compare   --fem FEM.csv --runs RUN.csv... --model A.toml --model B.toml ... --out DIR
//! fpi invert    --model MODEL.toml --fem FEM.csv --target TARGET.csv --out DRIVE.csv
//! fpi refine    --model MODEL.toml --fem FEM.csv --run RUN.csv... --out REFINED.toml
//! fpi export    --model MODEL.toml --fem FEM.csv [--dynamics DYN.toml] --out FIRMWARE.toml
//! fpi tune      --firmware FIRMWARE.toml [--dynamics DYN.toml | --frf FRF.csv [--accept-misfit]] --out TUNED.toml
//! fpi demo      [--out DIR]
//! fpi bench
//! fpi identify  --chirp FILE.csv... --out DYN.toml [--plots DIR] [--min-hz F]
//! fpi axes grid --stage xy|xyz --out GRID.csv | record --stage xy-built --drive D.csv --out R.csv
//!               predict --grid GRID.csv --model M.toml… --drive D.csv --out P.csv [--independent]
//!               compare --grid GRID.csv --model M.toml… --runs R.csv…
//! fpi lever     [--params LEVER.toml] --out FEM.csv [--points N] [--stroke-um S] [--output arc|deg]
//! fpi board emulate [--listen 127.0.0.1:PORT]
//! fpi board --port PORT status | move UM | wave … | stream FILE.csv | record --seconds S --out FILE.csv
//!                       load MODEL.toml [--fem FEM.csv] | safe | clear-fault | hold | analog | drive … | supervise MS
//! ```
//!
//! Run from `tests-host/` (where the datasets are `data/…`) as `cargo fpi …`, the
//! alias of `cargo run --release -p fpi-host --bin fpi -- …`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use fpi_host::data::Num;
use fpi_host::method::model::Kind;
use fpi_host::{cli, method::model::HostModel};

#[derive(Parser)]
#[command(
    name = "fpi",
    version,
    about = "The FPI-FFEM method (calibrate, predict, compare, invert, refine, export) and the board"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Part I: identify a model from Voltage–Force–Displacement recordings.
    Calibrate {
        /// Model kind: fpi (the paper's), pi, ldpi, efpi (extended FPI), epi (extended
        /// model without force), gpi (PI with an output map, no force), branch (the second
        /// paper's branch polynomials, eqs. 6–7). Default: efpi, or epi for recordings
        /// without force.
        ///
        /// When to use which: efpi for a stage you will run (the most accurate, and the
        /// firmware runs it); epi for recordings without force; fpi, pi and ldpi to
        /// reproduce the first paper's comparison; branch to compare with the second
        /// paper's hysteresis model (host only: `fpi export` and `fpi invert` do not
        /// take it; it fits the rig better than fpi with 7 coefficients, but predicts
        /// a stage no better, its force coupling being the FPI's).
        #[arg(long)]
        kind: Option<String>,
        /// Recordings `t_s,voltage_V,force_N,displacement_um` (CSV, .gz allowed), or
        /// the micromanipulator's `.dat`.
        #[arg(long, required = true, num_args = 1..)]
        rig: Vec<PathBuf>,
        /// Where to write the model.
        #[arg(long)]
        out: PathBuf,
        /// Play operators, including the `r = 0` one (default 10; gpi 21; 1..=32).
        #[arg(long, value_parser = parse_operators)]
        operators: Option<usize>,
        /// Stack compliance for efpi, µm/N, 0–0.5 (default: the datasheet's 0.02).
        #[arg(long, value_parser = parse_compliance, allow_negative_numbers = true)]
        compliance: Option<f64>,
        /// Fit only rows A-B (1-based, inclusive) of a single recording (at least
        /// 20 rows).
        #[arg(long, value_parser = parse_rows)]
        rows: Option<(usize, usize)>,
        /// Calibrate stack x, y or z of recordings of a stage of several axes
        /// (`fpi axes record`: its `voltage_V@…`, `force_N@…` and `x_pea_um@…`).
        #[arg(long, value_parser = parse_axis)]
        axis: Option<u8>,
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
        /// Identified dynamics (`fpi identify`): the prediction then runs through
        /// them (x_fhps_um rate-dependent; x_fhps_static_um added).
        #[arg(long)]
        dynamics: Option<PathBuf>,
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
        /// Identified dynamics (`fpi identify`): every model is also scored
        /// followed by them (as MODEL+dyn).
        #[arg(long)]
        dynamics: Option<PathBuf>,
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
        /// Highest voltage the amplifier may apply, V (0 < U_MAX ≤ 150, the board's
        /// amplifier span).
        #[arg(long, default_value_t = 150.0, value_parser = parse_amplifier_volts,
              allow_negative_numbers = true)]
        u_max: f64,
    },
    /// Design the board's loops for a stated robustness, offline.
    ///
    /// Active damping of the stage's first mode from the force sensor, the
    /// position PI around the damped stage and the feedforward that inverts it,
    /// from the identified dynamics (if given; else the PI alone, slow), written
    /// into the firmware model (its `[dynamics]`, `[damping]`, `[feedback]` and
    /// `[shaping]` sections), which `fpi board load` sends.
    Tune {
        /// A firmware model file (from `fpi export`).
        #[arg(long)]
        firmware: PathBuf,
        /// Identified dynamics (`fpi identify`).
        #[arg(long)]
        dynamics: Option<PathBuf>,
        /// A frequency response measured through the board (`fpi board frf`),
        /// instead of --dynamics: the dynamics and κ are fitted to it.
        #[arg(long, conflicts_with = "dynamics")]
        frf: Option<PathBuf>,
        /// With --frf: write the model even if the response was measured with
        /// the loops acting (damping on, loop closed) or the fitted plant misses
        /// it by more than a fit of the stage's own response leaves (30 %
        /// position, 60 % force, RMS); a warning says so.
        #[arg(long, requires = "frf")]
        accept_misfit: bool,
        #[command(flatten)]
        loops: TuneArgs,
        /// Where to write the tuned firmware model.
        #[arg(long)]
        out: PathBuf,
    },
    /// Refine a stage's FEM tables from measured runs of the built stage.
    ///
    /// The gain and offset of its output f_K and the scale of its preload f_F,
    /// stored in the model file (the actuator's parameters are kept).
    Refine {
        /// A calibrated model.
        #[arg(long)]
        model: PathBuf,
        /// FEM export of the stage `x_pea_um,preload_N,x_fhps_um`.
        #[arg(long)]
        fem: PathBuf,
        /// Measured runs of the built stage `t_s,voltage_V,force_N,x_fhps_um`.
        #[arg(long = "run", visible_alias = "runs", required = true, num_args = 1..)]
        runs: Vec<PathBuf>,
        /// Where to write the refined model (the model with a [fem_correction]).
        #[arg(long)]
        out: PathBuf,
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
        #[command(flatten)]
        settings: LoopArgs,
        /// Identified dynamics (`fpi identify`): the firmware shapes the reference
        /// with the inverse of the stage's lightly damped modes.
        #[arg(long)]
        dynamics: Option<PathBuf>,
        /// With --dynamics: the damping ratio the compensated modes get.
        #[arg(long, default_value_t = fpi_host::method::shaping::DAMPING, allow_negative_numbers = true)]
        damping: f64,
        /// With --dynamics: how much faster than each mode the compensated pair is.
        #[arg(long, default_value_t = fpi_host::method::shaping::SPEED_UP, allow_negative_numbers = true)]
        speed_up: f64,
        /// With --dynamics: the amplifier's output current limit, mA; the slew is
        /// then held to I_max / C (C from the dynamics).
        #[arg(long, allow_negative_numbers = true)]
        current_limit_ma: Option<f64>,
    },
    /// The whole chain on the datasets the project carries, into a folder.
    Demo {
        /// Output folder.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
    },
    /// Throughput of the host model and the calibration (figures, not a test).
    Bench,
    /// Watch the board live in the browser: a scope of its recorder.
    ///
    /// Serves a local page (nothing from the internet) showing the board's
    /// recorder as it streams: roll mode, a trigger on any channel, pause and
    /// zoom, per-channel scale, a spectrum, an X–Y view (the hysteresis loop),
    /// export to CSV and PNG. Every sample reaches the page; gaps are counted
    /// and shown. To drive the board meanwhile from the CLI or Python, serve it
    /// first (`fpi board serve`) and point the scope and the others at the
    /// served port. Runs until stopped (Ctrl-C).
    Scope {
        /// The board's port: a serial device, tcp:HOST:PORT (the emulated board
        /// or `fpi board serve`).
        #[arg(long, env = "FPI_BOARD")]
        port: String,
        /// Where the page is served: HOST:PORT (port 0: any free one).
        #[arg(long, default_value = "127.0.0.1:4610", value_parser = parse_listen_any)]
        listen: String,
        /// The signals to stream, by their recording column (x_ref_um,
        /// x_est_um, x_fhps_um, x_sensor_um, voltage_V, force_N, status,
        /// trigger); default: every one but trigger.
        #[arg(long, value_delimiter = ',')]
        signals: Vec<String>,
        /// Keep one tick in this many (default: every tick where the link
        /// carries it, else the fewest ticks it does).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        decimation: Option<u16>,
    },
    /// The stage's linear dynamics from chirps (voltage → x_fhps_um).
    ///
    /// Frequency response, rational transfer function, voltage-dependent gain,
    /// capacitance.
    Identify {
        /// Chirp recordings `t_s,voltage_V,x_fhps_um[,current_mA]` (CSV, .gz allowed).
        #[arg(long = "chirp", required = true, num_args = 1..)]
        chirps: Vec<PathBuf>,
        /// Where to write the dynamics (DYN.toml).
        #[arg(long)]
        out: PathBuf,
        /// Folder for the Bode figure (bode.svg).
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Lowest frequency of the transfer-function fit, Hz (> 0): below it the
        /// response is hysteresis and creep, which the FPI model holds.
        #[arg(long, default_value_t = fpi_host::method::identify::MIN_DYNAMICS_HZ,
              value_parser = parse_positive, allow_negative_numbers = true)]
        min_hz: f64,
    },
    /// An analytic stage: the second paper's three-stage lever as an FEM table.
    ///
    /// Eqs. 8–12 and Table 5 of the second paper, written as
    /// `x_pea_um,preload_N,x_fhps_um`.
    Lever {
        /// Lever parameters (TOML: [geometry], [output], [load]; default Table 5).
        #[arg(long)]
        params: Option<PathBuf>,
        /// Where to write the table.
        #[arg(long)]
        out: PathBuf,
        /// Table points (2..=10001).
        #[arg(long, default_value_t = fpi_host::method::lever::DEFAULT_POINTS)]
        points: usize,
        /// Stack stroke the table covers, µm (> 0).
        #[arg(long, default_value_t = fpi_host::method::lever::PAPER_STACK_UM,
              value_parser = parse_positive, allow_negative_numbers = true)]
        stroke_um: f64,
        /// The x_fhps_um column: arc (µm of arc at [output] radius_mm) or deg.
        #[arg(long, value_enum, default_value = "arc")]
        output: fpi_host::method::lever::OutputUnit,
    },
    /// Stages of several axes (XY, XYZ): FEM grids, the virtual stage, the
    /// coupled prediction against independent axes.
    Axes {
        #[command(subcommand)]
        command: AxesCommand,
    },
    /// Print one of the book's generated reference pages (Markdown).
    #[command(hide = true)]
    Reference {
        /// settings (the board's runtime settings), model (the model file's keys),
        /// cli (every command) or protocol (the link's messages).
        #[arg(value_enum)]
        page: ReferencePage,
    },
    /// A driver board (or the emulated board) over its command link.
    Board {
        /// The board's port: a serial device (/dev/ttyUSB0, COM3) or tcp:HOST:PORT
        /// (the emulated board). Not needed by `emulate`.
        #[arg(long, global = true, env = "FPI_BOARD")]
        port: Option<String>,
        /// The axis a per-axis command addresses on a board of several axes:
        /// x, y or z (a board refuses an axis it does not have); x if not
        /// given (`autotune` without it tunes every axis of a board of
        /// several).
        #[arg(long, global = true, value_parser = parse_axis)]
        axis: Option<u8>,
        #[command(subcommand)]
        command: BoardCommand,
    },
}

#[derive(Subcommand)]
enum AxesCommand {
    /// The FEM grid of a stage's design: the preload on every stack and the
    /// output of every axis over all the stacks' extensions.
    Grid {
        /// xy or xyz.
        #[arg(long, value_enum)]
        stage: fpi_host::cli::axes::Design,
        /// Keep every N-th of stage A's FEM points per stack (default 1 for xy,
        /// 4 for xyz: 49² and 13³ points).
        #[arg(long)]
        every: Option<usize>,
        /// Where to write `x_pea_um@x,…,preload_N@x,…,x_fhps_um@x,…` (CSV).
        #[arg(long)]
        out: PathBuf,
    },
    /// The board's decoupling for a stage's FEM grid: its cross gains, the
    /// output matrix (I + C)⁻¹ that takes them out of the commands, and the
    /// stacks' preload coupling.
    Decoupling {
        /// The stage's FEM grid (`fpi axes grid`).
        #[arg(long)]
        grid: PathBuf,
    },
    /// Record a virtual XY or XYZ stage under a drive (open loop).
    Record {
        /// xy or xyz (nominal twins: only the stacks differ from the FEM design),
        /// xy-built or xyz-built (the prototypes, which differ as stage A's does),
        /// or a variant file naming one as its base (`[x]`, `[y]`, `[z]`,
        /// `coupling_scale`, `sensor_crosstalk`).
        #[arg(long)]
        stage: String,
        /// Drive `t_s,voltage_V@x,voltage_V@y[,voltage_V@z]` at 20 kHz.
        #[arg(long)]
        drive: PathBuf,
        /// Where to write `t_s` and per axis `voltage_V`, `force_N`, `x_pea_um`,
        /// `x_fhps_um` (true) and `x_sensed_um` (`…@x`, `…@y`).
        #[arg(long)]
        out: PathBuf,
        /// Seed of the sensors' noise.
        #[arg(long, default_value_t = 1)]
        seed: u32,
    },
    /// Predict every axis from the stacks' models and the stage's FEM grid, the
    /// coupled equation solved for all stacks at each sample.
    Predict {
        /// The stage's FEM grid (`fpi axes grid`).
        #[arg(long)]
        grid: PathBuf,
        /// Calibrated models: one for every stack, or one per stack in axis order.
        #[arg(long, required = true, num_args = 1..)]
        model: Vec<PathBuf>,
        /// Drive `t_s,voltage_V@x,voltage_V@y[,voltage_V@z]`.
        #[arg(long)]
        drive: PathBuf,
        /// Where to write `t_s` and per axis `voltage_V`, `x_pea_um`, `preload_N`,
        /// `x_fhps_um`.
        #[arg(long)]
        out: PathBuf,
        /// Predict each axis alone from its own tables (a one-axis method).
        #[arg(long)]
        independent: bool,
    },
    /// Score the coupled prediction and independent axes on recordings of every
    /// axis (`x_fhps_um@…`), with their cost per sample.
    Compare {
        /// The stage's FEM grid.
        #[arg(long)]
        grid: PathBuf,
        /// Calibrated models: one for every stack, or one per stack in axis order.
        #[arg(long, required = true, num_args = 1..)]
        model: Vec<PathBuf>,
        /// Recordings (`fpi axes record`).
        #[arg(long, required = true, num_args = 1..)]
        runs: Vec<PathBuf>,
    },
    /// Correct the grid for the built stage, axis by axis, from measured runs:
    /// the preload on each stack and the gain and offset of each axis's output
    /// (`fpi refine` for several axes, with the coupled prediction).
    Refine {
        /// The stage's FEM grid.
        #[arg(long)]
        grid: PathBuf,
        /// Calibrated models: one for every stack, or one per stack in axis order.
        #[arg(long, required = true, num_args = 1..)]
        model: Vec<PathBuf>,
        /// Measured runs of the built stage (`t_s`, and per axis `voltage_V`,
        /// `force_N`, `x_fhps_um`: `…@x`, `…@y`).
        #[arg(long = "run", required = true, num_args = 1..)]
        runs: Vec<PathBuf>,
        /// Where to write each stack's refined model (its model with its axis's
        /// [fem_correction]): one per stack, in axis order.
        #[arg(long, required = true, num_args = 1..)]
        out: Vec<PathBuf>,
    },
}

/// The book's generated reference pages.
#[derive(Clone, Copy, clap::ValueEnum)]
enum ReferencePage {
    /// The board's runtime settings, from their declaration.
    Settings,
    /// The firmware model file's keys, from their declaration.
    Model,
    /// Every `fpi` command and option, from the command line's declaration.
    Cli,
    /// The link's messages, from the protocol crate's declaration.
    Protocol,
}

/// The reference `page`, Markdown.
fn reference(page: ReferencePage) -> Result<String> {
    Ok(match page {
        ReferencePage::Settings => fpi_host::board::settings::reference(),
        ReferencePage::Model => fpi_host::method::keys::reference(),
        ReferencePage::Protocol => {
            fpi_host::board::protocol_page::reference().map_err(anyhow::Error::msg)?
        }
        ReferencePage::Cli => {
            let options = clap_markdown::MarkdownOptions::new()
                .title("The fpi command line".into())
                .show_footer(false)
                .show_table_of_contents(true);
            let page = clap_markdown::help_markdown_custom::<Args>(&options);
            format!(
                "<!-- Generated by `fpi reference cli` from the command line's \
                 declaration; a test fails when they differ. -->\n\n{page}"
            )
        }
    })
}

/// The loop settings of an exported model (`fpi export`, `fpi board load`).
#[derive(clap::Args)]
struct LoopArgs {
    /// Control ISR rate, Hz (100..=200000).
    #[arg(long, default_value_t = 20_000,
          value_parser = clap::value_parser!(u32).range(100..=200_000))]
    rate: u32,
    /// Highest amplifier voltage, V (0 < U_MAX ≤ 150, the board's amplifier span).
    #[arg(long, default_value_t = 150.0, value_parser = parse_amplifier_volts,
          allow_negative_numbers = true)]
    u_max: f64,
    /// Largest setpoint slew, V/ms (0 < SLEW ≤ 100, the amplifier's).
    #[arg(long, default_value_t = 100.0, value_parser = parse_slew,
          allow_negative_numbers = true)]
    slew: f64,
    /// Highest voltage of the reachable stroke the reference may ask for, V
    /// (0 < V ≤ --u-max; default: the calibrated range of the model).
    #[arg(long, value_parser = parse_amplifier_volts, allow_negative_numbers = true)]
    stroke_voltage: Option<f64>,
}

impl LoopArgs {
    fn options(&self) -> fpi_host::method::export::ExportOptions {
        fpi_host::method::export::ExportOptions {
            rate_hz: self.rate,
            u_max: self.u_max,
            slew: self.slew,
            stroke_voltage: self.stroke_voltage,
        }
    }
}

#[derive(Subcommand)]
enum BoardCommand {
    /// Run the emulated board until stopped; its link listens on a TCP port.
    ///
    /// QEMU runs the firmware and its virtual stage.
    Emulate {
        /// Where the link listens: HOST:PORT.
        #[arg(long, default_value = "127.0.0.1:4545", value_parser = parse_listen)]
        listen: String,
        /// The link whose rate (in board time) the emulated board paces its own
        /// at: `uart` (115 200 Bd, 11 520 B/s) or `usb` (full-speed CDC, 800 kB/s,
        /// 1 ms latency). QEMU's bridged USART carries what its host allows on
        /// top of that.
        #[arg(long, default_value = "usb", value_parser = parse_link)]
        link: fpi_protocol::LinkKind,
        /// The analog front end it converts with: `internal` (the STM32's 12-bit
        /// ADC and DAC) or `precision` (AD7606 16-bit ADC, AD5791 20-bit DAC, with
        /// the ADC's transition noise). A reset returns to `internal`.
        #[arg(long, default_value = "internal", value_parser = parse_front_end)]
        frontend: fpi_protocol::FrontEndKind,
        /// The firmware image QEMU runs (default: the emulated board's
        /// firmware, `fpi-firmware` with --features qemu, built if needed).
        #[arg(long, value_name = "ELF")]
        firmware: Option<PathBuf>,
        /// Its axes: 1 (stage A) or 2 (the XY stage as designed; a board of
        /// several axes takes no bench order but the link's pace, and has the
        /// internal front end). Three axes run in-process (--port virtual:xyz):
        /// they do not fit QEMU's memory.
        #[arg(long, default_value_t = 1)]
        axes: u8,
    },
    /// Serve the board to several local clients at once on a TCP port.
    ///
    /// This process owns the board's link (--port); the CLI, Python and a scope
    /// connect to the port as to a board (--port tcp:HOST:PORT) and are served
    /// in turn, a request at a time. The client that started the running
    /// motion holds it: the others' motion commands are refused naming the
    /// holder (hold and safe never are). Every client may record at once, each
    /// at its own decimation. Runs until stopped (Ctrl-C).
    Serve {
        /// Where the clients connect: HOST:PORT.
        #[arg(long, default_value = "127.0.0.1:4600", value_parser = parse_listen)]
        listen: String,
    },
    /// The board, its model and the loop's state.
    Status,
    /// What the board has: axes, analog front end, link, protocol, capacity and
    /// limits, the features its running model gives it, the commands it takes
    /// and the runtime settings it has.
    Info,
    /// Ramp to a position and hold it.
    Move {
        /// Target of the addressed axis (--axis), µm.
        #[arg(value_parser = parse_finite, allow_negative_numbers = true,
              required_unless_present_any = ["x", "y", "z"], conflicts_with_all = ["x", "y", "z"])]
        um: Option<f64>,
        /// X's target, µm: with --y and --z, the axes named move from the
        /// same tick (a board of several axes).
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        x: Option<f64>,
        /// Y's target, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        y: Option<f64>,
        /// Z's target, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        z: Option<f64>,
        /// Speed, µm/s (> 0).
        #[arg(long, default_value_t = 1000.0, value_parser = parse_positive,
              allow_negative_numbers = true)]
        speed: f64,
        /// Record every tick of the move into this CSV (the columns of `fpi
        /// board record`, the true position `x_fhps_um` on the emulated
        /// board), from the tick the board takes it until it holds the target
        /// and 50 ms more; the command then returns when the move has ended.
        /// Needs a link that carries every tick (USB).
        #[arg(long, value_name = "OUT.csv")]
        record: Option<PathBuf>,
    },
    /// Run the waveform generator.
    Wave {
        /// sine, triangle or cosine (a raised cosine from the bottom of the swing).
        #[arg(long, default_value = "sine")]
        shape: String,
        /// Half-swing, µm (> 0).
        #[arg(long, value_parser = parse_positive, allow_negative_numbers = true)]
        amplitude_um: f64,
        /// Mid-point, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        offset_um: f64,
        /// Frequency, Hz (> 0).
        #[arg(long, value_parser = parse_positive, allow_negative_numbers = true)]
        freq_hz: f64,
        /// Periods to run (default: until another command).
        #[arg(long, default_value_t = 0)]
        cycles: u32,
        /// Record every tick of the wave (its approach included) into this CSV
        /// (the columns of `fpi board record`, the true position `x_fhps_um`
        /// on the emulated board): for --seconds, or until a wave of --cycles
        /// has ended and 50 ms more. Needs a link that carries every tick (USB).
        #[arg(long, value_name = "OUT.csv")]
        record: Option<PathBuf>,
        /// With --record: board time to record from the wave's start, s
        /// (0 < S ≤ 3600; needed for a wave without --cycles).
        #[arg(long, requires = "record", value_parser = parse_record_seconds,
              allow_negative_numbers = true)]
        seconds: Option<f64>,
    },
    /// Stream a trajectory: column `x_ref_um` of a CSV.
    ///
    /// One point every `--interval` control ticks, interpolated.
    Stream {
        /// The trajectory.
        file: PathBuf,
        /// Control ticks per point (20 = 1 kHz at 20 kHz; ≥ 1).
        #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u16).range(1..))]
        interval: u16,
        /// Record every tick of the stream into this CSV (the columns of `fpi
        /// board record`, the true position `x_fhps_um` on the emulated
        /// board), until the board holds its last point and 50 ms more. Needs
        /// a link that carries every tick (USB).
        #[arg(long, value_name = "OUT.csv")]
        record: Option<PathBuf>,
    },
    /// Record what the stage does into a CSV (the datasets' columns).
    Record {
        /// Board time to record, s (0 < S ≤ 3600). Without it, it records
        /// until stopped (Ctrl-C or SIGTERM), writing the CSV as it comes.
        #[arg(long, value_parser = parse_record_seconds, allow_negative_numbers = true)]
        seconds: Option<f64>,
        /// Where to write it.
        #[arg(long)]
        out: PathBuf,
        /// Keep one tick in this many (≥ 1).
        #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u16).range(1..))]
        decimation: u16,
        /// The signals to record, by their column (x_ref_um, x_fhps_um,
        /// voltage_V, force_N, x_est_um, status, x_sensor_um, trigger);
        /// default: every one but trigger.
        #[arg(long, value_delimiter = ',')]
        signals: Vec<String>,
    },
    /// Load a model into the board.
    ///
    /// A calibrated model with the stage's FEM tables (as `fpi export` takes
    /// them), or a firmware model file.
    Load {
        /// The model.
        model: PathBuf,
        /// FEM export of the stage (for a calibrated model).
        #[arg(long)]
        fem: Option<PathBuf>,
        /// Keep it in the board's flash (it survives a reset).
        #[arg(long)]
        store: bool,
        /// Then measure the stage's mode (a 0.1 µm sweep around the model's,
        /// loops open) and start the learned mass ratio at what it implies: a
        /// tuning loaded onto a heavier or lighter stage (a payload, another
        /// stage of the design) makes its first step at the stage's mass.
        #[arg(long)]
        match_mass: bool,
        #[command(flatten)]
        settings: LoopArgs,
    },
    /// Forget the stored model and run the factory default.
    Factory,
    /// Park the stage: ramp to the safe voltage, amplifier off.
    Safe,
    /// Clear a latched fault (the stage stays parked until the next motion).
    ClearFault,
    /// Stop the reference where it is.
    Hold,
    /// Follow the analog reference input.
    Analog,
    /// Compensated (inverse FPI) or uncompensated (straight line) drive.
    Drive {
        /// compensated or uncompensated.
        mode: String,
    },
    /// Read a runtime setting by key (every setting without one).
    ///
    /// Keys and values are in the book's reference (runtime settings):
    /// `fpi board get stage/0/damping`.
    Get {
        /// The key path, e.g. stage/0/loop_mode (dots or slashes).
        key: Option<String>,
    },
    /// Change a runtime setting by key, as its named command would.
    ///
    /// `fpi board set stage/0/damping off` is `fpi board damping off`, with the
    /// same checks.
    Set {
        /// The key path, e.g. stage/0/loop_mode (dots or slashes).
        key: String,
        /// The value: JSON, or as typed (on, off, closed, 500).
        value: String,
    },
    /// Park the stage if the host is silent this long while it drives the stage
    /// (0: off).
    Supervise {
        /// Timeout, ms.
        ms: u32,
    },
    /// Reset the board (it starts parked, with its stored model).
    Reset,
    /// The emulated board's virtual bench.
    ///
    /// What its analog input reads, what its force and position sensors do,
    /// which virtual stage it drives.
    Bench {
        #[command(flatten)]
        settings: fpi_host::cli::board::BenchSettings,
    },
    /// Open the loop, or close it on the position sensor, without a jump.
    ///
    /// Closing needs a model with a `[feedback]` section (from `fpi tune`).
    Loop {
        /// open, closed (feedback plus the inverse FPI feedforward) or feedback
        /// (feedback alone, through the straight-line drive).
        mode: String,
    },
    /// Switch the model's active damping on or off, without a jump.
    ///
    /// The damping is the model's `[damping]` section.
    Damping {
        /// on or off.
        state: String,
    },
    /// Drive the trigger output (pin PB1; on the emulated board recorded as the
    /// `trigger` column).
    ///
    /// travel: a pulse every --step-um of travel, either way; on_target: high
    /// while the position is within --band-um of the reference; window: high
    /// while it lies in --low-um … --high-um; point: a pulse at each point a
    /// stream takes; off. Levels not given stay as the board has them
    /// (`fpi board get` lists them).
    Trigger {
        /// off, travel, on_target, window or point.
        mode: String,
        #[command(flatten)]
        levels: fpi_host::board::trigger::Levels,
    },
    /// What a rising edge on the trigger input (pin PB9) starts.
    ///
    /// motion: a wave or stream ordered from now on waits (armed) for the
    /// next edge; recorder: a record order waits for it; both; off: orders
    /// start at once. The emulated board's input: `fpi board bench
    /// --trigger-in-ticks N`.
    TriggerIn {
        /// off, motion, recorder or both.
        starts: String,
    },
    /// Switch the model's reference shaping on or off, without a jump.
    ///
    /// The shaping is the model's `[shaping]` section.
    Shaping {
        /// on or off.
        state: String,
    },
    /// Step the reference, record and score the response.
    ///
    /// The step is a raised cosine; the figures are the rise time, the overshoot
    /// and the settling to ±0.1 µm (and to --tol).
    Step {
        /// From, µm (the stage moves there first and rests 50 ms).
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        from: f64,
        /// To, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        to: f64,
        /// Board time recorded from the step's start, s.
        #[arg(long, default_value_t = 0.05, value_parser = parse_positive, allow_negative_numbers = true)]
        seconds: f64,
        /// A second settling band, µm.
        #[arg(long, value_parser = parse_positive, allow_negative_numbers = true)]
        tol: Option<f64>,
        /// The raised cosine's duration, ms. Only steps of 1.5 ms or longer
        /// teach the board the stage's mass ratio; on a stage it has learned,
        /// 1.0 ms settles soonest.
        #[arg(long, default_value_t = 1.5, value_parser = parse_positive, allow_negative_numbers = true)]
        duration_ms: f64,
        /// Keep one tick in this many.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..))]
        decimation: u16,
        /// Where to write the recording (CSV).
        #[arg(long)]
        out: PathBuf,
    },
    /// A raster on two axes of a board of several, every axis recorded.
    ///
    /// Both axes go to their start; the lines start on the same tick on
    /// both: the fast axis a triangle at --freq-hz (a line is half its
    /// period), the slow axis a ramp (or a staircase) over the same lines.
    /// Prints the RMS error over the central 80 % of every line (the true
    /// positions on the emulated board, else the position sensors). The
    /// CSV's columns are `t_s` and each axis's `<signal>@<axis>`.
    Raster {
        /// The fast axis: x, y or z.
        #[arg(long, value_parser = parse_axis)]
        fast: u8,
        /// The slow axis.
        #[arg(long, value_parser = parse_axis)]
        slow: u8,
        /// The fast axis's triangle, Hz.
        #[arg(long, value_parser = parse_positive, allow_negative_numbers = true)]
        freq_hz: f64,
        /// Lines.
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        lines: u16,
        /// Where every line starts, µm (the fast axis; the slow axis too unless
        /// --slow-from-um).
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        from_um: f64,
        /// Where every line ends, µm (the fast axis; the slow axis too unless
        /// --slow-to-um).
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        to_um: f64,
        /// The slow axis's start, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        slow_from_um: Option<f64>,
        /// The slow axis's end, µm.
        #[arg(long, value_parser = parse_finite, allow_negative_numbers = true)]
        slow_to_um: Option<f64>,
        /// The slow axis steps at each line's start (else it ramps).
        #[arg(long)]
        staircase: bool,
        /// Where to write the recording (CSV).
        #[arg(long)]
        out: PathBuf,
    },
    /// Measure the frequency response through the board.
    ///
    /// Its own lock-in analyser, from the command to the position and force
    /// sensors; `fpi tune --frf` designs loops on it.
    Frf {
        #[command(flatten)]
        sweep: FrfArgs,
        /// Where to write it (CSV).
        #[arg(long)]
        out: PathBuf,
    },
    /// Tune the loops of the model the board runs, through the board.
    ///
    /// Measures the frequency response, fits the stage's dynamics, designs
    /// damping, PI and feedforward, loads the tuned model and verifies it with a
    /// step.
    ///
    /// On a board of several axes without --axis: every axis in turn, then
    /// their coupling (each axis moved while the others hold, every axis
    /// recorded), the decoupling set; --out is then one file of several
    /// axes (each axis's tuned model and the coupling) that `fpi board load`
    /// loads whole.
    Autotune {
        /// The model the board runs (as `fpi board load` took it): on a board
        /// of several axes, every axis's, or a file of several axes.
        model: PathBuf,
        /// FEM export of the stage (for a calibrated model).
        #[arg(long)]
        fem: Option<PathBuf>,
        #[command(flatten)]
        settings: LoopArgs,
        #[command(flatten)]
        loops: TuneArgs,
        #[command(flatten)]
        sweep: FrfArgs,
        /// Trials through the board the feedforward's taps are refined on (each:
        /// the step and the 100 Hz triangle, recorded at every tick); 0: the taps
        /// as designed on the fitted plant.
        #[arg(long, default_value_t = fpi_host::board::autotune::TRIALS)]
        trials: u32,
        /// Also keep the tuned model in the board's flash (of several axes:
        /// x's, the flash keeps the first axis's).
        #[arg(long)]
        store: bool,
        /// The fraction of every other axis's output each position sensor
        /// reads (their calibration, from a reference measurement; the
        /// sensors cannot tell it from the parasitic motion): the coupling of
        /// a board of several axes takes it out.
        #[arg(long, default_value_t = 0.0, value_parser = parse_finite, allow_negative_numbers = true)]
        sensor_crosstalk: f64,
        /// Where to write the measured response (CSV; one axis).
        #[arg(long)]
        frf_out: Option<PathBuf>,
        /// Where to write the tuned model (a firmware model file for `fpi board
        /// load`; of every axis: a file of several axes).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Files a command names, each with the option (or argument) that names it.
type Files<'a> = Vec<(&'static str, &'a Path)>;

impl BoardCommand {
    /// The files the command writes once it has worked on the board, with
    /// the options that name them, and the files it reads: checked before it
    /// starts ([`fpi_host::output::check_outputs`]).
    fn files(&self) -> (Files<'_>, Files<'_>) {
        match self {
            Self::Record { out, .. }
            | Self::Step { out, .. }
            | Self::Frf { out, .. }
            | Self::Raster { out, .. } => (vec![("--out", out.as_path())], vec![]),
            Self::Move {
                record: Some(r), ..
            }
            | Self::Wave {
                record: Some(r), ..
            } => (vec![("--record", r.as_path())], vec![]),
            Self::Stream {
                file,
                record: Some(r),
                ..
            } => (
                vec![("--record", r.as_path())],
                vec![("the trajectory", file.as_path())],
            ),
            Self::Autotune {
                model,
                fem,
                out,
                frf_out,
                ..
            } => {
                let mut outputs = vec![("--out", out.as_path())];
                outputs.extend(frf_out.as_deref().map(|f| ("--frf-out", f)));
                let mut inputs = vec![("the model", model.as_path())];
                inputs.extend(fem.as_deref().map(|f| ("--fem", f)));
                (outputs, inputs)
            }
            _ => (vec![], vec![]),
        }
    }
}

/// The sweep of `fpi board frf` and `fpi board autotune`.
#[derive(Debug, Clone, clap::Args)]
struct FrfArgs {
    /// Lowest frequency, Hz.
    #[arg(long, default_value_t = 20.0, value_parser = parse_positive, allow_negative_numbers = true)]
    from_hz: f64,
    /// Highest frequency, Hz (below a quarter of the control rate).
    #[arg(long, default_value_t = 4000.0, value_parser = parse_positive, allow_negative_numbers = true)]
    to_hz: f64,
    /// Frequencies, log-spaced (8–400).
    #[arg(long, default_value_t = 40)]
    points: usize,
    /// Excitation added to the command, µm (≤ 2).
    #[arg(long, default_value_t = 0.1, value_parser = parse_positive, allow_negative_numbers = true)]
    amplitude_um: f64,
    /// Where the stage holds meanwhile, µm.
    #[arg(long, default_value_t = 20.0, value_parser = parse_finite, allow_negative_numbers = true)]
    at_um: f64,
}

impl FrfArgs {
    fn settings(&self) -> fpi_host::board::frf::FrfSettings {
        fpi_host::board::frf::FrfSettings {
            from_hz: self.from_hz,
            to_hz: self.to_hz,
            points: self.points,
            amplitude_um: self.amplitude_um,
            at_um: self.at_um,
            ..Default::default()
        }
    }
}

/// How `fpi tune` and `fpi board autotune` design the loops.
#[derive(Debug, Clone, clap::Args)]
struct TuneArgs {
    /// Largest sensitivity peak |1/(1+L)| of the position loop over the mode's
    /// spread (±20 %, damping 0.01–0.06) and the model's gain spread (1.6: gain
    /// margin ≥ 8.5 dB, phase margin ≥ 36°).
    #[arg(long, default_value_t = 1.6, allow_negative_numbers = true)]
    pub max_sensitivity: f64,
    /// The highest crossover of the position loop, Hz (default: as high as the
    /// margins allow; without --dynamics, 20 Hz). One the margins do not allow
    /// is refused.
    #[arg(long, allow_negative_numbers = true)]
    pub bandwidth_hz: Option<f64>,
    /// No active damping (the PI and feedforward on the undamped stage).
    #[arg(long)]
    pub no_damping: bool,
    /// The damping ratio the damping aims for on the least-damped plant.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub target_damping: f64,
    /// κ, the dynamic force per µm of command, N/µm (default: estimated from
    /// the model's stiffness, coupling and lever; `fpi board autotune` measures it).
    #[arg(long, allow_negative_numbers = true)]
    pub force_gain: Option<f64>,
    /// σ of the force sensor's noise, N: the damping is lowered until it moves
    /// the stage at most 0.05 µm RMS at rest (default: not designed for;
    /// `fpi board autotune` measures it, and this replaces the measurement).
    #[arg(long, allow_negative_numbers = true)]
    pub force_noise_n: Option<f64>,
    /// No feedforward (reference shaping) of the damped stage.
    #[arg(long)]
    pub no_feedforward: bool,
    /// Largest correction the feedback adds to the reference, µm (> 0; default a
    /// quarter of the stroke).
    #[arg(long, value_parser = parse_signal_um, allow_negative_numbers = true)]
    pub limit_um: Option<f64>,
    /// Largest disagreement of the position sensor with the model's estimate,
    /// µm (> 0; default 15 % of the stroke).
    #[arg(long, value_parser = parse_signal_um, allow_negative_numbers = true)]
    pub tolerance_um: Option<f64>,
}

impl TuneArgs {
    fn options(&self) -> fpi_host::method::tune::TuneOptions {
        fpi_host::method::tune::TuneOptions {
            max_sensitivity: self.max_sensitivity,
            bandwidth_hz: self.bandwidth_hz,
            limit_um: self.limit_um,
            tolerance_um: self.tolerance_um,
            damping: !self.no_damping,
            target_damping: self.target_damping,
            force_gain: self.force_gain,
            force_noise_n: self.force_noise_n,
            feedforward: (!self.no_feedforward).then(fpi_host::method::tune::TimeOptions::default),
            ..Default::default()
        }
    }
}

/// `A-B`: rows A to B (1-based, inclusive), at least [`cli::MIN_FIT_ROWS`] of them.
fn parse_rows(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once('-')
        .ok_or_else(|| format!("{s:?}: expected A-B, e.g. 3152-3351"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("{v:?} is not a row number"))
    };
    let (a, b) = (p(a)?, p(b)?);
    if a < 1 {
        return Err(format!("{s}: rows are numbered from 1"));
    }
    if b < a {
        return Err(format!("{s}: the last row {b} comes before the first {a}"));
    }
    let n = b - a + 1;
    if n < cli::MIN_FIT_ROWS {
        return Err(format!(
            "{s}: {n} row(s); a fit needs at least {} rows of motion",
            cli::MIN_FIT_ROWS
        ));
    }
    Ok((a, b))
}

/// `HOST:PORT` ([`fpi_host::board::port::tcp_address`]), as given.
fn parse_listen(s: &str) -> Result<String, String> {
    fpi_host::board::port::tcp_address(s)
        .map(|_| s.to_string())
        .map_err(|e| format!("{e:#}"))
}

/// `--listen` where port 0 (any free port, the address printed) is allowed.
fn parse_listen_any(s: &str) -> Result<String, String> {
    match s.strip_suffix(":0") {
        Some(host) => parse_listen(&format!("{host}:1")).map(|_| s.to_string()),
        None => parse_listen(s),
    }
}

/// A finite number.
fn parse_finite(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

/// A finite number > 0.
fn parse_positive(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("{v}: must be > 0"))
    }
}

/// A finite number in `(0, max]` of unit `unit`; `limit` says what `max` is.
fn in_span(s: &str, unit: &str, max: f64, limit: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if v <= 0.0 {
        return Err(format!("{} {unit}: must be > 0 {unit}", Num(v)));
    }
    if v > max {
        return Err(format!("{} {unit}: above {limit} ({max} {unit})", Num(v)));
    }
    Ok(v)
}

/// A length the board holds as a signal, `(0, 4096] µm`.
fn parse_signal_um(s: &str) -> Result<f64, String> {
    in_span(
        s,
        "µm",
        piezo_fpi::q::SIGNAL_ABS_MAX,
        "the board's signal range",
    )
}

/// A voltage within the board's amplifier span `(0, 150] V`.
fn parse_amplifier_volts(s: &str) -> Result<f64, String> {
    use fpi_host::method::limits::AMPLIFIER_MAX_V;
    in_span(s, "V", AMPLIFIER_MAX_V, "the board's amplifier span")
}

/// A slew within the amplifier's `(0, 100] V/ms`.
fn parse_slew(s: &str) -> Result<f64, String> {
    use fpi_host::method::limits::AMPLIFIER_MAX_SLEW_V_PER_MS;
    in_span(
        s,
        "V/ms",
        AMPLIFIER_MAX_SLEW_V_PER_MS,
        "the amplifier's largest slew",
    )
}

/// A recording time, `(0, 3600] s`.
fn parse_record_seconds(s: &str) -> Result<f64, String> {
    in_span(s, "s", 3600.0, "an hour of recording")
}

/// A stack compliance, within `[0, 0.5)` µm/N.
fn parse_compliance(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    let top = piezo_fpi::q::COUPLING_ABS_MAX;
    if (0.0..=top).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{} µm/N: must be within 0–{top} µm/N (a stack yields under load, by 0.005–0.1 \
             µm/N; the firmware holds less than 0.5)",
            Num(v)
        ))
    }
}

/// A count of play operators, 1..=32.
fn parse_operators(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if (1..=32).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n}: a model has 1..=32 play operators")),
        Err(_) => Err(format!("{s:?} is not a count")),
    }
}

fn main() -> ExitCode {
    fpi_host::cli::exit_quietly_on_broken_pipe();
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e)
            if e.downcast_ref::<fpi_host::cli::board::Interrupted>()
                .is_some() =>
        {
            eprintln!("{e:#}");
            ExitCode::from(130)
        }
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
            axis,
        } => {
            let kind = kind.as_deref().map(Kind::parse).transpose()?;
            cli::calibrate(
                kind,
                &rig,
                &out,
                operators,
                compliance,
                rows,
                axis.map(usize::from),
            )
        }
        Command::Predict {
            model,
            fem,
            drive,
            out,
            dynamics,
        } => cli::predict_with(&model, &fem, &drive, &out, dynamics.as_deref()),
        Command::Compare {
            fem,
            runs,
            model,
            out,
            dynamics,
        } => cli::compare_with(&fem, &runs, &model, &out, dynamics.as_deref()),
        Command::Invert {
            model,
            fem,
            target,
            out,
            u_max,
        } => cli::invert(&model, &fem, &target, &out, u_max),
        Command::Refine {
            model,
            fem,
            runs,
            out,
        } => cli::refine(&model, &fem, &runs, &out),
        Command::Tune {
            firmware,
            dynamics,
            frf,
            accept_misfit,
            loops,
            out,
        } => cli::tune(
            &firmware,
            dynamics.as_deref(),
            frf.as_deref(),
            &out,
            &loops.options(),
            accept_misfit,
        ),
        Command::Export {
            model,
            fem,
            out,
            settings,
            dynamics,
            damping,
            speed_up,
            current_limit_ma,
        } => {
            let m = HostModel::read(&model)?;
            let shaping = fpi_host::method::shaping::ShapingOptions {
                damping,
                speed_up,
                current_limit_ma,
            };
            let dynamics = dynamics.as_deref().map(|d| (d, shaping));
            cli::export(&m, &model, &fem, &out, &settings.options(), dynamics)
        }
        Command::Demo { out } => cli::demo(&out).context("demo"),
        Command::Bench => cli::bench(),
        Command::Scope {
            port,
            listen,
            signals,
            decimation,
        } => fpi_host::cli::scope::run(&port, &listen, &signals, decimation),
        Command::Identify {
            chirps,
            out,
            plots,
            min_hz,
        } => cli::identify(&chirps, &out, plots.as_deref(), min_hz),
        Command::Lever {
            params,
            out,
            points,
            stroke_um,
            output,
        } => fpi_host::method::lever::command(params.as_deref(), &out, points, stroke_um, output),
        Command::Board {
            port,
            axis,
            command,
        } => board(port, axis, command),
        Command::Axes { command } => axes(command),
        Command::Reference { page } => {
            print!("{}", reference(page)?);
            Ok(())
        }
    }
}

/// `fpi axes …`.
fn axes(command: AxesCommand) -> Result<()> {
    use fpi_host::cli::axes;
    match command {
        AxesCommand::Grid { stage, every, out } => axes::grid(stage, every, &out),
        AxesCommand::Decoupling { grid } => axes::decoupling(&grid),
        AxesCommand::Record {
            stage,
            drive,
            out,
            seed,
        } => axes::record(&stage, &drive, &out, seed),
        AxesCommand::Predict {
            grid,
            model,
            drive,
            out,
            independent,
        } => axes::predict(&grid, &model, &drive, &out, independent),
        AxesCommand::Compare { grid, model, runs } => axes::compare(&grid, &model, &runs).map(drop),
        AxesCommand::Refine {
            grid,
            model,
            runs,
            out,
        } => axes::refine(&grid, &model, &runs, &out).map(drop),
    }
}

/// `--axis`: x, y or z, as its number.
fn parse_axis(s: &str) -> Result<u8, String> {
    fpi_host::board::client::axis_number(s)
        .ok_or_else(|| format!("{s:?} is not an axis: x, y or z"))
}

/// `--link`: `uart` or `usb`.
fn parse_link(s: &str) -> Result<fpi_protocol::LinkKind, String> {
    fpi_host::board::client::link_kind(s).ok_or_else(|| format!("{s:?}: uart or usb"))
}

fn parse_front_end(s: &str) -> Result<fpi_protocol::FrontEndKind, String> {
    fpi_protocol::FrontEndKind::from_name(s).ok_or_else(|| format!("{s:?}: internal or precision"))
}

fn board(port: Option<String>, axis: Option<u8>, command: BoardCommand) -> Result<()> {
    use fpi_host::board::emulator::Emulator;
    use fpi_host::cli::board as b;
    if let BoardCommand::Emulate {
        listen,
        link,
        frontend,
        firmware,
        axes,
    } = &command
    {
        // Ctrl-C, SIGTERM or SIGHUP stop QEMU with `fpi`; so does any other end
        // of `fpi` on Linux (QEMU's parent-death signal, `Emulator`).
        b::catch_ctrl_c()?;
        let e = Emulator::start_board(firmware.as_deref(), *axes, Some(listen), *link, *frontend)?;
        println!(
            "emulated board{} running, its link paced as {} ({} B/s), its front end {}; its link is --port {} \
             (Ctrl-C stops it)",
            if *axes == 1 {
                String::new()
            } else {
                format!(" of {axes} axes")
            },
            link.name(),
            link.bytes_per_s(),
            frontend.name(),
            e.port()
        );
        if e.wait_until(b::stop_asked)? {
            println!("emulated board stopped");
        }
        return Ok(());
    }
    let Some(port) = port else {
        anyhow::bail!("which board? --port /dev/ttyUSB0 (or COM3), or --port tcp:127.0.0.1:4545 for `fpi board emulate`");
    };
    // The outputs must take their files before the board does anything.
    let (outputs, inputs) = command.files();
    fpi_host::output::check_outputs(&outputs, &inputs)?;
    if let BoardCommand::Bench { settings } = &command {
        settings.check()?;
    }
    if let BoardCommand::Serve { listen } = &command {
        b::catch_ctrl_c()?;
        let c = b::open(&port)?;
        return fpi_host::board::hub::serve(c, listen, &b::stop_asked);
    }
    let mut c = b::open(&port)?;
    c.on_axis(axis.unwrap_or(0))?;
    // A motion ends whatever stream a previous client left (its points and
    // its supervision): say so.
    let motion = matches!(
        command,
        BoardCommand::Move { .. }
            | BoardCommand::Wave { .. }
            | BoardCommand::Stream { .. }
            | BoardCommand::Hold
            | BoardCommand::Analog
            | BoardCommand::Step { .. }
            | BoardCommand::Raster { .. }
    );
    let ended_before = if motion {
        Some(c.status()?.ended_points)
    } else {
        None
    };
    let done = board_command(&mut c, command, axis.is_some());
    if let Some(before) = ended_before {
        b::say_ended_stream(&mut c, before);
    }
    done
}

/// Runs a board command on the open board `c`.
/// `axis_given`: `--axis` was given (else a per-axis command addresses x, and
/// `autotune` tunes every axis of a board of several).
fn board_command(
    c: &mut fpi_host::board::client::Client,
    command: BoardCommand,
    axis_given: bool,
) -> Result<()> {
    use fpi_host::cli::board as b;
    use fpi_protocol::Command as C;
    match command {
        BoardCommand::Emulate { .. } | BoardCommand::Serve { .. } => Ok(()),
        BoardCommand::Status => b::status(c),
        BoardCommand::Info => {
            print!(
                "{}",
                fpi_host::board::info::describe(&fpi_host::board::info::read(c)?)
            );
            Ok(())
        }
        BoardCommand::Move {
            um: Some(um),
            speed,
            record,
            ..
        } => b::move_to(c, um, speed, record.as_deref()),
        BoardCommand::Move {
            x,
            y,
            z,
            speed,
            record,
            ..
        } => b::move_axes(c, [x, y, z], speed, record.as_deref()),
        BoardCommand::Wave {
            shape,
            amplitude_um,
            offset_um,
            freq_hz,
            cycles,
            record,
            seconds,
        } => b::wave(
            c,
            &shape,
            amplitude_um,
            offset_um,
            freq_hz,
            cycles,
            record.as_deref().map(|r| (r, seconds)),
        ),
        BoardCommand::Stream {
            file,
            interval,
            record,
        } => {
            let points = fpi_host::data::read_points(&file)?;
            b::stream(c, &points, interval, record.as_deref())
        }
        BoardCommand::Record {
            seconds,
            out,
            decimation,
            signals,
        } => {
            let signals = b::signals_arg(&signals)?;
            match seconds {
                Some(seconds) => b::record(c, seconds, decimation, signals, &out).map(|_| ()),
                None => b::record_until_stopped(c, decimation, signals, &out),
            }
        }
        BoardCommand::Load {
            model,
            fem,
            store,
            match_mass,
            settings,
        } => {
            let loaded = b::loadable(&model, fem.as_deref(), &settings.options())?;
            b::load_file(c, &loaded, store, match_mass)
        }
        BoardCommand::Factory => b::simple(c, &C::ModelFactory { axis: c.axis() }),
        BoardCommand::Safe => b::simple(c, &C::Safe),
        BoardCommand::ClearFault => b::simple(c, &C::ClearFault),
        BoardCommand::Hold => b::simple(c, &C::Hold { axis: c.axis() }),
        BoardCommand::Analog => b::simple(c, &C::Analog { axis: c.axis() }),
        BoardCommand::Drive { mode } => b::drive(c, &mode),
        BoardCommand::Reset => b::reset(c),
        BoardCommand::Bench { settings } => b::bench(c, &settings),
        BoardCommand::Loop { mode } => b::set_loop(c, &mode),
        BoardCommand::Damping { state } => b::damping(c, &state),
        BoardCommand::Shaping { state } => b::shaping(c, &state),
        BoardCommand::Trigger { mode, levels } => b::trigger(c, &mode, &levels),
        BoardCommand::TriggerIn { starts } => b::trigger_in(c, &starts),
        BoardCommand::Step {
            from,
            to,
            seconds,
            tol,
            duration_ms,
            decimation,
            out,
        } => {
            let s = fpi_host::board::step::StepSettings {
                from_um: from,
                to_um: to,
                seconds,
                tol_um: tol,
                duration_ms,
                decimation,
            };
            b::step(c, &s, &out)
        }
        BoardCommand::Frf { sweep, out } => b::frf(c, &sweep.settings(), &out),
        BoardCommand::Raster {
            fast,
            slow,
            freq_hz,
            lines,
            from_um,
            to_um,
            slow_from_um,
            slow_to_um,
            staircase,
            out,
        } => {
            let spec = fpi_host::board::raster::RasterSpec {
                fast,
                slow,
                fast_um: (from_um, to_um),
                slow_um: (slow_from_um.unwrap_or(from_um), slow_to_um.unwrap_or(to_um)),
                freq_hz,
                lines,
                staircase,
            };
            b::raster(c, &spec, &out)
        }
        BoardCommand::Autotune {
            model,
            fem,
            settings,
            loops,
            sweep,
            trials,
            store,
            sensor_crosstalk,
            frf_out,
            out,
        } => {
            let a = b::AutotuneArgs {
                model: (&model, fem.as_deref()),
                export: settings.options(),
                tune: loops.options(),
                settings: fpi_host::board::autotune::Settings {
                    sweep: sweep.settings(),
                    trials,
                },
                store,
                out: (&out, frf_out.as_deref()),
                every_axis: !axis_given,
                coupling: fpi_host::board::decoupling::Settings {
                    sensor_crosstalk,
                    ..Default::default()
                },
            };
            b::autotune(c, &a)
        }
        BoardCommand::Supervise { ms } => b::supervise(c, ms),
        BoardCommand::Get { key } => b::get(c, key.as_deref()),
        BoardCommand::Set { key, value } => b::set(c, &key, &value),
    }
}
