//! The book's reference page of the link protocol (`fpi reference protocol`),
//! read from its declaration: the source of `fpi-protocol` (`protocol/src/`),
//! parsed with `syn`, so that every message, field, wire number and doc comment
//! on the page is the one the firmware and the host compile.
//!
//! The crate is parsed rather than reflected on because what a reader needs is
//! in the declaration only: the wire numbers of `wire_enum!`, the fields of the
//! hand-encoded [`Command`](fpi_protocol::Command) and
//! [`Reply`](fpi_protocol::Reply), and the docs of each.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use quote::ToTokens;
use syn::parse::{Parse, ParseStream};
use syn::{Attribute, Fields, Item, Token};

use crate::method::keys::one_paragraph;

/// The declaration's files, as compiled.
const SOURCES: [(&str, &str); 9] = [
    (
        "protocol/src/lib.rs",
        include_str!("../../../protocol/src/lib.rs"),
    ),
    (
        "protocol/src/command.rs",
        include_str!("../../../protocol/src/command.rs"),
    ),
    (
        "protocol/src/reply.rs",
        include_str!("../../../protocol/src/reply.rs"),
    ),
    (
        "protocol/src/bench.rs",
        include_str!("../../../protocol/src/bench.rs"),
    ),
    (
        "protocol/src/modes.rs",
        include_str!("../../../protocol/src/modes.rs"),
    ),
    (
        "protocol/src/link.rs",
        include_str!("../../../protocol/src/link.rs"),
    ),
    (
        "protocol/src/record.rs",
        include_str!("../../../protocol/src/record.rs"),
    ),
    (
        "protocol/src/settings.rs",
        include_str!("../../../protocol/src/settings.rs"),
    ),
    // The fault codes a status reports: the core's.
    (
        "src/control/fault.rs",
        include_str!("../../../src/control/fault.rs"),
    ),
];

/// One field, or one variant of a fieldless enum, or one constant.
#[derive(Debug, Clone)]
struct Entry {
    name: String,
    /// The field's type; the variant's wire number; the constant's value.
    value: String,
    doc: String,
}

/// An enum or a struct with its doc and its entries (a variant with fields is
/// one entry per field, under the variant's entry).
#[derive(Debug, Clone, Default)]
struct Decl {
    doc: String,
    /// Variants (an enum) with their fields; a struct is one unnamed variant.
    variants: Vec<(Entry, Vec<Entry>)>,
}

/// Everything parsed from the crate, by name.
#[derive(Debug, Default)]
struct Protocol {
    decls: BTreeMap<String, Decl>,
    /// `wire_enum!`s: their variants with wire numbers.
    wire: BTreeMap<String, Decl>,
    /// Constants of the crate root and of `record`'s modules, by module.
    consts: BTreeMap<String, Vec<Entry>>,
}

/// A `wire_enum!`'s body: `#[doc] pub enum Name { #[doc] Variant = n (as "label")?, … }`.
struct WireEnum {
    attrs: Vec<Attribute>,
    name: syn::Ident,
    variants: Vec<(Vec<Attribute>, syn::Ident, syn::LitInt)>,
}

impl Parse for WireEnum {
    fn parse(input: ParseStream) -> syn::Result<Self> {
        let attrs = input.call(Attribute::parse_outer)?;
        input.parse::<Token![pub]>()?;
        input.parse::<Token![enum]>()?;
        let name = input.parse()?;
        let body;
        syn::braced!(body in input);
        let mut variants = Vec::new();
        while !body.is_empty() {
            let attrs = body.call(Attribute::parse_outer)?;
            let ident = body.parse()?;
            body.parse::<Token![=]>()?;
            let n = body.parse()?;
            if body.peek(Token![as]) {
                body.parse::<Token![as]>()?;
                body.parse::<syn::LitStr>()?;
            }
            if !body.is_empty() {
                body.parse::<Token![,]>()?;
            }
            variants.push((attrs, ident, n));
        }
        Ok(Self {
            attrs,
            name,
            variants,
        })
    }
}

/// The doc comment of `attrs`, lines joined.
fn doc(attrs: &[Attribute]) -> String {
    let lines: Vec<String> = attrs
        .iter()
        .filter(|a| a.path().is_ident("doc"))
        .filter_map(|a| match &a.meta {
            syn::Meta::NameValue(nv) => match &nv.value {
                syn::Expr::Lit(syn::ExprLit {
                    lit: syn::Lit::Str(s),
                    ..
                }) => Some(s.value()),
                _ => None,
            },
            _ => None,
        })
        // A link's reference definition (`[x]: path`) is no text.
        .filter(|l| !(l.trim_start().starts_with('[') && l.contains("]: ")))
        .collect();
    one_paragraph(&lines.join("\n"))
}

/// A type as written, spaced as rustfmt would.
fn type_text(ty: &syn::Type) -> String {
    let s = ty.to_token_stream().to_string();
    s.replace(" < ", "<")
        .replace("< ", "<")
        .replace(" >", ">")
        .replace(" ,", ",")
        .replace("& 'a ", "&")
        .replace("& ", "&")
        .replace(" ;", ";")
        .replace("[ ", "[")
        .replace(" ]", "]")
        .replace("{ ", "{")
        .replace(" }", "}")
        .replace(" :: ", "::")
        // A constant's path in a const generic: its name (the sizes' table).
        .replace("{crate::settings::", "")
        .replace("}>", ">")
}

fn fields(f: &Fields) -> Vec<Entry> {
    f.iter()
        .enumerate()
        .map(|(i, f)| Entry {
            name: f
                .ident
                .as_ref()
                .map_or_else(|| format!("{i}"), ToString::to_string),
            value: type_text(&f.ty),
            doc: doc(&f.attrs),
        })
        .collect()
}

fn consts(items: &[Item]) -> Vec<Entry> {
    items
        .iter()
        .filter_map(|i| match i {
            Item::Const(c) if matches!(c.vis, syn::Visibility::Public(_)) => Some(Entry {
                name: c.ident.to_string(),
                value: c.expr.to_token_stream().to_string().replace(' ', ""),
                doc: doc(&c.attrs),
            }),
            _ => None,
        })
        .collect()
}

impl Protocol {
    /// The crate's declarations.
    fn parse() -> Result<Self, String> {
        let mut p = Self::default();
        for (file, text) in SOURCES {
            let ast = syn::parse_file(text).map_err(|e| format!("{file}: {e}"))?;
            let module = file
                .rsplit('/')
                .next()
                .unwrap_or(file)
                .trim_end_matches(".rs");
            if module == "lib" || module == "settings" {
                p.consts
                    .entry("crate".into())
                    .or_default()
                    .extend(consts(&ast.items));
            }
            for item in &ast.items {
                p.item(module, item)?;
            }
        }
        Ok(p)
    }

    fn item(&mut self, module: &str, item: &Item) -> Result<(), String> {
        match item {
            Item::Enum(e) => {
                let variants = e
                    .variants
                    .iter()
                    .map(|v| {
                        let entry = Entry {
                            name: v.ident.to_string(),
                            // An explicit discriminant: the enum's code.
                            value: v
                                .discriminant
                                .as_ref()
                                .map_or_else(String::new, |(_, e)| e.to_token_stream().to_string()),
                            doc: doc(&v.attrs),
                        };
                        (entry, fields(&v.fields))
                    })
                    .collect();
                self.decls.insert(
                    e.ident.to_string(),
                    Decl {
                        doc: doc(&e.attrs),
                        variants,
                    },
                );
            }
            Item::Struct(s) if matches!(s.vis, syn::Visibility::Public(_)) => {
                let entry = Entry {
                    name: String::new(),
                    value: String::new(),
                    doc: String::new(),
                };
                self.decls.insert(
                    s.ident.to_string(),
                    Decl {
                        doc: doc(&s.attrs),
                        variants: vec![(entry, fields(&s.fields))],
                    },
                );
            }
            Item::Macro(m)
                if m.mac
                    .path
                    .segments
                    .last()
                    .is_some_and(|s| s.ident == "wire_enum") =>
            {
                let w: WireEnum = m
                    .mac
                    .parse_body()
                    .map_err(|e| format!("{module}.rs: wire_enum!: {e}"))?;
                let variants = w
                    .variants
                    .iter()
                    .map(|(attrs, ident, n)| {
                        let entry = Entry {
                            name: ident.to_string(),
                            value: n.to_string(),
                            doc: doc(attrs),
                        };
                        (entry, Vec::new())
                    })
                    .collect();
                self.wire.insert(
                    w.name.to_string(),
                    Decl {
                        doc: doc(&w.attrs),
                        variants,
                    },
                );
            }
            Item::Mod(m) => {
                if let Some((_, items)) = &m.content {
                    self.consts
                        .insert(format!("{module}::{}", m.ident), consts(items));
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn decl(&self, name: &str) -> Result<&Decl, String> {
        self.decls
            .get(name)
            .ok_or_else(|| format!("protocol/src: no declaration of {name}"))
    }

    fn wire(&self, name: &str) -> Result<&Decl, String> {
        self.wire
            .get(name)
            .ok_or_else(|| format!("protocol/src: no wire_enum! {name}"))
    }

    fn consts(&self, module: &str) -> Result<&[Entry], String> {
        self.consts
            .get(module)
            .map(Vec::as_slice)
            .ok_or_else(|| format!("protocol/src: no module {module}"))
    }
}

/// `|` escaped for a table cell.
fn cell(s: &str) -> String {
    s.replace('|', "\\|")
}

/// Fields as one table cell: `` `name: type` `` and the doc, one per line.
fn field_cell(fields: &[Entry]) -> String {
    if fields.is_empty() {
        return "—".into();
    }
    fields
        .iter()
        .map(|f| {
            let head = if f.name.parse::<usize>().is_ok() {
                format!("`{}`", f.value)
            } else {
                format!("`{}: {}`", f.name, f.value)
            };
            if f.doc.is_empty() {
                head
            } else {
                format!("{head} — {}", cell(&f.doc))
            }
        })
        .collect::<Vec<_>>()
        .join("<br>")
}

/// A tagged enum (`Command`, `Reply`, `BenchOrder`, …) with the wire numbers of
/// its kind enum: one row per variant.
fn tagged(out: &mut String, p: &Protocol, name: &str, kind: &str) -> Result<(), String> {
    let d = p.decl(name)?;
    let k = p.wire(kind)?;
    let _ = writeln!(out, "{}\n", d.doc);
    out.push_str("| # | Variant | Fields, in wire order | What it is |\n|---:|---|---|---|\n");
    let mut rows = Vec::new();
    for (v, fs) in &d.variants {
        let n: u8 = k
            .variants
            .iter()
            .find(|(e, _)| e.name == v.name)
            .and_then(|(e, _)| e.value.parse().ok())
            .ok_or_else(|| format!("{name}::{} has no {kind} wire number", v.name))?;
        rows.push((n, v, fs));
    }
    rows.sort_by_key(|r| r.0);
    for (n, v, fs) in rows {
        let _ = writeln!(
            out,
            "| {n} | `{}` | {} | {} |",
            v.name,
            field_cell(fs),
            cell(&v.doc)
        );
    }
    out.push('\n');
    Ok(())
}

/// A struct: one row per field.
fn structure(out: &mut String, p: &Protocol, name: &str) -> Result<(), String> {
    let d = p.decl(name)?;
    let _ = writeln!(out, "### `{name}`\n\n{}\n", d.doc);
    out.push_str("| Field | Type | What it holds |\n|---|---|---|\n");
    for (_, fs) in &d.variants {
        for f in fs {
            let _ = writeln!(out, "| `{}` | `{}` | {} |", f.name, f.value, cell(&f.doc));
        }
    }
    out.push('\n');
    Ok(())
}

/// A `wire_enum!` (or an enum with explicit codes): one row per variant.
fn numbered(out: &mut String, p: &Protocol, name: &str) -> Result<(), String> {
    let d = p.wire(name).or_else(|_| p.decl(name))?;
    let _ = writeln!(out, "### `{name}`\n\n{}\n", d.doc);
    out.push_str("| # | Variant | Meaning |\n|---:|---|---|\n");
    for (v, _) in &d.variants {
        let _ = writeln!(out, "| {} | `{}` | {} |", v.value, v.name, cell(&v.doc));
    }
    out.push('\n');
    Ok(())
}

/// Constants: one row each.
fn constants(out: &mut String, entries: &[Entry], what: &str) {
    let _ = writeln!(out, "| {what} | Value | Meaning |\n|---|---:|---|");
    for c in entries {
        let _ = writeln!(out, "| `{}` | {} | {} |", c.name, c.value, cell(&c.doc));
    }
    out.push('\n');
}

/// The book's reference page of the link protocol.
pub fn reference() -> Result<String, String> {
    let p = Protocol::parse()?;
    let version = p
        .consts("crate")?
        .iter()
        .find(|c| c.name == "VERSION")
        .map(|c| c.value.clone())
        .ok_or("protocol/src/lib.rs: no VERSION")?;
    let mut s = format!(
        "# The link protocol\n\n\
         <!-- Generated by `fpi reference protocol` from the declaration (`protocol/src/`, \
         the crate the firmware and the host both compile); a test fails when they differ. -->\n\n\
         Protocol version **{version}**. Every message the board's command link carries, as \
         declared: a request is a [header](#header), a command's wire number and its fields in \
         order; a reply is a [reply header](#replyheader), the reply's wire number and its \
         fields. How the fields become bytes (postcard, COBS, the CRC), worked examples and \
         what the board does with each command are in [The command link](../protocol.md). \
         Positions, voltages and forces are the core's raw `I16F16` bits (µm, V, N times \
         2¹⁶); frequencies are in mHz.\n\n"
    );
    s += "## Requests\n\n";
    structure(&mut s, &p, "Header")?;
    s += "### `Command`\n\n";
    tagged(&mut s, &p, "Command", "CommandKind")?;
    structure(&mut s, &p, "TriggerSettings")?;
    structure(&mut s, &p, "RasterOrder")?;
    s += "## Replies\n\n";
    structure(&mut s, &p, "ReplyHeader")?;
    s += "### `Reply`\n\n";
    tagged(&mut s, &p, "Reply", "ReplyKind")?;
    numbered(&mut s, &p, "Refusal")?;
    for name in [
        "Hello",
        "Status",
        "FaultReport",
        "ModelReport",
        "Counters",
        "Batch",
        "Analysis",
    ] {
        structure(&mut s, &p, name)?;
        if name == "FaultReport" {
            s += "The codes are the core's faults (`piezo_fpi::control::Fault`):\n\n";
            numbered(&mut s, &p, "Fault")?;
        }
        if name == "ModelReport" {
            s += "### `Origin`\n\n";
            tagged(&mut s, &p, "Origin", "OriginKind")?;
            s += "### `SlotReport`\n\n";
            tagged(&mut s, &p, "SlotReport", "SlotKind")?;
        }
    }
    s += "## Recordings\n\n";
    s += "### Signals\n\nThe mask of `Command::Record`, and the order of a sample's \
          values on the wire after its tick.\n\n";
    constants(&mut s, p.consts("record::signal")?, "Bit");
    s += "### Status bits\n\nThe bits of a recorded sample's `status` signal.\n\n";
    constants(&mut s, p.consts("record::status")?, "Bit");
    s += "### Line bits\n\nThe bits of a recorded sample's `lines` (the `TRIGGER` signal).\n\n";
    constants(&mut s, p.consts("record::lines")?, "Bit");
    structure(&mut s, &p, "Sample")?;
    s += "## Enumerations\n\nEach crosses the link as one byte, its wire number.\n\n";
    for name in [
        "Shape",
        "LoopMode",
        "SourceKind",
        "TriggerMode",
        "TriggerStart",
        "LinkKind",
        "BoardKind",
        "ResetReason",
        "FrontEndKind",
    ] {
        numbered(&mut s, &p, name)?;
    }
    s += "## The emulated board's bench\n\n### `BenchOrder`\n\n";
    tagged(&mut s, &p, "BenchOrder", "BenchKind")?;
    structure(&mut s, &p, "StageVariant")?;
    s += "## Sizes\n\n";
    constants(&mut s, p.consts("crate")?, "Constant");
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every command and reply the crate has is on the page with its wire
    /// number, and no rustdoc link target is left in the text.
    #[test]
    fn every_message_is_on_the_page_with_its_number() {
        let page = reference().unwrap();
        for k in fpi_protocol::CommandKind::ALL {
            let row = format!("| {} | `{k:?}` |", k.to_u8());
            assert!(page.contains(&row), "{row} not on the page");
        }
        for k in fpi_protocol::ReplyKind::ALL {
            let row = format!("| {} | `{k:?}` |", k.to_u8());
            assert!(page.contains(&row), "{row} not on the page");
        }
        for r in fpi_protocol::Refusal::ALL {
            let row = format!("| {} | `{r:?}` |", r.to_u8());
            assert!(page.contains(&row), "{row} not on the page");
        }
        assert!(page.contains(&format!("version **{}**", fpi_protocol::VERSION)));
        assert!(!page.contains("(crate::"), "a rustdoc link target is left");
    }
}
