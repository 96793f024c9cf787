//! The committed corpus as regression tests: every input under `corpus/<target>/`
//! through the function its fuzz target runs, on stable Rust and without
//! libFuzzer (`cargo test` here). Crashes the fuzzer found are kept in the corpus
//! (`crash-…` files), so they run here too.

use std::path::Path;

fn replay(target: &str, run: fn(&[u8])) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target);
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "{}: no corpus", dir.display());
    for f in files {
        let bytes = std::fs::read(&f).expect("corpus file readable");
        // Printed (shown for a failing test) to name the input that failed.
        println!("{}", f.display());
        run(&bytes);
    }
}

#[test]
fn csv() {
    replay("csv", fpi_fuzz::csv::run);
}

#[test]
fn toml_host() {
    replay("toml_host", fpi_fuzz::toml::host);
}

#[test]
fn toml_firmware() {
    replay("toml_firmware", fpi_fuzz::toml::firmware);
}

#[test]
fn model_image() {
    replay("model_image", fpi_fuzz::image::raw);
}

#[test]
fn model_image_edit() {
    replay("model_image_edit", fpi_fuzz::image::edited);
}

#[test]
fn link_bytes() {
    replay("link_bytes", fpi_fuzz::link::bytes);
}

#[test]
fn link_frames() {
    replay("link_frames", fpi_fuzz::link::ops);
}

/// The seeds that are real inputs reach past the readers and validators (so the
/// fuzzer starts from the deep paths, not only from refusals).
#[test]
fn real_seeds_are_accepted() {
    use fpi_firmware::board::capacity::{Store, BOARD};
    use fpi_host::method::model::HostModel;
    use piezo_sim::file::FirmwareModel;

    let seeds = |target: &str| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("corpus")
            .join(target);
        let mut v: Vec<_> = std::fs::read_dir(dir)
            .expect("corpus")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                let n = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
                !n.starts_with("bad-") && !n.starts_with("crash-") && n.len() < 40
            })
            .map(|p| (p.clone(), std::fs::read(p).expect("readable")))
            .collect();
        v.sort();
        v
    };
    let scratch = std::env::temp_dir().join(format!("fpi-fuzz-seeds-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).expect("scratch folder");
    for (p, bytes) in seeds("csv") {
        let file = scratch.join(if bytes[0] & 0x80 != 0 {
            "s.csv.gz"
        } else {
            "s.csv"
        });
        std::fs::write(&file, &bytes[1..]).expect("written");
        assert!(
            fpi_fuzz::csv::read(&file, bytes[0]),
            "{}: refused",
            p.display()
        );
    }
    let _ = std::fs::remove_dir_all(&scratch);
    for (p, bytes) in seeds("toml_host") {
        let text = String::from_utf8(bytes).expect("UTF-8");
        HostModel::parse(&text, "seed").unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
    }
    for (p, bytes) in seeds("toml_firmware") {
        let text = String::from_utf8(bytes).expect("UTF-8");
        FirmwareModel::parse(&text, "seed").unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    }
    for (p, bytes) in seeds("model_image") {
        let mut store = Box::new(Store::new());
        store
            .load(&bytes, &BOARD)
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    }
}
