//! WebGPU in the browser: online inference awaited in a dedicated worker (as the explorer's
//! worker runs it) computes what the CPU backend computes, and really ran on the adapter.
//!
//! `scripts/test.sh` runs it in headless Chromium with `--enable-unsafe-webgpu`
//! (`tests/web/webgpu-webdriver.json`), whose adapter is SwiftShader's: correct and very
//! slow, so the model and the run are tiny.
#![cfg(target_arch = "wasm32")]
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run

mod common;

use std::sync::Arc;

use common::{assert_close, config, observations};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::{Modality, Model, Observations, Observed};
use pvrnn_wgpu::WgpuBackend;
use wasm_bindgen_test::{wasm_bindgen_test, wasm_bindgen_test_configure};

wasm_bindgen_test_configure!(run_in_dedicated_worker);

/// The adapter, with every call on it however small (these shapes are).
async fn open_gpu() -> WgpuBackend {
    WgpuBackend::open()
        .await
        .unwrap_or_else(|e| {
            panic!("{e} (headless Chromium needs --enable-unsafe-webgpu for WebGPU)")
        })
        .with_tiling(pvrnn_wgpu::Tiling {
            min_work: 0,
            ..pvrnn_wgpu::Tiling::default()
        })
}

/// The test model (initialised with `seed`), `steps` of data, and online inference of it
/// with `iterations` updates per step over a window of 3, on the CPU and on `gpu`.
fn cpu_and_gpu(
    gpu: &WgpuBackend,
    steps: usize,
    iterations: usize,
    seed: u64,
) -> (
    Observations<f32>,
    OnlineInference<f32>,
    OnlineInference<f32>,
) {
    let config = config();
    let data = observations(&config, 1, steps);
    let model =
        Arc::new(Model::<f32>::init_on(&CpuBackend, config.clone(), 1, steps, seed).unwrap());
    let mut settings = InferenceSettings::from_config(&config, 2);
    settings.window = 3;
    settings.iterations = iterations;
    settings.observed = Observed {
        vision_levels: 1,
        proprio: true,
    };
    let on_cpu = OnlineInference::new(model.clone(), settings.clone()).unwrap();
    let on_gpu = OnlineInference::with_backend(model, settings, gpu).unwrap();
    (data, on_cpu, on_gpu)
}

#[wasm_bindgen_test]
async fn online_inference_on_webgpu_matches_the_cpu() {
    let gpu = open_gpu().await;
    let steps = 4;
    let (data, mut on_cpu, mut on_gpu) = cpu_and_gpu(&gpu, steps, 3, 3);
    for t in 0..steps {
        let x = data.step(Modality::Exteroceptive, 0, t);
        let p = data.step(Modality::Proprioceptive, 0, t);
        let want = on_cpu.step(x, p).unwrap();
        on_gpu.begin_step(x, p).unwrap();
        on_gpu.iterate_async(usize::MAX).await;
        let got = on_gpu.finish_step_async().await.unwrap();
        let (a, b) = (want.window_free_energy.total, got.window_free_energy.total);
        assert!((a - b).abs() <= 1e-4 * a.abs(), "step {t}: F {a} vs {b}");
        for mi in 0..2 {
            assert_close("reconstruction", &want.recon[mi], &got.recon[mi], 1e-3);
        }
    }
    // Every update's loss and every step's reconstruction came from the adapter.
    assert!(
        gpu.gpu().read_backs() >= (steps * 3) as u64,
        "only {} read-backs: the GPU path was not taken",
        gpu.gpu().read_backs()
    );
}

#[wasm_bindgen_test]
async fn error_regression_on_webgpu_runs_a_calls_updates_in_one_read_back() {
    let gpu = open_gpu().await.with_recurrence_on_gpu(true);
    let steps = 3;
    let (data, mut on_cpu, mut on_gpu) = cpu_and_gpu(&gpu, steps, 4, 5);
    for t in 0..steps {
        let x = data.step(Modality::Exteroceptive, 0, t);
        let p = data.step(Modality::Proprioceptive, 0, t);
        let want = on_cpu.step(x, p).unwrap();
        on_gpu.begin_step(x, p).unwrap();
        let before = gpu.gpu().read_backs();
        assert_eq!(on_gpu.iterate_async(usize::MAX).await, 0);
        // The recurrence, both read-outs and the optimiser for all four updates: one
        // submission, one read-back (one at a time it is two per update at least).
        assert_eq!(
            gpu.gpu().read_backs() - before,
            1,
            "step {t}: the updates were not run in one submission"
        );
        let got = on_gpu.finish_step_async().await.unwrap();
        let (a, b) = (want.window_free_energy.total, got.window_free_energy.total);
        assert!((a - b).abs() <= 1e-4 * a.abs(), "step {t}: F {a} vs {b}");
        for mi in 0..2 {
            assert_close("reconstruction", &want.recon[mi], &got.recon[mi], 1e-3);
        }
        for (w, g) in want.modules.iter().zip(&got.modules) {
            assert_close("posterior mu", &w.mu_q, &g.mu_q, 1e-3);
            assert_close("posterior sigma", &w.sigma_q, &g.sigma_q, 1e-3);
        }
    }
}
