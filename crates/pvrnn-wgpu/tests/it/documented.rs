//! The environment variables the workspace reads are the ones docs/cli.md lists, in one
//! place ("Environment variables"), and none of them is a switch of the wgpu backend: what
//! it computes is chosen by typed options (`WgpuOptions`: `pvrnn --gpu-recurrence`,
//! `--weights-on-host`, `--wgpu-checks`, `bench --profile-kernels`), not by the
//! environment.

use std::collections::BTreeSet;
use std::path::Path;

/// The project's prefix, spelt so that this file holds no name of its own.
const PREFIX: &str = concat!("PVRNN", "_");

/// Every name with the project's prefix that follows `opening` in `text` (a quote: the
/// string literals a program reads or a test sets; a backquote: a document's code spans).
fn names(text: &str, opening: char) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (at, _) in text.match_indices(&format!("{opening}{PREFIX}")) {
        let name: String = text[at + opening.len_utf8()..]
            .chars()
            .take_while(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || *c == '_')
            .collect();
        let name = name.trim_end_matches('_');
        if name.len() > PREFIX.len() {
            found.insert(name.to_string());
        }
    }
    found
}

/// The Rust sources under `dir` (`src`, `tests` and `benches` of every crate).
fn sources(dir: &Path, text: &mut String) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            if path.file_name().is_some_and(|n| n != "target") {
                sources(&path, text);
            }
        } else if path.extension().is_some_and(|e| e == "rs") {
            text.push_str(&std::fs::read_to_string(&path).unwrap());
        }
    }
}

#[test]
fn every_environment_variable_is_listed_in_docs_cli_md() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut code = String::new();
    sources(&repo.join("crates"), &mut code);
    let read = names(&code, '"');
    assert!(
        read.contains(&format!("{PREFIX}PROGRESS_EVERY"))
            && read.contains(&format!("{PREFIX}SKIP_WGPU")),
        "the scan found {read:?}"
    );
    let cli = std::fs::read_to_string(repo.join("docs/cli.md")).unwrap();
    let (_, section) = cli
        .split_once("## Environment variables")
        .expect("docs/cli.md has a section \"Environment variables\"");
    let section = section.split("\n## ").next().unwrap();
    let listed = names(section, '`');
    let unlisted: Vec<_> = read.difference(&listed).collect();
    assert!(
        unlisted.is_empty(),
        "not in docs/cli.md's environment variables: {unlisted:?}"
    );
    let scripts = std::fs::read_to_string(repo.join("scripts/test.sh")).unwrap();
    let gone: Vec<_> = listed
        .iter()
        .filter(|name| !read.contains(*name) && !scripts.contains(&format!("{{{name}")))
        .collect();
    assert!(
        gone.is_empty(),
        "docs/cli.md lists what nothing reads: {gone:?}"
    );
    let switches: Vec<_> = read
        .iter()
        .filter(|name| name.starts_with(&format!("{PREFIX}WGPU")))
        .collect();
    assert!(
        switches.is_empty(),
        "the wgpu backend's switches are typed options, not environment variables: {switches:?}"
    );
}
