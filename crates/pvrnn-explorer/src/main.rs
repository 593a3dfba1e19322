//! The explorer as a desktop app (`cargo run --release -p pvrnn-explorer`) and as the web
//! app's entry point (Trunk builds this file for wasm32).

/// The PV-RNN explorer: scrub time, toggle ablations, drop vision or proprioception, and
/// watch the latent states and predicted images follow.
#[cfg(not(target_arch = "wasm32"))]
#[derive(clap::Parser, Debug)]
#[command(
    name = "pvrnn-explorer",
    version,
    after_help = "Drop a bundle folder, or a model file with a dataset folder, on the window to open them.\n\n\
                  Example:\n  pvrnn-explorer --bundle models/default --view 'seq=wiping_650mm_test0&t=120&vision=1'"
)]
struct Args {
    /// A bundle folder from `pvrnn bundle` (default: models/default).
    #[arg(long)]
    bundle: Option<std::path::PathBuf>,
    /// A second network to show beside the first: a bundle folder of the same cameras and
    /// proprioception (another network, or another checkpoint's bundle).
    #[arg(long, value_name = "DIR")]
    second: Option<std::path::PathBuf>,
    /// Open this view: a URL hash such as 'seq=wiping_650mm_test0&t=120&vision=1'.
    #[arg(long)]
    view: Option<String>,
    /// Draw this many frames headless while scrubbing, print the time per frame (ms), exit.
    #[arg(long, value_name = "FRAMES")]
    bench_frames: Option<usize>,
    /// Compute the view's run live while drawing frames headless at 60 Hz, in the frame loop
    /// and then on a background thread; print steps per second of each, exit.
    #[arg(long)]
    bench_live: bool,
    /// Open the window, wait until the view's runs are computed, save a picture of the
    /// window to this PNG file and exit: a smoke test of the desktop app (with no display,
    /// run it under `xvfb-run`).
    #[arg(long, value_name = "FILE")]
    screenshot: Option<std::path::PathBuf>,
    /// Where live runs compute: `auto` (a GPU through wgpu if the machine has one, not a
    /// CPU Vulkan device such as lavapipe; else the CPU), `cpu`, or `wgpu` (any adapter,
    /// lavapipe included). The status bar says which.
    #[arg(long, value_enum, default_value_t = Compute::Auto)]
    backend: Compute,
    /// What draws the window: `auto` (wgpu on a GPU, glow's OpenGL where the only Vulkan
    /// device is a CPU implementation or there is none; glow if wgpu fails to open the
    /// window), `wgpu` or `glow`. The status bar says which.
    #[arg(long, value_enum, default_value_t = Drawing::Auto)]
    renderer: Drawing,
}

#[cfg(not(target_arch = "wasm32"))]
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Drawing {
    Auto,
    Wgpu,
    Glow,
}

/// The renderer `--renderer` asks for. `auto` looks at the adapter wgpu would take: a CPU
/// implementation (lavapipe) draws no faster than Mesa's OpenGL and glow is the path every
/// machine has, so wgpu only where there is a GPU.
#[cfg(not(target_arch = "wasm32"))]
fn choose_renderer(choice: Drawing) -> eframe::Renderer {
    match choice {
        Drawing::Wgpu => eframe::Renderer::Wgpu,
        Drawing::Glow => eframe::Renderer::Glow,
        Drawing::Auto => match pvrnn_wgpu::probe_now() {
            Ok((_, false)) => eframe::Renderer::Wgpu,
            _ => eframe::Renderer::Glow,
        },
    }
}

/// Opens the window with `renderer` (what `choice` became). Under `--renderer auto`, if
/// wgpu fails before the app was created (`created` says whether it was: an error after
/// the user closed a working window is not retried), tries once more with glow. An
/// explicit `--renderer wgpu` is not overridden.
#[cfg(not(target_arch = "wasm32"))]
fn open_with_fallback<E: std::fmt::Display>(
    choice: Drawing,
    renderer: eframe::Renderer,
    mut open: impl FnMut(eframe::Renderer) -> Result<(), E>,
    created: impl Fn() -> bool,
) -> Result<(), E> {
    let result = open(renderer);
    match &result {
        Err(e) if choice == Drawing::Auto && renderer == eframe::Renderer::Wgpu && !created() => {
            eprintln!("wgpu could not open the window ({e}); drawing with glow instead");
            open(eframe::Renderer::Glow)
        }
        _ => result,
    }
}

#[cfg(not(target_arch = "wasm32"))]
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Compute {
    Auto,
    Cpu,
    Wgpu,
}

/// The backend `--backend` asks for, with its name; `None`: the CPU.
#[cfg(not(target_arch = "wasm32"))]
fn open_backend(
    compute: Compute,
) -> Option<(
    std::sync::Arc<dyn pvrnn_core::backend::Backend<f32>>,
    String,
)> {
    if compute == Compute::Cpu {
        return None;
    }
    match pvrnn_wgpu::WgpuBackend::new() {
        Ok(gpu) if compute == Compute::Wgpu || !gpu.gpu().is_cpu() => {
            let name = format!("wgpu on {}", gpu.adapter_name());
            Some((std::sync::Arc::new(gpu), name))
        }
        Ok(_) => None,
        Err(e) => {
            if compute == Compute::Wgpu {
                eprintln!("--backend wgpu: {e}");
                std::process::exit(1);
            }
            None
        }
    }
}

#[cfg(not(target_arch = "wasm32"))]
fn main() {
    use std::path::PathBuf;

    use clap::Parser;
    use pvrnn_explorer::{Bundle, ExplorerApp, ViewState};

    let args = Args::parse();
    let dir = args.bundle.clone().unwrap_or_else(|| {
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
    if let (Some(hash), Some(b)) = (&args.view, &bundle) {
        let notes;
        (view, notes) = ViewState::from_hash(
            hash,
            &view,
            pvrnn_explorer::Condition::standard(&b.model.config),
        );
        for note in notes {
            eprintln!("--view: {note}");
        }
    }
    if args.bench_frames.is_some() || args.bench_live {
        let Some(bundle) = bundle else {
            eprintln!("benchmarks need a bundle");
            std::process::exit(1);
        };
        if let Some(frames) = args.bench_frames {
            pvrnn_explorer::app::bench_frames(ExplorerApp::new(Some(bundle), view), frames);
        } else {
            let bundle = std::cell::RefCell::new(Some(bundle));
            pvrnn_explorer::app::bench_live(|| {
                let b = bundle
                    .borrow_mut()
                    .take()
                    .or_else(|| Bundle::open_dir(&dir).ok());
                ExplorerApp::new(b, view.clone())
            });
        }
        return;
    }
    let renderer = choose_renderer(args.renderer);
    // The bundle goes to the first window; a second try (glow after wgpu failed) reads it
    // again.
    let bundle = std::cell::RefCell::new(bundle);
    // Whether a window got as far as creating the app: only a renderer that failed before
    // that is retried (an error after the user closed a working window is not).
    let created = std::rc::Rc::new(std::cell::Cell::new(false));
    let open_window = |renderer: eframe::Renderer| {
        let options = eframe::NativeOptions {
            viewport: eframe::egui::ViewportBuilder::default()
                .with_inner_size([1440.0, 920.0])
                .with_title("PV-RNN explorer")
                .with_drag_and_drop(true),
            renderer,
            ..Default::default()
        };
        let bundle = bundle
            .borrow_mut()
            .take()
            .or_else(|| Bundle::open_dir(&dir).ok());
        let second = args.second.as_ref().map(|dir| Bundle::open_dir(dir));
        let (screenshot, hash, compute) =
            (args.screenshot.clone(), args.view.clone(), args.backend);
        let created = created.clone();
        eframe::run_native(
            "PV-RNN explorer",
            options,
            Box::new(move |cc| {
                created.set(true);
                let mut app = ExplorerApp::new(bundle, ViewState::default());
                app.set_renderer_label(pvrnn_explorer::app::renderer_label(cc));
                // Through the app, so what it ignores or corrects shows in its status line.
                if let Some(hash) = &hash {
                    app.apply_hash(hash);
                }
                if let Some(Err(e)) = second.map(|opened| opened.and_then(|b| app.set_second(b))) {
                    eprintln!("the second network: {e}");
                }
                app.compute_in_background_on(&cc.egui_ctx, open_backend(compute));
                match screenshot {
                    Some(path) => app.screenshot_and_close(path),
                    None => app.offer_tour(),
                }
                Ok(Box::new(app))
            }),
        )
    };
    let result = open_with_fallback(args.renderer, renderer, open_window, || created.get());
    if let Err(e) = result {
        eprintln!("cannot open a window: {e}");
        std::process::exit(1);
    }
    if let Some(path) = &args.screenshot
        && !path.is_file()
    {
        eprintln!("no picture was saved to {}", path.display());
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
                pvrnn_explorer::browser::log(&e);
                pvrnn_explorer::web::show_panic(&e, "");
            }
        }
    };
    wasm_bindgen_futures::spawn_local(start);
}

#[cfg(all(test, not(target_arch = "wasm32")))]
mod tests {
    use super::{Drawing, open_with_fallback};
    use eframe::Renderer;

    /// Opens with a fake window that fails for the renderers in `failing`, and says which
    /// renderers were tried and how it ended.
    fn attempt(
        choice: Drawing,
        first: Renderer,
        failing: &[Renderer],
        created: bool,
    ) -> (Vec<Renderer>, Result<(), String>) {
        let mut tried = Vec::new();
        let result = open_with_fallback(
            choice,
            first,
            |r| {
                tried.push(r);
                if failing.contains(&r) {
                    Err(format!("{r:?} failed"))
                } else {
                    Ok(())
                }
            },
            || created,
        );
        (tried, result)
    }

    #[test]
    fn auto_falls_back_to_glow_when_wgpu_cannot_open_the_window() {
        let (tried, result) = attempt(Drawing::Auto, Renderer::Wgpu, &[Renderer::Wgpu], false);
        assert_eq!(tried, [Renderer::Wgpu, Renderer::Glow]);
        assert!(result.is_ok());
        // Both failing: the second error is the one reported.
        let (tried, result) = attempt(
            Drawing::Auto,
            Renderer::Wgpu,
            &[Renderer::Wgpu, Renderer::Glow],
            false,
        );
        assert_eq!(tried, [Renderer::Wgpu, Renderer::Glow]);
        assert_eq!(result, Err("Glow failed".to_string()));
    }

    #[test]
    fn no_second_window_when_it_was_asked_for_or_had_opened() {
        // An explicit --renderer wgpu is not overridden.
        let (tried, result) = attempt(Drawing::Wgpu, Renderer::Wgpu, &[Renderer::Wgpu], false);
        assert_eq!(tried, [Renderer::Wgpu]);
        assert!(result.is_err());
        // The window had opened (the error came after): no second window.
        let (tried, _) = attempt(Drawing::Auto, Renderer::Wgpu, &[Renderer::Wgpu], true);
        assert_eq!(tried, [Renderer::Wgpu]);
        // Auto chose glow and it failed: nothing else to try.
        let (tried, _) = attempt(Drawing::Auto, Renderer::Glow, &[Renderer::Glow], false);
        assert_eq!(tried, [Renderer::Glow]);
        // Success on the first try: one window.
        let (tried, result) = attempt(Drawing::Auto, Renderer::Wgpu, &[], false);
        assert_eq!(tried, [Renderer::Wgpu]);
        assert!(result.is_ok());
    }
}
