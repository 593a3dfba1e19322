//! Browser glue: downloading the bundle with progress, reading dropped files, the URL hash.

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

use eframe::wasm_bindgen::{JsCast, closure::Closure};
use eframe::web_sys;

use crate::app::Status;
use crate::bundle::{BUNDLE_MANIFEST, Bundle, BundleManifest};
use crate::drop::DroppedFile;

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

pub fn location_hash() -> String {
    web_sys::window()
        .and_then(|w| w.location().hash().ok())
        .unwrap_or_default()
}

/// Where live runs should compute, from the page's `?compute=` (`auto` when absent).
pub fn compute_preference() -> String {
    page_parameter("compute").unwrap_or_else(|| "auto".into())
}

/// Where a WebGPU engine runs the recurrence, from the page's `?recurrence=` (`gpu`, or
/// `cpu` when absent or anything else).
pub fn recurrence_preference() -> &'static str {
    match page_parameter("recurrence").as_deref() {
        Some("gpu") => "gpu",
        _ => "cpu",
    }
}

/// The value of `name` in the page's query (`?name=value&...`, before the `#`).
fn page_parameter(name: &str) -> Option<String> {
    let search = web_sys::window()?.location().search().ok()?;
    let prefix = format!("{name}=");
    search
        .trim_start_matches('?')
        .split('&')
        .find_map(|pair| pair.strip_prefix(prefix.as_str()).map(str::to_string))
}

pub fn set_hash(hash: &str) {
    if let Some(history) = web_sys::window().and_then(|w| w.history().ok()) {
        let _ = history.replace_state_with_url(
            &eframe::wasm_bindgen::JsValue::NULL,
            "",
            Some(&format!("#{hash}")),
        );
    }
}

/// Repaints when the URL hash changes (a pasted link, the back button), so the view follows
/// it even while the app is idle.
pub fn repaint_on_hash_change(ctx: eframe::egui::Context) {
    let Some(window) = web_sys::window() else {
        return;
    };
    let listener = Closure::<dyn FnMut()>::new(move || ctx.request_repaint());
    let _ =
        window.add_event_listener_with_callback("hashchange", listener.as_ref().unchecked_ref());
    // Lives as long as the page.
    listener.forget();
}

/// Offers `bytes` to the user as a downloaded file called `name`.
pub fn download(name: &str, bytes: &[u8], mime: &str) -> Result<(), String> {
    let document = web_sys::window()
        .and_then(|w| w.document())
        .ok_or("no document")?;
    let parts = js_sys::Array::of1(&js_sys::Uint8Array::from(bytes));
    let options = web_sys::BlobPropertyBag::new();
    options.set_type(mime);
    let blob = web_sys::Blob::new_with_u8_array_sequence_and_options(&parts, &options)
        .map_err(|e| format!("{e:?}"))?;
    let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(|e| format!("{e:?}"))?;
    let anchor: web_sys::HtmlAnchorElement = document
        .create_element("a")
        .map_err(|e| format!("{e:?}"))?
        .dyn_into()
        .map_err(|_| "not an anchor element")?;
    anchor.set_href(&url);
    anchor.set_download(name);
    anchor.click();
    let _ = web_sys::Url::revoke_object_url(&url);
    Ok(())
}

pub fn log(text: &str) {
    web_sys::console::log_1(&text.into());
}

/// Milliseconds since the page started loading.
pub fn now_ms() -> f64 {
    web_sys::window()
        .and_then(|w| w.performance())
        .map_or(0.0, |p| p.now())
}

/// GETs `url` as bytes, reporting (loaded, total) bytes.
fn fetch(
    url: &str,
    on_progress: impl FnMut(f64, f64) + 'static,
    on_done: impl FnOnce(Result<Vec<u8>, String>) + 'static,
) {
    let fail = |e: String| e;
    let xhr = match web_sys::XmlHttpRequest::new() {
        Ok(x) => x,
        Err(_) => return on_done(Err(fail("cannot create a request".into()))),
    };
    if xhr.open_with_async("GET", url, true).is_err() {
        return on_done(Err(format!("cannot request {url}")));
    }
    xhr.set_response_type(web_sys::XmlHttpRequestResponseType::Arraybuffer);
    let on_progress = RefCell::new(on_progress);
    let progress =
        Closure::<dyn FnMut(web_sys::ProgressEvent)>::new(move |e: web_sys::ProgressEvent| {
            let total = if e.length_computable() {
                e.total()
            } else {
                0.0
            };
            (on_progress.borrow_mut())(e.loaded(), total);
        });
    xhr.set_onprogress(Some(progress.as_ref().unchecked_ref()));
    progress.forget();
    let done = Rc::new(RefCell::new(Some(on_done)));
    let (xhr_ok, done_ok, url_ok) = (xhr.clone(), done.clone(), url.to_string());
    let load = Closure::<dyn FnMut()>::new(move || {
        let Some(callback) = done_ok.borrow_mut().take() else {
            return;
        };
        let status = xhr_ok.status().unwrap_or(0);
        if !(200..300).contains(&status) {
            return callback(Err(format!("{url_ok}: HTTP {status}")));
        }
        match xhr_ok.response() {
            Ok(body) => callback(Ok(js_sys::Uint8Array::new(&body).to_vec())),
            Err(_) => callback(Err(format!("{url_ok}: no response body"))),
        }
    });
    xhr.set_onload(Some(load.as_ref().unchecked_ref()));
    load.forget();
    let url_err = url.to_string();
    let error = Closure::<dyn FnMut()>::new(move || {
        if let Some(callback) = done.borrow_mut().take() {
            callback(Err(format!("{url_err}: network error")));
        }
    });
    xhr.set_onerror(Some(error.as_ref().unchecked_ref()));
    error.forget();
    if xhr.send().is_err() {
        log(&format!("cannot send the request for {url}"));
    }
}

#[derive(Default)]
struct Download {
    base: String,
    /// Files still to arrive (after the two manifests).
    expected: Vec<String>,
    files: HashMap<String, Vec<u8>>,
    progress: HashMap<String, (f64, f64)>,
    error: Option<String>,
    started_ms: f64,
}

/// Web-only state of the app: the bundle download and files being read after a drop.
#[derive(Default)]
pub struct WebState {
    download: Option<Rc<RefCell<Download>>>,
    dropped: Rc<RefCell<(usize, Vec<DroppedFile>)>>,
}

impl std::fmt::Debug for WebState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebState")
            .field("downloading", &self.download.is_some())
            .field("dropped_files_read", &self.dropped.borrow().1.len())
            .finish()
    }
}

impl WebState {
    /// Downloads `base` + bundle.json, then the dataset manifest, then every file.
    pub fn start_download(&mut self, base: &str) {
        let d = Rc::new(RefCell::new(Download {
            base: base.to_string(),
            started_ms: now_ms(),
            ..Default::default()
        }));
        self.download = Some(d.clone());
        let url = format!("{base}{BUNDLE_MANIFEST}");
        fetch(
            &url,
            |_, _| {},
            move |r| match r {
                Err(e) => d.borrow_mut().error = Some(e),
                Ok(bytes) => manifest_arrived(d, bytes),
            },
        );
    }

    /// Reads files dropped on the page (asynchronously in the browser).
    pub fn read_dropped(&self, dropped: &[eframe::egui::DroppedFileHandle]) {
        self.dropped.borrow_mut().0 += dropped.len();
        for f in dropped {
            let (f, queue) = (f.clone(), self.dropped.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let name = f.path().to_string_lossy().into_owned();
                let bytes = f.bytes_async().await;
                queue.borrow_mut().1.push((name, bytes));
            });
        }
    }

    /// Opens the browser's file picker (several files, or a whole folder); what the user
    /// picks is read like dropped files. Returns the input element (tests fill it).
    pub fn pick_files(&self, folder: bool) -> Result<web_sys::HtmlInputElement, String> {
        let document = web_sys::window()
            .and_then(|w| w.document())
            .ok_or("no document")?;
        let input: web_sys::HtmlInputElement = document
            .create_element("input")
            .map_err(|e| format!("{e:?}"))?
            .dyn_into()
            .map_err(|_| "not an input element")?;
        input.set_type("file");
        input.set_multiple(true);
        if folder {
            let _ = input.set_attribute("webkitdirectory", "");
        }
        let _ = input.set_attribute("style", "display:none");
        let queue = self.dropped.clone();
        let source = input.clone();
        let on_change = Closure::<dyn FnMut()>::new(move || {
            let Some(files) = source.files() else { return };
            queue.borrow_mut().0 += files.length() as usize;
            for i in 0..files.length() {
                let Some(file) = files.get(i) else { continue };
                let queue = queue.clone();
                wasm_bindgen_futures::spawn_local(async move {
                    let name = file.name();
                    let bytes = wasm_bindgen_futures::JsFuture::from(file.array_buffer())
                        .await
                        .map(|b| js_sys::Uint8Array::new(&b).to_vec())
                        .map_err(|e| format!("cannot read it: {e:?}"));
                    queue.borrow_mut().1.push((name, bytes));
                });
            }
            source.remove();
        });
        input.set_onchange(Some(on_change.as_ref().unchecked_ref()));
        on_change.forget();
        if let Some(body) = document.body() {
            let _ = body.append_child(&input);
        }
        input.click();
        Ok(input)
    }

    /// Dropped files, once all of a drop have been read.
    pub fn take_dropped(&self) -> Option<Vec<DroppedFile>> {
        let mut q = self.dropped.borrow_mut();
        if q.0 > 0 && q.1.len() == q.0 {
            q.0 = 0;
            return Some(std::mem::take(&mut q.1));
        }
        None
    }

    /// Whether a bundle is on its way.
    pub fn downloading(&self) -> bool {
        self.download.is_some()
    }

    /// Progress into `status`; the bundle (or the error) once the download ends.
    pub fn poll(&mut self, status: &mut Status) -> Option<Result<Bundle, String>> {
        let d = self.download.as_ref()?.clone();
        let d = d.borrow();
        if let Some(e) = &d.error {
            let e = format!("could not load the bundle: {e}");
            drop(d);
            self.download = None;
            return Some(Err(e));
        }
        let waiting = d
            .expected
            .iter()
            .filter(|f| !d.files.contains_key(*f))
            .count();
        if d.expected.is_empty() || waiting > 0 {
            let (loaded, total) = d
                .progress
                .values()
                .fold((0.0, 0.0), |(a, b), (l, t)| (a + l, b + t));
            *status = Status::Loading {
                what: format!(
                    "loading {} ({:.1} / {:.1} MB, {} of {} files)",
                    d.base,
                    loaded / 1e6,
                    total / 1e6,
                    d.expected.len() - waiting,
                    d.expected.len()
                ),
                fraction: (total > 0.0).then(|| (loaded / total) as f32),
            };
            return None;
        }
        let result = Bundle::from_files(&d.files);
        log(&format!(
            "bundle ready after {:.0} ms (page time {:.0} ms)",
            now_ms() - d.started_ms,
            now_ms()
        ));
        drop(d);
        self.download = None;
        Some(result)
    }
}

fn manifest_arrived(d: Rc<RefCell<Download>>, bytes: Vec<u8>) {
    let manifest = match BundleManifest::parse(&bytes, BUNDLE_MANIFEST) {
        Ok(m) => m,
        Err(e) => {
            d.borrow_mut().error = Some(e.to_string());
            return;
        }
    };
    d.borrow_mut().files.insert(BUNDLE_MANIFEST.into(), bytes);
    let url = format!("{}{}", d.borrow().base, manifest.dataset);
    let d2 = d.clone();
    fetch(
        &url,
        |_, _| {},
        move |r| match r {
            Err(e) => d2.borrow_mut().error = Some(e),
            Ok(json) => {
                let list = std::str::from_utf8(&json)
                    .map_err(|_| "the dataset manifest is not text".to_string())
                    .and_then(|text| Bundle::files_of(&manifest, text));
                match list {
                    Err(e) => d2.borrow_mut().error = Some(e),
                    Ok(list) => {
                        d2.borrow_mut().files.insert(manifest.dataset.clone(), json);
                        d2.borrow_mut().expected = list.clone();
                        let base = d2.borrow().base.clone();
                        for file in list {
                            let (dp, dd, name) = (d2.clone(), d2.clone(), file.clone());
                            let name2 = file.clone();
                            fetch(
                                &format!("{base}{file}"),
                                move |loaded, total| {
                                    dp.borrow_mut()
                                        .progress
                                        .insert(name.clone(), (loaded, total));
                                },
                                move |r| match r {
                                    Err(e) => dd.borrow_mut().error = Some(e),
                                    Ok(bytes) => {
                                        dd.borrow_mut().files.insert(name2, bytes);
                                    }
                                },
                            );
                        }
                    }
                }
            }
        },
    );
}
