//! The web entry: starts the explorer on the page's canvas and shows a panic over the page
//! (the page helpers it and the app share are in `browser`).

use std::cell::RefCell;
use std::rc::Rc;

use eframe::wasm_bindgen::{JsCast, closure::Closure};
use eframe::web_sys;

use crate::browser::{log, page_parameter, repaint_on_hash_change};

/// The running web app, as egui's and rerun's web entries hand it out: the runner, and
/// whether (and why) the app panicked.
#[derive(Clone)]
pub struct WebHandle {
    runner: eframe::WebRunner,
}

impl std::fmt::Debug for WebHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebHandle")
            .field("has_panicked", &self.has_panicked())
            .finish()
    }
}

impl WebHandle {
    pub fn runner(&self) -> &eframe::WebRunner {
        &self.runner
    }
    pub fn has_panicked(&self) -> bool {
        self.runner.has_panicked()
    }
    pub fn panic_message(&self) -> Option<String> {
        self.runner.panic_summary().map(|p| p.message())
    }
    pub fn panic_callstack(&self) -> Option<String> {
        self.runner.panic_summary().map(|p| p.callstack())
    }
}

/// Element id of the message shown over the page after a panic.
pub const PANIC_ELEMENT_ID: &str = "explorer-panic";

/// Shows a panic over the page instead of a frozen canvas: what happened, and what to do.
pub fn show_panic(message: &str, callstack: &str) {
    let Some(document) = web_sys::window().and_then(|w| w.document()) else {
        return;
    };
    if document.get_element_by_id(PANIC_ELEMENT_ID).is_some() {
        return;
    }
    let Ok(div) = document.create_element("div") else {
        return;
    };
    div.set_id(PANIC_ELEMENT_ID);
    let _ = div.set_attribute(
        "style",
        "position:absolute;inset:0;overflow:auto;padding:2em;background:#1b1b1bee;color:#eee;\
         font:15px sans-serif;z-index:10;white-space:pre-wrap",
    );
    div.set_text_content(Some(&format!(
        "The explorer stopped with an error:\n\n{message}\n\nReload the page to start again. \
         If it happens again, please report it with this text.\n\n{callstack}"
    )));
    if let Some(body) = document.body() {
        let _ = body.append_child(&div);
    }
}

/// Checks twice a second whether the app panicked, and shows it when it has.
fn watch_for_panic(handle: WebHandle) {
    let Some(window) = web_sys::window() else {
        return;
    };
    let id = Rc::new(RefCell::new(None::<i32>));
    let id_in = id.clone();
    let check = Closure::<dyn FnMut()>::new(move || {
        if handle.has_panicked() {
            show_panic(
                &handle.panic_message().unwrap_or_default(),
                &handle.panic_callstack().unwrap_or_default(),
            );
            if let (Some(w), Some(id)) = (web_sys::window(), *id_in.borrow()) {
                w.clear_interval_with_handle(id);
            }
        }
    });
    if let Ok(handle) = window
        .set_interval_with_callback_and_timeout_and_arguments_0(check.as_ref().unchecked_ref(), 500)
    {
        *id.borrow_mut() = Some(handle);
    }
    // Lives as long as the page.
    check.forget();
}

/// The web entry: starts `make`'s app on `canvas` (following URL hash changes, and showing a
/// panic over the page should one happen), drawn with WebGL2 (glow), or with WebGPU
/// (eframe's wgpu renderer) when the page's `?render=wgpu` asks for it and the browser has
/// it (WebGL otherwise). WebGL is the default: every browser has it, and a 2D interface
/// gains nothing visible from WebGPU (docs/gpu.md, "The explorer's renderer"). Returns the
/// app's handle once the first frame is set up. `main` passes the page's canvas and the
/// default bundle; the browser tests pass their own.
pub async fn start(
    canvas: web_sys::HtmlCanvasElement,
    make: impl FnOnce(&eframe::egui::Context) -> crate::ExplorerApp + 'static,
) -> Result<WebHandle, String> {
    let renderer = match page_parameter("render").as_deref() {
        Some("wgpu" | "webgpu") => eframe::Renderer::Wgpu,
        _ => eframe::Renderer::Glow,
    };
    let make = Rc::new(RefCell::new(Some(make)));
    // One runner for both tries: starting it again unsubscribes the failed try's listeners,
    // and its panic hook is installed once.
    let runner = eframe::WebRunner::new();
    match start_on(&runner, &canvas, renderer, make.clone()).await {
        Err(e) if renderer == eframe::Renderer::Wgpu => {
            // A canvas keeps the first kind of context it gave out, so glow draws on a
            // fresh copy of it.
            log(&format!(
                "WebGPU could not draw ({e}); drawing with WebGL instead"
            ));
            let fresh = canvas
                .clone_node()
                .ok()
                .and_then(|node| node.dyn_into::<web_sys::HtmlCanvasElement>().ok())
                .ok_or("the canvas could not be copied")?;
            canvas
                .replace_with_with_node_1(&fresh)
                .map_err(|e| format!("the canvas could not be replaced: {e:?}"))?;
            start_on(&runner, &fresh, eframe::Renderer::Glow, make).await?;
        }
        other => other?,
    }
    let handle = WebHandle { runner };
    watch_for_panic(handle.clone());
    Ok(handle)
}

/// One try at starting the app on `canvas` with `renderer`; `make` is taken by the try
/// that gets as far as creating the app (eframe opens the renderer first).
async fn start_on<F>(
    runner: &eframe::WebRunner,
    canvas: &web_sys::HtmlCanvasElement,
    renderer: eframe::Renderer,
    make: Rc<RefCell<Option<F>>>,
) -> Result<(), String>
where
    F: FnOnce(&eframe::egui::Context) -> crate::ExplorerApp + 'static,
{
    let options = eframe::WebOptions {
        renderer,
        ..Default::default()
    };
    runner
        .start(
            canvas.clone(),
            options,
            Box::new(move |cc| {
                let make = make
                    .borrow_mut()
                    .take()
                    .ok_or("the explorer was already started")?;
                repaint_on_hash_change(cc.egui_ctx.clone());
                let mut app = make(&cc.egui_ctx);
                let label = crate::app::renderer_label(cc);
                // The browser tests read which renderer drew the page from the console.
                log(&format!("page: {label}"));
                app.set_renderer_label(label);
                Ok(Box::new(app))
            }),
        )
        .await
        .map_err(|e| format!("the explorer failed to start: {e:?}"))
}
