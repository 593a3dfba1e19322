//! A loaded model's recurrence on the device ([`GpuRecurrence`] as the core's `Recurrence`):
//! the windows forward, their states read back into traces, and a pass's backward with its
//! weight gradients read back into the core's gradients; windows the kernels do not hold go
//! to the CPU's recurrence.

#[cfg(target_arch = "wasm32")]
use pvrnn_core::ModelConfig;
use pvrnn_core::assembled::{ModuleWeightGrads, Recurrence, RecurrenceGrads, RecurrencePass};
use pvrnn_core::backend::{ModuleTrace, Posterior, Trace, Window};
use pvrnn_core::data::Ablation;
use pvrnn_core::deferred::Deferred;

use crate::pool::PooledBuffer;
use crate::readback::read_back;

use super::GpuRecurrence;
use super::dispatch::WeightGradBuffers;
use super::layout::WindowEntry;

/// On the GPU where its kernels hold the windows, else on the CPU's recurrence.
impl Recurrence<f32> for GpuRecurrence {
    fn forward<'a>(
        &'a self,
        windows: &[Window<'_, f32>],
        ablation: &Ablation,
    ) -> Deferred<'a, Box<dyn RecurrencePass<f32> + 'a>> {
        match self.forward_on_gpu(windows, ablation) {
            Some(pass) => pass,
            None => self.cpu.forward(windows, ablation),
        }
    }

    /// In the browser on the CPU: this synchronous call (model initialisation) cannot wait
    /// on the event loop that WebGPU's read-backs need.
    #[cfg(target_arch = "wasm32")]
    fn prior_rollout(&self, config: &ModelConfig, steps: usize) -> ([Vec<f32>; 4], [Vec<f32>; 4]) {
        self.cpu.prior_rollout(config, steps)
    }
}

impl GpuRecurrence {
    /// The windows forward on the GPU; `None` for shapes its kernels do not hold.
    pub fn forward_on_gpu<'a>(
        &'a self,
        windows: &[Window<'_, f32>],
        ablation: &Ablation,
    ) -> Option<Deferred<'a, Box<dyn RecurrencePass<f32> + 'a>>> {
        let layout = &self.layout;
        let steps: usize = windows.iter().map(|w| w.len).sum();
        if !layout.fits(&self.gpu, windows.len(), steps) || windows.iter().any(|w| w.len == 0) {
            return None;
        }
        let s = layout.strides;
        let entries = layout.entries(
            windows
                .iter()
                .map(|w| (w.len, matches!(w.posterior, Posterior::Prior))),
        );
        let (inputs, initial) = layout.pack_inputs(windows);
        let gpu = &*self.gpu;
        let table = layout.upload_table(gpu, ablation, &entries);
        let input_buffer = gpu.upload("recurrence inputs", &inputs);
        let record = gpu.scratch(
            "recurrence record",
            steps * s.record,
            wgpu::BufferUsages::COPY_SRC,
        );
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        layout.encode_forward(
            gpu,
            &self.kernels,
            &mut encoder,
            &table,
            &self.weights_t,
            &input_buffer,
            &record,
            windows.len(),
        );
        let pending = read_back(gpu, encoder, &[(&record, steps * s.record)]);
        Some(Box::pin(async move {
            let values = pending.await.pop().unwrap_or_default();
            let traces = entries
                .iter()
                .zip(initial)
                .map(|(entry, init)| {
                    let (len, at) = (entry[0], entry[2]);
                    let mut init = init.into_iter();
                    let modules = std::array::from_fn(|m| {
                        let (h0, d0) = init.next().unwrap_or_default();
                        self.unpack_trace(&values[at..], len, m, h0, d0)
                    });
                    Trace { len, modules }
                })
                .collect();
            Box::new(GpuPass {
                recurrence: self,
                table,
                inputs: input_buffer,
                record,
                traces,
                entries,
                steps,
            }) as Box<dyn RecurrencePass<f32> + 'a>
        }))
    }
}

impl GpuRecurrence {
    /// Module m's states over a window from its forward record.
    fn unpack_trace(
        &self,
        record: &[f32],
        len: usize,
        m: usize,
        h0: Vec<f32>,
        d0: Vec<f32>,
    ) -> ModuleTrace<f32> {
        let ml = self.layout.modules[m];
        let (d, z) = (ml.d, ml.z);
        let stride = self.layout.strides.record;
        let gather = |offset: usize, width: usize| {
            let mut out = Vec::with_capacity(len * width);
            for t in 0..len {
                let at = t * stride + ml.record + offset;
                out.extend_from_slice(&record[at..at + width]);
            }
            out
        };
        let row = |k: usize| gather(2 * d + k * z, z);
        let kl_terms = row(8);
        ModuleTrace {
            h0,
            d0,
            h: gather(0, d),
            d: gather(d, d),
            pre_mu_p: row(0),
            mu_p: row(1),
            log_sigma_p: row(2),
            inv_var_p: row(3),
            mu_q: row(4),
            log_sigma_q: row(5),
            sigma_q: row(6),
            z: row(7),
            // As the CPU backend: the units' terms summed in f64, divided by z.
            kl: kl_terms
                .chunks_exact(z.max(1))
                .map(|k| k.iter().map(|&v| v as f64).sum::<f64>() / z as f64)
                .collect(),
        }
    }
}

/// A batch run forward on the GPU: the record and inputs stay on the device.
#[derive(Debug)]
struct GpuPass<'a> {
    recurrence: &'a GpuRecurrence,
    table: PooledBuffer,
    inputs: PooledBuffer,
    record: PooledBuffer,
    traces: Vec<Trace<f32>>,
    /// The windows' table entries (steps, offsets).
    entries: Vec<WindowEntry>,
    steps: usize,
}

impl RecurrencePass<f32> for GpuPass<'_> {
    fn traces(&self) -> &[Trace<f32>] {
        &self.traces
    }

    fn backward<'s>(
        &'s self,
        grad_d: &[[Option<&[f32]>; 4]],
        weight_grads: bool,
    ) -> Deferred<'s, RecurrenceGrads<f32>> {
        let r = self.recurrence;
        let gpu = &*r.gpu;
        let layout = &r.layout;
        let s = layout.strides;
        let mut from_readout = vec![0f32; self.steps * s.grad_d];
        for (entry, per_module) in self.entries.iter().zip(grad_d) {
            for (m, g) in per_module.iter().enumerate() {
                let Some(g) = g else { continue };
                let d = layout.modules[m].d;
                for t in 0..entry[0] {
                    let at = entry[4] + t * s.grad_d + layout.modules[m].grad_d;
                    from_readout[at..at + d].copy_from_slice(&g[t * d..(t + 1) * d]);
                }
            }
        }
        let grad_d = gpu.upload("read-out gradients", &from_readout);
        let back = gpu.scratch(
            "recurrence backward",
            self.steps * s.back,
            wgpu::BufferUsages::COPY_SRC,
        );
        let windows = self.entries.len();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let backward_params = layout.encode_backward(
            gpu,
            &r.kernels,
            &mut encoder,
            &self.table,
            &r.weights,
            &self.record,
            &grad_d,
            &back,
            windows,
        );
        let grads = gpu.scratch(
            "recurrent weight gradients",
            if weight_grads {
                layout.weight_floats
            } else {
                1
            },
            wgpu::BufferUsages::COPY_SRC,
        );
        let weights_params = weight_grads.then(|| {
            let buffers = WeightGradBuffers {
                table: &self.table,
                inputs: &self.inputs,
                record: &self.record,
                back: &back,
                grads: &grads,
            };
            layout.encode_weight_grads(gpu, &r.kernels, &mut encoder, buffers, &[(0..windows, 0)])
        });
        let mut sources = vec![(&*back, self.steps * s.back)];
        if weight_grads {
            sources.push((&*grads, layout.weight_floats));
        }
        let pending = read_back(gpu, encoder, &sources);
        // The submission's buffers stay out of the pool until it has run.
        let used = (grad_d, back, grads, backward_params, weights_params);
        Box::pin(async move {
            let results = pending.await;
            drop(used);
            self.unpack_grads(results)
        })
    }

    fn into_traces(self: Box<Self>) -> Vec<Trace<f32>> {
        self.traces
    }
}

impl GpuPass<'_> {
    /// The backward pass's read-back: d F / d a per window, and the weights' gradients
    /// when they were asked for.
    fn unpack_grads(&self, results: Vec<Vec<f32>>) -> RecurrenceGrads<f32> {
        let layout = &self.recurrence.layout;
        let s = layout.strides;
        let mut results = results.into_iter();
        let back = results.next().unwrap_or_default();
        let (mut a_mu, mut a_sigma) = (Vec::new(), Vec::new());
        for entry in &self.entries {
            let (len, at) = (entry[0], entry[5]);
            let gather = |m: usize, offset: usize| {
                let z = layout.modules[m].z;
                let mut out = Vec::with_capacity(len * z);
                for t in 0..len {
                    let i = at + t * s.back + layout.modules[m].back + offset * z;
                    out.extend_from_slice(&back[i..i + z]);
                }
                out
            };
            a_mu.push(std::array::from_fn(|m| gather(m, 0)));
            a_sigma.push(std::array::from_fn(|m| gather(m, 1)));
        }
        let weights = results.next().map(|g| {
            std::array::from_fn(|m| {
                let ml = layout.modules[m];
                let (d, z) = (ml.d, ml.z);
                let take = |at: usize, n: usize| g[at..at + n].to_vec();
                ModuleWeightGrads {
                    w_prior_mu: take(ml.w_prior, z * d),
                    w_prior_sigma: take(ml.w_prior + z * d, z * d),
                    b_prior_mu: take(ml.b_prior, z),
                    b_prior_sigma: take(ml.b_prior + z, z),
                    w_dd: take(ml.w_dd, d * d),
                    w_dz: take(ml.w_dz, d * z),
                    w_dh: take(ml.w_dh, d * ml.parent_d),
                }
            })
        });
        RecurrenceGrads {
            a_mu,
            a_sigma,
            weights,
        }
    }
}
