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

use common::{assert_close, assert_same_free_energy_and_gradients, config, observations};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::free_energy::{NoiseDraw, free_energy, free_energy_async};
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::{Modality, Model, NoiseMode, Observations, Observed};
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
        on_gpu.iterate_async(usize::MAX).await.unwrap();
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

/// Learning's free energy and every gradient with the recurrence on WebGPU (forward,
/// back-propagation through time, the weights' gradients), awaited, against the CPU's.
#[wasm_bindgen_test]
async fn the_recurrence_on_webgpu_gives_the_cpus_free_energy_and_gradients() {
    let gpu = open_gpu().await.with_recurrence_on_gpu(true);
    let plain = open_gpu().await;
    let mut config = config();
    config.prior_bias = true;
    let (sequences, steps) = (2, 6);
    let data = observations(&config, sequences, steps);
    let model = Model::<f32>::init_on(&CpuBackend, config, sequences, steps, 7).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0);
    let (f_cpu, g_cpu) = free_energy(&CpuBackend, &model, &data, draw, true).unwrap();
    let (f_gpu, g_gpu) = free_energy_async(&gpu, &model, &data, draw, true)
        .await
        .unwrap();
    free_energy_async(&plain, &model, &data, draw, true)
        .await
        .unwrap();
    // The recurrence's states and its gradients: two read-backs more than without it.
    assert_eq!(
        gpu.gpu().read_backs(),
        plain.gpu().read_backs() + 2,
        "the recurrence did not run on the adapter"
    );
    assert_same_free_energy_and_gradients((f_cpu, g_cpu), (f_gpu, g_gpu));
}
