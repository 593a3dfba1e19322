//! Inference run files: runs of several sequences stacked `[S, T_max, ...]` (per-module
//! states, per-step free-energy terms and errors, optionally the full read-outs), how their
//! states are stored ([`StateStorage`]), and reading them back ([`load_runs`]).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

use super::RUN_FORMAT;
use super::atomic::write_atomic;
use super::model::model_metadata;
use super::tensor_file::TensorFile;
use super::write::{OutTensor, to_bytes};
use crate::config::{Modality, ModelConfig, ModuleId};
use crate::error::{Error, Result};
use crate::free_energy::FreeEnergy;
use crate::infer::{InferenceSettings, ModuleStates, Run};
use crate::{Real, Tensor};

/// A run's per-step tensors (without the sequence axis): file name, `[steps, width]` data
/// and width.
fn run_tensors<'a, T: Real>(
    config: &ModelConfig,
    run: &'a Run<T>,
) -> Vec<(String, &'a [T], usize)> {
    let mut v = Vec::new();
    for modality in Modality::ALL {
        let width = config.modality_dims(modality);
        if let Some(recon) = &run.recon {
            v.push((
                format!("recon.{}", modality.name()),
                recon[modality.index()].data(),
                width,
            ));
        }
        if let Some(prior) = &run.prior_next {
            v.push((
                format!("prior.{}", modality.name()),
                prior[modality.index()].data(),
                width,
            ));
        }
    }
    for id in ModuleId::ALL {
        let m = &run.modules[id.index()];
        let widths = ModuleStates::<T>::widths(config.module(id).z, config.module(id).d);
        for ((field, data), width) in ModuleStates::<T>::FIELDS.iter().zip(m.fields()).zip(widths) {
            v.push((format!("{}.{field}", id.name()), data.as_slice(), width));
        }
    }
    v
}

/// Per-step scalars of a run, with their file names.
fn run_scalars<T: Real>(run: &Run<T>) -> Vec<(String, Vec<f64>)> {
    let mut v = vec![(
        "free_energy.total".to_string(),
        run.free_energy
            .iter()
            .map(|f| f.total)
            .collect::<Vec<f64>>(),
    )];
    for modality in Modality::ALL {
        let (n, i) = (modality.name(), modality.index());
        v.push((
            format!("free_energy.accuracy.{n}"),
            run.free_energy
                .iter()
                .map(|f| {
                    if i == 0 {
                        f.accuracy.exteroceptive
                    } else {
                        f.accuracy.proprioceptive
                    }
                })
                .collect(),
        ));
        v.push((
            format!("step_accuracy.{n}"),
            run.step_accuracy.iter().map(|a| a[i]).collect(),
        ));
        v.push((
            format!("recon_error.{n}"),
            run.recon_error.iter().map(|a| a[i]).collect(),
        ));
    }
    for id in ModuleId::ALL {
        v.push((
            format!("free_energy.complexity.{}", id.name()),
            run.free_energy
                .iter()
                .map(|f| f.complexity_of(id))
                .collect(),
        ));
    }
    v
}

/// Writes inference runs of several sequences, stacked `[S, T_max, ...]` (shorter runs are
/// zero-padded; `lengths` gives each run's steps): per-module states, per-step free-energy
/// terms and errors, and the full read-outs `recon.*` / `prior.*` when the runs kept them.
pub fn save_runs<T: Real>(
    path: &Path,
    config: &ModelConfig,
    runs: &[Run<T>],
    sequence_ids: &[usize],
    sequence_names: Option<&[String]>,
) -> Result<()> {
    write_atomic(
        path,
        &runs_to_bytes(
            config,
            runs,
            sequence_ids,
            sequence_names,
            StateStorage::F32,
        )?,
    )
}

/// How a runs file stores the per-step states (the per-step scalars stay f32).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StateStorage {
    F32,
    /// f16: half the size, about 3 significant digits.
    F16,
    /// f16 rounded to nearest with only this many of its 10 mantissa bits (the rest zero):
    /// the same dtype for readers, but far more compressible (gzip), for states that are
    /// drawn rather than computed with. 6 bits keep the relative error within about 2^-7 = 0.8%.
    F16Mantissa(u32),
}

impl StateStorage {
    /// The value a reader gets back for `v`.
    pub fn round_trip(self, v: f32) -> f32 {
        match self {
            StateStorage::F32 => v,
            _ => self.to_f16(v).to_f32(),
        }
    }

    /// `v` as an f16 (F32 storage writes f32 and does not use this).
    pub fn to_f16(self, v: f32) -> half::f16 {
        let h = half::f16::from_f32(v);
        match self {
            StateStorage::F16Mantissa(bits) if bits < 10 && h.is_finite() => {
                let drop = 10 - bits;
                let raw = h.to_bits();
                // Round half up on the magnitude; a carry into the exponent is still the
                // nearest value (and saturates to infinity only beyond f16's range).
                let rounded =
                    (raw & 0x7fff).saturating_add(1 << (drop - 1)) & !((1u16 << drop) - 1);
                half::f16::from_bits((raw & 0x8000) | rounded.min(0x7c00))
            }
            _ => h,
        }
    }
}

/// [`save_runs`] into bytes; `storage` chooses how the per-step states are stored (f16:
/// half the size, about three significant digits: enough for viewing, e.g. the explorer's
/// precomputed runs).
pub fn runs_to_bytes<T: Real>(
    config: &ModelConfig,
    runs: &[Run<T>],
    sequence_ids: &[usize],
    sequence_names: Option<&[String]>,
    storage: StateStorage,
) -> Result<Vec<u8>> {
    let Some(first) = runs.first() else {
        return Err(Error::InvalidArgument("no inference runs to save".into()));
    };
    let s = runs.len();
    let t_max = runs.iter().map(Run::steps).max().unwrap_or(0);
    let mut tensors = BTreeMap::new();
    let layout = run_tensors(config, first);
    for (k, (name, _, width)) in layout.iter().enumerate() {
        let width = *width;
        let mut data = vec![0f32; s * t_max * width];
        for (i, run) in runs.iter().enumerate() {
            let (other, t, _) = &run_tensors(config, run)[k];
            if other != name || t.len() != run.steps() * width {
                return Err(Error::InvalidArgument(format!(
                    "run {i} does not match the first run's layout at {name} ({} numbers for {} steps of width {width})",
                    t.len(),
                    run.steps()
                )));
            }
            for (dst, src) in data[i * t_max * width..].iter_mut().zip(t.iter()) {
                *dst = src.to_f32();
            }
        }
        let tensor = if storage == StateStorage::F32 {
            OutTensor::F32(vec![s, t_max, width], Cow::Owned(data))
        } else {
            OutTensor::F16(
                vec![s, t_max, width],
                data.iter().map(|&v| storage.to_f16(v)).collect(),
            )
        };
        tensors.insert(name.clone(), tensor);
    }
    let scalar_names: Vec<String> = run_scalars(first).into_iter().map(|(n, _)| n).collect();
    for (k, name) in scalar_names.into_iter().enumerate() {
        let mut data = vec![0f32; s * t_max];
        for (i, run) in runs.iter().enumerate() {
            for (t, v) in run_scalars(run)[k].1.iter().enumerate() {
                data[i * t_max + t] = *v as f32;
            }
        }
        tensors.insert(name, OutTensor::F32(vec![s, t_max], Cow::Owned(data)));
    }
    tensors.insert(
        "lengths".into(),
        OutTensor::I64(vec![s], runs.iter().map(|r| r.steps() as i64).collect()),
    );
    tensors.insert(
        "sequence".into(),
        OutTensor::I64(vec![s], sequence_ids.iter().map(|&i| i as i64).collect()),
    );
    let mut meta = model_metadata(config, RUN_FORMAT);
    meta.insert(
        "settings".into(),
        serde_json::to_string(&first.settings).expect("serialisable"),
    );
    if let Some(names) = sequence_names {
        meta.insert(
            "sequence_names".into(),
            serde_json::to_string(names).expect("serialisable"),
        );
    }
    to_bytes(&tensors, meta)
}

/// A run read from a file, with the sequence it belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedRun {
    /// Index of the sequence in the inputs it was run on.
    pub sequence: usize,
    /// Its name, for runs on a dataset.
    pub name: Option<String>,
    pub run: Run<f32>,
}

/// Reads runs written by [`save_runs`].
pub fn load_runs(file: &TensorFile, config: &ModelConfig) -> Result<Vec<LoadedRun>> {
    let bad = |detail: &str| Error::Format {
        what: file.what().into(),
        detail: detail.into(),
    };
    let settings: InferenceSettings = file
        .metadata("settings")
        .and_then(|s| serde_json::from_str::<InferenceSettings>(s).ok())
        .map(InferenceSettings::canonical)
        .ok_or_else(|| bad("no valid `settings` metadata: not a pvrnn inference file"))?;
    let names: Option<Vec<String>> = match file.metadata("sequence_names") {
        Some(text) => {
            Some(serde_json::from_str(text).map_err(|_| bad("invalid `sequence_names` metadata"))?)
        }
        None => None,
    };
    let lengths = file.indices("lengths")?;
    let ids = file.indices("sequence")?;
    let s = lengths.len();
    if ids.len() != s || names.as_ref().is_some_and(|n| n.len() != s) {
        return Err(bad(
            "`lengths`, `sequence` and `sequence_names` disagree on the number of runs",
        ));
    }
    let t_max = lengths.iter().copied().max().unwrap_or(0);
    let read = |name: &str, width: usize| file.f32(name, Some(&[s, t_max, width]));
    let cut = |t: &Tensor<f32>, i: usize, len: usize| -> Tensor<f32> {
        let width = t.shape()[2];
        Tensor::from_vec(&[len, width], t.sub(&[i])[..len * width].to_vec()).expect("sized")
    };
    let optional = |prefix: &str| -> Result<Option<Vec<Tensor<f32>>>> {
        if !file.contains(&format!("{prefix}.exteroceptive")) {
            return Ok(None);
        }
        Modality::ALL
            .iter()
            .map(|m| read(&format!("{prefix}.{}", m.name()), config.modality_dims(*m)))
            .collect::<Result<Vec<_>>>()
            .map(Some)
    };
    let recon = optional("recon")?;
    let prior = optional("prior")?;
    let mut module_tensors = Vec::new();
    for id in ModuleId::ALL {
        let (d, z) = (config.module(id).d, config.module(id).z);
        let n = id.name();
        module_tensors.push([
            read(&format!("{n}.mu_p"), z)?,
            read(&format!("{n}.sigma_p"), z)?,
            read(&format!("{n}.mu_q"), z)?,
            read(&format!("{n}.sigma_q"), z)?,
            read(&format!("{n}.d"), d)?,
            read(&format!("{n}.prior_d"), d)?,
        ]);
    }
    let scalar = |name: &str| file.f32(name, Some(&[s, t_max]));
    let total = scalar("free_energy.total")?;
    let per_modality = |prefix: &str| -> Result<Vec<Tensor<f32>>> {
        Modality::ALL
            .iter()
            .map(|m| scalar(&format!("{prefix}.{}", m.name())))
            .collect()
    };
    let fe_acc = per_modality("free_energy.accuracy")?;
    let step_acc = per_modality("step_accuracy")?;
    let recon_err = per_modality("recon_error")?;
    let cx: Vec<Tensor<f32>> = ModuleId::ALL
        .iter()
        .map(|m| scalar(&format!("free_energy.complexity.{}", m.name())))
        .collect::<Result<_>>()?;
    let mut runs = Vec::with_capacity(s);
    for i in 0..s {
        let len = lengths[i];
        let at = |x: &Tensor<f32>, t: usize| x.data()[i * t_max + t] as f64;
        let pair = |x: &[Tensor<f32>], t: usize| [at(&x[0], t), at(&x[1], t)];
        let free_energy = (0..len)
            .map(|t| {
                let mut fe = FreeEnergy::from_terms(
                    pair(&fe_acc, t),
                    std::array::from_fn(|m| at(&cx[m], t)),
                    config.kl_weight,
                );
                // The stored total, not one recomputed from f32-rounded terms.
                fe.total = at(&total, t);
                fe
            })
            .collect();
        let both = |x: &Option<Vec<Tensor<f32>>>| {
            x.as_ref().map(|v| [cut(&v[0], i, len), cut(&v[1], i, len)])
        };
        runs.push(LoadedRun {
            sequence: ids[i],
            name: names.as_ref().map(|n| n[i].clone()),
            run: Run {
                settings: settings.clone(),
                recon: both(&recon),
                prior_next: both(&prior),
                modules: std::array::from_fn(|m| {
                    let [a, b, c, d, e, f] = &module_tensors[m];
                    let cut = |x: &Tensor<f32>| cut(x, i, len).into_data();
                    ModuleStates {
                        mu_p: cut(a),
                        sigma_p: cut(b),
                        mu_q: cut(c),
                        sigma_q: cut(d),
                        d: cut(e),
                        prior_d: cut(f),
                    }
                }),
                free_energy,
                step_accuracy: (0..len).map(|t| pair(&step_acc, t)).collect(),
                recon_error: (0..len).map(|t| pair(&recon_err, t)).collect(),
            },
        });
    }
    Ok(runs)
}

#[cfg(test)]
mod storage_tests {
    use super::StateStorage;

    #[test]
    fn a_shortened_mantissa_rounds_to_nearest_and_zeroes_the_dropped_bits() {
        let six = StateStorage::F16Mantissa(6);
        for i in 0..20_000 {
            let v = ((i as f32) * 0.7317).sin() * 3.0 + (i as f32 * 1e-4);
            let stored = six.to_f16(v);
            assert_eq!(stored.to_bits() & 0b1111, 0, "{v}");
            let err = (stored.to_f32() - v).abs();
            // Half an ulp of a 6-bit mantissa after f16's own rounding (half an ulp of 10
            // bits), plus f16's absolute precision near zero.
            assert!(
                err <= v.abs() * (2f32.powi(-7) + 2f32.powi(-11)) + 1e-7,
                "{v} -> {stored}"
            );
        }
        // Rounding up carries into the exponent: 1.99 -> 2.
        assert_eq!(six.to_f16(1.999).to_f32(), 2.0);
        assert_eq!(six.to_f16(-1.999).to_f32(), -2.0);
        assert_eq!(StateStorage::F16.to_f16(0.1), half::f16::from_f32(0.1));
    }
}
