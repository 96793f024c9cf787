//! The README's wiring table names the same pins, in the same order, as the
//! board file's (`firmware/src/bin/fpi-firmware/board.rs`, whose table sits
//! beside the code that takes the pins).

use std::path::Path;

/// The pin cells of the first Markdown table after `marker` in `text`, each line
/// stripped of `prefix` (`"//! "` for a doc comment); the header and rule rows
/// left out.
fn pins(text: &str, marker: &str, prefix: &str, column: usize) -> Vec<String> {
    let start = text.find(marker).unwrap_or_else(|| panic!("no {marker:?}"));
    text[start..]
        .lines()
        .map(|l| {
            l.trim_start()
                .strip_prefix(prefix.trim_end())
                .unwrap_or(l)
                .trim()
        })
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .map(|row| {
            let cell = row.split('|').nth(column + 1).unwrap_or("").trim();
            // "PA0 (ADC1 ch 0)" → "PA0"; "PA9 TX, PA10 RX (USART1)" → "PA9 TX, PA10 RX".
            cell.split(" (").next().unwrap_or(cell).to_string()
        })
        .collect()
}

#[test]
fn the_readme_wiring_table_names_the_board_files_pins() {
    let top = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let board =
        std::fs::read_to_string(top.join("firmware/src/bin/fpi-firmware/board.rs")).unwrap();
    let readme = std::fs::read_to_string(top.join("README.md")).unwrap();
    let from_board = pins(&board, "//! | signal | pin | peripheral |", "//!", 1);
    let from_readme = pins(&readme, "## Flashing a real board", "", 1);
    assert!(from_board.len() >= 6, "{from_board:?}");
    assert_eq!(
        from_readme, from_board,
        "README wiring table against board.rs"
    );
}
