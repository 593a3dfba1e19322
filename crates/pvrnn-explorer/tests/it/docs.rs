//! The documents' claims about the desktop app's command line match it: every flag written
//! after `pvrnn-explorer` (a command in a code block or inline code, or
//! `cargo run ... -p pvrnn-explorer -- ...`) in the README, ARCHITECTURE.md and docs/ is
//! one that `pvrnn-explorer --help` lists. And ARCHITECTURE.md stays one page (at most
//! 1,600 words) that names only what exists: every file or folder in its code spans and
//! links, and every type, function, macro and `module::item`, is in the repository and the
//! crates' sources; crates/pvrnn-wgpu/README.md likewise.

use std::path::{Path, PathBuf};
use std::process::Command;

fn documents() -> Vec<PathBuf> {
    let repo = repo();
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
        // As cargo's package (`cargo test -p pvrnn-explorer --test it ui::`), the flags before
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
    assert!(flags_after_mentions("`cargo test -p pvrnn-explorer --test it ui::`").is_empty());
}

fn repo() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).to_path_buf()
}

/// The inline code spans of a Markdown text, outside fenced code blocks (a span may run
/// over a line break, not over a paragraph's end).
fn code_spans(text: &str) -> Vec<String> {
    let mut spans = Vec::new();
    let mut paragraph = String::new();
    let mut flush = |paragraph: &mut String| {
        // Between the odd and the even backticks of a paragraph; a backtick left unclosed
        // opens nothing.
        let text = std::mem::take(paragraph);
        let pieces: Vec<&str> = text.split('`').collect();
        let closed = pieces.len() - (1 - pieces.len() % 2);
        let inside = pieces[..closed].iter().skip(1).step_by(2);
        spans.extend(inside.map(|s| s.replace('\n', " ")));
    };
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            flush(&mut paragraph);
        } else if line.trim().is_empty() {
            flush(&mut paragraph);
        } else if !fenced {
            paragraph.push_str(line);
            paragraph.push('\n');
        }
    }
    flush(&mut paragraph);
    spans
}

/// The targets of a Markdown text's relative links, `[text](target)`, without an anchor.
fn link_targets(text: &str) -> Vec<String> {
    text.split("](")
        .skip(1)
        .filter_map(|rest| rest.split(')').next())
        .map(|target| target.split('#').next().unwrap_or("").to_string())
        .filter(|target| !target.is_empty() && !target.contains("://"))
        .collect()
}

/// Whether a code span names a file or folder: a path with `/`, or a file name with one of
/// the repository's source and document extensions.
fn names_a_path(span: &str) -> bool {
    let path_chars = |c: char| c.is_ascii_alphanumeric() || "_-./*".contains(c);
    let extensions = [".rs", ".md", ".toml", ".sh", ".py", ".wgsl"];
    !span.is_empty()
        && span.chars().all(path_chars)
        && !span.starts_with('-')
        && (span.contains('/') || extensions.iter().any(|e| span.ends_with(e)))
}

/// Whether `path` (relative to `dir`) exists; a `*` in its last part matches any text.
fn path_exists(dir: &Path, path: &str) -> bool {
    let path = path.trim_end_matches('/');
    match path.rsplit_once('/').unwrap_or(("", path)) {
        (folder, name) if name.contains('*') => {
            let (prefix, suffix) = name.split_once('*').unwrap();
            std::fs::read_dir(dir.join(folder)).is_ok_and(|entries| {
                entries.filter_map(|e| e.ok()).any(|e| {
                    let file = e.file_name().to_string_lossy().into_owned();
                    file.len() >= prefix.len() + suffix.len()
                        && file.starts_with(prefix)
                        && file.ends_with(suffix)
                })
            })
        }
        _ => dir.join(path).exists(),
    }
}

/// What a code span names in the code, if it is written like a Rust item: `Type`,
/// `function()`, `macro!` or `module::item` (a lower-case single word is left alone: it
/// may be a setting's value as well as a module). The path's parts, and whether it is
/// called as a function or a macro.
fn names_an_item(span: &str) -> Option<(Vec<&str>, &str)> {
    let (path, kind) = if let Some(path) = span.strip_suffix("()") {
        (path, "fn")
    } else if let Some(path) = span.strip_suffix('!') {
        (path, "macro")
    } else {
        (span, "")
    };
    let parts: Vec<&str> = path.split("::").collect();
    let identifier = |p: &&str| {
        p.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    };
    if !parts.iter().all(identifier) {
        return None;
    }
    let type_like = path.len() > 1 && path.starts_with(|c: char| c.is_ascii_uppercase());
    (parts.len() > 1 || !kind.is_empty() || type_like).then_some((parts, kind))
}

/// Every word of the crates' sources outside comments (Rust and WGSL), the names after
/// `fn` and the names after `macro_rules!`.
struct Sources {
    words: std::collections::BTreeSet<String>,
    functions: std::collections::BTreeSet<String>,
    macros: std::collections::BTreeSet<String>,
}

fn sources() -> Sources {
    let mut sources = Sources {
        words: Default::default(),
        functions: Default::default(),
        macros: Default::default(),
    };
    let mut stack: Vec<PathBuf> = std::fs::read_dir(repo().join("crates"))
        .unwrap()
        .map(|e| e.unwrap().path().join("src"))
        .filter(|p| p.is_dir())
        .collect();
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if !path.extension().is_some_and(|e| e == "rs" || e == "wgsl") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
                let words: Vec<&str> = line
                    .split(|c: char| !c.is_ascii_alphanumeric() && c != '_' && c != '!')
                    .filter(|w| !w.is_empty())
                    .collect();
                for pair in words.windows(2) {
                    match pair[0] {
                        "fn" => sources.functions.insert(pair[1].to_string()),
                        "macro_rules!" => sources.macros.insert(pair[1].to_string()),
                        _ => false,
                    };
                }
                let bare = words.iter().map(|w| w.trim_matches('!').to_string());
                sources.words.extend(bare);
            }
        }
    }
    sources
}

/// The problems of one document: paths that do not exist (relative to the document's
/// folder or the repository), items the sources do not have; and how many of each it names.
fn dangling_names(doc: &Path, sources: &Sources) -> (Vec<String>, usize, usize) {
    let text = std::fs::read_to_string(doc).unwrap();
    let dir = doc.parent().unwrap();
    let (mut problems, mut paths, mut items) = (Vec::new(), 0, 0);
    let spans = code_spans(&text);
    let linked = link_targets(&text);
    for path in spans.iter().filter(|s| names_a_path(s)).chain(&linked) {
        paths += 1;
        if !path_exists(dir, path) && !path_exists(&repo(), path) {
            problems.push(format!("`{path}`: no such file or folder"));
        }
    }
    for span in &spans {
        let Some((parts, kind)) = names_an_item(span) else {
            continue;
        };
        items += 1;
        let last = parts[parts.len() - 1];
        let found = match kind {
            "fn" => sources.functions.contains(last),
            "macro" => sources.macros.contains(last),
            _ => true,
        } && parts.iter().all(|p| sources.words.contains(*p));
        if !found {
            problems.push(format!("`{span}`: not in the crates' sources"));
        }
    }
    (problems, paths, items)
}

/// The longest ARCHITECTURE.md may be, in words (as `wc -w` counts them): one page.
const ARCHITECTURE_MAX_WORDS: usize = 1_600;

#[test]
fn the_architecture_names_only_files_and_items_that_exist() {
    let sources = sources();
    assert!(
        sources.functions.contains("evaluate") && sources.words.contains("LoadedModel"),
        "the sources were not read"
    );
    let doc = repo().join("ARCHITECTURE.md");
    let (problems, paths, items) = dangling_names(&doc, &sources);
    assert!(
        paths >= 20 && items >= 10,
        "only {paths} paths and {items} items found: is the reader broken?"
    );
    assert!(
        problems.is_empty(),
        "ARCHITECTURE.md names what does not exist:\n{}",
        problems.join("\n")
    );
    let words = std::fs::read_to_string(&doc)
        .unwrap()
        .split_whitespace()
        .count();
    assert!(
        words <= ARCHITECTURE_MAX_WORDS,
        "ARCHITECTURE.md has {words} words, more than a page ({ARCHITECTURE_MAX_WORDS}): \
         move detail into the crates' docs"
    );
}

#[test]
fn the_gpu_backend_s_readme_names_only_files_and_items_that_exist() {
    let doc = repo().join("crates/pvrnn-wgpu/README.md");
    let (problems, paths, items) = dangling_names(&doc, &sources());
    assert!(
        paths >= 10 && items >= 10,
        "only {paths} paths and {items} items found"
    );
    assert!(
        problems.is_empty(),
        "crates/pvrnn-wgpu/README.md names what does not exist:\n{}",
        problems.join("\n")
    );
}

#[test]
fn code_spans_are_read_as_paths_and_items() {
    let text = "See `crates/a.rs`, `Trainer::new()`, `backend_suite!` and `x\n--flag`.\n\
        ```sh\n`inside`\n```\n[the spec](docs/model.md#data) and [a site](https://x.org/).\n\n\
        An unclosed ` ends with its paragraph.\n\n`Gate`";
    let spans = code_spans(text);
    assert_eq!(
        spans,
        [
            "crates/a.rs",
            "Trainer::new()",
            "backend_suite!",
            "x --flag",
            "Gate"
        ]
    );
    assert_eq!(link_targets(text), ["docs/model.md"]);
    assert!(names_a_path("crates/a.rs") && names_a_path("build.rs") && names_a_path("fuzz/"));
    assert!(!names_a_path("x --flag") && !names_a_path("Trainer::new()"));
    assert_eq!(
        names_an_item("Trainer::new()"),
        Some((vec!["Trainer", "new"], "fn"))
    );
    assert_eq!(
        names_an_item("backend_suite!"),
        Some((vec!["backend_suite"], "macro"))
    );
    assert_eq!(names_an_item("Gate"), Some((vec!["Gate"], "")));
    // A lower-case word may be a setting's value; a flag or a command is not an item.
    assert_eq!(names_an_item("paper"), None);
    assert_eq!(names_an_item("--revision"), None);
    assert_eq!(names_an_item("x --flag"), None);
}
