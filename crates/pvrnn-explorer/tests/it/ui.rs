//! The explorer's interface logic, driven headless with egui_kittest.

use crate::common;

use std::collections::HashMap;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use pvrnn_core::infer::InferenceSettings;
use pvrnn_core::io;
use pvrnn_core::run_sequence;
use pvrnn_explorer::bundle::BUNDLE_MANIFEST;
use pvrnn_explorer::condition::Condition;
use pvrnn_explorer::{Bundle, ExplorerApp, ViewState};

fn harness(app: ExplorerApp) -> Harness<'static, ExplorerApp> {
    let mut h = Harness::builder()
        .with_size(eframe::egui::vec2(1400.0, 1000.0))
        .build_ui_state(|ui, app: &mut ExplorerApp| app.show(ui), app);
    settle(&mut h);
    h
}

/// Frames until every requested run is computed.
fn settle(h: &mut Harness<'static, ExplorerApp>) {
    for _ in 0..2000 {
        h.step();
        if h.state().idle() {
            h.step();
            return;
        }
    }
    panic!("inference did not finish");
}

#[test]
fn opens_on_the_first_sequence_and_computes_its_run() {
    let h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState::default(),
    ));
    let app = h.state();
    assert_eq!(app.view().sequence.as_deref(), Some("reach_learn"));
    let run = app.current_run().expect("the shown run exists");
    assert!(run.complete && run.error.is_none());
    assert_eq!(run.trace.steps, 12);
    assert!(app.predicted_vision().is_some());
}

#[test]
fn toggling_an_ablation_changes_the_predicted_image() {
    let view = ViewState {
        t: 7,
        maps: false,
        ..ViewState::default()
    };
    let mut h = harness(ExplorerApp::new(Some(common::bundle()), view));
    let before = h.state().predicted_vision().unwrap().to_vec();
    h.get_by_label("executive").click();
    h.step();
    settle(&mut h);
    let app = h.state();
    assert_eq!(
        app.condition().unwrap().ablation,
        [true, false, false, false]
    );
    let after = app.predicted_vision().unwrap();
    let diff: f32 = before.iter().zip(after).map(|(a, b)| (a - b).abs()).sum();
    assert!(
        diff > 1e-3,
        "the predicted image did not change (sum |diff| = {diff})"
    );
    // Toggling back shows the cached standard run again, without recomputing.
    h.get_by_label("executive").click();
    h.step();
    assert!(
        h.state().idle(),
        "the standard run should come from the cache"
    );
    h.step();
    assert_eq!(h.state().predicted_vision().unwrap(), before.as_slice());
}

#[test]
fn keys_step_and_play_moves_time() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            t: 3,
            maps: false,
            ..ViewState::default()
        },
    ));
    h.key_press(eframe::egui::Key::ArrowRight);
    h.step();
    assert_eq!(h.state().view().t, 4);
    h.key_press(eframe::egui::Key::ArrowLeft);
    h.key_press(eframe::egui::Key::ArrowLeft);
    h.step();
    assert_eq!(h.state().view().t, 2);
    h.get_by_label("play").click();
    // kittest's clock steps 0.25 s per frame, without sleeping: at 10 steps/s, the frame
    // that takes the click starts playing, the next two advance 2.5 steps each (2, then 3).
    h.step();
    assert_eq!(h.state().view().t, 2);
    h.step();
    h.step();
    assert_eq!(h.state().view().t, 7);
}

#[test]
fn vision_condition_and_sequence_pickers() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    ));
    h.get_by_label("proprioception observed").click();
    h.step();
    settle(&mut h);
    let c = h.state().condition().unwrap();
    assert!(!c.proprio);
    assert_eq!(h.state().current_run().unwrap().trace.steps, 12);
    // The view (with its condition) survives a trip through the URL hash.
    let hash = h.state().view().to_hash();
    let (back, _) = ViewState::from_hash(
        &hash,
        &ViewState::default(),
        Condition::standard(&common::config()),
    );
    assert_eq!(back.condition, h.state().view().condition);
}

#[test]
fn contribution_maps_need_and_get_the_ablation_runs() {
    let h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            t: 5,
            maps: true,
            ..ViewState::default()
        },
    ));
    let app = h.state();
    let key = app.current_key().unwrap();
    let standard = key.condition.without_ablation();
    for module in pvrnn_core::ModuleId::ALL {
        let k = pvrnn_explorer::condition::RunKey::new(&key.sequence, standard.ablating(module));
        let run = app
            .run(&k)
            .expect("each single-module ablation is computed");
        assert!(run.complete && run.trace.steps == 12);
        let map = app
            .contribution_map(module)
            .expect("its contribution map is drawn");
        assert_eq!(map.size, 8);
    }
    // Ablating a module changes the prediction somewhere: its map is not all black.
    let lit = pvrnn_core::ModuleId::ALL
        .iter()
        .filter(|&&m| {
            app.contribution_map(m)
                .unwrap()
                .pixels
                .iter()
                .any(|&p| p > 0)
        })
        .count();
    assert!(lit >= 1);

    // Over time: a value per step and module, the one at the cursor the map's mean, and
    // the map averaged over the cursor's subtask (steps 0-5: `first`).
    let mut h = h;
    for _ in 0..4 {
        h.step();
    }
    let app = h.state();
    for module in pvrnn_core::ModuleId::ALL {
        let curve = app.contribution_curve(module);
        assert_eq!(curve.len(), 12, "{module:?}");
        let map = app.contribution_map(module).unwrap();
        let shown: f32 = map.pixels.iter().step_by(3).map(|&p| p as f32).sum::<f32>()
            / (map.size * map.size) as f32
            * 1.8
            / (4.0 * 255.0);
        // The picture rounds down to 8 bits and clips at white.
        assert!(
            shown <= curve[5] + 1e-6,
            "{module:?}: {shown} vs {}",
            curve[5]
        );
        assert!(
            shown >= curve[5].min(1.8 / 4.0) - 0.01,
            "{module:?}: {shown} vs {}",
            curve[5]
        );
    }
    let labels = format!("{:?}", h.root());
    for text in [
        "Contributions over time",
        "averaged over the subtask `first` (6 steps read out)",
        "12 of 12 steps read out",
    ] {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
}

/// The web's progressive load on the shipped bundle: the first view needs the model, the
/// sequence the address asks for and the standard condition's runs (about 4.8 of 12 MB
/// gzipped), shows that sequence's precomputed run, and the rest joins it unchanged.
#[test]
fn the_first_view_needs_one_sequence_and_the_rest_joins_it() {
    use pvrnn_explorer::bundle::BundleManifest;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default");
    let all: HashMap<String, Vec<u8>> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect();
    let manifest = BundleManifest::parse(&all[BUNDLE_MANIFEST], BUNDLE_MANIFEST).unwrap();
    let dataset_json = std::str::from_utf8(&all["dataset.json"]).unwrap();
    let wanted = "wiping_650mm_test0";
    let first = Bundle::first_files(&manifest, dataset_json, Some(wanted)).unwrap();
    assert_eq!(
        first,
        [
            "model.safetensors",
            "wiping_650mm_test0.safetensors",
            "runs-all-on.safetensors"
        ]
    );
    let part: HashMap<String, Vec<u8>> = first
        .iter()
        .chain([&BUNDLE_MANIFEST.to_string(), &"dataset.json".to_string()])
        .map(|f| (f.clone(), all[f].clone()))
        .collect();
    let part_bundle = Bundle::from_part_of_files(&part).unwrap();
    assert_eq!(part_bundle.dataset.sequences.len(), 1);
    assert!(part_bundle.notes.is_empty(), "{:?}", part_bundle.notes);
    let view = ViewState {
        sequence: Some(wanted.into()),
        t: 100,
        maps: false,
        ..ViewState::default()
    };
    let mut app = ExplorerApp::new(Some(part_bundle), view);
    app.compute(std::time::Duration::ZERO);
    let shown = app.current_run().expect("the standard run is precomputed");
    assert!(shown.complete, "the first view needs no computing");
    let shown = shown.trace.clone();

    let whole = Bundle::from_files(&all).unwrap();
    app.complete_bundle(whole);
    assert_eq!(app.bundle().unwrap().dataset.sequences.len(), 6);
    assert_eq!(app.view().sequence.as_deref(), Some(wanted));
    assert_eq!(app.view().t, 100);
    assert_eq!(
        app.current_run().unwrap().trace,
        shown,
        "the shown run stays"
    );
    app.view_mut().sequence = Some("repositioning_590mm_test0".into());
    app.compute(std::time::Duration::ZERO);
    assert!(
        app.current_run().unwrap().complete,
        "the others' runs joined"
    );
    // Without the address's sequence the first sequence comes first.
    let first = Bundle::first_files(&manifest, dataset_json, Some("nowhere")).unwrap();
    assert_eq!(first[1], "repositioning_590mm_test0.safetensors");
}

/// Contributions averaged over trials: the curve of two trials is the mean of each trial's
/// (noise seeds 0 and 1), and the subtask's maps pool both trials' steps.
#[test]
fn contributions_average_over_trials() {
    let curves = |seed: u32, trials: u8| {
        let view = ViewState {
            t: 2,
            maps: true,
            map_trials: trials,
            condition: Some(Condition {
                seed,
                ..Condition::standard(&common::config())
            }),
            ..ViewState::default()
        };
        let mut h = harness(ExplorerApp::new(Some(common::bundle()), view));
        for _ in 0..6 {
            h.step();
        }
        let labels = format!("{:?}", h.root());
        let curves: Vec<Vec<f32>> = pvrnn_core::ModuleId::ALL
            .iter()
            .map(|&m| h.state().contribution_curve(m))
            .collect();
        (curves, labels)
    };
    let (both, labels) = curves(0, 2);
    let (first, _) = curves(0, 1);
    let (second, _) = curves(1, 1);
    for m in 0..4 {
        assert_eq!(both[m].len(), 12);
        for t in 0..12 {
            let mean = (first[m][t] + second[m][t]) / 2.0;
            assert!((both[m][t] - mean).abs() <= 1e-6, "module {m}, step {t}");
        }
    }
    assert_ne!(first, second, "the seeds are different trials");
    for text in [
        "mean of 2 trials, seeds 0-1",
        "averaged over the subtask `first` (12 steps read out)",
    ] {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
}

/// A bundle as `pvrnn bundle` writes it: precomputed runs show without computing.
#[test]
fn precomputed_runs_load_instantly() {
    let model = common::model();
    let dataset = common::dataset();
    let mut files: HashMap<String, Vec<u8>> = HashMap::new();
    let config = {
        let mut m = model.clone();
        m.config.normalisation = Some(pvrnn_dataset::proprio_ranges(
            &dataset.split(Some(pvrnn_dataset::Split::Learn)),
        ));
        m.config
    };
    let with_ranges = pvrnn_core::Model {
        config: config.clone(),
        ..model.clone()
    };
    files.insert(
        "model.safetensors".into(),
        io::model_to_bytes(&with_ranges.weights_only()).unwrap(),
    );
    let dir = tempdir();
    dataset.write(&dir).unwrap();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let p = entry.unwrap().path();
        files.insert(
            p.file_name().unwrap().to_string_lossy().into_owned(),
            std::fs::read(&p).unwrap(),
        );
    }
    let seqs: Vec<_> = dataset.sequences.iter().collect();
    let obs = dataset.observations(&seqs, &config).unwrap();
    let arc = std::sync::Arc::new(with_ranges.clone());
    let settings = InferenceSettings::from_config(&config, 0);
    let runs: Vec<_> = (0..seqs.len())
        .map(|s| {
            run_sequence(
                arc.clone(),
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
    files.insert(
        "runs.safetensors".into(),
        io::runs_to_bytes(
            &config,
            &runs,
            &[0, 1, 2],
            Some(&names),
            io::StateStorage::F16,
        )
        .unwrap(),
    );
    files.insert(
        BUNDLE_MANIFEST.into(),
        br#"{"format": "pvrnn-bundle/1", "description": "from files", "model": "model.safetensors", "dataset": "dataset.json", "runs": "runs.safetensors"}"#.to_vec(),
    );
    let bundle = Bundle::from_files(&files).unwrap();
    assert_eq!(bundle.precomputed.len(), 3);
    let mut app = ExplorerApp::new(
        Some(bundle),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    );
    // No time to compute: the run is already there, complete.
    app.compute(std::time::Duration::ZERO);
    let run = app.current_run().unwrap();
    assert!(run.complete && run.trace.steps == 12);

    // A bundle with one runs file per condition and a model card, as `pvrnn bundle`
    // writes it: every condition's runs load, and the card shows in "About this model".
    let mut blind = settings.clone();
    blind.observed.proprio = false;
    let runs: Vec<_> = (0..seqs.len())
        .map(|s| run_sequence(arc.clone(), blind.clone(), &obs, s, false, &mut |_, _| {}).unwrap())
        .collect();
    files.insert(
        "runs-blind.safetensors".into(),
        io::runs_to_bytes(
            &config,
            &runs,
            &[0, 1, 2],
            Some(&names),
            io::StateStorage::F16,
        )
        .unwrap(),
    );
    let card = pvrnn_dataset::card::ModelCard {
        iteration: Some(12_345),
        training_seconds: Some(3600.0),
        training_machine: Some("a test machine".into()),
        training_data: "three sequences".into(),
        ..Default::default()
    };
    let manifest = serde_json::json!({
        "format": "pvrnn-bundle/1", "description": "with a card", "model": "model.safetensors",
        "dataset": "dataset.json", "runs": ["runs.safetensors", "runs-blind.safetensors"], "card": card,
    });
    files.insert(BUNDLE_MANIFEST.into(), manifest.to_string().into_bytes());
    let bundle = Bundle::from_files(&files).unwrap();
    assert_eq!(bundle.precomputed.len(), 6);
    assert_eq!(bundle.card.as_ref(), Some(&card));
    let mut h = harness(ExplorerApp::new(
        Some(bundle),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    ));
    assert!(
        h.query_by_label("12,345 iterations, 1.0 h on a test machine")
            .is_none()
    );
    h.get_by_label("About this model").click();
    h.step();
    h.step();
    h.get_by_label("12,345 iterations, 1.0 h on a test machine");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn files_that_do_not_fit_get_a_clear_message() {
    let mut other = common::config();
    other.vision.resolutions = vec![8, 16];
    let model = pvrnn_core::Model::<f32>::init(other, 1, 3, 1).unwrap();
    let e = Bundle::new("x".into(), model, common::dataset()).unwrap_err();
    assert!(e.contains("does not fit") && e.contains("[8, 16]"), "{e}");
    let files = vec![(
        "model.safetensors".to_string(),
        Ok(b"not safetensors".to_vec()),
    )];
    let e = pvrnn_explorer::drop::assemble(files, None).unwrap_err();
    assert!(e.contains("model.safetensors"), "{e}");
    let files = vec![(
        "dataset.json".to_string(),
        Ok(serde_json::to_vec(&common::dataset().manifest).unwrap()),
    )];
    let e = pvrnn_explorer::drop::assemble(files, Some(&common::bundle())).unwrap_err();
    assert!(
        e.contains("reach_learn.safetensors") && e.contains("not dropped"),
        "{e}"
    );
    // Two models: refused, naming both, whatever order they come in.
    let bytes = io::model_to_bytes(&common::model()).unwrap();
    for names in [
        ["b.safetensors", "a.safetensors"],
        ["a.safetensors", "b.safetensors"],
    ] {
        let files = names.map(|n| (n.to_string(), Ok(bytes.clone()))).to_vec();
        let e = pvrnn_explorer::drop::assemble(files, Some(&common::bundle())).unwrap_err();
        assert!(
            e.contains("a.safetensors and b.safetensors are both models"),
            "{e}"
        );
    }
    // A model whose proprioception is not the data's.
    let mut other = common::config();
    other.proprio_dims = 20;
    let model = pvrnn_core::Model::<f32>::init(other, 1, 3, 1).unwrap();
    let e = Bundle::new("x".into(), model, common::dataset()).unwrap_err();
    assert!(
        e.contains("20 proprioceptive dimensions, the data 28"),
        "{e}"
    );
}

#[test]
fn views_outside_the_bundle_are_brought_back_with_a_message() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    ));
    // What a hand-edited URL hash such as `#vision=8&seq=nope` used to put in the view.
    let mut c = h.state().condition().unwrap();
    c.vision_levels = 8;
    h.state_mut().view_mut().condition = Some(c);
    h.state_mut().view_mut().sequence = Some("nope".into());
    h.step();
    settle(&mut h);
    assert_eq!(h.state().view().sequence.as_deref(), Some("reach_learn"));
    assert_eq!(h.state().condition().unwrap().vision_levels, 2);
    let status = format!("{:?}", h.state().status());
    assert!(
        status.contains("no sequence `nope`") && status.contains("vision levels 8"),
        "{status}"
    );
    // The pickers are still there to choose another sequence.
    h.get_by_label("Trial");
    // The same through the hash.
    h.state_mut().apply_hash("seq=wipe_test&t=999&vision=5");
    h.step();
    assert_eq!(h.state().view().sequence.as_deref(), Some("wipe_test"));
    assert_eq!(h.state().view().t, 8);
    assert_eq!(h.state().condition().unwrap().vision_levels, 2);
    // Entries the view cannot take are named in the status line, not dropped silently.
    h.state_mut().apply_hash("t=3&H=0&lr=-1&colour=red");
    h.step();
    assert_eq!(h.state().view().t, 3);
    let status = format!("{:?}", h.state().status());
    assert!(
        status.contains("`H=0`") && status.contains("`lr=-1`") && status.contains("`colour=red`"),
        "{status}"
    );
}

#[test]
fn precomputed_runs_keep_their_exact_rate_and_skipped_ones_are_named() {
    let mut bundle = common::bundle();
    let config = bundle.model.config.clone();
    let obs = bundle.observations("reach_test").unwrap();
    let model = bundle.model.clone();
    // A rate that thousandths would round to another (0.091).
    let mut odd = InferenceSettings::from_config(&config, 0);
    odd.optimizer.lr = 0.0905;
    let run = run_sequence(model.clone(), odd, &obs, 0, false, &mut |_, _| {}).unwrap();
    // The second run names a sequence the data does not have.
    let names = vec!["reach_test".to_string(), "nope".to_string()];
    let bytes = io::runs_to_bytes(
        &config,
        &[run.clone(), run],
        &[1, 1],
        Some(&names),
        io::StateStorage::F16,
    )
    .unwrap();
    assert_eq!(bundle.add_runs(bytes, "odd.safetensors").unwrap(), 1);
    assert_eq!(bundle.precomputed[0].0.condition.lr(), 0.0905);
    let note = bundle.notes.join("\n");
    assert!(
        note.contains("odd.safetensors: 1 of 2 runs skipped")
            && note.contains("no sequence `nope`"),
        "{note}"
    );
    // The note reaches the status line.
    let app = ExplorerApp::new(Some(bundle), ViewState::default());
    assert!(format!("{:?}", app.status()).contains("runs skipped"));
}

fn tempdir() -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "explorer-test-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The test bundle's first view (no maps) computed inline, and a harness of the same view
/// whose runs compute on a background thread (on `backend`; `None`: the CPU), stepped
/// until the shown run is complete or `seconds` pass.
fn inline_and_background(
    backend: Option<(
        std::sync::Arc<dyn pvrnn_core::backend::Backend<f32>>,
        String,
    )>,
    seconds: u64,
) -> (Harness<'static, ExplorerApp>, Harness<'static, ExplorerApp>) {
    let view = ViewState {
        maps: false,
        ..ViewState::default()
    };
    let inline = harness(ExplorerApp::new(Some(common::bundle()), view.clone()));
    let mut h = Harness::builder()
        .with_size(eframe::egui::vec2(1400.0, 1000.0))
        .build_ui_state(
            |ui, app: &mut ExplorerApp| app.show(ui),
            ExplorerApp::new(Some(common::bundle()), view),
        );
    let ctx = h.ctx.clone();
    h.state_mut().compute_in_background_on(&ctx, backend);
    // The frames that built the harness may have computed the tiny run in the frame loop
    // already: the bundle again drops it, so that the background thread computes it.
    h.state_mut().set_bundle(common::bundle());
    for _ in 0..seconds * 200 {
        h.step();
        if h.state().current_run().is_some_and(|r| r.complete) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let run = h.state().current_run().expect("the shown run");
    assert!(
        run.complete && run.error.is_none(),
        "not finished in {seconds} s"
    );
    (inline, h)
}

#[test]
fn a_background_thread_computes_the_same_run_as_the_frame_loop() {
    let (inline, h) = inline_and_background(None, 15);
    let expected = inline.state().current_run().unwrap().trace.clone();
    let run = h.state().current_run().expect("the shown run");
    // Same model, inputs and seed: the same numbers, whichever thread computed them.
    assert!(run.trace == expected, "the background run differs");
}

/// `--backend wgpu` on the desktop: the background thread computes on the GPU (lavapipe
/// where there is none), the status bar names it, and the run agrees with the CPU's to
/// f32 summation order.
#[test]
fn a_gpu_computes_the_run_and_the_status_bar_says_so() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    // The tiny model's calls are all below the size worth a round trip: send them anyway.
    let gpu = pvrnn_wgpu::WgpuBackend::new()
        .unwrap()
        .with_tiling(pvrnn_wgpu::Tiling {
            min_work: 0,
            ..pvrnn_wgpu::Tiling::default()
        });
    let name = format!("wgpu on {}", gpu.adapter_name());
    let device = gpu.gpu().clone();
    let (inline, h) = inline_and_background(Some((std::sync::Arc::new(gpu), name.clone())), 30);
    assert!(
        device.read_backs() > 0,
        "the run did not compute on the GPU"
    );
    let expected = inline.state().predicted_vision().unwrap().to_vec();
    assert_eq!(h.state().compute_label(), format!("compute: {name}"));
    h.get_by_label(&format!("compute: {name}"));
    let got = h.state().predicted_vision().unwrap();
    let worst = expected
        .iter()
        .zip(got)
        .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-3, "the GPU's predicted image differs by {worst}");
}

#[test]
fn the_comparison_view_computes_each_condition_side_by_side() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            maps: false,
            t: 5,
            compare: Some(pvrnn_explorer::state::CompareSet::Vision),
            ..ViewState::default()
        },
    ));
    settle(&mut h);
    let cells = h.state().comparison();
    // Two vision choices (8+4, 4) x proprioception on / off.
    let labels: Vec<&str> = cells.iter().map(|c| c.label.as_str()).collect();
    assert_eq!(
        labels,
        [
            "vision 8+4, proprio on",
            "vision 4, proprio on",
            "vision 8+4, proprio off",
            "vision 4, proprio off"
        ]
    );
    for c in &cells {
        let e = c.error_at_t.expect("computed past the cursor");
        assert!(e.iter().all(|v| v.is_finite()), "{c:?}");
        assert_eq!(c.steps, 12);
    }
    // Different conditions, different runs: the errors are not all the same.
    assert!(cells.iter().any(|c| c.error_at_t != cells[0].error_at_t));
    h.get_by_label("vision 4, proprio off");
    // Each ablation instead, in the hash too.
    h.state_mut().apply_hash("compare=ablation");
    settle(&mut h);
    let cells = h.state().comparison();
    assert_eq!(cells.len(), 5);
    assert!(cells.iter().all(|c| c.error_at_t.is_some()));
    assert!(h.state().view().to_hash().contains("compare=ablation"));
}

#[test]
fn the_shown_run_exports_as_csv() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    ));
    let dir = tempdir();
    h.state_mut().set_export_dir(dir.clone());
    h.get_by_label("Export CSV").click();
    h.step();
    let status = format!("{:?}", h.state().status());
    assert!(status.contains("saved"), "{status}");
    let file = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|e| e == "csv"))
        .expect("a CSV file");
    let text = std::fs::read_to_string(&file).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 13, "a header and the 12 steps");
    let header: Vec<&str> = lines[0].split(',').collect();
    assert!(header.contains(&"executive.mu_p0") && header.contains(&"proprio_recon27"));
    let row: Vec<&str> = lines[1].split(',').collect();
    assert_eq!(row.len(), header.len());
    assert_eq!(&row[..2], ["0", "first"]);
    let trace = &h.state().current_run().unwrap().trace;
    assert_eq!(row[2].parse::<f32>().unwrap(), trace.free_energy[0]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_open_buttons_read_what_the_file_dialog_chose() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            maps: false,
            ..ViewState::default()
        },
    ));
    // Another model of the same shape, in a folder as a user would have it.
    let dir = tempdir().join("chosen");
    std::fs::create_dir_all(&dir).unwrap();
    let other = pvrnn_core::Model::<f32>::init(common::config(), 1, 12, 99).unwrap();
    let path = dir.join("other-model.safetensors");
    io::save_model(&path, &other).unwrap();
    let asked = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
    let log = asked.clone();
    let answer = dir.clone();
    h.state_mut().set_file_dialog(Box::new(move |folder: bool| {
        log.borrow_mut().push(folder);
        Some(vec![if folder {
            answer.clone()
        } else {
            answer.join("other-model.safetensors")
        }])
    }));
    for (button, folder) in [("Open files", false), ("Open folder", true)] {
        h.get_by_label(button).click();
        settle(&mut h);
        assert_eq!(asked.borrow().last(), Some(&folder));
        let bundle = h.state().bundle().unwrap();
        let weights = |m: &pvrnn_core::Model<f32>| -> Vec<f32> {
            m.params
                .named()
                .iter()
                .flat_map(|(_, t, _)| t.data().to_vec())
                .collect()
        };
        assert_eq!(
            weights(&bundle.model),
            weights(&other),
            "{button}: the chosen model is shown"
        );
        assert_ne!(weights(&common::model()), weights(&other));
        assert_eq!(
            bundle.dataset.manifest.sequences.len(),
            3,
            "the dataset stays"
        );
    }
    // Nothing chosen: the view stays and the message says what else works.
    h.state_mut().set_file_dialog(Box::new(|_| None));
    h.get_by_label("Open files").click();
    h.step();
    let status = format!("{:?}", h.state().status());
    assert!(
        status.contains("nothing opened") && status.contains("dropping files"),
        "{status}"
    );
    // A file that is not a model: an error naming it.
    std::fs::write(dir.join("broken.safetensors"), b"not a model").unwrap();
    let broken = dir.join("broken.safetensors");
    h.state_mut()
        .set_file_dialog(Box::new(move |_| Some(vec![broken.clone()])));
    h.get_by_label("Open files").click();
    h.step();
    let status = format!("{:?}", h.state().status());
    assert!(status.contains("broken.safetensors"), "{status}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Branch at t: the branch shares the run's steps before t, differs after, is drawn beside
/// it (plots and a row of images), lives in the address, and goes away when removed.
#[test]
fn a_branch_at_the_cursor_shares_the_past_and_is_shown_beside_the_run() {
    let view = ViewState {
        t: 6,
        ..ViewState::default()
    };
    let mut h = harness(ExplorerApp::new(Some(common::bundle()), view));
    h.get_by_label("Branch here").click();
    h.step();
    settle(&mut h);
    let app = h.state();
    let branch = app.view().branch.expect("a branch at the cursor");
    assert_eq!((branch.at, branch.condition.vision_levels), (6, 0));
    assert!(app.view().to_hash().contains("branch=6&b.vision=0"));
    let (run, key) = (app.current_run().unwrap(), app.branch_key().unwrap());
    let forked = app.run(&key).expect("the branch is computed");
    assert!(
        forked.complete && forked.error.is_none(),
        "{:?}",
        forked.error
    );
    assert_eq!(forked.trace.steps, 12);
    for t in 0..12 {
        let apart: f64 = pvrnn_core::ModuleId::ALL
            .iter()
            .map(|&m| pvrnn_explorer::app::divergence(&run.trace, &forked.trace, m, t))
            .sum();
        assert_eq!(apart == 0.0, t < 6, "step {t}: divergence {apart}");
    }
    let labels = format!("{:?}", h.root());
    for text in [
        "Branch at step 6",
        "branch (from step 6)",
        "divergence: RMS |d(branch) - d(run)| per module",
        "KL(posterior || prior) per module (nats)",
    ] {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
    // The latent traces can show the branch instead of its run.
    h.get_by_label("latent traces of the branch").click();
    h.run_steps(2);
    assert!(h.state().view().to_hash().contains("btraces=1"));
    let labels = format!("{:?}", h.root());
    assert!(labels.contains("The traces below are the branch's (from step 6)"));
    h.get_by_label("remove the branch").click();
    h.step();
    assert_eq!(h.state().view().branch, None);
}

/// Two networks side by side: a checkpoint opened as the second network runs the shown
/// sequence under the shown condition beside the first, with its errors, their difference
/// and its images; a network that sees differently is refused with the reason.
#[test]
fn a_second_network_runs_beside_the_first() {
    let mut h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState {
            t: 4,
            ..ViewState::default()
        },
    ));
    let dir = tempdir().join("second");
    std::fs::create_dir_all(&dir).unwrap();
    let later = pvrnn_core::Model::<f32>::init(common::config(), 1, 12, 77).unwrap();
    io::save_model(&dir.join("late.safetensors"), &later).unwrap();
    let file = dir.join("late.safetensors");
    h.state_mut()
        .set_file_dialog(Box::new(move |_| Some(vec![file.clone()])));
    h.get_by_label("Second network").click();
    h.run_steps(3);
    h.get_by_label("Open files (a checkpoint of this dataset, or a bundle's files)")
        .click();
    h.step();
    settle(&mut h);
    let app = h.state();
    let (first, second) = (app.current_run().unwrap(), app.second_run().unwrap());
    assert!(
        second.complete && second.error.is_none(),
        "{:?}",
        second.error
    );
    assert_eq!(second.trace.steps, first.trace.steps);
    assert_ne!(second.trace.recon_error, first.trace.recon_error);
    let labels = format!("{:?}", h.root());
    for text in [
        "late.safetensors",
        "second network",
        "difference: second - first (below 0: the second predicts better)",
    ] {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
    // Another condition: the second network follows it.
    h.get_by_label("executive").click();
    h.step();
    settle(&mut h);
    let second = h.state().second_run().unwrap();
    assert!(second.complete && second.trace.steps == 12);
    // The comparison takes networks too: each condition on the first, then on the second.
    h.state_mut().view_mut().compare = Some(pvrnn_explorer::state::CompareSet::Vision);
    h.step();
    settle(&mut h);
    let cells = h.state().comparison();
    assert_eq!(cells.len(), 8);
    let (first, second): (Vec<_>, Vec<_>) = cells.iter().partition(|c| !c.second);
    for (a, b) in first.iter().zip(&second) {
        assert_eq!(a.key, b.key);
        assert!(b.label.ends_with("(second network)"), "{}", b.label);
        assert_eq!((a.steps, b.steps), (12, 12));
        assert_ne!(a.mean_error, b.mean_error, "{}", b.label);
    }
    h.state_mut().view_mut().compare = None;
    h.step();
    h.get_by_label("close the second network").click();
    h.step();
    assert!(h.state().second_run().is_none());

    // A network with other cameras cannot be compared, and the user is told why.
    let mut config = common::config();
    config.vision.resolutions = vec![8];
    let dataset = common::dataset();
    let other = pvrnn_core::Model::<f32>::init(config, 1, 12, 5).unwrap();
    let refused =
        Bundle::new("one level".into(), other, dataset).and_then(|b| h.state_mut().set_second(b));
    let err = refused.unwrap_err();
    assert!(err.contains("cannot be compared"), "{err}");
}

/// The tour: offered on a first visit, stepped through, remembered once done or skipped.
#[test]
fn the_tour_is_offered_once_and_can_be_skipped_or_restarted() {
    let config = tempdir().join("tour-config");
    let _ = std::fs::remove_dir_all(&config);
    let mut app = ExplorerApp::new(Some(common::bundle()), ViewState::default());
    app.set_config_dir(Some(config.clone()));
    app.offer_tour();
    let mut h = harness(app);
    assert_eq!(h.state().tour_stop(), Some(0));
    let labels = format!("{:?}", h.root());
    assert!(labels.contains("Tour 1 of 6: What you see"), "{labels}");
    assert!(labels.contains("A PV-RNN trained on "), "{labels}");
    for stop in 1..6 {
        h.get_by_label("next").click();
        // A new stop is a new window: egui sizes it before it shows.
        h.run_steps(6);
        assert_eq!(h.state().tour_stop(), Some(stop));
    }
    h.get_by_label("done").click();
    h.run_steps(6);
    assert_eq!(h.state().tour_stop(), None);
    // Remembered: not offered again; the Tour button starts it, and it can be skipped.
    let mut app = ExplorerApp::new(Some(common::bundle()), ViewState::default());
    app.set_config_dir(Some(config));
    app.offer_tour();
    let mut h = harness(app);
    assert_eq!(h.state().tour_stop(), None);
    h.get_by_label("Tour").click();
    h.run_steps(6);
    assert_eq!(h.state().tour_stop(), Some(0));
    h.get_by_label("skip the tour").click();
    h.run_steps(6);
    assert_eq!(h.state().tour_stop(), None);
}

/// A second network named by the view's address (`second=`, relative to the working folder
/// on the desktop, to the site in the browser) opens beside the first; one that cannot be
/// compared is refused with a message and the address stops naming it; closing it takes it
/// out of the address.
#[test]
fn a_second_network_opens_from_the_address() {
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default");
    let view = ViewState {
        second: Some("../../models/default".into()),
        ..ViewState::default()
    };
    let app = ExplorerApp::new(Some(Bundle::open_dir(&shipped).unwrap()), view.clone());
    let mut h = Harness::builder()
        .with_size(eframe::egui::vec2(1400.0, 1000.0))
        .build_ui_state(|ui, app: &mut ExplorerApp| app.show(ui), app);
    h.run_steps(4);
    let status = format!("{:?}", h.state().status());
    assert!(status.contains("second network: "), "{status}");
    assert!(
        h.state()
            .view()
            .to_hash()
            .contains("second=..%2F..%2Fmodels%2Fdefault")
    );
    h.get_by_label("close the second network").click();
    h.run_steps(2);
    assert_eq!(h.state().view().second, None);
    // The shipped network beside a small one of other cameras: refused, and forgotten.
    let app = ExplorerApp::new(Some(common::bundle()), view);
    let mut h = Harness::builder()
        .with_size(eframe::egui::vec2(1400.0, 1000.0))
        .build_ui_state(|ui, app: &mut ExplorerApp| app.show(ui), app);
    h.run_steps(4);
    let status = format!("{:?}", h.state().status());
    assert!(
        status.contains("the second network") && status.contains("cannot be compared"),
        "{status}"
    );
    assert_eq!(h.state().view().second, None);
}

/// Each stop of the tour stands beside the widget it names and outlines it: the images
/// panel on the left, the latent states in the centre, the conditions above, the time bar
/// below, the question buttons; the first stop is in the middle of the window.
#[test]
fn each_stop_of_the_tour_stands_beside_the_widget_it_names() {
    use pvrnn_explorer::TourTarget;
    let mut app = ExplorerApp::new(Some(common::bundle()), ViewState::default());
    app.start_tour();
    let mut h = harness(app);
    h.run_steps(6);
    let window = |h: &Harness<'static, ExplorerApp>, stop: usize| {
        let title = format!("Tour {} of 6", stop + 1);
        let labels = format!("{:?}", h.root());
        assert!(labels.contains(&title), "no `{title}` window: {labels}");
        // The window's buttons: its rect is theirs and its text's.
        h.get_by_label(if stop == 5 { "done" } else { "next" })
            .rect()
    };
    let (target, rect) = h.state().tour_target().unwrap();
    assert_eq!((target, rect), (TourTarget::Everything, None));
    let middle = window(&h, 0).center().x;
    assert!((middle - 700.0).abs() < 200.0, "first stop at x = {middle}");
    let expected = [
        TourTarget::Images,
        TourTarget::Latents,
        TourTarget::Conditions,
        TourTarget::Time,
        TourTarget::Questions,
    ];
    for (stop, want) in (1..6).zip(expected) {
        h.get_by_label("next").click();
        h.run_steps(6);
        let (target, rect) = h.state().tour_target().unwrap();
        assert_eq!(target, want, "stop {stop}");
        let rect = rect.unwrap_or_else(|| panic!("stop {stop}: {want:?} was not drawn"));
        let buttons = window(&h, stop);
        match want {
            // Right of the images panel, level with its upper part.
            TourTarget::Images => assert!(
                buttons.left() > rect.right() && buttons.left() < rect.right() + 420.0,
                "{buttons:?} beside {rect:?}"
            ),
            // Inside the central panel, near its top.
            TourTarget::Latents => assert!(
                rect.contains(buttons.center()) && buttons.top() < rect.top() + 400.0,
                "{buttons:?} in {rect:?}"
            ),
            // Just below the controls.
            TourTarget::Conditions => assert!(
                buttons.top() > rect.bottom() && buttons.top() < rect.bottom() + 400.0,
                "{buttons:?} under {rect:?}"
            ),
            // Just above the time bar.
            TourTarget::Time => assert!(
                buttons.bottom() < rect.top() && buttons.bottom() > rect.top() - 100.0,
                "{buttons:?} over {rect:?}"
            ),
            // Under the buttons it explains, from their left edge on.
            TourTarget::Questions => {
                let findings = h.get_by_label("Findings").rect();
                assert!(rect.contains(findings.center()), "{findings:?} in {rect:?}");
                assert!(
                    buttons.top() > rect.bottom() && buttons.top() < rect.bottom() + 400.0,
                    "{buttons:?} under {rect:?}"
                );
            }
            TourTarget::Everything => unreachable!(),
        }
    }
}

/// Another robot: one camera, one 6-joint arm without torque sensing, a gripper channel.
#[test]
fn a_robot_of_another_shape_is_shown_with_its_own_channels() {
    use pvrnn_dataset::{Channels, Dataset, Split};
    let channels = Channels {
        joints: (1..=6).map(|j| format!("q{j}")).collect(),
        torques: Vec::new(),
        extra: vec!["gripper".into()],
    };
    let one_arm = |name: &str, split, t: usize, seed: u32| {
        let mut s = common::sequence(name, "reach", split, t, seed);
        s.cameras = 1;
        s.images.truncate(t * 8 * 8 * 3);
        s.joints = (0..t * 6).map(|i| (i as f32 * 0.1).sin()).collect();
        s.torques = Vec::new();
        s.extra = (0..t)
            .map(|i| if i > t / 2 { 0.01 } else { 0.08 })
            .collect();
        s
    };
    let dataset = Dataset::with_channels(
        "one arm",
        vec!["wrist".into()],
        8,
        channels,
        vec![
            one_arm("learn", Split::Learn, 10, 1),
            one_arm("test", Split::Test, 8, 2),
        ],
    )
    .unwrap();
    let mut config = common::config();
    config.vision.cameras = 1;
    // A model with the paper's 28 proprioceptive dimensions does not fit, and says why.
    let paper = pvrnn_core::Model::<f32>::init(config.clone(), 1, 10, 3).unwrap();
    let paper = Bundle::new("x".into(), paper, dataset.clone()).unwrap_err();
    assert!(
        paper.contains("6 joint angles, 0 torques, 1 extra"),
        "{paper}"
    );
    config.proprio_dims = 7;
    let model = pvrnn_core::Model::<f32>::init(config, 1, 10, 3).unwrap();
    let bundle = Bundle::new("one arm".into(), model, dataset).unwrap();
    let h = harness(ExplorerApp::new(Some(bundle), ViewState::default()));
    let run = h.state().current_run().unwrap();
    assert_eq!(run.trace.steps, 10, "the run is computed for every step");
    assert_eq!(run.trace.proprio_recon.len(), 10 * 7);
    // A plot per kind of channel the robot has: no torque plot.
    let labels = format!("{:?}", h.root());
    assert!(
        labels.contains("joint angles (rad)") && labels.contains("extra channels"),
        "{labels}"
    );
    assert!(
        !labels.contains("torques (N m)"),
        "no torque plot for a robot without them"
    );
}

/// A robot that is not the paper's: three cameras (head, left_wrist, right_wrist), 3 joints,
/// 2 torques and 1 extra channel. Every label comes from the bundle's names.
#[test]
fn another_robot_s_cameras_and_channels_label_the_views() {
    let view = ViewState {
        compare: Some(pvrnn_explorer::state::CompareSet::Ablation),
        ..ViewState::default()
    };
    let h = harness(ExplorerApp::new(Some(common::three_camera_bundle()), view));
    let labels = format!("{:?}", h.root());
    for text in common::THREE_CAMERA_LABELS {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
    for paper_only in common::PAPER_ONLY_LABELS {
        assert!(!labels.contains(paper_only), "`{paper_only}` in the view");
    }
    // Its data names no bed height: no bed picker.
    assert!(
        labels.contains("Task") && !labels.contains("Bed"),
        "{labels}"
    );
    // The tour speaks of this robot, not of caregiving.
    let mut h = harness(ExplorerApp::new(
        Some(common::three_camera_bundle()),
        ViewState::default(),
    ));
    h.get_by_label("Tour").click();
    h.run_steps(6);
    assert_eq!(h.state().tour_stop(), Some(0));
    let labels = format!("{:?}", h.root());
    assert!(
        labels.contains(
            "A PV-RNN trained on one task (handover) from vision (3 cameras) and proprioception (3 joint angles, 2 torques, 1 other channels)."
        ),
        "{labels}"
    );
    assert!(!labels.contains("caregiving"), "{labels}");
}

/// The paper's robot: its two arms' channels in two colour groups the plot names.
#[test]
fn the_paper_s_arms_are_named_by_their_colour_groups() {
    let h = harness(ExplorerApp::new(
        Some(common::bundle()),
        ViewState::default(),
    ));
    let labels = format!("{:?}", h.root());
    for text in [
        "left camera",
        "right camera",
        "joint angles (rad); colours: left red, right cyan",
        "torques (N m); colours: left red, right cyan",
    ] {
        assert!(labels.contains(text), "no `{text}` in the view");
    }
}

/// Whole views drawn by egui's wgpu renderer (on a CPU Vulkan device such as Mesa's
/// lavapipe where there is no GPU) and compared with the pictures in `tests/snapshots/`:
/// layout, plots, images and text, as a user sees them. `UPDATE_SNAPSHOTS=1 cargo test`
/// rewrites the pictures after an intended change; look at them before committing.
mod snapshots {
    use super::*;
    use egui_kittest::SnapshotOptions;

    fn drawn(app: ExplorerApp) -> Harness<'static, ExplorerApp> {
        let mut h = Harness::builder()
            .with_size(eframe::egui::vec2(1400.0, 1000.0))
            // Plots of computed runs may move by a fraction of a pixel between CPUs (fused
            // multiply-adds); a few hundred anti-aliased edge pixels may differ, no more.
            .with_options(SnapshotOptions::new().threshold(1.0).max_failed_pixels(600))
            .wgpu()
            .build_ui_state(|ui, app: &mut ExplorerApp| app.show(ui), app);
        settle(&mut h);
        h
    }

    #[test]
    fn the_main_view() {
        let view = ViewState {
            t: 7,
            ..ViewState::default()
        };
        drawn(ExplorerApp::new(Some(common::bundle()), view)).snapshot("main_view");
    }

    #[test]
    fn the_comparison_view() {
        let view = ViewState {
            t: 5,
            maps: false,
            compare: Some(pvrnn_explorer::state::CompareSet::Vision),
            ..ViewState::default()
        };
        drawn(ExplorerApp::new(Some(common::bundle()), view)).snapshot("comparison_view");
    }

    #[test]
    fn a_branch_beside_its_run() {
        let view = ViewState {
            t: 9,
            maps: false,
            branch: Some(pvrnn_explorer::state::BranchView {
                at: 5,
                condition: Condition {
                    proprio: false,
                    ..Condition::standard(&common::bundle().model.config)
                },
            }),
            ..ViewState::default()
        };
        drawn(ExplorerApp::new(Some(common::bundle()), view)).snapshot("branch_view");
    }

    #[test]
    fn contributions_over_time() {
        let view = ViewState {
            t: 8,
            maps: true,
            ..ViewState::default()
        };
        let mut h = drawn(ExplorerApp::new(Some(common::bundle()), view));
        for _ in 0..4 {
            h.step();
        }
        h.snapshot("contributions_over_time");
    }

    #[test]
    fn the_findings_panel() {
        let mut h = drawn(ExplorerApp::new(
            Some(common::bundle()),
            ViewState::default(),
        ));
        h.get_by_label("Findings").click();
        h.run_steps(3);
        h.snapshot("findings");
    }

    #[test]
    fn a_second_network_beside_the_first() {
        let mut app = ExplorerApp::new(
            Some(common::bundle()),
            ViewState {
                t: 6,
                ..ViewState::default()
            },
        );
        let later = pvrnn_core::Model::<f32>::init(common::config(), 1, 12, 77).unwrap();
        let later = Bundle::new("a later checkpoint".into(), later, common::dataset()).unwrap();
        app.set_second(later).unwrap();
        drawn(app).snapshot("second_network");
    }

    #[test]
    fn the_tour_s_first_stop() {
        let mut app = ExplorerApp::new(Some(common::bundle()), ViewState::default());
        app.start_tour();
        drawn(app).snapshot("tour");
    }

    #[test]
    fn the_view_without_a_model() {
        drawn(ExplorerApp::new(None, ViewState::default())).snapshot("no_model");
    }
}

/// Frames until the Drive window's episode is over (it joins the data and is shown).
fn drive_to_the_end(h: &mut Harness<'static, ExplorerApp>) {
    for _ in 0..5000 {
        h.step();
        if !h.state().driving() {
            settle(h);
            return;
        }
    }
    panic!("the episode did not finish");
}

/// Frames (at least one, at most 200) until the episode being driven is longer than
/// `steps`; its length.
fn frames_until_longer(h: &mut Harness<'static, ExplorerApp>, steps: usize) -> usize {
    let live = pvrnn_explorer::driving::EPISODE_SO_FAR;
    let len = |h: &Harness<'static, ExplorerApp>| {
        h.state()
            .bundle()
            .unwrap()
            .dataset
            .by_name(live)
            .map_or(0, |s| s.len())
    };
    for _ in 0..200 {
        h.step();
        if len(h) > steps {
            break;
        }
    }
    len(h)
}

#[test]
fn the_network_drives_the_robot_and_a_link_replays_the_episode() {
    let mut h = harness(ExplorerApp::new(
        Some(common::caresim_bundle()),
        ViewState::default(),
    ));
    h.get_by_label("Drive").click();
    h.run_steps(2);
    h.get_by_label("Start driving").click();
    h.run_steps(3);
    assert!(h.state().driving(), "the episode runs frame by frame");
    // Perturbed while it acts: the push and the vision lost are recorded in the drive, so a
    // link replays them.
    h.get_by_label("push the left arm").click();
    h.run_steps(2);
    // While it acts, the main panels show the episode so far, the cursor on its newest
    // step, and the address holds the drive rather than a sequence no link could open.
    let app = h.state();
    let live = pvrnn_explorer::driving::EPISODE_SO_FAR;
    assert_eq!(app.view().sequence.as_deref(), Some(live));
    let so_far = app.bundle().unwrap().dataset.by_name(live).unwrap().len();
    assert!(so_far >= 1);
    assert_eq!(app.view().t, so_far - 1);
    assert_eq!(app.current_run().unwrap().trace.steps, so_far);
    assert!(!app.view().to_hash().contains("seq="));
    h.get_by_label("cover the right camera").click();
    h.run_steps(2);
    // It grows with the episode.
    let grown = frames_until_longer(&mut h, so_far);
    let app = h.state();
    assert!(grown > so_far, "{grown} steps, as before");
    assert_eq!(app.current_run().unwrap().trace.steps, grown);
    assert_eq!(
        app.view().t,
        grown - 1,
        "the cursor follows the newest step"
    );
    // A cursor moved back stays where the user put it while the episode grows.
    h.key_press(eframe::egui::Key::ArrowLeft);
    h.step();
    let back = h.state().view().t;
    frames_until_longer(&mut h, grown + 1);
    assert_eq!(h.state().view().t, back);
    h.get_by_label("see nothing").click();
    h.run_steps(2);
    assert!(
        h.query_by_label("see 16x16 only").is_none(),
        "no vision left to drop: {:?}",
        h.state().status()
    );
    drive_to_the_end(&mut h);
    let app = h.state();
    let shown = app.view().sequence.clone().unwrap();
    assert!(
        shown.starts_with("drive repositioning:650:0:1:network;push="),
        "{shown}"
    );
    assert!(shown.contains(":0 | vision 3 proprio 1"), "{shown}");
    assert!(shown.contains(";vision="), "{shown}");
    assert!(shown.contains(";occlude=right:"), "{shown}");
    assert!(
        app.bundle().unwrap().dataset.by_name(live).is_none(),
        "the episode so far makes way for the episode"
    );
    let episode = app
        .bundle()
        .unwrap()
        .dataset
        .by_name(&shown)
        .unwrap()
        .clone();
    let run = app.current_run().expect("the episode's run is shown");
    assert!(run.complete);
    assert_eq!(run.trace.steps, episode.len());
    assert!(
        format!("{:?}", app.status()).contains("repositioning: failure"),
        "{:?}",
        app.status()
    );
    let hash = app.view().to_hash();
    assert!(hash.contains("drive=repositioning"), "{hash}");
    // The link on a fresh window: the same episode, byte for byte.
    let standard = Condition::standard(&common::caresim_bundle().model.config);
    let (view, notes) = ViewState::from_hash(&hash, &ViewState::default(), standard);
    assert!(notes.is_empty(), "{notes:?}");
    let mut again = harness(ExplorerApp::new(Some(common::caresim_bundle()), view));
    drive_to_the_end(&mut again);
    let app = again.state();
    assert_eq!(app.view().sequence.as_deref(), Some(shown.as_str()));
    let replayed = app.bundle().unwrap().dataset.by_name(&shown).unwrap();
    assert_eq!(replayed.joints, episode.joints);
    assert!(replayed.images == episode.images);
}
