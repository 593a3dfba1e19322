//! The explorer's window. This module holds the app's state and its logic (loading,
//! computing, playback, the URL hash: [`ExplorerApp::logic`]); each panel draws in its own
//! file: `controls` (top bar), `status`, `time_panel`, `images_panel`, `traces`,
//! `summaries`, `compare`; `export` saves pictures and traces, `bench` times frames.

use std::collections::HashMap;

use eframe::egui::{self, Color32, RichText, TextureHandle, TextureOptions};
use egui_plot::{Bar, BarChart, Legend, Line, LineStyle, Plot, PlotPoints, VLine};
use pvrnn_core::config::ModuleId;
use pvrnn_core::{AblationMode, Modality};
use web_time::Duration;

#[cfg(target_arch = "wasm32")]
use crate::browser::DownloadPoll;
use crate::bundle::Bundle;
use crate::condition::{Condition, RunKey};
use crate::images::{self, Rgb};
use crate::runs::{Entry, RunStore, RunTrace};
use crate::state::{ViewState, format_units, parse_units};

mod bench;
mod branch;
mod compare;
mod contributions;
mod controls;
mod drive;
mod export;
mod findings_panel;
mod images_panel;
mod palette;
mod panel;
mod second;
mod status;
mod summaries;
mod time_panel;
mod tour;
mod traces;

pub use bench::bench_frames;
#[cfg(not(target_arch = "wasm32"))]
pub use bench::bench_live;
pub use branch::{divergence, module_kl};
use compare::CompareCache;
pub use compare::{CompareCell, compare_conditions};
pub use controls::condition_label;
pub use export::png_bytes;
use images_panel::ImageCache;
pub use summaries::uncertainty;
pub use tour::TourTarget;

/// Time given to online inference per frame.
const COMPUTE_BUDGET: Duration = Duration::from_millis(14);
const MODULE_TITLES: [&str; 4] = [
    "Executive module",
    "Associative module",
    "Exteroceptive module",
    "Proprioceptive module",
];
const SUBTASK_COLOURS: [Color32; 4] = [
    Color32::from_rgb(66, 133, 244),
    Color32::from_rgb(244, 160, 0),
    Color32::from_rgb(15, 157, 88),
    Color32::from_rgb(219, 68, 55),
];

/// A status line: progress of a download, or a message.
#[derive(Clone, Debug, PartialEq)]
pub enum Status {
    None,
    Loading { what: String, fraction: Option<f32> },
    Info(String),
    Error(String),
}

pub struct ExplorerApp {
    bundle: Option<Bundle>,
    store: RunStore,
    view: ViewState,
    status: Status,
    images: ImageCache,
    compare_images: CompareCache,
    contributions: contributions::ContributionsOverTime,
    /// The findings window (a panel type).
    findings: findings_panel::FindingsPanel,
    /// The Drive window and the episode in progress (a panel type).
    drive: drive::DrivePanel,
    /// A second network shown beside the first.
    second: Option<second::SecondNetwork>,
    /// The next files opened go to the second network.
    opening_second: bool,
    /// The guided tour: its stop while it is on, and where the widgets it names are.
    tour: tour::Tour,
    /// Where the desktop app remembers the tour was seen.
    #[cfg(not(target_arch = "wasm32"))]
    config_dir: Option<std::path::PathBuf>,
    /// A picture of the window on its way back from the renderer.
    pending_shot: export::PendingShot,
    /// Where exports go on the desktop.
    #[cfg(not(target_arch = "wasm32"))]
    export_dir: std::path::PathBuf,
    /// The top bar (a panel type).
    controls: controls::Controls,
    /// egui's clock at the last frame (real time in a window, stepped in tests).
    last_time: Option<f64>,
    /// The time bar and playback (a panel type).
    time: time_panel::TimePanel,
    /// The hash last written to (or read from) the URL.
    last_hash: String,
    /// How the last live run went: what was computed (shown) and how fast (shown on
    /// hover, so the status line does not change from run to run; logged in the browser
    /// console).
    last_run_note: Option<(String, String)>,
    /// Whether the "About this model" window is open.
    show_about: bool,
    /// Where live runs compute, for the status bar ("compute: CPU", "compute: wgpu on ...").
    compute_label: String,
    /// What draws the window, for the status bar ("drawing: wgpu, ...", "drawing: glow").
    renderer_label: String,
    /// `--screenshot`: where to save a picture of the window once every run the view
    /// needs is computed, then close (a desktop smoke test); whether it was asked for.
    #[cfg(not(target_arch = "wasm32"))]
    screenshot: Option<(std::path::PathBuf, bool)>,
    #[cfg(target_arch = "wasm32")]
    web: crate::browser::WebState,
    /// Asks the user for files (or a folder): the system's dialog unless replaced.
    #[cfg(not(target_arch = "wasm32"))]
    file_dialog: FileDialog,
}

/// What eframe draws the window with, in the status bar's words: wgpu and its adapter
/// (Vulkan, Metal, DX12; WebGPU in the browser) or glow (OpenGL; WebGL2 in the browser).
pub fn renderer_label(cc: &eframe::CreationContext<'_>) -> String {
    if let Some(state) = &cc.wgpu_render_state {
        let info = state.adapter.get_info();
        // Browsers may withhold the adapter's name.
        let name = if info.name.trim().is_empty() {
            "unnamed adapter".to_string()
        } else {
            info.name
        };
        return format!("drawing: wgpu, {name} ({:?})", info.backend);
    }
    if cfg!(target_arch = "wasm32") {
        "drawing: glow (WebGL)".into()
    } else {
        "drawing: glow (OpenGL)".into()
    }
}

/// A file dialog: `true` asks for one folder, `false` for files; `None` when the user
/// chose nothing (or no dialog could be shown).
#[cfg(not(target_arch = "wasm32"))]
pub type FileDialog = Box<dyn FnMut(bool) -> Option<Vec<std::path::PathBuf>>>;

/// The system's file dialog (through rfd: the XDG desktop portal or zenity on Linux, the
/// native dialogs on macOS and Windows).
#[cfg(not(target_arch = "wasm32"))]
pub fn system_file_dialog() -> FileDialog {
    Box::new(|folder| {
        let dialog = rfd::FileDialog::new().set_title(if folder {
            "Open a bundle folder"
        } else {
            "Open a bundle, a model with a dataset, or runs"
        });
        if folder {
            dialog.pick_folder().map(|p| vec![p])
        } else {
            dialog
                .add_filter("model, dataset, runs, bundle", &["safetensors", "json"])
                .pick_files()
        }
    })
}

impl std::fmt::Debug for ExplorerApp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExplorerApp")
            .field("bundle", &self.bundle)
            .field("store", &self.store)
            .field("view", &self.view)
            .finish()
    }
}

impl ExplorerApp {
    pub fn new(bundle: Option<Bundle>, view: ViewState) -> Self {
        let mut app = Self {
            bundle: None,
            store: RunStore::default(),
            controls: controls::Controls {
                units_text: format_units(&view.units),
            },
            view,
            status: Status::None,
            images: ImageCache::default(),
            compare_images: CompareCache::default(),
            contributions: Default::default(),
            findings: Default::default(),
            drive: Default::default(),
            second: None,
            opening_second: false,
            tour: tour::Tour::default(),
            #[cfg(not(target_arch = "wasm32"))]
            config_dir: tour::default_config_dir(),
            pending_shot: Default::default(),
            #[cfg(not(target_arch = "wasm32"))]
            export_dir: std::path::PathBuf::from("pvrnn-exports"),
            last_time: None,
            time: Default::default(),
            last_hash: String::new(),
            last_run_note: None,
            show_about: false,
            compute_label: "compute: CPU".into(),
            renderer_label: String::new(),
            #[cfg(not(target_arch = "wasm32"))]
            screenshot: None,
            #[cfg(target_arch = "wasm32")]
            web: crate::browser::WebState::default(),
            #[cfg(not(target_arch = "wasm32"))]
            file_dialog: system_file_dialog(),
        };
        if let Some(b) = bundle {
            app.set_bundle(b);
        }
        app
    }

    /// The web app: starts downloading the default bundle and reads the URL hash.
    #[cfg(target_arch = "wasm32")]
    pub fn new_web(bundle_url: &str, ctx: &egui::Context) -> Self {
        let mut app = Self::new(None, ViewState::default());
        // Live inference in a worker beside the page; in the page itself if that fails.
        let worker = format!(
            "./worker.js?compute={}",
            crate::browser::compute_preference()
        );
        match crate::worker::WorkerClient::spawn(&worker, ctx.clone()) {
            Ok(worker) => app.store = RunStore::with_executor(Box::new(worker)),
            Err(e) => crate::browser::log(&format!("computing in the page: {e}")),
        }
        app.web.start_download(bundle_url);
        app.offer_tour();
        app.last_hash = crate::browser::location_hash();
        app
    }

    /// Computes live runs on a background thread (the desktop app), so drawing keeps its
    /// full frame rate; `ctx` repaints when results arrive.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn compute_in_background(&mut self, ctx: &egui::Context) {
        self.compute_in_background_on(ctx, None);
    }

    /// As [`Self::compute_in_background`], with runs on `backend`: `(the backend, its name
    /// for the status bar)`; `None`: the CPU.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn compute_in_background_on(
        &mut self,
        ctx: &egui::Context,
        backend: Option<(
            std::sync::Arc<dyn pvrnn_core::backend::Backend<f32>>,
            String,
        )>,
    ) {
        let ctx = ctx.clone();
        let repaint = move || ctx.request_repaint_after(crate::runs::REPAINT_EVERY);
        let (backend, name) = match backend {
            Some((b, name)) => (Some(b), name),
            None => (None, "CPU".to_string()),
        };
        self.compute_label = format!("compute: {name}");
        match crate::thread::ThreadClient::spawn(repaint, backend) {
            Ok(t) => self.store.set_executor(Box::new(t)),
            Err(e) => self.status = Status::Error(e),
        }
    }

    /// Shows a new model and dataset; every cached run is dropped.
    pub fn set_bundle(&mut self, mut bundle: Bundle) {
        self.store.clear();
        // An episode of the previous network stops with it.
        let _ = self
            .store
            .drive(&bundle.model.clone(), crate::driving::DriveRequest::Stop);
        for (key, trace) in std::mem::take(&mut bundle.precomputed) {
            self.store.insert_complete(key, trace);
        }
        let standard = Condition::standard(&bundle.model.config);
        // Keep the view if its sequence exists; read a pending URL hash now that
        // conditions have defaults.
        let mut notes = Vec::new();
        if !self.last_hash.is_empty() {
            (self.view, notes) = ViewState::from_hash(&self.last_hash, &self.view, standard);
        }
        notes.extend(self.view.sanitize(&bundle));
        self.controls.units_text = format_units(&self.view.units);
        self.images = ImageCache::default();
        self.contributions = Default::default();
        // Another first network may not be comparable with the second.
        self.second = None;
        let notes: Vec<String> = bundle.notes.iter().cloned().chain(notes).collect();
        self.status = Status::Info(if !notes.is_empty() {
            notes.join("; ")
        } else if bundle.description.is_empty() {
            format!("{} sequences", bundle.dataset.sequences.len())
        } else {
            bundle.description.clone()
        });
        self.bundle = Some(bundle);
    }

    /// The whole bundle, after the first view showed part of it (the web's progressive
    /// load): its other sequences and precomputed runs join what is shown, which stays as
    /// it is (the view, the runs computed, the model the executor has).
    pub fn complete_bundle(&mut self, whole: Bundle) {
        let Some(shown) = self.bundle.as_mut() else {
            return self.set_bundle(whole);
        };
        if shown.model.params != whole.model.params || shown.model.config != whole.model.config {
            return self.set_bundle(whole);
        }
        let Bundle {
            description,
            card,
            dataset,
            precomputed,
            notes,
            ..
        } = whole;
        shown.description = description;
        shown.card = card;
        shown.dataset = dataset;
        shown.notes = notes;
        for (key, trace) in precomputed {
            if !self.store.get(&key).is_some_and(|e| e.complete) {
                self.store.insert_complete(key, trace);
            }
        }
        self.status = Status::Info(if shown.notes.is_empty() {
            format!("{} sequences", shown.dataset.sequences.len())
        } else {
            shown.notes.join("; ")
        });
    }

    pub fn view(&self) -> &ViewState {
        &self.view
    }

    /// Shows the view a URL hash describes (as the web page does when its hash changes).
    pub fn apply_hash(&mut self, hash: &str) {
        let Some(b) = &self.bundle else {
            self.last_hash = hash.to_string();
            return;
        };
        let (view, notes) =
            ViewState::from_hash(hash, &self.view, Condition::standard(&b.model.config));
        self.view = view;
        self.controls.units_text = format_units(&self.view.units);
        self.sanitize_view(notes);
    }

    /// Keeps the view within what the bundle can show; says what it changed, after `notes`.
    fn sanitize_view(&mut self, mut notes: Vec<String>) {
        if let Some(b) = &self.bundle {
            notes.extend(self.view.sanitize(b));
        }
        if !notes.is_empty() {
            self.status = Status::Info(notes.join("; "));
        }
    }
    pub fn view_mut(&mut self) -> &mut ViewState {
        &mut self.view
    }
    pub fn bundle(&self) -> Option<&Bundle> {
        self.bundle.as_ref()
    }
    /// Where live runs compute, as the status bar says it.
    pub fn compute_label(&self) -> &str {
        &self.compute_label
    }

    /// Records which renderer draws the window (see [`renderer_label`]).
    pub fn set_renderer_label(&mut self, label: String) {
        self.renderer_label = label;
    }

    /// What draws the window, as the status bar says it (empty until a window exists).
    pub fn renderer_label(&self) -> &str {
        &self.renderer_label
    }

    pub fn status(&self) -> &Status {
        &self.status
    }

    /// No inference running or waiting.
    pub fn idle(&self) -> bool {
        self.store.idle() && self.second.as_ref().is_none_or(|s| s.store.idle())
    }

    pub fn condition(&self) -> Option<Condition> {
        let b = self.bundle.as_ref()?;
        Some(
            self.view
                .condition
                .unwrap_or_else(|| Condition::standard(&b.model.config)),
        )
    }

    pub fn current_key(&self) -> Option<RunKey> {
        Some(RunKey::new(
            self.view.sequence.clone()?,
            self.condition()?.canonical(),
        ))
    }

    pub fn current_run(&self) -> Option<&Entry> {
        self.store.get(&self.current_key()?)
    }

    /// The predicted vision vector at the cursor, as last drawn.
    pub fn predicted_vision(&self) -> Option<&[f32]> {
        self.images.predicted.as_deref()
    }

    /// A module's contribution map at the cursor, as last drawn.
    pub fn contribution_map(&self, module: ModuleId) -> Option<&Rgb> {
        self.images.maps[module.index()].as_ref()
    }

    /// A module's contribution at every step read out so far (mean |standard - ablated|
    /// predicted image, model units; with the maps on).
    pub fn contribution_curve(&self, module: ModuleId) -> Vec<f32> {
        self.contributions.curves()[module.index()].clone()
    }

    /// Any cached or computing run.
    pub fn run(&self, key: &RunKey) -> Option<&Entry> {
        self.store.get(key)
    }

    fn sequence_len(&self) -> usize {
        self.panel_context().sequence_len()
    }

    /// Asks for the runs the view needs and computes for up to `budget`.
    pub fn compute(&mut self, budget: Duration) -> bool {
        let Some(key) = self.current_key() else {
            return false;
        };
        self.store.request(key.clone(), true);
        if let Some(branch) = self.branch_key() {
            self.store.request(branch, false);
        }
        if self.view.maps {
            let trials: Vec<Condition> =
                contributions::map_conditions(&key.condition, self.view.map_trials).collect();
            for c in trials {
                let base = c.without_ablation();
                self.store.request(RunKey::new(&key.sequence, base), false);
                for id in ModuleId::ALL {
                    self.store
                        .request(RunKey::new(&key.sequence, c.ablating(id)), false);
                }
            }
        }
        self.request_comparison();
        let Some(bundle) = self.bundle.as_mut() else {
            return false;
        };
        let model = bundle.model.clone();
        let worked = self
            .store
            .work(&model, budget, &mut |name| bundle.observations(name));
        let worked = self.compute_second() || worked;
        let notes = self.store.take_notes();
        if !notes.is_empty() {
            self.status = Status::Info(notes.join("; "));
        }
        #[cfg(target_arch = "wasm32")]
        {
            self.compute_label = match self.store.compute_label() {
                Some(label) => format!("compute: {label}"),
                None if self.store.computes_inline() => "compute: CPU (in the page)".into(),
                None => "compute: starting the worker".into(),
            };
        }
        worked
    }

    /// Replaces the file dialog (tests; an embedding application with its own).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn set_file_dialog(&mut self, dialog: FileDialog) {
        self.file_dialog = dialog;
    }

    /// Asks for files (or a folder) and opens them as if they were dropped.
    #[cfg(not(target_arch = "wasm32"))]
    fn open_with_dialog(&mut self, folder: bool) {
        let Some(paths) = (self.file_dialog)(folder) else {
            self.opening_second = false;
            self.status = Status::Info(
                "nothing opened (on Linux the file dialog needs xdg-desktop-portal or zenity; \
                 dropping files on the window, or --bundle DIR, works everywhere)"
                    .into(),
            );
            return;
        };
        self.open_files(crate::drop::read_paths(&paths));
    }

    /// Shows what a set of files holds (a bundle, a model, a dataset, runs), keeping what
    /// they do not replace.
    fn open_files(&mut self, files: Vec<crate::drop::DroppedFile>) {
        if std::mem::take(&mut self.opening_second) {
            return self.open_second(files);
        }
        match crate::drop::assemble(files, self.bundle.as_ref()) {
            Ok(bundle) => self.set_bundle(bundle),
            Err(e) => self.status = Status::Error(e),
        }
    }

    /// Handles files dropped on the window: a bundle, a model, a dataset, runs.
    fn take_dropped(&mut self, ctx: &egui::Context) {
        let dropped = ctx.input(|i| i.raw.dropped_files.clone());
        #[cfg(not(target_arch = "wasm32"))]
        let files = (!dropped.is_empty()).then(|| crate::drop::read_dropped(&dropped));
        #[cfg(target_arch = "wasm32")]
        let files = {
            if !dropped.is_empty() {
                self.web.read_dropped(&dropped);
            }
            self.web.take_dropped()
        };
        if let Some(files) = files {
            self.open_files(files);
        }
    }

    /// Everything a frame does besides drawing: a finished download or dropped files, the
    /// URL hash, keeping the view valid, keys and playback, and computing runs.
    pub fn logic(&mut self, ctx: &egui::Context) {
        #[cfg(target_arch = "wasm32")]
        match self.web.poll() {
            Some(DownloadPoll::Progress { what, fraction }) => {
                self.status = Status::Loading { what, fraction }
            }
            Some(DownloadPoll::First(bundle)) => self.set_bundle(*bundle),
            Some(DownloadPoll::Done(Ok(bundle))) if self.bundle.is_some() => {
                self.complete_bundle(*bundle)
            }
            Some(DownloadPoll::Done(Ok(bundle))) => self.set_bundle(*bundle),
            Some(DownloadPoll::Done(Err(e))) => self.status = Status::Error(e),
            None => {}
        }
        // The download's callbacks do not wake egui, so poll it: otherwise one frame the
        // renderer skips (wgpu on WebGPU may, when its surface is not ready) would leave
        // the page waiting for input before it shows the bundle.
        #[cfg(target_arch = "wasm32")]
        if self.web.downloading() {
            ctx.request_repaint_after(Duration::from_millis(100));
        }
        #[cfg(target_arch = "wasm32")]
        self.web.wake(ctx);
        self.take_dropped(ctx);
        self.follow_second_address();
        self.take_picture(ctx);
        // egui's clock rather than the wall clock, so tests can step time exactly.
        let now = ctx.input(|i| i.time);
        let dt = self
            .last_time
            .map_or(0.0, |l| (now - l) as f32)
            .clamp(0.0, 0.25);
        self.last_time = Some(now);
        if self.bundle.is_none() {
            return;
        }
        // The view as the URL hash has it (or the hash as the view has it, after the last
        // frame's controls), then within what the bundle can show.
        self.sync_hash();
        self.sanitize_view(Vec::new());
        self.follow_drive_address();
        if self.advance_drive() {
            ctx.request_repaint();
        }
        let keys = self.time.keyboard(ctx, &self.panel_context());
        self.apply(keys, ctx);
        // Panels lent out of the app while they read its context (as in `draw`).
        let mut time = std::mem::take(&mut self.time);
        let playback = time.advance(dt, &self.panel_context());
        self.time = time;
        self.apply(playback, ctx);
        // Inline runs advance only while frames are drawn; a worker's results repaint when
        // they arrive, so the page does not redraw at full rate beside it.
        if self.compute(COMPUTE_BUDGET) || (self.store.computes_inline() && !self.idle()) {
            ctx.request_repaint();
        }
        for f in self.store.take_finished() {
            let (what, timing) = status::finished_note(&f);
            #[cfg(target_arch = "wasm32")]
            crate::browser::log(&format!("{what} {timing}"));
            self.last_run_note = Some((what, timing));
        }
        if self.view.playing {
            ctx.request_repaint();
        }
        // The images at the cursor (and the comparison's), read out here rather than while
        // drawing; the contributions over time a few steps a frame until they are done.
        if self.refresh_contributions() {
            ctx.request_repaint();
        }
        self.refresh_images(ctx);
        if self.view.compare.is_some() {
            let cells = self.comparison();
            self.refresh_comparison(ctx, &cells);
        }
        #[cfg(target_arch = "wasm32")]
        self.web.log_status(match &self.status {
            Status::Info(s) => Some(format!("status: {s}")),
            Status::Error(s) => Some(format!("status (error): {s}")),
            Status::None | Status::Loading { .. } => None,
        });
    }

    /// Draws the panels (each in its own file).
    pub fn draw(&mut self, ui: &mut egui::Ui) {
        if self.bundle.is_none() {
            egui::CentralPanel::default().show(ui, |ui| self.empty_ui(ui));
            return;
        }
        let ctx = ui.ctx().clone();
        let view_before = self.view.clone();
        self.tour.targets.questions = None; // the question buttons add theirs as drawn
        let mut commands = Vec::new();
        let key = self.current_key();
        let bar = controls::Bar {
            about: self.show_about,
            findings: self.findings.open,
            drive: self.drive.open,
            status: &self.status,
            line: status::StatusLine {
                store: &self.store,
                shown: key.clone(),
                last_run: self.last_run_note.as_ref(),
                compute: &self.compute_label,
                renderer: &self.renderer_label,
            },
        };
        // A panel with state of its own is lent out of the app while it reads the app's
        // context, then put back.
        let (mut top, mut tour) = (
            std::mem::take(&mut self.controls),
            std::mem::take(&mut self.tour),
        );
        let conditions = egui::Panel::top("controls").show(ui, |ui| {
            commands.extend(top.ui(ui, &self.panel_context(), bar, &mut tour.targets))
        });
        (self.controls, self.tour) = (top, tour);
        self.apply(std::mem::take(&mut commands), &ctx);
        let mut time_panel = std::mem::take(&mut self.time);
        let time = egui::Panel::bottom("time").show(ui, |ui| {
            commands.extend(time_panel.ui(ui, &self.panel_context()))
        });
        self.time = time_panel;
        let images = egui::Panel::left("images")
            .resizable(true)
            .default_size(430.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| {
                    self.images.ui(ui, &self.panel_context());
                });
            });
        let latents = egui::CentralPanel::default().show(ui, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| {
                let context = self.panel_context();
                let mut central = branch::BranchControls::ui(ui, &context);
                if let Some(second) = &self.second {
                    central.extend(second.ui(ui, &context));
                }
                central.extend(self.contributions.ui(ui, &context));
                central.extend(traces::Traces::ui(ui, &context));
                self.apply(central, ui.ctx());
            });
        });
        let targets = &mut self.tour.targets;
        targets.conditions = Some(conditions.response.rect);
        targets.time = Some(time.response.rect);
        targets.images = Some(images.response.rect);
        targets.latents = Some(latents.response.rect);
        let cells = self.comparison();
        commands.extend(self.compare_images.ui(&ctx, &self.panel_context(), &cells));
        commands.extend(self.findings.ui(&ctx));
        let mut drive = std::mem::take(&mut self.drive);
        commands.extend(drive.ui(&ctx, &self.panel_context()));
        self.drive = drive;
        let mut tour = std::mem::take(&mut self.tour);
        commands.extend(tour.ui(&ctx, &self.panel_context()));
        self.tour = tour;
        self.apply(commands, &ctx);
        if let Some(bundle) = &self.bundle {
            egui::Window::new("About this model")
                .open(&mut self.show_about)
                .default_width(620.0)
                .vscroll(true)
                .show(&ctx, |ui| {
                    crate::about::about_ui(ui, &bundle.description, bundle.card.as_ref())
                });
        }
        // A view changed by this frame's controls is read out by the next frame's logic.
        if self.view != view_before {
            ctx.request_repaint();
        }
    }

    fn empty_ui(&mut self, ui: &mut egui::Ui) {
        ui.vertical_centered(|ui| {
            ui.add_space(80.0);
            ui.heading("Scalable PV-RNN explorer");
            ui.add_space(12.0);
            match &self.status {
                Status::Loading { what, fraction } => {
                    ui.label(what.as_str());
                    ui.add(egui::ProgressBar::new(fraction.unwrap_or(0.0)).desired_width(320.0).animate(true));
                }
                Status::Error(e) => {
                    ui.colored_label(Color32::from_rgb(230, 80, 80), e.as_str());
                }
                _ => {
                    ui.label("Drop a bundle folder (from `pvrnn bundle`), or a model file with a dataset folder, on this window.");
                }
            }
        });
    }

    /// Keeps the URL hash in step with the view (web) so a view can be shared.
    fn sync_hash(&mut self) {
        #[cfg(target_arch = "wasm32")]
        {
            let current = crate::browser::location_hash();
            let current = current.trim_start_matches('#').to_string();
            if current != self.last_hash.trim_start_matches('#') && self.bundle.is_some() {
                // Edited by the user (or the back button): follow it.
                self.apply_hash(&current);
                self.last_hash = current;
                return;
            }
            let wanted = self.view.to_hash();
            if wanted != self.last_hash {
                crate::browser::set_hash(&wanted);
                self.last_hash = wanted;
            }
        }
    }
}

impl eframe::App for ExplorerApp {
    fn logic(&mut self, ctx: &egui::Context, _frame: &mut eframe::Frame) {
        ExplorerApp::logic(self, ctx);
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.draw(ui);
    }

    /// Lets the browser tests look inside the running app (`WebRunner::app_mut`).
    #[cfg(target_arch = "wasm32")]
    fn as_any_mut(&mut self) -> Option<&mut dyn std::any::Any> {
        Some(&mut *self)
    }
}

impl ExplorerApp {
    /// One whole frame, logic then drawing (tests and benchmarks drive this without eframe).
    pub fn show(&mut self, ui: &mut egui::Ui) {
        self.logic(&ui.ctx().clone());
        self.draw(ui);
    }
}
