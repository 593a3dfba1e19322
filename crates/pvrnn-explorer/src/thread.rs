//! Live inference on a background thread: the desktop's counterpart of the web worker. The
//! window keeps drawing at full rate while an [`Engine`] computes beside it, instead of
//! sharing each frame's budget with it. Commands go in and events come out through
//! channels; events carry the generation of the model they belong to, so results still in
//! flight when a new model arrives are dropped.

use std::sync::Arc;
use std::sync::mpsc::{self, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;

use pvrnn_core::backend::Backend;
use pvrnn_core::{Model, Observations};
use web_time::Duration;

use crate::condition::RunKey;
use crate::driving::{DriveEvent, DriveProgress, DriveRequest, LocalDrive};
use crate::engine::{Engine, Event};
use crate::executor::Executor;

/// Computing time between looks at the command channel.
const TICK: Duration = Duration::from_millis(30);

enum Command {
    Model(u64, Arc<Model<f32>>),
    Observations(u64, String, Arc<Observations<f32>>),
    Run(u64, RunKey),
}

/// The window's handle on the inference thread.
pub struct ThreadClient {
    commands: Sender<Command>,
    events: Receiver<(u64, Event)>,
    generation: u64,
    thread: Option<JoinHandle<()>>,
    /// The Drive window's episode, stepped by the window between frames: its steps are
    /// short (about 10 ms), and the window shows each.
    drive: LocalDrive,
}

impl std::fmt::Debug for ThreadClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ThreadClient")
            .field("generation", &self.generation)
            .finish()
    }
}

impl ThreadClient {
    /// Starts the thread, computing on `backend` (`None`: the CPU); `repaint` is called
    /// when results arrive.
    pub fn spawn(
        repaint: impl Fn() + Send + 'static,
        backend: Option<Arc<dyn Backend<f32>>>,
    ) -> Result<Self, String> {
        let (commands, command_rx) = mpsc::channel();
        let (event_tx, events) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("pvrnn-inference".into())
            .spawn(move || {
                let engine = backend.map(Engine::on).unwrap_or_default();
                serve(engine, &command_rx, &event_tx, &repaint)
            })
            .map_err(|e| format!("cannot start the inference thread: {e}"))?;
        Ok(Self {
            commands,
            events,
            generation: 0,
            thread: Some(thread),
            drive: LocalDrive::default(),
        })
    }

    fn send(&self, command: Command) {
        // A stopped thread shows in `failure`.
        let _ = self.commands.send(command);
    }
}

impl Executor for ThreadClient {
    fn set_model(&mut self, model: &Arc<Model<f32>>) {
        self.generation += 1;
        self.send(Command::Model(self.generation, model.clone()));
    }

    fn add_observations(&mut self, name: &str, observations: Arc<Observations<f32>>) {
        self.send(Command::Observations(
            self.generation,
            name.to_string(),
            observations,
        ));
    }

    fn run(&mut self, key: &RunKey) {
        self.send(Command::Run(self.generation, key.clone()));
    }

    /// The events of the current model that arrived since the last call.
    fn poll(&mut self, _budget: Duration) -> Vec<Event> {
        let mut out = Vec::new();
        while let Ok((generation, event)) = self.events.try_recv() {
            if generation == self.generation {
                out.push(event);
            }
        }
        out
    }

    /// Why the thread cannot be used, once it stopped (a panic in inference).
    fn broken(&mut self) -> Option<String> {
        if !self.thread.as_ref().is_some_and(JoinHandle::is_finished) {
            return None;
        }
        let why = match self.thread.take().map(JoinHandle::join) {
            Some(Err(panic)) => panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic".into()),
            _ => "it stopped".into(),
        };
        Some(format!("the inference thread stopped: {why}"))
    }

    fn drive(&mut self, model: &Arc<Model<f32>>, request: DriveRequest) -> Result<(), String> {
        self.drive.request(Some(model), request)
    }

    fn drive_progress(&self) -> Option<DriveProgress> {
        self.drive.progress()
    }

    fn poll_drive(&mut self, budget: Duration) -> Vec<DriveEvent> {
        self.drive.step_for(budget).into_iter().collect()
    }
}

impl Drop for ThreadClient {
    fn drop(&mut self) {
        // Closing the command channel ends the thread after its current tick.
        let (closed, _) = mpsc::channel();
        self.commands = closed;
    }
}

/// The thread: waits for commands while idle, computes in ticks while a run is going.
fn serve(
    mut engine: Engine,
    commands: &Receiver<Command>,
    events: &Sender<(u64, Event)>,
    repaint: &dyn Fn(),
) {
    let mut generation = 0;
    loop {
        let mut next = if engine.running().is_none() {
            match commands.recv() {
                Ok(c) => Some(c),
                Err(_) => return,
            }
        } else {
            None
        };
        loop {
            let command = match next.take() {
                Some(c) => c,
                None => match commands.try_recv() {
                    Ok(c) => c,
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => return,
                },
            };
            match command {
                Command::Model(g, model) => {
                    engine.set_model(model);
                    generation = g;
                }
                // Meant for a model already replaced.
                Command::Observations(g, _, _) | Command::Run(g, _) if g != generation => {}
                Command::Observations(_, name, obs) => engine.add_observations(name, obs),
                Command::Run(_, key) => engine.run(key),
            }
        }
        let out = engine.work(TICK);
        if !out.is_empty() {
            for event in out {
                if events.send((generation, event)).is_err() {
                    return;
                }
            }
            repaint();
        }
    }
}
