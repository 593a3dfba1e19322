//! `docs/config.md` is generated from the doc comments of `src/config.rs` and the paper's
//! values (`ModelConfig::default()`); this test fails when the two drift apart.
//! Regenerate with `UPDATE_DOCS=1 cargo test -p pvrnn-core --test it config_docs::`.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

use pvrnn_core::ModelConfig;
use serde_json::Value;

#[derive(Debug, Default)]
struct Field {
    name: String,
    ty: String,
    doc: String,
}

#[derive(Debug, Default)]
struct Item {
    doc: String,
    is_enum: bool,
    /// Struct fields, or enum variants (name = the serialised value).
    members: Vec<Field>,
}

/// `Foo` -> `foo`, `FastFirst` -> `fast_first`.
fn snake(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.extend(c.to_lowercase());
    }
    out
}

/// Public structs and enums of a Rust source with their doc comments.
fn items(source: &str) -> BTreeMap<String, Item> {
    let mut items = BTreeMap::new();
    let mut doc: Vec<String> = Vec::new();
    let mut current: Option<(String, Item)> = None;
    for line in source.lines() {
        let trimmed = line.trim();
        if let Some(text) = trimmed.strip_prefix("///") {
            doc.push(text.trim().replace('\\', ""));
            continue;
        }
        if trimmed.starts_with("#[") {
            continue;
        }
        let header = trimmed
            .strip_prefix("pub struct ")
            .map(|r| (r, false))
            .or_else(|| trimmed.strip_prefix("pub enum ").map(|r| (r, true)));
        if let Some((rest, is_enum)) = header
            && rest.ends_with('{')
            && current.is_none()
        {
            let name = rest.trim_end_matches('{').trim().to_string();
            let item = Item {
                doc: doc.join(" "),
                is_enum,
                members: Vec::new(),
            };
            current = Some((name, item));
        } else if line == "}" {
            if let Some((name, item)) = current.take() {
                items.insert(name, item);
            }
        } else if let Some((_, item)) = &mut current {
            let member = if item.is_enum {
                let v = trimmed.trim_end_matches(',');
                (!v.is_empty() && v.chars().all(char::is_alphanumeric))
                    .then(|| (snake(v), String::new()))
            } else {
                trimmed.strip_prefix("pub ").and_then(|r| {
                    let (name, ty) = r.split_once(':')?;
                    Some((
                        name.to_string(),
                        ty.trim().trim_end_matches(',').to_string(),
                    ))
                })
            };
            if let Some((name, ty)) = member {
                item.members.push(Field {
                    name,
                    ty,
                    doc: doc.join(" "),
                });
            }
        }
        doc.clear();
    }
    items
}

/// A default value as TOML writes it.
fn show(v: &Value) -> String {
    match v {
        Value::Null => "(none)".into(),
        Value::String(s) => format!("`\"{s}\"`"),
        other => format!("`{other}`"),
    }
}

fn section(out: &mut String, items: &BTreeMap<String, Item>, table: &str, ty: &str, value: &Value) {
    let item = &items[ty];
    let title = if table.is_empty() {
        "Top level".to_string()
    } else {
        format!("`[{table}]`")
    };
    writeln!(out, "\n## {title}\n\n{}\n", item.doc).unwrap();
    writeln!(out, "| field | paper's value | meaning |\n|---|---|---|").unwrap();
    let mut nested = Vec::new();
    for f in &item.members {
        let inner =
            f.ty.strip_prefix("Option<")
                .map_or(f.ty.as_str(), |t| t.trim_end_matches('>'));
        match items.get(inner) {
            Some(sub) if !sub.is_enum => {
                writeln!(
                    out,
                    "| `{}` | see `[{}]` | {} |",
                    f.name,
                    join(table, &f.name),
                    f.doc
                )
                .unwrap();
                nested.push((f, inner));
            }
            Some(sub) => {
                let values: Vec<String> = sub
                    .members
                    .iter()
                    .map(|v| format!("`\"{}\"`: {}", v.name, v.doc.trim_end_matches('.')))
                    .collect();
                writeln!(
                    out,
                    "| `{}` | {} | {} One of: {} |",
                    f.name,
                    show(&value[&f.name]),
                    f.doc,
                    values.join("; ")
                )
                .unwrap();
            }
            None => writeln!(
                out,
                "| `{}` | {} | {} |",
                f.name,
                show(&value[&f.name]),
                f.doc
            )
            .unwrap(),
        }
    }
    for (f, inner) in nested {
        section(out, items, &join(table, &f.name), inner, &value[&f.name]);
    }
}

fn join(table: &str, field: &str) -> String {
    if table.is_empty() {
        field.to_string()
    } else {
        format!("{table}.{field}")
    }
}

fn render() -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let source = std::fs::read_to_string(root.join("src/config.rs")).unwrap();
    let items = items(&source);
    let defaults = serde_json::to_value(ModelConfig::default()).unwrap();
    let mut out = String::from(
        "# The model configuration\n\n\
         <!-- Generated from the doc comments of crates/pvrnn-core/src/config.rs by\n\
         `UPDATE_DOCS=1 cargo test -p pvrnn-core --test it config_docs::`; do not edit by hand. -->\n\n\
         Every model file carries its configuration (JSON metadata `config`). `pvrnn config`\n\
         prints the paper's as TOML and `pvrnn config --model M` a model's; edit a copy and pass\n\
         it to `pvrnn init --config my.toml`. Fields left out keep the paper's values. Points\n\
         the paper leaves open are marked [decided]: the value is this project's decision,\n\
         documented in the model specification ([model.md](model.md)).\n",
    );
    section(&mut out, &items, "", "ModelConfig", &defaults);
    out
}

#[test]
fn config_md_is_generated_from_the_doc_comments() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/config.md");
    let fresh = render();
    // Every field documented: an empty meaning is a field someone forgot to explain.
    for line in fresh.lines().filter(|l| l.starts_with("| `")) {
        assert!(!line.ends_with("|  |"), "undocumented field: {line}");
    }
    if std::env::var_os("UPDATE_DOCS").is_some() {
        std::fs::write(&path, &fresh).unwrap();
    }
    let stored = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        stored == fresh,
        "docs/config.md is out of date: run `UPDATE_DOCS=1 cargo test -p pvrnn-core --test it config_docs::`"
    );
}
