//! The explorer as a desktop app (`cargo run --release -p pvrnn-explorer`) and as the web
//! app's entry point (Trunk builds this file for wasm32).

#[cfg(not(target_arch = "wasm32"))]
fn main() {
    use std::path::PathBuf;

    use pvrnn_explorer::{Bundle, ExplorerApp, ViewState};

    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    if args.iter().any(|a| a == "--help" || a == "-h") {
        println!(
            "pvrnn-explorer [--bundle DIR] [--view HASH] [--bench-frames N]\n\n\
             --bundle DIR        a bundle folder from `pvrnn bundle` (default: models/default)\n\
             --view HASH         open this view, e.g. 'seq=wiping_650mm_test0&t=120&vision=1'\n\
             --bench-frames N    draw N frames headless while scrubbing, print the time per frame, exit\n\n\
             Drop a bundle folder, or a model file with a dataset folder, on the window to open them."
        );
        return;
    }
    let dir = value("--bundle").map(PathBuf::from).unwrap_or_else(|| {
        let local = PathBuf::from("models/default");
        if local.is_dir() {
            local
        } else {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models/default")
        }
    });
    let bundle = match Bundle::open_dir(&dir) {
        Ok(b) => Some(b),
        Err(e) => {
            eprintln!("{e}");
            None
        }
    };
    let mut view = ViewState::default();
    if let (Some(hash), Some(b)) = (value("--view"), &bundle) {
        view = ViewState::from_hash(
            &hash,
            &view,
            pvrnn_explorer::Condition::standard(&b.model.config),
        );
    }
    if let Some(frames) = value("--bench-frames") {
        let frames: usize = frames.parse().unwrap_or(300);
        let Some(bundle) = bundle else {
            eprintln!("--bench-frames needs a bundle");
            std::process::exit(1);
        };
        pvrnn_explorer::app::bench_frames(ExplorerApp::new(Some(bundle), view), frames);
        return;
    }
    let options = eframe::NativeOptions {
        viewport: eframe::egui::ViewportBuilder::default()
            .with_inner_size([1440.0, 920.0])
            .with_title("PV-RNN explorer")
            .with_drag_and_drop(true),
        ..Default::default()
    };
    let result = eframe::run_native(
        "PV-RNN explorer",
        options,
        Box::new(move |_cc| Ok(Box::new(ExplorerApp::new(bundle, view)))),
    );
    if let Err(e) = result {
        eprintln!("cannot open a window: {e}");
        std::process::exit(1);
    }
}

#[cfg(target_arch = "wasm32")]
fn main() {
    use eframe::wasm_bindgen::JsCast;
    use eframe::web_sys;

    // The same module runs in the inference worker (web/worker.js), which has no window.
    if web_sys::window().is_none() {
        return;
    }
    let start = async {
        let canvas = web_sys::window()
            .and_then(|w| w.document())
            .and_then(|d| d.get_element_by_id("explorer"))
            .and_then(|e| e.dyn_into::<web_sys::HtmlCanvasElement>().ok())
            .expect("index.html has a canvas with id `explorer`");
        let result = pvrnn_explorer::web::start(canvas, |ctx| {
            pvrnn_explorer::ExplorerApp::new_web("models/default/", ctx)
        })
        .await;
        if let Some(loading) = web_sys::window()
            .and_then(|w| w.document())
            .and_then(|d| d.get_element_by_id("loading"))
        {
            loading.remove();
        }
        match result {
            // The page's event handlers keep the app running; a panic shows over the page.
            Ok(_handle) => {}
            Err(e) => {
                pvrnn_explorer::web::log(&e);
                pvrnn_explorer::web::show_panic(&e, "");
            }
        }
    };
    wasm_bindgen_futures::spawn_local(start);
}
