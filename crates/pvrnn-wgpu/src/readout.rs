//! Both read-outs as one piece of an assembled model (pvrnn-core's
//! [`pvrnn_core::assembled::Readout`]): the output layers on the GPU ([`GpuOutputLayer`]),
//! and, for a learner, the hidden layers too; what the GPU does not take (the hidden layers
//! of a model loaded for one call, calls too small to pay for a transfer) runs on the CPU's
//! read-out with the same weights.

use std::sync::Arc;

use pvrnn_core::Modality;
use pvrnn_core::assembled::{Readout, ReadoutBatch, ReadoutLoss};
use pvrnn_core::cpu::{CpuReadout, readout_loss_from};
use pvrnn_core::deferred::{Deferred, ready};
use pvrnn_core::params::Params;

use crate::output::GpuOutputLayer;

#[derive(Debug)]
pub struct GpuReadout {
    layer: GpuOutputLayer,
    cpu: CpuReadout<f32>,
}

impl GpuReadout {
    /// `layer` must hold the output layers of `params`.
    pub fn new(layer: GpuOutputLayer, params: Arc<Params<f32>>) -> Self {
        Self {
            layer,
            cpu: CpuReadout::new(params),
        }
    }

    /// Predictions from the top hidden activations: on the GPU, or the CPU for few rows.
    fn predict_top<'a>(
        &'a self,
        modality: Modality,
        top: &[f32],
        n: usize,
    ) -> Deferred<'a, Vec<f32>> {
        match self.layer.predict(modality, top, n) {
            Some(prediction) => prediction,
            None => ready(self.cpu.output_predict(modality, top, n)),
        }
    }
}

impl Readout<f32> for GpuReadout {
    fn loss<'a>(&'a self, batch: &ReadoutBatch<'_, f32>) -> Deferred<'a, ReadoutLoss<f32>> {
        let ReadoutBatch {
            modality,
            d,
            n,
            k,
            divisor,
            targets,
            resident_targets,
            weight_grads,
        } = *batch;
        // A learner's read-out whole on the device, its hidden layers included.
        if let Some(whole) = self.layer.readout_loss(
            modality,
            d,
            n,
            k,
            divisor,
            targets,
            resident_targets,
            weight_grads,
        ) {
            return whole;
        }
        let acts = self.cpu.hidden_forward(modality, d, n);
        let top = acts.last().map(Vec::as_slice).unwrap_or(d);
        let on_gpu = self.layer.loss(
            modality,
            top,
            n,
            k,
            divisor,
            targets,
            resident_targets,
            weight_grads,
        );
        let Some(pending) = on_gpu else {
            let loss = self.cpu.output_loss(batch, top);
            return ready(readout_loss_from(
                &self.cpu,
                modality,
                d,
                n,
                &acts,
                loss,
                weight_grads,
            ));
        };
        // Back through the hidden layers once the output layer's gradient is in.
        let d = d.to_vec();
        Box::pin(async move {
            let loss = pending.await;
            readout_loss_from(&self.cpu, modality, &d, n, &acts, loss, weight_grads)
        })
    }

    fn predict<'a>(&'a self, modality: Modality, d: &[f32], n: usize) -> Deferred<'a, Vec<f32>> {
        // A learner's hidden layers live on the device (the host's copies are stale).
        if let Some(top) = self.layer.hidden_top(modality, d, n) {
            return Box::pin(async move {
                let top = top.await;
                self.predict_top(modality, &top, n).await
            });
        }
        let acts = self.cpu.hidden_forward(modality, d, n);
        let top = acts.last().map(Vec::as_slice).unwrap_or(d);
        self.predict_top(modality, top, n)
    }
}
