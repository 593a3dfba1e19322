//! A whole learning iteration on the device: the recurrence's weights and every training
//! sequence's adaptive variables stay there with their RAdam moments, beside the read-outs
//! ([`crate::learner`]), so that an iteration uploads only its eps and a small table, runs
//! in one submission (inputs packed from the adaptive variables and eps, the recurrence
//! forward, both read-outs from the module states in its record, their d F / d d into the
//! recurrence's backward pass, the recurrent weights' and the adaptive variables'
//! gradients) and reads back only what the free energy needs: the read-outs' row losses
//! and the KL terms per step and unit (summed on the host in f64, as the CPU backend sums
//! them). Values move between the kernels' layouts with `shaders/strided_copy.wgsl`.

use std::sync::Arc;

use pvrnn_core::data::{Ablation, Observations, Observed};
use pvrnn_core::free_energy::FreeEnergy;
use pvrnn_core::optim::RAdam;
use pvrnn_core::params::Model;
use pvrnn_core::{Error, Modality, ModelConfig, Result};

use crate::copy::{Strided, encode_copy};
use crate::encode::{DispatchList, row_losses, vec4s};
use crate::gpu::{Gpu, RecurrenceKernels};
use crate::output::{EncodedReadout, GpuOutputLayer, Tiling};
use crate::pool::PooledBuffer;
use crate::readback::read_back;
use crate::recurrence::RecurrenceLayout;
use crate::resident::{Part, ResidentLayer, ResidentTensor, resident_buffer};

/// The recurrence and the adaptive variables of a learning run, resident (see the module
/// docs), and the read-outs it feeds.
#[derive(Debug)]
pub(crate) struct DeviceIteration {
    config: ModelConfig,
    layout: RecurrenceLayout,
    kernels: Arc<RecurrenceKernels>,
    /// The packed recurrent weights (the recurrence's layout), and the same with every
    /// matrix transposed for the forward kernel, refreshed after each update.
    weights: wgpu::Buffer,
    weights_t: wgpu::Buffer,
    /// The recurrent weights' gradients, packed the same way.
    grads: wgpu::Buffer,
    /// Per module, a_mu and a_sigma of every sequence, `[sequences, steps, z]`, and their
    /// gradients.
    adaptive: [[wgpu::Buffer; 2]; 4],
    adaptive_grads: [[wgpu::Buffer; 2]; 4],
    sequences: usize,
    steps: usize,
    /// The recurrence's inputs and the read-outs' d F / d d in its layout, sized for every
    /// sequence at full length (cleared every iteration: initial states are zero, modules
    /// without a read-out get no gradient from one).
    inputs: wgpu::Buffer,
    grad_d: wgpu::Buffer,
    readouts: GpuOutputLayer,
}

/// A learning iteration's sequences as the kernels see them.
struct Batch<'l> {
    lengths: &'l [usize],
    /// Steps of every sequence together.
    total: usize,
    /// Each window's table entry (`RecurrenceLayout::entries`).
    entries: Vec<[usize; 6]>,
    /// Steps before each window.
    before: Vec<usize>,
    /// (first window, count): windows of one length are copied in one dispatch each way,
    /// others one by one.
    groups: Vec<(usize, usize)>,
}

impl<'l> Batch<'l> {
    fn of(layout: &RecurrenceLayout, lengths: &'l [usize]) -> Self {
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
        Self {
            lengths,
            total,
            entries: layout.entries(lengths.iter().map(|&len| (len, false))),
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
    /// moments from `optimizer`, adding them to `tensors`; `None` where the kernels do not
    /// hold the shapes or a read-out is not resident (`layers`).
    pub(crate) fn new(
        gpu: &Arc<Gpu>,
        tiling: Tiling,
        model: &Model<f32>,
        optimizer: &RAdam<f32>,
        layers: &[Option<Arc<ResidentLayer>>; 2],
        index_of: &dyn Fn(&pvrnn_core::Tensor<f32>) -> Option<usize>,
        tensors: &mut Vec<ResidentTensor>,
    ) -> Option<Self> {
        let config = &model.config;
        let (sequences, steps) = (model.adaptive.sequences(), model.adaptive.steps());
        let (layout, packed) = RecurrenceLayout::new(&model.params, config);
        if layers.iter().any(Option::is_none)
            || sequences == 0
            || steps == 0
            || !layout.fits(gpu, sequences, sequences * steps)
        {
            return None;
        }
        let weights = resident_buffer(gpu, "resident recurrent weights", &packed);
        let weights_t = resident_buffer(
            gpu,
            "resident recurrent weights, transposed",
            &layout.transposed(&packed),
        );
        let grads = resident_buffer(
            gpu,
            "resident recurrent gradients",
            &vec![0f32; packed.len()],
        );
        // The moments share the packed layout; each tensor is a range of the three buffers.
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
        let [m_packed, v_packed] =
            moments.map(|values| resident_buffer(gpu, "resident recurrent moments", &values));
        for (index, offset, len) in ranges {
            tensors.push(ResidentTensor {
                index,
                value: weights.clone(),
                moments: [m_packed.clone(), v_packed.clone()],
                grad: grads.clone(),
                len,
                offset,
                part: Part::Whole,
            });
        }
        // The adaptive variables follow the parameters in the trainer's order.
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
        let adaptive_grads = pairs.map(|pair| pair.map(|(_, grad)| grad));
        let s = layout.strides();
        let inputs = resident_buffer(
            gpu,
            "resident recurrence inputs",
            &vec![0f32; sequences * (s.init + steps * s.input)],
        );
        let grad_d = resident_buffer(
            gpu,
            "resident read-out gradients",
            &vec![0f32; sequences * steps * s.grad_d],
        );
        Some(Self {
            config: config.clone(),
            kernels: gpu.recurrence_kernels(),
            weights,
            weights_t,
            grads,
            adaptive,
            adaptive_grads,
            sequences,
            steps,
            inputs,
            grad_d,
            readouts: GpuOutputLayer::with_resident(gpu.clone(), tiling, &model.params, layers),
            layout,
        })
    }

    /// The free energy of the device's model on `data` with every gradient left in the
    /// resident buffers (see the module docs). `eps` per sequence and module, `[len, z]`.
    pub(crate) fn free_energy(
        &self,
        gpu: &Gpu,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<FreeEnergy> {
        Ok(pvrnn_core::deferred::now(
            self.free_energy_later(gpu, data, eps)?,
        ))
    }

    /// [`Self::free_energy`] submitted now and waited for when the future is first polled,
    /// so that a cohort's networks are all queued before the host waits for any.
    pub(crate) fn free_energy_later<'a>(
        &'a self,
        gpu: &Gpu,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<impl std::future::Future<Output = FreeEnergy> + 'a> {
        self.check_fits(data, eps)?;
        let batch = Batch::of(&self.layout, data.lengths());
        let encode_phase = pvrnn_core::profile::phase("evaluate on the device: upload and encode");
        let (eps_flat, per_module_at) = self.flatten_eps(&batch, eps)?;
        let layout = &self.layout;
        let table = layout.upload_table(gpu, &Ablation::none(), &batch.entries);
        let eps_buffer = gpu.upload("eps", &eps_flat);
        let s = layout.strides();
        let record = gpu.scratch(
            "recurrence record",
            batch.total * s.record,
            wgpu::BufferUsages::empty(),
        );
        let back = gpu.scratch(
            "recurrence backward",
            batch.total * s.back,
            wgpu::BufferUsages::empty(),
        );
        let mut keep: Vec<PooledBuffer> = Vec::new();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // Buffers that start from zero are cleared first; the dispatches are recorded and
        // then run in one compute pass (a pass per dispatch costs the host more than the
        // small kernels).
        let mut work = DispatchList::default();
        self.clear(&mut encoder);
        self.encode_inputs(
            gpu,
            &mut work,
            &batch,
            &eps_buffer,
            &per_module_at,
            &mut keep,
        );
        layout.encode_forward(
            gpu,
            &self.kernels,
            &mut work,
            &table,
            &self.weights_t,
            &self.inputs,
            &record,
            batch.windows(),
        );
        let readouts = self.encode_readouts(
            gpu,
            &mut encoder,
            &mut work,
            &batch,
            data,
            &record,
            &mut keep,
        )?;
        // Back through the recurrence: the weights' gradients, and d F / d a out to the
        // adaptive variables' layout.
        keep.push(layout.encode_backward(
            gpu,
            &self.kernels,
            &mut work,
            &table,
            &self.weights,
            &record,
            &self.grad_d,
            &back,
            batch.windows(),
        ));
        keep.push(layout.encode_weight_grads(
            gpu,
            &self.kernels,
            &mut work,
            &table,
            &self.inputs,
            &record,
            &back,
            &self.grads,
            batch.windows(),
        ));
        self.encode_adaptive_grads(gpu, &mut work, &batch, &back, &mut keep);
        let kl = self.encode_kl_terms(gpu, &mut work, &batch, &record, &per_module_at, &mut keep);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            work.replay(&mut pass);
        }
        let mut sources = vec![(&*kl, eps_flat.len())];
        sources.extend(readouts.iter().map(|(r, _)| (&*r.row_loss, batch.total)));
        let pending = read_back(gpu, encoder, &sources);
        drop(encode_phase);
        drop((keep, table, eps_buffer, record, back));
        let divisors = [readouts[0].1, readouts[1].1];
        drop(readouts);
        let total = batch.total;
        Ok(async move {
            let results = {
                let _phase =
                    pvrnn_core::profile::phase("evaluate on the device: run and read back");
                pending.await
            };
            self.free_energy_of(total, &per_module_at, divisors, results)
        })
    }

    /// Whether `data` and `eps` fit the sequences this learner holds.
    fn check_fits(&self, data: &Observations<f32>, eps: &[[Vec<f32>; 4]]) -> Result<()> {
        let lengths = data.lengths();
        if data.sequences() != self.sequences || data.steps() > self.steps {
            return Err(Error::Mismatch(format!(
                "the learner holds adaptive variables for {} sequences of {} steps, but the data has {} sequences of {} steps",
                self.sequences,
                self.steps,
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
        let modules = self.layout.modules();
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

    /// Clears what starts from zero: the inputs (initial states are zero), the read-outs'
    /// d F / d d (modules without a read-out get none), the adaptive gradients (steps past
    /// a sequence's length get none).
    fn clear(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.clear_buffer(&self.inputs, 0, None);
        encoder.clear_buffer(&self.grad_d, 0, None);
        for pair in &self.adaptive_grads {
            for grads in pair {
                encoder.clear_buffer(grads, 0, None);
            }
        }
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
        let s = self.layout.strides();
        for &(first, count) in &batch.groups {
            let len = batch.lengths[first];
            for (m, ml) in self.layout.modules().iter().enumerate() {
                let z = ml.z;
                let slot = |k: usize| Strided {
                    offset: batch.entries[first][1] + s.init + ml.input + k * z,
                    block: s.init + len * s.input,
                    row: s.input,
                };
                let adaptive_at = Strided {
                    offset: first * self.steps * z,
                    block: self.steps * z,
                    row: z,
                };
                for k in 0..2 {
                    encode_copy(
                        gpu,
                        work,
                        &self.adaptive[m][k],
                        adaptive_at,
                        &self.inputs,
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
                    &self.inputs,
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
        encoder: &mut wgpu::CommandEncoder,
        work: &mut DispatchList,
        batch: &Batch<'_>,
        data: &Observations<f32>,
        record: &wgpu::Buffer,
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
                &self.layout,
                encoder,
                work,
                RecordRows {
                    record,
                    grad_d: &self.grad_d,
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
        back: &wgpu::Buffer,
        keep: &mut Vec<PooledBuffer>,
    ) {
        let s = self.layout.strides();
        for (m, ml) in self.layout.modules().iter().enumerate() {
            let z = ml.z;
            for k in 0..2 {
                for &(first, count) in &batch.groups {
                    let len = batch.lengths[first];
                    encode_copy(
                        gpu,
                        work,
                        back,
                        Strided {
                            offset: batch.entries[first][5] + ml.back + k * z,
                            block: len * s.back,
                            row: s.back,
                        },
                        &self.adaptive_grads[m][k],
                        Strided {
                            offset: first * self.steps * z,
                            block: self.steps * z,
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
        record: &wgpu::Buffer,
        per_module_at: &[usize; 4],
        keep: &mut Vec<PooledBuffer>,
    ) -> PooledBuffer {
        let modules = self.layout.modules();
        let values = batch.total * modules.iter().map(|m| m.z).sum::<usize>();
        let kl = gpu.scratch("KL terms", values, wgpu::BufferUsages::COPY_SRC);
        let s = self.layout.strides();
        for (m, ml) in modules.iter().enumerate() {
            encode_copy(
                gpu,
                work,
                record,
                Strided::rows(ml.record + 2 * ml.d + 8 * ml.z, s.record),
                &kl,
                Strided::rows(per_module_at[m], ml.z),
                [1, batch.total, ml.z],
                keep,
            );
        }
        kl
    }

    /// F from what came back: the KL terms, then each read-out's row losses.
    fn free_energy_of(
        &self,
        total: usize,
        per_module_at: &[usize; 4],
        divisors: [usize; 2],
        results: Vec<Vec<f32>>,
    ) -> FreeEnergy {
        let mut results = results.into_iter();
        let kl = results.next().unwrap_or_default();
        let mut complexity = [0.0; 4];
        for (m, ml) in self.layout.modules().iter().enumerate() {
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

    /// Encodes the refresh of the forward kernel's copy of the weights after an update of
    /// the packed ones: every value (the prior biases are read there too), then the
    /// matrices transposed over theirs.
    pub(crate) fn encode_transposes(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        keep: &mut Vec<PooledBuffer>,
    ) {
        encoder.copy_buffer_to_buffer(&self.weights, 0, &self.weights_t, 0, self.weights.size());
        let mut work = DispatchList::default();
        for (at, rows, cols) in self.layout.matrices() {
            encode_copy(
                gpu,
                &mut work,
                &self.weights,
                Strided {
                    offset: at,
                    block: cols,
                    row: 1,
                },
                &self.weights_t,
                Strided {
                    offset: at,
                    block: 1,
                    row: rows,
                },
                [rows, cols, 1],
                keep,
            );
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        work.replay(&mut pass);
    }
}

/// A recurrence record's rows and the buffer for the read-outs' d F / d d in the
/// recurrence's layout.
pub(crate) struct RecordRows<'a> {
    pub(crate) record: &'a wgpu::Buffer,
    pub(crate) grad_d: &'a wgpu::Buffer,
    pub(crate) rows: usize,
}

/// Encodes the whole read-out of `modality` (its first `k` dimensions observed) from the
/// module states in a recurrence record: the states copied out into the read-out's input
/// (the output layer's padded rows, cleared first, for a read-out without hidden layers),
/// the read-out ([`GpuOutputLayer::encode_readout`]) and its d F / d d copied into the
/// recurrence's layout. Returns the read-out and its accuracy divisor; `None` unless the
/// read-out is on the device whole. Buffers the submission uses go into `keep`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn encode_readout_of_record(
    gpu: &Gpu,
    readouts: &GpuOutputLayer,
    config: &ModelConfig,
    layout: &RecurrenceLayout,
    encoder: &mut wgpu::CommandEncoder,
    work: &mut DispatchList,
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
        encoder.clear_buffer(&input, 0, None);
    }
    encode_copy(
        gpu,
        work,
        at.record,
        Strided::rows(ml.record + d, s.record),
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
        Strided::rows(ml.grad_d, s.grad_d),
        [1, at.rows, d],
        keep,
    );
    keep.push(input);
    Some((readout, divisor))
}
