//! The project's copies of the datasets are identical to the shared recordings:
//! every file listed in `data/SHA256SUMS` decompresses to that hash, and, when the
//! shared folder sits next to the project, to the same bytes.

use fpi_host::data::{data_dir, read_bytes};
use sha2::{Digest, Sha256};
use std::path::PathBuf;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[test]
fn every_copy_matches_its_recorded_hash() {
    let list = std::fs::read_to_string(data_dir().join("SHA256SUMS")).expect("SHA256SUMS");
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/datasets");
    let mut n = 0;
    for line in list.lines().filter(|l| !l.trim().is_empty()) {
        let (hash, name) = line.split_once("  ").expect("sha256sum format");
        let rel = name.trim_start_matches("./");
        let copy = data_dir().join(format!("{rel}.gz"));
        let bytes = read_bytes(&copy).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            hex(&Sha256::digest(&bytes)),
            hash,
            "{} differs from the shared recording",
            copy.display()
        );
        if shared.exists() {
            let original = std::fs::read(shared.join(rel)).expect("shared file");
            assert!(
                original == bytes,
                "{rel} differs from ../shared/datasets/{rel}"
            );
        }
        n += 1;
    }
    assert_eq!(
        n,
        21 + 6 + 1 + 1,
        "pea-rig (21), stage-a (6 + fem.csv), micromanipulator (1)"
    );
    assert!(
        data_dir().join("real/micromanipulator/LICENSE").exists(),
        "licence of the real data"
    );
}
