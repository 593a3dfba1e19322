//! A whole learning iteration on the device: the recurrence's weights and every training
//! sequence's adaptive variables stay there with their RAdam moments, beside the read-outs
//! ([`crate::learner`]), so that an iteration uploads only its eps and a small table, runs
//! in one submission (inputs packed from the adaptive variables and eps, the recurrence
//! forward, both read-outs from the module states in its record, their d F / d d into the
//! recurrence's backward pass, the recurrent weights' and the adaptive variables'
//! gradients) and reads back only what the free energy needs: the read-outs' row losses
//! and the KL terms per step and unit (summed on the host in f64, as the CPU backend sums
//! them). Values move between the kernels' layouts with `shaders/strided_copy.wgsl`.
//!
//! Several learning runs of one shape (a cohort: an experiment condition's networks, other
//! seeds) share a [`Stack`]: their recurrent weights, one network after another in the same
//! buffers, and the recurrence's buffers likewise, so that one forward and one backward
//! dispatch run every window of every network (a workgroup each: the recurrence is a
//! chain of dependent steps, and one network's 18 windows leave most of a GPU idle). Each
//! run prepares its part of an iteration (its inputs, read-outs and gradients' copies) when
//! it begins; the first to wait for its result submits every prepared run's at once.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use pvrnn_core::data::{Ablation, Observations, Observed};
use pvrnn_core::free_energy::FreeEnergy;
use pvrnn_core::optim::RAdam;
use pvrnn_core::params::Model;
use pvrnn_core::{Error, Modality, ModelConfig, Result};

use crate::copy::{Strided, encode_copy};
use crate::encode::{DispatchList, Recorder, bind, dispatch, grid, row_losses, vec4s};
use crate::gpu::{Gpu, RecurrenceKernels};
use crate::output::{EncodedReadout, GpuOutputLayer, Tiling};
use crate::pool::PooledBuffer;
use crate::readback::{ReadBack, read_back};
use crate::recurrence::{RecurrenceLayout, WeightGradBuffers, WindowEntry};
use crate::resident::{Part, ResidentLayer, ResidentTensor, TensorIndex, resident_buffer};
use crate::timing::{PassTimes, begin_pass};

/// What the learning runs of a cohort share on the device (see the module docs): `slots`
/// runs of `sequences` x `steps`, each run's part of every buffer at its slot.
#[derive(Debug)]
pub(crate) struct Stack {
    gpu: Arc<Gpu>,
    layout: RecurrenceLayout,
    kernels: Arc<RecurrenceKernels>,
    /// `WgpuOptions::profile_kernels`.
    profile_kernels: bool,
    /// The recurrence part of the last submission, with the runs (slot, windows) it was
    /// encoded for, replayed while they stay.
    recurrence_recording: Mutex<Option<RecordedRecurrence>>,
    slots: usize,
    sequences: usize,
    steps: usize,
    /// The packed recurrent weights (the recurrence's layout), the same with every matrix
    /// transposed for the forward kernel (refreshed after each update), their gradients
    /// and RAdam moments.
    weights: wgpu::Buffer,
    weights_t: wgpu::Buffer,
    grads: wgpu::Buffer,
    moments: [wgpu::Buffer; 2],
    /// The recurrence's inputs, the read-outs' d F / d d in its layout, its forward record
    /// and its backward record, every sequence at full length.
    inputs: wgpu::Buffer,
    grad_d: wgpu::Buffer,
    record: wgpu::Buffer,
    back: wgpu::Buffer,
    queue: Mutex<Queue>,
}

/// Iterations prepared and not yet submitted, submitted and not yet read back, and
/// results not yet taken.
#[derive(Debug, Default)]
struct Queue {
    next_ticket: u64,
    prepared: Vec<Prepared>,
    /// Oldest first.
    in_flight: Vec<InFlight>,
    results: HashMap<u64, Vec<Vec<f32>>>,
    /// The iterations whose submission failed (the device out of memory making the
    /// recurrence's scratch), with what the device said: their results are that error.
    failed: HashMap<u64, String>,
}

/// One submission on its way: its runs' tickets (`None`: withdrawn) with how many of the
/// read-back's parts are theirs, and what it uses, kept until it has run.
#[derive(Debug)]
struct InFlight {
    tickets: Vec<(Option<u64>, usize)>,
    read_back: ReadBack,
    _prepared: Vec<Prepared>,
    _recurrence: Arc<RecurrenceWork>,
}

/// `shaders/finite_check.wgsl`'s parameters.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FiniteCheckParams {
    count: u32,
    groups_x: u32,
    _pad: [u32; 2],
}

/// One run's part of an iteration, encoded (see [`DeviceIteration::free_energy_later`]).
#[derive(Debug)]
struct Prepared {
    ticket: u64,
    slot: usize,
    /// Clears of what starts from zero (and the read-outs' own), before everything else;
    /// taken when submitted.
    clears: Option<wgpu::CommandBuffer>,
    /// Its dispatches (the buffers they use are kept by the run's [`Recording`]).
    work: RunWork,
}

/// A run's dispatches of one iteration and what reading its results needs (shared by a
/// [`Prepared`] iteration and the run's [`Recording`]).
#[derive(Clone, Debug)]
struct RunWork {
    /// Before the recurrence forward: the inputs; between forward and backward: the
    /// read-outs; after the backward: the adaptive variables' gradients and the KL terms.
    inputs: Arc<DispatchList>,
    readouts: Arc<DispatchList>,
    after: Arc<DispatchList>,
    entries: Vec<WindowEntry>,
    /// What to read back (KL terms, each read-out's row losses) with its length.
    sources: Vec<(wgpu::Buffer, usize)>,
    reading: Reading,
}

impl Stack {
    /// Whether the kernels hold `slots` runs of `model`'s shapes in one dispatch.
    pub(crate) fn fits(gpu: &Gpu, model: &Model<f32>, slots: usize) -> bool {
        let (sequences, steps) = (model.adaptive.sequences(), model.adaptive.steps());
        let (layout, _) = RecurrenceLayout::new(&model.params, &model.config);
        let windows = slots * sequences;
        let binding = gpu.limits().max_storage_buffer_binding_size as usize;
        slots > 0
            && sequences > 0
            && steps > 0
            && layout.fits(gpu, windows, windows * steps)
            && 4 * slots * layout.weight_floats() <= binding
    }

    /// Device buffers for `slots` runs of `model`'s shapes; `None` where the kernels do not
    /// hold them ([`Self::fits`]). With `profile_kernels` ([`crate::WgpuOptions`]) each
    /// dispatch is timed apart while profiling.
    pub(crate) fn new(
        gpu: &Arc<Gpu>,
        tiling: Tiling,
        profile_kernels: bool,
        model: &Model<f32>,
        slots: usize,
    ) -> Option<Arc<Self>> {
        if !Self::fits(gpu, model, slots) {
            return None;
        }
        let (sequences, steps) = (model.adaptive.sequences(), model.adaptive.steps());
        let (layout, packed) = RecurrenceLayout::new(&model.params, &model.config);
        let threads = layout.threads(gpu, tiling.recurrence_threads);
        let s = layout.strides();
        let rows = slots * sequences * steps;
        let zeros = |floats: usize, label: &str| resident_buffer(gpu, label, &vec![0f32; floats]);
        let p = packed.len();
        Some(Arc::new(Self {
            gpu: gpu.clone(),
            kernels: gpu.recurrence_kernels(threads, tiling.recurrence_early_loads),
            profile_kernels,
            recurrence_recording: Mutex::default(),
            slots,
            sequences,
            steps,
            weights: zeros(slots * p, "resident recurrent weights"),
            weights_t: zeros(slots * p, "resident recurrent weights, transposed"),
            grads: zeros(slots * p, "resident recurrent gradients"),
            moments: [
                zeros(slots * p, "resident recurrent m"),
                zeros(slots * p, "resident recurrent v"),
            ],
            inputs: zeros(
                slots * sequences * (s.init + steps * s.input),
                "resident recurrence inputs",
            ),
            grad_d: zeros(rows * s.grad_d, "resident read-out gradients"),
            record: zeros(rows * s.record, "recurrence record"),
            back: zeros(rows * s.back, "recurrence backward"),
            layout,
            queue: Mutex::default(),
        }))
    }

    /// Whether `model` has the shapes of the stack's runs.
    pub(crate) fn holds(&self, model: &Model<f32>) -> bool {
        let (layout, _) = RecurrenceLayout::new(&model.params, &model.config);
        model.adaptive.sequences() == self.sequences
            && model.adaptive.steps() == self.steps
            && layout.same_shape(&self.layout)
    }

    fn weight_floats(&self) -> usize {
        self.layout.weight_floats()
    }

    /// Where slot `slot`'s part of the inputs, the record, the read-out gradients and the
    /// backward record start, and its weights: added to a run's own window entries.
    fn entry_base(&self, slot: usize) -> WindowEntry {
        let s = self.layout.strides();
        let rows = slot * self.sequences * self.steps;
        [
            0,
            slot * self.sequences * (s.init + self.steps * s.input),
            rows * s.record,
            0,
            rows * s.grad_d,
            rows * s.back,
            slot * self.weight_floats(),
        ]
    }

    /// The first row of slot `slot` in the record and the read-out gradients.
    fn first_row(&self, slot: usize) -> usize {
        slot * self.sequences * self.steps
    }

    /// Queues a run's prepared iteration; its ticket claims the result.
    fn enqueue(&self, mut prepared: Prepared) -> u64 {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        prepared.ticket = queue.next_ticket;
        queue.next_ticket += 1;
        let ticket = prepared.ticket;
        queue.prepared.push(prepared);
        ticket
    }

    /// Submits every prepared iteration (one submission), without waiting.
    pub(crate) fn submit_prepared(&self) {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        self.submit_locked(&mut queue);
    }

    /// Submitting allocates too (the recurrence's scratch, the read-back): where the
    /// device runs out of memory, the submission's iterations fail with that error when
    /// their results are claimed ([`Self::results_of`]), instead of wgpu's panic.
    fn submit_locked(&self, queue: &mut Queue) {
        let prepared = std::mem::take(&mut queue.prepared);
        if prepared.is_empty() {
            return;
        }
        let tickets: Vec<u64> = prepared.iter().map(|p| p.ticket).collect();
        let what = || match self.slots {
            1 => "submit a learning iteration".to_string(),
            n => format!("submit a learning iteration of {n} networks trained together"),
        };
        match self.gpu.allocating(what, || self.submit(prepared)) {
            Ok(in_flight) => queue.in_flight.push(in_flight),
            Err(error) => {
                let message = match error {
                    pvrnn_core::Error::Device(message) => message,
                    other => other.to_string(),
                };
                for ticket in tickets {
                    queue.failed.insert(ticket, message.clone());
                }
            }
        }
    }

    /// The read-back of `ticket`'s iteration: submitted with every other prepared one if it
    /// has not been yet, waited for (with the submissions before it).
    fn results_of(&self, ticket: u64) -> Result<Vec<Vec<f32>>> {
        let results = self.read_results_of(ticket)?;
        // A device that failed (out of memory outside the checked scopes, a read-back
        // refused) gave results that mean nothing.
        match self.gpu.failure() {
            Some(failure) => Err(failure),
            None => Ok(results),
        }
    }

    /// [`Self::results_of`] as they came back.
    fn read_results_of(&self, ticket: u64) -> Result<Vec<Vec<f32>>> {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(results) = queue.results.remove(&ticket) {
            return Ok(results);
        }
        if queue.prepared.iter().any(|p| p.ticket == ticket) {
            self.submit_locked(&mut queue);
        }
        if let Some(message) = queue.failed.remove(&ticket) {
            return Err(pvrnn_core::Error::Device(message));
        }
        let holds = |f: &InFlight| f.tickets.iter().any(|&(t, _)| t == Some(ticket));
        let Some(last) = queue.in_flight.iter().position(holds) else {
            return Err(pvrnn_core::Error::Device(format!(
                "{}: a learning iteration's results were claimed but never submitted",
                self.gpu.describe()
            )));
        };
        let _phase = pvrnn_core::profile::phase("evaluate on the device: run and read back");
        for in_flight in queue.in_flight.drain(..=last).collect::<Vec<_>>() {
            let mut all = pvrnn_core::deferred::now(in_flight.read_back).into_iter();
            for (t, parts) in in_flight.tickets {
                let results: Vec<Vec<f32>> = all.by_ref().take(parts).collect();
                if let Some(t) = t {
                    queue.results.insert(t, results);
                }
            }
        }
        queue.results.remove(&ticket).ok_or_else(|| {
            pvrnn_core::Error::Device(format!(
                "{}: a learning iteration's results did not come back",
                self.gpu.describe()
            ))
        })
    }

    /// Takes `ticket`'s iteration back: not submitted if it was not yet, its results not
    /// kept if it was.
    fn withdraw(&self, ticket: u64) {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        queue.prepared.retain(|p| p.ticket != ticket);
        queue.failed.remove(&ticket);
        queue.results.remove(&ticket);
        for in_flight in &mut queue.in_flight {
            for (t, _) in &mut in_flight.tickets {
                if *t == Some(ticket) {
                    *t = None;
                }
            }
        }
    }

    /// Every prepared run's iteration in one submission: their inputs, one forward dispatch
    /// over all their windows, their read-outs, one backward dispatch, each run's weight
    /// gradients and copies; then one read-back of every run's free-energy terms, not yet
    /// waited for.
    fn submit(&self, mut prepared: Vec<Prepared>) -> InFlight {
        let gpu = &*self.gpu;
        let clears: Vec<wgpu::CommandBuffer> = prepared
            .iter_mut()
            .filter_map(|p| p.clears.take())
            .collect();
        let encode_phase = pvrnn_core::profile::phase("evaluate on the device: upload and encode");
        let recurrence_phase = pvrnn_core::profile::phase(
            "evaluate on the device: the recurrence's part, encoded or replayed",
        );
        let recurrence = self.recurrence_work(&prepared);
        drop(recurrence_phase);
        let RecurrenceWork {
            forward,
            backward,
            weight_grads,
            ..
        } = &*recurrence;
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // Dispatches in one compute pass (a pass per dispatch costs the host more than the
        // small kernels); while profiling, a pass per part, each timed on the device.
        let parts: [(&'static str, Vec<&DispatchList>); 6] = [
            (
                "device: inputs into the recurrence's layout",
                prepared.iter().map(|p| &*p.work.inputs).collect(),
            ),
            ("device: recurrence forward", vec![forward]),
            (
                "device: read-outs (hidden and output layers, forward and backward)",
                prepared.iter().map(|p| &*p.work.readouts).collect(),
            ),
            ("device: recurrence backward", vec![backward]),
            ("device: recurrent weight gradients", vec![weight_grads]),
            (
                "device: gradients into the optimiser's layout",
                prepared.iter().map(|p| &*p.work.after).collect(),
            ),
        ];
        let (times, per_kernel) = self.pass_times(&parts);
        match &times {
            None => {
                let mut pass = begin_pass(&mut encoder, None, 0);
                parts
                    .iter()
                    .flat_map(|(_, lists)| lists)
                    .for_each(|list| list.replay(&mut pass));
            }
            Some(times) if per_kernel => {
                let dispatches = parts
                    .iter()
                    .flat_map(|(_, lists)| lists)
                    .flat_map(|list| (0..list.len()).map(move |index| (list, index)));
                for (pass_index, (list, index)) in dispatches.enumerate() {
                    let mut pass = begin_pass(&mut encoder, Some(times), pass_index);
                    list.replay_one(index, &mut pass);
                }
                times.resolve(&mut encoder);
            }
            Some(times) => {
                for (part, (_, lists)) in parts.iter().enumerate() {
                    let mut pass = begin_pass(&mut encoder, Some(times), part);
                    lists.iter().for_each(|list| list.replay(&mut pass));
                }
                times.resolve(&mut encoder);
            }
        }
        drop(parts);
        let sources: Vec<(&wgpu::Buffer, usize)> = prepared
            .iter()
            .flat_map(|p| p.work.sources.iter().map(|(b, n)| (b, *n)))
            .collect();
        // The clears first, then the iteration (queue order).
        gpu.queue.submit(clears);
        let read_back = read_back(gpu, encoder, &sources);
        if let Some(times) = times {
            times.collect(gpu);
        }
        drop(encode_phase);
        InFlight {
            tickets: prepared
                .iter()
                .map(|p| (Some(p.ticket), p.work.sources.len()))
                .collect(),
            read_back,
            _prepared: prepared,
            _recurrence: recurrence,
        }
    }

    /// The timestamps of a submission's passes while profiling: a pass per part, or with
    /// `WgpuOptions::profile_kernels` a pass per dispatch (then `true`), its time added to its
    /// part and to its kernel. A submission of more dispatches than one query set times
    /// (wgpu's `QUERY_SET_MAX_QUERIES`, two queries each) is timed per part.
    fn pass_times(
        &self,
        parts: &[(&'static str, Vec<&DispatchList>)],
    ) -> (Option<PassTimes>, bool) {
        // Not profiling (every iteration but a bench's): nothing to name or count.
        if !pvrnn_core::profile::enabled() {
            return (None, false);
        }
        let dispatches: usize = parts
            .iter()
            .flat_map(|(_, lists)| lists)
            .map(|list| list.len())
            .sum();
        let per_kernel =
            self.profile_kernels && 2 * dispatches <= wgpu::QUERY_SET_MAX_QUERIES as usize;
        let passes: Vec<Vec<&'static str>> = if per_kernel {
            let kernels = &self.gpu.kernel_names;
            parts
                .iter()
                .flat_map(|(part, lists)| {
                    lists
                        .iter()
                        .flat_map(|list| list.kernels())
                        .map(|kernel| vec![*part, kernels.phase(kernel)])
                })
                .collect()
        } else {
            parts.iter().map(|(part, _)| vec![*part]).collect()
        };
        (PassTimes::adding_to(&self.gpu, passes), per_kernel)
    }

    /// The recurrence's part of a submission for these runs: the one recorded for the same
    /// runs and windows when replaying, else encoded anew (and recorded).
    fn recurrence_work(&self, prepared: &[Prepared]) -> Arc<RecurrenceWork> {
        let mut recorded = self
            .recurrence_recording
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let same_runs = |last: &&RecordedRecurrence| {
            last.runs.len() == prepared.len()
                && last
                    .runs
                    .iter()
                    .zip(prepared)
                    .all(|((slot, entries), p)| *slot == p.slot && *entries == p.work.entries)
        };
        if let Some(last) = recorded.as_ref().filter(same_runs) {
            return last.work.clone();
        }
        let work = Arc::new(self.encode_recurrence(prepared));
        *recorded = Some(RecordedRecurrence {
            runs: prepared
                .iter()
                .map(|p| (p.slot, p.work.entries.clone()))
                .collect(),
            work: work.clone(),
        });
        work
    }

    /// The recurrence's part of a submission for every prepared run: the windows' table,
    /// one forward and one backward dispatch over all their windows, and the weight
    /// gradients of each run; with the buffers to keep until the submission has run.
    fn encode_recurrence(&self, prepared: &[Prepared]) -> RecurrenceWork {
        let gpu = &*self.gpu;
        gpu.count_recurrence_part_encoded();
        let entries: Vec<WindowEntry> = prepared
            .iter()
            .flat_map(|p| p.work.entries.clone())
            .collect();
        let windows = entries.len();
        let layout = &self.layout;
        let table = layout.upload_table(gpu, &Ablation::none(), &entries);
        let mut keep = Vec::new();
        let mut forward = DispatchList::default();
        layout.encode_forward(
            gpu,
            &self.kernels,
            &mut forward,
            &table,
            &self.weights_t,
            &self.inputs,
            &self.record,
            windows,
        );
        let mut backward = DispatchList::default();
        keep.push(layout.encode_backward(
            gpu,
            &self.kernels,
            &mut backward,
            &table,
            &self.weights,
            &self.record,
            &self.grad_d,
            &self.back,
            windows,
        ));
        let mut first = 0;
        let networks: Vec<_> = prepared
            .iter()
            .map(|p| {
                let count = p.work.entries.len();
                first += count;
                (first - count..first, p.slot * self.weight_floats())
            })
            .collect();
        let buffers = WeightGradBuffers {
            table: &table,
            inputs: &self.inputs,
            record: &self.record,
            back: &self.back,
            grads: &self.grads,
        };
        let mut weight_grads = DispatchList::default();
        keep.extend(layout.encode_weight_grads(
            gpu,
            &self.kernels,
            &mut weight_grads,
            buffers,
            &networks,
        ));
        keep.push(table);
        RecurrenceWork {
            forward,
            backward,
            weight_grads,
            _buffers: keep,
        }
    }
}

/// A submission's recurrence part and the runs it was encoded for (their slots and window
/// entries): the same runs replay it, for they bind the same buffers and shapes.
#[derive(Debug)]
struct RecordedRecurrence {
    runs: Vec<(usize, Vec<WindowEntry>)>,
    work: Arc<RecurrenceWork>,
}

/// What [`Stack::encode_recurrence`] encodes: the table, the dispatches per part, and the
/// buffers to keep until the submission has run (or while it is recorded).
#[derive(Debug)]
struct RecurrenceWork {
    forward: DispatchList,
    backward: DispatchList,
    weight_grads: DispatchList,
    /// The table, uniforms and scratch the dispatches bind, held from the pool.
    _buffers: Vec<PooledBuffer>,
}

/// A run's claim on its prepared iteration's results ([`Stack::enqueue`]). Dropped before
/// they are taken (a caller that gave up on the future), it withdraws the iteration, or
/// its results, so that nothing stale is submitted or kept.
struct Ticket<'s> {
    stack: &'s Stack,
    ticket: u64,
}

impl Ticket<'_> {
    fn results(&self) -> Result<Vec<Vec<f32>>> {
        self.stack.results_of(self.ticket)
    }
}

impl Drop for Ticket<'_> {
    fn drop(&mut self) {
        self.stack.withdraw(self.ticket);
    }
}

/// One learning run's recurrence and adaptive variables, resident in its [`Stack`] slot
/// and its own buffers (see the module docs), and the read-outs it feeds.
#[derive(Debug)]
pub(crate) struct DeviceIteration {
    stack: Arc<Stack>,
    slot: usize,
    config: ModelConfig,
    /// Per module, a_mu and a_sigma of every sequence, `[sequences, steps, z]`, and their
    /// gradients.
    adaptive: [[wgpu::Buffer; 2]; 4],
    adaptive_grads: [[wgpu::Buffer; 2]; 4],
    readouts: GpuOutputLayer,
    /// The run's part of an iteration as last encoded, to replay.
    recording: Mutex<Option<Recording>>,
    /// The evaluation queued ahead of its call (`Learner::queue_free_energy`).
    ahead: Mutex<Option<Ahead>>,
    /// The run's divergence mark: cleared as an evaluation starts and set when its
    /// free-energy terms are not finite (`shaders/finite_check.wgsl`); the learner's
    /// update queued after that evaluation reads it.
    diverged: wgpu::Buffer,
}

/// An evaluation queued ahead of its call: the data (`Observations::id`) and eps it is
/// for, its ticket, and what reading its results needs.
#[derive(Debug)]
struct Ahead {
    data: u64,
    eps: Vec<[Vec<f32>; 4]>,
    ticket: u64,
    reading: Reading,
}

/// What turns a run's read-back into its free energy ([`DeviceIteration::free_energy_of`]).
#[derive(Clone, Copy, Debug)]
struct Reading {
    total: usize,
    per_module_at: [usize; 4],
    divisors: [usize; 2],
}

impl Drop for DeviceIteration {
    fn drop(&mut self) {
        let ahead = self.ahead.get_mut().unwrap_or_else(|e| e.into_inner());
        if let Some(ahead) = ahead.take() {
            self.stack.withdraw(ahead.ticket);
        }
    }
}

/// A run's part of a learning iteration, encoded once and replayed while the data and its
/// shapes stay: every iteration runs the same dispatches on the same buffers, only eps
/// differs (uploaded into the recording's buffer). The recording holds every buffer its
/// dispatches use, so none returns to the pool while it lives.
#[derive(Debug)]
struct Recording {
    /// The data (`Observations::id`), its sequences' lengths and eps's floats.
    key: (u64, Vec<usize>, usize),
    eps: PooledBuffer,
    /// Buffers cleared before each iteration besides the run's own (`DeviceIteration::clear`).
    clears: Vec<wgpu::Buffer>,
    work: RunWork,
    /// The read-outs' marks for the learner's update ([`GpuOutputLayer::learner_marks`]).
    marks: [Option<(usize, bool)>; 2],
    _keep: Vec<PooledBuffer>,
    _readouts: Vec<EncodedReadout>,
}

/// A learning iteration's sequences as the kernels see them.
struct Batch<'l> {
    lengths: &'l [usize],
    /// Steps of every sequence together.
    total: usize,
    /// Each window's table entry (`RecurrenceLayout::entries`), at the run's slot.
    entries: Vec<WindowEntry>,
    /// Steps before each window.
    before: Vec<usize>,
    /// (first window, count): windows of one length are copied in one dispatch each way,
    /// others one by one.
    groups: Vec<(usize, usize)>,
}

impl<'l> Batch<'l> {
    fn of(layout: &RecurrenceLayout, lengths: &'l [usize], base: WindowEntry) -> Self {
        let mut before = Vec::with_capacity(lengths.len());
        let mut total = 0;
        for &len in lengths {
            before.push(total);
            total += len;
        }
        let groups = if lengths.iter().all(|&l| l == lengths[0]) {
            vec![(0, lengths.len())]
        } else {
            (0..lengths.len()).map(|w| (w, 1)).collect()
        };
        let entries = layout
            .entries(lengths.iter().map(|&len| (len, false)))
            .into_iter()
            .map(|entry| std::array::from_fn(|k| entry[k] + base[k]))
            .collect();
        Self {
            lengths,
            total,
            entries,
            before,
            groups,
        }
    }

    fn windows(&self) -> usize {
        self.lengths.len()
    }
}

impl DeviceIteration {
    /// Uploads the recurrent weights and the adaptive variables of `model` with their
    /// moments from `optimizer` (the weights into `stack`'s slot `slot`; a stack of one when
    /// `None`), adding them to `tensors`; `None` where the kernels do not hold the shapes
    /// or a read-out is not resident (`layers`).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        gpu: &Arc<Gpu>,
        tiling: Tiling,
        profile_kernels: bool,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
        layers: &[Option<Arc<ResidentLayer>>; 2],
        index_of: &TensorIndex<'_>,
        tensors: &mut Vec<ResidentTensor>,
        in_stack: Option<(Arc<Stack>, usize)>,
    ) -> Option<Self> {
        if layers.iter().any(Option::is_none) {
            return None;
        }
        let (stack, slot) = match in_stack {
            Some((stack, slot)) => (stack, slot),
            None => (Stack::new(gpu, tiling, profile_kernels, model, 1)?, 0),
        };
        if slot >= stack.slots || !stack.holds(model) {
            return None;
        }
        let (layout, packed) = RecurrenceLayout::new(&model.params, &model.config);
        let base = slot * packed.len();
        // The moments share the packed layout; each tensor is a range of the buffers.
        let mut moments = [vec![0f32; packed.len()], vec![0f32; packed.len()]];
        let mut ranges = Vec::new();
        for (m, p) in model.params.modules.iter().enumerate() {
            for (tensor, offset) in layout.trainable(m, p) {
                let index = index_of(tensor)?;
                let len = tensor.len();
                moments[0][offset..offset + len].copy_from_slice(&optimizer.m[index]);
                moments[1][offset..offset + len].copy_from_slice(&optimizer.v[index]);
                ranges.push((index, offset, len));
            }
        }
        let write = |buffer: &wgpu::Buffer, values: &[f32]| {
            gpu.queue
                .write_buffer(buffer, (4 * base) as u64, bytemuck::cast_slice(values));
        };
        write(&stack.weights, &packed);
        write(&stack.weights_t, &layout.transposed(&packed));
        write(&stack.moments[0], &moments[0]);
        write(&stack.moments[1], &moments[1]);
        for (index, offset, len) in ranges {
            tensors.push(ResidentTensor {
                index,
                value: stack.weights.clone(),
                moments: stack.moments.clone(),
                grad: stack.grads.clone(),
                len,
                offset: base + offset,
                part: Part::Whole,
            });
        }
        let (adaptive, adaptive_grads) = upload_adaptive(gpu, model, optimizer, tensors);
        Some(Self {
            stack,
            slot,
            config: model.config.clone(),
            adaptive,
            adaptive_grads,
            readouts: GpuOutputLayer::with_resident(gpu.clone(), tiling, &model.params, layers),
            recording: Mutex::default(),
            ahead: Mutex::default(),
            diverged: resident_buffer(gpu, "divergence mark", &[0.0]),
        })
    }

    /// The run's divergence mark (see [`Self::diverged`]'s field).
    pub(crate) fn divergence_mark(&self) -> &wgpu::Buffer {
        &self.diverged
    }

    fn layout(&self) -> &RecurrenceLayout {
        &self.stack.layout
    }

    /// The free energy of the device's model on `data` with every gradient left in the
    /// resident buffers (see the module docs). `eps` per sequence and module, `[len, z]`.
    pub(crate) fn free_energy(
        &self,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<FreeEnergy> {
        pvrnn_core::deferred::now(self.free_energy_later(data, eps)?)
    }

    /// [`Self::free_energy`] prepared now and submitted (with every other run of the stack
    /// prepared by then) when the future is first polled.
    pub(crate) fn free_energy_later(
        &self,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<impl std::future::Future<Output = Result<FreeEnergy>> + '_> {
        let taken = {
            let mut ahead = self.ahead.lock().unwrap_or_else(|e| e.into_inner());
            match ahead.take() {
                Some(a) if a.data == data.id() && a.eps == eps => Some(a),
                Some(a) => {
                    self.stack.withdraw(a.ticket);
                    None
                }
                None => None,
            }
        };
        let (ticket, reading) = match taken {
            Some(a) => (a.ticket, a.reading),
            None => self.enqueue(data, eps)?,
        };
        // Dropped unawaited, the guard takes the iteration back out of the queue.
        let ticket = Ticket {
            stack: &self.stack,
            ticket,
        };
        Ok(async move {
            let results = ticket.results()?;
            Ok(self.free_energy_of(reading, results))
        })
    }

    /// Queues the iteration [`Self::free_energy_later`] would for `data` and `eps`, for its
    /// next call with the same to take; kept if it is queued already.
    pub(crate) fn queue_ahead(
        &self,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<()> {
        let mut ahead = self.ahead.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(a) = ahead.take() {
            if a.data == data.id() && a.eps == eps {
                *ahead = Some(a);
                return Ok(());
            }
            self.stack.withdraw(a.ticket);
        }
        let (ticket, reading) = self.enqueue(data, eps)?;
        *ahead = Some(Ahead {
            data: data.id(),
            eps: eps.to_vec(),
            ticket,
            reading,
        });
        Ok(())
    }

    /// Starts what the stack has queued (this run's and its cohort's), without waiting.
    pub(crate) fn submit_queued(&self) {
        self.stack.submit_prepared();
    }

    /// The iteration on `data` with `eps`, prepared and queued in the stack; its ticket.
    fn enqueue(&self, data: &Observations<f32>, eps: &[[Vec<f32>; 4]]) -> Result<(u64, Reading)> {
        self.check_fits(data, eps)?;
        let stack = &*self.stack;
        // The first iteration uploads the targets and makes the read-outs' scratch.
        let what = || match stack.slots {
            1 => "prepare a learning iteration".to_string(),
            n => format!("prepare a learning iteration of {n} networks trained together"),
        };
        let prepared = stack.gpu.allocating(what, || self.prepare(data, eps))??;
        let reading = prepared.work.reading;
        Ok((stack.enqueue(prepared), reading))
    }

    /// The device work of one iteration of this run, encoded (or replayed from its
    /// [`Recording`]), with what reading its results needs ([`RunWork`]).
    fn prepare(&self, data: &Observations<f32>, eps: &[[Vec<f32>; 4]]) -> Result<Prepared> {
        let stack = &*self.stack;
        let gpu = &*stack.gpu;
        let batch = Batch::of(self.layout(), data.lengths(), stack.entry_base(self.slot));
        let _phase =
            pvrnn_core::profile::phase("evaluate on the device: a run's part, encoded or replayed");
        let (eps_flat, per_module_at) = self.flatten_eps(&batch, eps)?;
        let key = (data.id(), batch.lengths.to_vec(), eps_flat.len());
        let mut clears = gpu.device.create_command_encoder(&Default::default());
        self.clear(&mut clears);
        let mut recording = self.recording.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(r) = recording.as_ref().filter(|r| r.key == key) {
            return Ok(self.replay(r, &eps_flat, clears));
        }
        gpu.count_iteration_encoded();
        let eps_buffer = gpu.upload("eps", &eps_flat);
        let mut keep: Vec<PooledBuffer> = Vec::new();
        let mut inputs = DispatchList::default();
        self.encode_inputs(
            gpu,
            &mut inputs,
            &batch,
            &eps_buffer,
            &per_module_at,
            &mut keep,
        );
        let mut readout_work = DispatchList::default();
        let mut readout_clears = Vec::new();
        let readouts = self.encode_readouts(
            gpu,
            &mut readout_clears,
            &mut readout_work,
            &batch,
            data,
            &mut keep,
        )?;
        for buffer in &readout_clears {
            clears.clear_buffer(buffer, 0, None);
        }
        let mut after = DispatchList::default();
        self.encode_adaptive_grads(gpu, &mut after, &batch, &mut keep);
        let kl = self.encode_kl_terms(gpu, &mut after, &batch, &per_module_at, &mut keep);
        let mut sources = vec![((*kl).clone(), eps_flat.len())];
        sources.extend(
            readouts
                .iter()
                .map(|(r, _)| ((*r.row_loss).clone(), batch.total)),
        );
        self.encode_finite_checks(gpu, &mut after, &sources, &mut keep);
        let divisors = [readouts[0].1, readouts[1].1];
        keep.push(kl);
        let readouts: Vec<EncodedReadout> = readouts.into_iter().map(|(r, _)| r).collect();
        let work = RunWork {
            inputs: Arc::new(inputs),
            readouts: Arc::new(readout_work),
            after: Arc::new(after),
            entries: batch.entries,
            sources,
            reading: Reading {
                total: batch.total,
                per_module_at,
                divisors,
            },
        };
        let prepared = Prepared {
            ticket: 0,
            slot: self.slot,
            clears: Some(clears.finish()),
            work: work.clone(),
        };
        // The buffers stay with the recording, for the next iterations.
        *recording = Some(Recording {
            key,
            eps: eps_buffer,
            clears: readout_clears,
            work,
            marks: self.readouts.learner_marks(),
            _keep: keep,
            _readouts: readouts,
        });
        Ok(prepared)
    }

    /// `r` prepared again: eps written into its buffer (before the submission that uses
    /// it runs: queue order), its clears added to `clears`, the learner's marks set again.
    fn replay(
        &self,
        r: &Recording,
        eps_flat: &[f32],
        mut clears: wgpu::CommandEncoder,
    ) -> Prepared {
        let gpu = &*self.stack.gpu;
        gpu.queue
            .write_buffer(&r.eps, 0, bytemuck::cast_slice(eps_flat));
        for buffer in &r.clears {
            clears.clear_buffer(buffer, 0, None);
        }
        self.readouts.set_learner_marks(r.marks);
        Prepared {
            ticket: 0,
            slot: self.slot,
            clears: Some(clears.finish()),
            work: r.work.clone(),
        }
    }

    /// Whether `data` and `eps` fit the sequences this learner holds.
    fn check_fits(&self, data: &Observations<f32>, eps: &[[Vec<f32>; 4]]) -> Result<()> {
        let lengths = data.lengths();
        let (sequences, steps) = (self.stack.sequences, self.stack.steps);
        if data.sequences() != sequences || data.steps() > steps {
            return Err(Error::Mismatch(format!(
                "the learner holds adaptive variables for {sequences} sequences of {steps} steps, but the data has {} sequences of {} steps",
                data.sequences(),
                data.steps()
            )));
        }
        if lengths.contains(&0) || eps.len() != lengths.len() {
            return Err(Error::Mismatch(
                "every training sequence needs at least one step and its eps".into(),
            ));
        }
        Ok(())
    }

    /// eps per module, `[steps of every window, z]`, and where each module's block starts
    /// (the KL terms come back in the same layout).
    fn flatten_eps(
        &self,
        batch: &Batch<'_>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<(Vec<f32>, [usize; 4])> {
        let modules = self.layout().modules();
        let mut per_module_at = [0usize; 4];
        let mut flat = Vec::with_capacity(batch.total * modules.iter().map(|m| m.z).sum::<usize>());
        for (m, ml) in modules.iter().enumerate() {
            per_module_at[m] = flat.len();
            for (w, &len) in batch.lengths.iter().enumerate() {
                let e = &eps[w][m];
                if e.len() < len * ml.z {
                    return Err(Error::Mismatch(format!(
                        "eps of sequence {w} is shorter than its {len} steps"
                    )));
                }
                flat.extend_from_slice(&e[..len * ml.z]);
            }
        }
        Ok((flat, per_module_at))
    }

    /// Clears what starts from zero: the run's inputs (initial states are zero), its
    /// read-outs' d F / d d (modules without a read-out get none), its adaptive gradients
    /// (steps past a sequence's length get none), its divergence mark.
    fn clear(&self, encoder: &mut wgpu::CommandEncoder) {
        let stack = &*self.stack;
        let s = self.layout().strides();
        let base = stack.entry_base(self.slot);
        let rows = stack.sequences * stack.steps;
        let inputs = stack.sequences * (s.init + stack.steps * s.input);
        encoder.clear_buffer(
            &stack.inputs,
            (4 * base[1]) as u64,
            Some((4 * inputs) as u64),
        );
        encoder.clear_buffer(
            &stack.grad_d,
            (4 * base[4]) as u64,
            Some((4 * rows * s.grad_d) as u64),
        );
        for pair in &self.adaptive_grads {
            for grads in pair {
                encoder.clear_buffer(grads, 0, None);
            }
        }
        // The update after this evaluation reads this evaluation's mark only.
        encoder.clear_buffer(&self.diverged, 0, None);
    }

    /// The recurrence's inputs: per window its initial states (zero), then per step and
    /// module a_mu, a_sigma and eps.
    fn encode_inputs(
        &self,
        gpu: &Gpu,
        work: &mut DispatchList,
        batch: &Batch<'_>,
        eps_buffer: &wgpu::Buffer,
        per_module_at: &[usize; 4],
        keep: &mut Vec<PooledBuffer>,
    ) {
        let s = self.layout().strides();
        let steps = self.stack.steps;
        for &(first, count) in &batch.groups {
            let len = batch.lengths[first];
            for (m, ml) in self.layout().modules().iter().enumerate() {
                let z = ml.z;
                let slot = |k: usize| Strided {
                    offset: batch.entries[first][1] + s.init + ml.input + k * z,
                    block: s.init + len * s.input,
                    row: s.input,
                };
                let adaptive_at = Strided {
                    offset: first * steps * z,
                    block: steps * z,
                    row: z,
                };
                for k in 0..2 {
                    encode_copy(
                        gpu,
                        work,
                        &self.adaptive[m][k],
                        adaptive_at,
                        &self.stack.inputs,
                        slot(k),
                        [count, len, z],
                        keep,
                    );
                }
                let eps_at = Strided {
                    offset: per_module_at[m] + batch.before[first] * z,
                    block: len * z,
                    row: z,
                };
                encode_copy(
                    gpu,
                    work,
                    eps_buffer,
                    eps_at,
                    &self.stack.inputs,
                    slot(2),
                    [count, len, z],
                    keep,
                );
            }
        }
    }

    /// Both read-outs from the module states in the record, their d F / d d into the
    /// recurrence's layout.
    fn encode_readouts(
        &self,
        gpu: &Gpu,
        clears: &mut Vec<wgpu::Buffer>,
        work: &mut DispatchList,
        batch: &Batch<'_>,
        data: &Observations<f32>,
        keep: &mut Vec<PooledBuffer>,
    ) -> Result<Vec<(EncodedReadout, usize)>> {
        let config = &self.config;
        let observed = Observed::all(config);
        let mut readouts = Vec::with_capacity(2);
        for modality in Modality::ALL {
            let k = observed.dims(config, modality);
            let targets: Vec<&[f32]> = (0..batch.windows())
                .flat_map(|w| (0..batch.lengths[w]).map(move |t| data.step(modality, w, t)))
                .collect();
            let readout = encode_readout_of_record(
                gpu,
                &self.readouts,
                config,
                self.layout(),
                clears,
                work,
                RecordRows {
                    record: &self.stack.record,
                    grad_d: &self.stack.grad_d,
                    first: self.stack.first_row(self.slot),
                    rows: batch.total,
                },
                modality,
                k,
                &targets,
                Some(data.id()),
                true,
                keep,
            )
            .ok_or_else(|| {
                Error::Mismatch(format!(
                    "the {} read-out is not on the device",
                    modality.name()
                ))
            })?;
            readouts.push(readout);
        }
        Ok(readouts)
    }

    /// d F / d a from the backward record out to the adaptive variables' layout.
    fn encode_adaptive_grads(
        &self,
        gpu: &Gpu,
        work: &mut DispatchList,
        batch: &Batch<'_>,
        keep: &mut Vec<PooledBuffer>,
    ) {
        let s = self.layout().strides();
        let steps = self.stack.steps;
        for (m, ml) in self.layout().modules().iter().enumerate() {
            let z = ml.z;
            for k in 0..2 {
                for &(first, count) in &batch.groups {
                    let len = batch.lengths[first];
                    encode_copy(
                        gpu,
                        work,
                        &self.stack.back,
                        Strided {
                            offset: batch.entries[first][5] + ml.back + k * z,
                            block: len * s.back,
                            row: s.back,
                        },
                        &self.adaptive_grads[m][k],
                        Strided {
                            offset: first * steps * z,
                            block: steps * z,
                            row: z,
                        },
                        [count, len, z],
                        keep,
                    );
                }
            }
        }
    }

    /// The KL terms per step and unit (the last of the record's rows) into one buffer to
    /// read back, per module at `per_module_at`.
    fn encode_kl_terms(
        &self,
        gpu: &Gpu,
        work: &mut DispatchList,
        batch: &Batch<'_>,
        per_module_at: &[usize; 4],
        keep: &mut Vec<PooledBuffer>,
    ) -> PooledBuffer {
        let modules = self.layout().modules();
        let values = batch.total * modules.iter().map(|m| m.z).sum::<usize>();
        let kl = gpu.scratch("KL terms", values, wgpu::BufferUsages::COPY_SRC);
        let s = self.layout().strides();
        let first = self.stack.first_row(self.slot) * s.record;
        for (m, ml) in modules.iter().enumerate() {
            encode_copy(
                gpu,
                work,
                &self.stack.record,
                Strided::rows(first + ml.record + 2 * ml.d + 8 * ml.z, s.record),
                &kl,
                Strided::rows(per_module_at[m], ml.z),
                [1, batch.total, ml.z],
                keep,
            );
        }
        kl
    }

    /// The divergence mark set when one of the free-energy terms in `sources` is not
    /// finite (`shaders/finite_check.wgsl`).
    fn encode_finite_checks(
        &self,
        gpu: &Gpu,
        work: &mut DispatchList,
        sources: &[(wgpu::Buffer, usize)],
        keep: &mut Vec<PooledBuffer>,
    ) {
        let kernel = gpu.finite_check_kernel();
        for (terms, count) in sources.iter().filter(|(_, n)| *n > 0) {
            let (groups_x, groups_y) = grid(gpu, *count);
            let uniform = gpu.uniform(&FiniteCheckParams {
                count: *count as u32,
                groups_x,
                _pad: [0; 2],
            });
            let group = bind(gpu, &kernel, &[&uniform, terms, &self.diverged]);
            dispatch(work, &kernel, &group, groups_x, groups_y);
            keep.push(uniform);
        }
    }

    /// F from what came back: the KL terms, then each read-out's row losses.
    fn free_energy_of(&self, reading: Reading, results: Vec<Vec<f32>>) -> FreeEnergy {
        let Reading {
            total,
            per_module_at,
            divisors,
        } = reading;
        let mut results = results.into_iter();
        let kl = results.next().unwrap_or_default();
        let mut complexity = [0.0; 4];
        for (m, ml) in self.layout().modules().iter().enumerate() {
            let z = ml.z;
            let terms = &kl[per_module_at[m]..per_module_at[m] + total * z];
            // As the CPU backend: per step the units' terms summed in f64, divided by z.
            complexity[m] = terms
                .chunks_exact(z.max(1))
                .map(|step| step.iter().map(|&v| v as f64).sum::<f64>() / z as f64)
                .sum();
        }
        let mut accuracy = [0.0; 2];
        for ((sum, divisor), sums) in accuracy.iter_mut().zip(divisors).zip(results) {
            *sum = row_losses(sums, divisor).into_iter().sum();
        }
        FreeEnergy::from_terms(accuracy, complexity, self.config.kl_weight)
    }

    /// Records the refresh of the forward kernel's copy of the run's weights after an
    /// update of the packed ones (the matrices transposed over the copy), for
    /// [`Self::encode_transposes`].
    pub(crate) fn record_transposes(
        &self,
        gpu: &Gpu,
        keep: &mut Vec<PooledBuffer>,
    ) -> DispatchList {
        let stack = &*self.stack;
        let base = self.slot * stack.weight_floats();
        let mut work = DispatchList::default();
        for (at, rows, cols) in self.layout().matrices() {
            encode_copy(
                gpu,
                &mut work,
                &stack.weights,
                Strided {
                    offset: base + at,
                    block: cols,
                    row: 1,
                },
                &stack.weights_t,
                Strided {
                    offset: base + at,
                    block: 1,
                    row: rows,
                },
                [rows, cols, 1],
                keep,
            );
        }
        work
    }

    /// Encodes the refresh: every value copied (the prior biases are read there too), then
    /// the matrices transposed over theirs (`transposes`, from [`Self::record_transposes`]),
    /// their pass timed as `times`' part `part` where given.
    pub(crate) fn encode_transposes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        transposes: &DispatchList,
        (times, part): (Option<&PassTimes>, usize),
    ) {
        let stack = &*self.stack;
        let floats = stack.weight_floats();
        let base = self.slot * floats;
        encoder.copy_buffer_to_buffer(
            &stack.weights,
            (4 * base) as u64,
            &stack.weights_t,
            (4 * base) as u64,
            (4 * floats) as u64,
        );
        let mut pass = begin_pass(encoder, times, part);
        transposes.replay(&mut pass);
    }
}

/// The adaptive variables of `model` uploaded with their moments from `optimizer` (they
/// follow the parameters in the trainer's order), added to `tensors`: per module, a_mu and
/// a_sigma, and their gradients.
#[allow(clippy::type_complexity)]
fn upload_adaptive(
    gpu: &Gpu,
    model: &Model<f32>,
    optimizer: &RAdam<f32>,
    tensors: &mut Vec<ResidentTensor>,
) -> ([[wgpu::Buffer; 2]; 4], [[wgpu::Buffer; 2]; 4]) {
    let first_adaptive = model
        .params
        .named()
        .iter()
        .filter(|(_, _, role)| *role == pvrnn_core::params::Role::Trainable)
        .count();
    let mut adaptive_tensor = |m: usize, k: usize| {
        let tensor = if k == 0 {
            &model.adaptive.a_mu[m]
        } else {
            &model.adaptive.a_sigma[m]
        };
        let index = first_adaptive + 2 * m + k;
        let value = resident_buffer(gpu, "resident adaptive variables", tensor.data());
        let grad = resident_buffer(
            gpu,
            "resident adaptive gradients",
            &vec![0f32; tensor.len()],
        );
        tensors.push(ResidentTensor {
            index,
            value: value.clone(),
            moments: [
                resident_buffer(gpu, "resident m", &optimizer.m[index]),
                resident_buffer(gpu, "resident v", &optimizer.v[index]),
            ],
            grad: grad.clone(),
            len: tensor.len(),
            offset: 0,
            part: Part::Whole,
        });
        (value, grad)
    };
    let pairs: [[(wgpu::Buffer, wgpu::Buffer); 2]; 4] =
        std::array::from_fn(|m| std::array::from_fn(|k| adaptive_tensor(m, k)));
    let adaptive = pairs.clone().map(|pair| pair.map(|(value, _)| value));
    let grads = pairs.map(|pair| pair.map(|(_, grad)| grad));
    (adaptive, grads)
}

/// A recurrence record's rows (`rows` from row `first`) and the buffer for the read-outs'
/// d F / d d in the recurrence's layout.
pub(crate) struct RecordRows<'a> {
    pub(crate) record: &'a wgpu::Buffer,
    pub(crate) grad_d: &'a wgpu::Buffer,
    pub(crate) first: usize,
    pub(crate) rows: usize,
}

/// Encodes the whole read-out of `modality` (its first `k` dimensions observed) from the
/// module states in a recurrence record: the states copied out into the read-out's input
/// (the output layer's padded rows, for a read-out without hidden layers: the buffer goes
/// into `clears`, for the caller to clear before the submission),
/// the read-out ([`GpuOutputLayer::encode_readout`]) and its d F / d d copied into the
/// recurrence's layout. Returns the read-out and its accuracy divisor; `None` unless the
/// read-out is on the device whole. Buffers the submission uses go into `keep`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn encode_readout_of_record(
    gpu: &Gpu,
    readouts: &GpuOutputLayer,
    config: &ModelConfig,
    layout: &RecurrenceLayout,
    clears: &mut Vec<wgpu::Buffer>,
    work: &mut dyn Recorder,
    at: RecordRows<'_>,
    modality: Modality,
    k: usize,
    targets: &[&[f32]],
    resident: Option<u64>,
    weight_grads: bool,
    keep: &mut Vec<PooledBuffer>,
) -> Option<(EncodedReadout, usize)> {
    let s = layout.strides();
    let ml = layout.modules()[modality.module().index()];
    let d = ml.d;
    let divisor = config
        .accuracy_normalisation
        .divisor(k, config.modality_dims(modality));
    let width = if config.readout(modality).hidden.is_empty() {
        4 * vec4s(d)
    } else {
        d
    };
    let input = gpu.scratch(
        "read-out input",
        at.rows * width,
        wgpu::BufferUsages::empty(),
    );
    if width != d {
        clears.push((*input).clone());
    }
    encode_copy(
        gpu,
        work,
        at.record,
        Strided::rows(at.first * s.record + ml.record + d, s.record),
        &input,
        Strided::rows(0, width),
        [1, at.rows, d],
        keep,
    );
    let readout = readouts.encode_readout(
        work,
        modality,
        &input,
        at.rows,
        k,
        divisor,
        targets,
        resident,
        weight_grads,
    )?;
    encode_copy(
        gpu,
        work,
        &readout.grad_d,
        Strided::rows(0, readout.grad_stride),
        at.grad_d,
        Strided::rows(at.first * s.grad_d + ml.grad_d, s.grad_d),
        [1, at.rows, d],
        keep,
    );
    keep.push(input);
    Some((readout, divisor))
}
