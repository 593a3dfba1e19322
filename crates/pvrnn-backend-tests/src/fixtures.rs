//! Small models and data the suite runs on.

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
        Tensor::from_vec(&[s, t, dv], cast(uniform(s * t * dv, seed, -0.9, 0.9)))
            .expect("valid fixture data"),
        Tensor::from_vec(&[s, t, dp], cast(uniform(s * t * dp, seed + 1, -0.9, 0.9)))
            .expect("valid fixture data"),
        None,
    )
    .expect("valid fixture data")
}

/// A tiny f64 model whose adaptive variables are spread out (not just the prior).
pub fn tiny_model(config: ModelConfig, s: usize, t: usize, seed: u64) -> Model<f64> {
    let mut model = Model::<f64>::init(config, s, t, seed).expect("valid fixture data");
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
        .expect("valid fixture data"),
        Tensor::from_vec(&[s, t, config.proprio_dims], make(config.proprio_dims, 1.3))
            .expect("valid fixture data"),
        None,
    )
    .expect("valid fixture data")
}

/// A model large enough to learn the sine sequences in a few hundred iterations.
pub fn learning_config() -> ModelConfig {
    let mut c = tiny_config();
    let m = |d, z, fast, slow| ModuleConfig {
        d,
        z,
        tau: [fast, slow],
    };
    c.executive = m(10, 4, 6.0, 12.0);
    c.associative = m(10, 4, 3.0, 6.0);
    c.exteroceptive = m(12, 5, 1.5, 3.0);
    c.proprioceptive = m(10, 4, 1.5, 3.0);
    c.exteroceptive_readout.hidden = vec![12, 16];
    c.proprioceptive_readout.hidden = vec![12];
    c.kl_weight = 0.005;
    c.train.optimizer.lr = 0.01;
    c
}
