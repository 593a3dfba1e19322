//! One learning run on the device ([`DeviceIteration`]): its recurrent weights uploaded into
//! its stack's slot and its adaptive variables into buffers of its own, its iterations
//! queued (or queued ahead of their call), and its free energy read from what comes back.

use std::sync::{Arc, Mutex};

use pvrnn_core::data::Observations;
use pvrnn_core::free_energy::FreeEnergy;
use pvrnn_core::optim::RAdam;
use pvrnn_core::params::Model;
use pvrnn_core::{ModelConfig, Result};

use crate::encode::row_losses;
use crate::gpu::Gpu;
use crate::output::{EncodedReadout, GpuOutputLayer, Tiling};
use crate::pool::PooledBuffer;
use crate::recurrence::RecurrenceLayout;
use crate::resident::{Part, ResidentLayer, ResidentTensor, TensorIndex, resident_buffer};

use super::queue::Ticket;
use super::stack::{Reading, RunWork, Stack};

/// One learning run's recurrence and adaptive variables, resident in its [`Stack`] slot
/// and its own buffers (see the module docs), and the read-outs it feeds.
#[derive(Debug)]
pub(crate) struct DeviceIteration {
    pub(super) stack: Arc<Stack>,
    pub(super) slot: usize,
    pub(super) config: ModelConfig,
    /// Per module, a_mu and a_sigma of every sequence, `[sequences, steps, z]`, and their
    /// gradients.
    pub(super) adaptive: [[wgpu::Buffer; 2]; 4],
    pub(super) adaptive_grads: [[wgpu::Buffer; 2]; 4],
    pub(super) readouts: GpuOutputLayer,
    /// The run's part of an iteration as last encoded, to replay.
    pub(super) recording: Mutex<Option<Recording>>,
    /// The evaluation queued ahead of its call (`Learner::queue_free_energy`).
    ahead: Mutex<Option<Ahead>>,
    /// The run's divergence mark: cleared as an evaluation starts and set when its
    /// free-energy terms are not finite (`shaders/finite_check.wgsl`); the learner's
    /// update queued after that evaluation reads it.
    pub(super) diverged: wgpu::Buffer,
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
pub(super) struct Recording {
    /// The data (`Observations::id`), its sequences' lengths and eps's floats.
    pub(super) key: (u64, Vec<usize>, usize),
    pub(super) eps: PooledBuffer,
    /// Buffers cleared before each iteration besides the run's own (`DeviceIteration::clear`).
    pub(super) clears: Vec<wgpu::Buffer>,
    pub(super) work: RunWork,
    /// The read-outs' marks for the learner's update ([`GpuOutputLayer::learner_marks`]).
    pub(super) marks: [Option<(usize, bool)>; 2],
    pub(super) _keep: Vec<PooledBuffer>,
    pub(super) _readouts: Vec<EncodedReadout>,
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

    pub(super) fn layout(&self) -> &RecurrenceLayout {
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
