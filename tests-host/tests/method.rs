//! The FPI-FFEM method end to end on the project's datasets (`fpi demo`), with the
//! accuracy targets of the issue:
//!
//! * stage A, 5 and 15 Hz: the best model cuts PI-FEM's MAE by ≥ 75 % (the paper:
//!   76.7 % and 75.0 %); the paper's plain FPI reaches only about 60 %;
//! * the micromanipulator: PI about 0.33 µm on the authors' cycle, our GPI below
//!   the discrete backlash operator's 0.21 µm, and EPI, the default without force,
//!   within 0.12 µm, predicting the rest of the recording within 0.12 µm;
//! * the exported firmware model is the one the firmware embeds.

use fpi_host::data;
use fpi_host::data::fem::FemMaps;
use fpi_host::method::calibrate::{self, Options};
use fpi_host::method::compare::Comparison;
use fpi_host::method::model::Kind;
use fpi_host::report::demo;

#[test]
fn the_demo_chain_meets_every_target() {
    let out = std::env::temp_dir().join(format!("fpi-method-{}", std::process::id()));
    let s = demo::run(&out).unwrap_or_else(|e| panic!("{e:#}"));
    for l in &s.lines {
        println!("{l}");
    }
    assert!(s.ok, "a target was missed");
    // Step 1 names the default kind without force on the real recording, its
    // prediction of the rest per 1000-sample window, and the published figure.
    let lines = s.lines.join("\n");
    assert!(
        lines.contains("RMSE EPI 0.0") && lines.contains("EPI RMSE 0.0"),
        "{lines}"
    );
    assert!(lines.contains("0.73–0.83 µm on its test run"), "{lines}");
    assert!(lines.contains("several axes (XY twin"), "{lines}");
    let report = std::fs::read_to_string(&s.report).unwrap();
    for figure in [
        "loops_sine_05Hz.svg",
        "surface_sine_05Hz_efpi.svg",
        "rig_loops.svg",
        "rig_rmse.svg",
        "micromanipulator.svg",
        "xy_held_axis.svg",
    ] {
        assert!(report.contains(figure), "report shows {figure}");
        assert!(out.join(figure).exists(), "{figure} written");
    }
}

#[test]
fn the_papers_fpi_reaches_about_sixty_percent_and_efpi_over_seventy_five() {
    let rig = calibrate::load(&data::datasets_in("pea-rig"), None).unwrap();
    let fem = FemMaps::read(&data::dataset("stage-a/fem.csv")).unwrap();
    let pi_rig: Vec<_> = rig
        .iter()
        .filter(|d| (d.f0 / 25.0).round() == 2.0)
        .cloned()
        .collect();
    let models = vec![
        (
            "pi".to_string(),
            calibrate::calibrate(&pi_rig, &Options::for_kind(Kind::Pi)).unwrap(),
        ),
        (
            "fpi".to_string(),
            calibrate::calibrate(&rig, &Options::for_kind(Kind::Fpi)).unwrap(),
        ),
        (
            "efpi".to_string(),
            calibrate::calibrate(&rig, &Options::for_kind(Kind::Efpi)).unwrap(),
        ),
    ];
    let runs: Vec<_> = ["stage-a/sine_05Hz.csv", "stage-a/sine_15Hz.csv"]
        .iter()
        .map(|r| data::read_stage(&data::dataset(r)).unwrap())
        .collect();
    let c = Comparison::run(&fem, &runs, &models).unwrap();
    for r in 0..2 {
        let (fpi, efpi) = (c.reduction(r, 1), c.reduction(r, 2));
        println!("{}: FPI {fpi:.1} %, EFPI {efpi:.1} %", c.run_name(r));
        assert!(
            (45.0..70.0).contains(&fpi),
            "the paper's FPI: about 60 %, got {fpi}"
        );
        assert!(efpi >= 75.0, "EFPI: at least 75 %, got {efpi}");
    }
}

/// The real micromanipulator has no force channel: the default model is `epi`, the
/// extended model's structure without the force coupling (creep and the output
/// saturation), named so in its file. On the authors' identification cycle it
/// fits within 0.12 µm (measured 0.064 µm; gpi 0.159 µm), and fitted there it
/// predicts the rest of the recording, in 1000-sample windows each with its mean
/// error removed, within 0.12 µm (measured 0.066–0.116 µm) but for the first
/// window, the start from rest (measured 1.76 µm).
#[test]
fn a_recording_without_force_gets_creep_and_the_output_map() {
    let mm = calibrate::load(
        &[data::dataset("real/micromanipulator/Model_Vi_Do.dat")],
        Some((3152, 3351)),
    )
    .unwrap();
    let (kind, note) = fpi_host::method::kinds::default_for(&mm);
    assert_eq!((kind, note), (Kind::Epi, None));
    let opt = Options {
        offset: true,
        ..Options::for_kind(kind)
    };
    let m = calibrate::calibrate(&mm, &opt).unwrap();
    let text = toml::to_string(&m).unwrap();
    assert!(text.contains("kind = \"epi\""), "{text}");
    assert!(!m.creep.is_empty() && !m.output.is_identity());
    assert_eq!(m.coupling.k_f_v_per_n, 0.0);
    println!(
        "epi on the cycle: RMSE {:.4} µm ({})",
        m.calibration.rmse_um, m.calibration.method
    );
    assert!(m.calibration.rmse_um <= 0.12, "{}", m.calibration.rmse_um);
    let windows = calibrate::held_out(&m, &mm[0], 1000);
    println!("{}", calibrate::held_out_summary(&mm[0], &windows));
    assert_eq!(windows.len(), 9, "{windows:?}");
    assert_eq!(
        (windows[0].rows, windows[8].rows),
        ((1, 1000), (7352, 8027))
    );
    for w in &windows[1..] {
        assert!(w.rmse_um <= 0.12, "{w:?}");
    }
}
