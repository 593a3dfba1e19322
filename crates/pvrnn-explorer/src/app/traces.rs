//! Latent traces: mu and sigma (prior and posterior) and d per module, proprioception
//! actual and predicted. A panel type (`super::panel`).

use super::palette::unit_colour;
use super::panel::{Command, PanelContext};
use super::*;

/// The traces of the shown run (or of its branch, when the view asks for it).
pub(super) struct Traces;

impl Traces {
    /// Draws the traces; the step the user clicked, as a command.
    pub(super) fn ui(ui: &mut egui::Ui, ctx: &PanelContext<'_>) -> Vec<Command> {
        let Some(bundle) = ctx.bundle else {
            return Vec::new();
        };
        let branch = ctx.branch_key().filter(|_| ctx.view.branch_traces);
        let Some(key) = branch.or_else(|| ctx.key.clone()) else {
            return Vec::new();
        };
        let Some(seq) = bundle.dataset.by_name(&key.sequence) else {
            return Vec::new();
        };
        if let Some(then) = &key.then {
            ui.label(
                RichText::new(format!(
                    "The traces below are the branch's (from step {})",
                    then.at
                ))
                .strong(),
            );
        }
        let entry = ctx.store.get(&key);
        if let Some(err) = entry.and_then(|e| e.error.as_ref()) {
            ui.colored_label(
                Color32::from_rgb(230, 80, 80),
                format!("inference failed: {err}"),
            );
        }
        let empty = RunTrace::new(&bundle.model.config);
        let trace = entry.map_or(&empty, |e| &e.trace);
        let panel = TracesPanel {
            trace,
            sequence: seq,
            config: &bundle.model.config,
            channels: bundle.dataset.manifest.channels(),
            t: ctx.view.t,
            units: &ctx.view.units,
            show_d: ctx.view.show_d,
        };
        let seek = panel.ui(ui);
        super::summaries::uncertainty_ui(ui, trace);
        seek.map(Command::Seek).into_iter().collect()
    }
}

/// What the traces panel shows: one run of one sequence, at step `t`.
pub(super) struct TracesPanel<'a> {
    pub trace: &'a RunTrace,
    pub sequence: &'a pvrnn_dataset::Sequence,
    pub config: &'a pvrnn_core::ModelConfig,
    pub channels: pvrnn_dataset::Channels,
    pub t: usize,
    /// The latent units to plot (those a module lacks are skipped).
    pub units: &'a [usize],
    pub show_d: bool,
}

impl TracesPanel<'_> {
    /// Draws the latent states, proprioception and the summaries; the step the user
    /// clicked on a plot, if any.
    pub(super) fn ui(&self, ui: &mut egui::Ui) -> Option<usize> {
        let mut seek = self.latent_ui(ui);
        ui.add_space(8.0);
        seek = self.proprioception_ui(ui).or(seek);
        ui.add_space(8.0);
        self.summaries_ui(ui).or(seek)
    }

    fn len(&self) -> usize {
        self.sequence.len()
    }

    /// A plot over the sequence's steps with the cursor at `t`; the step clicked, if any.
    fn plot(
        &self,
        ui: &mut egui::Ui,
        id: String,
        title: &str,
        height: f32,
        lines: Vec<Line<'static>>,
        y: Option<(f64, f64)>,
    ) -> Option<usize> {
        let plot = StepPlot {
            len: self.len(),
            t: self.t,
            mark: None,
            legend: false,
        };
        plot.show(ui, id, title, height, lines, y)
    }
}

/// What each plot shows, by the start of its title: the quantity and its unit (the hover
/// help of the plots' titles).
pub(super) const PLOT_HELP: [(&str, &str); 12] = [
    (
        "mu",
        "Latent mean mu of each chosen unit of z over the steps: posterior (inferred from what was seen) solid, prior (predicted from the past) dashed; unitless",
    ),
    (
        "sigma",
        "Latent standard deviation sigma of each chosen unit of z: posterior solid, prior dashed; unitless, the network's uncertainty",
    ),
    (
        "d",
        "The module's deterministic state d = tanh(h) of its first units; unitless, -1 to 1",
    ),
    (
        "joint angles",
        "Joint angles in rad: measured solid, the network's posterior reconstruction dashed",
    ),
    (
        "torques",
        "Joint torques in N m: measured solid, the network's posterior reconstruction dashed",
    ),
    (
        "extra channels",
        "The robot's other channels in their own units: measured solid, reconstructed dashed",
    ),
    (
        "window free energy",
        "Free energy of the inference window after the step's updates (nats): reconstruction error plus the KL terms weighted by w",
    ),
    (
        "prediction error",
        "Mean squared error of the reconstruction against the whole observation (every pixel of every resolution, or every proprioceptive channel), in model units",
    ),
    (
        "divergence",
        "Root mean square of d(branch) - d(run) over each module's units at each step; unitless, 0 where the two share their past",
    ),
    (
        "KL(posterior",
        "KL divergence of each module's posterior from its prior at each step, summed over its units (nats): how much the observation moved the latent state",
    ),
    (
        "mean |standard - ablated|",
        "How much the predicted image changes when the module's z is set to 0 at that step: mean absolute difference over the pixels, model units",
    ),
    (
        "difference: second - first",
        "The second network's prediction error minus the first's at each step (model units): below 0 the second predicts better",
    ),
];

/// The hover help of a plot titled `title`.
pub(super) fn plot_help(title: &str) -> Option<&'static str> {
    // The short titles (mu, sigma, d) are whole titles; the others start longer ones.
    PLOT_HELP
        .iter()
        .find(|(start, _)| title == *start || (start.len() > 5 && title.starts_with(start)))
        .map(|(_, help)| *help)
}

/// The prediction errors' colours, per modality (vision, proprioception).
pub(super) const ERROR_COLOURS: [(&str, Color32); 2] = [
    ("vision", Color32::from_rgb(242, 146, 38)),
    ("proprioception", Color32::from_rgb(118, 172, 152)),
];

/// How the reference of two runs side by side is drawn (the run a branch leaves, the
/// first network): dashed, the other solid.
pub(super) const REFERENCE: LineStyle = LineStyle::Dashed { length: 6.0 };

/// Two runs' prediction errors per modality over their steps, `(trace, name)` each, the
/// reference dashed.
pub(super) fn paired_error_lines(
    reference: (&RunTrace, &str),
    other: (&RunTrace, &str),
) -> Vec<Line<'static>> {
    let mut lines = Vec::new();
    for ((trace, who), style) in [(reference, REFERENCE), (other, LineStyle::Solid)] {
        for (i, (name, colour)) in ERROR_COLOURS.into_iter().enumerate() {
            let points: Vec<[f64; 2]> = (0..trace.steps)
                .map(|t| [t as f64, trace.recon_error[t][i] as f64])
                .collect();
            let line = Line::new(format!("{name} ({who})"), PlotPoints::from(points));
            lines.push(line.color(colour).style(style));
        }
    }
    lines
}

/// A plot over a sequence's `len` steps with the cursor at `t` (and a marked step, such as
/// where a branch leaves its run).
#[derive(Clone, Copy)]
pub(super) struct StepPlot {
    pub len: usize,
    pub t: usize,
    pub mark: Option<usize>,
    pub legend: bool,
}

impl StepPlot {
    /// Draws `lines` under `title`; the step clicked, if any.
    pub(super) fn show(
        &self,
        ui: &mut egui::Ui,
        id: String,
        title: &str,
        height: f32,
        lines: Vec<Line<'static>>,
        y: Option<(f64, f64)>,
    ) -> Option<usize> {
        let len = self.len;
        let label = ui.label(RichText::new(title).small());
        if let Some(help) = plot_help(title) {
            label.on_hover_text(help);
        }
        let mut p = Plot::new(id)
            .height(height)
            .include_x(0.0)
            .include_x(len as f64)
            .allow_drag(false)
            .allow_zoom(false)
            .allow_scroll(false)
            .allow_boxed_zoom(false)
            .show_x(true);
        if let Some((lo, hi)) = y {
            p = p.include_y(lo).include_y(hi);
        }
        if self.legend {
            p = p.legend(Legend::default());
        }
        let cursor = ui.visuals().strong_text_color();
        let response = p.show(ui, |pu| {
            for l in lines {
                pu.line(l);
            }
            // The vertical lines are unnamed, so that legends list the plotted lines only.
            if let Some(at) = self.mark {
                pu.vline(
                    VLine::new("", at as f64)
                        .color(Color32::from_rgb(200, 120, 220))
                        .style(LineStyle::dashed_loose())
                        .width(1.5),
                );
            }
            pu.vline(VLine::new("", self.t as f64).color(cursor).width(1.5));
        });
        let r = &response.response;
        if r.is_pointer_button_down_on() || r.clicked() {
            r.interact_pointer_pos().map(|pos| {
                response
                    .transform
                    .value_from_position(pos)
                    .x
                    .round()
                    .clamp(0.0, (len.max(1) - 1) as f64) as usize
            })
        } else {
            None
        }
    }
}

impl TracesPanel<'_> {
    /// Per module mu and sigma (posterior solid, prior dashed) and, if asked, d.
    fn latent_ui(&self, ui: &mut egui::Ui) -> Option<usize> {
        let trace = self.trace;
        let mut seek = None;
        ui.heading("Latent states");
        ui.weak("posterior solid, prior dashed; one colour per unit");
        for id in ModuleId::ALL {
            let m = id.index();
            let (z, d) = (trace.z[m], trace.d[m]);
            let units: Vec<usize> = self.units.iter().copied().filter(|&u| u < z).collect();
            let series = |values: &[f32], width: usize, u: usize| -> Vec<[f64; 2]> {
                (0..trace.steps)
                    .map(|s| [s as f64, values[s * width + u] as f64])
                    .collect()
            };
            let pair = |post: &[f32], prior: &[f32]| -> Vec<Line<'static>> {
                let mut lines = Vec::new();
                for (k, &u) in units.iter().enumerate() {
                    let colour = unit_colour(k);
                    lines.push(
                        Line::new(format!("{u}"), PlotPoints::from(series(post, z, u)))
                            .color(colour)
                            .width(1.2),
                    );
                    lines.push(
                        Line::new(format!("{u} prior"), PlotPoints::from(series(prior, z, u)))
                            .color(colour)
                            .width(1.0)
                            .style(LineStyle::dashed_dense()),
                    );
                }
                lines
            };
            let mt = &trace.modules[m];
            ui.strong(MODULE_TITLES[m]);
            ui.columns(2, |cols| {
                let mu = pair(&mt.mu_q, &mt.mu_p);
                let sigma = pair(&mt.sigma_q, &mt.sigma_p);
                seek = self
                    .plot(
                        &mut cols[0],
                        format!("mu {m}"),
                        "mu",
                        110.0,
                        mu,
                        Some((-1.0, 1.0)),
                    )
                    .or(seek);
                seek = self
                    .plot(
                        &mut cols[1],
                        format!("sigma {m}"),
                        "sigma",
                        110.0,
                        sigma,
                        Some((0.0, 1.0)),
                    )
                    .or(seek);
            });
            if self.show_d {
                let lines: Vec<Line<'static>> = (0..d.min(units.len().max(1) * 2).min(d))
                    .map(|u| {
                        Line::new(format!("d{u}"), PlotPoints::from(series(&mt.d, d, u)))
                            .color(unit_colour(u))
                            .width(1.0)
                    })
                    .collect();
                seek = self
                    .plot(ui, format!("d {m}"), "d", 90.0, lines, Some((-1.0, 1.0)))
                    .or(seek);
            }
        }
        seek
    }

    /// The robot's channels as its dataset names them, one plot per kind it has: actual
    /// solid, the posterior reconstruction dashed, in the recordings' units.
    fn proprioception_ui(&self, ui: &mut egui::Ui) -> Option<usize> {
        let trace = self.trace;
        let mut seek = None;
        ui.heading("Proprioception");
        ui.weak("actual solid, predicted (posterior reconstruction) dashed");
        let norm = self.config.normalisation.clone();
        // Bundle::new checked that the model's proprioception is the data's.
        let dims = self.config.proprio_dims;
        let raw_pred = |values: &[f32], dim: usize| -> Vec<[f64; 2]> {
            (0..trace.steps)
                .map(|s| {
                    let v = values[s * dims + dim] as f64;
                    [
                        s as f64,
                        norm.as_ref().map_or(v, |n| n.proprio_from_model(dim, v)),
                    ]
                })
                .collect()
        };
        let ranges = self.channels.layout().ranges();
        let extra = format!(
            "extra channels: {} (their own units)",
            self.channels.extra.join(", ")
        );
        let kinds = [
            ("joint angles (rad)".to_string(), &self.channels.joints),
            ("torques (N m)".to_string(), &self.channels.torques),
            (extra, &self.channels.extra),
        ];
        for ((title, names), range) in kinds.into_iter().zip(ranges) {
            if names.is_empty() {
                continue;
            }
            let colours = ChannelColours::of(names);
            let title = format!("{title}; {}", colours.key());
            let mut lines = Vec::new();
            for (j, (dim, name)) in range.clone().zip(names.iter()).enumerate() {
                let colour = colours.colour(j);
                let actual: Vec<[f64; 2]> = (0..self.len())
                    .map(|s| [s as f64, self.sequence.proprio(s)[dim] as f64])
                    .collect();
                lines.push(
                    Line::new(name.clone(), PlotPoints::from(actual))
                        .color(colour)
                        .width(1.2),
                );
                if trace.steps > 0 {
                    lines.push(
                        Line::new(
                            format!("{name} predicted"),
                            PlotPoints::from(raw_pred(&trace.proprio_recon, dim)),
                        )
                        .color(colour)
                        .width(1.0)
                        .style(LineStyle::dashed_dense()),
                    );
                }
            }
            let id = format!("proprio {}", range.start);
            let plot = StepPlot {
                len: self.len(),
                t: self.t,
                mark: None,
                // Named lines where a legend stays readable; the groups' colours otherwise.
                legend: names.len() <= LEGEND_CHANNELS,
            };
            seek = plot.show(ui, id, &title, 150.0, lines, None).or(seek);
        }
        seek
    }

    /// The window free energy and the prediction errors per step.
    fn summaries_ui(&self, ui: &mut egui::Ui) -> Option<usize> {
        let trace = self.trace;
        let len = self.len();
        let mut seek = None;
        ui.heading("Summaries");
        let per_step = |v: Vec<f64>| -> PlotPoints<'static> {
            PlotPoints::from(
                v.into_iter()
                    .enumerate()
                    .map(|(s, v)| [s as f64, v])
                    .collect::<Vec<[f64; 2]>>(),
            )
        };
        let fe = per_step(trace.free_energy.iter().map(|&v| v as f64).collect());
        let ve = per_step(trace.recon_error.iter().map(|e| e[0] as f64).collect());
        let pe = per_step(trace.recon_error.iter().map(|e| e[1] as f64).collect());
        ui.columns(2, |cols| {
            let free_energy = vec![Line::new("F", fe).color(Color32::LIGHT_BLUE)];
            seek = self.plot(
                &mut cols[0],
                "fe".into(),
                "window free energy",
                120.0,
                free_energy,
                None,
            );
            let [(vision, vision_colour), (proprio, proprio_colour)] = ERROR_COLOURS;
            let lines = vec![
                Line::new(vision, ve).color(vision_colour),
                Line::new(proprio, pe).color(proprio_colour),
            ];
            let title = "prediction error (mean squared, all dimensions)";
            let label = cols[1].label(RichText::new(title).small());
            if let Some(help) = plot_help(title) {
                label.on_hover_text(help);
            }
            let cursor = cols[1].visuals().strong_text_color();
            let r = Plot::new("errors")
                .height(120.0)
                .legend(Legend::default())
                .include_x(0.0)
                .include_x(len as f64)
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false)
                .show(&mut cols[1], |pu| {
                    for l in lines {
                        pu.line(l);
                    }
                    pu.vline(VLine::new("t", self.t as f64).color(cursor).width(1.5));
                });
            if r.response.clicked()
                && let Some(pos) = r.response.interact_pointer_pos()
            {
                seek = Some(
                    r.transform
                        .value_from_position(pos)
                        .x
                        .round()
                        .clamp(0.0, (len.max(1) - 1) as f64) as usize,
                );
            }
        });
        seek
    }
}

/// Plots of at most this many channels name them in a legend.
const LEGEND_CHANNELS: usize = 8;

/// Colours of one kind of channels, from their names: channels whose names share a prefix
/// (`left_q1`, `left_q2`: group `left`) get shades of one hue, each group its own hue
/// (the paper's robot: left arm red, right arm cyan); ungrouped channels go around the
/// colour wheel.
pub(super) struct ChannelColours {
    /// Per channel: its group and its place in the group.
    place: Vec<(usize, usize)>,
    groups: Vec<(String, usize)>,
}

impl ChannelColours {
    pub(super) fn of(names: &[String]) -> Self {
        let prefix = |n: &str| n.split_once('_').map(|(p, _)| p.to_string());
        let mut groups: Vec<(String, usize)> = Vec::new();
        let mut place = Vec::new();
        for name in names {
            // A group is a prefix two channels or more share.
            let shared = prefix(name).filter(|p| {
                names
                    .iter()
                    .filter(|n| prefix(n).as_ref() == Some(p))
                    .count()
                    > 1
            });
            let key = shared.unwrap_or_else(|| name.clone());
            let g = match groups.iter().position(|(k, _)| *k == key) {
                Some(g) => g,
                None => {
                    groups.push((key, 0));
                    groups.len() - 1
                }
            };
            place.push((g, groups[g].1));
            groups[g].1 += 1;
        }
        Self { place, groups }
    }

    fn grouped(&self) -> bool {
        self.groups.len() < self.place.len()
    }

    pub(super) fn colour(&self, channel: usize) -> Color32 {
        let (g, k) = self.place[channel];
        if !self.grouped() {
            let hue = channel as f32 / self.place.len().max(1) as f32;
            return egui::ecolor::Hsva::new(hue, 0.7, 0.7, 1.0).into();
        }
        let hue = g as f32 / self.groups.len() as f32;
        let size = self.groups[g].1.max(1) as f32;
        egui::ecolor::Hsva::new(
            hue + 0.08 * k as f32 / size,
            0.75,
            0.55 + 0.4 * k as f32 / size,
            1.0,
        )
        .into()
    }

    /// What the colours mean, e.g. `colours: left red, right cyan`.
    pub(super) fn key(&self) -> String {
        if !self.grouped() {
            return "one colour per channel".into();
        }
        let groups: Vec<String> = (0..self.groups.len())
            .map(|g| {
                let hue = g as f32 / self.groups.len() as f32;
                format!("{} {}", self.groups[g].0, hue_name(hue))
            })
            .collect();
        format!("colours: {}", groups.join(", "))
    }
}

/// The common name of a hue in [0, 1).
fn hue_name(hue: f32) -> &'static str {
    const NAMES: [&str; 12] = [
        "red",
        "orange",
        "yellow",
        "lime",
        "green",
        "spring green",
        "cyan",
        "azure",
        "blue",
        "violet",
        "magenta",
        "rose",
    ];
    NAMES[((hue * 12.0).round() as usize) % 12]
}

#[cfg(test)]
mod tests {
    use super::plot_help;

    #[test]
    fn every_plot_title_has_its_help_and_only_its_own() {
        let help = |t: &str| plot_help(t).unwrap_or_else(|| panic!("no help for `{t}`"));
        assert!(help("mu").starts_with("Latent mean"));
        assert!(help("sigma").starts_with("Latent standard deviation"));
        assert!(help("d").starts_with("The module's deterministic state"));
        for (title, start) in [
            (
                "divergence: RMS |d(branch) - d(run)| per module",
                "Root mean square",
            ),
            (
                "difference: second - first (below 0: the second predicts better)",
                "The second",
            ),
            (
                "joint angles (rad); colours: left red, right cyan",
                "Joint angles",
            ),
            ("torques (N m); one colour per channel", "Joint torques"),
            (
                "extra channels: grip_mm (their own units)",
                "The robot's other",
            ),
            ("window free energy", "Free energy"),
            (
                "prediction error (mean squared, all dimensions)",
                "Mean squared error",
            ),
            ("KL(posterior || prior) per module (nats)", "KL divergence"),
            (
                "mean |standard - ablated| predicted image per module",
                "How much",
            ),
        ] {
            assert!(help(title).starts_with(start), "{title}");
        }
        assert_eq!(plot_help("dx"), None);
    }
}
