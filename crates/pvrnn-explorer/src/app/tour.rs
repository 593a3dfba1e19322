//! A short guided tour of the panels, offered on a first visit: skippable, and remembered
//! (the browser's local storage; a file in the user's configuration folder on the
//! desktop). The "Tour" button starts it again.

use super::*;

/// Each stop: its title, what it says, and where its window stands (by the panel it
/// explains). The first stop's text is the model's own ([`intro`]).
const STOPS: [(&str, &str, egui::Align2); 6] = [
    ("What you see", "", egui::Align2::CENTER_CENTER),
    (
        "Images (left)",
        "Each camera's actual image at every resolution, and the network's posterior \
         reconstruction of it (or, with \"prior prediction images\", its prediction of the \
         next step made before seeing it). With \"contribution maps\", how much each module \
         changes the prediction.",
        egui::Align2::LEFT_CENTER,
    ),
    (
        "Latent states (centre)",
        "Per module (executive, associative, exteroceptive, proprioceptive): the latent \
         mean mu and spread sigma over time, posterior solid and prior dashed; then \
         proprioception actual and predicted, and the free energy and prediction errors. \
         Click a plot to move the cursor.",
        egui::Align2::CENTER_TOP,
    ),
    (
        "Conditions (top)",
        "Drop the observed vision to low resolutions or none, turn proprioception off, \
         ablate a module (its z set to 0), or change the inference settings: the run under \
         that condition is computed live and its progress shows at the end of the third row.",
        egui::Align2::CENTER_TOP,
    ),
    (
        "Time (bottom)",
        "Scrub the time bar, play (space) or step (arrow keys). The bar under it shows the \
         subtasks, faded where inference has not reached yet.",
        egui::Align2::CENTER_BOTTOM,
    ),
    (
        "Questions to ask it",
        "\"Branch here\" continues the run from the cursor under another condition, beside \
         the original. \"Second network\" opens another network or checkpoint beside this one. \
         \"Compare\" sets conditions side by side. \"Findings\" lists the paper's claims with \
         what our experiments found and a view of this network that shows each. Every view \
         is a link: the address bar holds it.",
        egui::Align2::RIGHT_TOP,
    ),
];

impl ExplorerApp {
    /// Starts the tour unless this user has finished or skipped it before.
    pub fn offer_tour(&mut self) {
        if !self.tour_seen() {
            self.tour = Some(0);
        }
    }

    /// Starts the tour from its first stop.
    pub fn start_tour(&mut self) {
        self.tour = Some(0);
    }

    /// The tour's stop shown, if the tour is on.
    pub fn tour_stop(&self) -> Option<usize> {
        self.tour
    }

    pub(super) fn tour_ui(&mut self, ctx: &egui::Context) {
        let Some(stop) = self.tour else { return };
        let (title, text, anchor) = STOPS[stop.min(STOPS.len() - 1)];
        let text = if text.is_empty() {
            intro(self.bundle.as_ref())
        } else {
            text.to_string()
        };
        let mut next = Some(stop);
        egui::Window::new(format!("Tour {} of {}: {title}", stop + 1, STOPS.len()))
            .anchor(anchor, egui::vec2(0.0, 0.0) + offset(anchor))
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
        if next.is_none() {
            self.mark_tour_seen();
        }
        self.tour = next;
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

/// Keeps the tour's window off the panel edges.
fn offset(anchor: egui::Align2) -> egui::Vec2 {
    let x = match anchor.x() {
        egui::Align::Min => 40.0,
        egui::Align::Center => 0.0,
        egui::Align::Max => -40.0,
    };
    let y = match anchor.y() {
        egui::Align::Min => 130.0,
        egui::Align::Center => 0.0,
        egui::Align::Max => -90.0,
    };
    egui::vec2(x, y)
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

    fn mark_tour_seen(&self) {
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

    fn mark_tour_seen(&self) {
        // Not remembered where the folder cannot be written: the tour is offered again.
        if let Some(dir) = &self.config_dir
            && std::fs::create_dir_all(dir).is_ok()
        {
            let _ = std::fs::write(dir.join(TOUR_KEY), "1\n");
        }
    }
}
