//! The firmware model file's keys, from their one declaration
//! (`piezo_fpi::fields`: unit, stored format, range, default, doc) and the
//! serde sections of `piezo_sim::file` that read and write the file (its shape:
//! the type and whether a key is required, through `schemars`; the doc of the
//! text keys). `fpi reference model` prints the book's reference page from
//! them; a test fails when the two disagree on a key.

use piezo_fpi::fields::{Decl, Field, Range};
use serde_json::Value;

/// One key of the firmware model file.
#[derive(Debug, Clone, PartialEq)]
pub struct Key {
    /// `controller.rate_hz`; a key of an array of tables `creep[].tau_s`.
    pub path: String,
    /// `number`, `integer`, `string`, `boolean`, `array of number`, …
    pub kind: String,
    /// The file must hold it (else it is optional, or its section is).
    pub required: bool,
    /// Its doc: the declaration's, or the section's doc comment for a text key.
    pub doc: String,
    /// Its declaration; `None` for a text key (`format`, `provenance.*`, `notes`).
    pub decl: Option<Decl>,
}

/// The declaration of the file's key `path` (`tables.f_f.x0`, `creep[].tau_s`).
pub fn declared(path: &str) -> Option<Decl> {
    Field::keyed()
        .find(|f| f.to_string() == path)
        .map(Field::decl)
}

/// Every key of the firmware model file, section by section.
pub fn keys() -> Vec<Key> {
    let schema = schemars::schema_for!(piezo_sim::file::FirmwareModel);
    let root = schema.as_value();
    let defs = root.get("$defs").cloned().unwrap_or(Value::Null);
    let mut out = Vec::new();
    walk(root, &defs, ("", &[]), true, &mut out);
    out
}

/// The keys of the model file of several axes (`piezo_sim::file::AxesModel`)
/// other than its axes' models: each axis's table (`x`, `y`, `z`) is one row,
/// a whole firmware model under that prefix.
pub fn axes_keys() -> Vec<Key> {
    let schema = schemars::schema_for!(piezo_sim::file::AxesModel);
    let root = schema.as_value();
    let defs = root.get("$defs").cloned().unwrap_or(Value::Null);
    let mut out = Vec::new();
    walk(root, &defs, ("", &["x", "y", "z"]), true, &mut out);
    out
}

/// `v` with a `$ref` followed, and an `Option`'s `null` branch dropped.
fn resolve<'a>(v: &'a Value, defs: &'a Value) -> &'a Value {
    if let Some(r) = v.get("$ref").and_then(Value::as_str) {
        let name = r.rsplit('/').next().unwrap_or(r);
        return defs.get(name).map_or(v, |d| resolve(d, defs));
    }
    for alt in ["anyOf", "oneOf"] {
        if let Some(list) = v.get(alt).and_then(Value::as_array) {
            if let Some(t) = list.iter().find(|x| x.get("type") != Some(&"null".into())) {
                return resolve(t, defs);
            }
        }
    }
    v
}

/// The keys under the object schema `v`, their paths after `prefix`; a
/// key named in `whole` (a firmware model of its own) is one row.
fn walk(
    v: &Value,
    defs: &Value,
    (prefix, whole): (&str, &[&str]),
    required: bool,
    out: &mut Vec<Key>,
) {
    let Some(props) = v.get("properties").and_then(Value::as_object) else {
        return;
    };
    let needed: Vec<&str> = v
        .get("required")
        .and_then(Value::as_array)
        .map(|r| r.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    for (name, raw) in props {
        let path = format!("{prefix}{name}");
        let req = required && needed.contains(&name.as_str());
        let t = resolve(raw, defs);
        let doc = raw
            .get("description")
            .or_else(|| t.get("description"))
            .and_then(Value::as_str)
            .map(one_paragraph)
            .unwrap_or_default();
        if whole.contains(&name.as_str()) {
            out.push(Key {
                path: format!("{path}.*"),
                kind: "table: a firmware model".into(),
                required: req,
                doc,
                decl: None,
            });
            continue;
        }
        if t.get("properties").is_some() {
            walk(t, defs, (&format!("{path}."), &[]), req, out);
            continue;
        }
        if let Some(item) = t.get("items").map(|i| resolve(i, defs)) {
            if item.get("properties").is_some() {
                walk(item, defs, (&format!("{path}[]."), &[]), req, out);
                continue;
            }
        }
        let decl = declared(&path);
        out.push(Key {
            kind: kind(t, defs),
            required: req,
            doc: decl.map_or(doc, |d| one_paragraph(d.doc)),
            decl,
            path,
        });
    }
}

/// The JSON type of a leaf, as the reference names it.
fn kind(t: &Value, defs: &Value) -> String {
    let ty = match t.get("type") {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Array(a)) => a
            .iter()
            .filter_map(Value::as_str)
            .filter(|s| *s != "null")
            .collect::<Vec<_>>()
            .join(" or "),
        _ => "value".into(),
    };
    match t.get("items") {
        Some(i) if ty == "array" => format!("array of {}", kind(resolve(i, defs), defs)),
        _ => ty,
    }
}

/// A doc comment's lines as one paragraph, its rustdoc links as plain code
/// (the generated reference pages' doc column): `` [`X`] `` and
/// `` [`X`](crate::X) `` are `` `X` ``.
pub fn one_paragraph(doc: &str) -> String {
    without_links(
        &doc.split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
            .replace("[`", "`")
            .replace("`]", "`"),
    )
}

/// Rustdoc's link targets dropped: `` `X`(crate::X) `` (what
/// the brackets' removal leaves of a link) is `` `X` ``.
fn without_links(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find("`(") {
        let (head, tail) = rest.split_at(i + 1);
        out += head;
        let target_end = tail.find(')').filter(|&j| {
            let t = &tail[1..j];
            !t.is_empty() && !t.contains(' ') && !t.contains(".md") && !t.contains("://")
        });
        rest = match target_end {
            Some(j) => &tail[j + 1..],
            None => tail,
        };
    }
    out + rest
}

/// The book's reference page of the model file's keys (`fpi reference model`).
pub fn reference() -> String {
    let mut s = String::from(
        "# Model file keys\n\n\
         <!-- Generated by `fpi reference model` from the declaration \
         (`src/fields.rs`: unit, format, range, default, doc) and the file's sections \
         (`sim/src/file/`: type, required); a test fails when they differ. -->\n\n\
         Every key of the firmware model file (`firmware/model/NAME.toml`, written by \
         `fpi export` and extended by `fpi tune` and `fpi board autotune`), section by \
         section. A key of an optional section is needed only where the section is \
         there; `creep[]` is an array of tables (`[[creep]]`). *Stored as* is the \
         core's format in the model image (a corner or time constant is stored as its \
         rate per control tick); *host* keys are used by the host tools only. Every \
         value is checked when the file is read, and an error names the file, the key, \
         the value and the rule ([Model files](../model-file.md)); a static range is \
         the validator's own constant.\n\n\
         | Key | Type | Unit | Stored as | Range | Default | What it holds |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for k in keys() {
        let cell = |t: &str| t.replace('|', "\\|");
        let (unit, q, range) = match &k.decl {
            Some(d) => (d.unit, d.q.name, range_text(d)),
            None => ("", "text", String::new()),
        };
        let default = match (k.decl.and_then(|d| d.default), k.required) {
            (Some(d), _) => d.to_string(),
            (None, true) => "required".into(),
            (None, false) => "required in its section".into(),
        };
        s += &format!(
            "| `{}` | {} | {} | {} | {} | {} | {} |\n",
            k.path,
            k.kind,
            unit,
            q,
            cell(&range),
            cell(&default),
            cell(&k.doc)
        );
    }
    s += "\n## The model file of several axes\n\n\
          What `fpi board autotune` writes on a board of several axes (without `--axis`) and \
          `fpi board load` loads whole: each axis's firmware model under its axis's table \
          (`[x]`, `[y]`, `[z]`; every key above, under that prefix: `y.pi.w0_um_per_v`), and \
          the coupling its board's decoupling is made of. Square arrays are `[i][j]`, of axis \
          `i` per unit of axis `j`, one row per axis of the file, 0 on the diagonal; an entry \
          out of its range is named by its key, row and column ([Several axes](../axes.md)).\n\n\
          | Key | Type | Required | What it holds |\n|---|---|---|---|\n";
    for k in axes_keys() {
        s += &format!(
            "| `{}` | {} | {} | {} |\n",
            k.path,
            k.kind,
            if k.required { "yes" } else { "no" },
            k.doc.replace('|', "\\|")
        );
    }
    s
}

/// A declared range as the reference prints it.
fn range_text(d: &Decl) -> String {
    match d.range {
        Range::Format => "its format's".into(),
        Range::Within(lo, hi) => format!("{lo} … {hi}"),
        Range::Rule(r) => r.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn link_targets_are_dropped_and_other_parentheses_kept() {
        assert_eq!(
            without_links("see `Reply::Hello`(crate::Reply::Hello) (the board's)"),
            "see `Reply::Hello` (the board's)"
        );
        assert_eq!(without_links("`a` (b c)"), "`a` (b c)");
        assert_eq!(
            without_links("[the book](../x.md) `f`(../y.md)"),
            "[the book](../x.md) `f`(../y.md)"
        );
    }

    /// The file's sections hold exactly the declared keys, and the text keys.
    #[test]
    fn the_file_s_keys_are_the_declared_keys() {
        let all = keys();
        for k in &all {
            let text = k.path == "format"
                || k.path.starts_with("provenance.")
                || k.path.ends_with(".notes");
            assert_eq!(
                k.decl.is_some(),
                !text,
                "{}: a key of the file's sections that is not declared in src/fields.rs",
                k.path
            );
        }
        for f in Field::keyed() {
            assert!(
                all.iter().any(|k| k.path == f.to_string()),
                "{f:?} declares {f}, which the file's sections do not hold"
            );
        }
    }

    /// Every key the factory model's file holds is in the reference, and every
    /// key of the reference has its doc comment.
    #[test]
    fn every_key_of_the_factory_model_is_declared_with_its_doc() {
        let all = keys();
        for k in &all {
            assert!(!k.doc.is_empty(), "{k:?} has no doc comment");
        }
        let find = |p: &str| all.iter().find(|k| k.path == p);
        let rate = find("controller.rate_hz").expect("controller.rate_hz");
        assert!(rate.required && rate.kind == "integer", "{rate:?}");
        let gain = find("damping.gain_um_per_n_s").expect("damping.gain_um_per_n_s");
        assert!(!gain.required && gain.kind == "number", "{gain:?}");
        assert!(
            find("creep[].tau_s").is_some() || all.iter().any(|k| k.path.starts_with("creep[]."))
        );
        // The factory model's own keys, as written: each one is declared.
        let path = crate::data::project_root().join("firmware/model/stage-a.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let file: toml::Table = toml::from_str(&text).unwrap();
        let mut written = Vec::new();
        flatten(&toml::Value::Table(file), "", &mut written);
        for w in written {
            assert!(
                find(&w).is_some(),
                "{w} is in the factory model but not declared"
            );
        }
    }

    fn flatten(v: &toml::Value, prefix: &str, out: &mut Vec<String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let p = format!("{prefix}{k}");
                    match v {
                        toml::Value::Table(_) => flatten(v, &format!("{p}."), out),
                        toml::Value::Array(a)
                            if a.iter().all(|x| x.is_table()) && !a.is_empty() =>
                        {
                            for x in a {
                                flatten(x, &format!("{p}[]."), out);
                            }
                        }
                        _ => out.push(p),
                    }
                }
            }
            _ => out.push(prefix.trim_end_matches('.').to_string()),
        }
    }
}
