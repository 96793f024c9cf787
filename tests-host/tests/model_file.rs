//! The firmware model file: the embedded one is valid, malformed ones are rejected
//! with the file and the key (the same checks `build.rs` runs before it embeds one).

use fpi_firmware::model;
use fpi_host::model_file::FirmwareModel;

fn embedded() -> String {
    model::MODEL_TOML.to_string()
}

fn error_of(text: &str) -> String {
    FirmwareModel::parse(text, "m.toml").expect_err("must be rejected")
}

#[test]
fn the_embedded_model_is_valid_and_round_trips() {
    let m = FirmwareModel::parse(&embedded(), model::MODEL_FILE).unwrap();
    assert_eq!(m.pi.thresholds_v.len(), model::OPERATORS);
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
        "creep[1].tau_s = 0.00001: creep time constant not longer than T_s / ln 2",
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
    assert!(
        e.contains("m.toml: not a firmware model file") && e.contains("line"),
        "{e}"
    );
    let text = embedded().replace("input_max_v = 150.0", "input_max_v = nan");
    let e = error_of(&text);
    assert!(
        e.contains("pi.input_max_v = NaN: not a finite value"),
        "{e}"
    );
    let e = error_of("format = \"something else\"\n");
    assert!(e.contains("m.toml: not a firmware model file"), "{e}");
}
