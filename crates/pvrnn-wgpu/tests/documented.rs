//! docs/gpu.md cannot drift from the backend's knobs: every `PVRNN_WGPU_*` variable the
//! sources read is documented there, and every one it documents is still read.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))] // reads files

use std::collections::BTreeSet;
use std::path::Path;

/// Every `PVRNN_WGPU_NAME` in `text`.
fn variables(text: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (at, _) in text.match_indices("PVRNN_WGPU_") {
        let name: String = text[at..]
            .chars()
            .take_while(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || *c == '_')
            .collect();
        found.insert(name.trim_end_matches('_').to_string());
    }
    found
}

fn sources(dir: &Path, text: &mut String) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, text);
        } else if path.extension().is_some_and(|e| e == "rs") {
            text.push_str(&std::fs::read_to_string(&path).unwrap());
        }
    }
}

#[test]
fn every_environment_variable_is_documented_in_docs_gpu_md() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut code = String::new();
    sources(&crate_dir.join("src"), &mut code);
    let read = variables(&code);
    let docs = std::fs::read_to_string(crate_dir.join("../../docs/gpu.md")).unwrap();
    let documented = variables(&docs);
    assert!(
        read.contains("PVRNN_WGPU_MIN_WORK"),
        "the scan found {read:?}"
    );
    let undocumented: Vec<_> = read.difference(&documented).collect();
    assert!(
        undocumented.is_empty(),
        "not in docs/gpu.md: {undocumented:?}"
    );
    let gone: Vec<_> = documented.difference(&read).collect();
    assert!(
        gone.is_empty(),
        "docs/gpu.md names what the backend no longer reads: {gone:?}"
    );
}
