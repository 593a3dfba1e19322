//! Model parameters: weights, fixed constants and the adaptive variables of the training
//! sequences, with the tensor names of `docs/model.md`.

use rand_chacha::ChaCha8Rng;

use crate::config::{Modality, ModelConfig, ModuleId};
use crate::noise::{self, Stream};
use crate::{Real, Tensor};

/// A dense layer, weight `[out, in]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense<T> {
    pub weight: Tensor<T>,
    pub bias: Option<Tensor<T>>,
}

/// One module's recurrent and prior weights.
#[derive(Clone, Debug, PartialEq)]
pub struct ModuleParams<T> {
    /// `[d, d]` recurrent weights.
    pub w_dd: Tensor<T>,
    /// `[d, z]` latent-to-recurrent weights.
    pub w_dz: Tensor<T>,
    /// `[d, d_parent]` top-down weights (absent for the executive module).
    pub w_dh: Option<Tensor<T>>,
    /// `[d]` fixed recurrent bias.
    pub bias: Tensor<T>,
    /// `[d]` fixed time constants.
    pub tau: Tensor<T>,
    /// `[z, d]` prior mean weights.
    pub w_prior_mu: Tensor<T>,
    /// `[z, d]` prior log-sigma weights.
    pub w_prior_sigma: Tensor<T>,
    /// `[z]` optional prior biases (`prior_bias = true`).
    pub b_prior_mu: Option<Tensor<T>>,
    pub b_prior_sigma: Option<Tensor<T>>,
}

/// A modality's read-out: tanh hidden layers and a tanh output layer.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadoutParams<T> {
    pub hidden: Vec<Dense<T>>,
    pub out: Dense<T>,
}

/// All weights and fixed constants, indexed by [`ModuleId::index`] and [`Modality::index`].
#[derive(Clone, Debug, PartialEq)]
pub struct Params<T> {
    pub modules: [ModuleParams<T>; 4],
    pub readouts: [ReadoutParams<T>; 2],
}

/// The adaptive variables a of a set of sequences: `[S, T, z]` per module.
#[derive(Clone, Debug, PartialEq)]
pub struct Adaptive<T> {
    pub a_mu: [Tensor<T>; 4],
    pub a_sigma: [Tensor<T>; 4],
}

/// Whether an optimiser updates a tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    Trainable,
    Fixed,
}

// One listing of every tensor, instantiated for shared (`[&] iter`) and mutable
// (`[&mut] iter_mut`) access.
macro_rules! list_tensors {
    ($self:expr, $out:ident, [$($r:tt)+], $iter:ident) => {{
        for (id, m) in ModuleId::ALL.iter().zip($self.modules.$iter()) {
            let n = id.name();
            $out.push((format!("{n}.w_dd"), $($r)+ m.w_dd, Role::Trainable));
            $out.push((format!("{n}.w_dz"), $($r)+ m.w_dz, Role::Trainable));
            if let Some(w) = $($r)+ m.w_dh {
                $out.push((format!("{n}.w_dh"), w, Role::Trainable));
            }
            $out.push((format!("{n}.bias"), $($r)+ m.bias, Role::Fixed));
            $out.push((format!("{n}.tau"), $($r)+ m.tau, Role::Fixed));
            $out.push((format!("{n}.w_prior_mu"), $($r)+ m.w_prior_mu, Role::Trainable));
            $out.push((format!("{n}.w_prior_sigma"), $($r)+ m.w_prior_sigma, Role::Trainable));
            if let Some(b) = $($r)+ m.b_prior_mu {
                $out.push((format!("{n}.b_prior_mu"), b, Role::Trainable));
            }
            if let Some(b) = $($r)+ m.b_prior_sigma {
                $out.push((format!("{n}.b_prior_sigma"), b, Role::Trainable));
            }
        }
        for (modality, r) in Modality::ALL.iter().zip($self.readouts.$iter()) {
            let n = modality.name();
            for (k, layer) in r.hidden.$iter().enumerate() {
                $out.push((format!("{n}.fnn.{k}.weight"), $($r)+ layer.weight, Role::Trainable));
                if let Some(b) = $($r)+ layer.bias {
                    $out.push((format!("{n}.fnn.{k}.bias"), b, Role::Trainable));
                }
            }
            $out.push((format!("{n}.out.weight"), $($r)+ r.out.weight, Role::Trainable));
            if let Some(b) = $($r)+ r.out.bias {
                $out.push((format!("{n}.out.bias"), b, Role::Trainable));
            }
        }
    }};
}

impl<T: Real> Params<T> {
    /// Every tensor with its file name and role, in a fixed order.
    pub fn named(&self) -> Vec<(String, &Tensor<T>, Role)> {
        let mut out = Vec::new();
        list_tensors!(self, out, [&], iter);
        out
    }

    pub fn named_mut(&mut self) -> Vec<(String, &mut Tensor<T>, Role)> {
        let mut out = Vec::new();
        list_tensors!(self, out, [&mut], iter_mut);
        out
    }

    /// All-zero parameters of the configured shapes.
    pub fn zeros(config: &ModelConfig) -> Self {
        let modules = ModuleId::ALL.map(|id| {
            let m = config.module(id);
            ModuleParams {
                w_dd: Tensor::zeros(&[m.d, m.d]),
                w_dz: Tensor::zeros(&[m.d, m.z]),
                w_dh: id
                    .parent()
                    .map(|p| Tensor::zeros(&[m.d, config.module(p).d])),
                bias: Tensor::zeros(&[m.d]),
                tau: Tensor::zeros(&[m.d]),
                w_prior_mu: Tensor::zeros(&[m.z, m.d]),
                w_prior_sigma: Tensor::zeros(&[m.z, m.d]),
                b_prior_mu: config.prior_bias.then(|| Tensor::zeros(&[m.z])),
                b_prior_sigma: config.prior_bias.then(|| Tensor::zeros(&[m.z])),
            }
        });
        let readouts = Modality::ALL.map(|modality| {
            let rc = config.readout(modality);
            let mut fan_in = config.module(modality.module()).d;
            let mut hidden = Vec::new();
            for &width in &rc.hidden {
                hidden.push(Dense {
                    weight: Tensor::zeros(&[width, fan_in]),
                    bias: rc.hidden_bias.then(|| Tensor::zeros(&[width])),
                });
                fan_in = width;
            }
            let dims = config.modality_dims(modality);
            ReadoutParams {
                hidden,
                out: Dense {
                    weight: Tensor::zeros(&[dims, fan_in]),
                    bias: rc.output_bias.then(|| Tensor::zeros(&[dims])),
                },
            }
        });
        Self { modules, readouts }
    }

    /// Freshly initialised parameters: Xavier-normal weights, zero FNN and prior biases,
    /// recurrent bias ~ N(0, `recurrent_bias_variance`), taus per `tau_order`.
    pub fn init(config: &ModelConfig, seed: u64) -> Self {
        let mut rng = noise::rng(seed, Stream::Init, &[]);
        let gain = config.xavier_gain;
        let mut p = Self::zeros(config);
        for id in ModuleId::ALL {
            let m = &mut p.modules[id.index()];
            xavier(&mut rng, &mut m.w_dd, gain);
            xavier(&mut rng, &mut m.w_dz, gain);
            if let Some(w) = m.w_dh.as_mut() {
                xavier(&mut rng, w, gain);
            }
            xavier(&mut rng, &mut m.w_prior_mu, gain);
            xavier(&mut rng, &mut m.w_prior_sigma, gain);
            normal_scaled(
                &mut rng,
                m.bias.data_mut(),
                config.recurrent_bias_variance.sqrt(),
            );
            for (t, tau) in m.tau.data_mut().iter_mut().zip(config.taus(id)) {
                *t = T::from_f64(tau);
            }
        }
        for r in &mut p.readouts {
            for layer in &mut r.hidden {
                xavier(&mut rng, &mut layer.weight, gain);
            }
            xavier(&mut rng, &mut r.out.weight, gain);
        }
        p
    }

    /// The same parameters in another float type.
    pub fn cast<U: Real>(&self) -> Params<U> {
        let dense = |l: &Dense<T>| Dense {
            weight: l.weight.cast(),
            bias: l.bias.as_ref().map(Tensor::cast),
        };
        Params {
            modules: std::array::from_fn(|i| {
                let m = &self.modules[i];
                ModuleParams {
                    w_dd: m.w_dd.cast(),
                    w_dz: m.w_dz.cast(),
                    w_dh: m.w_dh.as_ref().map(Tensor::cast),
                    bias: m.bias.cast(),
                    tau: m.tau.cast(),
                    w_prior_mu: m.w_prior_mu.cast(),
                    w_prior_sigma: m.w_prior_sigma.cast(),
                    b_prior_mu: m.b_prior_mu.as_ref().map(Tensor::cast),
                    b_prior_sigma: m.b_prior_sigma.as_ref().map(Tensor::cast),
                }
            }),
            readouts: std::array::from_fn(|i| {
                let r = &self.readouts[i];
                ReadoutParams {
                    hidden: r.hidden.iter().map(dense).collect(),
                    out: dense(&r.out),
                }
            }),
        }
    }

    /// Zeros of the same shapes (a gradient or optimiser-moment container).
    pub fn zeros_like(&self) -> Self {
        let mut z = self.clone();
        for (_, t, _) in z.named_mut() {
            t.data_mut().fill(T::ZERO);
        }
        z
    }
}

impl<T: Real> Adaptive<T> {
    pub fn zeros(config: &ModelConfig, sequences: usize, steps: usize) -> Self {
        let shape = |id: ModuleId| [sequences, steps, config.module(id).z];
        Self {
            a_mu: ModuleId::ALL.map(|id| Tensor::zeros(&shape(id))),
            a_sigma: ModuleId::ALL.map(|id| Tensor::zeros(&shape(id))),
        }
    }

    pub fn sequences(&self) -> usize {
        self.a_mu[0].shape()[0]
    }
    pub fn steps(&self) -> usize {
        self.a_mu[0].shape()[1]
    }

    pub fn named(&self) -> Vec<(String, &Tensor<T>)> {
        let mut out = Vec::new();
        for id in ModuleId::ALL {
            out.push((format!("{}.a_mu", id.name()), &self.a_mu[id.index()]));
            out.push((format!("{}.a_sigma", id.name()), &self.a_sigma[id.index()]));
        }
        out
    }

    pub fn named_mut(&mut self) -> Vec<(String, &mut Tensor<T>)> {
        let mut out = Vec::new();
        for ((id, mu), sigma) in ModuleId::ALL
            .iter()
            .zip(&mut self.a_mu)
            .zip(&mut self.a_sigma)
        {
            out.push((format!("{}.a_mu", id.name()), mu));
            out.push((format!("{}.a_sigma", id.name()), sigma));
        }
        out
    }

    pub fn cast<U: Real>(&self) -> Adaptive<U> {
        Adaptive {
            a_mu: std::array::from_fn(|i| self.a_mu[i].cast()),
            a_sigma: std::array::from_fn(|i| self.a_sigma[i].cast()),
        }
    }
}

/// A model: configuration, parameters, and the adaptive variables of its training sequences.
#[derive(Clone, Debug, PartialEq)]
pub struct Model<T> {
    pub config: ModelConfig,
    pub params: Params<T>,
    pub adaptive: Adaptive<T>,
}

impl<T: Real> Model<T> {
    pub fn cast<U: Real>(&self) -> Model<U> {
        Model {
            config: self.config.clone(),
            params: self.params.cast(),
            adaptive: self.adaptive.cast(),
        }
    }

    /// The model without its training sequences' adaptive variables (zero sequences): all
    /// that online inference needs, and a much smaller file.
    pub fn weights_only(&self) -> Self {
        Self {
            config: self.config.clone(),
            params: self.params.clone(),
            adaptive: Adaptive::zeros(&self.config, 0, 1),
        }
    }
}

fn normal_scaled<T: Real>(rng: &mut ChaCha8Rng, out: &mut [T], std: f64) {
    noise::fill_normal(rng, out);
    for v in out {
        *v = T::from_f64(v.to_f64() * std);
    }
}

/// Xavier-normal fill of a `[out, in]` weight: std = gain * sqrt(2 / (fan_in + fan_out)).
fn xavier<T: Real>(rng: &mut ChaCha8Rng, w: &mut Tensor<T>, gain: f64) {
    let (rows, cols) = (w.shape()[0], w.shape()[1]);
    normal_scaled(
        rng,
        w.data_mut(),
        gain * (2.0 / (rows + cols) as f64).sqrt(),
    );
}
