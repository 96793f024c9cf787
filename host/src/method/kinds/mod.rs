//! The model kinds: each is one file here, one implementation of
//! [`ModelKind`](crate::method::model::ModelKind), and one line of `kinds!`
//! below, the one list of them. A model file names its kind (`kind = "efpi"`);
//! this list is where a name becomes a [`Kind`].
//!
//! | kind | input | parts |
//! |---|---|---|
//! | `pi` | `u` | PI with one-sided play operators (the conventional baseline) |
//! | `ldpi` | `u` | PI whose weights are affine in the preload, `w_i(F) = a_i + b_i·F` (the paper's LDPI baseline, as we implement it: its source is not available) |
//! | `fpi` | `û = max(u − k_f·F, 0)` | the paper's FPI (eqs. 5–7) |
//! | `efpi` | `û = g(u − U_p(F))` | extended FPI: `U_p = k0 + k_f·F + k_q·(F − F_q)²`, soft dead zone `g`, creep lags, output saturation, stack compliance |
//! | `gpi` | `u` | PI followed by a monotone quadratic output map and an offset (for recordings without force) |
//! | `epi` | `û = g(u − k0)` | the extended model without the force: soft dead zone, creep lags, output saturation (and an offset; the default for recordings without force) |
//! | `branch` | `û = clamp(u − k_f·F, 0, input_max)` | no PI: the second paper's branch polynomials (eqs. 6–7) from the last turning point, with a memory of turning points |

use anyhow::{Context, Result};
use serde::{Deserialize, Deserializer};

use crate::method::checks::force_unusable;
use crate::method::model::Kind;
use crate::method::series::CalibData;

pub mod play;

/// Declares each kind's module and lists the kinds, in the order reports list them.
macro_rules! kinds {
    ($($module:ident::$kind:ident),* $(,)?) => {
        $(pub mod $module;)*
        /// Every kind, in the order reports list them.
        pub static ALL: &[Kind] = &[$(Kind::of(&$module::$kind)),*];
    };
}

kinds! {
    pi::Pi,
    ldpi::Ldpi,
    fpi::Fpi,
    efpi::Efpi,
    gpi::Gpi,
    epi::Epi,
    branch::Branch,
}

impl Kind {
    /// A kind by its name.
    pub fn parse(s: &str) -> Result<Kind> {
        ALL.iter()
            .find(|k| k.name() == s)
            .copied()
            .with_context(|| {
                let names: Vec<&str> = ALL.iter().map(|k| k.name()).collect();
                let (last, rest) = names.split_last().expect("kinds are listed");
                format!(
                    "unknown model kind {}: expected {} or {last}",
                    piezo_sim::quote::Quoted(s),
                    rest.join(", ")
                )
            })
    }
}

impl<'de> Deserialize<'de> for Kind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Kind::parse(&name).map_err(|e| serde::de::Error::custom(format!("{e:#}")))
    }
}

/// The kind `fpi calibrate` fits by default: `efpi` where the recordings' force
/// can identify its coupling, else `epi` (the same structure without it); with a
/// note saying why when they have a force channel that cannot.
pub fn default_for(data: &[CalibData]) -> (Kind, Option<String>) {
    let (with, without) = (Kind::Efpi, Kind::Epi);
    match force_unusable(data) {
        None => (with, None),
        Some(why) => {
            let has_force = data.iter().all(|d| d.has_force);
            let note = format!(
                "{why}, so k_f cannot be identified: calibrating {without} instead of the \
                 default {with}"
            );
            (without, has_force.then_some(note))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data;
    use crate::data::fem::FemMaps;
    use crate::method::calibrate::{self, Options};
    use crate::method::model::{FemCorrection, HostModel, OutputMap};
    use crate::method::predict::predict;
    use crate::model_file::{CouplingSection, CreepSection, PiSection};

    #[test]
    fn every_kind_is_found_by_its_name() {
        for k in ALL {
            assert_eq!(Kind::parse(k.name()).unwrap(), *k);
        }
        let e = format!("{:#}", Kind::parse("magic").unwrap_err());
        assert_eq!(
            e,
            "unknown model kind \"magic\": expected pi, ldpi, fpi, efpi, gpi, epi or branch"
        );
    }

    fn efpi() -> HostModel {
        let mut m = HostModel::new(
            Kind::Efpi,
            PiSection {
                w0_um_per_v: 0.06,
                thresholds_v: vec![10.0, 30.0, 60.0],
                weights_um_per_v: vec![0.01, 0.008, 0.004],
                input_max_v: 150.0,
            },
        );
        m.coupling = CouplingSection {
            offset_v: -0.4,
            k_f_v_per_n: 0.106,
            k_q_v_per_n2: 1.6e-4,
            force_q_n: 75.0,
            compliance_um_per_n: 0.02,
            force_ref_n: None,
        };
        m.dead_zone_softness_v = 1.8;
        m.output = OutputMap::Saturation {
            beta_per_um: 0.0037,
        };
        m.creep = vec![CreepSection {
            tau_s: 0.01,
            gain_um_per_v: 0.003,
        }];
        m
    }

    #[test]
    fn model_files_round_trip() {
        let m = efpi();
        let dir = std::env::temp_dir().join(format!("hmodel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.toml");
        m.write(&p).unwrap();
        assert_eq!(HostModel::read(&p).unwrap(), m);
    }

    #[test]
    fn fem_corrections_round_trip_and_name_their_key() {
        let mut m = efpi();
        m.fem_correction = Some(FemCorrection {
            stage_gain: 0.98,
            stage_offset_um: -0.02,
            preload_scale: 0.97,
            fem: "data/stage-a/fem.csv.gz".into(),
            refined_on: vec!["data/stage-a/sine_05Hz.csv.gz".into()],
            rmse_before_um: Some(0.158),
            rmse_after_um: Some(0.024),
        });
        let text = toml::to_string(&m).unwrap();
        assert!(text.contains("[fem_correction]"), "{text}");
        assert_eq!(HostModel::parse(&text, "m.toml").unwrap(), m);
        // Without the section: as before.
        assert!(!toml::to_string(&efpi()).unwrap().contains("fem_correction"));
        // The three numbers alone are a section.
        let plain = toml::to_string(&efpi()).unwrap()
            + "\n[fem_correction]\nstage_gain = 1.01\nstage_offset_um = 0.0\npreload_scale = 0.99\n";
        let c = HostModel::parse(&plain, "m.toml")
            .unwrap()
            .fem_correction
            .unwrap();
        assert_eq!((c.stage_gain, c.preload_scale), (1.01, 0.99));
        for (key, bad) in [
            ("stage_gain", "stage_gain = 1.01", "stage_gain = 3.0"),
            (
                "preload_scale",
                "preload_scale = 0.99",
                "preload_scale = nan",
            ),
            (
                "stage_offset_um",
                "stage_offset_um = 0.0",
                "stage_offset_um = inf",
            ),
        ]
        .map(|(k, from, to)| (k, plain.replace(from, to)))
        {
            let e = format!("{:#}", HostModel::parse(&bad, "m.toml").unwrap_err());
            assert!(
                e.contains(&format!("fem_correction.{key}")) && e.contains("m.toml"),
                "{e}"
            );
        }
        let unknown = plain.clone() + "stage_slope = 1.0\n";
        let e = format!("{:#}", HostModel::parse(&unknown, "m.toml").unwrap_err());
        assert!(e.contains("stage_slope"), "{e}");
    }

    /// Bisection on the coupled equation: slow, but obviously right.
    fn bisect(model: &HostModel, fem: &FemMaps, t: &[f64], u: &[f64]) -> Vec<f64> {
        let dt = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
        let model = model.model();
        let mut st = model.state(dt);
        let f_ref = fem.rest_preload();
        u.iter()
            .map(|&uk| {
                let (mut lo, mut hi) = (-20.0, 40.0);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    let (f, df) = fem.preload_with_slope(mid);
                    if model.peek(&st, uk, f, df, f_ref).x > mid {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let x = 0.5 * (lo + hi);
                let (f, df) = fem.preload_with_slope(x);
                let p = model.peek(&st, uk, f, df, f_ref);
                model.commit(&mut st, p.uh);
                x
            })
            .collect()
    }

    #[test]
    fn newton_solve_equals_bisection_for_every_kind() {
        let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
        let rig = calibrate::load(&data::datasets_in("pea-rig")[6..9], None).unwrap();
        let run = data::read_stage(&data::dataset("stage-a/sine_15Hz.csv")).unwrap();
        for kind in [Kind::Pi, Kind::Ldpi, Kind::Fpi, Kind::Efpi] {
            let m = calibrate::calibrate(&rig, &Options::for_kind(kind)).unwrap();
            let fast = predict(&m, &fem, &run.t, &run.u).unwrap();
            let slow = bisect(&m, &fem, &run.t, &run.u);
            let worst = fast
                .x_pea
                .iter()
                .zip(&slow)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            println!(
                "{kind}: worst |Newton - bisection| {worst:.2e} um, {:.2} evaluations/sample",
                fast.iterations as f64 / run.t.len() as f64
            );
            assert!(worst < 1e-12, "{kind}: {worst} um");
            assert!(
                fast.iterations < 5 * run.t.len(),
                "{kind}: {} iterations",
                fast.iterations
            );
        }
    }
}
