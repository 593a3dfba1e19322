//! A read-out encoded from the module states in a recurrence record: the states copied into
//! the read-out's input, the read-out, and its d F / d d copied back into the recurrence's
//! layout.

use pvrnn_core::{Modality, ModelConfig};

use crate::copy::{Strided, encode_copy};
use crate::encode::{Recorder, vec4s};
use crate::gpu::Gpu;
use crate::output::{EncodedReadout, GpuOutputLayer};
use crate::pool::PooledBuffer;
use crate::recurrence::RecurrenceLayout;

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
