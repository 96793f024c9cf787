//! The host side of the piezo FPI project, in layers, each using only those
//! before it (the test `layers::each_layer_uses_only_those_before_it` keeps it so):
//!
//! * [`output`] — writing the commands' files atomically, never over an input.
//! * [`data`] — the recorded datasets and the stage's FEM export, read with errors
//!   that name the file, the line and the column; where the project's files are.
//! * [`method`] — the FPI-FFEM method (Actuators 2025, 14(8):411, Table 1): the model
//!   kinds, one file each ([`method::kinds`]), and the calibrated model's file
//!   ([`method::model`]), calibration, the coupled prediction, comparison, offline
//!   inversion, the export of a firmware model and the board's limits. The models
//!   are evaluated by the project's float model (`piezo-sim`).
//! * [`board`] — the firmware from the host: building it for the Cortex-M4,
//!   running it on the emulated board (QEMU) or in this process, its link's client,
//!   the scripted sessions, the twin, and measuring the fixed-point core against
//!   its f64 reference ([`board::accuracy`]).
//! * [`scope`] — `fpi scope`: the board's recorder streamed live to a page in the
//!   browser, served from this binary.
//! * [`report`] — the Markdown report, its SVG plots, and `fpi demo`, the whole
//!   chain on the project's datasets and the emulated board (so after `board`).
//! * [`cli`] — the `fpi` commands, `fpi board …` among them ([`cli::board`]); the
//!   binaries only parse arguments.

pub mod board;
pub mod cli;
pub mod data;
pub mod method;
pub mod output;
pub mod report;
pub mod scope;

/// The firmware model file (shared with the firmware's build).
pub use piezo_sim::file as model_file;

#[cfg(test)]
mod layers {
    use std::path::{Path, PathBuf};

    /// The layers, in order: each may use those before it.
    const ORDER: [&str; 7] = [
        "output", "data", "method", "board", "scope", "report", "cli",
    ];

    /// The `.rs` files of a layer: `src/NAME.rs` and everything under `src/NAME/`.
    fn files(layer: &str) -> Vec<PathBuf> {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut out = vec![];
        let mut todo = vec![src.join(layer)];
        let file = src.join(format!("{layer}.rs"));
        if file.is_file() {
            out.push(file);
        }
        while let Some(d) = todo.pop() {
            for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
                let p = e.path();
                if p.is_dir() {
                    todo.push(p);
                } else if p.extension().is_some_and(|x| x == "rs") {
                    out.push(p);
                }
            }
        }
        out
    }

    /// The layers a line of code names as `crate::LAYER` or in `crate::{…}`
    /// (comments aside).
    fn named(line: &str) -> Vec<&'static str> {
        let code = line.split("//").next().unwrap_or("");
        let word = |c: char| c.is_alphanumeric() || c == '_';
        let braced: Vec<&str> = code
            .split("crate::{")
            .skip(1)
            .flat_map(|rest| rest.split('}').next().unwrap_or("").split(','))
            .map(|item| item.trim().split("::").next().unwrap_or(""))
            .collect();
        ORDER
            .iter()
            .filter(|l| {
                braced.contains(l)
                    || code
                        .match_indices(&format!("crate::{l}"))
                        .any(|(k, m)| !code[k + m.len()..].starts_with(word))
            })
            .copied()
            .collect()
    }

    #[test]
    fn each_layer_uses_only_those_before_it() {
        let mut steps_back = vec![];
        for (k, layer) in ORDER.iter().enumerate() {
            let found = files(layer);
            assert!(!found.is_empty(), "no files for the layer {layer}");
            for f in found {
                let text = std::fs::read_to_string(&f).unwrap();
                for (n, line) in text.lines().enumerate() {
                    for used in named(line) {
                        if ORDER.iter().position(|l| *l == used).unwrap() > k {
                            steps_back.push(format!(
                                "{}:{}: {layer} uses {used}",
                                f.display(),
                                n + 1
                            ));
                        }
                    }
                }
            }
        }
        assert!(
            steps_back.is_empty(),
            "steps back:\n{}",
            steps_back.join("\n")
        );
    }

    #[test]
    fn a_step_back_is_seen() {
        assert_eq!(named("use crate::board::client::Client;"), ["board"]);
        assert_eq!(named("    let x = crate::cli::stage_maps(a);"), ["cli"]);
        assert!(named("/// see [`crate::board::client`]").is_empty());
        assert!(named("use crate::boarding;").is_empty());
        assert_eq!(named("use crate::{data, cli::board};"), ["data", "cli"]);
    }
}
