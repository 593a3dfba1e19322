//! The branch panel: the shown run and its branch (the same run up to step `at`, another
//! condition from it on) over time: how far their states drift apart, their prediction
//! errors, and each module's KL. The branch's predicted images are in the images panel. A
//! panel type (`super::panel`).

use super::controls::condition_ui;
use super::palette::unit_colour;
use super::panel::{Command, PanelContext};
use super::traces::{REFERENCE, StepPlot, paired_error_lines};
use super::*;
use crate::state::BranchView;

impl ExplorerApp {
    /// The branch's run, when the view has one.
    pub fn branch_key(&self) -> Option<RunKey> {
        let b = self.view.branch?;
        Some(self.current_key()?.branched(b.at, b.condition))
    }

    /// Branches the shown run at the cursor; it continues without vision until the user
    /// chooses another condition.
    pub fn branch_here(&mut self) {
        let Some(c) = self.condition() else { return };
        self.view.branch = Some(BranchView {
            at: self.view.t,
            condition: Condition {
                vision_levels: 0,
                ..c
            },
        });
    }
}

/// The branch panel: its controls and plots, over the panels' context.
pub(super) struct BranchControls;

impl BranchControls {
    /// The branch's controls and plots (nothing without a branch); what the user changed,
    /// as commands.
    pub(super) fn ui(ui: &mut egui::Ui, ctx: &PanelContext<'_>) -> Vec<Command> {
        let (Some(bundle), Some(mut branch), Some(key)) = (ctx.bundle, ctx.view.branch, &ctx.key)
        else {
            return Vec::new();
        };
        let mut commands = Vec::new();
        let config = &bundle.model.config;
        let standard = Condition::standard(config);
        let mut removed = false;
        ui.horizontal_wrapped(|ui| {
            ui.heading(format!("Branch at step {}", branch.at));
            if ui
                .button("move to the cursor")
                .on_hover_text("branch at the cursor's step instead")
                .clicked()
            {
                branch.at = ctx.view.t;
            }
            removed = ui.button("remove the branch").clicked();
            let mut traces = ctx.view.branch_traces;
            if ui
                .checkbox(&mut traces, "latent traces of the branch")
                .on_hover_text("The latent states, proprioception and summaries below show the branch instead of its run")
                .changed()
            {
                commands.push(Command::BranchTraces(traces));
            }
        });
        if removed {
            commands.push(Command::Branch(None));
            return commands;
        }
        ui.label(
            RichText::new(
                "From the branch step on, the run continues under this condition (its \
                 window H stays the run's; the window is read under the new condition):",
            )
            .small(),
        );
        condition_ui(ui, config, &mut branch.condition, standard, "branch");
        branch.condition.window = key.condition.window;
        if Some(branch) != ctx.view.branch {
            commands.push(Command::Branch(Some(branch)));
        }
        let empty = RunTrace::new(config);
        let original = ctx.store.get(key).map_or(&empty, |e| &e.trace);
        // The branch as shown this frame (a changed condition's run is asked for next).
        let branch_entry = ctx.branch_key().and_then(|k| ctx.store.get(&k));
        if let Some(err) = branch_entry.and_then(|e| e.error.as_ref()) {
            ui.colored_label(
                Color32::from_rgb(230, 80, 80),
                format!("the branch failed: {err}"),
            );
        }
        let panel = BranchPanel {
            original,
            branch: branch_entry.map_or(&empty, |e| &e.trace),
            at: branch.at,
            plot: StepPlot {
                len: ctx.sequence_len(),
                t: ctx.view.t,
                mark: Some(branch.at),
                legend: false,
            },
        };
        if let Some(t) = panel.ui(ui) {
            commands.push(Command::Seek(t));
        }
        ui.separator();
        commands
    }
}

/// What the branch panel shows: two runs that share their steps before `at`.
struct BranchPanel<'a> {
    original: &'a RunTrace,
    branch: &'a RunTrace,
    at: usize,
    plot: StepPlot,
}

impl BranchPanel<'_> {
    /// The three plots; the step clicked, if any.
    fn ui(&self, ui: &mut egui::Ui) -> Option<usize> {
        let shared = self.original.steps.min(self.branch.steps);
        ui.label(
            RichText::new(format!(
                "branch computed to step {} of {}; solid: the branch, dashed: the run",
                self.branch.steps, self.plot.len
            ))
            .small(),
        );
        ui.horizontal_wrapped(|ui| {
            ui.label(RichText::new("modules:").small());
            for id in ModuleId::ALL {
                ui.label(
                    RichText::new(id.name())
                        .small()
                        .color(unit_colour(id.index())),
                );
            }
            ui.label(RichText::new("(the pink dashed line: the branch step)").small());
        });
        let mut seek = None;
        ui.columns(3, |cols| {
            let divergence = ModuleId::ALL
                .iter()
                .map(|&id| {
                    let points = (0..shared)
                        .map(|t| [t as f64, divergence(self.original, self.branch, id, t)])
                        .collect::<Vec<_>>();
                    Line::new(id.name(), PlotPoints::from(points)).color(unit_colour(id.index()))
                })
                .collect();
            let title = "divergence: RMS |d(branch) - d(run)| per module";
            seek = self.show(&mut cols[0], "branch divergence", title, divergence);
            let errors = paired_error_lines((self.original, "run"), (self.branch, "branch"));
            let title = "prediction error (mean squared, all dimensions)";
            let with_legend = StepPlot {
                legend: true,
                ..self.plot
            };
            seek = with_legend
                .show(
                    &mut cols[1],
                    "branch errors".into(),
                    title,
                    130.0,
                    errors,
                    None,
                )
                .or(seek);
            let mut kl = Vec::new();
            for (trace, style, who) in [
                (self.original, REFERENCE, "run"),
                (self.branch, LineStyle::Solid, "branch"),
            ] {
                for id in ModuleId::ALL {
                    let points = (0..trace.steps)
                        .map(|t| [t as f64, module_kl(trace, id, t)])
                        .collect::<Vec<_>>();
                    let name = format!("{} ({who})", id.name());
                    let line = Line::new(name, PlotPoints::from(points));
                    kl.push(line.color(unit_colour(id.index())).style(style));
                }
            }
            let title = "KL(posterior || prior) per module (nats)";
            seek = self.show(&mut cols[2], "branch kl", title, kl).or(seek);
        });
        if self.branch.steps > self.at && self.original.steps > self.at {
            let same = (0..self.at.min(shared))
                .all(|t| divergence(self.original, self.branch, ModuleId::Executive, t) == 0.0);
            if !same {
                ui.weak(
                    "the steps before the branch differ slightly from the run's: the run was \
                     precomputed (stored at reduced precision) and the branch recomputed them",
                );
            }
        }
        seek
    }

    fn show(
        &self,
        ui: &mut egui::Ui,
        id: &str,
        title: &str,
        lines: Vec<Line<'static>>,
    ) -> Option<usize> {
        self.plot
            .show(ui, id.to_string(), title, 130.0, lines, None)
    }
}

/// Root mean square of d(branch) - d(run) over a module's units at step t.
pub fn divergence(run: &RunTrace, branch: &RunTrace, module: ModuleId, t: usize) -> f64 {
    let a = run.d_at(module, t, false);
    let b = branch.d_at(module, t, false);
    let sum: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    (sum / a.len().max(1) as f64).sqrt()
}

/// KL(q || p) of a module's latent at step t, summed over its units.
pub fn module_kl(trace: &RunTrace, module: ModuleId, t: usize) -> f64 {
    let m = module.index();
    let z = trace.z[m];
    let s = &trace.modules[m];
    (t * z..(t + 1) * z)
        .map(|i| {
            let (mq, sq) = (s.mu_q[i] as f64, s.sigma_q[i] as f64);
            let (mp, sp) = (s.mu_p[i] as f64, s.sigma_p[i] as f64);
            (sp / sq).ln() + (sq * sq + (mq - mp).powi(2)) / (2.0 * sp * sp) - 0.5
        })
        .sum()
}
