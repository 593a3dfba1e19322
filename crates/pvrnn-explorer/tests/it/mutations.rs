//! Bounded mutation tests of every parser a user's files reach: starting from valid files,
//! bytes are flipped, cut and appended, and header fields tampered with; each parser must
//! answer with an error or a valid result, never a panic or a hang. (The explorer's test
//! suite holds them because the explorer reads every format: models, checkpoints, inputs,
//! runs, bundles, datasets, recordings and the URL hash.) Run with `--nocapture` to see how
//! many inputs each target ran and how many it accepted.

use crate::common;

use std::collections::HashMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc;
use std::time::Duration;

use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::io::{self, TensorFile};
use pvrnn_core::run_sequence;
use pvrnn_core::train::Trainer;
use pvrnn_core::{Modality, NoiseMode};
use pvrnn_dataset::{Dataset, Split};
use pvrnn_explorer::{Bundle, ExplorerApp, ViewState};

/// Mutated inputs per target.
const MUTATIONS: usize = 1000;
/// Longer than any target needs (a few seconds); past it the target counts as hung.
const TARGET_LIMIT: Duration = Duration::from_secs(240);

/// A small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One mutation of `valid`: flips, a cut, an extension, or a tampered safetensors header
/// (its length field, or a digit or character inside its JSON).
fn mutate(valid: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut v = valid.to_vec();
    let header_end = if v.len() >= 8 {
        let n = u64::from_le_bytes(v[..8].try_into().expect("8 bytes")) as usize;
        (8 + n).min(v.len())
    } else {
        v.len()
    };
    match rng.below(7) {
        0 => {
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(v.len());
                v[i] ^= 1 << rng.below(8);
            }
        }
        1 => {
            // Inside the header (or the text), where structure lives.
            for _ in 0..1 + rng.below(3) {
                let i = rng.below(header_end);
                v[i] = b"0123456789{}[]\",:-.eEaz "[rng.below(24)];
            }
        }
        2 => v.truncate(rng.below(v.len())),
        3 => {
            let extra = 1 + rng.below(64);
            v.extend((0..extra).map(|_| rng.next() as u8));
        }
        4 if v.len() >= 8 => {
            let n = match rng.below(3) {
                0 => rng.next(),
                1 => (header_end as u64).saturating_sub(8) + rng.below(16) as u64,
                _ => (header_end as u64).saturating_sub(9 + rng.below(16) as u64),
            };
            v[..8].copy_from_slice(&n.to_le_bytes());
        }
        5 => {
            // A digit in the header made larger: shapes, offsets, lengths.
            let digits: Vec<usize> = (0..header_end).filter(|&i| v[i].is_ascii_digit()).collect();
            if !digits.is_empty() {
                let i = digits[rng.below(digits.len())];
                v[i] = b'9';
                v.insert(i, b'9');
            }
        }
        _ => {
            // A run of bytes duplicated (a repeated line or tensor row).
            if v.len() > 2 {
                let a = rng.below(v.len() - 1);
                let b = (a + 1 + rng.below(40)).min(v.len());
                let piece = v[a..b].to_vec();
                let at = rng.below(v.len());
                v.splice(at..at, piece);
            }
        }
    }
    v
}

#[derive(Debug, Default)]
struct Tally {
    inputs: usize,
    accepted: usize,
    panics: Vec<String>,
}

/// Runs `parse` on `MUTATIONS` mutations of each valid input (on a thread, so a hang fails
/// the test rather than stalling it), and returns the tally.
fn run_target(
    name: &'static str,
    valid: Vec<Vec<u8>>,
    seed: u64,
    parse: impl Fn(Vec<u8>, usize) -> bool + Send + 'static,
) -> Tally {
    let (send, receive) = mpsc::channel();
    std::thread::spawn(move || {
        let mut rng = Rng(seed | 1);
        let mut tally = Tally::default();
        for (which, input) in valid.iter().enumerate() {
            // The valid input itself first: it must be accepted.
            assert!(
                parse(input.clone(), which),
                "{name}: the valid input is rejected"
            );
            for _ in 0..MUTATIONS {
                let bytes = mutate(input, &mut rng);
                tally.inputs += 1;
                match catch_unwind(AssertUnwindSafe(|| parse(bytes.clone(), which))) {
                    Ok(true) => tally.accepted += 1,
                    Ok(false) => {}
                    Err(p) => {
                        let text = p
                            .downcast_ref::<String>()
                            .cloned()
                            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                            .unwrap_or_default();
                        tally.panics.push(format!("{text} ({} bytes)", bytes.len()));
                    }
                }
            }
        }
        let _ = send.send(tally);
    });
    let tally = match receive.recv_timeout(TARGET_LIMIT) {
        Ok(tally) => tally,
        Err(mpsc::RecvTimeoutError::Timeout) => {
            panic!("{name}: no answer within {TARGET_LIMIT:?} (a hang)")
        }
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            panic!("{name}: the target stopped (see the panic above)")
        }
    };
    eprintln!(
        "{name}: {} mutated inputs, {} accepted, {} panics",
        tally.inputs,
        tally.accepted,
        tally.panics.len()
    );
    tally
}

fn assert_no_panics(name: &str, tally: &Tally) {
    assert!(
        tally.panics.is_empty(),
        "{name}: {} of {} inputs panicked, e.g. {:?}",
        tally.panics.len(),
        tally.inputs,
        &tally.panics[..tally.panics.len().min(3)]
    );
}

fn temp(name: &str) -> std::path::PathBuf {
    let dir =
        std::env::temp_dir().join(format!("explorer-mutations-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The dataset's files by name (manifest and sequences), as a dataset folder holds them.
fn dataset_files() -> HashMap<String, Vec<u8>> {
    let dir = temp("dataset");
    common::dataset().write(&dir).unwrap();
    let files = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    let _ = std::fs::remove_dir_all(&dir);
    files
}

fn runs_bytes() -> Vec<u8> {
    let bundle = common::bundle();
    let config = bundle.model.config.clone();
    let seqs: Vec<_> = bundle.dataset.sequences.iter().collect();
    let obs = bundle.dataset.observations(&seqs, &config).unwrap();
    let settings = InferenceSettings::from_config(&config, 0);
    let runs: Vec<_> = (0..seqs.len())
        .map(|s| {
            run_sequence(
                bundle.model.clone(),
                settings.clone(),
                &obs,
                s,
                false,
                &mut |_, _| {},
            )
            .unwrap()
        })
        .collect();
    let names: Vec<String> = seqs.iter().map(|s| s.info.name.clone()).collect();
    io::runs_to_bytes(
        &config,
        &runs,
        &[0, 1, 2],
        Some(&names),
        io::StateStorage::F16,
    )
    .unwrap()
}

#[test]
fn model_checkpoint_and_inputs_files() {
    let model_bytes = io::model_to_bytes(&common::model()).unwrap();
    let tally = run_target("model", vec![model_bytes], 1, |bytes, _| {
        io::model_from_bytes(bytes, "mutated model").is_ok()
    });
    assert_no_panics("model", &tally);

    let dir = temp("checkpoint");
    let path = dir.join("run.safetensors");
    let mut trainer = Trainer::new(common::model(), NoiseMode::Sampled { seed: 3 });
    io::save_checkpoint(&path, &mut trainer, None).unwrap();
    let checkpoint = std::fs::read(&path).unwrap();
    let tally = run_target("checkpoint", vec![checkpoint], 2, move |bytes, _| {
        std::fs::write(&path, bytes).unwrap();
        io::load_checkpoint(&path).is_ok()
    });
    assert_no_panics("checkpoint", &tally);

    let dataset = common::dataset();
    let mut config = common::config();
    config.normalisation = Some(pvrnn_dataset::proprio_ranges(
        &dataset.split(Some(Split::Learn)),
    ));
    let obs = dataset.observations(&dataset.split(None), &config).unwrap();
    let inputs = dir.join("inputs.safetensors");
    io::save_observations(&inputs, &obs).unwrap();
    let valid = std::fs::read(&inputs).unwrap();
    let tally = run_target("inputs", vec![valid], 3, |bytes, _| {
        TensorFile::from_bytes(bytes, "mutated inputs")
            .and_then(|f| io::observations_from_file(&f))
            .is_ok_and(|o| {
                Modality::ALL
                    .iter()
                    .all(|m| o.tensor(*m).data().iter().all(|v| v.is_finite()))
            })
    });
    assert_no_panics("inputs", &tally);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn runs_and_bundle_files() {
    let runs = runs_bytes();
    let config = common::bundle().model.config.clone();
    let tally = run_target("runs", vec![runs.clone()], 4, move |bytes, _| {
        TensorFile::from_bytes(bytes, "mutated runs")
            .and_then(|f| io::load_runs(&f, &config))
            .is_ok()
    });
    assert_no_panics("runs", &tally);

    // A bundle from files, as downloaded: its manifest, or its runs file, mutated.
    let mut files = dataset_files();
    files.insert(
        "model.safetensors".into(),
        io::model_to_bytes(&common::bundle().model.weights_only()).unwrap(),
    );
    files.insert("runs.safetensors".into(), runs);
    let manifest = br#"{"format": "pvrnn-bundle/1", "description": "mutations", "model": "model.safetensors", "dataset": "dataset.json", "runs": ["runs.safetensors"]}"#.to_vec();
    files.insert(
        pvrnn_explorer::bundle::BUNDLE_MANIFEST.into(),
        manifest.clone(),
    );
    let which = ["bundle.json", "runs.safetensors"];
    let valid = vec![manifest, files["runs.safetensors"].clone()];
    let tally = run_target("bundle", valid, 5, move |bytes, k| {
        let mut files = files.clone();
        files.insert(which[k].into(), bytes);
        Bundle::from_files(&files).is_ok()
    });
    assert_no_panics("bundle", &tally);
}

#[test]
fn dataset_manifest_and_sequence_files() {
    let files = dataset_files();
    let which = ["dataset.json", "reach_test.safetensors"];
    let valid = which.iter().map(|w| files[*w].clone()).collect();
    let tally = run_target("dataset", valid, 6, move |bytes, k| {
        let mut files = files.clone();
        files.insert(which[k].into(), bytes);
        let Ok(json) = String::from_utf8(files["dataset.json"].clone()) else {
            return false;
        };
        Dataset::from_parts(&json, |name| {
            files
                .get(name)
                .cloned()
                .ok_or_else(|| pvrnn_dataset::Error::Format {
                    what: name.into(),
                    detail: "missing".into(),
                })
        })
        .is_ok()
    });
    assert_no_panics("dataset", &tally);
}

#[test]
fn recordings_for_import() {
    use pvrnn_dataset::import::{import_sequence, write_recording};
    let seq = common::sequence("rec", "wiping", Split::Learn, 6, 4);
    let layout = pvrnn_dataset::import::RecordingLayout::paper(&["left".into(), "right".into()], 8);
    let dir = temp("recording");
    write_recording(&seq, &layout, &dir).unwrap();
    let parts = ["meta.json", "proprio.csv", "left/000002.png"];
    let valid: Vec<Vec<u8>> = parts
        .iter()
        .map(|p| std::fs::read(dir.join(p)).unwrap())
        .collect();
    let originals = valid.clone();
    let tally = run_target("recordings", valid, 7, move |bytes, k| {
        for (part, original) in parts.iter().zip(&originals) {
            std::fs::write(dir.join(part), original).unwrap();
        }
        std::fs::write(dir.join(parts[k]), bytes).unwrap();
        import_sequence(&dir, "rec", &layout).is_ok()
    });
    assert_no_panics("recordings", &tally);
}

#[test]
fn url_hashes_on_a_running_explorer() {
    let valid = vec![
        b"seq=reach_test&t=5&vision=1&proprio=0&ablate=1000&amode=inference&H=3&iter=2&lr=0.09&seed=4&units=0-14&d=1&prior=1&contours=1&maps=0".to_vec(),
    ];
    let tally = run_target("URL hash", valid, 8, |bytes, _| {
        let Ok(hash) = String::from_utf8(bytes) else {
            return false;
        };
        let mut app = ExplorerApp::new(Some(common::bundle()), ViewState::default());
        app.apply_hash(&hash);
        // Draw a frame: what the hash asks for is laid out and its run starts.
        let ctx = eframe::egui::Context::default();
        let input = eframe::egui::RawInput {
            screen_rect: Some(eframe::egui::Rect::from_min_size(
                eframe::egui::Pos2::ZERO,
                eframe::egui::vec2(1200.0, 800.0),
            )),
            ..Default::default()
        };
        let mut out = ctx.run_ui(input, |ui| app.show(ui));
        // Nothing draws here: textures are not uploaded anywhere.
        out.textures_delta.clear();
        let view = app.view();
        let len = view
            .sequence
            .as_deref()
            .and_then(|s| app.bundle()?.dataset.by_name(s))
            .map_or(0, |s| s.len());
        view.t < len
    });
    assert_no_panics("URL hash", &tally);
}

#[test]
fn the_harness_catches_a_panicking_parser() {
    // A parser that panics on some inputs is caught (so the targets above can fail).
    let tally = run_target("panicking", vec![b"{\"a\": 1}".to_vec()], 9, |bytes, _| {
        assert!(bytes.len() < 9, "longer than the valid input");
        true
    });
    assert!(!tally.panics.is_empty() && tally.accepted > 0, "{tally:?}");
}
