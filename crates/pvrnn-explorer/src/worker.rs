//! Live inference in a Web Worker, so the page keeps drawing at full rate while a run is
//! computed beside it. The worker is the same wasm module as the page (`web/worker.js` loads
//! it and calls [`run_worker`]); it hosts an [`Engine`] and talks in plain messages:
//!
//! page → worker: `model {generation, bytes}`, `observations {generation, name, steps,
//! extero, proprio}`, `run {generation, key}`, `drive {generation, id, action, ...}` (the
//! Drive window's episode `id`: `start` with the drive's text and the condition as JSON,
//! `push` an arm, `occlude` a camera, `drop-vision` to fewer levels, `stop`);
//! worker → page: `ready {compute}` (where runs compute: WebGPU or the CPU), `step {generation, key, data}`, `done {generation, key, steps,
//! busy_ms, wall_ms}`, `failed {generation, key, message}`, `drive-progress {generation,
//! id, spec, condition, trial, done, len, step, cameras, live}` after each tick of an
//! episode, with the episode so far (`so-far-header`, `so-far-sequence`, `so-far-runs`:
//! the bytes of a `drive-done`) when it grew since the last one sent,
//! `drive-done {generation, id, spec, condition, summary, demonstration, info, sequence,
//! runs}` when it ends (the episode's sequence file as the dataset writes it, the network's
//! run as `pvrnn infer` writes it, in f32), `drive-failed {generation, id, message}`, and
//! `fatal {generation, message}` when the worker cannot go on (a command it cannot read, a
//! message it cannot send): the page then computes in itself, and says why.
//!
//! One typed protocol, one encoder and decoder per direction: [`Command`] and [`Reply`].
//! Keys are [`RunKey`]s as JSON, steps are [`CompactStep::to_f32s`]. Messages carry the
//! generation of the model they belong to, so results that were in flight when a new model
//! arrived are dropped; drive messages also carry their episode's id, so the progress of an
//! episode already stopped is dropped.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use eframe::wasm_bindgen::{self, JsCast, JsValue, closure::Closure, prelude::wasm_bindgen};
use eframe::web_sys;
use js_sys::{Array, Float32Array, Object, Reflect, Uint8Array};
use pvrnn_core::config::ModelConfig;
use pvrnn_core::{Modality, Model, Observations, Tensor, io};
use pvrnn_drive::DriveSpec;
use web_time::Duration;

use crate::condition::{Condition, RunKey};
use crate::driving::{
    DriveEvent, DriveProgress, DriveRequest, EpisodeParts, EpisodeSoFar, FinishedDrive, LocalDrive,
};
use crate::engine::{CompactStep, Engine, Event, Finished, StepLayout};
use crate::executor::Executor;

/// Computing time per worker tick; messages from the page are handled between ticks.
const TICK: Duration = Duration::from_millis(30);

use crate::runs::REPAINT_EVERY;

fn message(kind: &str, generation: u32, fields: &[(&str, JsValue)]) -> Object {
    let m = Object::new();
    let set = |k: &str, v: &JsValue| {
        let _ = Reflect::set(&m, &k.into(), v);
    };
    set("kind", &kind.into());
    set("generation", &generation.into());
    for (k, v) in fields {
        set(k, v);
    }
    m
}

fn field(m: &JsValue, name: &str) -> JsValue {
    Reflect::get(m, &name.into()).unwrap_or(JsValue::UNDEFINED)
}

fn string_field(m: &JsValue, name: &str) -> Result<String, String> {
    field(m, name)
        .as_string()
        .ok_or_else(|| format!("a worker message has no text `{name}`"))
}

fn number_field(m: &JsValue, name: &str) -> Result<f64, String> {
    field(m, name)
        .as_f64()
        .ok_or_else(|| format!("a worker message has no number `{name}`"))
}

fn floats(values: &[f32]) -> Float32Array {
    Float32Array::from(values)
}

/// Encodes a key as the messages carry it.
pub fn key_to_text(key: &RunKey) -> String {
    serde_json::to_string(key).expect("a key is plain data")
}

pub fn key_from_text(text: &str) -> Result<RunKey, String> {
    serde_json::from_str(text).map_err(|e| format!("a worker message has a bad run key: {e}"))
}

fn bytes_field(m: &JsValue, name: &str) -> Result<Vec<u8>, String> {
    Ok(field(m, name)
        .dyn_into::<Uint8Array>()
        .map_err(|_| format!("a worker message has no `{name}` bytes"))?
        .to_vec())
}

/// An episode's parts as a message's fields under `names` (header, sequence, runs); the
/// bytes are transferred, not copied.
fn episode_fields(
    fields: &mut Vec<(&'static str, JsValue)>,
    transfer: &Array,
    parts: EpisodeParts,
    [header, sequence, runs]: [&'static str; 3],
) {
    fields.push((header, parts.header.into()));
    for (name, bytes) in [(sequence, Some(parts.sequence)), (runs, parts.run)] {
        if let Some(bytes) = bytes {
            let bytes = Uint8Array::from(&bytes[..]);
            transfer.push(&bytes.buffer());
            fields.push((name, bytes.into()));
        }
    }
}

/// Reads [`episode_fields`] back.
fn episode_parts(m: &JsValue, [header, sequence, runs]: [&str; 3]) -> Result<EpisodeParts, String> {
    Ok(EpisodeParts {
        header: string_field(m, header)?,
        sequence: bytes_field(m, sequence)?,
        run: match field(m, runs).is_undefined() {
            true => None,
            false => Some(bytes_field(m, runs)?),
        },
    })
}

fn spec_field(m: &JsValue) -> Result<DriveSpec, String> {
    DriveSpec::parse_text(&string_field(m, "spec")?).map_err(|e| e.to_string())
}

fn condition_field(m: &JsValue) -> Result<Condition, String> {
    serde_json::from_str(&string_field(m, "condition")?)
        .map_err(|e| format!("a worker message has a bad condition: {e}"))
}

fn condition_text(c: &Condition) -> String {
    serde_json::to_string(c).expect("a condition is plain data")
}

/// Page → worker.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// A new model (its safetensors bytes); `generation` tags everything that follows.
    Model { generation: u32, bytes: Vec<u8> },
    /// A sequence's inputs.
    Observations {
        generation: u32,
        name: String,
        steps: usize,
        extero: Vec<f32>,
        proprio: Vec<f32>,
    },
    /// Compute this run (pausing the one in progress).
    Run { generation: u32, key: RunKey },
    /// The Drive window's request for episode `id` (a start begins episode `id`).
    Drive {
        generation: u32,
        id: u32,
        request: DriveRequest,
    },
}

/// Worker → page.
#[derive(Debug, PartialEq)]
pub enum Reply {
    /// The worker's module is loaded and its compute chosen: commands can come.
    Ready { compute: String },
    /// What the engine did, for the model of `generation`.
    Event { generation: u32, event: Event },
    /// The worker cannot go on (a command it cannot read, a result it cannot send).
    Fatal { generation: u32, message: String },
    /// Episode `id` so far.
    DriveProgress {
        generation: u32,
        id: u32,
        progress: Box<DriveProgress>,
    },
    /// Episode `id` is over.
    DriveEnded {
        generation: u32,
        id: u32,
        event: DriveEvent,
    },
}

impl Command {
    fn generation(&self) -> u32 {
        match self {
            Self::Model { generation, .. }
            | Self::Observations { generation, .. }
            | Self::Run { generation, .. }
            | Self::Drive { generation, .. } => *generation,
        }
    }

    /// The message, and the buffers to transfer with it.
    pub fn encode(&self) -> (Object, Array) {
        let transfer = Array::new();
        let m = match self {
            Self::Model { generation, bytes } => {
                let bytes = Uint8Array::from(&bytes[..]);
                transfer.push(&bytes.buffer());
                message("model", *generation, &[("bytes", bytes.into())])
            }
            Self::Observations {
                generation,
                name,
                steps,
                extero,
                proprio,
            } => {
                let (extero, proprio) = (floats(extero), floats(proprio));
                transfer.push(&extero.buffer());
                transfer.push(&proprio.buffer());
                message(
                    "observations",
                    *generation,
                    &[
                        ("name", name.into()),
                        ("steps", (*steps as f64).into()),
                        ("extero", extero.into()),
                        ("proprio", proprio.into()),
                    ],
                )
            }
            Self::Run { generation, key } => {
                message("run", *generation, &[("key", key_to_text(key).into())])
            }
            Self::Drive {
                generation,
                id,
                request,
            } => {
                let mut fields = vec![("id", JsValue::from(*id))];
                match request {
                    DriveRequest::Start { spec, condition } => {
                        fields.push(("action", "start".into()));
                        fields.push(("spec", spec.to_text().into()));
                        fields.push(("condition", condition_text(condition).into()));
                    }
                    DriveRequest::Push(arm) => {
                        fields.push(("action", "push".into()));
                        fields.push(("which", (*arm as f64).into()));
                    }
                    DriveRequest::Occlude(camera) => {
                        fields.push(("action", "occlude".into()));
                        fields.push(("which", (*camera as f64).into()));
                    }
                    DriveRequest::DropVision(levels) => {
                        fields.push(("action", "drop-vision".into()));
                        fields.push(("which", (*levels as f64).into()));
                    }
                    DriveRequest::Stop => fields.push(("action", "stop".into())),
                }
                message("drive", *generation, &fields)
            }
        };
        (m, transfer)
    }

    pub fn decode(m: &JsValue) -> Result<Self, String> {
        let generation = number_field(m, "generation")? as u32;
        let vector = |which: &str| -> Result<Vec<f32>, String> {
            Ok(field(m, which)
                .dyn_into::<Float32Array>()
                .map_err(|_| format!("a worker message has no `{which}` data"))?
                .to_vec())
        };
        match string_field(m, "kind")?.as_str() {
            "model" => Ok(Self::Model {
                generation,
                bytes: field(m, "bytes")
                    .dyn_into::<Uint8Array>()
                    .map_err(|_| "a model message has no bytes")?
                    .to_vec(),
            }),
            "observations" => Ok(Self::Observations {
                generation,
                name: string_field(m, "name")?,
                steps: number_field(m, "steps")? as usize,
                extero: vector("extero")?,
                proprio: vector("proprio")?,
            }),
            "run" => Ok(Self::Run {
                generation,
                key: key_from_text(&string_field(m, "key")?)?,
            }),
            "drive" => {
                let which = || number_field(m, "which").map(|v| v as usize);
                let request = match string_field(m, "action")?.as_str() {
                    "start" => DriveRequest::Start {
                        spec: Box::new(spec_field(m)?),
                        condition: condition_field(m)?,
                    },
                    "push" => DriveRequest::Push(which()?),
                    "occlude" => DriveRequest::Occlude(which()?),
                    "drop-vision" => DriveRequest::DropVision(which()?),
                    "stop" => DriveRequest::Stop,
                    other => return Err(format!("unknown drive action `{other}`")),
                };
                Ok(Self::Drive {
                    generation,
                    id: number_field(m, "id")? as u32,
                    request,
                })
            }
            other => Err(format!("unknown command `{other}`")),
        }
    }
}

impl Reply {
    /// The message, and the buffers to transfer with it; `config` is the model's (to write
    /// a finished episode's run). A finished episode that cannot be written is sent as a
    /// failed one, with the reason.
    pub fn encode_with(&self, config: Option<&ModelConfig>) -> (Object, Array) {
        let transfer = Array::new();
        let m = match self {
            Self::DriveProgress {
                generation,
                id,
                progress: p,
            } => {
                let mut fields = vec![
                    ("id", JsValue::from(*id)),
                    ("spec", p.spec.to_text().into()),
                    ("condition", condition_text(&p.condition).into()),
                    ("trial", p.trial.as_str().into()),
                    ("done", (p.steps_done as f64).into()),
                    ("len", (p.len as f64).into()),
                ];
                let live = floats(&p.live);
                transfer.push(&live.buffer());
                fields.push(("live", live.into()));
                if let Some((step, images)) = &p.cameras {
                    let images = Uint8Array::from(&images[..]);
                    transfer.push(&images.buffer());
                    fields.push(("step", (*step as f64).into()));
                    fields.push(("cameras", images.into()));
                }
                let so_far = match (&p.so_far, config) {
                    (None, _) => Ok(None),
                    (Some(s), Some(config)) => s.to_parts(config).map(Some),
                    (Some(_), None) => Err("the worker has no model".to_string()),
                };
                match so_far {
                    Ok(parts) => {
                        if let Some(parts) = parts {
                            let names = ["so-far-header", "so-far-sequence", "so-far-runs"];
                            episode_fields(&mut fields, &transfer, parts, names);
                        }
                        message("drive-progress", *generation, &fields)
                    }
                    Err(why) => message(
                        "drive-failed",
                        *generation,
                        &[
                            ("id", JsValue::from(*id)),
                            (
                                "message",
                                format!("the episode so far could not be sent: {why}").into(),
                            ),
                        ],
                    ),
                }
            }
            Self::DriveEnded {
                generation,
                id,
                event,
            } => {
                let finished = match (event, config) {
                    (DriveEvent::Finished(f), Some(config)) => f.to_parts(config),
                    (DriveEvent::Finished(_), None) => Err("the worker has no model".into()),
                    (DriveEvent::Failed(why), _) => Err(why.clone()),
                };
                match finished {
                    Ok(parts) => {
                        let mut fields = vec![("id", JsValue::from(*id))];
                        let names = ["header", "sequence", "runs"];
                        episode_fields(&mut fields, &transfer, parts, names);
                        message("drive-done", *generation, &fields)
                    }
                    Err(why) => message(
                        "drive-failed",
                        *generation,
                        &[("id", JsValue::from(*id)), ("message", why.into())],
                    ),
                }
            }
            Self::Ready { compute } => message("ready", 0, &[("compute", compute.into())]),
            Self::Fatal {
                generation,
                message: text,
            } => message("fatal", *generation, &[("message", text.into())]),
            Self::Event { generation, event } => match event {
                Event::Step(key, step) => {
                    let data = floats(&step.to_f32s());
                    transfer.push(&data.buffer());
                    message(
                        "step",
                        *generation,
                        &[("key", key_to_text(key).into()), ("data", data.into())],
                    )
                }
                Event::Done(f) => message(
                    "done",
                    *generation,
                    &[
                        ("key", key_to_text(&f.key).into()),
                        ("steps", (f.steps as f64).into()),
                        ("busy_ms", (f.busy.as_secs_f64() * 1e3).into()),
                        ("wall_ms", (f.wall.as_secs_f64() * 1e3).into()),
                        ("replayed", (f.replayed as f64).into()),
                    ],
                ),
                Event::Failed(key, e) => message(
                    "failed",
                    *generation,
                    &[("key", key_to_text(key).into()), ("message", e.into())],
                ),
            },
        };
        (m, transfer)
    }

    /// [`Self::encode_with`] for replies that need no model.
    pub fn encode(&self) -> (Object, Array) {
        self.encode_with(None)
    }

    /// Reads a reply; steps need the layout of the model they belong to, a finished
    /// episode's run the model's configuration.
    pub fn decode(
        m: &JsValue,
        layout: Option<&StepLayout>,
        config: Option<&ModelConfig>,
    ) -> Result<Self, String> {
        let generation = number_field(m, "generation")? as u32;
        let kind = string_field(m, "kind")?;
        let id = || number_field(m, "id").map(|v| v as u32);
        match kind.as_str() {
            "drive-progress" => {
                let cameras = match field(m, "cameras").is_undefined() {
                    true => None,
                    false => Some((
                        number_field(m, "step")? as usize,
                        bytes_field(m, "cameras")?,
                    )),
                };
                let progress = DriveProgress {
                    spec: spec_field(m)?,
                    condition: condition_field(m)?,
                    trial: string_field(m, "trial")?,
                    steps_done: number_field(m, "done")? as usize,
                    len: number_field(m, "len")? as usize,
                    cameras,
                    live: field(m, "live")
                        .dyn_into::<Float32Array>()
                        .map_err(|_| "a drive's progress has no `live` numbers")?
                        .to_vec(),
                    so_far: match field(m, "so-far-header").is_undefined() {
                        true => None,
                        false => Some(Arc::new(EpisodeSoFar::from_parts(
                            episode_parts(m, ["so-far-header", "so-far-sequence", "so-far-runs"])?,
                            config,
                        )?)),
                    },
                };
                return Ok(Self::DriveProgress {
                    generation,
                    id: id()?,
                    progress: Box::new(progress),
                });
            }
            "drive-done" => {
                return Ok(Self::DriveEnded {
                    generation,
                    id: id()?,
                    event: DriveEvent::Finished(Box::new(FinishedDrive::from_parts(
                        episode_parts(m, ["header", "sequence", "runs"])?,
                        config,
                    )?)),
                });
            }
            "drive-failed" => {
                return Ok(Self::DriveEnded {
                    generation,
                    id: id()?,
                    event: DriveEvent::Failed(string_field(m, "message")?),
                });
            }
            "ready" => {
                return Ok(Self::Ready {
                    compute: string_field(m, "compute")?,
                });
            }
            "fatal" => {
                return Ok(Self::Fatal {
                    generation,
                    message: string_field(m, "message")?,
                });
            }
            _ => {}
        }
        let key = key_from_text(&string_field(m, "key")?)?;
        let ms = |name| number_field(m, name).map(|v| Duration::from_secs_f64(v.max(0.0) / 1e3));
        let event = match kind.as_str() {
            "step" => {
                let layout = layout.ok_or("a step arrived before its model")?;
                let data = field(m, "data")
                    .dyn_into::<Float32Array>()
                    .map_err(|_| "a step message has no data")?;
                Event::Step(
                    key,
                    Box::new(CompactStep::from_f32s(&data.to_vec(), layout)?),
                )
            }
            "done" => Event::Done(Finished {
                key,
                steps: number_field(m, "steps")? as usize,
                busy: ms("busy_ms")?,
                wall: ms("wall_ms")?,
                replayed: number_field(m, "replayed")? as usize,
            }),
            "failed" => Event::Failed(key, string_field(m, "message")?),
            other => return Err(format!("unknown worker message `{other}`")),
        };
        Ok(Self::Event { generation, event })
    }
}

struct WorkerSide {
    /// `None` while a tick awaits the GPU; commands wait in `queued` until it is back.
    engine: Option<Engine>,
    queued: Vec<JsValue>,
    generation: u32,
    scheduled: bool,
    /// The Drive window's episode (on the CPU: a step's inference is small), and its id.
    drive: LocalDrive,
    drive_id: u32,
    /// The steps of the episode so far last sent to the page (sent again only grown).
    so_far_sent: Option<usize>,
}

impl WorkerSide {
    /// Whether the next tick has work: a run, or an episode.
    fn busy(&self) -> bool {
        self.drive.is_driving() || self.engine.as_ref().is_some_and(|e| e.running().is_some())
    }

    /// Steps the episode for a tick; what to tell the page (its progress, or its end).
    fn drive_tick(&mut self) -> Option<Reply> {
        if !self.drive.is_driving() {
            return None;
        }
        let (generation, id) = (self.generation, self.drive_id);
        Some(match self.drive.step_for(TICK) {
            Some(event) => Reply::DriveEnded {
                generation,
                id,
                event,
            },
            None => {
                let mut progress = self.drive.progress()?;
                let steps = progress.so_far.as_ref().map(|s| s.steps());
                if steps == self.so_far_sent {
                    progress.so_far = None; // the page has it
                }
                self.so_far_sent = steps;
                Reply::DriveProgress {
                    generation,
                    id,
                    progress: Box::new(progress),
                }
            }
        })
    }
}

/// Worker → itself: a message through this channel runs one tick. Unlike `setTimeout(0)`
/// it is not clamped to 4 ms, and page messages still get in between ticks.
struct Ticker {
    port: web_sys::MessagePort,
}

impl Ticker {
    /// Asks for the next tick; whether it was scheduled. A tick that cannot be scheduled
    /// would leave the run "computing" for ever, so the page is told the worker failed.
    fn schedule(&self, scope: &web_sys::DedicatedWorkerGlobalScope, generation: u32) -> bool {
        match self.port.post_message(&JsValue::NULL) {
            Ok(()) => true,
            Err(err) => {
                report_fatal(scope, generation, &format!("cannot schedule work: {err:?}"));
                false
            }
        }
    }
}

/// Where the worker's runs compute, from the page's `?compute=` (`auto`, `cpu`, `webgpu`):
/// the engine and the status bar's words for it. `auto` takes a WebGPU adapter unless it is
/// a CPU implementation (SwiftShader, WARP: slower than the CPU backend); `webgpu` takes
/// any; without an adapter, the CPU.
async fn open_engine(preference: &str) -> (Engine, String) {
    if preference == "cpu" {
        return (Engine::default(), "CPU (worker)".into());
    }
    match pvrnn_wgpu::WgpuBackend::open().await {
        Ok(gpu) if preference == "webgpu" || !gpu.gpu().is_cpu() => {
            let name = format!("WebGPU, {} (worker)", gpu.adapter_name());
            (Engine::on(Arc::new(gpu)), name)
        }
        Ok(gpu) => (
            Engine::default(),
            format!(
                "CPU (worker; WebGPU's {} is a CPU implementation, ?compute=webgpu takes it)",
                gpu.adapter_name()
            ),
        ),
        Err(e) => {
            crate::browser::log(&format!("worker: computing on the CPU: {e}"));
            (Engine::default(), "CPU (worker; no WebGPU adapter)".into())
        }
    }
}

/// The worker's entry point (called by `web/worker.js` after the module loaded) with the
/// page's compute preference (see [`open_engine`]).
#[wasm_bindgen]
pub fn run_worker(compute: String) -> Result<(), JsValue> {
    let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().dyn_into()?;
    let side = Rc::new(RefCell::new(WorkerSide {
        engine: None,
        queued: Vec::new(),
        generation: 0,
        scheduled: false,
        drive: LocalDrive::default(),
        drive_id: 0,
        so_far_sent: None,
    }));
    let channel = web_sys::MessageChannel::new()?;
    let ticker = Rc::new(Ticker {
        port: channel.port2(),
    });

    let (tick_side, tick_scope, tick_ticker) = (side.clone(), scope.clone(), ticker.clone());
    let tick = Closure::<dyn FnMut()>::new(move || {
        let mut engine = {
            let mut s = tick_side.borrow_mut();
            s.scheduled = false;
            match s.engine.take() {
                Some(engine) => engine,
                None => return, // a tick in flight schedules the next when it ends
            }
        };
        let (side, scope, ticker) = (tick_side.clone(), tick_scope.clone(), tick_ticker.clone());
        wasm_bindgen_futures::spawn_local(async move {
            let events = engine.work_async(TICK).await;
            let mut s = side.borrow_mut();
            s.engine = Some(engine);
            let generation = s.generation;
            for event in events {
                let (m, transfer) = Reply::Event { generation, event }.encode();
                if let Err(err) = scope.post_message_with_transfer(&m, &transfer) {
                    // A lost result would leave the page waiting for ever.
                    report_fatal(
                        &scope,
                        generation,
                        &format!("cannot send a result: {err:?}"),
                    );
                }
            }
            if let Some(reply) = s.drive_tick() {
                let config = s.engine.as_ref().and_then(|e| e.model()).map(|m| &m.config);
                let (m, transfer) = reply.encode_with(config);
                if let Err(err) = scope.post_message_with_transfer(&m, &transfer) {
                    report_fatal(
                        &scope,
                        generation,
                        &format!("cannot send the drive: {err:?}"),
                    );
                }
            }
            apply_queued(&mut s, &scope);
            if s.busy() && !s.scheduled {
                s.scheduled = ticker.schedule(&scope, s.generation);
            }
        });
    });
    channel
        .port1()
        .set_onmessage(Some(tick.as_ref().unchecked_ref()));
    tick.forget();

    let scope_for_messages = scope.clone();
    let message_side = side.clone();
    let on_message =
        Closure::<dyn FnMut(web_sys::MessageEvent)>::new(move |e: web_sys::MessageEvent| {
            let mut s = message_side.borrow_mut();
            s.queued.push(e.data());
            if s.engine.is_none() {
                return; // applied when the engine is back
            }
            apply_queued(&mut s, &scope_for_messages);
            if s.busy() && !s.scheduled {
                s.scheduled = ticker.schedule(&scope_for_messages, s.generation);
            }
        });
    scope.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
    on_message.forget();

    wasm_bindgen_futures::spawn_local(async move {
        let (engine, compute) = open_engine(&compute).await;
        crate::browser::log(&format!("worker: live runs compute on {compute}"));
        side.borrow_mut().engine = Some(engine);
        if let Err(err) = scope.post_message(&Reply::Ready { compute }.encode().0) {
            crate::browser::log(&format!("worker: cannot say it is ready: {err:?}"));
        }
    });
    Ok(())
}

/// Applies the page's commands that arrived while the engine was busy, in order.
fn apply_queued(s: &mut WorkerSide, scope: &web_sys::DedicatedWorkerGlobalScope) {
    for m in std::mem::take(&mut s.queued) {
        match handle_command(s, &m) {
            Ok(None) => {}
            // A drive that cannot start or be perturbed: the page says why; the worker goes on.
            Ok(Some(reply)) => {
                if let Err(err) = scope.post_message(&reply.encode().0) {
                    report_fatal(scope, s.generation, &format!("cannot answer: {err:?}"));
                }
            }
            Err(err) => report_fatal(scope, s.generation, &err),
        }
    }
}

/// Tells the page the worker cannot go on (and the console, in case that fails too).
fn report_fatal(scope: &web_sys::DedicatedWorkerGlobalScope, generation: u32, why: &str) {
    crate::browser::log(&format!("worker: {why}"));
    let reply = Reply::Fatal {
        generation,
        message: why.to_string(),
    };
    let _ = scope.post_message(&reply.encode().0);
}

/// Applies a page's command; a reply when a drive request was refused.
fn handle_command(s: &mut WorkerSide, m: &JsValue) -> Result<Option<Reply>, String> {
    let command = Command::decode(m)?;
    let Some(engine) = s.engine.as_mut() else {
        return Err("a command reached the worker while its engine was busy".into());
    };
    if !matches!(command, Command::Model { .. }) && command.generation() != s.generation {
        return Ok(None); // meant for a model already replaced
    }
    match command {
        Command::Model { generation, bytes } => {
            let model = io::model_from_bytes(bytes, "the model sent to the worker")
                .map_err(|e| e.to_string())?;
            engine.set_model(Arc::new(model));
            s.generation = generation;
            // An episode of the previous model ends with it.
            s.drive = LocalDrive::default();
        }
        Command::Observations {
            name,
            steps,
            extero,
            proprio,
            ..
        } => {
            let tensor = |data: Vec<f32>| -> Result<Tensor<f32>, String> {
                let dims = data.len() / steps.max(1);
                Tensor::from_vec(&[1, steps, dims], data).map_err(|e| e.to_string())
            };
            let obs = Observations::new(tensor(extero)?, tensor(proprio)?, None)
                .map_err(|e| e.to_string())?;
            engine.add_observations(name, Arc::new(obs));
        }
        Command::Run { key, .. } => engine.run(key),
        Command::Drive {
            generation,
            id,
            request,
        } => {
            let start = matches!(request, DriveRequest::Start { .. });
            if start {
                s.drive_id = id;
                s.so_far_sent = None;
            } else if id != s.drive_id {
                return Ok(None); // an episode already over
            }
            let model = engine.model().cloned();
            if let Err(why) = s.drive.request(model.as_ref(), request) {
                return Ok(Some(Reply::DriveEnded {
                    generation,
                    id,
                    event: DriveEvent::Failed(why),
                }));
            }
        }
    }
    Ok(None)
}

#[derive(Default)]
struct PageSide {
    ready: bool,
    /// Commands posted before the worker was ready.
    pending: Vec<(Object, Array)>,
    events: Vec<Event>,
    failure: Option<String>,
    generation: u32,
    layout: Option<StepLayout>,
    /// The model's configuration (to read a finished episode's run).
    config: Option<ModelConfig>,
    /// Where the worker's runs compute, once it is ready.
    compute: Option<String>,
    /// The episode the worker drives, as last heard of, and its id.
    drive: Option<DriveProgress>,
    drive_id: u32,
    drive_events: Vec<DriveEvent>,
    /// When the episode was sent to the worker (its speed goes to the console).
    drive_started: Option<web_time::Instant>,
    /// How many times the episode so far arrived (said with its speed).
    so_far_received: usize,
}

/// The page's handle on the worker.
pub struct WorkerClient {
    worker: web_sys::Worker,
    side: Rc<RefCell<PageSide>>,
}

impl std::fmt::Debug for WorkerClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.side.borrow();
        f.debug_struct("WorkerClient")
            .field("ready", &s.ready)
            .field("generation", &s.generation)
            .finish()
    }
}

impl WorkerClient {
    /// Starts the worker script at `url` (a module worker); `ctx` repaints when results arrive.
    pub fn spawn(url: &str, ctx: eframe::egui::Context) -> Result<Self, String> {
        let options = web_sys::WorkerOptions::new();
        options.set_type(web_sys::WorkerType::Module);
        let worker = web_sys::Worker::new_with_options(url, &options)
            .map_err(|e| format!("cannot start {url}: {e:?}"))?;
        let side = Rc::new(RefCell::new(PageSide::default()));
        let err_ctx = ctx.clone();

        let (msg_side, msg_worker) = (side.clone(), worker.clone());
        let on_message = Closure::<dyn FnMut(web_sys::MessageEvent)>::new(
            move |e: web_sys::MessageEvent| {
                let m = e.data();
                let mut s = msg_side.borrow_mut();
                let reply = Reply::decode(&m, s.layout.as_ref(), s.config.as_ref());
                match reply {
                    Ok(Reply::Ready { compute }) => {
                        crate::browser::log(&format!("live runs compute on {compute}"));
                        s.ready = true;
                        s.compute = Some(compute);
                        for (m, transfer) in std::mem::take(&mut s.pending) {
                            if let Err(e) = msg_worker.post_message_with_transfer(&m, &transfer) {
                                s.failure = Some(format!("cannot message the worker: {e:?}"));
                            }
                        }
                        return;
                    }
                    Ok(Reply::Fatal { message, .. }) => {
                        s.failure = Some(message);
                        ctx.request_repaint();
                        return;
                    }
                    // Results of a model (or an episode) already replaced.
                    Ok(
                        Reply::Event { generation, .. }
                        | Reply::DriveProgress { generation, .. }
                        | Reply::DriveEnded { generation, .. },
                    ) if generation != s.generation => return,
                    Ok(Reply::DriveProgress { id, .. } | Reply::DriveEnded { id, .. })
                        if id != s.drive_id || s.drive.is_none() || !s.drive_events.is_empty() =>
                    {
                        return;
                    }
                    Ok(Reply::Event { event, .. }) => s.events.push(event),
                    Ok(Reply::DriveProgress { mut progress, .. }) => {
                        // Sent only when it grew: the one the page has stands.
                        if progress.so_far.is_none() {
                            progress.so_far = s.drive.as_mut().and_then(|d| d.so_far.take());
                        } else {
                            s.so_far_received += 1;
                        }
                        s.drive = Some(*progress);
                    }
                    Ok(Reply::DriveEnded { event, .. }) => {
                        if let (DriveEvent::Finished(f), Some(started)) = (&event, s.drive_started)
                        {
                            let seconds = started.elapsed().as_secs_f64();
                            let steps = f.sequence.len();
                            crate::browser::log(&format!(
                                "drive: the worker drove {} ({} controller): {steps} steps in {seconds:.1} s ({:.1} steps/s); the episode so far arrived {} times for the main panels",
                                f.spec.trial().map(|t| t.name()).unwrap_or_default(),
                                f.spec.controller.name(),
                                steps as f64 / seconds.max(1e-9),
                                s.so_far_received
                            ));
                        }
                        // In progress until the app takes the end (`poll_drive`), so that
                        // no frame sees it neither in progress nor over.
                        s.drive_events.push(event);
                        ctx.request_repaint();
                        return;
                    }
                    Err(_) if field(&m, "generation").as_f64() != Some(s.generation as f64) => {
                        return;
                    }
                    Err(err) => s.failure = Some(err),
                }
                ctx.request_repaint_after(REPAINT_EVERY);
            },
        );
        worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
        on_message.forget();

        let err_side = side.clone();
        let on_error = Closure::<dyn FnMut(web_sys::Event)>::new(move |e: web_sys::Event| {
            let text = e
                .dyn_ref::<web_sys::ErrorEvent>()
                .map_or_else(|| "the worker failed".to_string(), |e| e.message());
            err_side.borrow_mut().failure = Some(text);
            err_ctx.request_repaint();
        });
        worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
        on_error.forget();
        // A message that cannot be deserialised would otherwise vanish with its run.
        let lost_side = side.clone();
        let on_lost = Closure::<dyn FnMut(web_sys::MessageEvent)>::new(move |_| {
            lost_side.borrow_mut().failure = Some("a message from the worker was lost".into());
        });
        worker.set_onmessageerror(Some(on_lost.as_ref().unchecked_ref()));
        on_lost.forget();
        Ok(Self { worker, side })
    }

    fn post(&self, command: &Command) {
        let (m, transfer) = command.encode();
        let mut s = self.side.borrow_mut();
        if s.ready {
            if let Err(e) = self.worker.post_message_with_transfer(&m, &transfer) {
                s.failure = Some(format!("cannot message the worker: {e:?}"));
            }
        } else {
            s.pending.push((m, transfer));
        }
    }
}

impl Executor for WorkerClient {
    fn set_model(&mut self, model: &Arc<Model<f32>>) {
        let generation = {
            let mut s = self.side.borrow_mut();
            s.generation += 1;
            s.layout = Some(StepLayout::of(&model.config));
            s.config = Some(model.config.clone());
            s.events.clear();
            // The worker ends an episode of the previous model.
            s.drive = None;
            s.generation
        };
        match io::model_to_bytes(model.as_ref()) {
            Ok(bytes) => self.post(&Command::Model { generation, bytes }),
            Err(e) => {
                self.side.borrow_mut().failure =
                    Some(format!("cannot send the model to the worker: {e}"))
            }
        }
    }

    fn add_observations(&mut self, name: &str, obs: Arc<Observations<f32>>) {
        let generation = self.side.borrow().generation;
        self.post(&Command::Observations {
            generation,
            name: name.to_string(),
            steps: obs.steps(),
            extero: obs.tensor(Modality::Exteroceptive).data().to_vec(),
            proprio: obs.tensor(Modality::Proprioceptive).data().to_vec(),
        });
    }

    fn run(&mut self, key: &RunKey) {
        let generation = self.side.borrow().generation;
        self.post(&Command::Run {
            generation,
            key: key.clone(),
        });
    }

    fn poll(&mut self, _budget: Duration) -> Vec<Event> {
        std::mem::take(&mut self.side.borrow_mut().events)
    }

    /// Sends the request to the worker; a start shows at once as an episode at step 0.
    fn drive(&mut self, _model: &Arc<Model<f32>>, request: DriveRequest) -> Result<(), String> {
        let (generation, id) = {
            let mut s = self.side.borrow_mut();
            match &request {
                DriveRequest::Start { spec, condition } => {
                    s.drive_id += 1;
                    s.drive_started = Some(web_time::Instant::now());
                    s.so_far_received = 0;
                    crate::browser::log(&format!(
                        "drive: episode {} ({}) sent to the worker",
                        s.drive_id,
                        spec.to_text()
                    ));
                    s.drive = Some(DriveProgress {
                        spec: (**spec).clone(),
                        condition: *condition,
                        trial: spec.trial().map(|t| t.name()).unwrap_or_default(),
                        steps_done: 0,
                        len: 0,
                        cameras: None,
                        live: Vec::new(),
                        so_far: None,
                    });
                }
                DriveRequest::Stop => s.drive = None,
                DriveRequest::Push(_) | DriveRequest::Occlude(_) | DriveRequest::DropVision(_)
                    if s.drive.is_none() =>
                {
                    return Ok(());
                }
                DriveRequest::Push(_) | DriveRequest::Occlude(_) | DriveRequest::DropVision(_) => {}
            }
            (s.generation, s.drive_id)
        };
        self.post(&Command::Drive {
            generation,
            id,
            request,
        });
        Ok(())
    }

    fn drive_progress(&self) -> Option<DriveProgress> {
        self.side.borrow().drive.clone()
    }

    fn drives_here(&self) -> bool {
        false
    }

    fn poll_drive(&mut self, _budget: Duration) -> Vec<DriveEvent> {
        let mut s = self.side.borrow_mut();
        if !s.drive_events.is_empty() {
            s.drive = None;
        }
        std::mem::take(&mut s.drive_events)
    }

    /// Where the worker's runs compute ("WebGPU, ... (worker)", "CPU (worker)"), once it
    /// said.
    fn compute_label(&self) -> Option<String> {
        self.side.borrow().compute.clone()
    }

    /// Why the worker cannot be used, once it failed.
    fn broken(&mut self) -> Option<String> {
        let failure = self.side.borrow_mut().failure.take();
        if failure.is_some() {
            self.worker.terminate();
        }
        failure
    }
}
