//! Contribution maps over time (the paper's Fig. 2B / 3B are time-resolved): per module,
//! how much zeroing its z changes the predicted image (|standard - ablated|, read-out
//! ablation) at every step, as a curve over the run, and averaged over the steps of the
//! cursor's subtask phase, as a map. Read out a few steps per frame as the ablation runs
//! arrive, so the window never waits for all of them.

use super::images_panel::{camera_name, read_out_vision};
use super::traces::{StepPlot, unit_colour};
use super::*;

/// Steps read out per frame (five read-outs each).
const STEPS_PER_FRAME: usize = 8;

/// The contributions of one run's modules, as far as its ablation runs are computed.
#[derive(Default)]
pub(super) struct ContributionsOverTime {
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

impl ContributionsOverTime {
    /// Reads out the steps that every run of `base`'s maps has computed and this has not
    /// (a few per call); whether anything changed.
    pub(super) fn update(&mut self, bundle: &Bundle, store: &RunStore, base: &RunKey) -> bool {
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

    /// Module `m`'s map averaged over the steps of subtask `label` read out so far, and
    /// how many steps that is.
    pub(super) fn phase_map(&self, label: u32, m: usize, size: usize) -> Option<(Rgb, usize)> {
        let (sums, count) = self.sums.get(&label)?;
        let mean: Vec<f32> = sums[m].iter().map(|s| s / *count as f32).collect();
        Some((images::gray(&mean, size, 4.0), *count))
    }
}

impl ExplorerApp {
    /// The shown run's contributions, a few steps further (when the maps are on).
    pub(super) fn refresh_contributions(&mut self) {
        let (Some(bundle), Some(key), true) = (&self.bundle, self.current_key(), self.view.maps)
        else {
            return;
        };
        let base = RunKey::new(&key.sequence, key.condition.without_ablation());
        if self.contributions.update(bundle, &self.store, &base) {
            // The phase maps changed: read the pictures out again.
            self.images.key = None;
        }
    }

    /// The curves over the run (when the maps are on).
    pub(super) fn contributions_ui(&mut self, ui: &mut egui::Ui) {
        if !self.view.maps {
            return;
        }
        let c = &self.contributions;
        let lines = ModuleId::ALL
            .iter()
            .map(|&id| {
                let points: Vec<[f64; 2]> = c.curves[id.index()]
                    .iter()
                    .enumerate()
                    .map(|(t, &v)| [t as f64, v as f64])
                    .collect();
                Line::new(id.name(), PlotPoints::from(points)).color(unit_colour(id.index()))
            })
            .collect();
        let plot = StepPlot {
            len: self.sequence_len(),
            t: self.view.t,
            mark: None,
            legend: true,
        };
        ui.heading("Contributions over time");
        let title = format!(
            "mean |standard - ablated| predicted image per module (model units; read-out \
             ablation; {} at full resolution); {} of {} steps read out",
            self.camera_label(),
            c.done,
            self.sequence_len()
        );
        if let Some(t) = plot.show(ui, "contributions".into(), &title, 140.0, lines, None) {
            self.view.t = t;
        }
        ui.add_space(8.0);
    }

    /// The name of the camera the maps show (the last one).
    fn camera_label(&self) -> String {
        self.bundle.as_ref().map_or_else(String::new, |b| {
            let cameras = &b.dataset.manifest.cameras;
            camera_name(cameras, b.model.config.vision.cameras - 1)
        })
    }
}
