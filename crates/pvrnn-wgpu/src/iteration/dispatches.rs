//! The dispatches of a run's part of an iteration, around the recurrence's: its inputs copied
//! into the recurrence's layout, both read-outs from the record, the adaptive variables'
//! gradients and the KL terms copied out, the divergence check; and the refresh of the
//! forward kernel's transposed weights after an update.

use pvrnn_core::data::{Observations, Observed};
use pvrnn_core::{Error, Modality, Result};

use crate::copy::{Strided, encode_copy};
use crate::encode::{DispatchList, bind, dispatch, grid};
use crate::gpu::Gpu;
use crate::output::EncodedReadout;
use crate::pool::PooledBuffer;
use crate::recurrence::{RecurrenceLayout, WindowEntry};
use crate::timing::{PassTimes, begin_pass};

use super::record_readout::{RecordRows, encode_readout_of_record};
use super::run::DeviceIteration;

/// `shaders/finite_check.wgsl`'s parameters.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FiniteCheckParams {
    count: u32,
    groups_x: u32,
    _pad: [u32; 2],
}

/// A learning iteration's sequences as the kernels see them.
pub(super) struct Batch<'l> {
    pub(super) lengths: &'l [usize],
    /// Steps of every sequence together.
    pub(super) total: usize,
    /// Each window's table entry (`RecurrenceLayout::entries`), at the run's slot.
    pub(super) entries: Vec<WindowEntry>,
    /// Steps before each window.
    pub(super) before: Vec<usize>,
    /// (first window, count): windows of one length are copied in one dispatch each way,
    /// others one by one.
    pub(super) groups: Vec<(usize, usize)>,
}

impl<'l> Batch<'l> {
    pub(super) fn of(layout: &RecurrenceLayout, lengths: &'l [usize], base: WindowEntry) -> Self {
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
    /// The recurrence's inputs: per window its initial states (zero), then per step and
    /// module a_mu, a_sigma and eps.
    pub(super) fn encode_inputs(
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
    pub(super) fn encode_readouts(
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
    pub(super) fn encode_adaptive_grads(
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
    pub(super) fn encode_kl_terms(
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
    pub(super) fn encode_finite_checks(
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
