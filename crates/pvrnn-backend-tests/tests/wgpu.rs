//! The suite on the wgpu backend: the first adapter the machine offers (a GPU, or Mesa's
//! lavapipe CPU Vulkan device in CI), every call on the device however small, with the
//! recurrence on the CPU and on the GPU, and with the fused and the register-blocked
//! output-layer kernels.
//! Without an adapter the tests fail, naming the problem, unless `PVRNN_SKIP_WGPU` is set.
#![cfg(not(target_arch = "wasm32"))]

use std::sync::Arc;

use pvrnn_backend_tests::Shared;
use pvrnn_wgpu::{OutputKernels, Tiling, WgpuBackend};

fn wgpu(recurrence_on_gpu: bool, output_kernels: OutputKernels) -> Option<Shared<f32>> {
    match WgpuBackend::new() {
        // Every call on the GPU, however small (the suite's shapes are).
        Ok(backend) => Some(Arc::new(
            backend
                .with_tiling(Tiling {
                    min_work: 0,
                    output_kernels,
                    ..Tiling::default()
                })
                .with_recurrence_on_gpu(recurrence_on_gpu),
        )),
        Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
            eprintln!("wgpu backend skipped (PVRNN_SKIP_WGPU): {e}");
            None
        }
        Err(e) => panic!("{e} (set PVRNN_SKIP_WGPU=1 to skip the GPU backend's tests)"),
    }
}

pvrnn_backend_tests::backend_suite!(wgpu_f32, f32, wgpu(false, OutputKernels::Fused));
pvrnn_backend_tests::backend_suite!(
    wgpu_recurrence_on_gpu_f32,
    f32,
    wgpu(true, OutputKernels::Fused)
);
pvrnn_backend_tests::backend_suite!(
    wgpu_blocked_output_f32,
    f32,
    wgpu(false, OutputKernels::Blocked)
);
pvrnn_backend_tests::backend_suite!(
    wgpu_recurrence_on_gpu_blocked_f32,
    f32,
    wgpu(true, OutputKernels::Blocked)
);
