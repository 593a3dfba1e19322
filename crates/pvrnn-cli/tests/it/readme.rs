//! The documents' claims about the command line match it: every `pvrnn` command shown in
//! the README and the docs' `sh` blocks names a real subcommand, and every flag it uses is
//! one that subcommand has; the training log's name is the one the README gives.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

fn repo() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

/// `pvrnn ...` command lines of a Markdown file's `sh` blocks, continuations joined.
fn commands(doc: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_sh = false;
    let mut pending = String::new();
    for line in doc.lines() {
        if let Some(lang) = line.trim_start().strip_prefix("```") {
            in_sh = !in_sh && lang.trim() == "sh";
            continue;
        }
        if !in_sh {
            continue;
        }
        // A comment after the command is not part of it.
        let code = line.split(" #").next().unwrap_or("").trim_end();
        pending.push_str(code.trim_end_matches('\\'));
        pending.push(' ');
        if code.ends_with('\\') {
            continue;
        }
        let command = std::mem::take(&mut pending);
        let command = command.trim();
        if command.starts_with("pvrnn ") {
            out.push(command.to_string());
        }
    }
    out
}

fn help(sub: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_pvrnn"))
        .args(sub)
        .arg("--help")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "`pvrnn {} --help` failed",
        sub.join(" ")
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn every_command_the_documents_show_exists() {
    let mut docs = vec![repo().join("README.md")];
    for entry in std::fs::read_dir(repo().join("docs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") {
            docs.push(path);
        }
    }
    let mut helps: BTreeMap<String, String> = BTreeMap::new();
    let mut checked = 0;
    for doc in &docs {
        let text = std::fs::read_to_string(doc).unwrap();
        for command in commands(&text) {
            let words: Vec<&str> = command
                .split_whitespace()
                .map(|w| w.trim_matches(|c| c == '[' || c == ']'))
                .collect();
            // The subcommand, and `report`'s own subcommand.
            let mut sub = vec![words[1]];
            if words[1] == "report" {
                sub.push(words[2]);
            }
            let key = sub.join(" ");
            let text = helps.entry(key.clone()).or_insert_with(|| help(&sub));
            for flag in words.iter().filter(|w| w.starts_with("--")) {
                let flag = flag.split('=').next().unwrap();
                assert!(
                    text.contains(&format!("{flag} ")) || text.contains(&format!("{flag}\n")),
                    "{}: `{command}` uses {flag}, which `pvrnn {key}` does not have",
                    doc.display()
                );
            }
            checked += 1;
        }
    }
    assert!(
        checked >= 20,
        "only {checked} commands found: is the parser broken?"
    );
}

#[test]
fn the_training_log_is_where_the_docs_say() {
    let cli = std::fs::read_to_string(repo().join("docs/cli.md")).unwrap();
    assert!(
        cli.contains("`<out stem>.log.csv` (`run.safetensors` -> `run.log.csv`)"),
        "docs/cli.md's training-log sentence changed: update this test with it"
    );
    // What `pvrnn train` writes (its help says the same).
    let text = help(&["train"]);
    assert!(
        text.contains("`run.safetensors` -> `run.log.csv`"),
        "{text}"
    );
}

/// The workspace crates a cell of the dependency table names (`–` = none; words after the
/// names, in parentheses, are comments).
fn crate_names(cell: &str) -> std::collections::BTreeSet<String> {
    cell.split('(')
        .next()
        .unwrap_or("")
        .split(',')
        .map(str::trim)
        .filter(|w| !w.is_empty() && *w != "–")
        .map(str::to_string)
        .collect()
}

#[test]
fn architecture_dependency_table_matches_the_manifests() {
    use std::collections::BTreeSet;
    let doc = std::fs::read_to_string(repo().join("ARCHITECTURE.md")).unwrap();
    let table = doc
        .split("<!-- dependencies: begin -->")
        .nth(1)
        .and_then(|rest| rest.split("<!-- dependencies: end -->").next())
        .expect("ARCHITECTURE.md has its dependency table between the markers");
    type Deps = BTreeMap<String, (BTreeSet<String>, BTreeSet<String>)>;
    let mut documented: Deps = BTreeMap::new();
    for line in table
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| crate"))
    {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        documented.insert(
            cells[1].to_string(),
            (crate_names(cells[2]), crate_names(cells[3])),
        );
    }
    let out = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let metadata: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let packages = metadata["packages"].as_array().unwrap();
    let workspace: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect();
    let mut actual: Deps = BTreeMap::new();
    for p in packages {
        let (mut normal, mut dev) = (BTreeSet::new(), BTreeSet::new());
        for d in p["dependencies"].as_array().unwrap() {
            let name = d["name"].as_str().unwrap().to_string();
            if !workspace.contains(&name) {
                continue;
            }
            if d["kind"].is_null() {
                normal.insert(name);
            } else if d["kind"] == "dev" {
                dev.insert(name);
            }
        }
        actual.insert(p["name"].as_str().unwrap().to_string(), (normal, dev));
    }
    assert_eq!(
        documented, actual,
        "ARCHITECTURE.md's dependency table (left) differs from the Cargo.toml files (right)"
    );
}
