//! A short guided tour of the panels, offered on a first visit: skippable, and remembered
//! (the browser's local storage; a file in the user's configuration folder on the
//! desktop). The "Tour" button starts it again.

use super::panel::{Command, PanelContext};
use super::*;

/// What a stop of the tour explains: the widget its window stands beside and outlines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TourTarget {
    /// The whole window (the first stop).
    Everything,
    /// The images panel (left).
    Images,
    /// The latent states and traces (centre).
    Latents,
    /// The conditions' controls (top).
    Conditions,
    /// The time bar (bottom).
    Time,
    /// The buttons that ask the network questions (findings, compare, second network).
    Questions,
}

/// Where the widgets the tour names were drawn this frame (none before the first frame).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct TourTargets {
    pub(super) images: Option<egui::Rect>,
    pub(super) latents: Option<egui::Rect>,
    pub(super) conditions: Option<egui::Rect>,
    pub(super) time: Option<egui::Rect>,
    pub(super) questions: Option<egui::Rect>,
}

impl TourTargets {
    fn rect(&self, target: TourTarget) -> Option<egui::Rect> {
        match target {
            TourTarget::Everything => None,
            TourTarget::Images => self.images,
            TourTarget::Latents => self.latents,
            TourTarget::Conditions => self.conditions,
            TourTarget::Time => self.time,
            TourTarget::Questions => self.questions,
        }
    }

    /// Adds a question button's rect to the questions' outline.
    pub(super) fn add_question(&mut self, rect: egui::Rect) {
        self.questions = Some(self.questions.map_or(rect, |r| r.union(rect)));
    }
}

/// The tour's state: its stop while it is on, and where its targets are.
#[derive(Debug, Default)]
pub(super) struct Tour {
    stop: Option<usize>,
    pub(super) targets: TourTargets,
}

impl Tour {
    /// Draws the shown stop beside the widget it names; a finished or skipped tour, as a
    /// command (the app remembers it).
    pub(super) fn ui(&mut self, ctx: &egui::Context, panels: &PanelContext<'_>) -> Vec<Command> {
        let Some(stop) = self.stop else {
            return Vec::new();
        };
        let (title, text, target) = STOPS[stop.min(STOPS.len() - 1)];
        let text = if text.is_empty() {
            intro(panels.bundle)
        } else {
            text.to_string()
        };
        let screen = ctx.content_rect();
        let (pivot, at) = match self.targets.rect(target) {
            Some(rect) => {
                // Outlined, so the words point at it.
                ctx.layer_painter(egui::LayerId::new(
                    egui::Order::Foreground,
                    egui::Id::unique("tour target"),
                ))
                .rect_stroke(
                    rect.shrink(2.0),
                    4.0,
                    egui::Stroke::new(3.0, Color32::from_rgb(255, 170, 0)),
                    egui::StrokeKind::Inside,
                );
                beside(target, rect)
            }
            None => (egui::Align2::CENTER_CENTER, screen.center()),
        };
        let mut next = Some(stop);
        egui::Window::new(format!("Tour {} of {}: {title}", stop + 1, STOPS.len()))
            .pivot(pivot)
            .fixed_pos(at)
            .collapsible(false)
            .resizable(false)
            .default_width(380.0)
            .show(ctx, |ui| {
                ui.label(text);
                ui.add_space(6.0);
                ui.horizontal(|ui| {
                    if stop > 0 && ui.button("back").clicked() {
                        next = Some(stop - 1);
                    }
                    let last = stop + 1 == STOPS.len();
                    if ui.button(if last { "done" } else { "next" }).clicked() {
                        next = (!last).then_some(stop + 1);
                    }
                    if !last && ui.button("skip the tour").clicked() {
                        next = None;
                    }
                });
            });
        self.stop = next;
        if next.is_none() {
            vec![Command::TourSeen]
        } else {
            Vec::new()
        }
    }
}

/// Each stop: its title, what it says, and the widget it explains. The first stop's text
/// is the model's own ([`intro`]).
const STOPS: [(&str, &str, TourTarget); 6] = [
    ("What you see", "", TourTarget::Everything),
    (
        "Images (left)",
        "Each camera's actual image at every resolution, and the network's posterior \
         reconstruction of it (or, with \"prior prediction images\", its prediction of the \
         next step made before seeing it). With \"contribution maps\", how much each module \
         changes the prediction.",
        TourTarget::Images,
    ),
    (
        "Latent states (centre)",
        "Per module (executive, associative, exteroceptive, proprioceptive): the latent \
         mean mu and spread sigma over time, posterior solid and prior dashed; then \
         proprioception actual and predicted, and the free energy and prediction errors. \
         Click a plot to move the cursor.",
        TourTarget::Latents,
    ),
    (
        "Conditions (top)",
        "Drop the observed vision to low resolutions or none, turn proprioception off, \
         ablate a module (its z set to 0), or change the inference settings: the run under \
         that condition is computed live and its progress shows at the end of the third row.",
        TourTarget::Conditions,
    ),
    (
        "Time (bottom)",
        "Scrub the time bar, play (space) or step (arrow keys). The bar under it shows the \
         subtasks, faded where inference has not reached yet.",
        TourTarget::Time,
    ),
    (
        "Questions to ask it",
        "\"Branch here\" continues the run from the cursor under another condition, beside \
         the original. \"Second network\" opens another network or checkpoint beside this one. \
         \"Compare\" sets conditions side by side. \"Findings\" lists the paper's claims with \
         what our experiments found and a view of this network that shows each. Every view \
         is a link: the address bar holds it.",
        TourTarget::Questions,
    ),
];

impl ExplorerApp {
    /// Starts the tour unless this user has finished or skipped it before.
    pub fn offer_tour(&mut self) {
        if !self.tour_seen() {
            self.tour.stop = Some(0);
        }
    }

    /// Starts the tour from its first stop.
    pub fn start_tour(&mut self) {
        self.tour.stop = Some(0);
    }

    /// The tour's stop shown, if the tour is on.
    pub fn tour_stop(&self) -> Option<usize> {
        self.tour.stop
    }

    /// What the shown stop explains, and where that widget was drawn (`None` for the
    /// whole window, or before the first frame).
    pub fn tour_target(&self) -> Option<(TourTarget, Option<egui::Rect>)> {
        let target = STOPS[self.tour.stop?.min(STOPS.len() - 1)].2;
        Some((target, self.tour.targets.rect(target)))
    }
}

/// Where a stop's window stands: just outside its widget, on the side facing the middle of
/// the window (inside it for the large central panel, by its top edge).
fn beside(target: TourTarget, rect: egui::Rect) -> (egui::Align2, egui::Pos2) {
    const GAP: f32 = 12.0;
    match target {
        TourTarget::Images => (
            egui::Align2::LEFT_TOP,
            egui::pos2(rect.right() + GAP, rect.top() + GAP),
        ),
        TourTarget::Latents => (
            egui::Align2::CENTER_TOP,
            egui::pos2(rect.center().x, rect.top() + GAP),
        ),
        TourTarget::Conditions => (
            egui::Align2::CENTER_TOP,
            egui::pos2(rect.center().x, rect.bottom() + GAP),
        ),
        TourTarget::Time => (
            egui::Align2::CENTER_BOTTOM,
            egui::pos2(rect.center().x, rect.top() - GAP),
        ),
        TourTarget::Questions => (
            egui::Align2::LEFT_TOP,
            egui::pos2(rect.left(), rect.bottom() + GAP),
        ),
        TourTarget::Everything => (egui::Align2::CENTER_CENTER, rect.center()),
    }
}

/// The tour's first words, in the terms of the model's own data: its tasks, cameras and
/// proprioceptive channels (caresim's tasks described as caregiving, any other robot's by
/// their names).
pub fn intro(bundle: Option<&Bundle>) -> String {
    let what = match bundle {
        Some(b) => {
            let m = &b.dataset.manifest;
            let mut tasks: Vec<&str> = b
                .dataset
                .sequences
                .iter()
                .map(|s| s.info.task.as_str())
                .collect();
            tasks.sort_unstable();
            tasks.dedup();
            let tasks = if m.source.starts_with("caresim") {
                "the caregiving tasks of caresim (repositioning a person, wiping with a towel)"
                    .to_string()
            } else {
                let n = tasks.len();
                format!(
                    "{} ({})",
                    if n == 1 { "one task" } else { "its tasks" },
                    tasks.join(", ")
                )
            };
            let torques = if m.torques.is_empty() {
                String::new()
            } else {
                format!(", {} torques", m.torques.len())
            };
            format!(
                "A PV-RNN trained on {tasks} from vision ({} camera{}) and proprioception ({} joint angles{torques}{}).",
                m.cameras.len(),
                if m.cameras.len() == 1 { "" } else { "s" },
                m.joints.len(),
                if m.extra.is_empty() {
                    String::new()
                } else {
                    format!(", {} other channels", m.extra.len())
                }
            )
        }
        None => "A PV-RNN trained from vision and proprioception.".to_string(),
    };
    format!(
        "{what} The explorer runs its online inference: at every step the network infers its \
         latent states from what it has seen and felt so far. Runs not precomputed are \
         computed live, beside the page."
    )
}

const TOUR_KEY: &str = "pvrnn-explorer-tour-seen";

#[cfg(target_arch = "wasm32")]
impl ExplorerApp {
    fn tour_seen(&self) -> bool {
        eframe::web_sys::window()
            .and_then(|w| w.local_storage().ok().flatten())
            .and_then(|s| s.get_item(TOUR_KEY).ok().flatten())
            .is_some()
    }

    pub(super) fn mark_tour_seen(&self) {
        let storage = eframe::web_sys::window().and_then(|w| w.local_storage().ok().flatten());
        if let Some(storage) = storage {
            let _ = storage.set_item(TOUR_KEY, "1");
        }
    }
}

/// Where the desktop app remembers what it remembers: `$XDG_CONFIG_HOME/pvrnn-explorer/`
/// or `~/.config/pvrnn-explorer/`.
#[cfg(not(target_arch = "wasm32"))]
pub fn default_config_dir() -> Option<std::path::PathBuf> {
    let config = std::env::var_os("XDG_CONFIG_HOME")
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::Path::new(&h).join(".config")))?;
    Some(config.join("pvrnn-explorer"))
}

#[cfg(not(target_arch = "wasm32"))]
impl ExplorerApp {
    /// Where the app remembers the tour (`None`: nowhere; the tour is offered each time).
    pub fn set_config_dir(&mut self, dir: Option<std::path::PathBuf>) {
        self.config_dir = dir;
    }

    fn tour_seen(&self) -> bool {
        self.config_dir
            .as_ref()
            .is_some_and(|d| d.join(TOUR_KEY).is_file())
    }

    pub(super) fn mark_tour_seen(&self) {
        // Not remembered where the folder cannot be written: the tour is offered again.
        if let Some(dir) = &self.config_dir
            && std::fs::create_dir_all(dir).is_ok()
        {
            let _ = std::fs::write(dir.join(TOUR_KEY), "1\n");
        }
    }
}
