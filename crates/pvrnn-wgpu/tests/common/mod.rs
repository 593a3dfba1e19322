//! What the native and the browser tests share: a small model and its data, and how close
//! two backends' results must be.
#![allow(dead_code)] // each test file uses its part

use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::free_energy::Gradients;
use pvrnn_core::{FreeEnergy, ModelConfig, Observations, Tensor};

/// Small, but with the paper's 50-unit top hidden layer and enough vision columns and rows
/// for several column tiles, row blocks and (with small tiling) splits and chunks.
pub fn config() -> ModelConfig {
    let mut c = ModelConfig::default();
    let m = |d, z, fast, slow| ModuleConfig {
        d,
        z,
        tau: [fast, slow],
    };
    c.executive = m(6, 3, 4.0, 8.0);
    c.associative = m(6, 3, 2.0, 4.0);
    c.exteroceptive = m(8, 4, 1.5, 2.0);
    c.proprioceptive = m(6, 3, 1.0, 2.0);
    c.exteroceptive_readout.hidden = vec![12, 50];
    c.proprioceptive_readout.hidden = vec![10];
    // The paper's output layers have no bias; the option is tested on one of them.
    c.exteroceptive_readout.output_bias = true;
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![4, 8],
    };
    c.proprio_dims = 6;
    c.kl_weight = 0.1;
    c
}

pub fn observations(config: &ModelConfig, sequences: usize, steps: usize) -> Observations<f32> {
    let wave = |dims: usize, phase: f64| {
        let mut v = Vec::with_capacity(sequences * steps * dims);
        for s in 0..sequences {
            for t in 0..steps {
                for d in 0..dims {
                    let x = 0.3 * t as f64 + 0.7 * d as f64 + 1.1 * s as f64 + phase;
                    v.push((0.8 * x.sin()) as f32);
                }
            }
        }
        v
    };
    let (vd, pd) = (config.vision.dims(), config.proprio_dims);
    Observations::new(
        Tensor::from_vec(&[sequences, steps, vd], wave(vd, 0.0)).unwrap(),
        Tensor::from_vec(&[sequences, steps, pd], wave(pd, 0.5)).unwrap(),
        None,
    )
    .unwrap()
}

/// max |a - b| <= tol * max |a| (plus a floor for tensors that are all but zero).
pub fn assert_close(name: &str, cpu: &[f32], gpu: &[f32], tol: f64) {
    assert_eq!(cpu.len(), gpu.len(), "{name}: length");
    let scale = cpu.iter().fold(0f64, |m, &v| m.max((v as f64).abs()));
    let diff = cpu
        .iter()
        .zip(gpu)
        .fold(0f64, |m, (&a, &b)| m.max((a as f64 - b as f64).abs()));
    assert!(
        diff <= tol * scale + 1e-9,
        "{name}: max difference {diff:e} against max magnitude {scale:e}"
    );
}

/// Two backends' free energy and gradients ([`pvrnn_core::free_energy::free_energy`]):
/// every term within 1e-5 relative, every weight's and adaptive variable's gradient within
/// 1e-4 (f32 summation order).
pub fn assert_same_free_energy_and_gradients(
    cpu: (FreeEnergy, Option<Gradients<f32>>),
    gpu: (FreeEnergy, Option<Gradients<f32>>),
) {
    let terms = |f: &FreeEnergy| {
        [
            f.total,
            f.accuracy.exteroceptive,
            f.accuracy.proprioceptive,
            f.complexity.executive,
            f.complexity.associative,
            f.complexity.exteroceptive,
            f.complexity.proprioceptive,
        ]
    };
    for (a, b) in terms(&cpu.0).into_iter().zip(terms(&gpu.0)) {
        assert!(
            (a - b).abs() <= 1e-5 * a.abs(),
            "free-energy term: cpu {a} gpu {b}"
        );
    }
    let (g_cpu, g_gpu) = (cpu.1.expect("CPU gradients"), gpu.1.expect("GPU gradients"));
    for ((name, a, _), (_, b, _)) in g_cpu.params.named().into_iter().zip(g_gpu.params.named()) {
        assert_close(&name, a.data(), b.data(), 1e-4);
    }
    for m in 0..4 {
        assert_close(
            "a_mu",
            g_cpu.adaptive.a_mu[m].data(),
            g_gpu.adaptive.a_mu[m].data(),
            1e-4,
        );
        assert_close(
            "a_sigma",
            g_cpu.adaptive.a_sigma[m].data(),
            g_gpu.adaptive.a_sigma[m].data(),
            1e-4,
        );
    }
}
