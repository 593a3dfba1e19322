//! A second network beside the first: another bundle, or another checkpoint of the same
//! dataset (an early and a late one), run on the same sequence under the same condition,
//! with both networks' prediction errors over time and their difference, and its predicted
//! images in the images panel. Its runs compute in their own store, a slice per frame. A
//! panel type (`super::panel`).

use super::panel::{Command, PanelContext};
use super::traces::{ERROR_COLOURS, StepPlot, paired_error_lines};
use super::*;

/// Time the second network's runs get per frame.
const SECOND_BUDGET: Duration = Duration::from_millis(8);

/// The second network and its runs.
pub(super) struct SecondNetwork {
    pub(super) bundle: Bundle,
    pub(super) store: RunStore,
    /// What the user opened, as the panel names it.
    pub(super) name: String,
    /// The view's address (`second=`) it was opened from, if it was.
    pub(super) address: Option<String>,
}

impl SecondNetwork {
    /// `bundle` beside `first`, if the two can be compared: the same cameras, resolutions
    /// and proprioception, so the same sequences and conditions mean the same.
    pub(super) fn new(bundle: Bundle, first: &Bundle, name: String) -> Result<Self, String> {
        let (a, b) = (&first.model.config, &bundle.model.config);
        if a.vision != b.vision || a.proprio_dims != b.proprio_dims {
            return Err(format!(
                "`{name}` cannot be compared with the open network: it sees {} camera(s) at \
                 {:?} and {} proprioceptive dimensions, the open one {} at {:?} and {}",
                b.vision.cameras,
                b.vision.resolutions,
                b.proprio_dims,
                a.vision.cameras,
                a.vision.resolutions,
                a.proprio_dims
            ));
        }
        let mut store = RunStore::default();
        for (key, trace) in bundle.precomputed.iter().cloned() {
            store.insert_complete(key, trace);
        }
        Ok(Self {
            bundle,
            store,
            name,
            address: None,
        })
    }

    /// The run of `key` on this network, if its dataset has the sequence.
    pub(super) fn run(&self, key: &RunKey) -> Option<&Entry> {
        self.store.get(key)
    }
}

impl ExplorerApp {
    /// Opens files as the second network (a bundle, or a model that uses the open one's
    /// dataset).
    pub(super) fn open_second(&mut self, files: Vec<crate::drop::DroppedFile>) {
        let Some(first) = &self.bundle else {
            self.status = Status::Error("open a network first, then a second beside it".into());
            return;
        };
        let name = files
            .iter()
            .map(|(n, _)| n.as_str())
            .find(|n| n.ends_with(".safetensors") || *n == crate::bundle::BUNDLE_MANIFEST)
            .unwrap_or("second network")
            .to_string();
        let opened = crate::drop::assemble(files, Some(first)).and_then(|b| {
            let name = if b.description == "dropped files" {
                name
            } else {
                b.description.clone()
            };
            SecondNetwork::new(b, first, name)
        });
        match opened {
            Ok(second) => {
                self.status = Status::Info(format!("second network: {}", second.name));
                self.second = Some(second);
                // Files the user picked have no address a link could name.
                self.view.second = None;
            }
            Err(e) => self.status = Status::Error(e),
        }
    }

    /// Opens the browser's file picker for the second network; what the user picks opens
    /// beside the first. Returns the input element (tests fill it).
    #[cfg(target_arch = "wasm32")]
    pub fn pick_second_network(
        &mut self,
        folder: bool,
    ) -> Result<eframe::web_sys::HtmlInputElement, String> {
        self.opening_second = true;
        self.web
            .pick_files(folder)
            .inspect_err(|_| self.opening_second = false)
    }

    /// Opens a bundle folder as the second network (the desktop's `--second`).
    pub fn set_second(&mut self, bundle: Bundle) -> Result<(), String> {
        let first = self.bundle.as_ref().ok_or("open a network first")?;
        let name = bundle.description.clone();
        self.second = Some(SecondNetwork::new(bundle, first, name)?);
        Ok(())
    }

    /// Opens the second network the view's address names (`second=`: a bundle relative
    /// to the site, or to the working folder on the desktop) unless it is the one open:
    /// downloaded in the browser, read from disk on the desktop.
    pub(super) fn follow_second_address(&mut self) {
        let Some(address) = self.view.second.clone() else {
            return;
        };
        if self.bundle.is_none()
            || self
                .second
                .as_ref()
                .is_some_and(|s| s.address.as_deref() == Some(address.as_str()))
        {
            return;
        }
        #[cfg(target_arch = "wasm32")]
        let opened = {
            if self.web.second_address() != Some(address.as_str()) {
                let base = if address.ends_with('/') {
                    address.clone()
                } else {
                    format!("{address}/")
                };
                self.web.start_second_download(&base);
                self.status = Status::Info(format!(
                    "loading the second network {}",
                    crate::state::quoted(&address)
                ));
            }
            match self.web.poll_second() {
                None => return,
                Some(result) => result.map(|b| *b),
            }
        };
        #[cfg(not(target_arch = "wasm32"))]
        let opened = Bundle::open_dir(std::path::Path::new(&address));
        let shown = crate::state::quoted(&address);
        match opened.and_then(|b| self.set_second(b)) {
            Ok(()) => {
                if let Some(second) = self.second.as_mut() {
                    second.address = Some(address);
                    self.status = Status::Info(format!("second network: {}", second.name));
                }
            }
            Err(e) => {
                self.status = Status::Error(format!("the second network {shown}: {e}"));
                self.view.second = None;
            }
        }
    }

    /// The second network's run of the shown run, if there is a second network.
    pub fn second_run(&self) -> Option<&Entry> {
        self.second.as_ref()?.run(&self.current_key()?)
    }

    /// Asks the second network for the shown run and computes for a slice.
    pub(super) fn compute_second(&mut self) -> bool {
        let key = self.current_key();
        let (Some(second), Some(key)) = (self.second.as_mut(), key) else {
            return false;
        };
        if second.bundle.dataset.by_name(&key.sequence).is_none() {
            return false;
        }
        second.store.request(key, true);
        let model = second.bundle.model.clone();
        let bundle = &mut second.bundle;
        second
            .store
            .work(&model, SECOND_BUDGET, &mut |name| bundle.observations(name))
            || !second.store.idle()
    }
}

impl SecondNetwork {
    /// The second network's panel beside the shown run; closing it and seeking, as
    /// commands.
    pub(super) fn ui(&self, ui: &mut egui::Ui, ctx: &PanelContext<'_>) -> Vec<Command> {
        let Some(key) = &ctx.key else {
            return Vec::new();
        };
        let mut commands = Vec::new();
        ui.horizontal_wrapped(|ui| {
            ui.heading("Second network");
            ui.label(&self.name);
            if ui.button("close the second network").clicked() {
                commands.push(Command::CloseSecond);
            }
        });
        if self.bundle.dataset.by_name(&key.sequence).is_none() {
            ui.colored_label(
                Color32::from_rgb(230, 80, 80),
                format!(
                    "the second network's data has no sequence `{}`",
                    key.sequence
                ),
            );
        } else if let Some(err) = self.run(key).and_then(|e| e.error.as_ref()) {
            ui.colored_label(
                Color32::from_rgb(230, 80, 80),
                format!("its run failed: {err}"),
            );
        }
        let empty = RunTrace::default();
        let first = ctx.run().map_or(&empty, |e| &e.trace);
        let other = self.run(key).map_or(&empty, |e| &e.trace);
        let plot = StepPlot {
            len: ctx.sequence_len(),
            t: ctx.view.t,
            mark: None,
            legend: true,
        };
        if let Some(t) = errors_ui(ui, &plot, first, other) {
            commands.push(Command::Seek(t));
        }
        ui.separator();
        commands
    }
}

/// Both networks' prediction errors over time, and their difference; the step clicked.
fn errors_ui(
    ui: &mut egui::Ui,
    plot: &StepPlot,
    first: &RunTrace,
    second: &RunTrace,
) -> Option<usize> {
    let mut seek = None;
    ui.columns(2, |cols| {
        let lines = paired_error_lines((first, "first"), (second, "second"));
        let title = "prediction error (mean squared, all dimensions); dashed: the first network";
        seek = plot.show(
            &mut cols[0],
            "second errors".into(),
            title,
            130.0,
            lines,
            None,
        );
        let both = first.steps.min(second.steps);
        let difference = ERROR_COLOURS
            .into_iter()
            .enumerate()
            .map(|(i, (name, colour))| {
                let points: Vec<[f64; 2]> = (0..both)
                    .map(|t| {
                        let d = second.recon_error[t][i] - first.recon_error[t][i];
                        [t as f64, d as f64]
                    })
                    .collect();
                Line::new(name, PlotPoints::from(points)).color(colour)
            })
            .collect();
        let title = "difference: second - first (below 0: the second predicts better)";
        seek = plot
            .show(
                &mut cols[1],
                "second difference".into(),
                title,
                130.0,
                difference,
                None,
            )
            .or(seek);
    });
    seek
}
