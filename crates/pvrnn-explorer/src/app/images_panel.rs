//! Images: actual and predicted at the cursor, per camera and resolution, and the
//! contribution maps; read out from the run's states when the view changes.

use super::panel::PanelContext;
use super::*;

/// Images shown at the cursor, recomputed when what they depend on changes.
#[derive(Default)]
pub(super) struct ImageCache {
    pub(super) key: Option<(RunKey, usize, bool, bool, [usize; 7])>,
    pub(super) textures: HashMap<String, TextureHandle>,
    /// The predicted vision vector and contribution maps at the cursor (kept for tests).
    pub(super) predicted: Option<Vec<f32>>,
    pub(super) maps: [Option<Rgb>; 4],
    /// The subtask at the cursor and the steps its averaged maps hold so far.
    pub(super) phase: Option<String>,
    pub(super) phase_steps: usize,
}

/// The vision read-outs of `count` exteroceptive d rows (concatenated), none for none.
pub(super) fn read_out_vision(bundle: &Bundle, rows: &[f32], count: usize) -> Vec<f32> {
    if count == 0 {
        return Vec::new();
    }
    crate::runs::host_read_out(bundle.loaded.as_ref(), Modality::Exteroceptive, rows, count)
}

/// The runs the images at the cursor come from: the shown run, the same condition without
/// ablation (the contribution maps' base), each module ablated, and the branch.
struct ImageRuns {
    shown: RunKey,
    base: RunKey,
    ablated: Vec<RunKey>,
    branch: Option<RunKey>,
}

impl ImageRuns {
    fn of(key: &RunKey, branch: Option<RunKey>) -> Self {
        Self {
            branch,
            shown: key.clone(),
            base: RunKey::new(&key.sequence, key.condition.without_ablation()),
            ablated: ModuleId::ALL
                .iter()
                .map(|&id| RunKey::new(&key.sequence, key.condition.ablating(id)))
                .collect(),
        }
    }
}

/// Names of the contribution maps' read-outs and pictures, per module.
const MAPS: [&str; 4] = ["map0", "map1", "map2", "map3"];

/// Vision read-outs of several runs at one step, by name.
struct ReadOuts {
    dims: usize,
    names: Vec<&'static str>,
    values: Vec<f32>,
}

impl ReadOuts {
    fn get(&self, name: &str) -> Option<&[f32]> {
        self.names
            .iter()
            .position(|w| *w == name)
            .map(|i| &self.values[i * self.dims..(i + 1) * self.dims])
    }
}

impl ExplorerApp {
    /// Recomputes the images at the cursor when anything they depend on changed.
    pub(super) fn refresh_images(&mut self, ctx: &egui::Context) {
        let (Some(bundle), Some(key)) = (&self.bundle, self.current_key()) else {
            return;
        };
        let t = self.view.t;
        let runs = ImageRuns::of(&key, self.branch_key());
        let steps_of = |k: &RunKey| self.store.get(k).map_or(0, |e| e.trace.steps).min(t + 1);
        let stamp = [
            steps_of(&runs.shown),
            steps_of(&runs.base),
            steps_of(&runs.ablated[0]),
            steps_of(&runs.ablated[1]),
            steps_of(&runs.ablated[2]) + steps_of(&runs.ablated[3]),
            runs.branch.as_ref().map_or(0, steps_of),
            self.second_run().map_or(0, |e| e.trace.steps.min(t + 1)),
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
        let layout = &bundle.model.config.vision;
        let Some(seq) = bundle.dataset.by_name(&key.sequence) else {
            return;
        };
        let mut actual = vec![0f32; layout.dims()];
        pvrnn_dataset::inputs::vision_vector(seq, t.min(seq.len() - 1), layout, &mut actual);
        let read_outs = self.read_outs_at(bundle, &runs, t);
        let (mut pictures, maps) = self.pictures(layout, &actual, &read_outs);
        pictures.extend(self.second_pictures(t));
        if self.view.maps {
            let label = seq.subtask.get(t).copied().unwrap_or(0);
            let size = layout.resolutions[layout.resolutions.len() - 1];
            self.images.phase_steps = 0;
            for m in 0..4 {
                if let Some((map, steps)) = self.contributions.phase_map(label, m, size) {
                    pictures.push((format!("phase map {m}"), map));
                    self.images.phase_steps = steps;
                }
            }
            self.images.phase = seq.info.subtasks.get(label as usize).cloned();
        }
        self.images.maps = maps;
        self.images.predicted = read_outs.get("shown").map(<[f32]>::to_vec);
        self.upload_textures(ctx, pictures);
        self.images.key = Some(cache_key);
    }

    /// The vision read-outs at step `t` of the runs the images need (those computed that
    /// far): the shown run (its prior prediction if the view asks), and, for the maps, the
    /// base and the ablated runs.
    fn read_outs_at(&self, bundle: &Bundle, runs: &ImageRuns, t: usize) -> ReadOuts {
        let ext = ModuleId::Exteroceptive;
        let mut rows: Vec<f32> = Vec::new();
        let mut names: Vec<&'static str> = Vec::new();
        let mut push = |key: &RunKey, name: &'static str, prior: bool| {
            if let Some(e) = self.store.get(key)
                && e.trace.steps > t
            {
                rows.extend_from_slice(e.trace.d_at(ext, t, prior));
                names.push(name);
            }
        };
        push(&runs.shown, "shown", self.view.prior_images);
        if let Some(branch) = &runs.branch {
            push(branch, "branch", self.view.prior_images);
        }
        if self.view.maps {
            push(&runs.base, "base", false);
            for (k, name) in runs.ablated.iter().zip(MAPS) {
                push(k, name, false);
            }
        }
        ReadOuts {
            dims: bundle.model.config.vision.dims(),
            values: read_out_vision(bundle, &rows, names.len()),
            names,
        }
    }

    /// The second network's predictions at step t (its own read-out of its own states).
    fn second_pictures(&self, t: usize) -> Vec<(String, Rgb)> {
        let (Some(second), Some(entry)) = (&self.second, self.second_run()) else {
            return Vec::new();
        };
        if entry.trace.steps <= t {
            return Vec::new();
        }
        let d = entry
            .trace
            .d_at(ModuleId::Exteroceptive, t, self.view.prior_images);
        let vision = read_out_vision(&second.bundle, d, 1);
        let layout = &second.bundle.model.config.vision;
        let mut pictures = Vec::new();
        for cam in 0..layout.cameras {
            for level in 0..layout.resolutions.len() {
                let p = images::camera_image(layout, &vision, level, cam);
                pictures.push((format!("second {cam} {level}"), p));
            }
        }
        pictures
    }

    /// Every picture the panel shows (actual and predicted per camera and level, the
    /// contours, the contribution maps), and the maps themselves.
    fn pictures(
        &self,
        layout: &pvrnn_core::config::VisionLayout,
        actual: &[f32],
        read_outs: &ReadOuts,
    ) -> (Vec<(String, Rgb)>, [Option<Rgb>; 4]) {
        let top = layout.resolutions.len() - 1;
        let last_camera = layout.cameras - 1;
        let edges = images::contours(&images::camera_image(layout, actual, top, last_camera));
        let outlined = |picture: Rgb, outline: bool| {
            if outline {
                images::overlay(&picture, &edges, 60)
            } else {
                picture
            }
        };
        let mut pictures: Vec<(String, Rgb)> = Vec::new();
        for cam in 0..layout.cameras {
            for level in 0..=top {
                let a = images::camera_image(layout, actual, level, cam);
                let a = if self.view.contours && level == top {
                    images::overlay(&a, &images::contours(&a), 60)
                } else {
                    a
                };
                pictures.push((format!("actual {cam} {level}"), a));
                let outline = self.view.contours && level == top && cam == last_camera;
                for (run, name) in [("shown", "predicted"), ("branch", "branch")] {
                    if let Some(v) = read_outs.get(run) {
                        let p = outlined(images::camera_image(layout, v, level, cam), outline);
                        pictures.push((format!("{name} {cam} {level}"), p));
                    }
                }
            }
        }
        pictures.push(("contours".to_string(), edges.clone()));
        let mut maps: [Option<Rgb>; 4] = Default::default();
        if let Some(base) = read_outs.get("base") {
            for (m, name) in MAPS.iter().enumerate() {
                if let Some(v) = read_outs.get(name) {
                    let map = images::contribution(layout, base, v, top, last_camera, 4.0);
                    maps[m] = Some(map.clone());
                    pictures.push((format!("map {m}"), outlined(map, self.view.contours)));
                }
            }
        }
        (pictures, maps)
    }

    /// The pictures into the texture cache (textures no longer shown are dropped).
    fn upload_textures(&mut self, ctx: &egui::Context, pictures: Vec<(String, Rgb)>) {
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
    }
}

impl ImageCache {
    /// Draws the pictures read out at the cursor (the logic reads them out:
    /// `ExplorerApp::refresh_images`); a panel that only reads.
    pub(super) fn ui(&self, ui: &mut egui::Ui, ctx: &PanelContext<'_>) {
        let Some(bundle) = ctx.bundle else { return };
        let panel = ImagesPanel {
            layout: &bundle.model.config.vision,
            cameras: &bundle.dataset.manifest.cameras,
            textures: &self.textures,
            prior_images: ctx.view.prior_images,
            maps: ctx.view.maps,
            // The view's own mode (the key's is reset when nothing is ablated).
            ablation_mode: ctx
                .view
                .condition
                .map_or(AblationMode::default(), |c| c.ablation_mode),
            branch_at: ctx.view.branch.map(|b| b.at),
            second: ctx.second_open,
            phase: self.phase.as_deref(),
            phase_steps: self.phase_steps,
        };
        panel.ui(ui);
    }
}

/// What the images panel shows: the pictures the logic layer read out at the cursor
/// (`ExplorerApp::refresh_images`), per camera and resolution, and the contours and
/// contribution maps.
struct ImagesPanel<'a> {
    layout: &'a pvrnn_core::config::VisionLayout,
    /// The cameras' names, as the dataset gives them.
    cameras: &'a [String],
    textures: &'a HashMap<String, TextureHandle>,
    /// Whether the predicted row is the prior prediction of t+1 (else the posterior
    /// reconstruction of t).
    prior_images: bool,
    maps: bool,
    ablation_mode: AblationMode,
    /// Where the branch leaves the run, when there is one: its predictions get a row.
    branch_at: Option<usize>,
    /// Whether a second network's predictions get a row.
    second: bool,
    /// The subtask at the cursor, and the steps of it the averaged maps hold.
    phase: Option<&'a str>,
    phase_steps: usize,
}

impl ImagesPanel<'_> {
    fn ui(&self, ui: &mut egui::Ui) {
        let layout = self.layout;
        let top = layout.resolutions.len() - 1;
        let shown = 120.0;
        // Each picture by its texture's name, with what it shows on hover.
        let image = |ui: &mut egui::Ui, name: &str, size: f32| {
            let response = match self.textures.get(name) {
                Some(t) => ui.add(egui::Image::new(t).fit_to_exact_size(egui::vec2(size, size))),
                None => {
                    let (rect, response) =
                        ui.allocate_exact_size(egui::vec2(size, size), egui::Sense::hover());
                    ui.painter().rect_filled(rect, 2.0, Color32::from_gray(40));
                    ui.painter().text(
                        rect.center(),
                        egui::Align2::CENTER_CENTER,
                        "computing",
                        egui::FontId::proportional(11.0),
                        Color32::GRAY,
                    );
                    response
                }
            };
            response.on_hover_text(picture_help(name, self.prior_images));
        };
        let camera = |cam: usize| camera_name(self.cameras, cam);
        let predicted_label = if self.prior_images {
            "prior prediction (t+1)"
        } else {
            "posterior reconstruction"
        };
        for cam in 0..layout.cameras {
            ui.strong(camera(cam));
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
                        image(ui, &format!("actual {cam} {level}"), shown);
                    }
                    ui.end_row();
                    let mut rows = vec![(predicted_label.to_string(), "predicted")];
                    if let Some(at) = self.branch_at {
                        rows.push((format!("branch (from step {at})"), "branch"));
                    }
                    if self.second {
                        rows.push(("second network".to_string(), "second"));
                    }
                    for (label, name) in rows {
                        ui.label(label);
                        for level in (0..=top).rev() {
                            image(ui, &format!("{name} {cam} {level}"), shown);
                        }
                        ui.end_row();
                    }
                });
        }
        ui.add_space(6.0);
        ui.strong(format!(
            "contours and contributions ({}, {}x{})",
            camera(layout.cameras - 1),
            layout.resolutions[top],
            layout.resolutions[top]
        ));
        ui.horizontal_wrapped(|ui| {
            ui.vertical(|ui| {
                ui.label("contours");
                image(ui, "contours", 96.0);
            });
            if self.maps {
                for (m, id) in ModuleId::ALL.iter().enumerate() {
                    ui.vertical(|ui| {
                        ui.label(id.name());
                        image(ui, &format!("map {m}"), 96.0);
                    });
                }
            }
        });
        if self.maps && self.phase_steps > 0 {
            ui.label(format!(
                "averaged over the subtask `{}` ({} steps read out)",
                self.phase.unwrap_or("?"),
                self.phase_steps
            ));
            ui.horizontal_wrapped(|ui| {
                for (m, id) in ModuleId::ALL.iter().enumerate() {
                    ui.vertical(|ui| {
                        ui.label(id.name());
                        image(ui, &format!("phase map {m}"), 96.0);
                    });
                }
            });
        }
        if self.maps {
            let mode = self.ablation_mode;
            ui.weak(format!(
                "brighter = larger |standard - ablated| prediction (x4); {} ablation",
                mode.name()
            ));
        }
    }
}

/// A camera's name as the dataset gives it (`camera 2` if it gives none).
pub(super) fn camera_name(names: &[String], cam: usize) -> String {
    match names.get(cam) {
        Some(name) if !name.trim().is_empty() => format!("{name} camera"),
        _ => format!("camera {cam}"),
    }
}

/// What a picture of the images panel shows, by its texture's name (`actual 0 2`, `map 1`).
fn picture_help(name: &str, prior_images: bool) -> &'static str {
    let kind = name.split(' ').next().unwrap_or("");
    match kind {
        "actual" => {
            "The camera's actual frame at this resolution (model units -1 to 1 shown as 8-bit RGB)"
        }
        "predicted" if prior_images => {
            "The network's prior prediction of step t+1, made at t before seeing it, read out of its state"
        }
        "predicted" => {
            "The network's posterior reconstruction of step t, read out of its inferred state"
        }
        "branch" => "The branch's prediction at t (the same as the run's before the branch step)",
        "second" => "The second network's prediction at t, under the same condition",
        "contours" => "Edges of the actual image (Sobel magnitude of its brightness)",
        "map" => {
            "Contribution at t: |standard - ablated| predicted image with the module's z set to 0, x4 (white: a difference of 0.45 model units or more)"
        }
        "phase" => {
            "Contribution averaged over the steps of the cursor's subtask read out so far, x4"
        }
        _ => "",
    }
}
