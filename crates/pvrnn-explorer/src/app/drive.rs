//! The Drive window: the open network drives caresim's robot live (`pvrnn_drive`), under
//! the shown condition (what it observes, H, iterations, rate, noise seed). The episode is
//! stepped where runs are computed (`crate::driving`): on the site in the web worker, so
//! the page keeps drawing; in the desktop app between frames, a share of each. The window
//! shows what the cameras see, and the user pushes an arm or covers a camera while it
//! acts. While it acts, the episode so far is the open data's `drive in progress`
//! (`EPISODE_SO_FAR`), which the main panels show as it grows: latent traces, images and
//! errors follow the newest step unless the user moves the time cursor (runs under other
//! conditions, the contribution maps among them, wait for its end). A finished episode joins
//! the open data as a sequence named `drive <spec>` with the network's run, so every panel
//! shows it like a recording (its name holds the drive and the condition, all the episode
//! depends on, so one name is one episode), and the address holds the drive (`drive=`),
//! so a link replays the same episode (seeded). A panel type (`super::panel`).

use pvrnn_drive::spec::{parse_speed_limit, speed_limit_text};
use pvrnn_drive::{Controller, DriveSpec};

use super::panel::{Command, DriveCommand, PanelContext};
use super::*;
use crate::driving::{
    DriveEvent, DriveProgress, DriveRequest, EPISODE_SO_FAR, EpisodeSoFar, FinishedDrive,
    LIVE_PER_STEP, OCCLUSION_STEPS, PUSH_RADIANS,
};
use crate::state::drive_episode_name;

/// The share of a frame the episode may take when stepped between frames (at least one
/// step a frame).
const DRIVE_BUDGET: Duration = Duration::from_millis(35);

/// The Drive window (a panel type): its settings and the cameras last shown; the episode
/// itself is where runs are computed (`RunStore::drive`).
#[derive(Default)]
pub(super) struct DrivePanel {
    pub(super) open: bool,
    settings: Option<DriveSpec>,
    /// The cameras at the latest step (the step, the picture).
    picture: Option<(usize, TextureHandle)>,
    /// A drive from the address that could not start (not retried every frame).
    pub(super) refused: Option<String>,
    /// The steps of the episode so far the main panels show (0: none shown).
    shown_so_far: usize,
    /// What the view showed before the episode so far took it (sequence, time).
    before: Option<(Option<String>, usize)>,
}

impl std::fmt::Debug for DrivePanel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DrivePanel")
            .field("open", &self.open)
            .field("settings", &self.settings)
            .finish()
    }
}

impl DrivePanel {
    /// The window: settings, the drive button, and while driving the cameras, progress and
    /// the perturbations.
    pub(super) fn ui(&mut self, ctx: &egui::Context, panels: &PanelContext<'_>) -> Vec<Command> {
        let mut commands = Vec::new();
        let Some(bundle) = panels.bundle else {
            return commands;
        };
        let mut open = self.open;
        egui::Window::new("Drive the robot")
            .open(&mut open)
            .default_width(460.0)
            // Sized to what it shows: the settings, or the episode with its plots.
            .resizable(false)
            .show(ctx, |ui| {
                if let Err(why) = pvrnn_drive::check_model(&bundle.model.config) {
                    ui.label(format!("This network cannot drive caresim's robot: {why}"));
                    return;
                }
                ui.label(
                    RichText::new(
                        "The network drives caresim's robot: each step what the cameras and \
                         sensors return updates it by online inference (under the condition \
                         shown in the top bar), and its predicted joint angles move the arms. \
                         The finished episode opens like any recording.",
                    )
                    .small(),
                );
                match panels.store.drive_progress() {
                    Some(progress) => running_ui(&mut self.picture, ui, &progress, &mut commands),
                    None => self.settings_ui(ui, &mut commands),
                }
            });
        if open != self.open {
            commands.push(Command::ShowDrive(open));
        }
        commands
    }

    fn settings_ui(&mut self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        let spec = self.settings.get_or_insert_with(|| {
            DriveSpec::new(caresim::Task::Repositioning, 650, 0, caresim::Revision::R1)
        });
        egui::Grid::new("drive settings").num_columns(2).show(ui, |ui| {
            ui.label("task");
            egui::ComboBox::from_id_salt("drive task")
                .selected_text(spec.task.name())
                .show_ui(ui, |ui| {
                    for task in caresim::Task::ALL {
                        ui.selectable_value(&mut spec.task, task, task.name());
                    }
                });
            ui.end_row();
            ui.label("bed height (mm)")
                .on_hover_text("learned: 590, 650, 710; any other is a height the network never saw");
            ui.add(egui::DragValue::new(&mut spec.bed_height_mm).range(300..=1200));
            ui.end_row();
            ui.label("trial seed")
                .on_hover_text("the test trial of caresim's dataset with this seed");
            ui.add(egui::DragValue::new(&mut spec.seed).range(0..=u32::MAX as u64));
            ui.end_row();
            ui.label("caresim revision")
                .on_hover_text("the edition the network learned: 1 for the shipped model");
            egui::ComboBox::from_id_salt("drive revision")
                .selected_text(spec.revision.number().to_string())
                .show_ui(ui, |ui| {
                    for r in caresim::Revision::ALL {
                        ui.selectable_value(&mut spec.revision, r, r.number().to_string());
                    }
                });
            ui.end_row();
            ui.label("who drives");
            egui::ComboBox::from_id_salt("drive controller")
                .selected_text(spec.controller.name())
                .show_ui(ui, |ui| {
                    for c in Controller::ALL {
                        ui.selectable_value(&mut spec.controller, c, c.name());
                    }
                })
                .response
                .on_hover_text(
                    "network: closed loop; prior: the network's own prediction with nothing fed back; \
                     mean-trajectory: the learning trials' mean joint angles, no network",
                );
            ui.end_row();
            ui.label("joint speed");
            let mut limit = speed_limit_text(spec.speed_limit);
            egui::ComboBox::from_id_salt("drive speed")
                .selected_text(limit)
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut limit, "scripted", "scripted (2 rad a step)");
                    ui.selectable_value(&mut limit, "panda", "panda (a Franka Panda's)");
                });
            spec.speed_limit = parse_speed_limit(limit).unwrap_or_default();
            ui.end_row();
            ui.label("sensor noise (x a recording's)");
            ui.add(
                egui::DragValue::new(&mut spec.perturbations.sensor_noise)
                    .range(0.0..=10.0)
                    .speed(0.1),
            );
            ui.end_row();
        });
        if ui
            .button("Start driving")
            .on_hover_text("reset the trial and let the chosen controller act")
            .clicked()
        {
            commands.push(Command::Drive(DriveCommand::Start(Box::new(spec.clone()))));
        }
    }
}

/// The episode in progress: progress, the cameras, the perturbations.
fn running_ui(
    picture: &mut Option<(usize, TextureHandle)>,
    ui: &mut egui::Ui,
    drive: &DriveProgress,
    commands: &mut Vec<Command>,
) {
    {
        let (done, len) = (drive.steps_done, drive.len);
        ui.label(format!(
            "{} driven by the {} controller: step {done} of {len}",
            drive.trial,
            drive.spec.controller.name()
        ));
        ui.add(egui::ProgressBar::new(done as f32 / len.max(1) as f32).desired_width(420.0));
        if let Some((step, images)) = &drive.cameras {
            let stale = picture.as_ref().is_none_or(|(t, _)| t != step);
            if stale {
                let image = cameras_side_by_side(images);
                let texture =
                    ui.ctx()
                        .load_texture("drive cameras", image, TextureOptions::NEAREST);
                *picture = Some((*step, texture));
            }
        }
        if let Some((_, texture)) = picture.as_ref() {
            ui.add(egui::Image::new(texture).fit_to_exact_size(egui::vec2(384.0, 192.0)));
            ui.label(RichText::new("left and right camera, as the network is given them").small());
        }
        ui.horizontal_wrapped(|ui| {
            for (arm, name) in [(0, "push the left arm"), (1, "push the right arm")] {
                if ui
                    .button(name)
                    .on_hover_text(format!(
                        "every joint of the arm turned {PUSH_RADIANS} rad in the next step"
                    ))
                    .clicked()
                {
                    commands.push(Command::Drive(DriveCommand::Push(arm)));
                }
            }
            for (camera, name) in [(0, "cover the left camera"), (1, "cover the right camera")] {
                if ui
                    .button(name)
                    .on_hover_text(format!("mid-grey for {OCCLUSION_STEPS} steps"))
                    .clicked()
                {
                    commands.push(Command::Drive(DriveCommand::Occlude(camera)));
                }
            }
            if drive.spec.controller == Controller::Network {
                let observed = drive.condition.vision_levels as usize;
                let dropped = drive.spec.perturbations.vision_drop.map(|v| v.levels);
                for (levels, name, what) in [
                    (1, "see 16x16 only", "only the lowest vision resolution"),
                    (0, "see nothing", "no vision"),
                ] {
                    if levels < dropped.unwrap_or(observed)
                        && ui
                            .button(name)
                            .on_hover_text(format!(
                                "from the next step on the network observes {what} (the cameras still record)"
                            ))
                            .clicked()
                    {
                        commands.push(Command::Drive(DriveCommand::DropVision(levels)));
                    }
                }
            }
            if ui
                .button("stop")
                .on_hover_text("abandon the episode")
                .clicked()
            {
                commands.push(Command::Drive(DriveCommand::Stop));
            }
        });
        live_plots(ui, drive);
    }
}

/// How the network copes, step by step: its errors against what the robot sensed and each
/// module's KL, with the perturbations marked.
fn live_plots(ui: &mut egui::Ui, drive: &DriveProgress) {
    let steps = drive.live.len() / LIVE_PER_STEP;
    if steps == 0 {
        return;
    }
    // Errors span decades (a push lifts proprioception's a thousandfold): log10.
    let series = |k: usize, log: bool| -> PlotPoints<'static> {
        (0..steps)
            .map(|t| {
                let v = drive.live[t * LIVE_PER_STEP + k] as f64;
                [t as f64, if log { v.max(1e-12).log10() } else { v }]
            })
            .collect()
    };
    let p = &drive.spec.perturbations;
    let marks: Vec<(String, usize)> = [
        p.push.map(|x| ("push".to_string(), x.step)),
        p.occlusion.map(|x| ("camera covered".to_string(), x.from)),
        p.vision_drop
            .map(|x| (format!("vision {} levels", x.levels), x.from)),
    ]
    .into_iter()
    .flatten()
    .collect();
    let plot = |ui: &mut egui::Ui, id: &str, title: &str, lines: Vec<Line<'static>>| {
        ui.label(RichText::new(title).small());
        Plot::new(id.to_string())
            .height(110.0)
            .width(420.0)
            .legend(Legend::default().position(egui_plot::Corner::RightTop))
            .include_x(0.0)
            .include_x(drive.len.max(steps) as f64)
            .allow_drag(false)
            .allow_zoom(false)
            .allow_scroll(false)
            .show(ui, |pu| {
                for l in lines {
                    pu.line(l);
                }
                // Unnamed: kept out of the legend (said under the plots).
                for (_, at) in &marks {
                    pu.vline(
                        VLine::new("", *at as f64)
                            .color(Color32::DARK_GRAY)
                            .width(1.5),
                    );
                }
            });
    };
    let [(vision, vision_colour), (proprio, proprio_colour)] = super::traces::ERROR_COLOURS;
    plot(
        ui,
        "drive errors",
        "log10 of the network's error against what the robot sensed (mean squared, model units)",
        vec![
            Line::new(vision, series(0, true)).color(vision_colour),
            Line::new(proprio, series(1, true)).color(proprio_colour),
        ],
    );
    let modules = [
        "executive",
        "associative",
        "exteroceptive",
        "proprioceptive",
    ];
    plot(
        ui,
        "drive kl",
        "each module's KL in the inference window",
        modules
            .iter()
            .enumerate()
            .map(|(m, name)| Line::new(*name, series(2 + m, false)).color(palette::unit_colour(m)))
            .collect(),
    );
    if !marks.is_empty() {
        let said: Vec<String> = marks
            .iter()
            .map(|(name, at)| format!("{name} at step {at}"))
            .collect();
        ui.label(RichText::new(format!("grey lines: {}", said.join(", "))).small());
    }
}

/// Both 64x64 cameras of a step, side by side.
fn cameras_side_by_side(images: &[u8]) -> egui::ColorImage {
    let s = caresim::IMAGE_SIZE;
    let mut rgb = vec![0u8; 2 * s * s * 3];
    for cam in 0..2 {
        for y in 0..s {
            let from = &images[(cam * s * s + y * s) * 3..(cam * s * s + (y + 1) * s) * 3];
            let to = (y * 2 * s + cam * s) * 3;
            rgb[to..to + s * 3].copy_from_slice(from);
        }
    }
    egui::ColorImage::from_rgb([2 * s, s], &rgb)
}

impl ExplorerApp {
    /// Whether an episode is being driven.
    pub fn driving(&self) -> bool {
        self.store.drive_progress().is_some()
    }

    /// Applies the Drive window's command.
    pub(super) fn drive_command(&mut self, command: DriveCommand) {
        let request = match command {
            DriveCommand::Start(spec) => {
                if let Err(e) = self.start_drive(*spec) {
                    self.status = Status::Error(format!("drive: {e}"));
                }
                return;
            }
            DriveCommand::Stop => {
                self.status = Status::Info("the episode was abandoned".into());
                self.forget_so_far(true);
                DriveRequest::Stop
            }
            DriveCommand::Push(arm) => DriveRequest::Push(arm),
            DriveCommand::Occlude(camera) => DriveRequest::Occlude(camera),
            DriveCommand::DropVision(levels) => DriveRequest::DropVision(levels),
        };
        let Some(model) = self.bundle.as_ref().map(|b| b.model.clone()) else {
            return;
        };
        if let Err(e) = self.store.drive(&model, request) {
            self.status = Status::Error(format!("drive: {e}"));
        }
    }

    /// Resets the trial with the open network under the shown condition.
    pub(super) fn start_drive(&mut self, spec: DriveSpec) -> Result<(), String> {
        let (Some(bundle), Some(condition)) = (&self.bundle, self.condition()) else {
            return Err("no network is open".into());
        };
        // Said at once, before the episode goes where it is stepped.
        let trial = spec.trial().map_err(|e| e.to_string())?;
        if spec.controller.uses_network() {
            pvrnn_drive::check_model(&bundle.model.config).map_err(|e| e.to_string())?;
        }
        let model = bundle.model.clone();
        let controller = spec.controller;
        // The address holds the drive being driven, not an earlier episode's.
        if self.view.drive.as_deref() != Some(spec.to_text().as_str()) {
            self.view.drive = None;
        }
        self.store.drive(
            &model,
            DriveRequest::Start {
                spec: Box::new(spec),
                condition,
            },
        )?;
        self.status = Status::Info(format!(
            "driving {} ({} controller)",
            trial.name(),
            controller.name()
        ));
        self.drive.open = true;
        Ok(())
    }

    /// Steps the episode in progress for a share of the frame (or takes in what the worker
    /// sent); keeps it when it is over. Whether to draw again at once.
    pub(super) fn advance_drive(&mut self) -> bool {
        let events = self.store.poll_drive(DRIVE_BUDGET);
        // Stepped between frames (the page without a worker, the desktop app): draw on.
        let mut again = !events.is_empty() || (self.store.drives_here() && self.driving());
        for event in events {
            match event {
                DriveEvent::Finished(finished) => {
                    self.forget_so_far(false);
                    self.keep_episode(*finished);
                }
                DriveEvent::Failed(e) => {
                    self.forget_so_far(true);
                    self.status = Status::Error(format!("the drive stopped: {e}"));
                    // A drive from the address is not started again every frame.
                    self.drive.refused = self.view.drive.clone();
                }
            }
        }
        let so_far = self
            .store
            .drive_progress()
            .and_then(|p| Some((p.so_far?, p.condition)));
        if let Some((so_far, condition)) = so_far
            && so_far.steps() != self.drive.shown_so_far
        {
            self.show_so_far(&so_far, condition);
            again = true;
        }
        again
    }

    /// Shows the episode so far in the main panels, as [`EPISODE_SO_FAR`]: its recording
    /// joins the open data, the network's run the store. The first steps take the view;
    /// the time cursor follows the newest step unless the user moved it back.
    fn show_so_far(&mut self, so_far: &EpisodeSoFar, condition: Condition) {
        let Some(bundle) = self.bundle.as_mut() else {
            return;
        };
        let mut sequence = so_far.sequence.clone();
        sequence.info.name = EPISODE_SO_FAR.into();
        sequence.info.file = format!("{}.safetensors", pvrnn_dataset::file_stem(EPISODE_SO_FAR));
        bundle.replace_sequence(sequence);
        self.store.forget_sequence(EPISODE_SO_FAR);
        if let Some(run) = &so_far.run {
            let trace = RunTrace::from_run(run, &bundle.model.config, bundle.loaded.as_ref());
            let key = RunKey::new(EPISODE_SO_FAR, condition.canonical());
            self.store.insert_complete(key, trace);
        }
        let newest = so_far.steps().saturating_sub(1);
        if self.drive.shown_so_far == 0 {
            // The first steps take the view; a user who then looks elsewhere stays there.
            self.drive.before = Some((self.view.sequence.take(), self.view.t));
            self.view.sequence = Some(EPISODE_SO_FAR.into());
            self.view.condition = Some(condition);
            self.view.branch = None;
            self.view.t = newest;
        } else if self.view.sequence.as_deref() == Some(EPISODE_SO_FAR)
            && self.view.t + 1 >= self.drive.shown_so_far
        {
            self.view.t = newest;
        }
        self.drive.shown_so_far = so_far.steps();
    }

    /// Takes the episode so far out of the open data (its end, or the drive stopped); with
    /// `restore` the view goes back to what it showed before it.
    fn forget_so_far(&mut self, restore: bool) {
        self.drive.shown_so_far = 0;
        let before = self.drive.before.take();
        let Some(bundle) = self.bundle.as_mut() else {
            return;
        };
        bundle.remove_sequence(EPISODE_SO_FAR);
        self.store.forget_sequence(EPISODE_SO_FAR);
        if restore && self.view.sequence.as_deref() == Some(EPISODE_SO_FAR) {
            let (sequence, t) = before.unwrap_or_default();
            self.view.sequence = sequence;
            self.view.t = t;
        }
    }

    /// Adds a finished episode to the open data (replacing one of the same drive) with the
    /// network's run, and shows it.
    fn keep_episode(&mut self, episode: FinishedDrive) {
        let Some(bundle) = self.bundle.as_mut() else {
            return;
        };
        let condition = episode.condition;
        let text = episode.spec.to_text();
        let name = drive_episode_name(&text, &condition);
        let mut sequence = episode.sequence;
        sequence.info.name = name.clone();
        sequence.info.file = format!("{}.safetensors", pvrnn_dataset::file_stem(&name));
        bundle.replace_sequence(sequence);
        let key = RunKey::new(name.clone(), condition.canonical());
        if let Some(run) = &episode.run {
            let trace = RunTrace::from_run(run, &bundle.model.config, bundle.loaded.as_ref());
            self.store.insert_complete(key, trace);
        }
        self.view.sequence = Some(name);
        self.view.t = 0;
        self.view.condition = Some(condition);
        self.view.drive = Some(text);
        self.status = Status::Info(format!(
            "{} (the demonstration: {})",
            episode.summary,
            if episode.demonstration_success {
                "success"
            } else {
                "failure"
            }
        ));
    }

    /// Whether the address names a drive that is neither open, nor being driven, nor
    /// refused: one to start.
    pub(super) fn drive_pending(&self) -> bool {
        let Some(text) = self.view.drive.as_deref() else {
            return false;
        };
        let (Some(bundle), Some(condition)) = (&self.bundle, self.condition()) else {
            return false;
        };
        let open = bundle
            .dataset
            .by_name(&drive_episode_name(text, &condition))
            .is_some();
        let running = self
            .store
            .drive_progress()
            .is_some_and(|d| d.spec.to_text() == text);
        !open && !running && self.drive.refused.as_deref() != Some(text)
    }

    /// Starts the drive the address names, when its episode is not open yet.
    pub(super) fn follow_drive_address(&mut self) {
        if !self.drive_pending() {
            return;
        }
        let Some(text) = self.view.drive.clone() else {
            return;
        };
        let started = DriveSpec::parse_text(&text)
            .map_err(|e| e.to_string())
            .and_then(|spec| self.start_drive(spec));
        if let Err(e) = started {
            self.status = Status::Error(format!("drive in the address: {e}"));
            self.drive.refused = Some(text);
        }
    }
}
