//! `docs/walkthrough.md` as written: every `pvrnn` command of its `sh` blocks runs, in order,
//! on the one-arm recordings in `tests/data/one-arm/`, and every line the document says a
//! command prints (in the `text` block after it) is printed, except timings. Its Python
//! block then reads the outputs back (when python3 has `safetensors` and `numpy`, which
//! `scripts/setup.sh` installs; `PVRNN_REQUIRE_PYTHON=1`, set by `scripts/test.sh`, makes
//! their absence a failure). With `PVRNN_EXPLORER_BIN` (and a display) its explorer line
//! opens the window too.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The document's code blocks in order: (language, lines).
fn blocks(doc: &str) -> Vec<(String, Vec<String>)> {
    let mut out = Vec::new();
    let mut current: Option<(String, Vec<String>)> = None;
    for line in doc.lines() {
        match (&mut current, line.strip_prefix("```")) {
            (None, Some(lang)) => current = Some((lang.trim().to_string(), Vec::new())),
            (Some(_), Some(_)) => out.extend(current.take()),
            (Some((_, lines)), None) => lines.push(line.to_string()),
            (None, None) => {}
        }
    }
    out
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

/// Runs the explorer line as written plus `--screenshot`: the window opens on the
/// walkthrough's bundle, computes the view's runs and saves a picture of itself.
fn open_explorer(bin: &Path, args: &[&str], dir: &Path) {
    let shot = dir.join("walkthrough-explorer.png");
    let out = Command::new(bin)
        .args(args)
        .arg("--screenshot")
        .arg(&shot)
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "pvrnn-explorer {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = std::fs::read(&shot).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 50_000,
        "{} bytes: a blank window?",
        png.len()
    );
}

#[test]
fn the_walkthrough_runs_as_written() {
    let doc = std::fs::read_to_string(repo().join("docs/walkthrough.md")).unwrap();
    let work = tempfile::tempdir().unwrap();
    copy_dir(
        &repo().join("tests/data/one-arm"),
        &work.path().join("tests/data/one-arm"),
    );
    let blocks = blocks(&doc);
    let (mut ran, mut explorer) = (0, 0);
    for (i, (lang, lines)) in blocks.iter().enumerate() {
        if lang != "sh" {
            continue;
        }
        for line in lines {
            let words: Vec<&str> = line.split_whitespace().collect();
            match words.first() {
                Some(&"pvrnn") => {}
                Some(&"pvrnn-explorer") => {
                    // A window: opened for real where the test is given the explorer and a
                    // display (`scripts/test.sh` does, under Xvfb), else left to the
                    // explorer's own tests, which open bundles of this shape.
                    explorer += 1;
                    if let Some(bin) = std::env::var_os("PVRNN_EXPLORER_BIN") {
                        open_explorer(Path::new(&bin), &words[1..], work.path());
                    }
                    continue;
                }
                _ => panic!("an sh block line the test cannot run: `{line}`"),
            }
            let out = Command::new(env!("CARGO_BIN_EXE_pvrnn"))
                .args(["--threads", "1"])
                .args(&words[1..])
                .current_dir(work.path())
                .output()
                .unwrap();
            let printed = format!(
                "{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
            assert!(out.status.success(), "`{line}` failed:\n{printed}");
            ran += 1;
            // What the document says it prints (timings and elisions aside).
            if let Some((next, shown)) = blocks.get(i + 1)
                && next == "text"
            {
                for expected in shown {
                    let vary = expected.contains(" s each")
                        || expected.contains("...")
                        || expected.trim().is_empty();
                    if !vary {
                        assert!(
                            printed.contains(expected.as_str()),
                            "`{line}` did not print `{expected}`:\n{printed}"
                        );
                    }
                }
            }
        }
    }
    assert_eq!(
        (ran, explorer),
        (6, 1),
        "import, init, train, infer, evaluate, bundle; then the explorer"
    );

    // The robot's shape travelled from recordings.json to the dataset, the model, the
    // evaluation and the bundle.
    let root = work.path().join("my-robot");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("dataset/dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest["image_size"], 128);
    assert_eq!(manifest["cameras"], serde_json::json!(["wrist"]));
    assert_eq!(manifest["joints"].as_array().unwrap().len(), 6);
    assert_eq!(manifest["torques"], serde_json::json!([]));
    assert_eq!(manifest["extra"], serde_json::json!(["gripper"]));
    let model = pvrnn_core::io::load_model(&root.join("trained.safetensors")).unwrap();
    assert_eq!(model.config.vision.cameras, 1);
    assert_eq!(model.config.vision.resolutions, [32, 64, 128]);
    assert_eq!(model.config.proprio_dims, 7);
    let summary = std::fs::read_to_string(root.join("eval/summary.md")).unwrap();
    assert!(
        summary.contains("| extra |") && summary.contains("| joints |"),
        "{summary}"
    );
    assert!(!summary.contains("| torques |"), "{summary}");
    for runs in ["all-on", "32-on", "32-off", "none-on"] {
        assert!(
            root.join(format!("bundle/runs-{runs}.safetensors"))
                .is_file(),
            "{runs}"
        );
    }

    // The Python snippet converts the outputs back to recorded units.
    let python: Vec<&(String, Vec<String>)> =
        blocks.iter().filter(|(lang, _)| lang == "python").collect();
    assert_eq!(python.len(), 1, "one Python block");
    let have = Command::new("python3")
        .args(["-c", "import safetensors, numpy"])
        .status()
        .is_ok_and(|s| s.success());
    if !have {
        assert!(
            std::env::var_os("PVRNN_REQUIRE_PYTHON").is_none(),
            "python3 with safetensors and numpy is required (scripts/setup.sh installs them)"
        );
        eprintln!("skipping the Python block: python3 lacks safetensors or numpy");
        return;
    }
    std::fs::write(work.path().join("snippet.py"), python[0].1.join("\n")).unwrap();
    let out = Command::new("python3")
        .arg("snippet.py")
        .current_dir(work.path())
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the Python block failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        printed.contains("q1..q6, gripper at step 0:") && printed.contains("128x128 camera 0"),
        "{printed}"
    );
}
