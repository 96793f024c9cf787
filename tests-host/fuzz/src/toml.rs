//! The model files on arbitrary text.
//!
//! * [`host`]: `HostModel::parse` (what `fpi calibrate` writes and `fpi export`,
//!   `fpi predict`, … read); a model it accepts is written back and read again
//!   (the same text), and evaluated as the float model for a few samples.
//! * [`firmware`]: `FirmwareModel::parse` (what `fpi export` writes, `build.rs` and
//!   `fpi board load` read), then `check` and `image`; the image goes into the
//!   board's store, which must accept it unless the board's capacity or hardware
//!   limits refuse it (the same validator ran on the host), and must hold the same
//!   model; the loaded model's controller and the float controller are stepped.

use fpi_firmware::board::capacity::{Store, BOARD};
use fpi_host::method::model::HostModel;
use piezo_fpi::error::ModelError;
use piezo_sim::file::FirmwareModel;

/// The name errors carry.
pub const NAME: &str = "fuzz.toml";

/// `HostModel::parse` on the input (UTF-8 only: `read` goes through
/// `read_to_string`).
pub fn host(input: &[u8]) {
    let Ok(text) = std::str::from_utf8(input) else {
        return;
    };
    let m = match HostModel::parse(text, NAME) {
        Ok(m) => m,
        Err(e) => {
            let msg = format!("{e:#}");
            assert!(
                msg.starts_with(NAME),
                "the error does not name the file: {msg}"
            );
            return;
        }
    };
    // What `HostModel::write` writes (without its comment line) reads back as the
    // same model. Compared as text: NaN is allowed in some keys.
    let written = ::toml::to_string(&m).expect("a parsed model serialises");
    let again = HostModel::parse(&written, NAME)
        .unwrap_or_else(|e| panic!("a written model does not read back: {e:#}\n{written}"));
    let rewritten = ::toml::to_string(&again).expect("a parsed model serialises");
    assert_eq!(
        written, rewritten,
        "a model changes when written and read back"
    );
    // The float model runs over the input domain.
    let model = m.model();
    let mut st = model.state(5e-5);
    let u_max = m.pi.input_max_v;
    for k in 0..48 {
        let u = u_max * (k as f64 / 24.0 - 0.25);
        let _ = model.step(&mut st, u, 50.0 + k as f64, 50.0);
    }
}

/// `FirmwareModel::parse`, `check`, `image`, and the image on the board.
pub fn firmware(input: &[u8]) {
    let Ok(text) = std::str::from_utf8(input) else {
        return;
    };
    let m = match FirmwareModel::parse(text, NAME) {
        Ok(m) => m,
        Err(e) => {
            assert!(e.starts_with(NAME), "the error does not name the file: {e}");
            return;
        }
    };
    let (q, shape) = m
        .check()
        .unwrap_or_else(|e| panic!("parse accepted a model check refuses: {e}"));
    let img = m
        .image()
        .unwrap_or_else(|e| panic!("a checked model has no image: {e}"));
    assert_eq!(
        img.len(),
        piezo_fpi::model::image::encoded_len(&q.spec()),
        "the image's length"
    );
    // The written file reads back as the same model.
    let written = m.to_toml().expect("a parsed model serialises");
    let again = FirmwareModel::parse(&written, NAME)
        .unwrap_or_else(|e| panic!("a written model does not read back: {e}\n{written}"));
    assert_eq!(
        again.to_toml().expect("a parsed model serialises"),
        written,
        "a model changes when written and read back"
    );
    assert_eq!(
        again.image().ok().as_deref(),
        Some(&img[..]),
        "the image changes"
    );
    // The board: what the host validated, the board's validator accepts, unless the
    // board's capacity or hardware limits refuse it.
    let mut store = Box::new(Store::new());
    match store.load(&img, &BOARD) {
        Ok(s) => {
            assert_eq!(s, shape, "the board sees another shape than the host");
            assert_eq!(store.spec(), q.spec(), "the image does not carry the model");
            crate::image::run(&store);
        }
        Err(e) => assert!(
            matches!(
                e.error,
                ModelError::RateMismatch
                    | ModelError::WidensHardwareLimit
                    | ModelError::OverCapacity
            ),
            "the board's validator refuses a model the host's accepted: {e}"
        ),
    }
    // The float reference of the same model.
    if let Some(c) = m.controller() {
        let mut st = c.initial_state();
        let (lo, hi) = (m.controller.reference_min_um, m.controller.reference_max_um);
        let f = m.coupling.force_ref_n.unwrap_or(0.0);
        for k in 0..48 {
            let x = lo + (hi - lo) * (k as f64 / 40.0 - 0.1);
            let _ = c.step(&mut st, x, f);
        }
    }
}
