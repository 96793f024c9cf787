//! The book's wiring table (`docs/src/flashing.md`, *Flashing a real board*) names
//! the same pins, for the same front ends, in the same order, as the board
//! definition's (`firmware/src/board/definition.rs`), and the board definition's code
//! takes every pin its table names and no other.

use std::collections::BTreeSet;
use std::path::Path;

/// The rows' cells of the first Markdown table after `marker` in `text`, each
/// line stripped of `prefix` (`"//!"` for a doc comment); the header and rule
/// rows left out.
fn rows(text: &str, marker: &str, prefix: &str) -> Vec<Vec<String>> {
    let start = text.find(marker).unwrap_or_else(|| panic!("no {marker:?}"));
    text[start..]
        .lines()
        .map(|l| l.trim_start().strip_prefix(prefix).unwrap_or(l).trim())
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .map(|row| row.split('|').map(|c| c.trim().to_string()).collect())
        .collect()
}

/// A row's pin cell without its peripheral: "PA0 (ADC1 ch 0)" → "PA0";
/// "PA9 TX, PA10 RX (USART1)" → "PA9 TX, PA10 RX".
fn pin(row: &[String]) -> String {
    let cell = &row[2];
    cell.split(" (").next().unwrap_or(cell).to_string()
}

/// The port pins a cell names: "PC6, PC7, PC8" → pc6, pc7, pc8 (as the HAL's
/// fields spell them).
fn port_pins(cell: &str) -> Vec<String> {
    cell.split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| {
            w.len() >= 3
                && w.starts_with('P')
                && w.as_bytes()[1].is_ascii_uppercase()
                && w[2..].chars().all(|c| c.is_ascii_digit())
        })
        .map(str::to_ascii_lowercase)
        .collect()
}

/// The port pins the code (not the comments) of `text` takes: `a.pa5`, `c.pc4`…
fn pins_in_code(text: &str) -> BTreeSet<String> {
    let mut taken = BTreeSet::new();
    for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
        for (i, _) in line.match_indices(".p") {
            let rest = &line[i + 1..];
            let end = rest
                .find(|c: char| !c.is_ascii_alphanumeric())
                .unwrap_or(rest.len());
            taken.extend(port_pins(&rest[..end].to_ascii_uppercase()));
        }
    }
    taken
}

#[test]
fn the_book_s_wiring_table_names_the_board_definitions_pins() {
    let top = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let def = std::fs::read_to_string(top.join("firmware/src/board/definition.rs")).unwrap();
    let page = std::fs::read_to_string(top.join("docs/src/flashing.md")).unwrap();
    let from_def = rows(&def, "//! | signal | pin | peripheral | front end |", "//!");
    let from_page = rows(&page, "# Flashing a real board", "");
    assert!(from_def.len() >= 20, "{from_def:?}");
    let def_cells: Vec<(String, String)> =
        from_def.iter().map(|r| (pin(r), r[4].clone())).collect();
    let page_cells: Vec<(String, String)> =
        from_page.iter().map(|r| (pin(r), r[3].clone())).collect();
    assert_eq!(
        page_cells, def_cells,
        "docs/src/flashing.md wiring table (pin, front end) against board_def.rs"
    );
    for (_, front) in &def_cells {
        assert!(["internal", "precision", "both"].contains(&front.as_str()));
    }
}

#[test]
fn the_board_definition_takes_the_pins_its_table_names() {
    let top = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let def = std::fs::read_to_string(top.join("firmware/src/board/definition.rs")).unwrap();
    let named: BTreeSet<String> =
        rows(&def, "//! | signal | pin | peripheral | front end |", "//!")
            .iter()
            .flat_map(|r| port_pins(&pin(r)))
            .collect();
    assert!(named.contains("pa5") && named.contains("pb13"), "{named:?}");
    assert_eq!(
        pins_in_code(&def),
        named,
        "pins in the code against the table"
    );
}
