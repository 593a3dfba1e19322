//! Every crate's modules stay layered (ARCHITECTURE.md): no module imports another that
//! imports it back; in the core the CPU backend is named only by itself and by `defaults`,
//! the one place a default backend is chosen; and no function is longer than a newcomer
//! reads at once (120 lines); the CPU backend's float helpers run inside its SIMD dispatch.
//! Read from the sources, so that the rules cannot drift. And test builds leave the crates
//! that only run while building unoptimised (Cargo.toml).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn crates_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Each top-level module of `krate` (its file, or its folder's files) without comments and
/// without unit tests.
fn modules(krate: &str) -> BTreeMap<String, String> {
    let src = crates_dir().join(krate).join("src");
    let mut modules = BTreeMap::new();
    let mut stack = vec![src.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("the core's sources") {
            let path = entry.expect("a source entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let relative = path.strip_prefix(&src).expect("under src");
            let top = relative
                .components()
                .next()
                .and_then(|c| c.as_os_str().to_str())
                .expect("a file name")
                .trim_end_matches(".rs")
                .to_string();
            if top == "lib" || top == "main" {
                continue;
            }
            let text = std::fs::read_to_string(&path).expect("a readable source");
            let text = text.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
            let code: String = text
                .lines()
                .filter(|line| !line.trim_start().starts_with("//"))
                .map(|line| format!("{line}\n"))
                .collect();
            modules
                .entry(top)
                .or_insert_with(String::new)
                .push_str(&code);
        }
    }
    modules
}

/// The modules each module names through `crate::`.
fn imports(modules: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    modules
        .iter()
        .map(|(name, code)| {
            let mut used = BTreeSet::new();
            for (at, _) in code.match_indices("crate::") {
                let rest = &code[at + "crate::".len()..];
                let names: Vec<&str> = match rest.strip_prefix('{') {
                    Some(group) => group
                        .split('}')
                        .next()
                        .unwrap_or("")
                        .split(',')
                        .map(|item| item.trim().split("::").next().unwrap_or(""))
                        .collect(),
                    None => vec![
                        rest.split(|c: char| !c.is_alphanumeric() && c != '_')
                            .next()
                            .unwrap_or(""),
                    ],
                };
                for module in names {
                    if module != name && modules.contains_key(module) {
                        used.insert(module.to_string());
                    }
                }
            }
            (name.clone(), used)
        })
        .collect()
}

/// A chain of imports that comes back to its start, if there is one.
fn find_circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(start) = path.iter().position(|p| p == node) {
            let mut circle = path[start..].to_vec();
            circle.push(node.to_string());
            return Some(circle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(circle) = visit(next, graph, path, done) {
                return Some(circle);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|node| visit(node, graph, &mut Vec::new(), &mut done))
}

#[test]
fn no_crate_s_modules_import_each_other_in_a_circle() {
    let crates: Vec<String> = std::fs::read_dir(crates_dir())
        .expect("the crates folder")
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("src").is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(crates.len() >= 8, "the crates were not found: {crates:?}");
    let core = imports(&modules("pvrnn-core"));
    assert!(
        core["cpu"].contains("assembled"),
        "the reading of imports is broken: {core:?}"
    );
    let mut circles = Vec::new();
    for krate in &crates {
        if let Some(circle) = find_circle(&imports(&modules(krate))) {
            circles.push(format!("{krate}: {}", circle.join(" -> ")));
        }
    }
    assert!(
        circles.is_empty(),
        "modules that import each other in a circle:\n{}",
        circles.join("\n")
    );
}

/// Within each module folder, the files that name each other through `super::` (a sibling
/// file's module), per folder of every crate: `folder -> {file -> siblings it imports}`.
fn sibling_imports() -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
    let mut folders = BTreeMap::new();
    let mut stack: Vec<PathBuf> = std::fs::read_dir(crates_dir())
        .expect("the crates folder")
        .filter_map(|e| Some(e.ok()?.path().join("src")))
        .filter(|p| p.is_dir())
        .collect();
    while let Some(dir) = stack.pop() {
        let mut files = BTreeMap::new();
        for entry in std::fs::read_dir(&dir).expect("a source folder") {
            let path = entry.expect("a source entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
            if path.extension().is_none_or(|e| e != "rs") || ["mod", "lib", "main"].contains(&stem)
            {
                continue;
            }
            let text = std::fs::read_to_string(&path).expect("a readable source");
            let text = text.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
            let code: String = text
                .lines()
                .filter(|line| !line.trim_start().starts_with("//"))
                .map(|line| format!("{line}\n"))
                .collect();
            files.insert(stem.to_string(), code);
        }
        let graph: BTreeMap<String, BTreeSet<String>> = files
            .iter()
            .map(|(name, code)| {
                let used = code
                    .match_indices("super::")
                    .filter_map(|(at, _)| {
                        let rest = &code[at + "super::".len()..];
                        let next = rest
                            .split(|c: char| !c.is_alphanumeric() && c != '_')
                            .next()?;
                        (next != name && files.contains_key(next)).then(|| next.to_string())
                    })
                    .collect();
                (name.clone(), used)
            })
            .collect();
        folders.insert(dir.display().to_string(), graph);
    }
    folders
}

/// The rule above at every depth: the files of one module folder (the explorer's `app/`,
/// the core's `cpu/`) do not import each other in a circle either.
#[test]
fn no_files_of_one_folder_import_each_other_in_a_circle() {
    let circles: Vec<String> = sibling_imports()
        .iter()
        .filter_map(|(folder, graph)| {
            find_circle(graph).map(|c| format!("{folder}: {}", c.join(" -> ")))
        })
        .collect();
    assert!(
        circles.is_empty(),
        "files that import each other in a circle:\n{}",
        circles.join("\n")
    );
    // The reader sees sibling imports: the explorer's traces draw the summaries.
    let app = sibling_imports()
        .into_iter()
        .find(|(folder, _)| folder.ends_with("pvrnn-explorer/src/app"))
        .expect("the explorer's app folder")
        .1;
    assert!(app["traces"].contains("summaries"), "{app:?}");
}

#[test]
fn only_the_cpu_backend_and_the_defaults_name_the_cpu_backend() {
    let named: Vec<String> = modules("pvrnn-core")
        .into_iter()
        .filter(|(name, code)| name != "cpu" && name != "defaults" && code.contains("CpuBackend"))
        .map(|(name, _)| name)
        .collect();
    assert!(
        named.is_empty(),
        "these modules name CpuBackend (choose a default in defaults.rs): {named:?}"
    );
}

#[test]
fn the_circle_finder_finds_a_circle() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(
        find_circle(&graph),
        Some(vec!["a".into(), "b".into(), "c".into(), "a".into()])
    );
}

/// The longest a function may be, in lines from its `fn` to its closing brace.
const MAX_FUNCTION_LINES: usize = 120;

/// Every function of `text` with a body: (name, first line, lines). A function ends at the
/// first line that closes a brace at its `fn`'s indentation (rustfmt's layout).
fn functions(text: &str) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        let indent = line.len() - line.trim_start().len();
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some(at) = words.iter().position(|w| *w == "fn") else {
            i += 1;
            continue;
        };
        let before_ok = words[..at].iter().all(|w| {
            matches!(*w, "pub" | "async" | "const" | "unsafe" | "extern") || w.starts_with("pub(")
        });
        if !before_ok || line.trim_start().starts_with("//") {
            i += 1;
            continue;
        }
        let name = words
            .get(at + 1)
            .map(|w| w.split(['(', '<']).next().unwrap_or("").to_string())
            .unwrap_or_default();
        // The signature ends with `{` (a body) or `;` (a declaration).
        let mut j = i;
        while j < lines.len()
            && !lines[j].trim_end().ends_with('{')
            && !lines[j].trim_end().ends_with(';')
        {
            j += 1;
        }
        if j >= lines.len() || lines[j].trim_end().ends_with(';') {
            i = j + 1;
            continue;
        }
        let close = " ".repeat(indent) + "}";
        let mut k = j + 1;
        while k < lines.len()
            && !(lines[k].starts_with(&close)
                && lines[k].len() - lines[k].trim_start().len() == indent)
        {
            k += 1;
        }
        found.push((name, i + 1, k - i + 1));
        i = j + 1;
    }
    found
}

#[test]
fn no_function_is_longer_than_a_newcomer_reads_at_once() {
    let mut long = Vec::new();
    let mut stack = vec![crates_dir()];
    let mut files = 0;
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("a readable folder") {
            let path = entry.expect("an entry").path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if path.is_dir() {
                // Sources only: not tests, benches or build output.
                if !matches!(name, "tests" | "benches" | "target" | "snapshots") {
                    stack.push(path);
                }
                continue;
            }
            if !name.ends_with(".rs") || !path.components().any(|c| c.as_os_str() == "src") {
                continue;
            }
            files += 1;
            let text = std::fs::read_to_string(&path).expect("a readable source");
            for (function, line, lines) in functions(&text) {
                if lines > MAX_FUNCTION_LINES {
                    long.push(format!(
                        "{}:{line} {function}: {lines} lines",
                        path.display()
                    ));
                }
            }
        }
    }
    assert!(files > 50, "the sources were not found ({files} files)");
    assert!(
        long.is_empty(),
        "functions over {MAX_FUNCTION_LINES} lines (split them into named steps):\n{}",
        long.join("\n")
    );
}

#[test]
fn the_function_reader_measures_bodies_and_skips_declarations() {
    let text = "trait T {\n    fn declared(\n        &self,\n    ) -> u32;\n}\n\npub(crate) fn body(x: u32) -> u32 {\n    let y = x;\n    y\n}\n";
    assert_eq!(functions(text), vec![("body".to_string(), 7, 4)]);
}

/// The functions of `text` that do float maths through `Real` (`madd`, `tanh`, `exp`, `ln`)
/// yet are neither inlined always, nor wrap their body in the kernels' SIMD dispatch
/// (`simd(`), nor enable target features themselves, and the closures bound to a name that
/// do such maths: (name, first line).
///
/// On x86-64 such a function is compiled for the baseline CPU even when it is called from
/// inside the dispatch: every `madd` becomes a call to libm's `fmaf` and nothing
/// vectorises. That made online inference with 16x16 + proprioception a quarter slower
/// (`latent_grads`, 2026-11-29, docs/speed.md); the results are the same either way.
fn float_helpers_outside_the_dispatch(text: &str) -> Vec<(String, usize)> {
    let text = text.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
    let lines: Vec<&str> = text.lines().collect();
    let maths = [".madd(", ".tanh(", ".exp(", ".ln("];
    // The functions of `text` that do float maths themselves: (name, first line, body).
    let doing_maths: Vec<(String, usize, String)> = functions(text)
        .into_iter()
        .map(|(name, first, count)| {
            let body = lines[first - 1..(first - 1 + count).min(lines.len())].join("\n");
            (name, first, body)
        })
        .filter(|(_, _, body)| maths.iter().any(|m| body.contains(m)))
        .collect();
    // What a closure must not call: the methods above and those functions.
    let mut calls: Vec<String> = maths.iter().map(|m| m.to_string()).collect();
    for (name, _, _) in &doing_maths {
        calls.extend([format!("{name}("), format!("{name}::<")]);
    }
    let mut found = Vec::new();
    for (name, first, body) in doing_maths {
        if body.contains("simd(") {
            continue;
        }
        let attributes = lines[..first - 1]
            .iter()
            .rev()
            .take_while(|l| {
                let l = l.trim_start();
                l.starts_with("#[") || l.starts_with("//")
            })
            .any(|l| l.contains("#[inline(always)]") || l.contains("#[target_feature"));
        if !attributes {
            found.push((name, first));
        }
    }
    // A closure bound to a name (`let rows = |..| {`) is a function of its own that the
    // compiler may leave apart, and it cannot be marked `#[inline(always)]`: none may do
    // float maths, itself or through a function of this file.
    for (i, line) in lines.iter().enumerate() {
        let code = line.trim_start();
        let Some(name) = code
            .strip_prefix("let ")
            .and_then(|rest| rest.split_once(" = "))
            .filter(|(_, value)| value.starts_with('|') || value.starts_with("move |"))
            .filter(|_| code.ends_with('{'))
            .map(|(name, _)| name.trim_start_matches("mut ").to_string())
        else {
            continue;
        };
        let close = " ".repeat(line.len() - code.len()) + "};";
        let end = (i + 1..lines.len())
            .find(|&k| lines[k].starts_with(&close))
            .unwrap_or(lines.len() - 1);
        let closure = lines[i..=end].join("\n");
        if calls.iter().any(|c| closure.contains(c.as_str())) {
            found.push((name, i + 1));
        }
    }
    found
}

#[test]
fn the_cpu_backend_s_float_helpers_run_inside_its_simd_dispatch() {
    let core = crates_dir().join("pvrnn-core").join("src");
    let mut files: Vec<PathBuf> = std::fs::read_dir(core.join("cpu"))
        .expect("the CPU backend's sources")
        .map(|e| e.expect("an entry").path())
        .collect();
    files.extend(["kernels.rs", "optim.rs"].map(|f| core.join(f)));
    let mut outside = Vec::new();
    for path in &files {
        let text = std::fs::read_to_string(path).expect("a readable source");
        for (name, line) in float_helpers_outside_the_dispatch(&text) {
            outside.push(format!("{}:{line} {name}", path.display()));
        }
    }
    assert!(files.len() >= 5, "the sources were not found: {files:?}");
    assert!(
        outside.is_empty(),
        "float helpers compiled outside the SIMD dispatch (mark them #[inline(always)] or \
         wrap their body in `simd(`; make a named closure such a function):\n{}",
        outside.join("\n")
    );
}

#[test]
fn the_dispatch_reader_flags_helpers_only_hinted_inline_and_named_closures() {
    let text = "#[inline]\nfn hinted<T: Real>(x: T) -> T {\n    x.exp()\n}\n\n\
        #[inline(always)] // inside the dispatch\nfn always<T: Real>(x: T) -> T {\n    x.tanh()\n}\n\n\
        pub(crate) fn entry<T: Real>(x: T) -> T {\n    simd(|| x.madd(x, x))\n}\n\n\
        fn plain(x: u32) -> u32 {\n    x + 1\n}\n\n\
        #[inline(always)]\nfn rows<T: Real>(x: T) -> T {\n    let step = |y: T| {\n        y.madd(x, y)\n    };\n    \
        let index = |k: usize| {\n        k + 1\n    };\n    let tile = |y: T| {\n        always::<T>(y)\n    };\n    step(x)\n}\n";
    assert_eq!(
        float_helpers_outside_the_dispatch(text),
        vec![
            ("hinted".to_string(), 2),
            ("step".to_string(), 21),
            ("tile".to_string(), 27)
        ]
    );
}

/// The crates of Cargo.lock that only run while building: proc macros, and what only they
/// and build scripts use (read with `cargo metadata`, every target).
fn build_only_crates() -> BTreeSet<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // Not --offline: a build fetches only its own platforms' crates, metadata reads them all.
    let output = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked"])
        .current_dir(crates_dir())
        .output()
        .expect("cargo metadata runs");
    assert!(
        output.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let metadata: serde_json::Value =
        serde_json::from_slice(&output.stdout).expect("cargo metadata's JSON");
    let packages: BTreeMap<&str, &serde_json::Value> = metadata["packages"]
        .as_array()
        .expect("packages")
        .iter()
        .map(|p| (p["id"].as_str().expect("an id"), p))
        .collect();
    let is_proc_macro = |id: &str| {
        packages[id]["targets"]
            .as_array()
            .expect("targets")
            .iter()
            .any(|t| {
                t["kind"]
                    .as_array()
                    .expect("kinds")
                    .iter()
                    .any(|k| k == "proc-macro")
            })
    };
    let nodes: BTreeMap<&str, &serde_json::Value> = metadata["resolve"]["nodes"]
        .as_array()
        .expect("the resolved graph")
        .iter()
        .map(|n| (n["id"].as_str().expect("an id"), n))
        .collect();
    // Everything reachable from the workspace without a build-dependency edge or a proc
    // macro is compiled into some program; the rest only runs while building.
    let mut runtime = BTreeSet::new();
    let mut stack: Vec<&str> = metadata["workspace_members"]
        .as_array()
        .expect("workspace members")
        .iter()
        .map(|m| m.as_str().expect("a member id"))
        .collect();
    while let Some(id) = stack.pop() {
        if !runtime.insert(id) {
            continue;
        }
        for dep in nodes[id]["deps"].as_array().expect("deps") {
            let target = dep["pkg"].as_str().expect("a dependency id");
            let build_only = dep["dep_kinds"]
                .as_array()
                .expect("dependency kinds")
                .iter()
                .all(|k| k["kind"] == "build");
            if !build_only && !is_proc_macro(target) {
                stack.push(target);
            }
        }
    }
    let name = |id: &str| packages[id]["name"].as_str().expect("a name").to_string();
    let runtime_names: BTreeSet<String> = runtime.iter().map(|id| name(id)).collect();
    nodes
        .keys()
        .filter(|id| !runtime.contains(*id))
        .map(|id| name(id))
        .filter(|n| !runtime_names.contains(n))
        .collect()
}

#[test]
fn test_builds_leave_the_build_only_crates_unoptimised() {
    let manifest: toml::Table = std::fs::read_to_string(crates_dir().join("../Cargo.toml"))
        .expect("the workspace manifest")
        .parse()
        .expect("the workspace manifest parses");
    let named: BTreeSet<String> = manifest["profile"]["dev"]["package"]
        .as_table()
        .expect("[profile.dev.package]")
        .iter()
        .filter(|(_, settings)| settings.get("opt-level").and_then(|l| l.as_integer()) == Some(0))
        .map(|(name, _)| name.clone())
        .collect();
    let build_only = build_only_crates();
    assert!(
        build_only.contains("syn"),
        "the build-only crates were not found: {build_only:?}"
    );
    assert_eq!(
        named, build_only,
        "Cargo.toml's opt-level-0 list under [profile.dev.package] must name exactly the \
         build-only crates (else \"*\" compiles them at opt-level 2, or a runtime crate runs \
         unoptimised)"
    );
}
