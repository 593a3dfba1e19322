//! The recurrence's kernels ([`RecurrenceKernels`]), compiled per workgroup width: the forward
//! and backward passes with their dot products instanced, and the weight gradients.

use std::sync::Arc;

use super::Gpu;

/// The recurrence's kernels (shapes come from a table at run time, so one set per workgroup
/// width serves every model).
#[derive(Debug)]
pub(crate) struct RecurrenceKernels {
    pub(crate) forward: wgpu::ComputePipeline,
    pub(crate) backward: wgpu::ComputePipeline,
    /// The weight gradients, one thread per weight over all of a network's windows: where
    /// the partial sums below do not fit one binding or dispatch.
    pub(crate) weights: wgpu::ComputePipeline,
    /// The weight gradients' partial sums, one thread per weight and window.
    pub(crate) weight_partials: wgpu::ComputePipeline,
    /// The partial sums added in window order.
    pub(crate) weights_reduce: wgpu::ComputePipeline,
}

/// Loads the recurrence kernels issue before their multiply-adds in each dot product
/// (`shaders/recurrence_dot.wgsl`), forward and backward: a step's phases are chains of
/// dependent loads. On an H200 (2026-12-01) the backward took 2.70 ms an iteration at 30
/// (one round trip per 30-long sum) against 3.03 at 8, the forward 1.44 ms at 8 against
/// 1.93 at 30; 4 loads both ways (the kernels before 2026-11-28) were slower still.
const RECURRENCE_LOADS: [usize; 2] = [8, 30];

/// The recurrence kernels' compiled shape: threads per workgroup, a step's loads issued at
/// its start.
pub(super) type RecurrenceShape = (u32, bool);

impl Gpu {
    /// The recurrence's kernels with `threads` per window's workgroup
    /// (`RecurrenceLayout::threads`), [`RECURRENCE_LOADS`] in flight per dot product and a
    /// step's loads issued at its start where the width allows (`early`,
    /// `Tiling::recurrence_early_loads`), compiled on first use.
    pub(crate) fn recurrence_kernels(&self, threads: u32, early: bool) -> Arc<RecurrenceKernels> {
        let [forward_loads, backward_loads] = RECURRENCE_LOADS;
        let mut compiled = self
            .recurrence_kernels
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let shape = (threads, early);
        if let Some((_, kernels)) = compiled.iter().find(|(key, _)| *key == shape) {
            return kernels.clone();
        }
        let kernels = {
            let common = shader!("recurrence_common.wgsl");
            let weights = shader!("recurrence_weights.wgsl");
            // A kernel's source: the common part, its own, and its dot products
            // (`recurrence_dot.wgsl` once per function name, weights and values); PARTIALS
            // picks the weight-gradient kernel's form (1: a partial sum per window).
            let source = |text: &str, dots: &[[&str; 3]], partials: usize, loads: usize| {
                let mut full = format!("{common}\n{text}");
                for [name, weights, values] in dots {
                    let dot = shader!("recurrence_dot.wgsl");
                    full.push('\n');
                    full.push_str(
                        &dot.replace("DOT", name)
                            .replace("WEIGHTS", weights)
                            .replace("VALUES", values),
                    );
                }
                crate::template::expand(
                    &full,
                    &[
                        ("WG", threads as usize),
                        ("LOADS", loads),
                        ("PARTIALS", partials),
                        ("EARLY", usize::from(early)),
                    ],
                )
            };
            Arc::new(RecurrenceKernels {
                forward: self.pipeline(
                    "recurrence forward",
                    source(
                        shader!("recurrence_forward.wgsl"),
                        &[
                            ["dot_d_prev", "weights_t", "d_prev"],
                            ["dot_zs", "weights_t", "zs"],
                        ],
                        0,
                        forward_loads,
                    ),
                ),
                backward: self.pipeline(
                    "recurrence backward",
                    source(
                        shader!("recurrence_backward.wgsl"),
                        &[
                            ["dot_gu", "weights", "gu"],
                            ["dot_gprior", "weights", "gprior"],
                        ],
                        0,
                        backward_loads,
                    ),
                ),
                // No dot products: LOADS is unused there.
                weights: self.pipeline("recurrence weights", source(weights, &[], 0, 1)),
                weight_partials: self
                    .pipeline("recurrence weight partials", source(weights, &[], 1, 1)),
                weights_reduce: self.pipeline(
                    "recurrence weights reduce",
                    shader!("recurrence_weights_reduce.wgsl").into(),
                ),
            })
        };
        compiled.push((shape, kernels.clone()));
        kernels
    }
}
