//! Browser glue the app, the run store and the worker share: downloading the bundle with
//! progress, reading dropped files, the URL hash and query, the console.

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

use eframe::wasm_bindgen::{JsCast, closure::Closure};
use eframe::web_sys;

use crate::bundle::{BUNDLE_MANIFEST, Bundle, BundleManifest};
use crate::drop::DroppedFile;

pub fn location_hash() -> String {
    web_sys::window()
        .and_then(|w| w.location().hash().ok())
        .unwrap_or_default()
}

/// Where live runs should compute, from the page's `?compute=` (`auto` when absent).
pub fn compute_preference() -> String {
    page_parameter("compute").unwrap_or_else(|| "auto".into())
}

/// The value of `name` in the page's query (`?name=value&...`, before the `#`).
pub(crate) fn page_parameter(name: &str) -> Option<String> {
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

/// Files fetched on demand (the findings' figures): each requested once, kept until
/// taken; the page repaints when one arrives.
#[derive(Debug, Default)]
pub struct Fetches(Rc<RefCell<HashMap<String, Fetched>>>);

/// A fetch's result, `None` until it arrives (or once taken).
type Fetched = Option<Result<Vec<u8>, String>>;

impl Fetches {
    /// `url`'s bytes once they arrived (then forgotten here); `None` while on the way.
    pub fn get(
        &mut self,
        url: &str,
        ctx: &eframe::egui::Context,
    ) -> Option<Result<Vec<u8>, String>> {
        let mut files = self.0.borrow_mut();
        match files.get_mut(url) {
            Some(arrived) => arrived.take(),
            None => {
                files.insert(url.to_string(), None);
                let (files, key, ctx) = (self.0.clone(), url.to_string(), ctx.clone());
                fetch(
                    url,
                    |_, _| {},
                    move |result| {
                        files.borrow_mut().insert(key, Some(result));
                        ctx.request_repaint();
                    },
                );
                None
            }
        }
    }
}

#[derive(Default)]
struct Download {
    base: String,
    /// Every file to arrive (after the two manifests).
    expected: Vec<String>,
    /// Those the first view needs: fetched first, the rest only once they are in.
    first: Vec<String>,
    /// Whether the first view's bundle was handed over.
    first_shown: bool,
    files: HashMap<String, Vec<u8>>,
    progress: HashMap<String, (f64, f64)>,
    error: Option<String>,
    started_ms: f64,
}

/// Web-only state of the app: the bundle download and files being read after a drop.
/// What [`WebState::poll`] says of the bundle's download.
#[derive(Debug)]
pub enum DownloadPoll {
    /// Still downloading: what, and the fraction done when the sizes are known.
    Progress { what: String, fraction: Option<f32> },
    /// What the first view needs is in (the model, one sequence, its precomputed run): a
    /// bundle of that much, shown while the rest downloads.
    First(Box<Bundle>),
    /// Everything is in: the whole bundle (or why it could not be read).
    Done(Result<Box<Bundle>, String>),
}

#[derive(Default)]
pub struct WebState {
    download: Option<Rc<RefCell<Download>>>,
    /// The second network's bundle on its way, and the address it came from.
    second: Option<(String, Rc<RefCell<Download>>)>,
    dropped: Rc<RefCell<(usize, Vec<DroppedFile>)>>,
    /// Wakes the app when a file it was reading arrives (the reads end between frames).
    repaint: Rc<RefCell<Option<eframe::egui::Context>>>,
    /// The status line's message last logged.
    last_status: String,
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
        self.download = Some(begin_download(base));
    }

    /// Downloads the second network's bundle from `base` (the address's `second=`).
    pub fn start_second_download(&mut self, base: &str) {
        self.second = Some((base.to_string(), begin_download(base)));
    }

    /// The address of the second network's bundle on its way, if one is.
    pub fn second_address(&self) -> Option<&str> {
        self.second.as_ref().map(|(address, _)| address.as_str())
    }

    /// The second network's bundle once it is in (or why it could not be read); `None`
    /// while it downloads or when none does.
    pub fn poll_second(&mut self) -> Option<Result<Box<Bundle>, String>> {
        let mut slot = self.second.as_ref().map(|(_, d)| d.clone());
        let polled = poll_download(&mut slot);
        if slot.is_none() {
            self.second = None;
        }
        match polled {
            Some(DownloadPoll::Done(result)) => Some(result),
            _ => None,
        }
    }

    /// Logs the status line's message to the console when it changes (what a view was
    /// corrected to, an error), so that the page's tests and users' consoles see it.
    pub fn log_status(&mut self, text: Option<String>) {
        let Some(text) = text else { return };
        if self.last_status != text {
            log(&text);
            self.last_status = text;
        }
    }

    /// The context to wake when a file read ends (the app sets it every frame).
    pub fn wake(&self, ctx: &eframe::egui::Context) {
        let mut repaint = self.repaint.borrow_mut();
        if repaint.is_none() {
            *repaint = Some(ctx.clone());
        }
    }

    /// Reads files dropped on the page (asynchronously in the browser).
    pub fn read_dropped(&self, dropped: &[eframe::egui::DroppedFileHandle]) {
        self.dropped.borrow_mut().0 += dropped.len();
        for f in dropped {
            let (f, queue, repaint) = (f.clone(), self.dropped.clone(), self.repaint.clone());
            wasm_bindgen_futures::spawn_local(async move {
                let name = f.path().to_string_lossy().into_owned();
                let bytes = f.bytes_async().await;
                queue.borrow_mut().1.push((name, bytes));
                if let Some(ctx) = repaint.borrow().as_ref() {
                    ctx.request_repaint();
                }
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
        let (queue, repaint) = (self.dropped.clone(), self.repaint.clone());
        let source = input.clone();
        let on_change = Closure::<dyn FnMut()>::new(move || {
            let Some(files) = source.files() else { return };
            queue.borrow_mut().0 += files.length() as usize;
            for i in 0..files.length() {
                let Some(file) = files.get(i) else { continue };
                let (queue, repaint) = (queue.clone(), repaint.clone());
                wasm_bindgen_futures::spawn_local(async move {
                    let name = file.name();
                    let bytes = wasm_bindgen_futures::JsFuture::from(file.array_buffer())
                        .await
                        .map(|b| js_sys::Uint8Array::new(&b).to_vec())
                        .map_err(|e| format!("cannot read it: {e:?}"));
                    queue.borrow_mut().1.push((name, bytes));
                    if let Some(ctx) = repaint.borrow().as_ref() {
                        ctx.request_repaint();
                    }
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

    /// Whether a bundle (the first network's or the second's) is on its way.
    pub fn downloading(&self) -> bool {
        self.download.is_some() || self.second.is_some()
    }

    /// How the download goes: its progress, or the bundle (or the error) once it ends;
    /// `None` when nothing is downloading.
    pub fn poll(&mut self) -> Option<DownloadPoll> {
        poll_download(&mut self.download)
    }
}

/// Starts downloading `base` + bundle.json, then the dataset manifest, then every file.
fn begin_download(base: &str) -> Rc<RefCell<Download>> {
    let d = Rc::new(RefCell::new(Download {
        base: base.to_string(),
        started_ms: now_ms(),
        ..Default::default()
    }));
    let url = format!("{base}{BUNDLE_MANIFEST}");
    let handle = d.clone();
    fetch(
        &url,
        |_, _| {},
        move |r| match r {
            Err(e) => handle.borrow_mut().error = Some(e),
            Ok(bytes) => manifest_arrived(handle, bytes),
        },
    );
    d
}

/// How the download in `slot` goes (emptied once it ends).
fn poll_download(slot: &mut Option<Rc<RefCell<Download>>>) -> Option<DownloadPoll> {
    let d = slot.as_ref()?.clone();
    let d = d.borrow();
    if let Some(e) = &d.error {
        let e = format!("could not load the bundle: {e}");
        drop(d);
        *slot = None;
        return Some(DownloadPoll::Done(Err(e)));
    }
    let waiting = d
        .expected
        .iter()
        .filter(|f| !d.files.contains_key(*f))
        .count();
    let first_in = !d.first.is_empty() && d.first.iter().all(|f| d.files.contains_key(f));
    if first_in && !d.first_shown && waiting > 0 {
        let part = Bundle::from_part_of_files(&d.files);
        log(&format!(
            "first view's files in after {:.0} ms ({} of {} files; page time {:.0} ms)",
            now_ms() - d.started_ms,
            d.expected.len() - waiting,
            d.expected.len(),
            now_ms()
        ));
        drop(d);
        let download = slot.as_ref()?;
        download.borrow_mut().first_shown = true;
        // A first part that cannot be read waits for the whole bundle, which says why.
        return part.ok().map(|b| DownloadPoll::First(Box::new(b)));
    }
    if d.expected.is_empty() || waiting > 0 {
        let (loaded, total) = d
            .progress
            .values()
            .fold((0.0, 0.0), |(a, b), (l, t)| (a + l, b + t));
        let what = if d.first_shown {
            "loading the other sequences and runs of"
        } else {
            "loading"
        };
        return Some(DownloadPoll::Progress {
            what: format!(
                "{what} {} ({:.1} / {:.1} MB, {} of {} files)",
                d.base,
                loaded / 1e6,
                total / 1e6,
                d.expected.len() - waiting,
                d.expected.len()
            ),
            fraction: (total > 0.0).then(|| (loaded / total) as f32),
        });
    }
    let result = Bundle::from_files(&d.files);
    log(&format!(
        "bundle ready after {:.0} ms (page time {:.0} ms)",
        now_ms() - d.started_ms,
        now_ms()
    ));
    drop(d);
    *slot = None;
    Some(DownloadPoll::Done(result.map(Box::new)))
}

/// The sequence the page's address asks for, if any (its files come first).
fn wanted_sequence() -> Option<String> {
    let standard = crate::Condition::standard(&pvrnn_core::ModelConfig::default());
    let hash = location_hash();
    crate::ViewState::from_hash(&hash, &crate::ViewState::default(), standard)
        .0
        .sequence
}

/// Fetches `files` into the download; once the first view's files are all in, the rest.
fn fetch_files(d: &Rc<RefCell<Download>>, files: Vec<String>) {
    let base = d.borrow().base.clone();
    for file in files {
        let (dp, dd, name) = (d.clone(), d.clone(), file.clone());
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
                    let rest = {
                        let mut d = dd.borrow_mut();
                        let was_in = d.first.iter().all(|f| d.files.contains_key(f));
                        d.files.insert(name2, bytes);
                        let now_in = d.first.iter().all(|f| d.files.contains_key(f));
                        (!was_in && now_in).then(|| {
                            d.expected
                                .iter()
                                .filter(|f| !d.first.contains(f))
                                .cloned()
                                .collect::<Vec<_>>()
                        })
                    };
                    if let Some(rest) = rest {
                        fetch_files(&dd, rest);
                    }
                }
            },
        );
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
                let first = std::str::from_utf8(&json)
                    .map_err(|_| "the dataset manifest is not text".to_string())
                    .and_then(|text| {
                        Bundle::first_files(&manifest, text, wanted_sequence().as_deref())
                    });
                match list.and_then(|l| first.map(|f| (l, f))) {
                    Err(e) => d2.borrow_mut().error = Some(e),
                    Ok((list, first)) => {
                        d2.borrow_mut().files.insert(manifest.dataset.clone(), json);
                        d2.borrow_mut().expected = list;
                        d2.borrow_mut().first = first.clone();
                        fetch_files(&d2, first);
                    }
                }
            }
        },
    );
}
