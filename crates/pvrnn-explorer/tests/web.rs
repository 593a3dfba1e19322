//! The explorer's web entry and browser glue, in headless Chromium (scripts/test.sh):
//! `WASM_BINDGEN_TEST_WEBDRIVER_JSON=$PWD/tests/web/webdriver.json CHROMEDRIVER=/usr/bin/chromedriver
//! cargo test -p pvrnn-explorer --target wasm32-unknown-unknown` (the JSON turns on software
//! WebGL). The built site, with its worker, is tested by tests/web/smoke.mjs.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(target_arch = "wasm32")]

mod common;

use eframe::wasm_bindgen::JsCast;
use eframe::web_sys;
use pvrnn_explorer::{ExplorerApp, ViewState};

use pvrnn_explorer::condition::{Condition, RunKey};
use pvrnn_explorer::engine::{CompactStep, Event, Finished, ModuleStates, StepLayout};
use pvrnn_explorer::worker::{Command, Reply};
use wasm_bindgen_test::{wasm_bindgen_test, wasm_bindgen_test_configure};
use web_time::Duration;

wasm_bindgen_test_configure!(run_in_browser);

fn key() -> RunKey {
    RunKey::new(
        "wiping_650mm_test0",
        Condition {
            vision_levels: 1,
            proprio: true,
            ablation: [false, true, false, false],
            ablation_mode: pvrnn_core::AblationMode::Inference,
            window: 30,
            iterations: 50,
            lr_bits: 0.09f64.to_bits(),
            seed: 3,
        },
    )
}

async fn sleep_ms(ms: i32) {
    let promise = js_sys::Promise::new(&mut |resolve, _| {
        web_sys::window()
            .expect("a window")
            .set_timeout_with_callback_and_timeout_and_arguments_0(&resolve, ms)
            .expect("setTimeout");
    });
    wasm_bindgen_futures::JsFuture::from(promise)
        .await
        .expect("timer");
}

/// The same entry `main` uses, on a test canvas with a tiny bundle: the app starts, draws,
/// and computes the shown run live (inline here: the test page has no worker script).
#[wasm_bindgen_test]
async fn the_web_entry_starts_the_explorer_and_computes_a_run() {
    let document = web_sys::window()
        .and_then(|w| w.document())
        .expect("a document");
    let canvas: web_sys::HtmlCanvasElement = document
        .create_element("canvas")
        .expect("canvas")
        .dyn_into()
        .expect("a canvas element");
    canvas
        .set_attribute(
            "style",
            "position:absolute;left:0;top:0;width:1000px;height:700px",
        )
        .expect("style");
    document
        .body()
        .expect("body")
        .append_child(&canvas)
        .expect("appended");

    let handle = pvrnn_explorer::web::start(canvas, |_| {
        ExplorerApp::new(Some(common::bundle()), ViewState::default())
    })
    .await
    .expect("the explorer starts");
    let runner = handle.runner();
    let complete = |runner: &eframe::WebRunner| {
        runner
            .app_mut::<ExplorerApp>()
            .and_then(|app| app.current_run().map(|e| e.complete))
            .unwrap_or(false)
    };
    for _ in 0..300 {
        if complete(runner) || handle.has_panicked() {
            break;
        }
        sleep_ms(100).await;
    }
    assert!(
        !handle.has_panicked(),
        "the app panicked: {:?}",
        handle.panic_message()
    );
    {
        let app = runner.app_mut::<ExplorerApp>().expect("the app is running");
        let run = app.current_run().expect("the shown sequence has a run");
        assert!(run.complete, "the live run did not finish in 30 s");
        assert_eq!(run.error, None);
        assert!(run.trace.steps > 0 && run.trace.free_energy.iter().all(|f| f.is_finite()));
    }

    // Branch at step 5 without vision, as a link does: through the page's address.
    web_sys::window()
        .unwrap()
        .location()
        .set_hash("t=5&branch=5&b.vision=0")
        .unwrap();
    let branched = |runner: &eframe::WebRunner| {
        let app = runner.app_mut::<ExplorerApp>()?;
        let key = app.branch_key()?;
        app.run(&key).map(|e| e.complete)
    };
    for _ in 0..300 {
        if branched(runner) == Some(true) {
            break;
        }
        sleep_ms(100).await;
    }
    let forked = {
        let app = runner.app_mut::<ExplorerApp>().expect("the app is running");
        let branch = app.branch_key().expect("the address's branch");
        assert_eq!(branch.then.map(|s| s.at), Some(5));
        app.run(&branch).expect("the branch is computed").clone()
    };
    assert!(
        forked.complete && forked.error.is_none(),
        "{:?}",
        forked.error
    );
    assert_eq!(forked.trace.steps, 12);

    // A second network (another checkpoint), chosen in the browser's picker.
    let later = pvrnn_core::Model::<f32>::init(common::config(), 1, 12, 77).unwrap();
    let bytes = pvrnn_core::io::model_to_bytes(&later).unwrap();
    let input = {
        let mut app = runner.app_mut::<ExplorerApp>().expect("the app is running");
        app.pick_second_network(false).expect("a file input")
    };
    let chosen = web_sys::DataTransfer::new().expect("a DataTransfer");
    let parts = js_sys::Array::of1(&js_sys::Uint8Array::from(&bytes[..]));
    let file = web_sys::File::new_with_u8_array_sequence(&parts, "late.safetensors").unwrap();
    chosen.items().add_with_file(&file).expect("added");
    input.set_files(chosen.files().as_ref());
    input
        .dispatch_event(&web_sys::Event::new("change").expect("an event"))
        .expect("dispatched");
    let second = |runner: &eframe::WebRunner| {
        let app = runner.app_mut::<ExplorerApp>()?;
        app.second_run().map(|e| e.complete)
    };
    for _ in 0..300 {
        if second(runner) == Some(true) {
            break;
        }
        sleep_ms(100).await;
    }
    {
        let app = runner.app_mut::<ExplorerApp>().expect("the app is running");
        let second = app.second_run().expect("the second network's run");
        assert!(
            second.complete && second.error.is_none(),
            "{:?}",
            second.error
        );
        assert_ne!(second.trace.recon_error, forked.trace.recon_error);
    }
    web_sys::window().unwrap().location().set_hash("").unwrap();
}

/// A robot that is not the paper's is labelled with its own names in the browser build too:
/// the app's accessibility tree (what screen readers get) holds every label.
#[wasm_bindgen_test]
fn another_robot_s_names_label_the_web_view() {
    let view = ViewState {
        compare: Some(pvrnn_explorer::state::CompareSet::Ablation),
        ..ViewState::default()
    };
    let mut app = ExplorerApp::new(Some(common::three_camera_bundle()), view);
    let ctx = eframe::egui::Context::default();
    ctx.enable_accesskit();
    let input = || eframe::egui::RawInput {
        screen_rect: Some(eframe::egui::Rect::from_min_size(
            eframe::egui::Pos2::ZERO,
            eframe::egui::vec2(1400.0, 1000.0),
        )),
        ..Default::default()
    };
    let mut tree = String::new();
    for _ in 0..400 {
        let mut out = ctx.run_ui(input(), |ui| app.show(ui));
        // Headless: no textures are uploaded, so their deltas are dropped on purpose.
        out.textures_delta.clear();
        tree = format!("{:?}", out.platform_output.accesskit_update);
        if app.idle() && tree.contains("elbow_tau") {
            break;
        }
    }
    for text in common::THREE_CAMERA_LABELS {
        assert!(tree.contains(text), "no `{text}` in the web view");
    }
    for paper_only in common::PAPER_ONLY_LABELS {
        assert!(!tree.contains(paper_only), "`{paper_only}` in the web view");
    }
}

/// A panic shows over the page, with its message, instead of a frozen canvas.
#[wasm_bindgen_test]
fn a_panic_is_shown_over_the_page() {
    pvrnn_explorer::web::show_panic("index out of bounds", "at somewhere.rs:1");
    let text = web_sys::window()
        .and_then(|w| w.document())
        .and_then(|d| d.get_element_by_id(pvrnn_explorer::web::PANIC_ELEMENT_ID))
        .and_then(|e| e.text_content())
        .expect("the panic message element");
    assert!(
        text.contains("index out of bounds") && text.contains("Reload the page"),
        "{text}"
    );
}

/// Waits up to 10 s for a worker's failure.
async fn failure_of(mut worker: pvrnn_explorer::worker::WorkerClient) -> Option<String> {
    use pvrnn_explorer::executor::Executor;
    for _ in 0..100 {
        if let Some(f) = worker.broken() {
            return Some(f);
        }
        sleep_ms(100).await;
    }
    None
}

/// A worker that cannot start (its script is missing), or that says it cannot go on (a
/// result it could not send), surfaces as a failure with a message, so runs fall back to the
/// page instead of waiting for ever.
#[wasm_bindgen_test]
async fn a_lost_worker_is_reported() {
    use pvrnn_explorer::worker::WorkerClient;
    let ctx = eframe::egui::Context::default();
    let missing = WorkerClient::spawn("./no-such-worker.js", ctx.clone()).expect("a Worker");
    assert!(failure_of(missing).await.is_some(), "a missing script");
    let script = "postMessage({kind: 'ready', generation: 0}); \
                  postMessage({kind: 'fatal', generation: 0, message: 'cannot send a result'});";
    let fatal =
        WorkerClient::spawn(&format!("data:text/javascript,{script}"), ctx).expect("a Worker");
    let failure = failure_of(fatal).await;
    assert_eq!(failure.as_deref(), Some("cannot send a result"));
}

#[wasm_bindgen_test]
fn worker_messages_round_trip() {
    let layout = StepLayout {
        z: [1, 2, 1, 1],
        d: [2, 3, 2, 2],
        proprio: 3,
    };
    let mut n = 0.0f32;
    let mut next = |len: usize| {
        (0..len)
            .map(|_| {
                n += 0.25;
                n
            })
            .collect::<Vec<f32>>()
    };
    let step = CompactStep {
        modules: std::array::from_fn(|m| ModuleStates {
            mu_p: next(layout.z[m]),
            sigma_p: next(layout.z[m]),
            mu_q: next(layout.z[m]),
            sigma_q: next(layout.z[m]),
            d: next(layout.d[m]),
            prior_d: next(layout.d[m]),
        }),
        free_energy: 12.5,
        recon_error: [0.01, 0.02],
        proprio_recon: next(3),
        proprio_prior: next(3),
    };
    let events = [
        Event::Step(key(), Box::new(step)),
        Event::Done(Finished {
            key: key(),
            steps: 300,
            busy: Duration::from_millis(1500),
            wall: Duration::from_millis(2000),
            replayed: 40,
        }),
        Event::Failed(key(), "no observations".into()),
    ];
    for event in events {
        let reply = Reply::Event {
            generation: 7,
            event,
        };
        let (message, _transfer) = reply.encode();
        let back = Reply::decode(&message, Some(&layout), None).expect("decodes");
        assert_eq!(back, reply);
    }
    for reply in [
        Reply::Ready {
            compute: "WebGPU, SwiftShader (worker)".into(),
        },
        Reply::Fatal {
            generation: 3,
            message: "cannot send a result".into(),
        },
    ] {
        assert_eq!(Reply::decode(&reply.encode().0, None, None).unwrap(), reply);
    }
    // A step of another model's layout is refused with a message, not misread.
    let (message, _) = Reply::Event {
        generation: 7,
        event: Event::Step(key(), Box::default()),
    }
    .encode();
    let err = Reply::decode(&message, Some(&layout), None).unwrap_err();
    assert!(err.contains("numbers"), "{err}");
    // Commands, page to worker.
    for command in [
        Command::Model {
            generation: 2,
            bytes: vec![1, 2, 3],
        },
        Command::Observations {
            generation: 2,
            name: "wiping_650mm_test0".into(),
            steps: 2,
            extero: vec![0.5, -0.5, 0.25, 1.0],
            proprio: vec![0.1, 0.2],
        },
        Command::Run {
            generation: 2,
            key: key(),
        },
        // A branch: the run's condition up to step 40, another from it on.
        Command::Run {
            generation: 2,
            key: key().branched(
                40,
                Condition {
                    proprio: false,
                    ..key().condition
                },
            ),
        },
    ] {
        assert_eq!(Command::decode(&command.encode().0).unwrap(), command);
    }
    let ready = Reply::Ready {
        compute: "CPU (worker)".into(),
    };
    let err = Command::decode(&ready.encode().0).unwrap_err();
    assert!(err.contains("unknown command `ready`"), "{err}");
}

/// The Drive window's messages: its requests to the worker, the episode's progress and its
/// end (the finished episode's bytes are checked natively: `tests/it/driving.rs`).
#[wasm_bindgen_test]
fn drive_messages_round_trip() {
    use pvrnn_explorer::driving::{
        DriveEvent, DriveProgress, DriveRequest, EpisodeSoFar, FinishedDrive,
    };
    let bundle = common::caresim_bundle();
    let config = &bundle.model.config;
    let condition = Condition::standard(config);
    let mut spec =
        pvrnn_drive::DriveSpec::new(caresim::Task::Wiping, 680, 2, caresim::Revision::R2);
    spec.perturbations.sensor_noise = 3.0;
    for request in [
        DriveRequest::Start {
            spec: Box::new(spec.clone()),
            condition,
        },
        DriveRequest::Push(1),
        DriveRequest::Occlude(0),
        DriveRequest::DropVision(1),
        DriveRequest::Stop,
    ] {
        let command = Command::Drive {
            generation: 4,
            id: 9,
            request,
        };
        assert_eq!(Command::decode(&command.encode().0).unwrap(), command);
    }
    let progress = |cameras, so_far| Reply::DriveProgress {
        generation: 4,
        id: 9,
        progress: Box::new(DriveProgress {
            spec: spec.clone(),
            condition,
            trial: "wiping_680mm_test2".into(),
            steps_done: 12,
            len: 240,
            cameras,
            live: (0..12 * 6).map(|i| i as f32 * 0.5).collect(),
            so_far,
        }),
    };
    // The episode so far (here the bundle's recording, with no run) for the main panels.
    let so_far = Some(std::sync::Arc::new(EpisodeSoFar {
        sequence: bundle.dataset.sequences[0].clone(),
        run: None,
    }));
    let with_so_far = progress(None, so_far.clone());
    let (message, _) = with_so_far.encode_with(Some(config));
    assert_eq!(
        Reply::decode(&message, None, Some(config)).unwrap(),
        with_so_far
    );
    // Without the model it cannot be written: the page hears why instead.
    match Reply::decode(&with_so_far.encode_with(None).0, None, None).unwrap() {
        Reply::DriveEnded {
            event: DriveEvent::Failed(why),
            ..
        } => assert!(
            why.contains("episode so far") && why.contains("no model"),
            "{why}"
        ),
        other => panic!("{other:?}"),
    }
    for reply in [
        progress(None, None),
        progress(Some((12, vec![7u8; 2 * 64 * 64 * 3])), None),
        Reply::DriveEnded {
            generation: 4,
            id: 9,
            event: DriveEvent::Failed("the network's prediction of joint 3 is NaN".into()),
        },
    ] {
        assert_eq!(Reply::decode(&reply.encode().0, None, None).unwrap(), reply);
    }
    // A finished episode (here the bundle's recording as the episode, with no run).
    let finished = Reply::DriveEnded {
        generation: 4,
        id: 9,
        event: DriveEvent::Finished(Box::new(FinishedDrive {
            spec: spec.clone(),
            condition,
            sequence: bundle.dataset.sequences[0].clone(),
            run: None,
            summary: "wiping: failure (towel grasped no)".into(),
            demonstration_success: true,
        })),
    };
    let (message, _) = finished.encode_with(Some(config));
    assert_eq!(
        Reply::decode(&message, None, Some(config)).unwrap(),
        finished
    );
    // Without the model it cannot be written: it goes to the page as a failed episode.
    let (message, _) = finished.encode_with(None);
    match Reply::decode(&message, None, None).unwrap() {
        Reply::DriveEnded {
            event: DriveEvent::Failed(why),
            ..
        } => assert!(why.contains("no model"), "{why}"),
        other => panic!("{other:?}"),
    }
}

/// Files chosen in the browser's picker (here put into its input as a user's choice would)
/// are read like dropped files.
#[wasm_bindgen_test]
async fn picked_files_are_read_like_dropped_ones() {
    let web = pvrnn_explorer::browser::WebState::default();
    let input = web.pick_files(false).expect("a file input");
    assert!(input.multiple() && input.type_() == "file");
    let chosen = web_sys::DataTransfer::new().expect("a DataTransfer");
    for (name, bytes) in [("a.json", &b"{}"[..]), ("b.safetensors", &[1u8, 2, 3][..])] {
        let parts = js_sys::Array::of1(&js_sys::Uint8Array::from(bytes));
        let file = web_sys::File::new_with_u8_array_sequence(&parts, name).expect("a File");
        chosen.items().add_with_file(&file).expect("added");
    }
    input.set_files(chosen.files().as_ref());
    input
        .dispatch_event(&web_sys::Event::new("change").expect("an event"))
        .expect("dispatched");
    let mut read = None;
    for _ in 0..100 {
        read = web.take_dropped();
        if read.is_some() {
            break;
        }
        sleep_ms(20).await;
    }
    let mut files = read.expect("the picked files are read");
    files.sort_by(|a, b| a.0.cmp(&b.0));
    assert_eq!(files.len(), 2);
    assert_eq!(files[0].0, "a.json");
    assert_eq!(files[0].1.as_deref(), Ok(&b"{}"[..]));
    assert_eq!(files[1].1.as_deref(), Ok(&[1u8, 2, 3][..]));
}

#[wasm_bindgen_test]
fn the_url_hash_round_trips() {
    pvrnn_explorer::browser::set_hash("seq=wiping_650mm_test0&t=12&vision=1");
    assert_eq!(
        pvrnn_explorer::browser::location_hash(),
        "#seq=wiping_650mm_test0&t=12&vision=1"
    );
}
