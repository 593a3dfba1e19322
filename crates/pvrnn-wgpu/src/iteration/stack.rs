//! What the learning runs of a cohort share on the device ([`Stack`]): every run's recurrent
//! weights with their gradients and moments, and the recurrence's inputs, records and
//! gradients, each run's part at its slot; and the work queued in it (a run's prepared part,
//! a submission on its way, the recurrence's part recorded for replay).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use pvrnn_core::params::Model;

use crate::encode::DispatchList;
use crate::gpu::{Gpu, RecurrenceKernels};
use crate::output::Tiling;
use crate::pool::PooledBuffer;
use crate::readback::ReadBack;
use crate::recurrence::{RecurrenceLayout, WindowEntry};
use crate::resident::resident_buffer;

/// What the learning runs of a cohort share on the device (see the module docs): `slots`
/// runs of `sequences` x `steps`, each run's part of every buffer at its slot.
#[derive(Debug)]
pub(crate) struct Stack {
    pub(super) gpu: Arc<Gpu>,
    pub(super) layout: RecurrenceLayout,
    pub(super) kernels: Arc<RecurrenceKernels>,
    /// `WgpuOptions::profile_kernels`.
    pub(super) profile_kernels: bool,
    /// The recurrence part of the last submission, with the runs (slot, windows) it was
    /// encoded for, replayed while they stay.
    pub(super) recurrence_recording: Mutex<Option<RecordedRecurrence>>,
    pub(super) slots: usize,
    pub(super) sequences: usize,
    pub(super) steps: usize,
    /// The packed recurrent weights (the recurrence's layout), the same with every matrix
    /// transposed for the forward kernel (refreshed after each update), their gradients
    /// and RAdam moments.
    pub(super) weights: wgpu::Buffer,
    pub(super) weights_t: wgpu::Buffer,
    pub(super) grads: wgpu::Buffer,
    pub(super) moments: [wgpu::Buffer; 2],
    /// The recurrence's inputs, the read-outs' d F / d d in its layout, its forward record
    /// and its backward record, every sequence at full length.
    pub(super) inputs: wgpu::Buffer,
    pub(super) grad_d: wgpu::Buffer,
    pub(super) record: wgpu::Buffer,
    pub(super) back: wgpu::Buffer,
    pub(super) queue: Mutex<Queue>,
}

/// Iterations prepared and not yet submitted, submitted and not yet read back, and
/// results not yet taken.
#[derive(Debug, Default)]
pub(super) struct Queue {
    pub(super) next_ticket: u64,
    pub(super) prepared: Vec<Prepared>,
    /// Oldest first.
    pub(super) in_flight: Vec<InFlight>,
    pub(super) results: HashMap<u64, Vec<Vec<f32>>>,
    /// The iterations whose submission failed (the device out of memory making the
    /// recurrence's scratch), with what the device said: their results are that error.
    pub(super) failed: HashMap<u64, String>,
}

/// One submission on its way: its runs' tickets (`None`: withdrawn) with how many of the
/// read-back's parts are theirs, and what it uses, kept until it has run.
#[derive(Debug)]
pub(super) struct InFlight {
    pub(super) tickets: Vec<(Option<u64>, usize)>,
    pub(super) read_back: ReadBack,
    pub(super) _prepared: Vec<Prepared>,
    pub(super) _recurrence: Arc<RecurrenceWork>,
}

/// One run's part of an iteration, encoded (see
/// [`DeviceIteration::free_energy_later`](super::DeviceIteration::free_energy_later)).
#[derive(Debug)]
pub(super) struct Prepared {
    pub(super) ticket: u64,
    pub(super) slot: usize,
    /// Clears of what starts from zero (and the read-outs' own), before everything else;
    /// taken when submitted.
    pub(super) clears: Option<wgpu::CommandBuffer>,
    /// Its dispatches (the buffers they use are kept by the run's
    /// [`Recording`](super::run::Recording)).
    pub(super) work: RunWork,
}

/// A run's dispatches of one iteration and what reading its results needs (shared by a
/// [`Prepared`] iteration and the run's [`Recording`](super::run::Recording)).
#[derive(Clone, Debug)]
pub(super) struct RunWork {
    /// Before the recurrence forward: the inputs; between forward and backward: the
    /// read-outs; after the backward: the adaptive variables' gradients and the KL terms.
    pub(super) inputs: Arc<DispatchList>,
    pub(super) readouts: Arc<DispatchList>,
    pub(super) after: Arc<DispatchList>,
    pub(super) entries: Vec<WindowEntry>,
    /// What to read back (KL terms, each read-out's row losses) with its length.
    pub(super) sources: Vec<(wgpu::Buffer, usize)>,
    pub(super) reading: Reading,
}

/// What turns a run's read-back into its free energy
/// ([`DeviceIteration::free_energy_of`](super::DeviceIteration::free_energy_of)).
#[derive(Clone, Copy, Debug)]
pub(super) struct Reading {
    pub(super) total: usize,
    pub(super) per_module_at: [usize; 4],
    pub(super) divisors: [usize; 2],
}

/// A submission's recurrence part and the runs it was encoded for (their slots and window
/// entries): the same runs replay it, for they bind the same buffers and shapes.
#[derive(Debug)]
pub(super) struct RecordedRecurrence {
    pub(super) runs: Vec<(usize, Vec<WindowEntry>)>,
    pub(super) work: Arc<RecurrenceWork>,
}

/// What [`Stack::encode_recurrence`] encodes: the table, the dispatches per part, and the
/// buffers to keep until the submission has run (or while it is recorded).
#[derive(Debug)]
pub(super) struct RecurrenceWork {
    pub(super) forward: DispatchList,
    pub(super) backward: DispatchList,
    pub(super) weight_grads: DispatchList,
    /// The table, uniforms and scratch the dispatches bind, held from the pool.
    pub(super) _buffers: Vec<PooledBuffer>,
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

    pub(super) fn weight_floats(&self) -> usize {
        self.layout.weight_floats()
    }

    /// Where slot `slot`'s part of the inputs, the record, the read-out gradients and the
    /// backward record start, and its weights: added to a run's own window entries.
    pub(super) fn entry_base(&self, slot: usize) -> WindowEntry {
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
    pub(super) fn first_row(&self, slot: usize) -> usize {
        slot * self.sequences * self.steps
    }
}
