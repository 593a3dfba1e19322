//! The top bar: which sequence, under which condition (vision, proprioception, ablation,
//! inference settings), what is shown. A panel type (`super::panel`).

use super::panel::{Command, PanelContext};
use super::tour::TourTargets;
use super::*;
use crate::state::CompareSet;

/// The top bar (a panel type): it edits a copy of the view and sends it back as one
/// command; its buttons send theirs. The units' text being typed is its own state.
#[derive(Debug, Default)]
pub(super) struct Controls {
    pub(super) units_text: String,
}

/// What the top bar shows besides the panels' context: the windows it toggles, the
/// status, and the status line of the runs.
pub(super) struct Bar<'a> {
    pub(super) about: bool,
    pub(super) findings: bool,
    pub(super) drive: bool,
    pub(super) status: &'a Status,
    pub(super) line: super::status::StatusLine<'a>,
}

impl Controls {
    pub(super) fn ui(
        &mut self,
        ui: &mut egui::Ui,
        ctx: &PanelContext<'_>,
        bar: Bar<'_>,
        targets: &mut TourTargets,
    ) -> Vec<Command> {
        let Some(bundle) = ctx.bundle else {
            return Vec::new();
        };
        let mut commands = Vec::new();
        let mut view = ctx.view.clone();
        let config = &bundle.model.config;
        top_row_ui(ui, bundle, &mut view, &bar, targets, &mut commands);
        let standard = Condition::standard(config);
        let mut c = view.condition.unwrap_or(standard);
        condition_ui(ui, config, &mut c, standard, "");
        if Some(c) != view.condition && !(view.condition.is_none() && c == standard) {
            view.condition = Some(c);
        }
        self.display_row_ui(ui, &mut view, bar.line, &mut commands);
        if view != *ctx.view {
            commands.insert(0, Command::SetView(Box::new(view)));
        }
        commands
    }

    /// The last row: which units and what is drawn, and the run's progress.
    fn display_row_ui(
        &mut self,
        ui: &mut egui::Ui,
        view: &mut ViewState,
        line: super::status::StatusLine<'_>,
        commands: &mut Vec<Command>,
    ) {
        ui.horizontal_wrapped(|ui| {
            let l = ui.label("Units:");
            let edit = ui
                .add(egui::TextEdit::singleline(&mut self.units_text).desired_width(90.0))
                .labelled_by(l.id)
                .on_hover_text("Which latent units (indices of z, and of d with d traces) the plots show, e.g. 0-3,7");
            if edit.changed()
                && let Some(u) = parse_units(&self.units_text)
            {
                view.units = u;
            }
            ui.checkbox(&mut view.show_d, "d traces")
                .on_hover_text("Also plot each module's deterministic state d (tanh of its internal state h, unitless, -1 to 1)");
            ui.checkbox(&mut view.prior_images, "prior prediction images")
                .on_hover_text("Predicted images: the prior's prediction of step t+1 made at t (before seeing it) instead of the posterior reconstruction of step t");
            ui.checkbox(&mut view.contours, "contours")
                .on_hover_text("Draw the edges of the actual image over the pictures (Sobel magnitude of its brightness)");
            ui.checkbox(&mut view.maps, "contribution maps").on_hover_text("Runs inference once more with each module ablated (four runs; minutes at full vision in a browser)");
            if view.branch.is_none()
                && ui
                    .button("Branch here")
                    .on_hover_text("Continue this run from the cursor's step under another condition, shown beside it")
                    .clicked()
            {
                commands.push(Command::BranchHere);
            }
            ui.separator();
            line.ui(ui);
        });
    }
}

/// The first row: the name, about, comparison, export, open, the sequence, the status.
fn top_row_ui(
    ui: &mut egui::Ui,
    bundle: &Bundle,
    view: &mut ViewState,
    bar: &Bar<'_>,
    targets: &mut TourTargets,
    commands: &mut Vec<Command>,
) {
    ui.horizontal_wrapped(|ui| {
        ui.strong("PV-RNN explorer");
        let mut about = bar.about;
        if ui.toggle_value(&mut about, "About this model").changed() {
            commands.push(Command::ShowAbout(about));
        }
        if ui
            .button("Tour")
            .on_hover_text("A short tour of the panels")
            .clicked()
        {
            commands.push(Command::StartTour);
        }
        let mut findings_open = bar.findings;
        let findings = ui.toggle_value(&mut findings_open, "Findings")
            .on_hover_text("The paper's claims, what the experiments found, and a view of this network that shows each");
        if findings.changed() {
            commands.push(Command::ShowFindings(findings_open));
        }
        targets.add_question(findings.rect);
        if pvrnn_drive::check_model(&bundle.model.config).is_ok() {
            let mut drive_open = bar.drive;
            if ui
                .toggle_value(&mut drive_open, "Drive")
                .on_hover_text("Let the network drive caresim's robot in closed loop, and perturb it")
                .changed()
            {
                commands.push(Command::ShowDrive(drive_open));
            }
        }
        let l = ui.label("Compare");
        targets.add_question(l.rect);
        let text = |c: Option<CompareSet>| match c {
            None => "off",
            Some(CompareSet::Vision) => "vision x proprio",
            Some(CompareSet::Ablation) => "ablations",
        };
        let compare = egui::ComboBox::from_id_salt("compare")
            .selected_text(text(view.compare))
            .show_ui(ui, |ui| {
                for c in [None, Some(CompareSet::Vision), Some(CompareSet::Ablation)] {
                    ui.selectable_value(&mut view.compare, c, text(c));
                }
            })
            .response;
        targets.add_question(compare.rect);
        compare
            .labelled_by(l.id)
            .on_hover_text("Set conditions side by side at the cursor: every observed resolution with proprioception on and off (Fig. 5), or each module ablated (Fig. 2B)");
        if ui
            .button("Export CSV")
            .on_hover_text("the shown run's traces, one row per step")
            .clicked()
        {
            commands.push(Command::ExportCsv);
        }
        if ui
            .button("Save picture")
            .on_hover_text("the window as a PNG")
            .clicked()
        {
            commands.push(Command::SavePicture);
        }
        for (label, folder) in [("Open files", false), ("Open folder", true)] {
            if ui
                .button(label)
                .on_hover_text("a bundle folder, or a model file with a dataset's files")
                .clicked()
            {
                commands.push(Command::Open {
                    folder,
                    second: false,
                });
            }
        }
        let second = ui.menu_button("Second network", |ui| {
            for (label, folder) in [
                ("Open a bundle folder", true),
                ("Open files (a checkpoint of this dataset, or a bundle's files)", false),
            ] {
                if ui.button(label).clicked() {
                    commands.push(Command::Open {
                        folder,
                        second: true,
                    });
                    ui.close();
                }
            }
        })
        .response
        .on_hover_text("Show another network (another bundle, or an earlier or later checkpoint) beside this one, on the same sequence under the same condition");
        targets.add_question(second.rect);
        ui.separator();
        sequence_picker(ui, bundle, view);
        ui.separator();
        match bar.status {
            Status::Error(e) => {
                ui.colored_label(Color32::from_rgb(230, 80, 80), e.as_str());
            }
            Status::Info(s) => {
                ui.weak(s.as_str());
            }
            Status::Loading { what, fraction } => {
                ui.label(what.as_str());
                ui.add(egui::ProgressBar::new(fraction.unwrap_or(0.0)).desired_width(120.0));
            }
            Status::None => {}
        }
    });
}

/// Task, bed height (where the data has them), split and trial of the shown sequence.
fn sequence_picker(ui: &mut egui::Ui, bundle: &Bundle, view: &mut ViewState) {
    let seqs = &bundle.dataset.sequences;
    let Some(current) = view
        .sequence
        .as_ref()
        .and_then(|n| bundle.dataset.by_name(n))
    else {
        return;
    };
    let info = current.info.clone();
    let mut tasks: Vec<String> = seqs.iter().map(|s| s.info.task.clone()).collect();
    tasks.dedup();
    tasks.sort();
    tasks.dedup();
    let height = |s: &pvrnn_dataset::SequenceInfo| {
        s.bed_height_mm
            .map_or("-".to_string(), |h| format!("{h:.0} mm"))
    };
    let mut task = info.task.clone();
    let mut bed = height(&info);
    let mut split = info.split.name().to_string();
    let l = ui.label("Task");
    egui::ComboBox::from_id_salt("task")
        .selected_text(&task)
        .show_ui(ui, |ui| {
            for t in &tasks {
                ui.selectable_value(&mut task, t.clone(), t);
            }
        })
        .response
        .labelled_by(l.id);
    let mut heights: Vec<String> = seqs
        .iter()
        .filter(|s| s.info.task == task)
        .map(|s| height(&s.info))
        .collect();
    heights.sort();
    heights.dedup();
    // caresim's bed heights; a robot whose recordings name none has no use for it.
    if seqs.iter().any(|s| s.info.bed_height_mm.is_some()) {
        let l = ui.label("Bed");
        egui::ComboBox::from_id_salt("bed")
            .selected_text(&bed)
            .show_ui(ui, |ui| {
                for h in &heights {
                    ui.selectable_value(&mut bed, h.clone(), h);
                }
            })
            .response
            .labelled_by(l.id);
    }
    let l = ui.label("Split");
    egui::ComboBox::from_id_salt("split")
        .selected_text(&split)
        .show_ui(ui, |ui| {
            for s in ["learn", "test"] {
                ui.selectable_value(&mut split, s.to_string(), s);
            }
        })
        .response
        .labelled_by(l.id);
    let matching: Vec<&str> = seqs
        .iter()
        .filter(|s| s.info.task == task && height(&s.info) == bed && s.info.split.name() == split)
        .map(|s| s.info.name.as_str())
        .collect();
    let mut chosen = view.sequence.clone().unwrap_or_default();
    let l = ui.label("Trial");
    egui::ComboBox::from_id_salt("trial")
        .selected_text(&chosen)
        .show_ui(ui, |ui| {
            for name in &matching {
                ui.selectable_value(&mut chosen, name.to_string(), *name);
            }
        })
        .response
        .labelled_by(l.id);
    let choice = if matching.contains(&chosen.as_str()) {
        Some(chosen)
    } else {
        // A changed task, bed or split: the first sequence that matches as much as possible.
        matching
            .first()
            .map(|s| s.to_string())
            .or_else(|| {
                seqs.iter()
                    .find(|s| s.info.task == task && height(&s.info) == bed)
                    .map(|s| s.info.name.clone())
            })
            .or_else(|| {
                seqs.iter()
                    .find(|s| s.info.task == task)
                    .map(|s| s.info.name.clone())
            })
    };
    if let Some(name) = choice
        && Some(&name) != view.sequence.as_ref()
    {
        let len = bundle.dataset.by_name(&name).map_or(1, |s| s.len());
        view.sequence = Some(name);
        view.t = view.t.min(len.saturating_sub(1));
    }
}

/// The condition of online inference as controls (vision, proprioception, ablation and
/// its mode, H, iterations, lr, seed, back to standard), edited in place.
/// A condition's controls. `salt` keeps a second set (the branch's) apart from the
/// first; the branch's window is its run's, so only the first offers H.
pub(super) fn condition_ui(
    ui: &mut egui::Ui,
    config: &pvrnn_core::ModelConfig,
    c: &mut Condition,
    standard: Condition,
    salt: &str,
) {
    ui.horizontal_wrapped(|ui| {
        let vision_label = ui.label("Vision observed:");
        let levels = config.vision.resolutions.len();
        let label = |n: usize| {
            if n == 0 {
                "none".to_string()
            } else {
                config.vision.resolutions[..n]
                    .iter()
                    .rev()
                    .map(|r| r.to_string())
                    .collect::<Vec<_>>()
                    .join("+")
            }
        };
        egui::ComboBox::from_id_salt((salt, "vision"))
            .selected_text(label(c.vision_levels as usize))
            .show_ui(ui, |ui| {
                for n in (0..=levels).rev() {
                    ui.selectable_value(&mut c.vision_levels, n as u8, label(n));
                }
            })
            .response
            .labelled_by(vision_label.id)
            .on_hover_text("The image resolutions the network observes during inference (pixels per side; the lowest first); none = it infers from proprioception alone");
        ui.checkbox(&mut c.proprio, "proprioception observed")
            .on_hover_text("Whether the joint angles (rad) and torques (N m) are observed during inference");
        ui.separator();
        ui.label("Ablate:");
        for id in ModuleId::ALL {
            ui.checkbox(&mut c.ablation[id.index()], id.name())
                .on_hover_text(format!("Set the {} module's latent z to 0 (see mode)", id.name()));
        }
        let l = ui.label("mode");
        egui::ComboBox::from_id_salt((salt, "ablation mode"))
            .selected_text(c.ablation_mode.name())
            .show_ui(ui, |ui| {
                for (mode, tip) in [
                    (
                        AblationMode::Readout,
                        "inference runs as standard; each step is read out again with z = 0 (the paper's contribution maps)",
                    ),
                    (
                        AblationMode::Inference,
                        "z = 0 during the whole inference, so the other modules may compensate",
                    ),
                ] {
                    ui.selectable_value(&mut c.ablation_mode, mode, mode.name())
                        .on_hover_text(tip);
                }
            })
            .response
            .labelled_by(l.id)
            .on_hover_text("when an ablation (and the contribution maps) applies");
        ui.separator();
        if salt.is_empty() {
            let l = ui.label("H");
            ui.add(egui::DragValue::new(&mut c.window).range(1..=500))
                .labelled_by(l.id)
                .on_hover_text("H: the inference window, in steps: the last H steps' latents are re-inferred at each step");
        }
        let l = ui.label("iterations");
        ui.add(egui::DragValue::new(&mut c.iterations).range(0..=1000))
            .labelled_by(l.id)
            .on_hover_text("Inference updates (RAdam) of the window's latents per step");
        let l = ui.label("lr");
        let mut lr = c.lr();
        if ui
            .add(
                egui::DragValue::new(&mut lr)
                    .range(0.001..=100.0)
                    .speed(0.01),
            )
            .labelled_by(l.id)
            .on_hover_text("The inference learning rate (RAdam, unitless)")
            .changed()
        {
            c.set_lr(lr);
        }
        let l = ui.label("seed");
        ui.add(egui::DragValue::new(&mut c.seed))
            .labelled_by(l.id)
            .on_hover_text("Seed of the noise eps sampled in inference: another seed, another trial");
        if ui
            .button("standard")
            .on_hover_text("The model's configured inference, everything observed")
            .clicked()
        {
            *c = standard;
        }
    });
}

/// Short text of a condition, e.g. `vision 32+16, proprio off, ablate executive, H 30, 50 it`.
pub fn condition_label(c: &Condition) -> String {
    let ablated: Vec<&str> = ModuleId::ALL
        .iter()
        .filter(|id| c.ablation[id.index()])
        .map(|id| id.name())
        .collect();
    format!(
        "vision levels {}, proprio {}, ablate {}, H {}, {} iterations, lr {}, seed {}",
        c.vision_levels,
        if c.proprio { "on" } else { "off" },
        if ablated.is_empty() {
            "none".to_string()
        } else {
            format!("{} ({})", ablated.join("+"), c.ablation_mode.name())
        },
        c.window,
        c.iterations,
        c.lr(),
        c.seed
    )
}
