//! The comparison view: the step at the cursor under several conditions side by side, each
//! with its predicted image and its reconstruction error, filled in as the runs arrive
//! (vision 64 / 32+16 / 16 x proprioception on / off: the paper's Fig. 5 question answered by
//! looking; or each module ablated). With a second network open, its cells follow the
//! first's: the same conditions, the other network.

use super::images_panel::read_out_vision;
use super::panel::{Command, PanelContext};
use super::*;
use crate::state::CompareSet;

/// The comparison's conditions, derived from `current` (its H, iterations, lr and seed are
/// kept), with their labels.
pub fn compare_conditions(
    set: CompareSet,
    current: Condition,
    resolutions: &[usize],
) -> Vec<(String, Condition)> {
    let vision_label = |n: usize| {
        resolutions[..n]
            .iter()
            .rev()
            .map(|r| r.to_string())
            .collect::<Vec<_>>()
            .join("+")
    };
    match set {
        CompareSet::Vision => {
            let mut out = Vec::new();
            for proprio in [true, false] {
                for levels in (1..=resolutions.len()).rev() {
                    let c = Condition {
                        vision_levels: levels as u8,
                        proprio,
                        ..current
                    };
                    let label = format!(
                        "vision {}, proprio {}",
                        vision_label(levels),
                        if proprio { "on" } else { "off" }
                    );
                    out.push((label, c.canonical()));
                }
            }
            out
        }
        CompareSet::Ablation => {
            let mut out = vec![("no ablation".to_string(), current.without_ablation())];
            for id in ModuleId::ALL {
                out.push((format!("{} ablated", id.name()), current.ablating(id)));
            }
            out
        }
    }
}

/// What the comparison's pictures were read out of: each cell's run (and whether the second
/// network's), the cursor, and how far each run had got.
type CompareStamp = (Vec<(RunKey, bool)>, usize, Vec<usize>);

/// Textures of the comparison at the cursor, redone when a run grows past the cursor.
#[derive(Default)]
pub(super) struct CompareCache {
    key: Option<CompareStamp>,
    textures: Vec<Option<TextureHandle>>,
}

/// One cell as the view shows it.
#[derive(Clone, Debug, PartialEq)]
pub struct CompareCell {
    pub label: String,
    pub key: RunKey,
    /// Whether the cell is the second network's.
    pub second: bool,
    /// Mean squared reconstruction error at the cursor (vision, proprioception), once the
    /// run got there.
    pub error_at_t: Option<[f32; 2]>,
    /// The same averaged over the steps computed so far.
    pub mean_error: Option<[f32; 2]>,
    /// Steps computed of the sequence's.
    pub steps: usize,
}

/// What the comparison window shows: each cell's picture (read out by the logic layer)
/// and errors at step `t`.
struct ComparePanel<'a> {
    set: CompareSet,
    cells: &'a [CompareCell],
    textures: &'a [Option<TextureHandle>],
    resolutions: &'a [usize],
    /// The sequence's steps.
    len: usize,
    t: usize,
    /// The name of the camera shown.
    camera: String,
}

impl ComparePanel<'_> {
    /// Draws the window; whether it stays open.
    fn show(&self, ctx: &egui::Context) -> bool {
        let top = self.resolutions.len() - 1;
        let r = self.resolutions[top];
        let mut open = true;
        let columns = if self.set == CompareSet::Vision {
            self.resolutions.len()
        } else {
            self.cells.iter().filter(|c| !c.second).count()
        };
        egui::Window::new(format!("Compare: {}", self.set.name()))
            .open(&mut open)
            .default_width(160.0 * columns as f32)
            .show(ctx, |ui| {
                ui.weak(format!(
                    "step t = {}: {} at {r}x{r}, posterior reconstruction; error = mean squared error of all dimensions (model units) at t, and over the steps computed",
                    self.t, self.camera
                ));
                egui::Grid::new("compare grid")
                    .spacing([8.0, 6.0])
                    .show(ui, |ui| {
                        for (i, cell) in self.cells.iter().enumerate() {
                            ui.vertical(|ui| {
                                ui.strong(&cell.label);
                                let size = egui::vec2(140.0, 140.0);
                                match self.textures.get(i).and_then(Option::as_ref) {
                                    Some(t) => {
                                        ui.add(egui::Image::new(t).fit_to_exact_size(size));
                                    }
                                    None => {
                                        let (rect, _) =
                                            ui.allocate_exact_size(size, egui::Sense::hover());
                                        ui.painter().rect_filled(rect, 2.0, Color32::from_gray(40));
                                        ui.painter().text(
                                            rect.center(),
                                            egui::Align2::CENTER_CENTER,
                                            format!("computing {}/{}", cell.steps, self.len),
                                            egui::FontId::proportional(11.0),
                                            Color32::GRAY,
                                        );
                                    }
                                }
                                let text = |e: Option<[f32; 2]>| {
                                    e.map_or("–".to_string(), |e| {
                                        format!("vision {:.4}, proprio {:.4}", e[0], e[1])
                                    })
                                };
                                ui.label(format!("at t: {}", text(cell.error_at_t)));
                                ui.weak(format!(
                                    "mean over {} steps: {}",
                                    cell.steps,
                                    text(cell.mean_error)
                                ));
                            });
                            if (i + 1) % columns == 0 {
                                ui.end_row();
                            }
                        }
                    });
            });
        open
    }
}

impl ExplorerApp {
    /// The comparison's cells, when the view is open.
    pub fn comparison(&self) -> Vec<CompareCell> {
        let (Some(set), Some(bundle), Some(key)) =
            (self.view.compare, &self.bundle, self.current_key())
        else {
            return Vec::new();
        };
        let t = self.view.t;
        let conditions =
            compare_conditions(set, key.condition, &bundle.model.config.vision.resolutions);
        let second = self
            .second
            .as_ref()
            .filter(|s| s.bundle.dataset.by_name(&key.sequence).is_some());
        let networks = std::iter::once(false).chain(second.map(|_| true));
        networks
            .flat_map(|network| conditions.iter().map(move |c| (network, c.clone())))
            .map(|(network, (label, condition))| {
                let key = RunKey::new(&key.sequence, condition);
                let label = if network {
                    format!("{label} (second network)")
                } else {
                    label
                };
                let trace = self.compare_store(network).get(&key).map(|e| &e.trace);
                let steps = trace.map_or(0, |tr| tr.steps);
                let mean_error = trace.filter(|tr| tr.steps > 0).map(|tr| {
                    let n = tr.recon_error.len() as f32;
                    let sum = tr
                        .recon_error
                        .iter()
                        .fold([0f32; 2], |a, e| [a[0] + e[0], a[1] + e[1]]);
                    [sum[0] / n, sum[1] / n]
                });
                CompareCell {
                    label,
                    second: network,
                    error_at_t: trace.and_then(|tr| tr.recon_error.get(t).copied()),
                    mean_error,
                    steps,
                    key,
                }
            })
            .collect()
    }

    /// The runs of the first network (`false`) or the second.
    fn compare_store(&self, second: bool) -> &RunStore {
        match (&self.second, second) {
            (Some(s), true) => &s.store,
            _ => &self.store,
        }
    }

    /// Asks for the comparison's runs (after the shown one).
    pub(super) fn request_comparison(&mut self) {
        for cell in self.comparison() {
            match (&mut self.second, cell.second) {
                (Some(s), true) => s.store.request(cell.key, false),
                _ => self.store.request(cell.key, false),
            }
        }
    }

    /// Reads out the cells' images at the cursor when a run reached it since last time.
    pub(super) fn refresh_comparison(&mut self, ctx: &egui::Context, cells: &[CompareCell]) {
        let Some(bundle) = &self.bundle else { return };
        let t = self.view.t;
        let key = (
            cells
                .iter()
                .map(|c| (c.key.clone(), c.second))
                .collect::<Vec<_>>(),
            t,
            cells.iter().map(|c| c.steps.min(t + 1)).collect::<Vec<_>>(),
        );
        if self.compare_images.key.as_ref() == Some(&key) {
            return;
        }
        let ext = ModuleId::Exteroceptive;
        let mut textures = vec![None; cells.len()];
        // Each network reads its own cells out, in one batch.
        for network in [false, true] {
            let reader = match (&self.second, network) {
                (Some(s), true) => &s.bundle,
                (None, true) => continue,
                _ => bundle,
            };
            let mut rows = Vec::new();
            let mut which = Vec::new();
            for (i, cell) in cells
                .iter()
                .enumerate()
                .filter(|(_, c)| c.second == network)
            {
                let store = self.compare_store(network);
                if let Some(e) = store.get(&cell.key).filter(|e| e.trace.steps > t) {
                    rows.extend_from_slice(e.trace.d_at(ext, t, false));
                    which.push(i);
                }
            }
            let layout = &reader.model.config.vision;
            let dims = layout.dims();
            let predictions = read_out_vision(reader, &rows, which.len());
            let top = layout.resolutions.len() - 1;
            for (k, &i) in which.iter().enumerate() {
                let picture = &predictions[k * dims..(k + 1) * dims];
                let rgb = images::camera_image(layout, picture, top, 0);
                textures[i] = Some(ctx.load_texture(
                    format!("compare {i}"),
                    rgb.to_color_image(),
                    TextureOptions::NEAREST,
                ));
            }
        }
        self.compare_images = CompareCache {
            key: Some(key),
            textures,
        };
    }
}

impl CompareCache {
    /// The comparison window over `cells` (when the view has one open); closing it, as a
    /// command.
    pub(super) fn ui(
        &self,
        egui_ctx: &egui::Context,
        ctx: &PanelContext<'_>,
        cells: &[CompareCell],
    ) -> Vec<Command> {
        let (Some(set), Some(bundle)) = (ctx.view.compare, ctx.bundle) else {
            return Vec::new();
        };
        let len = cells
            .first()
            .and_then(|c| bundle.dataset.by_name(&c.key.sequence))
            .map_or(0, |s| s.len());
        let panel = ComparePanel {
            set,
            cells,
            textures: &self.textures,
            resolutions: &bundle.model.config.vision.resolutions,
            len,
            t: ctx.view.t,
            camera: super::images_panel::camera_name(&bundle.dataset.manifest.cameras, 0),
        };
        if panel.show(egui_ctx) {
            Vec::new()
        } else {
            vec![Command::CloseCompare]
        }
    }
}
