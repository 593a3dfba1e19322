//! Panels as types (the pattern of rerun's `re_viewer_context`): a panel keeps its own
//! state, reads what the app shows through a [`PanelContext`], and asks for changes with
//! [`Command`]s that the app applies once the frame's panels are drawn, so the app is the
//! wiring between them. Types so far: the findings window
//! (`findings_panel::FindingsPanel`), the time bar (`time_panel::TimePanel`), the tour
//! (`tour::Tour`), the branch (`branch::BranchControls`), the second network
//! (`second::SecondNetwork`), the contributions over time
//! (`contributions::ContributionsOverTime`), the latent traces (`traces::Traces`), the
//! images (`images_panel::ImageCache`: the logic reads the pictures out, the panel draws
//! them), the top bar (`controls::Controls`), the comparison
//! (`compare::CompareCache`) and the Drive window (`drive::DrivePanel`). What is left on the app is wiring: reading files and the
//! address, asking for runs, reading pictures out, applying commands.

use super::*;

/// What a panel reads of the app for one frame.
pub(super) struct PanelContext<'a> {
    pub(super) bundle: Option<&'a Bundle>,
    pub(super) view: &'a ViewState,
    /// The open network's runs.
    pub(super) store: &'a RunStore,
    /// The shown run's key (a sequence and a condition are shown).
    pub(super) key: Option<RunKey>,
    /// Steps of the shown run computed so far.
    pub(super) computed: usize,
    /// Whether a second network is open beside the first.
    pub(super) second_open: bool,
}

impl PanelContext<'_> {
    /// The shown sequence, if the open network's data has it.
    pub(super) fn sequence(&self) -> Option<&pvrnn_dataset::Sequence> {
        let name = self.view.sequence.as_ref()?;
        self.bundle?.dataset.by_name(name)
    }

    /// The shown run, as computed so far.
    pub(super) fn run(&self) -> Option<&Entry> {
        self.store.get(self.key.as_ref()?)
    }

    /// The shown run's branch, when the view has one.
    pub(super) fn branch_key(&self) -> Option<RunKey> {
        let b = self.view.branch?;
        Some(self.key.as_ref()?.branched(b.at, b.condition))
    }

    /// The shown sequence's length (0 without one).
    pub(super) fn sequence_len(&self) -> usize {
        self.sequence().map_or(0, |s| s.len())
    }
}

/// What a panel asks of the app.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Command {
    /// Move the cursor to step `t` (the app keeps it within the sequence).
    Seek(usize),
    /// Start or stop playback.
    Play(bool),
    /// Playback speed, steps per second.
    Speed(f32),
    /// Open a view given as an address (a finding's link).
    OpenAddress(&'static str),
    /// The tour was finished or skipped: remember it.
    TourSeen,
    /// Set (or remove) the branch of the shown run.
    Branch(Option<crate::state::BranchView>),
    /// Show the branch's latent traces instead of its run's.
    BranchTraces(bool),
    /// Close the second network (and take it out of the address).
    CloseSecond,
    /// Trials the contributions over time average.
    MapTrials(u8),
    /// The view as the top bar edited it.
    SetView(Box<ViewState>),
    /// Branch the shown run at the cursor.
    BranchHere,
    /// Open or close the "About this model" window.
    ShowAbout(bool),
    /// Open or close the findings window.
    ShowFindings(bool),
    /// Start the tour from its first stop.
    StartTour,
    /// Export the shown run's traces as CSV.
    ExportCsv,
    /// Save a picture of the window.
    SavePicture,
    /// Open files or a folder (a file dialog, or the browser's picker), as the network or
    /// the second one.
    Open { folder: bool, second: bool },
    /// Close the comparison window.
    CloseCompare,
    /// Open or close the Drive window.
    ShowDrive(bool),
    /// What the Drive window asks (start, stop, push, cover a camera).
    Drive(DriveCommand),
}

/// What the Drive window asks of the app.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum DriveCommand {
    Start(Box<pvrnn_drive::DriveSpec>),
    Stop,
    /// Push this arm now.
    Push(usize),
    /// Cover this camera from now on.
    Occlude(usize),
    /// Observe only this many of the lowest vision resolutions from now on.
    DropVision(usize),
}

impl ExplorerApp {
    /// The context the panels read this frame.
    pub(super) fn panel_context(&self) -> PanelContext<'_> {
        PanelContext {
            bundle: self.bundle.as_ref(),
            view: &self.view,
            store: &self.store,
            key: self.current_key(),
            computed: self.current_run().map_or(0, |e| e.trace.steps),
            second_open: self.second.is_some(),
        }
    }

    /// Applies the panels' commands, in the order they were given.
    pub(super) fn apply(&mut self, commands: Vec<Command>, egui_ctx: &egui::Context) {
        for command in commands {
            match command {
                Command::Seek(t) => self.view.t = t.min(self.sequence_len().saturating_sub(1)),
                Command::Play(on) => self.view.playing = on,
                Command::Speed(speed) => self.view.speed = speed,
                Command::OpenAddress(address) => self.apply_hash(address),
                Command::TourSeen => self.mark_tour_seen(),
                Command::Branch(branch) => self.view.branch = branch,
                Command::BranchTraces(on) => self.view.branch_traces = on,
                Command::MapTrials(n) => self.view.map_trials = n,
                Command::SetView(view) => self.view = *view,
                Command::BranchHere => self.branch_here(),
                Command::ShowAbout(open) => self.show_about = open,
                Command::ShowFindings(open) => self.findings.open = open,
                Command::StartTour => self.start_tour(),
                Command::ExportCsv => self.export_csv(),
                Command::SavePicture => self.request_picture(egui_ctx),
                Command::Open { folder, second } => self.open(folder, second),
                Command::CloseCompare => self.view.compare = None,
                Command::ShowDrive(open) => self.drive.open = open,
                Command::Drive(command) => self.drive_command(command),
                Command::CloseSecond => {
                    self.second = None;
                    self.view.second = None;
                }
            }
        }
    }

    /// Opens files or a folder as the network (or as the second one, `second`).
    fn open(&mut self, folder: bool, second: bool) {
        #[cfg(target_arch = "wasm32")]
        {
            let picked = if second {
                self.pick_second_network(folder).map(|_| ())
            } else {
                self.web.pick_files(folder).map(|_| ())
            };
            if let Err(e) = picked {
                self.status = Status::Error(format!("cannot open the file picker: {e}"));
            }
        }
        #[cfg(not(target_arch = "wasm32"))]
        {
            self.opening_second = second;
            self.open_with_dialog(folder);
        }
    }
}
