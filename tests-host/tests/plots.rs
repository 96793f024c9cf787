//! The report figures ([`fpi_host::report::plots`]) from synthetic data shaped like the real
//! runs: each SVG must exist, start with `<svg` and stay below 1.5 MB; degenerate
//! inputs must not panic.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use fpi_host::report::plots::{self, Panel};

fn out_dir() -> PathBuf {
    std::env::temp_dir().join("fpi-host-plots")
}

fn check_svg(path: &Path) {
    let meta = std::fs::metadata(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(meta.len() > 0, "{} is empty", path.display());
    assert!(
        meta.len() < 1_500_000,
        "{} is {} bytes",
        path.display(),
        meta.len()
    );
    let text = std::fs::read_to_string(path).unwrap();
    assert!(
        text.starts_with("<svg"),
        "{} does not start with <svg",
        path.display()
    );
    assert!(text.trim_end().ends_with("</svg>"));
}

/// Deterministic small "noise" in [-1, 1].
fn noise(i: usize) -> f64 {
    let x = (i as f64 * 12.9898).sin() * 43_758.545_3;
    2.0 * (x - x.floor()) - 1.0
}

/// Triangle voltage 0 → 100 → 0 V, `cycles` times, `n` samples in all, with its
/// time base (s) at 10 kHz.
fn voltage(n: usize, cycles: usize) -> (Vec<f64>, Vec<f64>) {
    let per = n / cycles;
    let u = (0..n)
        .map(|i| {
            let p = (i % per) as f64 / per as f64;
            if p < 0.5 {
                200.0 * p
            } else {
                200.0 * (1.0 - p)
            }
        })
        .collect();
    let t = (0..n).map(|i| i as f64 / 10_000.0).collect();
    (u, t)
}

/// Stage extension (µm) at voltage `u` on the way up or down, scaled by `s`.
fn branch(u: f64, up: bool, s: f64) -> f64 {
    let base = 0.4 * u - 0.002 * u * u;
    let shift = if up { 0.0 } else { 0.0012 * u * (100.0 - u) };
    s * (base + shift)
}

/// A loop traced along `u`; `err` distorts it like an imperfect model.
fn trace(u: &[f64], s: f64, err: f64) -> Vec<f64> {
    let mut prev = 0.0;
    u.iter()
        .map(|&v| {
            let up = v >= prev;
            prev = v;
            branch(v, up, s) * (1.0 + err) + err * 4.0 * (v * PI / 50.0).sin()
        })
        .collect()
}

/// Loop scale at preload `f` (N): loops shrink as the preload grows.
fn scale(f: f64) -> f64 {
    1.0 / (1.0 + f / 150.0)
}

#[test]
fn loops_and_curves() {
    let dir = out_dir();
    let (u, t) = voltage(2000, 2);
    let measured: Vec<f64> = trace(&u, 1.0, 0.0)
        .iter()
        .enumerate()
        .map(|(i, x)| x + 0.05 * noise(i))
        .collect();
    let pi = trace(&u, 1.0, 0.06);
    let fpi = trace(&u, 1.0, 0.015);
    let path = dir.join("loops.svg");
    plots::loops(
        &path,
        "Stage output, 50 N preload",
        "voltage (V)",
        "stage output (µm)",
        &u,
        Some(&measured),
        &[("PI", &pi), ("FPI", &fpi)],
    )
    .unwrap();
    check_svg(&path);

    let e_pi: Vec<f64> = measured.iter().zip(&pi).map(|(m, p)| p - m).collect();
    let e_fpi: Vec<f64> = measured.iter().zip(&fpi).map(|(m, p)| p - m).collect();
    let path = dir.join("curves.svg");
    plots::curves(
        &path,
        "Prediction error, 50 N preload",
        "error (µm)",
        &t,
        &[("PI", &e_pi), ("FPI", &e_fpi)],
    )
    .unwrap();
    check_svg(&path);
}

#[test]
fn long_series_are_decimated() {
    let dir = out_dir();
    let (u, t) = voltage(70_000, 10);
    let measured: Vec<f64> = trace(&u, 1.0, 0.0)
        .iter()
        .enumerate()
        .map(|(i, x)| x + 0.2 * noise(i))
        .collect();
    let models: Vec<Vec<f64>> = [0.08, 0.04, 0.02, 0.01]
        .iter()
        .map(|&e| trace(&u, 1.0, e))
        .collect();
    let series: Vec<(&str, &[f64])> = ["PI", "FPI", "FPI-FFEM", "FPI (fixed)"]
        .iter()
        .zip(&models)
        .map(|(n, m)| (*n, m.as_slice()))
        .collect();
    let path = dir.join("loops_long.svg");
    plots::loops(
        &path,
        "Long run (70 000 samples)",
        "voltage (V)",
        "stage output (µm)",
        &u,
        Some(&measured),
        &series,
    )
    .unwrap();
    check_svg(&path);

    let errors: Vec<Vec<f64>> = models
        .iter()
        .map(|m| m.iter().zip(&measured).map(|(a, b)| a - b).collect())
        .collect();
    let series: Vec<(&str, &[f64])> = ["PI", "FPI", "FPI-FFEM", "FPI (fixed)"]
        .iter()
        .zip(&errors)
        .map(|(n, m)| (*n, m.as_slice()))
        .collect();
    let path = dir.join("curves_long.svg");
    plots::curves(
        &path,
        "Prediction error, long run",
        "error (µm)",
        &t,
        &series,
    )
    .unwrap();
    check_svg(&path);
}

#[test]
fn surface_family_and_path() {
    let (u, _) = voltage(400, 1);
    let preloads = [25.0, 50.0, 75.0, 100.0, 125.0, 150.0];
    let family: Vec<(f64, Vec<(f64, f64)>)> = preloads
        .iter()
        .map(|&f| {
            let x = trace(&u, scale(f), 0.0);
            (f, u.iter().copied().zip(x).collect())
        })
        .collect();
    // In the stage the preload follows the extension (spring of 5 N/µm on 30 N).
    let mut prev = 0.0;
    let path3d: Vec<(f64, f64, f64)> = u
        .iter()
        .map(|&v| {
            let up = v >= prev;
            prev = v;
            // Fixed point of x = branch(u) * scale(30 + 5 x), a few iterations.
            let mut x = 0.0;
            for _ in 0..20 {
                x = branch(v, up, scale(30.0 + 5.0 * x));
            }
            (v, 30.0 + 5.0 * x, x)
        })
        .collect();
    let path = out_dir().join("surface.svg");
    plots::surface(
        &path,
        "Hysteresis loops at constant preload and the loop in the stage",
        &family,
        &path3d,
    )
    .unwrap();
    check_svg(&path);
}

#[test]
fn bars_grouped() {
    let groups: Vec<String> = [25, 50, 75, 100, 125, 150]
        .iter()
        .map(|f| format!("{f} N"))
        .collect();
    let pi = vec![0.42, 0.55, 0.71, 0.86, 1.02, 1.21];
    let fpi = vec![0.21, 0.19, 0.24, 0.22, 0.26, 0.25];
    let ffem = vec![0.18, 0.17, 0.2, 0.21, 0.22, 0.23];
    let path = out_dir().join("bars.svg");
    plots::bars(
        &path,
        "RMS prediction error by preload",
        "RMS error (µm)",
        &groups,
        &[("PI", pi), ("FPI", fpi), ("FPI-FFEM", ffem)],
    )
    .unwrap();
    check_svg(&path);
}

#[test]
fn panels_grid() {
    let (u, _) = voltage(3000, 1);
    let preloads = [25.0, 50.0, 75.0, 100.0, 125.0, 150.0];
    let data: Vec<[Vec<f64>; 3]> = preloads
        .iter()
        .map(|&f| {
            let s = scale(f);
            let m: Vec<f64> = trace(&u, s, 0.0)
                .iter()
                .enumerate()
                .map(|(i, x)| x + 0.05 * noise(i))
                .collect();
            [m, trace(&u, s, 0.05), trace(&u, s, 0.01)]
        })
        .collect();
    let panels: Vec<Panel> = preloads
        .iter()
        .zip(&data)
        .map(|(f, [m, pi, fpi])| Panel {
            title: format!("{f} N"),
            x: &u,
            measured: Some(m.as_slice()),
            series: vec![("PI", pi.as_slice()), ("FPI", fpi.as_slice())],
        })
        .collect();
    let path = out_dir().join("panels.svg");
    plots::loop_panels(
        &path,
        "Measured and predicted loops by preload",
        "voltage (V)",
        "output (µm)",
        &panels,
    )
    .unwrap();
    check_svg(&path);
    // Six panels of 70 000 samples and three lines each stay small.
    let (u_long, _) = voltage(70_000, 10);
    let long: Vec<[Vec<f64>; 3]> = preloads
        .iter()
        .map(|&f| {
            let s = scale(f);
            let m: Vec<f64> = trace(&u_long, s, 0.0)
                .iter()
                .enumerate()
                .map(|(i, x)| x + 0.1 * noise(i))
                .collect();
            [m, trace(&u_long, s, 0.05), trace(&u_long, s, 0.01)]
        })
        .collect();
    let long_panels: Vec<Panel> = preloads
        .iter()
        .zip(&long)
        .map(|(f, [m, pi, fpi])| Panel {
            title: format!("{f} N"),
            x: &u_long,
            measured: Some(m.as_slice()),
            series: vec![("PI", pi.as_slice()), ("FPI", fpi.as_slice())],
        })
        .collect();
    let path = out_dir().join("panels_long.svg");
    plots::loop_panels(
        &path,
        "Long runs",
        "voltage (V)",
        "output (µm)",
        &long_panels,
    )
    .unwrap();
    check_svg(&path);
    for n in [1, 2, 4, 5] {
        let path = out_dir().join(format!("panels_{n}.svg"));
        plots::loop_panels(&path, "Panels", "voltage (V)", "output (µm)", &panels[..n]).unwrap();
        check_svg(&path);
    }
}

#[test]
fn degenerate_inputs_do_not_panic() {
    let dir = out_dir().join("degenerate").join("nested");
    let empty: &[f64] = &[];
    let nan = [f64::NAN; 5];
    let mixed = [
        0.0,
        f64::NAN,
        1.0,
        f64::INFINITY,
        2.0,
        3.0,
        f64::NEG_INFINITY,
    ];
    let flat = [2.5; 10];
    let x10: Vec<f64> = (0..10).map(f64::from).collect();
    let one = [1.0];
    let huge = [f64::MAX, -f64::MAX, 0.0];
    let tiny = [1e-300, 2e-300, 3e-300];
    let alternating: Vec<f64> = (0..9000)
        .map(|i| if i % 2 == 0 { f64::NAN } else { i as f64 })
        .collect();

    let p = |name: &str| dir.join(name);
    let _ = plots::loops(&p("l0.svg"), "", "", "", empty, None, &[]);
    let _ = plots::loops(
        &p("l1.svg"),
        "t",
        "x",
        "y",
        empty,
        Some(empty),
        &[("a", empty)],
    );
    let _ = plots::loops(
        &p("l2.svg"),
        "t",
        "x",
        "y",
        &nan,
        Some(&nan),
        &[("a", &nan)],
    );
    let _ = plots::loops(
        &p("l3.svg"),
        "t",
        "x",
        "y",
        &mixed,
        Some(&mixed),
        &[("a", &flat)],
    );
    let _ = plots::loops(
        &p("l4.svg"),
        "t",
        "x",
        "y",
        &x10,
        Some(&flat),
        &[("a", &flat)],
    );
    let _ = plots::loops(
        &p("l5.svg"),
        "t",
        "x",
        "y",
        &one,
        Some(&one),
        &[("a", &one)],
    );
    let _ = plots::loops(
        &p("l6.svg"),
        "t",
        "x",
        "y",
        &huge,
        Some(&huge),
        &[("a", &tiny)],
    );
    let _ = plots::loops(&p("l7.svg"), "t", "x", "y", &tiny, Some(&tiny), &[]);
    let _ = plots::loops(
        &p("l8.svg"),
        "t",
        "x",
        "y",
        &alternating,
        Some(&alternating),
        &[],
    );
    let _ = plots::curves(&p("c0.svg"), "", "", empty, &[]);
    let _ = plots::curves(&p("c1.svg"), "t", "y", &x10, &[("a", &nan), ("b", &flat)]);
    let _ = plots::curves(&p("c2.svg"), "t", "y", &x10, &[("a", &mixed), ("b", empty)]);
    let _ = plots::curves(&p("c3.svg"), "t", "y", &huge, &[("a", &huge)]);
    let _ = plots::surface(&p("s0.svg"), "", &[], &[]);
    let _ = plots::surface(
        &p("s1.svg"),
        "t",
        &[
            (f64::NAN, vec![(1.0, 1.0)]),
            (5.0, vec![]),
            (6.0, vec![(f64::NAN, 0.0)]),
        ],
        &[(f64::NAN, 1.0, 2.0), (1.0, 1.0, 1.0)],
    );
    let _ = plots::surface(
        &p("s2.svg"),
        "t",
        &[(5.0, vec![(1.0, 1.0), (1.0, 1.0)])],
        &[],
    );
    let _ = plots::bars(&p("b0.svg"), "", "", &[], &[]);
    let g: Vec<String> = vec!["a".into(), "b".into()];
    let _ = plots::bars(&p("b1.svg"), "t", "y", &g, &[]);
    let _ = plots::bars(&p("b2.svg"), "t", "y", &g, &[("a", vec![f64::NAN])]);
    let _ = plots::bars(
        &p("b3.svg"),
        "t",
        "y",
        &g,
        &[("a", vec![-1.0, 2.0, 3.0]), ("b", vec![])],
    );
    let _ = plots::bars(&p("b4.svg"), "t", "y", &g, &[("a", vec![0.0, 0.0])]);
    let _ = plots::bars(&p("b5.svg"), "t", "y", &[], &[("a", vec![1.0])]);
    let _ = plots::loop_panels(&p("p0.svg"), "", "", "", &[]);
    let bad = Panel {
        title: String::new(),
        x: empty,
        measured: Some(&nan),
        series: vec![("a", &flat), ("b", empty)],
    };
    let many: Vec<Panel> = (0..8).map(|_| bad.clone()).collect();
    let _ = plots::loop_panels(&p("p1.svg"), "t", "x", "y", &[bad]);
    let _ = plots::loop_panels(&p("p2.svg"), "t", "x", "y", &many);
    // Whatever happened above, files that were written are well-formed.
    for entry in std::fs::read_dir(&dir).unwrap() {
        check_svg(&entry.unwrap().path());
    }
}

#[test]
fn bode_draws_the_coherence_panel_only_with_a_coherence() {
    use nalgebra::Complex;
    use plots::BodeSeries;
    let dir = out_dir().join("bode");
    let f: Vec<f64> = (0..40)
        .map(|k| 20.0 * 200f64.powf(k as f64 / 39.0))
        .collect();
    let h: Vec<Complex<f64>> = f
        .iter()
        .map(|f| {
            let s = Complex::new(0.0, f / 850.0);
            Complex::new(1.0, 0.0) / (s * s + s * 0.06 + 1.0)
        })
        .collect();
    let measured = |name| BodeSeries {
        name,
        f_hz: f.clone(),
        h: h.clone(),
        fit_f_hz: f.clone(),
        fit_h: h.clone(),
        coherence_f_hz: vec![],
        coherence: vec![],
    };
    // The board's analyser: no coherence, one series without a fit.
    let board = [
        measured("undamped"),
        BodeSeries {
            fit_f_hz: vec![],
            fit_h: vec![],
            ..measured("damped (IFF)")
        },
    ];
    let path = dir.join("board.svg");
    plots::bode(&path, "board", &board).unwrap();
    check_svg(&path);
    let svg = std::fs::read_to_string(&path).unwrap();
    assert!(svg.contains("phase (deg)") && !svg.contains("coherence"));
    // A chirp's identification: a coherence per frequency.
    let chirp = [BodeSeries {
        coherence_f_hz: f.clone(),
        coherence: f.iter().map(|f| 1.0 - f / 1e4).collect(),
        ..measured("chirp")
    }];
    let path = dir.join("chirp.svg");
    plots::bode(&path, "chirp", &chirp).unwrap();
    check_svg(&path);
    assert!(std::fs::read_to_string(&path)
        .unwrap()
        .contains("coherence"));
}
