//! The documents' claims about the desktop app's command line match it: every flag written
//! after `pvrnn-explorer` (a command in a code block or inline code, or
//! `cargo run ... -p pvrnn-explorer -- ...`) in the README, ARCHITECTURE.md and docs/ is
//! one that `pvrnn-explorer --help` lists.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))]

use std::path::{Path, PathBuf};
use std::process::Command;

fn documents() -> Vec<PathBuf> {
    let repo = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let mut docs = vec![repo.join("README.md"), repo.join("ARCHITECTURE.md")];
    for entry in std::fs::read_dir(repo.join("docs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") {
            docs.push(path);
        }
    }
    docs
}

/// The `--flags` written after each mention of `pvrnn-explorer` on a line, up to the end
/// of its inline code span.
fn flags_after_mentions(line: &str) -> Vec<String> {
    let mut flags = Vec::new();
    for (i, _) in line.match_indices("pvrnn-explorer") {
        let rest = &line[i + "pvrnn-explorer".len()..];
        let mut span = rest.split('`').next().unwrap_or("");
        // As cargo's package (`cargo test -p pvrnn-explorer --test ui`), the flags before
        // ` -- ` are cargo's; only what follows it goes to the app.
        if line[..i].ends_with("-p ") {
            span = span.split_once(" -- ").map_or("", |(_, app)| app);
        }
        flags.extend(
            span.split_whitespace()
                .filter(|w| w.starts_with("--") && w.len() > 2)
                .map(|w| {
                    w.split('=')
                        .next()
                        .unwrap()
                        .trim_end_matches([',', ')', '.'])
                        .to_string()
                }),
        );
    }
    flags
}

#[test]
fn every_explorer_flag_the_documents_show_exists() {
    let out = Command::new(env!("CARGO_BIN_EXE_pvrnn-explorer"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    let mut checked = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).unwrap();
        for (n, line) in text.lines().enumerate() {
            for flag in flags_after_mentions(line) {
                assert!(
                    help.contains(&format!("{flag} ")) || help.contains(&format!("{flag}\n")),
                    "{}:{}: `pvrnn-explorer {flag}` is not a flag of the app:\n{help}",
                    doc.display(),
                    n + 1
                );
                checked += 1;
            }
        }
    }
    // --bundle, --view, --screenshot and the benchmarks are all documented somewhere.
    assert!(checked >= 5, "only {checked} flags found in the documents");
}

#[test]
fn mentions_are_read_up_to_the_end_of_their_code_span() {
    assert_eq!(
        flags_after_mentions(
            "open it with `pvrnn-explorer --bundle B/`, or run `pvrnn train --resume`"
        ),
        ["--bundle"]
    );
    assert_eq!(
        flags_after_mentions("`cargo run --release -p pvrnn-explorer -- --bench-frames 300`"),
        ["--bench-frames"]
    );
    assert!(flags_after_mentions("`cargo test -p pvrnn-explorer --test ui`").is_empty());
}
