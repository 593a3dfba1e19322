//! The explorer's window: controls, time, images, latent and proprioceptive traces,
//! summaries; online inference computed in slices between frames.

use std::collections::HashMap;

use eframe::egui::{self, Color32, RichText, TextureHandle, TextureOptions};
use egui_plot::{Bar, BarChart, Legend, Line, LineStyle, Plot, PlotPoints, VLine};
use pvrnn_core::config::ModuleId;
use pvrnn_core::cpu::readout;
use pvrnn_core::{AblationMode, Modality};
use web_time::{Duration, Instant};

use crate::bundle::Bundle;
use crate::images::{self, Rgb};
use crate::runs::{Condition, Entry, RunKey, RunStore, RunTrace};
use crate::state::{ViewState, format_units, parse_units};
use pvrnn_dataset::JOINTS;

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

/// Images shown at the cursor, recomputed when what they depend on changes.
#[derive(Default)]
struct ImageCache {
    key: Option<(RunKey, usize, bool, bool, [usize; 5])>,
    textures: HashMap<String, TextureHandle>,
    /// The predicted vision vector and contribution maps at the cursor (kept for tests).
    predicted: Option<Vec<f32>>,
    maps: [Option<Rgb>; 4],
}

pub struct ExplorerApp {
    bundle: Option<Bundle>,
    store: RunStore,
    view: ViewState,
    status: Status,
    images: ImageCache,
    units_text: String,
    last_frame: Option<Instant>,
    play_accum: f32,
    /// The hash last written to (or read from) the URL.
    last_hash: String,
    /// How the last live run went (shown, and logged in the browser console).
    last_run_note: Option<String>,
    /// Whether the "About this model" window is open.
    show_about: bool,
    #[cfg(target_arch = "wasm32")]
    web: crate::web::WebState,
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
            units_text: format_units(&view.units),
            view,
            status: Status::None,
            images: ImageCache::default(),
            last_frame: None,
            play_accum: 0.0,
            last_hash: String::new(),
            last_run_note: None,
            show_about: false,
            #[cfg(target_arch = "wasm32")]
            web: crate::web::WebState::default(),
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
        match crate::worker::WorkerClient::spawn("./worker.js", ctx.clone()) {
            Ok(worker) => {
                app.store = RunStore::with_executor(crate::runs::Executor::Worker(worker))
            }
            Err(e) => crate::web::log(&format!("computing in the page: {e}")),
        }
        app.web.start_download(bundle_url);
        app.last_hash = crate::web::location_hash();
        app
    }

    /// Shows a new model and dataset; every cached run is dropped.
    pub fn set_bundle(&mut self, mut bundle: Bundle) {
        self.store.clear();
        for (key, trace) in std::mem::take(&mut bundle.precomputed) {
            self.store.insert_complete(key, trace);
        }
        let standard = Condition::standard(&bundle.model.config);
        // Keep the view if its sequence exists; read a pending URL hash now that
        // conditions have defaults.
        if !self.last_hash.is_empty() {
            self.view = ViewState::from_hash(&self.last_hash, &self.view, standard);
        }
        let notes = self.view.sanitize(&bundle);
        self.units_text = format_units(&self.view.units);
        self.images = ImageCache::default();
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

    pub fn view(&self) -> &ViewState {
        &self.view
    }

    /// Shows the view a URL hash describes (as the web page does when its hash changes).
    pub fn apply_hash(&mut self, hash: &str) {
        let Some(b) = &self.bundle else {
            self.last_hash = hash.to_string();
            return;
        };
        self.view = ViewState::from_hash(hash, &self.view, Condition::standard(&b.model.config));
        self.units_text = format_units(&self.view.units);
        self.sanitize_view();
    }

    /// Keeps the view within what the bundle can show; says what it changed.
    fn sanitize_view(&mut self) {
        if let Some(b) = &self.bundle {
            let notes = self.view.sanitize(b);
            if !notes.is_empty() {
                self.status = Status::Info(notes.join("; "));
            }
        }
    }
    pub fn view_mut(&mut self) -> &mut ViewState {
        &mut self.view
    }
    pub fn bundle(&self) -> Option<&Bundle> {
        self.bundle.as_ref()
    }
    pub fn status(&self) -> &Status {
        &self.status
    }

    /// No inference running or waiting.
    pub fn idle(&self) -> bool {
        self.store.idle()
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
        Some(RunKey {
            sequence: self.view.sequence.clone()?,
            condition: self.condition()?.canonical(),
        })
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

    /// Any cached or computing run.
    pub fn run(&self, key: &RunKey) -> Option<&Entry> {
        self.store.get(key)
    }

    fn sequence_len(&self) -> usize {
        let (Some(b), Some(name)) = (&self.bundle, &self.view.sequence) else {
            return 0;
        };
        b.dataset.by_name(name).map_or(0, |s| s.len())
    }

    /// Asks for the runs the view needs and computes for up to `budget`.
    pub fn compute(&mut self, budget: Duration) -> bool {
        let Some(key) = self.current_key() else {
            return false;
        };
        self.store.request(key.clone(), true);
        if self.view.maps {
            let base = key.condition.without_ablation();
            self.store.request(
                RunKey {
                    condition: base,
                    ..key.clone()
                },
                false,
            );
            for id in ModuleId::ALL {
                self.store.request(
                    RunKey {
                        condition: key.condition.ablating(id),
                        ..key.clone()
                    },
                    false,
                );
            }
        }
        let Some(bundle) = self.bundle.as_mut() else {
            return false;
        };
        let model = bundle.model.clone();
        let worked = self
            .store
            .work(&model, budget, &mut |name| bundle.observations(name));
        let notes = self.store.take_notes();
        if !notes.is_empty() {
            self.status = Status::Info(notes.join("; "));
        }
        worked
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
            match crate::drop::assemble(files, self.bundle.as_ref()) {
                Ok(bundle) => self.set_bundle(bundle),
                Err(e) => self.status = Status::Error(e),
            }
        }
    }

    fn ui_frame(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        #[cfg(target_arch = "wasm32")]
        if let Some(result) = self.web.poll(&mut self.status) {
            match result {
                Ok(bundle) => self.set_bundle(bundle),
                Err(e) => self.status = Status::Error(e),
            }
        }
        self.take_dropped(&ctx);
        let now = Instant::now();
        let dt = self
            .last_frame
            .map_or(0.0, |l| (now - l).as_secs_f32())
            .min(0.25);
        self.last_frame = Some(now);

        if self.bundle.is_none() {
            egui::CentralPanel::default().show(ui, |ui| self.empty_ui(ui));
            return;
        }
        self.sanitize_view();
        self.keyboard(&ctx);
        self.advance_playback(dt);
        // Inline runs advance only while frames are drawn; a worker's results repaint when
        // they arrive, so the page does not redraw at full rate beside it.
        if self.compute(COMPUTE_BUDGET) || (self.store.computes_inline() && !self.idle()) {
            ctx.request_repaint();
        }
        for f in self.store.take_finished() {
            let rate = f.steps as f64 / f.wall.as_secs_f64().max(1e-9);
            let text = format!(
                "run {} ({}) computed live: {} steps in {:.1} s = {:.1} steps/s ({:.1} steps/s of computing time)",
                f.key.sequence,
                condition_label(&f.key.condition),
                f.steps,
                f.wall.as_secs_f64(),
                rate,
                f.steps as f64 / f.busy.as_secs_f64().max(1e-9)
            );
            #[cfg(target_arch = "wasm32")]
            crate::web::log(&text);
            self.last_run_note = Some(text);
        }
        if self.view.playing {
            ctx.request_repaint();
        }
        egui::Panel::top("controls").show(ui, |ui| self.controls_ui(ui));
        egui::Panel::bottom("time").show(ui, |ui| self.time_ui(ui));
        egui::Panel::left("images")
            .resizable(true)
            .default_size(430.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.images_ui(ui));
            });
        egui::CentralPanel::default().show(ui, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| self.traces_ui(ui));
        });
        if let Some(bundle) = &self.bundle {
            egui::Window::new("About this model")
                .open(&mut self.show_about)
                .default_width(620.0)
                .vscroll(true)
                .show(&ctx, |ui| {
                    crate::about::about_ui(ui, &bundle.description, bundle.card.as_ref())
                });
        }
        self.sync_hash();
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

    fn keyboard(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let len = self.sequence_len();
        ctx.input(|i| {
            if i.key_pressed(egui::Key::Space) {
                self.view.playing = !self.view.playing;
            }
            if i.key_pressed(egui::Key::ArrowRight) {
                self.view.t = (self.view.t + 1).min(len.saturating_sub(1));
            }
            if i.key_pressed(egui::Key::ArrowLeft) {
                self.view.t = self.view.t.saturating_sub(1);
            }
        });
    }

    fn advance_playback(&mut self, dt: f32) {
        if !self.view.playing {
            self.play_accum = 0.0;
            return;
        }
        self.play_accum += dt * self.view.speed;
        let steps = self.play_accum.floor();
        self.play_accum -= steps;
        let last = self.sequence_len().saturating_sub(1);
        self.view.t = (self.view.t + steps as usize).min(last);
        if self.view.t >= last {
            self.view.playing = false;
        }
    }

    fn controls_ui(&mut self, ui: &mut egui::Ui) {
        let Some(bundle) = &self.bundle else { return };
        let config = bundle.model.config.clone();
        ui.horizontal_wrapped(|ui| {
            ui.strong("PV-RNN explorer");
            ui.toggle_value(&mut self.show_about, "About this model");
            ui.separator();
            self.sequence_picker(ui);
            ui.separator();
            match &self.status {
                Status::Error(e) => {
                    ui.colored_label(Color32::from_rgb(230, 80, 80), e.as_str());
                }
                Status::Info(s) => {
                    ui.weak(s.as_str());
                }
                Status::Loading { what, fraction } => {
                    ui.label(what.as_str());
                    ui.add(egui::ProgressBar::new(fraction.unwrap_or(0.0)).desired_width(120.0));
                }
                Status::None => {}
            }
        });
        let standard = Condition::standard(&config);
        let mut c = self.view.condition.unwrap_or(standard);
        ui.horizontal_wrapped(|ui| {
            let vision_label = ui.label("Vision observed:");
            let levels = config.vision.resolutions.len();
            let label = |n: usize| {
                if n == 0 {
                    "none".to_string()
                } else {
                    config.vision.resolutions[..n]
                        .iter()
                        .rev()
                        .map(|r| r.to_string())
                        .collect::<Vec<_>>()
                        .join("+")
                }
            };
            egui::ComboBox::from_id_salt("vision")
                .selected_text(label(c.vision_levels as usize))
                .show_ui(ui, |ui| {
                    for n in (0..=levels).rev() {
                        ui.selectable_value(&mut c.vision_levels, n as u8, label(n));
                    }
                })
                .response
                .labelled_by(vision_label.id);
            ui.checkbox(&mut c.proprio, "proprioception observed");
            ui.separator();
            ui.label("Ablate:");
            for id in ModuleId::ALL {
                ui.checkbox(&mut c.ablation[id.index()], id.name());
            }
            let l = ui.label("mode");
            egui::ComboBox::from_id_salt("ablation mode")
                .selected_text(c.ablation_mode.name())
                .show_ui(ui, |ui| {
                    for (mode, tip) in [
                        (
                            AblationMode::Readout,
                            "inference runs as standard; each step is read out again with z = 0 (the paper's contribution maps)",
                        ),
                        (
                            AblationMode::Inference,
                            "z = 0 during the whole inference, so the other modules may compensate",
                        ),
                    ] {
                        ui.selectable_value(&mut c.ablation_mode, mode, mode.name())
                            .on_hover_text(tip);
                    }
                })
                .response
                .labelled_by(l.id)
                .on_hover_text("when an ablation (and the contribution maps) applies");
            ui.separator();
            let l = ui.label("H");
            ui.add(egui::DragValue::new(&mut c.window).range(1..=500))
                .labelled_by(l.id);
            let l = ui.label("iterations");
            ui.add(egui::DragValue::new(&mut c.iterations).range(0..=1000))
                .labelled_by(l.id);
            let l = ui.label("lr");
            let mut lr = c.lr();
            if ui
                .add(
                    egui::DragValue::new(&mut lr)
                        .range(0.001..=100.0)
                        .speed(0.01),
                )
                .labelled_by(l.id)
                .changed()
            {
                c.set_lr(lr);
            }
            let l = ui.label("seed");
            ui.add(egui::DragValue::new(&mut c.seed)).labelled_by(l.id);
            if ui
                .button("standard")
                .on_hover_text("The model's configured inference, everything observed")
                .clicked()
            {
                c = standard;
            }
        });
        if Some(c) != self.view.condition && !(self.view.condition.is_none() && c == standard) {
            self.view.condition = Some(c);
        }
        ui.horizontal_wrapped(|ui| {
            let l = ui.label("Units:");
            let edit = ui.add(egui::TextEdit::singleline(&mut self.units_text).desired_width(90.0)).labelled_by(l.id);
            if edit.changed()
                && let Some(u) = parse_units(&self.units_text)
            {
                self.view.units = u;
            }
            ui.checkbox(&mut self.view.show_d, "d traces");
            ui.checkbox(&mut self.view.prior_images, "prior prediction images");
            ui.checkbox(&mut self.view.contours, "contours");
            ui.checkbox(&mut self.view.maps, "contribution maps").on_hover_text("Runs inference once more with each module ablated (four runs; minutes at full vision in a browser)");
            ui.separator();
            self.progress_ui(ui);
        });
    }

    fn progress_ui(&self, ui: &mut egui::Ui) {
        match (self.store.computing(), self.store.progress()) {
            (Some(key), Some((done, total))) => {
                let what = if Some(key) == self.current_key().as_ref() {
                    "inference"
                } else {
                    "ablation runs"
                };
                ui.spinner();
                ui.label(format!("{what}: step {done}/{total}"));
                ui.add(
                    egui::ProgressBar::new(done as f32 / total.max(1) as f32).desired_width(120.0),
                );
                if self.store.waiting() > 0 {
                    ui.weak(format!("+{} waiting", self.store.waiting()));
                }
            }
            _ => {
                ui.weak("all runs ready");
            }
        }
        if let Some(note) = &self.last_run_note {
            ui.weak(note.as_str());
        }
    }

    fn sequence_picker(&mut self, ui: &mut egui::Ui) {
        let Some(bundle) = &self.bundle else { return };
        let seqs = &bundle.dataset.sequences;
        let Some(current) = self
            .view
            .sequence
            .as_ref()
            .and_then(|n| bundle.dataset.by_name(n))
        else {
            return;
        };
        let info = current.info.clone();
        let mut tasks: Vec<String> = seqs.iter().map(|s| s.info.task.clone()).collect();
        tasks.dedup();
        tasks.sort();
        tasks.dedup();
        let height = |s: &pvrnn_dataset::SequenceInfo| {
            s.bed_height_mm
                .map_or("-".to_string(), |h| format!("{h:.0} mm"))
        };
        let mut task = info.task.clone();
        let mut bed = height(&info);
        let mut split = info.split.name().to_string();
        let l = ui.label("Task");
        egui::ComboBox::from_id_salt("task")
            .selected_text(&task)
            .show_ui(ui, |ui| {
                for t in &tasks {
                    ui.selectable_value(&mut task, t.clone(), t);
                }
            })
            .response
            .labelled_by(l.id);
        let mut heights: Vec<String> = seqs
            .iter()
            .filter(|s| s.info.task == task)
            .map(|s| height(&s.info))
            .collect();
        heights.sort();
        heights.dedup();
        let l = ui.label("Bed");
        egui::ComboBox::from_id_salt("bed")
            .selected_text(&bed)
            .show_ui(ui, |ui| {
                for h in &heights {
                    ui.selectable_value(&mut bed, h.clone(), h);
                }
            })
            .response
            .labelled_by(l.id);
        let l = ui.label("Split");
        egui::ComboBox::from_id_salt("split")
            .selected_text(&split)
            .show_ui(ui, |ui| {
                for s in ["learn", "test"] {
                    ui.selectable_value(&mut split, s.to_string(), s);
                }
            })
            .response
            .labelled_by(l.id);
        let matching: Vec<&str> = seqs
            .iter()
            .filter(|s| {
                s.info.task == task && height(&s.info) == bed && s.info.split.name() == split
            })
            .map(|s| s.info.name.as_str())
            .collect();
        let mut chosen = self.view.sequence.clone().unwrap_or_default();
        let l = ui.label("Trial");
        egui::ComboBox::from_id_salt("trial")
            .selected_text(&chosen)
            .show_ui(ui, |ui| {
                for name in &matching {
                    ui.selectable_value(&mut chosen, name.to_string(), *name);
                }
            })
            .response
            .labelled_by(l.id);
        let choice = if matching.contains(&chosen.as_str()) {
            Some(chosen)
        } else {
            // A changed task, bed or split: the first sequence that matches as much as possible.
            matching
                .first()
                .map(|s| s.to_string())
                .or_else(|| {
                    seqs.iter()
                        .find(|s| s.info.task == task && height(&s.info) == bed)
                        .map(|s| s.info.name.clone())
                })
                .or_else(|| {
                    seqs.iter()
                        .find(|s| s.info.task == task)
                        .map(|s| s.info.name.clone())
                })
        };
        if let Some(name) = choice
            && Some(&name) != self.view.sequence.as_ref()
        {
            let len = bundle.dataset.by_name(&name).map_or(1, |s| s.len());
            self.view.sequence = Some(name);
            self.view.t = self.view.t.min(len.saturating_sub(1));
        }
    }

    fn time_ui(&mut self, ui: &mut egui::Ui) {
        let len = self.sequence_len();
        let computed = self.current_run().map_or(0, |e| e.trace.steps);
        ui.horizontal(|ui| {
            let label = if self.view.playing { "pause" } else { "play" };
            if ui.button(label).clicked() {
                if !self.view.playing && self.view.t + 1 >= len {
                    self.view.t = 0;
                }
                self.view.playing = !self.view.playing;
            }
            if ui
                .button("<")
                .on_hover_text("step back (left arrow)")
                .clicked()
            {
                self.view.t = self.view.t.saturating_sub(1);
            }
            if ui
                .button(">")
                .on_hover_text("step forward (right arrow)")
                .clicked()
            {
                self.view.t = (self.view.t + 1).min(len.saturating_sub(1));
            }
            ui.add(
                egui::Slider::new(&mut self.view.speed, 1.0..=60.0)
                    .suffix(" steps/s")
                    .logarithmic(true)
                    .text("speed"),
            );
            ui.separator();
            ui.label(format!("t = {} / {}", self.view.t, len.saturating_sub(1)));
        });
        let mut t = self.view.t;
        ui.spacing_mut().slider_width = ui.available_width() - 60.0;
        ui.add(
            egui::Slider::new(&mut t, 0..=len.saturating_sub(1))
                .show_value(false)
                .text("time"),
        );
        self.view.t = t;
        // Subtask strip under the scrub bar, and how far inference has got.
        let (rect, _) = ui.allocate_exact_size(
            egui::vec2(ui.spacing().slider_width, 8.0),
            egui::Sense::hover(),
        );
        if let (Some(b), Some(name)) = (&self.bundle, &self.view.sequence)
            && let Some(seq) = b.dataset.by_name(name)
        {
            let painter = ui.painter_at(rect);
            let w = rect.width() / seq.len().max(1) as f32;
            for (t, &label) in seq.subtask.iter().enumerate() {
                let x = rect.left() + t as f32 * w;
                let alpha = if t < computed { 255 } else { 90 };
                let c = SUBTASK_COLOURS[label as usize % 4];
                painter.rect_filled(
                    egui::Rect::from_min_max(
                        egui::pos2(x, rect.top()),
                        egui::pos2(x + w + 0.5, rect.bottom()),
                    ),
                    0.0,
                    Color32::from_rgba_unmultiplied(c.r(), c.g(), c.b(), alpha),
                );
            }
            let x = rect.left() + self.view.t as f32 * w;
            painter.vline(x, rect.y_range(), (2.0, Color32::WHITE));
            let names = seq
                .info
                .subtasks
                .get(seq.subtask[self.view.t.min(seq.len() - 1)] as usize)
                .cloned()
                .unwrap_or_default();
            ui.horizontal(|ui| {
                ui.weak(format!("subtask: {names}"));
                if computed < seq.len() {
                    ui.weak(format!("(inference has reached step {computed})"));
                }
            });
        }
    }

    /// Recomputes the images at the cursor when anything they depend on changed.
    fn refresh_images(&mut self, ctx: &egui::Context) {
        let (Some(bundle), Some(key)) = (&self.bundle, self.current_key()) else {
            return;
        };
        let t = self.view.t;
        let base = key.condition.without_ablation();
        let map_keys: Vec<RunKey> = ModuleId::ALL
            .iter()
            .map(|&id| RunKey {
                condition: key.condition.ablating(id),
                ..key.clone()
            })
            .collect();
        let steps_of = |k: &RunKey| self.store.get(k).map_or(0, |e| e.trace.steps);
        let base_key = RunKey {
            condition: base,
            ..key.clone()
        };
        let stamp = [
            steps_of(&key).min(t + 1),
            steps_of(&base_key).min(t + 1),
            steps_of(&map_keys[0]).min(t + 1),
            steps_of(&map_keys[1]).min(t + 1),
            steps_of(&map_keys[2]).min(t + 1) + steps_of(&map_keys[3]).min(t + 1),
        ];
        let cache_key = (
            key.clone(),
            t,
            self.view.prior_images,
            self.view.contours,
            stamp,
        );
        if self.images.key.as_ref() == Some(&cache_key) {
            return;
        }
        let config = &bundle.model.config;
        let layout = &config.vision;
        let Some(seq) = bundle.dataset.by_name(&key.sequence) else {
            return;
        };
        let mut actual = vec![0f32; layout.dims()];
        pvrnn_dataset::inputs::vision_vector(seq, t.min(seq.len() - 1), layout, &mut actual);
        let top = layout.resolutions.len() - 1;

        // Read-outs at the cursor: the shown run, then the standard and ablated runs.
        let ext = ModuleId::Exteroceptive;
        let mut rows: Vec<f32> = Vec::new();
        let mut which: Vec<&str> = Vec::new();
        let prior = self.view.prior_images;
        let mut push = |trace: &RunTrace, name: &'static str, prior: bool| {
            if trace.steps > t {
                rows.extend_from_slice(trace.d_at(ext, t, prior));
                which.push(name);
            }
        };
        if let Some(e) = self.store.get(&key) {
            push(&e.trace, "shown", prior);
        }
        if self.view.maps {
            if let Some(e) = self.store.get(&base_key) {
                push(&e.trace, "base", false);
            }
            for (k, name) in map_keys.iter().zip(["map0", "map1", "map2", "map3"]) {
                if let Some(e) = self.store.get(k) {
                    push(&e.trace, name, false);
                }
            }
        }
        let dims = layout.dims();
        let predictions = if which.is_empty() {
            Vec::new()
        } else {
            readout(
                &bundle.model.params,
                Modality::Exteroceptive,
                &rows,
                which.len(),
            )
        };
        let vector = |name: &str| {
            which
                .iter()
                .position(|w| *w == name)
                .map(|i| &predictions[i * dims..(i + 1) * dims])
        };

        let edges = images::contours(&images::camera_image(
            layout,
            &actual,
            top,
            layout.cameras - 1,
        ));
        let mut pictures: Vec<(String, Rgb)> = Vec::new();
        for cam in 0..layout.cameras {
            for level in 0..=top {
                let a = images::camera_image(layout, &actual, level, cam);
                let a = if self.view.contours && level == top {
                    images::overlay(&a, &images::contours(&a), 60)
                } else {
                    a
                };
                pictures.push((format!("actual {cam} {level}"), a));
                if let Some(v) = vector("shown") {
                    let p = images::camera_image(layout, v, level, cam);
                    let p = if self.view.contours && level == top && cam == layout.cameras - 1 {
                        images::overlay(&p, &edges, 60)
                    } else {
                        p
                    };
                    pictures.push((format!("predicted {cam} {level}"), p));
                }
            }
        }
        pictures.push(("contours".to_string(), edges.clone()));
        self.images.maps = Default::default();
        if let Some(b) = vector("base") {
            for (m, name) in ["map0", "map1", "map2", "map3"].iter().enumerate() {
                if let Some(v) = vector(name) {
                    let map = images::contribution(layout, b, v, top, layout.cameras - 1, 4.0);
                    self.images.maps[m] = Some(map.clone());
                    let map = if self.view.contours {
                        images::overlay(&map, &edges, 60)
                    } else {
                        map
                    };
                    pictures.push((format!("map {m}"), map));
                }
            }
        }
        self.images.predicted = vector("shown").map(<[f32]>::to_vec);
        let keep: std::collections::HashSet<String> =
            pictures.iter().map(|(n, _)| n.clone()).collect();
        self.images.textures.retain(|n, _| keep.contains(n));
        for (name, rgb) in pictures {
            let image = rgb.to_color_image();
            match self.images.textures.get_mut(&name) {
                Some(handle) => handle.set(image, TextureOptions::NEAREST),
                None => {
                    let handle = ctx.load_texture(name.clone(), image, TextureOptions::NEAREST);
                    self.images.textures.insert(name, handle);
                }
            }
        }
        self.images.key = Some(cache_key);
    }

    fn images_ui(&mut self, ui: &mut egui::Ui) {
        self.refresh_images(ui.ctx());
        let Some(bundle) = &self.bundle else { return };
        let layout = bundle.model.config.vision.clone();
        let top = layout.resolutions.len() - 1;
        let shown = 120.0;
        let image = |ui: &mut egui::Ui, tex: Option<&TextureHandle>, size: f32| match tex {
            Some(t) => {
                ui.add(egui::Image::new(t).fit_to_exact_size(egui::vec2(size, size)));
            }
            None => {
                let (rect, _) =
                    ui.allocate_exact_size(egui::vec2(size, size), egui::Sense::hover());
                ui.painter().rect_filled(rect, 2.0, Color32::from_gray(40));
                ui.painter().text(
                    rect.center(),
                    egui::Align2::CENTER_CENTER,
                    "computing",
                    egui::FontId::proportional(11.0),
                    Color32::GRAY,
                );
            }
        };
        let cams = ["left camera", "right camera"];
        let predicted_label = if self.view.prior_images {
            "prior prediction (t+1)"
        } else {
            "posterior reconstruction"
        };
        for cam in 0..layout.cameras {
            ui.strong(cams.get(cam).copied().unwrap_or("camera"));
            egui::Grid::new(format!("images {cam}"))
                .spacing([4.0, 2.0])
                .show(ui, |ui| {
                    ui.label("");
                    for level in (0..=top).rev() {
                        let r = layout.resolutions[level];
                        ui.label(format!("{r}x{r}"));
                    }
                    ui.end_row();
                    ui.label("actual");
                    for level in (0..=top).rev() {
                        image(
                            ui,
                            self.images.textures.get(&format!("actual {cam} {level}")),
                            shown,
                        );
                    }
                    ui.end_row();
                    ui.label(predicted_label);
                    for level in (0..=top).rev() {
                        image(
                            ui,
                            self.images
                                .textures
                                .get(&format!("predicted {cam} {level}")),
                            shown,
                        );
                    }
                    ui.end_row();
                });
        }
        ui.add_space(6.0);
        ui.strong(format!(
            "contours and contributions ({}, {}x{})",
            cams[layout.cameras.min(2) - 1],
            layout.resolutions[top],
            layout.resolutions[top]
        ));
        ui.horizontal_wrapped(|ui| {
            ui.vertical(|ui| {
                ui.label("contours");
                image(ui, self.images.textures.get("contours"), 96.0);
            });
            if self.view.maps {
                for (m, id) in ModuleId::ALL.iter().enumerate() {
                    ui.vertical(|ui| {
                        ui.label(id.name());
                        image(ui, self.images.textures.get(&format!("map {m}")), 96.0);
                    });
                }
            }
        });
        if self.view.maps {
            let mode = self
                .condition()
                .map_or(AblationMode::default(), |c| c.ablation_mode);
            ui.weak(format!(
                "brighter = larger |standard - ablated| prediction (x4); {} ablation",
                mode.name()
            ));
        }
    }

    fn traces_ui(&mut self, ui: &mut egui::Ui) {
        let Some(bundle) = &self.bundle else { return };
        let Some(key) = self.current_key() else {
            return;
        };
        let Some(seq) = bundle.dataset.by_name(&key.sequence) else {
            return;
        };
        let len = seq.len();
        let entry = self.store.get(&key);
        if let Some(err) = entry.and_then(|e| e.error.as_ref()) {
            ui.colored_label(
                Color32::from_rgb(230, 80, 80),
                format!("inference failed: {err}"),
            );
        }
        let empty = RunTrace::new(&bundle.model.config);
        let trace = entry.map_or(&empty, |e| &e.trace);
        let mut seek: Option<usize> = None;
        let t = self.view.t;
        let plot = |ui: &mut egui::Ui,
                    id: String,
                    title: &str,
                    height: f32,
                    lines: Vec<Line<'static>>,
                    y: Option<(f64, f64)>|
         -> Option<usize> {
            ui.label(RichText::new(title).small());
            let mut p = Plot::new(id)
                .height(height)
                .include_x(0.0)
                .include_x(len as f64)
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false)
                .allow_boxed_zoom(false)
                .show_x(true);
            if let Some((lo, hi)) = y {
                p = p.include_y(lo).include_y(hi);
            }
            let cursor = ui.visuals().strong_text_color();
            let response = p.show(ui, |pu| {
                for l in lines {
                    pu.line(l);
                }
                pu.vline(VLine::new("t", t as f64).color(cursor).width(1.5));
            });
            let r = &response.response;
            if r.is_pointer_button_down_on() || r.clicked() {
                r.interact_pointer_pos().map(|pos| {
                    response
                        .transform
                        .value_from_position(pos)
                        .x
                        .round()
                        .clamp(0.0, (len.max(1) - 1) as f64) as usize
                })
            } else {
                None
            }
        };

        ui.heading("Latent states");
        ui.weak("posterior solid, prior dashed; one colour per unit");
        for id in ModuleId::ALL {
            let m = id.index();
            let (z, d) = (trace.z[m], trace.d[m]);
            let units: Vec<usize> = self.view.units.iter().copied().filter(|&u| u < z).collect();
            let series = |values: &[f32], width: usize, u: usize| -> Vec<[f64; 2]> {
                (0..trace.steps)
                    .map(|s| [s as f64, values[s * width + u] as f64])
                    .collect()
            };
            let pair = |post: &[f32], prior: &[f32]| -> Vec<Line<'static>> {
                let mut lines = Vec::new();
                for (k, &u) in units.iter().enumerate() {
                    let colour = unit_colour(k);
                    lines.push(
                        Line::new(format!("{u}"), PlotPoints::from(series(post, z, u)))
                            .color(colour)
                            .width(1.2),
                    );
                    lines.push(
                        Line::new(format!("{u} prior"), PlotPoints::from(series(prior, z, u)))
                            .color(colour)
                            .width(1.0)
                            .style(LineStyle::dashed_dense()),
                    );
                }
                lines
            };
            let mt = &trace.modules[m];
            ui.strong(MODULE_TITLES[m]);
            ui.columns(2, |cols| {
                if let Some(s) = plot(
                    &mut cols[0],
                    format!("mu {m}"),
                    "mu",
                    110.0,
                    pair(&mt.mu_q, &mt.mu_p),
                    Some((-1.0, 1.0)),
                ) {
                    seek = Some(s);
                }
                if let Some(s) = plot(
                    &mut cols[1],
                    format!("sigma {m}"),
                    "sigma",
                    110.0,
                    pair(&mt.sigma_q, &mt.sigma_p),
                    Some((0.0, 1.0)),
                ) {
                    seek = Some(s);
                }
            });
            if self.view.show_d {
                let lines: Vec<Line<'static>> = (0..d.min(units.len().max(1) * 2).min(d))
                    .map(|u| {
                        Line::new(format!("d{u}"), PlotPoints::from(series(&mt.d, d, u)))
                            .color(unit_colour(u))
                            .width(1.0)
                    })
                    .collect();
                if let Some(s) = plot(ui, format!("d {m}"), "d", 90.0, lines, Some((-1.0, 1.0))) {
                    seek = Some(s);
                }
            }
        }

        ui.add_space(8.0);
        ui.heading("Proprioception");
        ui.weak("actual solid, predicted (posterior reconstruction) dashed; left arm warm colours, right arm cool");
        let norm = bundle.model.config.normalisation.clone();
        // Bundle::new checked that the model's proprioception is the data's.
        let dims = bundle.model.config.proprio_dims;
        let raw_pred = |values: &[f32], dim: usize| -> Vec<[f64; 2]> {
            (0..trace.steps)
                .map(|s| {
                    let v = values[s * dims + dim] as f64;
                    [
                        s as f64,
                        norm.as_ref().map_or(v, |n| n.proprio_from_model(dim, v)),
                    ]
                })
                .collect()
        };
        for (title, offset) in [("joint angles (rad)", 0), ("torques (N m)", JOINTS)] {
            let mut lines = Vec::new();
            for j in 0..JOINTS {
                let dim = offset + j;
                let colour = arm_colour(j);
                let actual: Vec<[f64; 2]> = (0..len)
                    .map(|s| [s as f64, seq.proprio(s)[dim] as f64])
                    .collect();
                lines.push(
                    Line::new(format!("{dim}"), PlotPoints::from(actual))
                        .color(colour)
                        .width(1.2),
                );
                if trace.steps > 0 {
                    lines.push(
                        Line::new(
                            format!("{dim} predicted"),
                            PlotPoints::from(raw_pred(&trace.proprio_recon, dim)),
                        )
                        .color(colour)
                        .width(1.0)
                        .style(LineStyle::dashed_dense()),
                    );
                }
            }
            if let Some(s) = plot(ui, format!("proprio {offset}"), title, 150.0, lines, None) {
                seek = Some(s);
            }
        }

        ui.add_space(8.0);
        ui.heading("Summaries");
        let fe: Vec<[f64; 2]> = trace
            .free_energy
            .iter()
            .enumerate()
            .map(|(s, &v)| [s as f64, v as f64])
            .collect();
        let ve: Vec<[f64; 2]> = trace
            .recon_error
            .iter()
            .enumerate()
            .map(|(s, e)| [s as f64, e[0] as f64])
            .collect();
        let pe: Vec<[f64; 2]> = trace
            .recon_error
            .iter()
            .enumerate()
            .map(|(s, e)| [s as f64, e[1] as f64])
            .collect();
        ui.columns(2, |cols| {
            if let Some(s) = plot(
                &mut cols[0],
                "fe".into(),
                "window free energy",
                120.0,
                vec![Line::new("F", PlotPoints::from(fe)).color(Color32::LIGHT_BLUE)],
                None,
            ) {
                seek = Some(s);
            }
            let lines = vec![
                Line::new("vision", PlotPoints::from(ve)).color(Color32::from_rgb(242, 146, 38)),
                Line::new("proprioception", PlotPoints::from(pe))
                    .color(Color32::from_rgb(118, 172, 152)),
            ];
            cols[1].label(RichText::new("prediction error (mean squared, all dimensions)").small());
            let cursor = cols[1].visuals().strong_text_color();
            let r = Plot::new("errors")
                .height(120.0)
                .legend(Legend::default())
                .include_x(0.0)
                .include_x(len as f64)
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false)
                .show(&mut cols[1], |pu| {
                    for l in lines {
                        pu.line(l);
                    }
                    pu.vline(VLine::new("t", t as f64).color(cursor).width(1.5));
                });
            if r.response.clicked()
                && let Some(pos) = r.response.interact_pointer_pos()
            {
                seek = Some(
                    r.transform
                        .value_from_position(pos)
                        .x
                        .round()
                        .clamp(0.0, (len.max(1) - 1) as f64) as usize,
                );
            }
        });
        self.uncertainty_ui(ui, trace);
        if let Some(s) = seek {
            self.view.t = s;
        }
    }

    /// Fig. 4 for the shown run: per module, the mean prior sigma and its mean absolute
    /// change between steps.
    fn uncertainty_ui(&self, ui: &mut egui::Ui, trace: &RunTrace) {
        let summary = uncertainty(trace);
        ui.label(
            RichText::new("uncertainty (Fig. 4): mean prior sigma and its mean |change| per step")
                .small(),
        );
        ui.columns(2, |cols| {
            for (col, (title, pick)) in cols.iter_mut().zip([
                ("mean prior sigma", 0usize),
                ("mean |change of prior sigma|", 1usize),
            ]) {
                let bars: Vec<Bar> = summary
                    .iter()
                    .enumerate()
                    .map(|(i, (name, v))| {
                        Bar::new(i as f64, [v.0, v.1][pick])
                            .name(name.to_string())
                            .fill(unit_colour(i))
                    })
                    .collect();
                col.label(RichText::new(title).small());
                Plot::new(format!("uncertainty {pick}"))
                    .height(100.0)
                    .allow_drag(false)
                    .allow_zoom(false)
                    .allow_scroll(false)
                    .show_x(false)
                    .show(col, |pu| {
                        pu.bar_chart(BarChart::new(title, bars).width(0.7));
                    });
                let text = summary
                    .iter()
                    .map(|(n, v)| format!("{n} {:.4}", [v.0, v.1][pick]))
                    .collect::<Vec<_>>()
                    .join("   ");
                col.label(RichText::new(text).small().monospace());
            }
        });
    }

    /// Keeps the URL hash in step with the view (web) so a view can be shared.
    fn sync_hash(&mut self) {
        #[cfg(target_arch = "wasm32")]
        {
            let current = crate::web::location_hash();
            let current = current.trim_start_matches('#').to_string();
            if current != self.last_hash.trim_start_matches('#') && self.bundle.is_some() {
                // Edited by the user (or the back button): follow it.
                self.apply_hash(&current);
                self.last_hash = current;
                return;
            }
            let wanted = self.view.to_hash();
            if wanted != self.last_hash {
                crate::web::set_hash(&wanted);
                self.last_hash = wanted;
            }
        }
    }
}

/// Short text of a condition, e.g. `vision 32+16, proprio off, ablate executive, H 30, 50 it`.
pub fn condition_label(c: &Condition) -> String {
    let ablated: Vec<&str> = ModuleId::ALL
        .iter()
        .filter(|id| c.ablation[id.index()])
        .map(|id| id.name())
        .collect();
    format!(
        "vision levels {}, proprio {}, ablate {}, H {}, {} iterations, lr {}, seed {}",
        c.vision_levels,
        if c.proprio { "on" } else { "off" },
        if ablated.is_empty() {
            "none".to_string()
        } else {
            format!("{} ({})", ablated.join("+"), c.ablation_mode.name())
        },
        c.window,
        c.iterations,
        c.lr(),
        c.seed
    )
}

/// Per module (and all together): (mean prior sigma, mean |prior sigma(t) - prior sigma(t-1)|).
pub fn uncertainty(trace: &RunTrace) -> Vec<(&'static str, (f64, f64))> {
    let mut out = Vec::new();
    let (mut all_mean, mut all_change, mut all_n, mut all_m) = (0.0, 0.0, 0usize, 0usize);
    for (m, name) in ["Exe", "Mul", "Ext", "Pro"].into_iter().enumerate() {
        let z = trace.z[m];
        let s = &trace.modules[m].sigma_p;
        let steps = trace.steps;
        let mean: f64 = s[..steps * z].iter().map(|&v| v as f64).sum::<f64>();
        let change: f64 = (1..steps)
            .flat_map(|t| (0..z).map(move |u| (t, u)))
            .map(|(t, u)| (s[t * z + u] - s[(t - 1) * z + u]).abs() as f64)
            .sum();
        let n = steps * z;
        let c = steps.saturating_sub(1) * z;
        out.push((name, (mean / n.max(1) as f64, change / c.max(1) as f64)));
        all_mean += mean;
        all_change += change;
        all_n += n;
        all_m += c;
    }
    out.push((
        "All",
        (
            all_mean / all_n.max(1) as f64,
            all_change / all_m.max(1) as f64,
        ),
    ));
    out
}

fn unit_colour(k: usize) -> Color32 {
    // Evenly spaced hues.
    let hue = (k as f32 * 0.618_034) % 1.0;
    let c = egui::ecolor::Hsva::new(hue, 0.7, 0.95, 1.0);
    c.into()
}

fn arm_colour(joint: usize) -> Color32 {
    let (hue, j) = if joint < 7 {
        (0.0 + joint as f32 * 0.025, joint)
    } else {
        (0.5 + (joint - 7) as f32 * 0.03, joint - 7)
    };
    egui::ecolor::Hsva::new(hue, 0.75, 0.6 + 0.05 * j as f32, 1.0).into()
}

impl eframe::App for ExplorerApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.ui_frame(ui);
    }

    /// Lets the browser tests look inside the running app (`WebRunner::app_mut`).
    #[cfg(target_arch = "wasm32")]
    fn as_any_mut(&mut self) -> Option<&mut dyn std::any::Any> {
        Some(&mut *self)
    }
}

impl ExplorerApp {
    /// Draws one frame into `ui` (tests and benchmarks drive this without eframe).
    pub fn show(&mut self, ui: &mut egui::Ui) {
        self.ui_frame(ui);
    }
}

/// Draws `frames` frames headless (layout and tessellation, no GPU) while scrubbing through
/// the first sequence, and prints the time per frame.
pub fn bench_frames(mut app: ExplorerApp, frames: usize) {
    let ctx = egui::Context::default();
    let input = || egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(1440.0, 920.0),
        )),
        ..Default::default()
    };
    // Let the shown run finish first: scrubbing is measured on computed runs.
    while !app.idle() {
        app.compute(Duration::from_millis(200));
    }
    let len = app.sequence_len().max(1);
    // Headless: no textures are uploaded, so their deltas are dropped on purpose.
    ctx.run_ui(input(), |ui| app.show(ui))
        .textures_delta
        .clear();
    let mut times = Vec::with_capacity(frames);
    for i in 0..frames {
        app.view_mut().t = (i * 7) % len;
        let start = Instant::now();
        let mut out = ctx.run_ui(input(), |ui| app.show(ui));
        out.textures_delta.clear();
        let _ = ctx.tessellate(out.shapes, out.pixels_per_point);
        times.push(start.elapsed().as_secs_f64() * 1000.0);
    }
    times.sort_by(f64::total_cmp);
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    let p95 = times[(times.len() * 95 / 100).min(times.len() - 1)];
    println!(
        "{frames} frames while scrubbing: mean {mean:.2} ms, 95th percentile {p95:.2} ms per frame (layout + tessellation, one thread)"
    );
}
