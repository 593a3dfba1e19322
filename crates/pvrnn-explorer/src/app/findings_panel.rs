//! The findings panel: the paper's claims beside what the experiments found (verdict, statistic,
//! effect with its interval, scale, the committed figures), each with one click to the
//! view of the shipped network that shows it and a sentence on what to look at (a panel
//! type: `super::panel`).

use super::panel::Command;
use super::*;
use crate::findings::{FINDINGS, Finding, Verdict};

/// The findings' figures as textures, read when the panel first shows them, and the one
/// opened full size (a click on a figure).
#[derive(Default)]
struct FigureCache {
    textures: HashMap<&'static str, Result<TextureHandle, String>>,
    full_size: Option<&'static str>,
    #[cfg(target_arch = "wasm32")]
    fetches: crate::browser::Fetches,
}

impl FigureCache {
    /// A figure's texture: read (desktop: built in; web: fetched, `None` until it arrives).
    fn get(
        &mut self,
        ctx: &egui::Context,
        path: &'static str,
    ) -> Option<&Result<TextureHandle, String>> {
        if !self.textures.contains_key(path) {
            let bytes = self.bytes(ctx, path)?;
            let texture = bytes.and_then(|b| {
                let image = image::load_from_memory(&b)
                    .map_err(|e| format!("{path}: {e}"))?
                    .to_rgba8();
                let size = [image.width() as usize, image.height() as usize];
                let pixels = egui::ColorImage::from_rgba_unmultiplied(size, image.as_raw());
                Ok(ctx.load_texture(path, pixels, TextureOptions::LINEAR))
            });
            self.textures.insert(path, texture);
        }
        self.textures.get(path)
    }

    /// The figure opened full size, in a window of its own that scrolls.
    fn full_size_ui(&mut self, ctx: &egui::Context) {
        let Some(path) = self.full_size else { return };
        let Some(Ok(texture)) = self.get(ctx, path) else {
            return;
        };
        let texture = texture.clone();
        let mut open = true;
        egui::Window::new(format!("docs/results/{path}"))
            .open(&mut open)
            .default_size(texture.size_vec2().min(ctx.content_rect().size() * 0.9))
            .scroll(true)
            .show(ctx, |ui| {
                ui.add(egui::Image::new(&texture).fit_to_exact_size(texture.size_vec2()));
            });
        if !open {
            self.full_size = None;
        }
    }

    #[cfg(not(target_arch = "wasm32"))]
    fn bytes(&mut self, _ctx: &egui::Context, path: &str) -> Option<Result<Vec<u8>, String>> {
        Some(
            crate::findings::FIGURES
                .iter()
                .find(|(p, _)| *p == path)
                .map(|(_, b)| b.to_vec())
                .ok_or_else(|| format!("{path} is not built in")),
        )
    }

    #[cfg(target_arch = "wasm32")]
    fn bytes(&mut self, ctx: &egui::Context, path: &str) -> Option<Result<Vec<u8>, String>> {
        self.fetches.get(&crate::findings::figure_url(path), ctx)
    }
}

/// The findings window: whether it is open, and its figures.
#[derive(Default)]
pub(super) struct FindingsPanel {
    pub(super) open: bool,
    figures: FigureCache,
}

impl FindingsPanel {
    /// The findings window, when open; a finding's link followed, as a command.
    pub(super) fn ui(&mut self, ctx: &egui::Context) -> Vec<Command> {
        let mut open = self.open;
        let mut follow = None;
        egui::Window::new("The paper's findings, and ours")
            .open(&mut open)
            .default_width(720.0)
            .max_width(760.0)
            .default_height(640.0)
            .vscroll(true)
            .show(ctx, |ui| {
                ui.label(
                    "Each claim of the paper with our verdict (by the rules of \
                     docs/experiments.md), the paper's statistic, ours as measured (effect with \
                     its 95% interval; docs/results/experiments.md), the scale it was measured \
                     at, and the view of the shipped network that shows it. A verdict needs \
                     networks that pass the validity gate (on held-out data they beat the \
                     strongest baseline without dynamics); the November 2026 networks do not, \
                     so their findings are not testable and are shown for the record.",
                );
                for (i, finding) in FINDINGS.iter().enumerate() {
                    let panel = FindingPanel { finding, index: i };
                    if panel.ui(ui, &mut self.figures) {
                        follow = finding.view;
                    }
                }
            });
        self.open = open;
        if open {
            self.figures.full_size_ui(ctx);
        }
        follow.map(Command::OpenAddress).into_iter().collect()
    }
}

/// One finding, drawn in the findings window.
struct FindingPanel<'a> {
    finding: &'a Finding,
    index: usize,
}

impl FindingPanel<'_> {
    /// Draws the finding; whether the user asked for its view.
    fn ui(&self, ui: &mut egui::Ui, figures: &mut FigureCache) -> bool {
        let f = self.finding;
        let mut follow = false;
        egui::CollapsingHeader::new(header(ui, f))
            .id_salt(("finding", self.index))
            .default_open(self.index == 0)
            .show(ui, |ui| {
                for (label, text) in [
                    ("verdict:", f.verdict.label()),
                    ("paper:", f.paper),
                    ("ours:", f.ours),
                    ("effect [95% CI]; detectable:", f.effect),
                    ("scale:", f.scale),
                ] {
                    ui.horizontal_wrapped(|ui| {
                        ui.label(RichText::new(label).weak());
                        ui.label(text);
                    });
                }
                ui.horizontal_wrapped(|ui| {
                    for &path in f.figures {
                        match figures.get(ui.ctx(), path) {
                            Some(Ok(texture)) => {
                                let size = texture.size_vec2();
                                let width = 340.0f32.min(size.x);
                                let clicked = ui
                                    .add(
                                        egui::Image::new(texture)
                                            .fit_to_exact_size(egui::vec2(
                                                width,
                                                width * size.y / size.x,
                                            ))
                                            .alt_text(format!("figure {path}"))
                                            .sense(egui::Sense::click()),
                                    )
                                    .on_hover_text(format!(
                                        "docs/results/{path}: click to open it full size"
                                    ))
                                    .clicked();
                                if clicked {
                                    figures.full_size = Some(path);
                                }
                            }
                            Some(Err(e)) => {
                                ui.weak(format!("figure not available: {e}"));
                            }
                            None => {
                                ui.spinner();
                            }
                        }
                    }
                });
                ui.label(f.look);
                match f.view {
                    Some(view) => {
                        follow = ui
                            .button("Show it on the shipped network")
                            .on_hover_text(format!("opens #{view}"))
                            .clicked();
                    }
                    None => {
                        ui.weak("no view of one network shows it");
                    }
                }
            });
        follow
    }
}

/// A finding's header: the claim, then the verdict in its colour, so that the verdicts read
/// down the closed list.
fn header(ui: &egui::Ui, f: &Finding) -> egui::text::LayoutJob {
    let visuals = ui.visuals();
    let colour = match f.verdict {
        Verdict::Agrees => Color32::from_rgb(52, 168, 83),
        Verdict::Disagrees => visuals.error_fg_color,
        Verdict::Undecided => visuals.warn_fg_color,
        Verdict::Descriptive | Verdict::NotTestable => visuals.weak_text_color(),
    };
    let mut job = egui::text::LayoutJob::default();
    for text in [
        RichText::new(f.claim).strong(),
        RichText::new(format!("  {}", f.verdict.label())).color(colour),
    ] {
        text.append_to(
            &mut job,
            ui.style(),
            egui::FontSelection::Default,
            egui::Align::Center,
        );
    }
    job
}
