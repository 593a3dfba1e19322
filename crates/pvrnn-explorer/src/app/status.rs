//! Status and progress: what is loading or computing, and how the last live run went.

use super::*;
use crate::engine::Finished;

/// What the status bar says of a finished live run, and its timing (the hover text; the
/// web build also logs both).
pub(super) fn finished_note(f: &Finished) -> (String, String) {
    let mut what = format!(
        "run {} ({}) computed live: {} steps",
        f.key.sequence,
        condition_label(&f.key.condition),
        f.steps,
    );
    if let Some(then) = &f.key.then {
        what = format!(
            "branch of run {} ({}) at step {} under ({}) computed live: {} steps, {} of them \
             computed",
            f.key.sequence,
            condition_label(&f.key.condition),
            then.at,
            condition_label(&then.condition),
            f.steps,
            f.steps - f.replayed
        );
    }
    let computed = (f.steps - f.replayed) as f64;
    let timing = format!(
        "in {:.1} s = {:.1} steps/s ({:.1} steps/s of computing time)",
        f.wall.as_secs_f64(),
        computed / f.wall.as_secs_f64().max(1e-9),
        computed / f.busy.as_secs_f64().max(1e-9)
    );
    (what, timing)
}

/// The status line: which run computes and how far, the last run's note, where runs
/// compute and what draws.
pub(super) struct StatusLine<'a> {
    pub(super) store: &'a RunStore,
    /// The run the view shows.
    pub(super) shown: Option<RunKey>,
    /// What the last finished run computed, and how fast (on hover).
    pub(super) last_run: Option<&'a (String, String)>,
    pub(super) compute: &'a str,
    pub(super) renderer: &'a str,
}

impl StatusLine<'_> {
    pub(super) fn ui(&self, ui: &mut egui::Ui) {
        match (self.store.computing(), self.store.progress()) {
            (Some(key), Some((done, total))) => {
                let what = if Some(key) == self.shown.as_ref() {
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
        if let Some((what, timing)) = self.last_run {
            ui.weak(what.as_str()).on_hover_text(timing.as_str());
        }
        ui.weak(self.compute)
            .on_hover_text(
                "where live runs compute (desktop: --backend auto|cpu|wgpu; web: ?compute=auto|cpu|webgpu before the #)",
            );
        if !self.renderer.is_empty() {
            ui.weak(self.renderer).on_hover_text(
                "what draws the window (desktop: --renderer auto|wgpu|glow; web: ?render=glow|wgpu before the #)",
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::condition::{Condition, RunKey};

    #[test]
    fn a_finished_run_says_its_speed() {
        let mut f = Finished {
            key: RunKey::new(
                "wiping_650mm_test0",
                Condition::standard(&pvrnn_core::ModelConfig::default()),
            ),
            steps: 300,
            busy: Duration::from_secs(20),
            wall: Duration::from_secs(30),
            replayed: 0,
        };
        let (what, timing) = finished_note(&f);
        assert!(what.starts_with("run wiping_650mm_test0 ("), "{what}");
        assert!(what.ends_with("computed live: 300 steps"), "{what}");
        assert_eq!(
            timing,
            "in 30.0 s = 10.0 steps/s (15.0 steps/s of computing time)"
        );
        // A branch's speed counts the steps it computed, not those it shares.
        let blind = Condition {
            vision_levels: 0,
            ..f.key.condition
        };
        f.key = f.key.branched(150, blind);
        f.replayed = 150;
        let (what, timing) = finished_note(&f);
        assert!(
            what.starts_with("branch of run wiping_650mm_test0 ("),
            "{what}"
        );
        assert!(
            what.contains(") at step 150 under (vision levels 0,"),
            "{what}"
        );
        assert!(what.ends_with("300 steps, 150 of them computed"), "{what}");
        assert_eq!(
            timing,
            "in 30.0 s = 5.0 steps/s (7.5 steps/s of computing time)"
        );
    }
}
