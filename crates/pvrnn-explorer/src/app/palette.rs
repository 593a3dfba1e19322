//! Colours shared by the panels that draw per-unit and per-channel lines (the traces, the
//! summaries, a branch, the contributions over time).

use eframe::egui::{self, Color32};

/// The colour of latent unit `k` in the traces.
pub(super) fn unit_colour(k: usize) -> Color32 {
    // Evenly spaced hues.
    let hue = (k as f32 * 0.618_034) % 1.0;
    let c = egui::ecolor::Hsva::new(hue, 0.7, 0.95, 1.0);
    c.into()
}
