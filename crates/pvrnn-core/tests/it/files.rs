//! safetensors round trips, and a clear error for every kind of bad file or input.

use crate::fixtures;

#[cfg(target_arch = "wasm32")]
use wasm_bindgen_test::wasm_bindgen_test as test;

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};

use fixtures::{random_observations, tiny_config};
use pvrnn_core::free_energy::{NoiseDraw, free_energy};
use pvrnn_core::io::{self, OutTensor, TensorFile};
use pvrnn_core::{Model, ModelConfig, NoiseMode, cpu::CpuBackend};

fn tiny_model() -> Model<f32> {
    Model::<f32>::init(tiny_config(), 2, 5, 3).unwrap()
}

fn err_of(bytes: Vec<u8>) -> String {
    io::model_from_bytes(bytes, "m.safetensors")
        .unwrap_err()
        .to_string()
}

/// Rewrites a model file's tensors through `edit`.
fn edited(
    model: &Model<f32>,
    edit: impl FnOnce(&mut BTreeMap<String, OutTensor<'static>>),
) -> Vec<u8> {
    let mut tensors: BTreeMap<String, OutTensor<'static>> = BTreeMap::new();
    for (name, t, _) in model.params.named() {
        tensors.insert(name, OutTensor::f32(t));
    }
    for (name, t) in model.adaptive.named() {
        tensors.insert(name, OutTensor::f32(t));
    }
    edit(&mut tensors);
    let meta = HashMap::from([("config".to_string(), model.config.to_json())]);
    io::to_bytes(&tensors, meta).unwrap()
}

#[test]
fn model_round_trip_is_exact() {
    let model = tiny_model();
    let bytes = io::model_to_bytes(&model).unwrap();
    let back = io::model_from_bytes(bytes, "m").unwrap();
    assert_eq!(back, model);
}

#[test]
fn an_f16_model_is_half_the_size_and_rounds_each_weight() {
    // The paper's sizes, so the weights (not the metadata) make up the file.
    let model = Model::<f32>::init(ModelConfig::default(), 1, 2, 0).unwrap();
    let full = io::model_to_bytes(&model).unwrap();
    let half = io::model_to_bytes_f16(&model).unwrap();
    assert!(
        half.len() * 10 < full.len() * 6,
        "{} vs {}",
        half.len(),
        full.len()
    );
    let back = io::model_from_bytes(half, "m").unwrap();
    assert_eq!(back.config, model.config);
    for ((name, a, _), (_, b, _)) in model.params.named().into_iter().zip(back.params.named()) {
        for (x, y) in a.data().iter().zip(b.data()) {
            // f16 keeps 11 significant bits.
            assert!((x - y).abs() <= x.abs() * 1e-3 + 1e-7, "{name}: {x} vs {y}");
        }
    }
}

#[test]
fn spec_tensor_names_and_config_metadata() {
    let model = Model::<f32>::init(ModelConfig::default(), 1, 2, 0).unwrap();
    let file = TensorFile::from_bytes(io::model_to_bytes(&model).unwrap(), "m").unwrap();
    for name in [
        "executive.w_dd",
        "executive.w_dz",
        "associative.w_dh",
        "exteroceptive.bias",
        "proprioceptive.tau",
        "executive.w_prior_mu",
        "executive.w_prior_sigma",
        "executive.a_mu",
        "proprioceptive.a_sigma",
        "exteroceptive.fnn.0.weight",
        "exteroceptive.fnn.0.bias",
        "exteroceptive.fnn.1.weight",
        "exteroceptive.fnn.1.bias",
        "exteroceptive.out.weight",
        "proprioceptive.fnn.0.weight",
        "proprioceptive.fnn.0.bias",
        "proprioceptive.out.weight",
    ] {
        assert!(file.contains(name), "{name}");
    }
    assert!(!file.contains("executive.w_dh"));
    assert_eq!(
        file.shape("exteroceptive.out.weight"),
        Some(&[32256, 50][..])
    );
    assert_eq!(file.shape("exteroceptive.a_mu"), Some(&[1, 2, 40][..]));
    assert_eq!(file.shape("associative.w_dh"), Some(&[30, 30][..]));
    let config = ModelConfig::from_json(file.metadata("config").unwrap()).unwrap();
    assert_eq!(config, ModelConfig::default());
}

#[test]
fn truncated_file_is_reported() {
    let mut bytes = io::model_to_bytes(&tiny_model()).unwrap();
    bytes.truncate(bytes.len() - 10);
    let e = err_of(bytes);
    assert!(
        e.contains("m.safetensors") && e.contains("truncated"),
        "{e}"
    );
}

#[test]
fn corrupt_header_is_reported() {
    let mut bytes = io::model_to_bytes(&tiny_model()).unwrap();
    bytes[12] = b'#';
    let e = err_of(bytes);
    assert!(
        e.contains("m.safetensors") && e.contains("not a readable safetensors file"),
        "{e}"
    );
    let e = err_of(vec![1, 2, 3]);
    assert!(e.contains("header"), "{e}");
}

#[test]
fn missing_tensor_is_named() {
    let bytes = edited(&tiny_model(), |t| {
        t.remove("associative.w_prior_sigma");
    });
    assert_eq!(
        err_of(bytes),
        "m.safetensors: missing tensor `associative.w_prior_sigma`"
    );
}

#[test]
fn wrong_shape_is_named() {
    let bytes = edited(&tiny_model(), |t| {
        t.insert(
            "executive.w_dd".into(),
            OutTensor::F32(vec![3, 4], Cow::Owned(vec![0.0; 12])),
        );
    });
    let e = err_of(bytes);
    assert!(
        e.contains("`executive.w_dd` has shape [3, 4], expected [4, 4]"),
        "{e}"
    );
}

#[test]
fn nan_in_a_weight_is_named() {
    let model = tiny_model();
    let bytes = edited(&model, |t| {
        let mut v = model.params.modules[2].w_dz.data().to_vec();
        v[3] = f32::NAN;
        t.insert(
            "exteroceptive.w_dz".into(),
            OutTensor::F32(vec![5, 3], Cow::Owned(v)),
        );
    });
    let e = err_of(bytes);
    assert!(
        e.contains("`exteroceptive.w_dz` holds a non-finite value (NaN) at index [1, 0]"),
        "{e}"
    );
}

#[test]
fn unexpected_tensor_and_missing_config_are_reported() {
    let bytes = edited(&tiny_model(), |t| {
        t.insert(
            "cortex.w".into(),
            OutTensor::F32(vec![1], Cow::Owned(vec![0.0])),
        );
    });
    assert!(err_of(bytes).contains("unexpected tensor `cortex.w`"));
    let mut tensors: BTreeMap<String, OutTensor<'static>> = BTreeMap::new();
    tensors.insert("x".into(), OutTensor::F32(vec![1], Cow::Owned(vec![0.0])));
    let e = err_of(io::to_bytes(&tensors, HashMap::new()).unwrap());
    assert!(e.contains("no `config` metadata"), "{e}");
}

#[test]
fn model_that_does_not_fit_the_data_is_reported() {
    let model = tiny_model();
    let data = random_observations::<f32>(&model.config, 3, 5, 1);
    let e = free_energy(
        &CpuBackend,
        &model,
        &data,
        NoiseDraw::evaluation(NoiseMode::Zero),
        false,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("2 sequences of 5 steps") && e.contains("3 sequences"),
        "{e}"
    );
    let mut other = tiny_config();
    other.proprio_dims = 6;
    let data = random_observations::<f32>(&other, 2, 5, 1);
    let e = free_energy(
        &CpuBackend,
        &model,
        &data,
        NoiseDraw::evaluation(NoiseMode::Zero),
        false,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("x_proprio has 6 dimensions per step but the model expects 4"),
        "{e}"
    );
}

#[test]
fn inputs_with_nan_or_wrong_rank_are_rejected() {
    let mut tensors = BTreeMap::new();
    let mut x = vec![0f32; 2 * 3 * 30];
    x[40] = f32::INFINITY;
    tensors.insert(
        "x_extero".to_string(),
        OutTensor::F32(vec![2, 3, 30], Cow::Owned(x)),
    );
    tensors.insert(
        "x_proprio".to_string(),
        OutTensor::F32(vec![2, 3, 4], Cow::Owned(vec![0.0; 24])),
    );
    let file = TensorFile::from_bytes(
        io::to_bytes(&tensors, HashMap::new()).unwrap(),
        "x.safetensors",
    )
    .unwrap();
    let e = io::observations_from_file(&file).unwrap_err().to_string();
    assert!(
        e.contains(
            "x.safetensors: tensor `x_extero` holds a non-finite value (inf) at index [0, 1, 10]"
        ),
        "{e}"
    );

    tensors.insert(
        "x_extero".to_string(),
        OutTensor::F32(vec![6, 30], Cow::Owned(vec![0.0; 180])),
    );
    let file = TensorFile::from_bytes(
        io::to_bytes(&tensors, HashMap::new()).unwrap(),
        "x.safetensors",
    )
    .unwrap();
    let e = io::observations_from_file(&file).unwrap_err().to_string();
    assert!(
        e.contains("x.safetensors") && e.contains("`x_extero` has shape [6, 30]"),
        "{e}"
    );

    tensors.remove("x_extero");
    let file = TensorFile::from_bytes(
        io::to_bytes(&tensors, HashMap::new()).unwrap(),
        "x.safetensors",
    )
    .unwrap();
    assert_eq!(
        io::observations_from_file(&file).unwrap_err().to_string(),
        "x.safetensors: missing tensor `x_extero`"
    );
}

#[test]
fn dtype_other_than_f32_is_rejected() {
    let mut tensors = BTreeMap::new();
    tensors.insert(
        "x_extero".to_string(),
        OutTensor::I64(vec![1, 1, 1], vec![3]),
    );
    let file =
        TensorFile::from_bytes(io::to_bytes(&tensors, HashMap::new()).unwrap(), "x").unwrap();
    let e = file.f32("x_extero", None).unwrap_err().to_string();
    assert!(e.contains("dtype I64, expected F32"), "{e}");
}

#[cfg(not(target_arch = "wasm32"))]
mod on_disk {
    use super::*;
    use pvrnn_core::infer::InferenceSettings;
    use pvrnn_core::run_sequence;
    use pvrnn_core::train::Trainer;
    use std::sync::Arc;

    #[test]
    fn checkpoint_resume_continues_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let data = random_observations::<f32>(&tiny_config(), 2, 5, 9);
        let mut straight = Trainer::new(tiny_model(), NoiseMode::Sampled { seed: 4 });
        let mut split = Trainer::new(tiny_model(), NoiseMode::Sampled { seed: 4 });
        for _ in 0..3 {
            straight.step(&data).unwrap();
            split.step(&data).unwrap();
        }
        let path = dir.path().join("ckpt.safetensors");
        io::save_checkpoint(&path, &mut split, None).unwrap();
        let mut resumed = io::load_checkpoint(&path).unwrap();
        assert_eq!(resumed.iteration, 3);
        for _ in 0..3 {
            let a = straight.step(&data).unwrap();
            let b = resumed.step(&data).unwrap();
            assert_eq!(a, b);
        }
        assert_eq!(straight.model(), resumed.model());
        // A checkpoint is also a model file.
        assert_eq!(io::load_model(&path).unwrap().config, tiny_config());
        // And a model is not a checkpoint.
        let mpath = dir.path().join("m.safetensors");
        io::save_model(&mpath, &tiny_model()).unwrap();
        let e = io::load_checkpoint(&mpath).unwrap_err().to_string();
        assert!(e.contains("not a checkpoint"), "{e}");
    }

    #[test]
    fn missing_file_is_named() {
        let e = io::load_model(std::path::Path::new("/nonexistent/m.safetensors"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/nonexistent/m.safetensors:"), "{e}");
    }

    #[test]
    fn inputs_and_runs_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let config = tiny_config();
        let data = random_observations::<f32>(&config, 2, 5, 9);
        let path = dir.path().join("x.safetensors");
        io::save_observations(&path, &data).unwrap();
        assert_eq!(io::load_observations(&path).unwrap(), data);

        let model = Arc::new(tiny_model());
        let mut settings = InferenceSettings::from_config(&config, 2);
        settings.window = 3;
        settings.iterations = 2;
        let runs: Vec<_> = (0..2)
            .map(|s| {
                run_sequence(
                    model.clone(),
                    settings.clone(),
                    &data,
                    s,
                    true,
                    &mut |_, _| {},
                )
                .unwrap()
            })
            .collect();
        let rpath = dir.path().join("runs.safetensors");
        io::save_runs(&rpath, &config, &runs, &[0, 1], None).unwrap();
        let back = io::load_runs(&TensorFile::open(&rpath).unwrap(), &config).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[1].sequence, 1);
        assert_eq!(back[1].run.recon, runs[1].recon);
        assert_eq!(back[1].run.modules, runs[1].modules);
        assert_eq!(back[1].run.settings, settings);
        assert_eq!(back[1].run.recon_error.len(), 5);
        assert_eq!(back[0].run.modules[0].sigma_p.len(), 5 * config.executive.z);
        // A compact run keeps what reproduces the read-outs: recon = readout(d).
        let compact = pvrnn_core::infer::Run::<f32>::from_steps(settings.clone(), &[], false);
        assert!(compact.recon.is_none());
        let dw = config.exteroceptive.d;
        let d = &runs[0].modules[2].d[3 * dw..4 * dw];
        let again = pvrnn_core::backend::Backend::load(&CpuBackend, &model.params, &model.config)
            .readout(pvrnn_core::Modality::Exteroceptive, d, 1)
            .unwrap();
        let stored = runs[0].recon.as_ref().unwrap()[0].sub(&[3]);
        let worst = again
            .iter()
            .zip(stored)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5,
            "readout(d) differs from the stored reconstruction by {worst}"
        );
    }
}
