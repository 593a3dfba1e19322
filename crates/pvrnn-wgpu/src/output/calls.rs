//! The calls a read-out makes of its output layer (the loss, a learner's whole read-out, its
//! top hidden activations, predictions): encoded, submitted, and read back as futures.

use bytemuck::{Pod, Zeroable};
use pvrnn_core::Modality;
use pvrnn_core::assembled::{OutputLoss, ReadoutLoss};
use pvrnn_core::deferred::Deferred;

use crate::encode::{WORKGROUP, bind, dispatch, pad_rows, row_losses, unpad_rows, vec4s};
use crate::readback::read_back;

use super::GpuOutputLayer;

/// Rows per workgroup of `predict.wgsl`.
const PREDICT_ROWS: usize = 4;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PredictParams {
    rows: u32,
    dims: u32,
    _pad: [u32; 2],
}

/// The output layer's pieces, each declining (`None`) what the GPU does not take; the
/// results are read back before the futures finish ([`Deferred`]: a native GPU's at once,
/// WebGPU's through the browser's event loop). Inputs are read before a call returns.
impl GpuOutputLayer {
    /// The fused loss of the first `k` dimensions for the top hidden activations `input`
    /// (`[n, hidden]`): forward, error, d F / d input, and d F / d W and b when
    /// `weight_grads` (left on the device for a resident layer). `None` for calls too small
    /// to pay for a transfer.
    #[allow(clippy::too_many_arguments)]
    pub fn loss<'a>(
        &'a self,
        modality: Modality,
        input: &[f32],
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<Deferred<'a, OutputLoss<f32>>> {
        let layer = self.layer(modality)?;
        if n == 0 || k == 0 || self.too_small(layer, n * k) {
            return None;
        }
        let gpu = &*self.gpu;
        let (hl, hv) = (layer.hidden, vec4s(layer.hidden));
        let encode_phase = pvrnn_core::profile::phase("    GPU: upload and encode");
        let x = gpu.upload("hidden", &pad_rows(input, hl));
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let encoded = self.encode_loss(
            &mut encoder,
            layer,
            modality,
            &x,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        );
        let mut sources: Vec<(&wgpu::Buffer, usize)> =
            vec![(&encoded.grad_in, n * 4 * hv), (&encoded.row_loss, n)];
        if let Some((gw, gb)) = &encoded.grads {
            sources.push((gw, k * 4 * hv));
            sources.push((gb, k));
        }
        let pending = read_back(gpu, encoder, &sources);
        drop(encode_phase);
        let has_bias = layer.has_bias;
        // The buffers the submission uses stay out of the pool until it has run.
        let used = (x, encoded);
        Some(Box::pin(async move {
            let wait_phase = pvrnn_core::profile::phase("    GPU: run and read back");
            let mut results = pending.await.into_iter();
            drop(used);
            drop(wait_phase);
            let grad_in = unpad_rows(&results.next().unwrap_or_default(), hl);
            let row_loss = row_losses(results.next().unwrap_or_default(), divisor);
            let grad_w = results.next().map(|g| unpad_rows(&g, hl));
            let grad_b = results.next().filter(|_| has_bias);
            OutputLoss {
                row_loss,
                grad_in,
                grad_w,
                grad_b,
            }
        }))
    }

    /// Only for a learner's read-outs (their hidden layers' weights are on the device):
    /// the hidden layers, the output layer's loss and the way back to the module states in
    /// one submission, reading back d F / d d and the row losses.
    #[allow(clippy::too_many_arguments)]
    pub fn readout_loss<'a>(
        &'a self,
        modality: Modality,
        d: &[f32],
        n: usize,
        k: usize,
        divisor: usize,
        targets: &[&[f32]],
        resident: Option<u64>,
        weight_grads: bool,
    ) -> Option<Deferred<'a, ReadoutLoss<f32>>> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        if k == 0 || readout.hidden.is_empty() {
            return None;
        }
        let width = readout.input_width;
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(ReadoutLoss {
                row_loss: Vec::new(),
                grad_d: Vec::new(),
                weight_grads: None,
            }));
        }
        let gpu = &*self.gpu;
        // Until the results are in (the CPU's read-out phases do not run).
        let readout_phase = pvrnn_core::profile::phase("  read-out, hidden and output layers");
        let encode_phase = pvrnn_core::profile::phase("    GPU: upload and encode");
        let input = gpu.upload("module states", d);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let encoded = self.encode_readout(
            &mut encoder,
            modality,
            &input,
            n,
            k,
            divisor,
            targets,
            resident,
            weight_grads,
        )?;
        let pending = read_back(
            gpu,
            encoder,
            &[(&encoded.grad_d, n * width), (&encoded.row_loss, n)],
        );
        drop(encode_phase);
        let used = (input, encoded);
        Some(Box::pin(async move {
            let wait_phase = pvrnn_core::profile::phase("    GPU: run and read back");
            let mut results = pending.await.into_iter();
            drop(used);
            drop(wait_phase);
            let grad_d = results.next().unwrap_or_default();
            let row_loss = row_losses(results.next().unwrap_or_default(), divisor);
            drop(readout_phase);
            // The weight gradients stay on the device for the learner's update.
            ReadoutLoss {
                row_loss,
                grad_d,
                weight_grads: None,
            }
        }))
    }

    /// For a learner's read-outs, whose hidden weights live on the device (see
    /// [`Self::readout_loss`]): their hidden layers forward, the top activations read back.
    pub fn hidden_top<'a>(
        &'a self,
        modality: Modality,
        d: &[f32],
        n: usize,
    ) -> Option<Deferred<'a, Vec<f32>>> {
        let layer = self.layer(modality)?;
        let readout = layer.resident()?;
        if readout.hidden.is_empty() {
            return None;
        }
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(Vec::new()));
        }
        let gpu = &*self.gpu;
        let input = gpu.upload("module states", d);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let mut in_flight = Vec::new();
        let acts = self.encode_hidden_forward(&mut encoder, readout, &input, n, &mut in_flight);
        let (top, stride) = acts.last().expect("hidden layers");
        let pending = read_back(gpu, encoder, &[(top, n * stride)]);
        let hl = layer.hidden;
        let used = (input, acts, in_flight);
        Some(Box::pin(async move {
            let top = pending.await.into_iter().next().unwrap_or_default();
            drop(used);
            unpad_rows(&top, hl)
        }))
    }

    /// Predictions of every dimension, `[n, dims]`, for the top hidden activations
    /// `input` (`[n, hidden]`); `None` for calls too small to pay for a transfer.
    pub fn predict<'a>(
        &'a self,
        modality: Modality,
        input: &[f32],
        n: usize,
    ) -> Option<Deferred<'a, Vec<f32>>> {
        let layer = self.layer(modality)?;
        if n == 0 {
            return Some(pvrnn_core::deferred::ready(Vec::new()));
        }
        if self.too_small(layer, n * layer.dims) {
            return None;
        }
        let gpu = &*self.gpu;
        let (hl, dims) = (layer.hidden, layer.dims);
        let limit = self.chunk_limit();
        let chunk = (limit / (4 * dims))
            .max(1)
            .min(n)
            .min(PREDICT_ROWS * gpu.limits().max_compute_workgroups_per_dimension as usize);
        let input = pad_rows(input, hl);
        let padded = input.len() / n;
        Some(Box::pin(async move {
            let mut prediction = Vec::with_capacity(n * dims);
            let mut start = 0;
            while start < n {
                let rows = chunk.min(n - start);
                let x = gpu.upload("hidden", &input[start * padded..(start + rows) * padded]);
                let out = gpu.scratch("prediction", rows * dims, wgpu::BufferUsages::COPY_SRC);
                let params = gpu.uniform(&PredictParams {
                    rows: rows as u32,
                    dims: dims as u32,
                    _pad: [0; 2],
                });
                let group = bind(
                    gpu,
                    &layer.kernels.predict,
                    &[&params, &x, layer.weight(), layer.bias(), &out],
                );
                let mut encoder = gpu.device.create_command_encoder(&Default::default());
                dispatch(
                    &mut encoder,
                    &layer.kernels.predict,
                    &group,
                    dims.div_ceil(WORKGROUP) as u32,
                    rows.div_ceil(PREDICT_ROWS) as u32,
                );
                let part = read_back(gpu, encoder, &[(&out, rows * dims)]).await;
                prediction.extend(part.into_iter().flatten());
                start += rows;
            }
            prediction
        }))
    }
}
