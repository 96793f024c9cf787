//! The model files: the firmware model file (the embedded one is valid, malformed
//! ones are rejected with the file and the key: the same checks `build.rs` runs
//! before it embeds one), and the calibrated (host) model file, whose validator
//! refuses models that cannot move or invert, by key and value, when reading and
//! before writing.

use fpi_firmware::board::factory_model;
use fpi_host::model_file::FirmwareModel;

fn embedded() -> String {
    factory_model::MODEL_TOML.to_string()
}

fn error_of(text: &str) -> String {
    FirmwareModel::parse(text, "m.toml").expect_err("must be rejected")
}

/// `m` edited by `edit` is refused with a message that contains `want`.
fn refused(m: &FirmwareModel, edit: &dyn Fn(&mut FirmwareModel), want: &str) {
    let mut bad = m.clone();
    edit(&mut bad);
    let e = error_of(&bad.to_toml().unwrap());
    assert!(e.contains(want), "{e}");
}

#[test]
fn the_embedded_model_is_valid_and_round_trips() {
    let m = FirmwareModel::parse(&embedded(), factory_model::MODEL_FILE).unwrap();
    assert_eq!(m.pi.thresholds_v.len(), factory_model::OPERATORS);
    let again = FirmwareModel::parse(&m.to_toml().unwrap(), "again").unwrap();
    assert_eq!(again, m);
}

#[test]
fn malformed_models_name_their_key() {
    let m = FirmwareModel::parse(&embedded(), "m.toml").unwrap();
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| {
        let mut bad = m.clone();
        edit(&mut bad);
        let e = error_of(&bad.to_toml().unwrap());
        assert!(e.starts_with("m.toml: ") && e.contains(want), "{e}");
    };
    check(
        &|b| b.pi.weights_um_per_v[0] = -1.0,
        "pi.weights_um_per_v[0] = -1: a partial weight sum S_j is not positive",
    );
    check(
        &|b| b.pi.thresholds_v[1] = -3.0,
        "pi.thresholds_v[1] = -3: a play-operator threshold is negative",
    );
    check(
        &|b| b.pi.thresholds_v.swap(0, 2),
        "pi.thresholds_v[1] = 20: play-operator thresholds are not sorted",
    );
    check(
        &|b| {
            b.pi.weights_um_per_v.pop();
        },
        "pi.weights_um_per_v has 8 values but pi.thresholds_v has 9",
    );
    check(
        &|b| b.pi.w0_um_per_v = 0.0,
        "pi.w0_um_per_v = 0: a partial weight sum S_j is not positive",
    );
    check(
        &|b| b.coupling.k_f_v_per_n = 0.7,
        "coupling.k_f_v_per_n = 0.7: not a finite value within ±0.499999",
    );
    check(
        &|b| b.coupling.k_q_v_per_n2 = 0.01,
        "coupling.k_q_v_per_n2 = 0.01: k_q beyond ±0.00195 V/N²",
    );
    check(
        &|b| b.controller.u_min_v = 200.0,
        "controller.u_min_v = 200: the lower limit exceeds the upper limit",
    );
    check(
        &|b| b.controller.force_source = "guessed".into(),
        "controller.force_source = \"guessed\": expected \"measured\" or \"predicted\"",
    );
    check(
        &|b| b.controller.reference_max_um = 500.0,
        "controller.reference_max_um = 500: the reference range reaches beyond the f_K⁻¹ table",
    );
    check(
        &|b| b.controller.safe_voltage_v = 160.0,
        "controller.safe_voltage_v = 160: the safe voltage lies outside the voltage limits",
    );
    check(
        &|b| b.controller.rate_hz = 50,
        "controller.rate_hz = 50: the control rate is outside 100..=200000 Hz",
    );
    check(
        &|b| b.controller.slew_v_per_ms = 0.0,
        "controller.slew_v_per_ms = 0: the slew limit is not positive",
    );
    check(
        &|b| b.creep[1].tau_s = 1e-5,
        "creep[1].tau_s = 1e-5: creep time constant not longer than T_s / ln 2",
    );
    check(
        &|b| b.tables.f_k.values[7] = 0.0,
        "tables.f_k.values[7] = 0: table values are not monotone (previous knot 2.14735",
    );
    check(
        &|b| b.tables.f_f.step_log2 = 3,
        "tables.f_f.step_log2 = 3: table knot spacing outside 2^-15..=1 units",
    );
    // The case the old, separate file check let through and the build then failed
    // on with a const-evaluation panic naming no key.
    check(
        &|b| b.tables.f_f.step_log2 = -16,
        "tables.f_f.step_log2 = -16: table knot spacing outside 2^-15..=1 units",
    );
    check(
        &|b| b.tables.f_k_inv.values.truncate(1),
        "tables.f_k_inv.values: a lookup table needs 2..=4096 knots",
    );
    // Tables that break the model's assumptions (a new user's falling f_F and
    // constant f_K were loaded, and the board faulted on the first move).
    check(
        &|b| {
            let first = b.tables.f_f.values[0];
            for (k, v) in b.tables.f_f.values.iter_mut().enumerate() {
                *v = first - 0.125 * k as f64;
            }
        },
        "tables.f_f.values[1] = 61.675: the preload falls as the stack extends",
    );
    check(
        &|b| b.tables.f_k.values.iter_mut().for_each(|v| *v = 20.0),
        "tables.f_k.values[1] = 20: the stage output does not rise as the stack extends, so \
         f_k has no inverse",
    );
    check(
        &|b| b.tables.f_k_inv.values.iter_mut().for_each(|v| *v *= 1.1),
        "f_k_inv does not invert f_k here",
    );
    check(
        &|b| {
            if let Some(d) = b.dead_zone.as_mut() {
                d.inverse.values[3] = 40.0;
            }
        },
        "dead_zone.inverse.values[3] = 40: neighbouring table values differ by 0.5 or more",
    );
}

#[test]
fn non_numbers_and_syntax_errors_give_line_and_column() {
    let text = embedded().replace("rate_hz = 20000", "rate_hz = \"fast\"");
    let e = error_of(&text);
    let line = text.lines().position(|l| l.contains("\"fast\"")).unwrap() + 1;
    assert!(
        e.starts_with(&format!("m.toml:{line}:11: not a firmware model file: ")),
        "{e}"
    );
    let text = embedded().replace("input_max_v = 150.0", "input_max_v = nan");
    let e = error_of(&text);
    assert!(
        e.contains("pi.input_max_v = NaN: not a finite value"),
        "{e}"
    );
    let e = error_of("format = \"something else\"\n");
    assert!(
        e.contains("m.toml:") && e.contains("not a firmware model file"),
        "{e}"
    );
}

/// A calibrated fpi model's file (as `fpi calibrate` writes it).
const HOST_MODEL: &str = r#"format = "piezo-fpi-model/1"
kind = "fpi"
dead_zone_softness_v = 0.0
offset_um = 0.0

[pi]
w0_um_per_v = 0.0645
thresholds_v = [10.0, 20.0, 30.0]
weights_um_per_v = [0.006, 0.01, 0.005]
input_max_v = 150.0

[coupling]
offset_v = 0.0
k_f_v_per_n = 0.1
k_q_v_per_n2 = 0.0
force_q_n = 0.0
compliance_um_per_n = 0.0

[output]
map = "identity"

[calibration]
created_by = "tests/model_file.rs"
files = []
rmse_um = 0.05
mte_um = 0.2
per_file = []
method = "by hand"
"#;

/// The error reading [`HOST_MODEL`] with `from` replaced by `to`.
fn host_error(from: &str, to: &str) -> String {
    use fpi_host::method::model::HostModel;
    assert!(HOST_MODEL.contains(from), "{from:?}");
    let text = HOST_MODEL.replacen(from, to, 1);
    format!(
        "{:#}",
        HostModel::parse(&text, "h.toml").expect_err("must be rejected")
    )
}

#[test]
fn host_models_that_cannot_move_or_invert_name_their_key() {
    use fpi_host::method::model::HostModel;
    HostModel::parse(HOST_MODEL, "h.toml").unwrap();
    let cases = [
        (
            ("w0_um_per_v = 0.0645", "w0_um_per_v = 0.0"),
            "pi.w0_um_per_v = 0: must be > 0 µm/V",
        ),
        (
            ("weights_um_per_v = [0.006,", "weights_um_per_v = [-0.07,"),
            "pi.weights_um_per_v[0] = -0.07: the slope w0 + w_1 = ",
        ),
        (
            ("0.01, 0.005]", "-0.0805, 0.005]"),
            "pi.weights_um_per_v[1] = -0.0805: the slope w0 + w_1 + … + w_2 = ",
        ),
        (
            ("dead_zone_softness_v = 0.0", "dead_zone_softness_v = -1.5"),
            "dead_zone_softness_v = -1.5: must be ≥ 0 V (0: the hard dead zone)",
        ),
        (
            ("compliance_um_per_n = 0.0", "compliance_um_per_n = -0.02"),
            "coupling.compliance_um_per_n = -0.02: must be within 0–0.499999 µm/N",
        ),
        (
            ("compliance_um_per_n = 0.0", "compliance_um_per_n = 1e9"),
            "coupling.compliance_um_per_n = 1e9: must be within 0–0.499999 µm/N",
        ),
        (
            ("thresholds_v = [10.0,", "thresholds_v = [-10.0,"),
            "pi.thresholds_v[0] = -10: thresholds are voltages ≥ 0 V",
        ),
        // A weight of 1e308 µm/V was predicted from (x_pea at the FEM table's
        // end) and named only by export, in 309 digits.
        (
            ("w0_um_per_v = 0.0645", "w0_um_per_v = 1e308"),
            "pi.w0_um_per_v = 1e308: the model's output over its input range (the magnitudes \
             of its weights and creep gains times pi.input_max_v = 150 V) reaches inf µm, \
             beyond 1000000 µm (a metre: no piezo stage's motion)",
        ),
        (
            ("0.01, 0.005]", "1e4, 0.005]"),
            "pi.weights_um_per_v[1] = 10000: the model's output over its input range",
        ),
        (
            ("w0_um_per_v = 0.0645", "w0_um_per_v = -1e308"),
            "pi.w0_um_per_v = -1e308: the model's output",
        ),
        (
            ("w0_um_per_v = 0.0645", "w0_um_per_v = nan"),
            "pi.w0_um_per_v = NaN: not finite",
        ),
    ];
    for ((from, to), want) in cases {
        let e = host_error(from, to);
        assert!(e.starts_with("h.toml: ") && e.contains(want), "{e}");
    }
}

#[test]
fn a_host_model_without_motion_is_not_written() {
    use fpi_host::method::model::HostModel;
    let mut m = HostModel::parse(HOST_MODEL, "h.toml").unwrap();
    m.pi.w0_um_per_v = 0.0;
    m.pi.weights_um_per_v = vec![0.0; 3];
    let dir = std::env::temp_dir().join(format!("fpi-model-file-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("still.toml");
    let e = format!("{:#}", m.write(&p).expect_err("must not be written"));
    assert!(
        e.contains("still.toml: not written")
            && e.contains("pi.w0_um_per_v and pi.weights_um_per_v are all 0"),
        "{e}"
    );
    assert!(!p.exists());
}

/// The amplifier's current limit and the stack's capacitance bound the slew the
/// model enforces per tick to `I_max / C` (eq. 14) when that is below its setting.
#[test]
fn the_current_limit_bounds_the_slew_per_tick() {
    let m = FirmwareModel::parse(&embedded(), "m.toml").unwrap();
    let step = |m: &FirmwareModel| {
        let (q, _) = m.check().unwrap();
        q.spec().max_step.to_num::<f64>()
    };
    let rate = m.controller.rate_hz as f64;
    let setting = step(&m);
    assert!((setting - m.controller.slew_v_per_ms * 1e3 / rate).abs() < 1e-4);
    let mut limited = m.clone();
    limited.controller.current_limit_ma = Some(100.0);
    limited.controller.capacitance_uf = Some(2.0);
    // 100 mA / 2 µF = 50 V/ms = 2.5 V per 50 µs tick.
    assert!((step(&limited) - 2.5).abs() < 1e-4, "{}", step(&limited));
    let again = FirmwareModel::parse(&limited.to_toml().unwrap(), "again").unwrap();
    assert_eq!(again, limited, "the keys round-trip");
    // A generous amplifier leaves the setting.
    limited.controller.current_limit_ma = Some(10_000.0);
    assert!((step(&limited) - setting).abs() < 1e-9);
    // Bad or half-given values are refused by key.
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| refused(&m, edit, want);
    check(
        &|b| b.controller.current_limit_ma = Some(100.0),
        "controller.current_limit_ma and controller.capacitance_uf go together",
    );
    check(
        &|b| {
            b.controller.current_limit_ma = Some(-1.0);
            b.controller.capacitance_uf = Some(2.0);
        },
        "controller.current_limit_ma = -1: not a positive finite current, mA",
    );
}

/// The feedback and shaping sections are checked by the core's validator,
/// naming their keys.
#[test]
fn feedback_and_shaping_sections_name_their_keys() {
    use piezo_sim::file::{FeedbackSection, ShapingSection};
    let m = FirmwareModel::parse(&embedded(), "m.toml").unwrap();
    let fb = FeedbackSection {
        kp: 0.1,
        ki_per_s: 120.0,
        limit_um: 4.0,
        position_min_um: -9.0,
        position_max_um: 49.0,
        position_tolerance_um: 6.0,
        watch_swing_um: None,
        notes: String::new(),
    };
    let mut good = m.clone();
    good.feedback = Some(fb.clone());
    good.shaping = Some(ShapingSection {
        sections: vec![[0.5, 0.0, 0.0, -0.5, 0.0]],
        preview_ticks: 0,
        taps: Vec::new(),
        notes: String::new(),
    });
    let again = FirmwareModel::parse(&good.to_toml().unwrap(), "again").unwrap();
    assert_eq!(again, good);
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| refused(&good, edit, want);
    check(
        &|b| b.feedback.as_mut().unwrap().ki_per_s = 40_000.0,
        "feedback.ki_per_s = 40000: a feedback gain is negative or beyond its range",
    );
    check(
        &|b| b.feedback.as_mut().unwrap().position_tolerance_um = 0.0,
        "feedback.position_tolerance_um = 0: the tolerance is not positive",
    );
    check(
        &|b| b.shaping.as_mut().unwrap().sections[0] = [0.6, 0.0, 0.0, -0.5, 0.0],
        "shaping.sections[0]: a filter section's static gain is not exactly 1",
    );
    check(
        &|b| b.shaping.as_mut().unwrap().sections[0] = [300.0, 0.0, 0.0, -0.5, 0.0],
        "shaping.sections[0][0] = 300: not a finite value within ±128",
    );
    check(
        &|b| b.shaping.as_mut().unwrap().preview_ticks = 8,
        "shaping.preview_ticks = 8: not within [0, 7] ticks (u8)",
    );
    check(
        &|b| b.shaping.as_mut().unwrap().preview_ticks = 3,
        "shaping.sections: a shaping that runs ahead (preview_ticks > 0) is its taps, not sections",
    );
    // A shaping that runs ahead: taps summing to 1, at most 16 of them.
    let mut ahead = good.clone();
    ahead.shaping = Some(ShapingSection {
        sections: Vec::new(),
        preview_ticks: 4,
        taps: vec![1.5, -0.25, -0.25],
        notes: String::new(),
    });
    let again = FirmwareModel::parse(&ahead.to_toml().unwrap(), "again").unwrap();
    assert_eq!(again, ahead);
    assert!(again.image().is_ok());
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| refused(&ahead, edit, want);
    check(
        &|b| b.shaping.as_mut().unwrap().taps[0] = 1.6,
        "shaping.taps: a filter section's static gain is not exactly 1",
    );
    check(
        &|b| b.shaping.as_mut().unwrap().taps = vec![0.0625; 17],
        "shaping.taps has 17 taps: the board runs at most 16",
    );
}

/// The embedded model with the loops of isr-bench's closed-loop model
/// (autotune's, stage as built) and their lead's baseline.
fn with_loops() -> FirmwareModel {
    use piezo_sim::file::{DampingSection, DynamicsSection, FeedbackSection, ShapingSection};
    let mut m = FirmwareModel::parse(&embedded(), "m.toml").unwrap();
    m.feedback = Some(FeedbackSection {
        kp: 0.75,
        ki_per_s: 1762.6,
        limit_um: 9.98,
        position_min_um: -10.0,
        position_max_um: 50.0,
        position_tolerance_um: 6.0,
        watch_swing_um: None,
        notes: String::new(),
    });
    m.dynamics = Some(DynamicsSection {
        mode_hz: 850.852,
        damping_ratio: 0.030_098,
        lag_hz: Some(2026.966),
        force_gain_n_per_um: Some(7.017),
        notes: String::new(),
    });
    m.damping = Some(DampingSection {
        gain_um_per_n_s: 1315.7,
        highpass_hz: 100.0,
        leak_hz: 100.0,
        limit_um: 39.9,
        lead_baseline: Some(0.88),
        notes: String::new(),
    });
    m.shaping = Some(ShapingSection {
        sections: Vec::new(),
        preview_ticks: 4,
        taps: vec![1.5, -0.25, -0.25],
        notes: String::new(),
    });
    m
}

/// The lead's baseline (`damping.lead_baseline`) travels in the model's image
/// and back; outside [0.5, 2), or without damping and a shaping that runs
/// ahead, it is refused with its key named.
#[test]
fn a_lead_baseline_names_its_key() {
    let m = with_loops();
    let text = m.to_toml().unwrap();
    assert!(text.contains("lead_baseline = 0.88"), "{text}");
    let again = FirmwareModel::parse(&text, "again").unwrap();
    assert_eq!(again, m);
    let with = m.image().unwrap();
    let mut without = m.clone();
    without.damping.as_mut().unwrap().lead_baseline = None;
    // One i32 more (the lead block, flag bit 8).
    assert_eq!(with.len(), without.image().unwrap().len() + 4);
    assert_eq!(u16::from_le_bytes([with[6], with[7]]) & 256, 256);
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| refused(&m, edit, want);
    check(
        &|b| b.damping.as_mut().unwrap().lead_baseline = Some(2.0),
        "damping.lead_baseline = 2: not within [0.5, 2) (I2F30)",
    );
    check(
        &|b| b.damping.as_mut().unwrap().lead_baseline = Some(0.4),
        "damping.lead_baseline = 0.4: not within [0.5, 2) (I2F30)",
    );
    check(
        &|b| {
            let s = b.shaping.as_mut().unwrap();
            s.preview_ticks = 0;
            s.taps.clear();
        },
        "damping.lead_baseline = 0.88: a lead baseline needs active damping ([damping]) and a \
         shaping that runs ahead (preview_ticks > 0)",
    );
}

/// The oscillation watch's half swing (`feedback.watch_swing_um`) travels in
/// the model's image and back; outside 0.075…0.2 µm, or without a position
/// loop, it is refused with its key named.
#[test]
fn a_watch_swing_names_its_key() {
    let mut m = with_loops();
    m.feedback.as_mut().unwrap().watch_swing_um = Some(0.1);
    let text = m.to_toml().unwrap();
    assert!(text.contains("watch_swing_um = 0.1"), "{text}");
    let again = FirmwareModel::parse(&text, "again").unwrap();
    assert_eq!(again, m);
    let with = m.image().unwrap();
    let mut without = m.clone();
    without.feedback.as_mut().unwrap().watch_swing_um = None;
    // One i32 more (the watch block, flag bit 9).
    assert_eq!(with.len(), without.image().unwrap().len() + 4);
    assert_eq!(u16::from_le_bytes([with[6], with[7]]) & 512, 512);
    let check = |edit: &dyn Fn(&mut FirmwareModel), want: &str| refused(&m, edit, want);
    for h in [0.05, 0.25] {
        check(
            &|b| b.feedback.as_mut().unwrap().watch_swing_um = Some(h),
            &format!(
                "feedback.watch_swing_um = {h}: the oscillation watch's half swing must lie \
                 within 0.075…0.2 µm"
            ),
        );
    }
    check(
        &|b| b.feedback.as_mut().unwrap().watch_swing_um = Some(f64::NAN),
        "feedback.watch_swing_um = NaN: not a finite value within ±4096 (I16F16 signal range)",
    );
}

/// [`with_loops`] with every optional number of `[controller]` given too.
fn with_every_key() -> FirmwareModel {
    let mut m = with_loops();
    let k = &mut m.controller;
    k.force_split_hz = Some(10.0);
    k.force_dynamic_limit_n = Some(4.0 * k.force_tolerance_n);
    k.current_limit_ma = Some(10_000.0);
    k.capacitance_uf = Some(2.0);
    m.feedback.as_mut().unwrap().watch_swing_um = Some(0.1);
    m
}

/// The value at `key` (`pi.weights_um_per_v[2]`, `creep[1].tau_s`) of a
/// file's TOML; a key the file does not hold fails the test, naming it.
fn value_at<'d>(doc: &'d mut toml::Value, key: &str) -> &'d mut toml::Value {
    let mut at = doc;
    for part in key.split('.') {
        let mut pieces = part.split('[');
        let name = pieces.next().unwrap();
        at = at
            .get_mut(name)
            .unwrap_or_else(|| panic!("{key}: the file has no {name}"));
        for index in pieces {
            at = &mut at[index.trim_end_matches(']').parse::<usize>().unwrap()];
        }
    }
    at
}

/// The text of `m` with the number at `key` (`pi.weights_um_per_v[2]`,
/// `creep[1].tau_s`) set to `v`.
fn with_number(m: &FirmwareModel, key: &str, v: f64) -> String {
    let mut doc: toml::Value = toml::from_str(&m.to_toml().unwrap()).unwrap();
    let at = value_at(&mut doc, key);
    assert!(at.is_float() || at.is_integer(), "{key}: {at:?}");
    *at = toml::Value::Float(v);
    toml::to_string(&doc).unwrap()
}

/// Every number of a firmware model file, given as a huge, infinite or
/// not-a-number value (and, where the rule wants it positive, as -1), is refused
/// with the file, the key, the value as the file gives it (`1e308`, not 309
/// digits) and the rule it breaks.
#[test]
fn every_number_out_of_its_range_names_file_key_value_and_rule() {
    use piezo_sim::quote::Num;
    let m = with_every_key();
    FirmwareModel::parse(&m.to_toml().unwrap(), "m.toml").unwrap();
    // (key, refused at -1 too)
    let keys: &[(&str, bool)] = &[
        ("pi.w0_um_per_v", true),
        ("pi.thresholds_v[2]", true),
        ("pi.weights_um_per_v[2]", false),
        ("pi.input_max_v", true),
        ("coupling.offset_v", false),
        ("coupling.k_f_v_per_n", false),
        ("coupling.k_q_v_per_n2", false),
        ("coupling.force_q_n", false),
        ("coupling.compliance_um_per_n", false),
        ("coupling.force_ref_n", false),
        ("dead_zone.forward.x0", false),
        ("dead_zone.forward.values[3]", false),
        ("dead_zone.inverse.values[3]", false),
        ("saturation.forward.values[3]", false),
        ("saturation.inverse.x0", false),
        ("creep[1].tau_s", true),
        ("creep[1].gain_um_per_v", false),
        ("controller.u_min_v", false),
        ("controller.u_max_v", true),
        ("controller.slew_v_per_ms", true),
        ("controller.reference_min_um", false),
        ("controller.reference_max_um", false),
        ("controller.force_min_n", false),
        ("controller.force_max_n", false),
        ("controller.force_tolerance_n", true),
        ("controller.safe_voltage_v", true),
        ("controller.current_limit_ma", true),
        ("controller.capacitance_uf", true),
        ("controller.force_split_hz", true),
        ("controller.force_dynamic_limit_n", true),
        ("tables.f_f.x0", false),
        ("tables.f_f.values[3]", false),
        ("tables.f_k.values[3]", false),
        ("tables.f_k_inv.x0", false),
        ("tables.f_k_inv.values[3]", false),
        ("feedback.kp", true),
        ("feedback.ki_per_s", true),
        ("feedback.limit_um", true),
        ("feedback.position_min_um", false),
        ("feedback.position_max_um", false),
        ("feedback.position_tolerance_um", true),
        ("feedback.watch_swing_um", true),
        ("dynamics.mode_hz", true),
        ("dynamics.damping_ratio", true),
        ("dynamics.lag_hz", true),
        ("dynamics.force_gain_n_per_um", true),
        ("damping.gain_um_per_n_s", true),
        ("damping.highpass_hz", true),
        ("damping.leak_hz", true),
        ("damping.limit_um", true),
        ("damping.lead_baseline", true),
        ("shaping.taps[0]", false),
    ];
    // The list holds every declared number (the integers, the choice and the
    // filter's sections are refused by the TOML reader and their own tests).
    use piezo_fpi::fields::Field;
    let listed = |k: &str| {
        keys.iter().any(|(x, _)| {
            let x = x.replace("[1]", "[]");
            x.split_once('[').map_or(x.as_str(), |(head, _)| head) == k || x == k
        })
    };
    for f in Field::DECLARED {
        let skip = matches!(
            f,
            Field::Rate | Field::PreviewTicks | Field::ForceSource | Field::Shaping
        );
        assert!(
            skip || listed(f.key()),
            "{} is declared but not tried here",
            f.key()
        );
    }
    let mut wrong = Vec::new();
    for &(key, negative) in keys {
        let values = [
            1e308,
            -1e308,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -1.0,
        ];
        // A huge current limit limits nothing: the slew is the model's.
        let huge = key != "controller.current_limit_ma";
        let wanted = |v: f64| (v != -1.0 || negative) && (v != 1e308 || huge);
        for v in values.into_iter().filter(|&v| wanted(v)) {
            let text = with_number(&m, key, v);
            // The key and the value, as the first key of the message or as the
            // bound it is compared with (`u_min_v = 0: … (controller.u_max_v = -1)`).
            let given = format!("{key} = {}", Num(v));
            match FirmwareModel::parse(&text, "m.toml") {
                Ok(_) => wrong.push(format!("{key} = {v}: accepted")),
                Err(e) if !(e.starts_with("m.toml: ") && e.contains(&given)) => {
                    wrong.push(format!("{key} = {v}: {e}"))
                }
                // The rule after the first value: a sentence, not just the value.
                Err(e) => {
                    let rule = e.split_once(": ").and_then(|(_, r)| r.split_once(": "));
                    if rule.is_none_or(|(_, r)| r.len() < 15) {
                        wrong.push(format!("{key} = {v}: no rule: {e}"));
                    }
                }
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    // The integers are refused by the TOML reader, at their line (which names
    // the key).
    let text = m.to_toml().unwrap();
    for key in ["rate_hz", "step_log2", "preview_ticks"] {
        let at = text.find(&format!("\n{key} = ")).unwrap() + 1;
        let end = at + text[at..].find('\n').unwrap();
        let bad = format!("{}{key} = 1e308{}", &text[..at], &text[end..]);
        let line = text[..at].lines().count() + 1;
        let e = FirmwareModel::parse(&bad, "m.toml").unwrap_err();
        assert!(
            e.starts_with(&format!("m.toml:{line}:"))
                && e.contains(&format!("(in \"{key} = 1e308\")")),
            "{e}"
        );
    }
}

/// A lag below the mode is refused naming both keys, their values and the rule
/// (it blamed the lag alone with the dynamics' general range message).
#[test]
fn a_lag_below_the_mode_names_both() {
    let m = with_loops();
    refused(
        &m,
        &|b| b.dynamics.as_mut().unwrap().lag_hz = Some(300.0),
        "m.toml: dynamics.lag_hz = 300: must be above dynamics.mode_hz = 850.852 (the lag's \
         corner lies above the mode; no lag: leave lag_hz out)",
    );
    refused(
        &m,
        &|b| b.dynamics.as_mut().unwrap().mode_hz = 3000.0,
        "dynamics.lag_hz = 2026.966: must be above dynamics.mode_hz = 3000",
    );
    refused(
        &m,
        &|b| b.dynamics.as_mut().unwrap().mode_hz = 12_000.0,
        "dynamics.mode_hz = 12000: the mode must lie from 1 Hz up to below the Nyquist \
         frequency, 10000 Hz at controller.rate_hz = 20000",
    );
}

/// The image of `m`, quantised and encoded without the validator (a changed
/// key need not leave a model that runs).
fn raw_image(m: &FirmwareModel) -> Vec<u8> {
    let q = m.quantize().unwrap();
    let spec = q.spec();
    let mut out = vec![0; piezo_fpi::model::image::encoded_len(&spec)];
    piezo_fpi::model::image::encode(&spec, &mut out).unwrap();
    out
}

/// `m` with the value at `key` (`creep[1].tau_s`; an array's element 1)
/// changed: a number by 1 % (at least 0.001, above every format's LSB), an integer by one, a choice to
/// the other one.
fn with_changed(m: &FirmwareModel, key: &str) -> FirmwareModel {
    let mut doc: toml::Value = toml::from_str(&m.to_toml().unwrap()).unwrap();
    let mut at = value_at(&mut doc, key);
    while at.is_array() {
        let i = at.as_array().map_or(1, |a| a.len().min(2) - 1);
        at = &mut at[i];
    }
    *at = match at {
        toml::Value::Float(v) => toml::Value::Float(*v + (0.01 * v.abs()).max(0.001)),
        toml::Value::Integer(v) => toml::Value::Integer(*v - 1),
        toml::Value::String(s) if s == "measured" => toml::Value::String("predicted".into()),
        other => panic!("{key}: {other:?}"),
    };
    doc.try_into().unwrap()
}

/// Every key the declaration (`src/fields.rs`) says the image carries reaches
/// the image: changing it in a file that has every section changes the image's
/// bytes, and the block (or flag) it is declared in is flagged in the header.
/// A key added to the declaration and to the file but not to the image's
/// encoding fails here.
#[test]
fn every_declared_key_reaches_the_image() {
    use piezo_fpi::fields::{Field, Image};
    let preview = with_every_key();
    let mut sections = with_every_key();
    sections.damping.as_mut().unwrap().lead_baseline = None;
    sections.shaping = Some(piezo_sim::file::ShapingSection {
        sections: vec![[0.5, 0.5, 0.0, 0.0, 0.0]],
        preview_ticks: 0,
        taps: Vec::new(),
        notes: String::new(),
    });
    let mut wrong = Vec::new();
    let mut checked = 0;
    for f in Field::keyed() {
        let d = f.decl();
        let flag = match d.image {
            Image::Host => continue,
            Image::Body => 0,
            Image::Block { flag, .. } | Image::Flag(flag) => flag,
        };
        // An array of tables' key at its element 1 (`creep[1].tau_s`); an
        // array's element is found by `with_changed`.
        let key = if d.key.contains("[]") {
            f.at(1).to_string()
        } else {
            f.to_string()
        };
        let m = if f == Field::Shaping {
            &sections
        } else {
            &preview
        };
        let before = raw_image(m);
        let after = raw_image(&with_changed(m, &key));
        let flags = u16::from_le_bytes([after[6], after[7]]);
        if after == before {
            wrong.push(format!("{key}: the image did not change"));
        } else if flags & flag != flag {
            wrong.push(format!("{key}: flag {flag} is not set"));
        }
        checked += 1;
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    assert!(checked > 60, "{checked}");
}
