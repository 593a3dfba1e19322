//! Time: the slider with the subtask bar, play and pause, and the keyboard (a panel type:
//! `super::panel`).

use super::panel::{Command, PanelContext};
use super::*;

/// The time bar, the keyboard's play and step keys, and playback.
#[derive(Debug, Default)]
pub(super) struct TimePanel {
    /// Playback's fraction of a step not yet taken.
    play_accum: f32,
}

impl TimePanel {
    /// Space plays or pauses, the arrows step (unless a text field has the keyboard).
    pub(super) fn keyboard(
        &self,
        egui_ctx: &egui::Context,
        ctx: &PanelContext<'_>,
    ) -> Vec<Command> {
        if egui_ctx.egui_wants_keyboard_input() {
            return Vec::new();
        }
        let (len, t) = (ctx.sequence_len(), ctx.view.t);
        egui_ctx.input(|i| {
            let mut commands = Vec::new();
            if i.key_pressed(egui::Key::Space) {
                commands.push(Command::Play(!ctx.view.playing));
            }
            if i.key_pressed(egui::Key::ArrowRight) {
                commands.push(Command::Seek((t + 1).min(len.saturating_sub(1))));
            }
            if i.key_pressed(egui::Key::ArrowLeft) {
                commands.push(Command::Seek(t.saturating_sub(1)));
            }
            commands
        })
    }

    /// Playback over `dt` seconds: the steps to move on, and stopping at the end.
    pub(super) fn advance(&mut self, dt: f32, ctx: &PanelContext<'_>) -> Vec<Command> {
        if !ctx.view.playing {
            self.play_accum = 0.0;
            return Vec::new();
        }
        self.play_accum += dt * ctx.view.speed;
        let steps = self.play_accum.floor();
        self.play_accum -= steps;
        let last = ctx.sequence_len().saturating_sub(1);
        let t = (ctx.view.t + steps as usize).min(last);
        let mut commands = vec![Command::Seek(t)];
        if t >= last {
            commands.push(Command::Play(false));
        }
        commands
    }

    /// Draws the time bar; what the user changed, as commands.
    pub(super) fn ui(&mut self, ui: &mut egui::Ui, ctx: &PanelContext<'_>) -> Vec<Command> {
        let view = ctx.view;
        let (mut t, mut playing, mut speed) = (view.t, view.playing, view.speed);
        time_panel(
            ui,
            (&mut t, &mut playing, &mut speed),
            ctx.sequence(),
            ctx.computed,
        );
        let mut commands = Vec::new();
        if t != view.t {
            commands.push(Command::Seek(t));
        }
        if playing != view.playing {
            commands.push(Command::Play(playing));
        }
        if speed != view.speed {
            commands.push(Command::Speed(speed));
        }
        commands
    }
}

/// The time bar: play, step, speed, the scrub bar with the sequence's subtasks under it
/// (faded where inference has not reached), and the subtask at the cursor.
fn time_panel(
    ui: &mut egui::Ui,
    (t, playing, speed): (&mut usize, &mut bool, &mut f32),
    sequence: Option<&pvrnn_dataset::Sequence>,
    computed: usize,
) {
    let len = sequence.map_or(0, |s| s.len());
    ui.horizontal(|ui| {
        let label = if *playing { "pause" } else { "play" };
        if ui
            .button(label)
            .on_hover_text("play the run from the cursor (space)")
            .clicked()
        {
            if !*playing && *t + 1 >= len {
                *t = 0;
            }
            *playing = !*playing;
        }
        if ui
            .button("<")
            .on_hover_text("step back (left arrow)")
            .clicked()
        {
            *t = t.saturating_sub(1);
        }
        if ui
            .button(">")
            .on_hover_text("step forward (right arrow)")
            .clicked()
        {
            *t = (*t + 1).min(len.saturating_sub(1));
        }
        ui.add(
            egui::Slider::new(speed, 1.0..=60.0)
                .suffix(" steps/s")
                .logarithmic(true)
                .text("speed"),
        )
        .on_hover_text("playback speed, in sequence steps per second");
        ui.separator();
        ui.label(format!("t = {} / {}", *t, len.saturating_sub(1)));
    });
    ui.spacing_mut().slider_width = ui.available_width() - 60.0;
    ui.add(
        egui::Slider::new(t, 0..=len.saturating_sub(1))
            .show_value(false)
            .text("time"),
    )
    .on_hover_text("the cursor's step t; the bar under it: the subtasks, faded where inference has not reached");
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
        let x = rect.left() + *t as f32 * w;
        painter.vline(x, rect.y_range(), (2.0, Color32::WHITE));
        let names = seq
            .info
            .subtasks
            .get(seq.subtask[(*t).min(seq.len() - 1)] as usize)
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
