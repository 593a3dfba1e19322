//! The output layer on the GPU at the paper's shapes: learning's full batch (5,400 rows x
//! 32,256 vision columns, loss, input and weight gradients, targets resident) and online
//! inference's window (30 rows, everything observed or 16x16 only, input gradient only,
//! targets resident as online inference keeps them for a step's 50 updates).
//!
//! The first three run the fused kernels (`OutputKernels::Fused`, what the default picks
//! for inference's window); then the same three with the register-blocked kernels
//! (`OutputKernels::Blocked`, named "blocked": what the default picks for learning's
//! batch) and learning's full batch with the blocked kernels' knobs (no weight gradient,
//! shallow tiles, one chunk, other workgroup targets, scalar accesses). Then the fused kernels' knobs:
//! learning's full batch at the workgroup target before 2026-11-30 (1,024), without the
//! weight gradient, in one chunk, and inference's everything-observed case under caps on
//! the column splits (`Tiling::max_splits`), the knob that trades the row pass's
//! parallelism against the length of the reduce pass's sums. With `-- --checks=all` every
//! case runs with wgpu's runtime checks (the output-layer kernels run without them by
//! default), with `-- --checks=none` no kernel has them (`RuntimeChecks`).
//!
//! `cargo bench -p pvrnn-wgpu --bench output_layer` prints milliseconds per call and the
//! arithmetic rate counted as the CPU backend's products (2 N K H per product: three with
//! weight gradients, two without; the GPU's column pass recomputes the forward product, which
//! is not counted), and for each case after the first of its shape how far its loss and
//! gradients lie from that first (the fused kernels'). `WGPU_ADAPTER_NAME` / `WGPU_BACKEND` pick the adapter; `-- 16x16` runs only
//! the cases whose name contains `16x16`.
#![allow(clippy::unwrap_used)] // a benchmark: a failed unwrap is a failed run

mod common;
use common::values;

use std::time::Instant;

use pvrnn_core::assembled::OutputLoss;
use pvrnn_core::params::Params;
use pvrnn_core::{Modality, ModelConfig};
use pvrnn_wgpu::{
    BlockedDepth, GpuOutputLayer, OutputKernels, RuntimeChecks, Tiling, WgpuBackend, WgpuOptions,
};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let checks: RuntimeChecks = args
        .iter()
        .find_map(|a| a.strip_prefix("--checks="))
        .map_or(Ok(RuntimeChecks::default()), str::parse)
        .unwrap_or_else(|e| panic!("{e}"));
    let options = WgpuOptions {
        checks,
        ..WgpuOptions::default()
    };
    let backend = match WgpuBackend::new_with(options) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("no GPU: {e}");
            return;
        }
    };
    println!(
        "adapter: {}, runtime checks {checks:?}",
        backend.adapter_name()
    );
    let config = ModelConfig::default();
    let params = Params::<f32>::init(&config, 0);
    let hidden = *config.exteroceptive_readout.hidden.last().unwrap();
    let dims = config.vision.dims();
    let p16 = 2 * 3 * 16 * 16;

    // (what, rows, observed columns, weight gradients, repetitions, tiling); the targets
    // are resident in every case, as learning and online inference keep them.
    // Every call on the GPU: the bench times the layer there, small calls included.
    let fused = Tiling {
        min_work: 0,
        output_kernels: OutputKernels::Fused,
        ..Tiling::default()
    };
    let mut cases = vec![
        (
            "learning, full batch".to_string(),
            5400,
            dims,
            true,
            20,
            fused,
        ),
        (
            "inference, everything observed".into(),
            30,
            dims,
            false,
            50,
            fused,
        ),
        (
            "inference, 16x16 observed".into(),
            30,
            p16,
            false,
            50,
            fused,
        ),
    ];
    let blocked = Tiling {
        output_kernels: OutputKernels::Blocked,
        ..fused
    };
    let blocked_cases: Vec<_> = cases
        .iter()
        .map(|(what, n, k, grads, reps, _)| {
            (format!("{what}, blocked"), *n, *k, *grads, *reps, blocked)
        })
        .collect();
    cases.extend(blocked_cases);
    // The blocked kernels' knobs on learning's full batch: without the weight gradient
    // (the forward and input-gradient products alone), the shallower tiles of a 16 KiB
    // adapter, one chunk instead of 6, and other workgroup targets (the input gradient's
    // column splits, the weight gradient's row ranges).
    let mut blocked_learning = |what: &str, grads: bool, tiling: Tiling| {
        let what = format!("learning, blocked, {what}");
        cases.push((what, 5400, dims, grads, 20, tiling));
    };
    blocked_learning("no d W", false, blocked);
    let shallow = Tiling {
        blocked_depth: Some(BlockedDepth::Shallow),
        ..blocked
    };
    blocked_learning("shallow tiles", true, shallow);
    let one_chunk = Tiling {
        max_chunk_bytes: 768 << 20,
        ..blocked
    };
    blocked_learning("one chunk", true, one_chunk);
    for target_workgroups in [1024, 4096] {
        let tiling = Tiling {
            target_workgroups,
            ..blocked
        };
        blocked_learning(&format!("{target_workgroups} workgroups"), true, tiling);
    }
    // The targets and error gradients one value at a time (the kernels before the fourth
    // session of 2026-11-30) against the vec4 accesses of the default.
    let scalar_io = Tiling {
        vector_io: false,
        ..blocked
    };
    blocked_learning("scalar accesses", true, scalar_io);
    // The fused kernels on learning's full batch: at the workgroup target they were
    // measured at before 2026-11-30, without the weight gradient (the row pass and its
    // reduce alone: the column pass is the difference), and in one chunk of 768 MiB
    // instead of 6 of 128.
    let fused_1024 = Tiling {
        target_workgroups: 1024,
        ..fused
    };
    cases.push((
        "learning, full batch, 1024 workgroups".into(),
        5400,
        dims,
        true,
        20,
        fused_1024,
    ));
    cases.push((
        "learning, full batch, no d W".into(),
        5400,
        dims,
        false,
        20,
        fused,
    ));
    let one_chunk = Tiling {
        max_chunk_bytes: 768 << 20,
        ..fused
    };
    cases.push((
        "learning, one chunk".into(),
        5400,
        dims,
        true,
        20,
        one_chunk,
    ));
    for max_splits in [1024, 256, 128, 64, 32, 16] {
        let tiling = Tiling {
            max_splits,
            ..fused
        };
        let what = format!("inference, everything, <= {max_splits} splits");
        cases.push((what, 30, dims, false, 50, tiling));
    }
    // `cargo bench ... -- WORD` runs the cases whose name contains WORD.
    let filter: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let mut references: Vec<((usize, usize, bool), OutputLoss<f32>)> = Vec::new();
    for (what, n, k, weight_grads, reps, tiling) in cases {
        if !filter.iter().all(|f| what.contains(f.as_str())) {
            continue;
        }
        let layer = GpuOutputLayer::upload(backend.gpu().clone(), tiling, &params);
        let input = values(n * hidden, 1);
        let target_data = values(n * k, 2);
        let targets: Vec<&[f32]> = target_data.chunks_exact(k).collect();
        let resident = Some(u64::MAX - 1);
        let call = || {
            let loss = layer
                .loss(
                    Modality::Exteroceptive,
                    &input,
                    n,
                    k,
                    k,
                    &targets,
                    resident,
                    weight_grads,
                )
                .unwrap();
            pvrnn_core::deferred::now(loss)
        };
        // Warm-up: compiles the kernels and, for resident targets, uploads them; its result
        // is compared with the first case's of the same shape (the fused kernels').
        let result = call();
        let key = (n, k, weight_grads);
        let agreement = match references.iter().find(|(r, _)| *r == key) {
            Some((_, reference)) => disagreement(reference, &result),
            None => {
                references.push((key, result));
                String::new()
            }
        };
        let start = Instant::now();
        for _ in 0..reps {
            std::hint::black_box(call());
        }
        let s = start.elapsed().as_secs_f64() / reps as f64;
        let products = if weight_grads { 3.0 } else { 2.0 };
        let flops = products * 2.0 * (n * k * hidden) as f64;
        println!(
            "{what:44} {n:5} x {k:5}: {:8.3} ms per call, {:8.1} GFLOP/s{agreement}",
            s * 1e3,
            flops / s / 1e9
        );
    }
}

/// How far `other` lies from `reference`: the loss's relative difference and each
/// gradient's largest difference relative to its largest magnitude.
fn disagreement(reference: &OutputLoss<f32>, other: &OutputLoss<f32>) -> String {
    let total = |l: &OutputLoss<f32>| l.row_loss.iter().sum::<f64>();
    let loss = (total(other) - total(reference)).abs() / total(reference).abs().max(1e-30);
    let relative = |a: &[f32], b: &[f32]| {
        let scale = a.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-30);
        let diff = a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        diff / scale
    };
    let mut text = format!(
        ", vs fused: loss {loss:.1e}, d input {:.1e}",
        relative(&reference.grad_in, &other.grad_in)
    );
    if let (Some(a), Some(b)) = (&reference.grad_w, &other.grad_w) {
        text.push_str(&format!(", d W {:.1e}", relative(a, b)));
    }
    text
}
