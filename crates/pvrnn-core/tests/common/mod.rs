//! Small models and data shared by the integration tests.
#![allow(dead_code)]

use pvrnn_core::backend::Backend;
use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::{Model, ModelConfig, Observations, Real, Tensor};

/// A model small enough for finite differences but with every structural feature:
/// four modules with different sizes, two hidden layers, two cameras at two resolutions.
pub fn tiny_config() -> ModelConfig {
    let mut c = ModelConfig::default();
    let m = |d, z, fast, slow| ModuleConfig {
        d,
        z,
        tau: [fast, slow],
    };
    c.executive = m(4, 3, 3.0, 6.0);
    c.associative = m(4, 2, 2.0, 4.0);
    c.exteroceptive = m(5, 3, 1.5, 2.0);
    c.proprioceptive = m(3, 2, 1.0, 2.0);
    c.exteroceptive_readout.hidden = vec![4, 5];
    c.proprioceptive_readout.hidden = vec![4];
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![1, 2],
    };
    c.proprio_dims = 4;
    // A large W so the complexity gradients matter in the checks.
    c.kl_weight = 0.3;
    c.recurrent_bias_variance = 1.0;
    c
}

/// Deterministic pseudo-random values in [lo, hi).
pub fn uniform(n: usize, seed: u64, lo: f64, hi: f64) -> Vec<f64> {
    let mut s = seed.wrapping_mul(0x9E3779B97F4A7C15).wrapping_add(12345);
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (hi - lo) * ((s >> 11) as f64 / (1u64 << 53) as f64)
        })
        .collect()
}

/// Random observations in [-0.9, 0.9].
pub fn random_observations<T: Real>(
    config: &ModelConfig,
    s: usize,
    t: usize,
    seed: u64,
) -> Observations<T> {
    let dv = config.vision.dims();
    let dp = config.proprio_dims;
    let cast = |v: Vec<f64>| v.into_iter().map(T::from_f64).collect::<Vec<T>>();
    Observations::new(
        Tensor::from_vec(&[s, t, dv], cast(uniform(s * t * dv, seed, -0.9, 0.9))).unwrap(),
        Tensor::from_vec(&[s, t, dp], cast(uniform(s * t * dp, seed + 1, -0.9, 0.9))).unwrap(),
        None,
    )
    .unwrap()
}

/// A tiny f64 model whose adaptive variables are spread out (not just the prior).
pub fn tiny_model(config: ModelConfig, s: usize, t: usize, seed: u64) -> Model<f64> {
    let mut model = Model::<f64>::init(config, s, t, seed).unwrap();
    for (i, (_, a)) in model.adaptive.named_mut().into_iter().enumerate() {
        let (lo, hi) = if i % 2 == 0 { (-0.8, 0.8) } else { (-1.2, 0.2) };
        let v = uniform(a.len(), seed * 31 + i as u64, lo, hi);
        a.data_mut().copy_from_slice(&v);
    }
    model
}

/// Smooth, learnable sequences: each dimension a phase-shifted sinusoid, a different
/// frequency per sequence.
pub fn sine_observations<T: Real>(config: &ModelConfig, s: usize, t: usize) -> Observations<T> {
    let make = |dims: usize, offset: f64| {
        let mut v = Vec::with_capacity(s * t * dims);
        for seq in 0..s {
            let period = 16.0 + 6.0 * seq as f64;
            for step in 0..t {
                for i in 0..dims {
                    let phase = offset + i as f64 * 0.7;
                    v.push(T::from_f64(
                        0.6 * (std::f64::consts::TAU * step as f64 / period + phase).sin(),
                    ));
                }
            }
        }
        v
    };
    Observations::new(
        Tensor::from_vec(
            &[s, t, config.vision.dims()],
            make(config.vision.dims(), 0.0),
        )
        .unwrap(),
        Tensor::from_vec(&[s, t, config.proprio_dims], make(config.proprio_dims, 1.3)).unwrap(),
        None,
    )
    .unwrap()
}

/// Every backend the shared test suite runs on, by name. A new backend adds itself here and
/// every gradient check, learning and inference test runs on it too (as candle runs one
/// suite per device). The wgpu backend computes in f32 only, so it joins the f32 tests
/// (learning, inference); the f64 finite-difference checks hold it through its agreement
/// with the CPU backend (pvrnn-wgpu's `tests/agrees_with_cpu.rs`).
pub fn backends<T: TestReal>() -> Vec<(&'static str, Box<dyn Backend<T>>)> {
    let mut all: Vec<(&'static str, Box<dyn Backend<T>>)> =
        vec![("cpu", Box::new(pvrnn_core::cpu::CpuBackend))];
    all.extend(T::gpu_backends());
    all
}

/// The precisions the suite runs in, and the backends each adds beyond the CPU.
pub trait TestReal: Real {
    fn gpu_backends() -> Vec<(&'static str, Box<dyn Backend<Self>>)>;
}

impl TestReal for f64 {
    fn gpu_backends() -> Vec<(&'static str, Box<dyn Backend<Self>>)> {
        Vec::new()
    }
}

impl TestReal for f32 {
    fn gpu_backends() -> Vec<(&'static str, Box<dyn Backend<Self>>)> {
        #[cfg(not(target_arch = "wasm32"))]
        match pvrnn_wgpu::WgpuBackend::new() {
            Ok(b) => {
                // Every call on the GPU, however small (the suite's shapes are).
                let b = b.with_tiling(pvrnn_wgpu::Tiling {
                    min_work: 0,
                    ..pvrnn_wgpu::Tiling::default()
                });
                return vec![
                    ("wgpu", Box::new(b.clone())),
                    (
                        "wgpu, recurrence on the GPU",
                        Box::new(b.with_recurrence_on_gpu(true)),
                    ),
                ];
            }
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("wgpu backend skipped (PVRNN_SKIP_WGPU): {e}");
            }
            Err(e) => panic!("{e} (set PVRNN_SKIP_WGPU=1 to skip the GPU backend's tests)"),
        }
        Vec::new()
    }
}

/// Runs `test` on every backend of [`backends`], naming the backend if it fails.
pub fn for_each_backend<T: TestReal>(mut test: impl FnMut(&dyn Backend<T>)) {
    for (name, backend) in backends::<T>() {
        eprintln!("backend: {name}");
        test(backend.as_ref());
    }
}
