//! `fpi lever`: the second paper's three-stage lever (eqs. 8–12, Table 5) as an
//! analytic FEM table. The stated strokes, the disagreements documented in
//! `method::lever`, a monotone `f_K`, the round trip through the FEM reader, refused
//! parameter files, and `fpi predict` / `fpi export` on the table.

use std::path::{Path, PathBuf};

use fpi_host::data::fem::FemMaps;
use fpi_host::method::lever::{
    self, Geometry, LeverParams, OutputUnit, Reflection, PAPER_STACK_UM, PAPER_STAGES_DEG,
    TABLE5_ALPHA0_DEG,
};

mod common;
use common::{ok, refused, s};

fn tmp() -> PathBuf {
    common::scratch("lever")
}

/// Tolerance on the output's stated 40°, degrees (α₀ is rounded to 0.001°).
const OUTPUT_TOL_DEG: f64 = 0.01;
/// Tolerance on lever 1's stated 1.5°, relative.
const LEVER1_TOL: f64 = 0.05;

#[test]
fn the_stated_strokes_are_reproduced_where_the_equations_allow() {
    let [l1, l2, out] = Geometry::default().strokes_deg(PAPER_STACK_UM).unwrap();
    let [p1, p2, p3] = PAPER_STAGES_DEG;
    assert!(
        (out - p3).abs() < OUTPUT_TOL_DEG,
        "output {out}° (paper {p3}°)"
    );
    assert!(
        (l1 / p1 - 1.0).abs() < LEVER1_TOL,
        "lever 1 {l1}° (paper {p1}°)"
    );
    assert!((l1 - 1.432).abs() < 1e-3, "lever 1 {l1}°");
    // The documented disagreement: eqs. 8–9 turn lever 2 by 12.1°, not 20°, for any α₀.
    assert!(
        (l2 - 12.12).abs() < 0.01 && (l2 - p2).abs() > 7.0,
        "lever 2 {l2}°"
    );
    let literal = Geometry {
        alpha0_deg: 0.0,
        ..Geometry::default()
    };
    let [_, l2_0, out_0] = literal.strokes_deg(PAPER_STACK_UM).unwrap();
    assert!(
        (l2_0 - l2).abs() < 1e-9,
        "α₀ moves lever 2: {l2_0}° vs {l2}°"
    );
    assert!((out_0 - 5.39).abs() < 0.01, "α₀ = 0: output {out_0}°");
}

#[test]
fn the_default_alpha0_is_the_branch_where_eq12_agrees_with_the_kinematics() {
    let g = Geometry::default();
    let a = lever::solve_alpha0(&g, PAPER_STACK_UM, 40.0, (70.0, 90.0)).unwrap();
    assert!((a - TABLE5_ALPHA0_DEG).abs() < 1e-3, "α₀ = {a}°");
    let other = lever::solve_alpha0(&g, PAPER_STACK_UM, 40.0, (60.0, 70.0)).unwrap();
    assert!(
        (other - 65.20).abs() < 0.01,
        "the other branch: α₀ = {other}°"
    );
    // On the default branch eq. 12's ratio matches the slope of eqs. 8–11 at 50 µm.
    let x = PAPER_STACK_UM * 1e-3;
    let eq12 = g.eq12_ratio_per_mm(&g.pose(x).unwrap());
    let slope = g.slope_rad_per_mm(x).unwrap();
    assert!(
        (eq12 / slope - 1.0).abs() < 0.005,
        "eq. 12 {eq12} vs slope {slope} 1/mm"
    );
    // On the other it does not.
    let h = Geometry {
        alpha0_deg: other,
        ..g
    };
    let ratio = h.eq12_ratio_per_mm(&h.pose(x).unwrap()) / h.slope_rad_per_mm(x).unwrap();
    assert!(ratio > 2.0, "other branch: eq. 12 / slope = {ratio}");
}

#[test]
fn eq11_as_transcribed_has_no_real_angle() {
    let literal = Geometry {
        alpha0_deg: 0.0,
        ..Geometry::default()
    };
    let r = literal.pose(0.0).unwrap().eq11_radicand;
    assert!((r + 0.846).abs() < 1e-3, "radicand {r}");
}

#[test]
fn f_k_is_monotone_from_zero_and_f_f_grows_with_the_stroke() {
    let p = LeverParams::default();
    let t = lever::table(&p, PAPER_STACK_UM, 101, OutputUnit::Arc).unwrap();
    assert_eq!(t.x_fhps[0], 0.0);
    assert!(t.x_fhps.windows(2).all(|w| w[1] > w[0]), "f_K not monotone");
    let end = 40f64.to_radians() * 1e3; // 40° of arc at 1 mm, µm
    let last = t.x_fhps[100];
    assert!((last - end).abs() < 0.2, "f_K(50 µm) = {last} µm of arc");
    assert!(
        t.preload_n.windows(2).all(|w| w[1] > w[0]),
        "f_F not increasing"
    );
    let deg = lever::table(&p, PAPER_STACK_UM, 101, OutputUnit::Deg).unwrap();
    assert!((deg.x_fhps[100] - 40.0).abs() < OUTPUT_TOL_DEG);
    assert_eq!(deg.preload_n, t.preload_n);
    let vw = LeverParams {
        load: lever::Load {
            reflection: Reflection::VirtualWork,
            ..p.load
        },
        ..p
    };
    let v = lever::table(&vw, PAPER_STACK_UM, 101, OutputUnit::Arc).unwrap();
    assert!(v.preload_n[0] < t.preload_n[0], "virtual work at rest");
    assert!((v.preload_n[100] / t.preload_n[100] - 1.0).abs() < 0.01);
}

/// `fpi lever` into `dir/name` with extra arguments; its output.
fn lever_table(dir: &Path, name: &str, extra: &[&str]) -> (PathBuf, String) {
    let out = dir.join(name);
    let mut args = vec!["lever", "--out", s(&out)];
    args.extend_from_slice(extra);
    let text = ok(&args);
    (out, text)
}

#[test]
fn the_table_round_trips_through_the_fem_reader() {
    let d = tmp();
    let (out, text) = lever_table(&d, "rt.csv", &["--params", "data/lever/table5.toml"]);
    assert!(
        text.contains("read back through the FEM reader: 401 points, 0 warning(s)"),
        "{text}"
    );
    assert!(text.contains("output 40.00"), "{text}");
    let back = FemMaps::read(&out).unwrap();
    assert!(back.warnings().is_empty(), "{:?}", back.warnings());
    let t = lever::table(
        &LeverParams::default(),
        PAPER_STACK_UM,
        lever::DEFAULT_POINTS,
        OutputUnit::Arc,
    )
    .unwrap();
    assert_eq!(back.x_pea(), &t.x_pea_um[..]);
    for (i, x) in t.x_pea_um.iter().enumerate() {
        assert!((back.stage_at(*x) - t.x_fhps[i]).abs() < 1e-9);
        assert!((back.preload_at(*x) - t.preload_n[i]).abs() < 1e-9);
        assert!((back.stack_for(t.x_fhps[i]) - x).abs() < 1e-6);
    }
    let (deg, text) = lever_table(&d, "deg.csv", &["--output", "deg", "--points", "51"]);
    assert!(text.contains("note: --output deg"), "{text}");
    let back = FemMaps::read(&deg).unwrap();
    assert_eq!(back.x_pea().len(), 51);
    assert!((back.stage_at(PAPER_STACK_UM) - 40.0).abs() < OUTPUT_TOL_DEG);
}

/// A parameter file with `text`, refused by `fpi lever` naming the file and `key`;
/// nothing is written.
fn refused_file(d: &Path, name: &str, text: &str, key: &str) {
    let p = d.join(name);
    std::fs::write(&p, text).unwrap();
    let out = d.join(format!("{name}.csv"));
    refused(
        &["lever", "--params", s(&p), "--out", s(&out)],
        &[s(&p), key],
    );
    assert!(!out.exists(), "{name}: written despite the error");
    let e = format!("{:#}", LeverParams::parse(text, name).unwrap_err());
    assert!(e.contains(name) && e.contains(key), "{e}");
}

#[test]
fn bad_parameter_files_are_refused_naming_the_key() {
    let d = tmp();
    let cases = [
        ("neg.toml", "[geometry]\nrb1_mm = -2.0\n", "geometry.rb1_mm"),
        ("zero.toml", "[output]\nradius_mm = 0\n", "output.radius_mm"),
        ("nan.toml", "[load]\ntorque_Nmm = nan\n", "load.torque_Nmm"),
        ("r12.toml", "[geometry]\nr12_mm = 70.0\n", "geometry.r12_mm"),
        (
            "a0.toml",
            "[geometry]\nalpha0_deg = 1000\n",
            "geometry.alpha0_deg",
        ),
        (
            "k.toml",
            "[load]\nstiffness_Nmm_per_rad = -1\n",
            "load.stiffness_Nmm_per_rad",
        ),
        ("unknown.toml", "[geometry]\nrb4_mm = 1.0\n", "rb4_mm"),
        ("type.toml", "[geometry]\nrb2_mm = \"4.36\"\n", "rb2_mm"),
        (
            "refl.toml",
            "[load]\nreflection = \"lever\"\n",
            "reflection",
        ),
        ("section.toml", "[gemoetry]\nrb1_mm = 2.0\n", "gemoetry"),
        ("contact.toml", "[geometry]\nrb2_mm = 20.0\n", "rb2_mm"),
    ];
    for (name, text, key) in cases {
        refused_file(&d, name, text, key);
    }
    // Refused when the table is made (the values read well, the table would not).
    for (name, text, key) in [
        (
            "radius.toml",
            "[output]\nradius_mm = 100\n",
            "output.radius_mm",
        ),
        (
            "torque.toml",
            "[load]\ntorque_Nmm = 1e4\n",
            "load.torque_Nmm",
        ),
    ] {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        let out = d.join(format!("{name}.csv"));
        refused(
            &["lever", "--params", s(&p), "--out", s(&out)],
            &[s(&p), key],
        );
        assert!(!out.exists(), "{name}: written despite the error");
    }
}

#[test]
fn bad_command_lines_are_refused_and_nothing_is_written() {
    let d = tmp();
    let out = d.join("bad.csv");
    for (args, wanted) in [
        (vec!["--points", "1"], "--points 1"),
        (vec!["--stroke-um", "600"], "--stroke-um 600"),
        (vec!["--stroke-um", "-5"], "must be > 0"),
        (
            vec!["--stroke-um", "0.001", "--points", "10001"],
            "resolves",
        ),
    ] {
        let mut a = vec!["lever", "--out", s(&out)];
        a.extend_from_slice(&args);
        refused(&a, &[wanted]);
        assert!(!out.exists());
    }
    // On the other α₀ branch the output turns back within 100 µm of stack.
    let p = d.join("turn.toml");
    std::fs::write(&p, "[geometry]\nalpha0_deg = 65.2\n").unwrap();
    let a = [
        "lever",
        "--params",
        s(&p),
        "--out",
        s(&out),
        "--stroke-um",
        "100",
    ];
    refused(&a, &[s(&p), "turns back", "alpha0_deg"]);
    assert!(!out.exists());
    refused(
        &["lever", "--params", s(&p), "--out", s(&p)],
        &["refusing to overwrite"],
    );
}

#[test]
fn fpi_predict_and_export_run_on_the_lever_table() {
    let d = tmp();
    let (fem, _) = lever_table(&d, "fem.csv", &[]);
    let model = d.join("fpi.toml");
    let rig = "data/pea-rig/preload_050N_sine_05Hz.csv.gz";
    ok(&[
        "calibrate",
        "--kind",
        "fpi",
        "--rig",
        rig,
        "--out",
        s(&model),
    ]);
    let pred = d.join("pred.csv");
    let drive = "data/stage-a/sine_05Hz.csv.gz";
    let args = [
        "predict",
        "--model",
        s(&model),
        "--fem",
        s(&fem),
        "--drive",
        drive,
    ];
    ok(&[&args[..], &["--out", s(&pred)]].concat());
    let text = std::fs::read_to_string(&pred).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,voltage_V,x_pea_um,preload_N,x_fhps_um")
    );
    let back = FemMaps::read(&fem).unwrap();
    let mut top: f64 = 0.0;
    for l in lines {
        let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
        assert!((v[4] - back.stage_at(v[2])).abs() < 1e-5, "{l}");
        top = top.max(v[4]);
    }
    assert!(
        top > 50.0,
        "the predicted output reaches only {top} µm of arc"
    );
    let fw = d.join("firmware.toml");
    let text = ok(&[
        "export",
        "--model",
        s(&model),
        "--fem",
        s(&fem),
        "--out",
        s(&fw),
    ]);
    assert!(text.contains("tables.f_k_inv"), "{text}");
    let (deg, _) = lever_table(&d, "deg.csv", &["--output", "deg"]);
    let fw = d.join("firmware-deg.toml");
    ok(&[
        "export",
        "--model",
        s(&model),
        "--fem",
        s(&deg),
        "--out",
        s(&fw),
    ]);
    assert!(fw.exists());
}
