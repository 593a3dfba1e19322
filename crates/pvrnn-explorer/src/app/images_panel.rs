//! Images: actual and predicted at the cursor, per camera and resolution, and the
//! contribution maps; read out from the run's states when the view changes.

use super::*;

/// Images shown at the cursor, recomputed when what they depend on changes.
#[derive(Default)]
pub(super) struct ImageCache {
    pub(super) key: Option<(RunKey, usize, bool, bool, [usize; 5])>,
    pub(super) textures: HashMap<String, TextureHandle>,
    /// The predicted vision vector and contribution maps at the cursor (kept for tests).
    pub(super) predicted: Option<Vec<f32>>,
    pub(super) maps: [Option<Rgb>; 4],
}

/// The vision read-outs of `count` exteroceptive d rows (concatenated), none for none.
pub(super) fn read_out_vision(bundle: &Bundle, rows: &[f32], count: usize) -> Vec<f32> {
    if count == 0 {
        return Vec::new();
    }
    bundle.loaded.readout(Modality::Exteroceptive, rows, count)
}

impl ExplorerApp {
    /// Recomputes the images at the cursor when anything they depend on changed.
    pub(super) fn refresh_images(&mut self, ctx: &egui::Context) {
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
        let predictions = read_out_vision(bundle, &rows, which.len());
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

    pub(super) fn images_ui(&mut self, ui: &mut egui::Ui) {
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
}
