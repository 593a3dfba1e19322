//! Contribution maps over time (the paper's Fig. 2B / 3B are time-resolved): per module,
//! how much zeroing its z changes the predicted image (|standard - ablated|, read-out
//! ablation) at every step, as a curve over the run, and averaged over the steps of the
//! cursor's subtask phase, as a map; over one trial or averaged over several (noise seeds,
//! as the paper averages its maps over trials). Read out a few steps per frame as the
//! ablation runs arrive, so the window never waits for all of them.

use super::images_panel::{camera_name, read_out_vision};
use super::palette::unit_colour;
use super::panel::{Command, PanelContext};
use super::traces::StepPlot;
use super::*;

/// Steps read out per frame (five read-outs each).
const STEPS_PER_FRAME: usize = 8;

/// The contributions averaged over trials (one `TrialContributions` per seed).
#[derive(Default)]
pub(super) struct ContributionsOverTime {
    trials: Vec<TrialContributions>,
}

impl ContributionsOverTime {
    /// Reads further into each trial's runs (`bases`: one standard run per trial); whether
    /// anything changed.
    pub(super) fn update(&mut self, bundle: &Bundle, store: &RunStore, bases: &[RunKey]) -> bool {
        self.trials
            .resize_with(bases.len(), TrialContributions::default);
        let mut changed = false;
        for (trial, base) in self.trials.iter_mut().zip(bases) {
            changed |= trial.update(bundle, store, base);
        }
        changed
    }

    /// Steps read out in every trial.
    pub(super) fn done(&self) -> usize {
        self.trials.iter().map(|t| t.done).min().unwrap_or(0)
    }

    /// Per module, the mean over trials of each step's contribution, for the steps every
    /// trial has read out.
    pub(super) fn curves(&self) -> [Vec<f32>; 4] {
        let (steps, n) = (self.done(), self.trials.len().max(1) as f32);
        std::array::from_fn(|m| {
            (0..steps)
                .map(|t| self.trials.iter().map(|tr| tr.curves[m][t]).sum::<f32>() / n)
                .collect()
        })
    }

    /// Module `m`'s map averaged over the steps of subtask `label` in every trial read out
    /// so far, and how many steps (over all trials) that is.
    pub(super) fn phase_map(&self, label: u32, m: usize, size: usize) -> Option<(Rgb, usize)> {
        let mut total: Vec<f32> = Vec::new();
        let mut count = 0;
        for (sums, n) in self.trials.iter().filter_map(|t| t.sums.get(&label)) {
            if total.is_empty() {
                total = vec![0.0; sums[m].len()];
            }
            for (a, b) in total.iter_mut().zip(&sums[m]) {
                *a += b;
            }
            count += n;
        }
        (count > 0).then(|| {
            let mean: Vec<f32> = total.iter().map(|s| s / count as f32).collect();
            (images::gray(&mean, size, 4.0), count)
        })
    }
}

/// The contributions of one run's modules, as far as its ablation runs are computed.
#[derive(Default)]
struct TrialContributions {
    /// The standard run they belong to (its condition without ablation).
    base: Option<RunKey>,
    /// Steps read out so far.
    pub(super) done: usize,
    /// Per module, per step: mean |standard - ablated| over the pixels (model units).
    pub(super) curves: [Vec<f32>; 4],
    /// Per subtask label: the per-module sums of |standard - ablated| images, and how many
    /// steps they sum.
    sums: HashMap<u32, ([Vec<f32>; 4], usize)>,
}

impl TrialContributions {
    /// Reads out the steps that every run of `base`'s maps has computed and this has not
    /// (a few per call); whether anything changed.
    fn update(&mut self, bundle: &Bundle, store: &RunStore, base: &RunKey) -> bool {
        if self.base.as_ref() != Some(base) {
            *self = Self {
                base: Some(base.clone()),
                ..Self::default()
            };
        }
        let Some(seq) = bundle.dataset.by_name(&base.sequence) else {
            return false;
        };
        let runs: Vec<RunKey> = std::iter::once(base.clone())
            .chain(
                ModuleId::ALL
                    .iter()
                    .map(|&id| RunKey::new(&base.sequence, base.condition.ablating(id))),
            )
            .collect();
        let traces: Option<Vec<&RunTrace>> = runs
            .iter()
            .map(|k| store.get(k).map(|e| &e.trace))
            .collect();
        let Some(traces) = traces else { return false };
        let ready = traces.iter().map(|t| t.steps).min().unwrap_or(0);
        let end = ready.min(self.done + STEPS_PER_FRAME);
        if end <= self.done {
            return false;
        }
        let ext = ModuleId::Exteroceptive;
        let steps = self.done..end;
        let mut rows = Vec::new();
        for trace in &traces {
            for t in steps.clone() {
                rows.extend_from_slice(trace.d_at(ext, t, false));
            }
        }
        let n = steps.len();
        let vision = read_out_vision(bundle, &rows, traces.len() * n);
        let layout = &bundle.model.config.vision;
        let dims = layout.dims();
        let (top, camera) = (layout.resolutions.len() - 1, layout.cameras - 1);
        let at = |run: usize, i: usize| &vision[(run * n + i) * dims..(run * n + i + 1) * dims];
        for (i, t) in steps.enumerate() {
            let label = seq.subtask.get(t).copied().unwrap_or(0);
            let (sums, count) = self.sums.entry(label).or_default();
            for m in 0..4 {
                let diff = images::pixel_differences(layout, at(0, i), at(m + 1, i), top, camera);
                self.curves[m].push(diff.iter().sum::<f32>() / diff.len().max(1) as f32);
                if sums[m].is_empty() {
                    sums[m] = vec![0.0; diff.len()];
                }
                for (s, d) in sums[m].iter_mut().zip(&diff) {
                    *s += d;
                }
            }
            *count += 1;
        }
        self.done = end;
        true
    }
}

impl ExplorerApp {
    /// The shown run's contributions, a few steps further (when the maps are on); whether
    /// they changed.
    pub(super) fn refresh_contributions(&mut self) -> bool {
        let (Some(bundle), Some(key), true) = (&self.bundle, self.current_key(), self.view.maps)
        else {
            return false;
        };
        let bases: Vec<RunKey> = map_conditions(&key.condition, self.view.map_trials)
            .map(|c| RunKey::new(&key.sequence, c.without_ablation()))
            .collect();
        let changed = self.contributions.update(bundle, &self.store, &bases);
        if changed {
            // The phase maps changed: read the pictures out again.
            self.images.key = None;
        }
        changed
    }
}

impl ContributionsOverTime {
    /// The curves over the run (when the maps are on); the trials asked for and the step
    /// clicked, as commands.
    pub(super) fn ui(&self, ui: &mut egui::Ui, ctx: &PanelContext<'_>) -> Vec<Command> {
        let view = ctx.view;
        if !view.maps {
            return Vec::new();
        }
        let mut commands = Vec::new();
        let curves = self.curves();
        let lines = ModuleId::ALL
            .iter()
            .map(|&id| {
                let points: Vec<[f64; 2]> = curves[id.index()]
                    .iter()
                    .enumerate()
                    .map(|(t, &v)| [t as f64, v as f64])
                    .collect();
                Line::new(id.name(), PlotPoints::from(points)).color(unit_colour(id.index()))
            })
            .collect();
        let plot = StepPlot {
            len: ctx.sequence_len(),
            t: view.t,
            mark: None,
            legend: true,
        };
        ui.horizontal(|ui| {
            ui.heading("Contributions over time");
            let l = ui.label("trials");
            let mut trials = view.map_trials;
            ui.add(egui::DragValue::new(&mut trials).range(1..=MAX_MAP_TRIALS))
                .labelled_by(l.id)
                .on_hover_text("Average the contributions (curves and subtask maps) over this many trials: noise seeds from the condition's on, five runs each");
            if trials != view.map_trials {
                commands.push(Command::MapTrials(trials));
            }
        });
        let seed = ctx.key.as_ref().map_or(0, |k| k.condition.seed);
        let trials = match view.map_trials {
            1 => format!("trial of seed {seed}"),
            n => format!("mean of {n} trials, seeds {seed}-{}", seed + n as u32 - 1),
        };
        let camera = ctx.bundle.map_or_else(String::new, |b| {
            let cameras = &b.dataset.manifest.cameras;
            camera_name(cameras, b.model.config.vision.cameras - 1)
        });
        let title = format!(
            "mean |standard - ablated| predicted image per module (model units; read-out \
             ablation; {camera} at full resolution; {trials}); {} of {} steps read out",
            self.done(),
            ctx.sequence_len()
        );
        if let Some(t) = plot.show(ui, "contributions".into(), &title, 140.0, lines, None) {
            commands.push(Command::Seek(t));
        }
        ui.add_space(8.0);
        commands
    }
}

/// The most trials the contributions average over.
pub const MAX_MAP_TRIALS: u8 = 10;

/// The conditions of the trials the contribution maps average over: `condition` with
/// seeds from its own on.
pub(super) fn map_conditions(
    condition: &Condition,
    trials: u8,
) -> impl Iterator<Item = Condition> + '_ {
    (0..trials.max(1) as u32).map(move |k| Condition {
        seed: condition.seed.wrapping_add(k),
        ..*condition
    })
}
