//! Status and progress: what is loading or computing, and how the last live run went.

use super::*;

impl ExplorerApp {
    pub(super) fn progress_ui(&self, ui: &mut egui::Ui) {
        match (self.store.computing(), self.store.progress()) {
            (Some(key), Some((done, total))) => {
                let what = if Some(key) == self.current_key().as_ref() {
                    "inference"
                } else {
                    "ablation runs"
                };
                // A spinner repaints every frame: fine when the frame loop computes anyway,
                // but off-thread it would take the core the inference needs.
                if self.store.computes_inline() {
                    ui.spinner();
                }
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
        if let Some((what, timing)) = &self.last_run_note {
            ui.weak(what.as_str()).on_hover_text(timing.as_str());
        }
        ui.weak(self.compute_label.as_str())
            .on_hover_text(
                "where live runs compute (desktop: --backend auto|cpu|wgpu [--gpu-recurrence]; web: ?compute=auto|cpu|webgpu[&recurrence=gpu] before the #)",
            );
        if !self.renderer_label.is_empty() {
            ui.weak(self.renderer_label.as_str()).on_hover_text(
                "what draws the window (desktop: --renderer auto|wgpu|glow; web: ?render=glow|wgpu before the #)",
            );
        }
    }
}
