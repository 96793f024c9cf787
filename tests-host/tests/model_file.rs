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
        "pi.weights_um_per_v[0]: partial sum S_1",
    );
    check(
        &|b| b.pi.thresholds_v[1] = -3.0,
        "pi.thresholds_v[1] = -3: thresholds must be >= 0",
    );
    check(&|b| b.pi.thresholds_v.swap(0, 2), "must be non-decreasing");
    check(
        &|b| {
            b.pi.weights_um_per_v.pop();
        },
        "pi.weights_um_per_v has",
    );
    check(
        &|b| b.pi.w0_um_per_v = 0.0,
        "pi.w0_um_per_v = 0: must be > 0",
    );
    check(
        &|b| b.coupling.k_f_v_per_n = 0.7,
        "coupling.k_f_v_per_n = 0.7: not a finite value within",
    );
    check(
        &|b| b.controller.u_min_v = 200.0,
        "controller.u_min_v = 200 exceeds controller.u_max_v",
    );
    check(
        &|b| b.controller.force_source = "guessed".into(),
        "controller.force_source",
    );
    check(
        &|b| b.controller.reference_max_um = 500.0,
        "outside the tables.f_k_inv grid",
    );
    check(
        &|b| b.tables.f_k.values[7] = 0.0,
        "tables.f_k.values[7] = 0: not monotone",
    );
    check(
        &|b| b.tables.f_f.step_log2 = 3,
        "tables.f_f.step_log2 = 3: must be -16..=0",
    );
    check(
        &|b| b.tables.f_k_inv.values.truncate(1),
        "tables.f_k_inv.values has 1 values",
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
