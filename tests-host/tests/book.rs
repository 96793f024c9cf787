//! The book (`docs/`, an mdBook) and the README hold together: every relative link
//! in the book's pages (`docs/src/SUMMARY.md` and every page under `docs/src/`)
//! and in `README.md` points to a file that exists, and a link's `#anchor` to a
//! heading of the page it points to, as mdBook makes its ids (lowercase, spaces to
//! `-`, punctuation other than `-` and `_` dropped, a repeated heading numbered
//! `-1`, `-2`…); every page under `docs/src/` is listed in `SUMMARY.md`; and the
//! README stays short (at most 200 lines), the manual being the book. A failure
//! names the file, the line and the link.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The README's longest allowed length, in lines.
const README_MAX_LINES: usize = 200;

fn top() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn book_src() -> PathBuf {
    top().join("docs").join("src")
}

/// `path` as the repository names it (`docs/src/x.md`, `README.md`).
fn shown(path: &Path) -> String {
    let top = top();
    path.strip_prefix(&top)
        .unwrap_or(path)
        .display()
        .to_string()
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every Markdown file under `dir`, sorted.
fn pages(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut dirs = vec![dir.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for entry in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|x| x == "md") {
                found.push(path);
            }
        }
    }
    found.sort();
    found
}

/// The lines of `text` outside fenced code blocks, with their 1-based numbers.
fn prose_lines(text: &str) -> Vec<(usize, &str)> {
    let mut fenced = false;
    let mut lines = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        if t.starts_with("```") || t.starts_with("~~~") {
            fenced = !fenced;
        } else if !fenced {
            lines.push((i + 1, line));
        }
    }
    lines
}

/// `line` without its inline code spans (`` `…` ``): a link inside one is text.
fn without_code(line: &str) -> String {
    let mut out = String::new();
    for (i, part) in line.split('`').enumerate() {
        if i % 2 == 0 {
            out.push_str(part);
        }
    }
    out
}

/// The targets of the inline links and images on `line`: `[text](target)`.
fn link_targets(line: &str) -> Vec<String> {
    let line = without_code(line);
    let mut targets = Vec::new();
    let mut rest = line.as_str();
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let end = after.find(')').unwrap_or(after.len());
        let target = after[..end].trim();
        if !target.is_empty() && !target.contains(' ') {
            targets.push(target.to_string());
        }
        rest = &after[end.min(after.len())..];
    }
    targets
}

/// A heading's text as mdBook reads it: inline code, emphasis and link syntax
/// gone, their text kept.
fn heading_text(raw: &str) -> String {
    let mut text = String::new();
    let mut rest = raw.trim().trim_end_matches('#').trim_end();
    // [text](target) → text
    while let Some(open) = rest.find('[') {
        let Some(close) = rest[open..].find("](").map(|c| open + c) else {
            break;
        };
        let Some(end) = rest[close..].find(')').map(|e| close + e) else {
            break;
        };
        text.push_str(&rest[..open]);
        text.push_str(&rest[open + 1..close]);
        rest = &rest[end + 1..];
    }
    text.push_str(rest);
    text.replace(['`', '*'], "")
}

/// mdBook's id of a heading's text: lowercase, whitespace to `-`, alphanumerics,
/// `-` and `_` kept, everything else dropped.
fn anchor(text: &str) -> String {
    text.trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| {
            if c.is_alphanumeric() || c == '_' || c == '-' {
                Some(c)
            } else if c.is_whitespace() {
                Some('-')
            } else {
                None
            }
        })
        .collect()
}

/// The ids of the headings of a page, a repeated one numbered as mdBook does.
fn heading_ids(text: &str) -> BTreeSet<String> {
    let mut ids = BTreeSet::new();
    for (_, line) in prose_lines(text) {
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if !(1..=6).contains(&hashes) || !line[hashes..].starts_with(' ') {
            continue;
        }
        let id = anchor(&heading_text(&line[hashes..]));
        let mut unique = id.clone();
        let mut n = 1;
        while ids.contains(&unique) {
            unique = format!("{id}-{n}");
            n += 1;
        }
        ids.insert(unique);
    }
    ids
}

/// What is wrong with the relative links of the Markdown file `file`, one line
/// each: `file:line: link: why`. External links (`scheme:`) are not checked.
fn broken_links(file: &Path) -> Vec<String> {
    let text = read(file);
    let dir = file.parent().unwrap();
    let mut broken = Vec::new();
    for (number, line) in prose_lines(&text) {
        for link in link_targets(line) {
            let scheme = link.split(['/', '#']).next().unwrap_or("");
            if scheme.contains(':') {
                continue;
            }
            let (path, fragment) = match link.split_once('#') {
                Some((p, f)) => (p, Some(f)),
                None => (link.as_str(), None),
            };
            let target = if path.is_empty() {
                file.to_path_buf()
            } else {
                dir.join(path)
            };
            let at = format!("{}:{number}: {link}", shown(file));
            if !target.exists() {
                broken.push(format!("{at}: no such file {}", shown(&target)));
                continue;
            }
            let Some(fragment) = fragment else { continue };
            if target.extension().is_none_or(|x| x != "md") {
                broken.push(format!("{at}: an anchor into a file that is not a page"));
            } else if !heading_ids(&read(&target)).contains(fragment) {
                broken.push(format!(
                    "{at}: no heading of {} has the id {fragment:?}",
                    shown(&target)
                ));
            }
        }
    }
    broken
}

#[test]
fn anchors_are_made_as_mdbook_makes_them() {
    let cases = [
        (
            "Rate dependence: `fpi identify` and `--dynamics`",
            "rate-dependence-fpi-identify-and---dynamics",
        ),
        (
            "The stage's correction: `[fem_correction]`",
            "the-stages-correction-fem_correction",
        ),
        (
            "Status, and what the checks cannot see",
            "status-and-what-the-checks-cannot-see",
        ),
        (
            "The main job: [`cargo demo`](x.md)",
            "the-main-job-cargo-demo",
        ),
    ];
    for (heading, id) in cases {
        assert_eq!(anchor(&heading_text(heading)), id, "{heading}");
    }
    let ids = heading_ids("# A\n\n```\n# not a heading\n```\n## A\n## B ##\n");
    let want: BTreeSet<String> = ["a", "a-1", "b"].map(String::from).into();
    assert_eq!(ids, want);
    assert_eq!(
        link_targets("[a](x.md#y) and `[b](z.md)` and ![c](img.svg)"),
        ["x.md#y", "img.svg"]
    );
}

#[test]
fn every_link_in_the_book_resolves() {
    let pages = pages(&book_src());
    assert!(
        pages.iter().any(|p| p.ends_with("SUMMARY.md")),
        "no docs/src/SUMMARY.md"
    );
    let broken: Vec<String> = pages.iter().flat_map(|p| broken_links(p)).collect();
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_readme_s_links_into_the_book_resolve() {
    let readme = top().join("README.md");
    let into_book = prose_lines(&read(&readme))
        .iter()
        .flat_map(|(_, line)| link_targets(line))
        .filter(|l| l.starts_with("docs/"))
        .count();
    assert!(into_book > 0, "README.md links nowhere into docs/");
    let broken = broken_links(&readme);
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn every_page_is_listed_in_the_summary() {
    let src = book_src();
    let summary = read(&src.join("SUMMARY.md"));
    let listed: BTreeSet<String> = prose_lines(&summary)
        .iter()
        .flat_map(|(_, line)| link_targets(line))
        .map(|l| l.split('#').next().unwrap_or_default().to_string())
        .collect();
    let unlisted: Vec<String> = pages(&src)
        .iter()
        .map(|p| {
            let rel = p.strip_prefix(&src).unwrap();
            rel.components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join("/")
        })
        .filter(|rel| rel != "SUMMARY.md" && !listed.contains(rel))
        .collect();
    assert!(
        unlisted.is_empty(),
        "pages under docs/src/ missing from docs/src/SUMMARY.md: {unlisted:?}"
    );
}

#[test]
fn the_readme_stays_short() {
    let lines = read(&top().join("README.md")).lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines, more than {README_MAX_LINES}: move the detail into the book (docs/src/)"
    );
}

/// The page of measured figures is its template (`docs/figures/page.md`)
/// with each command's output after it, as `docs/figures/regenerate` writes
/// it: no figure on it is copied by hand, and every command has an output.
#[test]
fn the_figures_page_is_its_template_with_the_commands_output() {
    let template = read(&top().join("docs").join("figures").join("page.md"));
    let page = read(&book_src().join("measured-figures.md"));
    let (mut text, mut block, mut problems) = (Vec::new(), None::<(usize, usize)>, Vec::new());
    for (n, line) in page.lines().enumerate() {
        match &mut block {
            Some((start, lines)) if line == "<!-- end run -->" => {
                // The opening and closing fences hold at least one line.
                if *lines < 3 {
                    problems.push(format!(
                        "docs/src/measured-figures.md:{}: the command has no output",
                        *start + 1
                    ));
                }
                block = None;
            }
            Some((_, lines)) => *lines += 1,
            None => {
                text.push(line);
                if line.starts_with("<!-- run: ") {
                    block = Some((n, 0));
                }
            }
        }
    }
    if let Some((start, _)) = block {
        problems.push(format!(
            "docs/src/measured-figures.md:{}: the output is not closed by <!-- end run -->",
            start + 1
        ));
    }
    let expected: Vec<&str> = template.lines().collect();
    if let Some(n) = (0..text.len().max(expected.len())).find(|&i| text.get(i) != expected.get(i)) {
        problems.push(format!(
            "docs/src/measured-figures.md differs from docs/figures/page.md outside the \
             commands' output at the template's line {}: {:?} against {:?} \
             (edit the template and run docs/figures/regenerate)",
            n + 1,
            text.get(n),
            expected.get(n)
        ));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The reference pages generated from a declaration are what their command
/// prints now: the runtime settings (`fpi reference settings`, from
/// `fpi_protocol::Settings`), the model file's keys (`fpi reference model`,
/// from `piezo_sim::file`'s sections), the command line (`fpi reference cli`, from
/// clap's declaration) and the link's messages (`fpi reference protocol`, from
/// `protocol/src/`). A setting or an option added without regenerating
/// the page fails here, with the command that regenerates it.
#[test]
fn the_generated_reference_pages_are_their_declarations() {
    let mut problems = Vec::new();
    for page in ["settings", "model", "cli", "protocol"] {
        let out = std::process::Command::new(fpi_tests::fpi_bin())
            .args(["reference", page])
            .output()
            .expect("running fpi reference");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let path = book_src().join("reference").join(format!("{page}.md"));
        if read(&path) != String::from_utf8_lossy(&out.stdout) {
            problems.push(format!(
                "{} is not what `fpi reference {page}` prints: run \
                 `cargo run --release -p fpi-host --bin fpi -- reference {page} > {}`",
                shown(&path),
                shown(&path)
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
