//! The "About this model" window: the bundle's description and its model card (training
//! iterations, time and machine, and the evaluation against the baselines).

use eframe::egui::{self, RichText};
use pvrnn_dataset::card::ModelCard;

/// Draws the card's contents (the caller puts it in a window).
pub fn about_ui(ui: &mut egui::Ui, description: &str, card: Option<&ModelCard>) {
    if !description.is_empty() {
        ui.label(RichText::new(description).strong());
    }
    let Some(card) = card else {
        ui.label("This bundle has no model card (write one with `pvrnn bundle --evaluation ...`).");
        return;
    };
    egui::Grid::new("about_training")
        .num_columns(2)
        .show(ui, |ui| {
            ui.label("Training");
            ui.label(card.training_summary());
            ui.end_row();
            ui.label("Data");
            ui.label(&card.training_data);
            ui.end_row();
            if let Some(f) = card.free_energy {
                ui.label("Free energy");
                ui.label(format!("{f:.1} at the last iteration"));
                ui.end_row();
            }
            ui.label("Configuration");
            if card.departures.is_empty() {
                ui.label("the paper's");
            } else {
                ui.label(format!(
                    "the paper's except (departures): {}",
                    card.departures.join("; ")
                ));
            }
            ui.end_row();
            ui.label("Weights");
            ui.label(&card.weights);
            ui.end_row();
        });
    for (i, e) in card.evaluations.iter().enumerate() {
        ui.separator();
        ui.strong(format!(
            "{} ({} test sequences x {} trials)",
            e.condition, e.sequences, e.trials
        ));
        ui.weak("Mean squared error in model units; * = not observed.");
        egui::Grid::new(("about_eval", i))
            .striped(true)
            .num_columns(5)
            .show(ui, |ui| {
                for head in ["target", "group", "pixels", "model", "baselines"] {
                    ui.strong(head);
                }
                ui.end_row();
                for r in &e.rows {
                    ui.label(&r.target);
                    ui.label(format!("{}{}", r.group, if r.observed { "" } else { "*" }));
                    ui.label(&r.pixels);
                    ui.label(r.model_text());
                    ui.label(r.baselines_text());
                    ui.end_row();
                }
            });
    }
}
