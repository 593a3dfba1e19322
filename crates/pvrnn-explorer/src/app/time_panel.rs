//! Time: the slider with the subtask bar, play and pause, and the keyboard.

use super::*;

impl ExplorerApp {
    pub(super) fn keyboard(&mut self, ctx: &egui::Context) {
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

    pub(super) fn advance_playback(&mut self, dt: f32) {
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

    pub(super) fn time_ui(&mut self, ui: &mut egui::Ui) {
        let computed = self.current_run().map_or(0, |e| e.trace.steps);
        let sequence = self.bundle.as_ref().and_then(|b| {
            self.view
                .sequence
                .as_ref()
                .and_then(|name| b.dataset.by_name(name))
        });
        time_panel(ui, &mut self.view, sequence, computed);
    }
}

/// The time bar: play, step, speed, the scrub bar with the sequence's subtasks under it
/// (faded where inference has not reached), and the subtask at the cursor.
fn time_panel(
    ui: &mut egui::Ui,
    view: &mut crate::state::ViewState,
    sequence: Option<&pvrnn_dataset::Sequence>,
    computed: usize,
) {
    let len = sequence.map_or(0, |s| s.len());
    ui.horizontal(|ui| {
        let label = if view.playing { "pause" } else { "play" };
        if ui
            .button(label)
            .on_hover_text("play the run from the cursor (space)")
            .clicked()
        {
            if !view.playing && view.t + 1 >= len {
                view.t = 0;
            }
            view.playing = !view.playing;
        }
        if ui
            .button("<")
            .on_hover_text("step back (left arrow)")
            .clicked()
        {
            view.t = view.t.saturating_sub(1);
        }
        if ui
            .button(">")
            .on_hover_text("step forward (right arrow)")
            .clicked()
        {
            view.t = (view.t + 1).min(len.saturating_sub(1));
        }
        ui.add(
            egui::Slider::new(&mut view.speed, 1.0..=60.0)
                .suffix(" steps/s")
                .logarithmic(true)
                .text("speed"),
        )
        .on_hover_text("playback speed, in sequence steps per second");
        ui.separator();
        ui.label(format!("t = {} / {}", view.t, len.saturating_sub(1)));
    });
    let mut t = view.t;
    ui.spacing_mut().slider_width = ui.available_width() - 60.0;
    ui.add(
        egui::Slider::new(&mut t, 0..=len.saturating_sub(1))
            .show_value(false)
            .text("time"),
    )
    .on_hover_text("the cursor's step t; the bar under it: the subtasks, faded where inference has not reached");
    view.t = t;
    // Subtask strip under the scrub bar, and how far inference has got.
    let (rect, _) = ui.allocate_exact_size(
        egui::vec2(ui.spacing().slider_width, 8.0),
        egui::Sense::hover(),
    );
    if let Some(seq) = sequence {
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
        let x = rect.left() + view.t as f32 * w;
        painter.vline(x, rect.y_range(), (2.0, Color32::WHITE));
        let names = seq
            .info
            .subtasks
            .get(seq.subtask[view.t.min(seq.len() - 1)] as usize)
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
