//! Learning with the read-outs resident on the GPU (pvrnn-core's [`Learner`]): their
//! weights, biases and RAdam moments, hidden layers included, are uploaded once per run.
//! Every iteration a read-out takes the module states, runs its hidden layers and output
//! layer forward and back (`GpuOutputLayer::readout_loss`), leaves every weight gradient
//! in the learner's buffers and returns dF/dd; `radam.wgsl` then updates the weights where
//! they are. At the paper's scale that is 1.6 M of the model's 1.7 M weights, so an
//! iteration no longer uploads 6.5 MB of weights nor reads 6.5 MB of gradients back, and
//! the host's RAdam covers only the rest. The recurrence and the KL terms stay where
//! [`WgpuBackend`] puts them; with the recurrence on the GPU, the learner keeps the
//! recurrent weights and the adaptive variables too and runs the whole iteration
//! ([`DeviceIteration`]). A learner's loaded models serve learning's evaluation only:
//! the host's copies of the resident weights are stale until downloaded.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use pvrnn_core::ModelConfig;
use pvrnn_core::backend::{Backend, Learner, LoadedModel};
use pvrnn_core::optim::{RAdam, RAdamStep};
use pvrnn_core::params::{Model, Params, Role};

use crate::WgpuBackend;
use crate::encode::{DispatchList, Recorder, bind, dispatch, grid, unpad_rows, vec4s};
use crate::gpu::Gpu;
use crate::iteration::{DeviceIteration, Stack};
use crate::pool::PooledBuffer;
use crate::readback::read_back;
use crate::resident::{Part, ResidentLayer, ResidentTensor, resident_buffer};
use crate::timing::{PassTimes, begin_pass};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RAdamParams {
    count: u32,
    live: u32,
    groups_x: u32,
    rectified: u32,
    b1: f32,
    b2: f32,
    one_b1: f32,
    one_b2: f32,
    wd: f32,
    eps: f32,
    sqrt_bias2: f32,
    lr: f32,
    offset: u32,
    _pad: [u32; 3],
}

/// A learning run on [`WgpuBackend`] with its read-outs resident (see the module docs), and
/// with the recurrence on the GPU ([`WgpuBackend::with_recurrence_on_gpu`]) everything
/// else too (`iteration/`).
#[derive(Debug)]
pub struct GpuLearner {
    backend: WgpuBackend,
    layers: [Option<Arc<ResidentLayer>>; 2],
    /// The recurrence and the adaptive variables, when the whole iteration runs here.
    iteration: Option<DeviceIteration>,
    /// Their tensors (ranges of the packed recurrent weights, the adaptive variables).
    more: Vec<ResidentTensor>,
    resident: Vec<usize>,
    /// The update as first encoded, to replay with each step's scalars.
    recorded_update: Mutex<Option<RecordedUpdate>>,
    /// What the updates read to skip after a diverged iteration: the whole iteration's
    /// divergence mark, or one never set when the host checks the free energy first.
    divergence_mark: wgpu::Buffer,
}

/// A learner's update as first encoded: the RAdam dispatches with their uniform buffers
/// (rewritten with each step's scalars), and with the recurrence on the device the
/// refresh of its transposed weights. Every tensor's update is the same dispatch each
/// step; only the scalars and how many of its values have a gradient change.
#[derive(Debug)]
struct RecordedUpdate {
    radam: DispatchList,
    /// The uniforms of `radam`'s dispatches, in the order of [`GpuLearner::updates`].
    params: Vec<PooledBuffer>,
    transposes: Option<DispatchList>,
    _keep: Vec<PooledBuffer>,
}

impl GpuLearner {
    /// Uploads the read-outs of `model` that the kernels hold, with their moments from
    /// `optimizer`; `None` if there is none to keep.
    pub(crate) fn new(
        backend: &WgpuBackend,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
    ) -> Option<Self> {
        Self::in_stack(backend, model, optimizer, None)
    }

    /// [`Self::new`] with the recurrence in slot `slot` of a cohort's [`Stack`] (`None`: a
    /// stack of its own).
    pub(crate) fn in_stack(
        backend: &WgpuBackend,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
        in_stack: Option<(Arc<Stack>, usize)>,
    ) -> Option<Self> {
        let index_of = trainable_indices(&model.params);
        let layers: [Option<Arc<ResidentLayer>>; 2] = std::array::from_fn(|mi| {
            ResidentLayer::upload(backend.gpu(), &model.params, (optimizer, &index_of), mi)
                .map(Arc::new)
        });
        let mut more = Vec::new();
        let iteration = backend
            .recurrence_on_gpu()
            .then(|| {
                DeviceIteration::new(
                    backend.gpu(),
                    backend.tiling(),
                    backend.options().profile_kernels,
                    model,
                    optimizer,
                    &layers,
                    &index_of,
                    &mut more,
                    in_stack,
                )
            })
            .flatten();
        let resident: Vec<usize> = layers
            .iter()
            .flatten()
            .flat_map(|l| l.tensors.iter().map(|t| t.index))
            .chain(more.iter().map(|t| t.index))
            .collect();
        (!resident.is_empty()).then(|| Self {
            backend: backend.clone(),
            layers,
            divergence_mark: match &iteration {
                Some(iteration) => iteration.divergence_mark().clone(),
                None => resident_buffer(backend.gpu(), "divergence mark, never set", &[0.0]),
            },
            iteration,
            more,
            resident,
            recorded_update: Mutex::default(),
        })
    }

    /// Learners for `runs` sharing one [`Stack`] (a cohort); `None` unless they run whole
    /// iterations on the device (`--gpu-recurrence`, resident learning), are at least two
    /// and have one shape.
    pub(crate) fn cohort(
        backend: &WgpuBackend,
        runs: &[(&Model<f32>, &RAdam<f32>)],
    ) -> Option<Vec<Self>> {
        let (first, _) = runs.first()?;
        if runs.len() < 2
            || !backend.recurrence_on_gpu()
            || !backend.resident_learning()
            || runs.iter().any(|(model, _)| model.config != first.config)
        {
            return None;
        }
        // As many runs per stack as one dispatch's buffers hold (the device's binding
        // limits), the rest in further stacks.
        let per_stack = (1..=runs.len())
            .rev()
            .find(|&slots| Stack::fits(backend.gpu(), first, slots))?;
        let mut learners = Vec::with_capacity(runs.len());
        for chunk in runs.chunks(per_stack) {
            let profile_kernels = backend.options().profile_kernels;
            let stack = Stack::new(
                backend.gpu(),
                backend.tiling(),
                profile_kernels,
                first,
                chunk.len(),
            )?;
            for (slot, (model, optimizer)) in chunk.iter().enumerate() {
                let learner =
                    Self::in_stack(backend, model, optimizer, Some((stack.clone(), slot)))
                        .filter(|learner| learner.iteration.is_some())?;
                learners.push(learner);
            }
        }
        Some(learners)
    }

    fn gpu(&self) -> &Gpu {
        self.backend.gpu()
    }

    /// Every resident tensor with its RAdam step's parameters: its first `live` elements
    /// with their gradient (what the last evaluation wrote, whose marks this takes), the
    /// rest without.
    fn updates(&self, step: &RAdamStep) -> Vec<(&ResidentTensor, RAdamParams)> {
        let gpu = self.gpu();
        let params = |t: &ResidentTensor, live: usize| {
            let (groups_x, _) = grid(gpu, t.len);
            RAdamParams {
                count: t.len as u32,
                live: live as u32,
                groups_x,
                rectified: step.rectified.is_some() as u32,
                b1: step.beta1 as f32,
                b2: step.beta2 as f32,
                one_b1: (1.0 - step.beta1) as f32,
                one_b2: (1.0 - step.beta2) as f32,
                wd: step.weight_decay as f32,
                eps: step.eps as f32,
                sqrt_bias2: step.sqrt_bias2 as f32,
                lr: step.rectified.unwrap_or(step.plain) as f32,
                offset: t.offset as u32,
                _pad: [0; 3],
            }
        };
        let mut updates = Vec::new();
        for layer in self.layers.iter().flatten() {
            let k = layer.rows_with_gradient.swap(0, Ordering::SeqCst);
            let hidden = layer.hidden_gradients.swap(false, Ordering::SeqCst);
            for t in &layer.tensors {
                let live = match t.part {
                    Part::OutputWeight => k * 4 * vec4s(layer.hidden_width),
                    Part::OutputBias => k,
                    Part::Hidden if hidden => t.len,
                    Part::Hidden => 0,
                    Part::Whole => t.len,
                };
                updates.push((t, params(t, live)));
            }
        }
        updates.extend(self.more.iter().map(|t| (t, params(t, t.len))));
        updates
    }

    /// Encodes one RAdam step of `t` with `params`; returns the uniform buffer holding them.
    fn encode_update(
        &self,
        encoder: &mut dyn Recorder,
        t: &ResidentTensor,
        params: &RAdamParams,
    ) -> PooledBuffer {
        let gpu = self.gpu();
        let (groups_x, groups_y) = grid(gpu, t.len);
        let uniform = gpu.uniform(params);
        let kernel = gpu.radam_kernel();
        let group = bind(
            gpu,
            &kernel,
            &[
                &uniform,
                &t.value,
                &t.moments[0],
                &t.moments[1],
                &t.grad,
                &self.divergence_mark,
            ],
        );
        dispatch(encoder, &kernel, &group, groups_x, groups_y);
        uniform
    }

    /// The update encoded: every tensor's RAdam dispatch with its parameters' uniform, and
    /// the transposes' dispatches (with the buffers they keep).
    fn record_update(&self, updates: &[(&ResidentTensor, RAdamParams)]) -> RecordedUpdate {
        let mut radam = DispatchList::default();
        let params = updates
            .iter()
            .map(|(t, p)| self.encode_update(&mut radam, t, p))
            .collect();
        let mut keep = Vec::new();
        let transposes = self
            .iteration
            .as_ref()
            .map(|iteration| iteration.record_transposes(self.gpu(), &mut keep));
        RecordedUpdate {
            radam,
            params,
            transposes,
            _keep: keep,
        }
    }
}

/// A function giving a tensor's index in the trainer's order of trainable tensors (the
/// parameters that are `Role::Trainable`, in `Params::named` order, then the adaptive
/// variables), or `None` for a fixed one.
fn trainable_indices(params: &Params<f32>) -> impl Fn(&pvrnn_core::Tensor<f32>) -> Option<usize> {
    let addresses: Vec<*const pvrnn_core::Tensor<f32>> = params
        .named()
        .into_iter()
        .filter(|(_, _, role)| *role == Role::Trainable)
        .map(|(_, t, _)| t as *const _)
        .collect();
    move |tensor| addresses.iter().position(|&a| std::ptr::eq(a, tensor))
}

impl Backend<f32> for GpuLearner {
    /// A model whose read-outs are the learner's. When the learner runs whole iterations,
    /// the recurrent weights and adaptive variables it keeps are not in such a model (it
    /// takes them from `params` and the windows, the host's stale copies): learning then
    /// evaluates through [`Learner::free_energy`] only, as `Trainer` does.
    fn load(&self, params: &Params<f32>, config: &ModelConfig) -> Box<dyn LoadedModel<f32>> {
        self.backend.load_with_layers(
            params,
            config,
            &self.layers,
            self.backend.recurrence_on_gpu(),
        )
    }
}

impl Learner<f32> for GpuLearner {
    fn resident(&self) -> &[usize] {
        &self.resident
    }

    fn failure(&self) -> Option<pvrnn_core::Error> {
        self.gpu().failure()
    }

    fn update(&self, step: &RAdamStep) {
        let gpu = self.gpu();
        let updates = self.updates(step);
        let mut recorded = self
            .recorded_update
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let update: &RecordedUpdate = match &mut *recorded {
            Some(r) if r.params.len() == updates.len() => {
                // The same dispatches: only their parameters change (written before the
                // submission below runs: queue order).
                for (uniform, (_, params)) in r.params.iter().zip(&updates) {
                    gpu.queue
                        .write_buffer(uniform, 0, bytemuck::bytes_of(params));
                }
                r
            }
            slot => slot.insert(self.record_update(&updates)),
        };
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let transposes = self.iteration.as_ref().zip(update.transposes.as_ref());
        let names = [
            "device: optimiser (RAdam)",
            "device: recurrent weights transposed for the forward kernel",
        ];
        let times = PassTimes::new(gpu, &names[..1 + usize::from(transposes.is_some())]);
        {
            // Every tensor's update in one compute pass.
            let mut pass = begin_pass(&mut encoder, times.as_ref(), 0);
            update.radam.replay(&mut pass);
        }
        if let Some((iteration, transposes)) = transposes {
            iteration.encode_transposes(&mut encoder, transposes, (times.as_ref(), 1));
        }
        if let Some(times) = &times {
            times.resolve(&mut encoder);
        }
        // Queued, not waited for: the next iteration's submissions run after it.
        gpu.queue.submit([encoder.finish()]);
        if let Some(times) = times {
            times.collect(gpu);
        }
    }

    fn download(&self, index: usize, value: &mut [f32], m: &mut [f32], v: &mut [f32]) {
        let found = self
            .layers
            .iter()
            .flatten()
            .find_map(|l| {
                l.tensors
                    .iter()
                    .find(|t| t.index == index)
                    .map(|t| (Some(l.hidden_width), t))
            })
            .or_else(|| {
                self.more
                    .iter()
                    .find(|t| t.index == index)
                    .map(|t| (None, t))
            });
        let Some((layer_width, t)) = found else {
            panic!("tensor {index} is not resident on this learner");
        };
        let gpu = self.gpu();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // The tensor's range of its three buffers (a packed buffer holds others too).
        let len = t.len;
        let part = gpu.scratch("download", 3 * len, wgpu::BufferUsages::COPY_SRC);
        let [mb, vb] = &t.moments;
        for (k, buffer) in [&t.value, mb, vb].into_iter().enumerate() {
            encoder.copy_buffer_to_buffer(
                buffer,
                (4 * t.offset) as u64,
                &part,
                (4 * k * len) as u64,
                (4 * len) as u64,
            );
        }
        let results = pvrnn_core::deferred::now(read_back(gpu, encoder, &[(&part, 3 * len)]));
        drop(part);
        let values = results.into_iter().next().unwrap_or_default();
        for (dst, src) in [value, m, v]
            .into_iter()
            .zip(values.chunks_exact(len.max(1)))
        {
            match layer_width {
                Some(width) if t.part == Part::OutputWeight => {
                    dst.copy_from_slice(&unpad_rows(src, width));
                }
                _ => dst.copy_from_slice(src),
            }
        }
    }

    fn runs_whole_iterations(&self) -> bool {
        self.iteration.is_some()
    }

    fn free_energy(
        &self,
        data: &pvrnn_core::Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Option<pvrnn_core::Result<pvrnn_core::FreeEnergy>> {
        let iteration = self.iteration.as_ref()?;
        Some(iteration.free_energy(data, eps))
    }

    /// With the whole iteration on the device: its updates read the run's divergence mark
    /// (`shaders/finite_check.wgsl`), so the trainer queues the next iteration before it
    /// reads this one's free energy back. On an H200 (2026-12-01) that took one network's
    /// iteration from 0.0122 to 0.0103 s and five networks' from 0.0420 to 0.0325 s.
    fn guards_updates(&self) -> bool {
        self.iteration.is_some()
    }

    fn queue_free_energy(
        &self,
        data: &pvrnn_core::Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> pvrnn_core::Result<()> {
        match &self.iteration {
            Some(iteration) => iteration.queue_ahead(data, eps),
            None => Ok(()),
        }
    }

    fn submit_queued(&self) {
        if let Some(iteration) = &self.iteration {
            iteration.submit_queued();
        }
    }

    fn begin_free_energy<'a>(
        &'a self,
        data: &'a pvrnn_core::Observations<f32>,
        eps: &'a [[Vec<f32>; 4]],
    ) -> Option<pvrnn_core::deferred::Deferred<'a, pvrnn_core::Result<pvrnn_core::FreeEnergy>>>
    {
        let iteration = self.iteration.as_ref()?;
        Some(match iteration.free_energy_later(data, eps) {
            Ok(later) => Box::pin(later),
            Err(e) => pvrnn_core::deferred::ready(Err(e)),
        })
    }
}
