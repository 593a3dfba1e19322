//! The wgpu backend computes what the CPU backend computes: the free energy, every gradient,
//! online inference and the read-outs, on the same inputs, to f32 summation order. The CPU
//! backend's gradients are checked against finite differences (the backend suite's
//! `crates/pvrnn-backend-tests/src/gradients.rs`), so agreement here makes the GPU's gradients exact too.
//!
//! Runs on whatever adapter wgpu finds: on a machine without a GPU, Mesa's lavapipe (a CPU
//! Vulkan device). Set `PVRNN_SKIP_WGPU=1` to skip on a machine with no Vulkan driver.

use crate::common;

use common::{assert_close, assert_same_free_energy_and_gradients, config, observations};

use std::sync::Arc;

use pvrnn_core::backend::{
    Backend, FullOutputs, Grads, Posterior, Request, Trace, Window, WindowResult,
};
use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::free_energy::{NoiseDraw, free_energy};
use pvrnn_core::infer::{InferenceSettings, OnlineInference, run_sequence_on};
use pvrnn_core::train::Trainer;
use pvrnn_core::{
    Ablation, Modality, Model, ModelConfig, NoiseMode, Observations, Observed, Tensor,
};
use pvrnn_wgpu::{BlockedDepth, GpuRecurrence, OutputKernels, Tiling, WgpuBackend};

/// Tiling that sends every call to the GPU, however small (the tests' shapes are).
fn every_call() -> Tiling {
    Tiling {
        min_work: 0,
        ..Tiling::default()
    }
}

fn gpu() -> Option<WgpuBackend> {
    match WgpuBackend::new() {
        Ok(b) => {
            eprintln!("adapter: {}", b.adapter_name());
            Some(b.with_tiling(every_call()))
        }
        Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
            eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
            None
        }
        Err(e) => panic!("{e} (set PVRNN_SKIP_WGPU=1 to skip the GPU tests)"),
    }
}

fn free_energy_and_gradients_agree(gpu: WgpuBackend, sequences: usize, steps: usize) {
    free_energy_and_gradients_agree_with(gpu, config(), sequences, steps);
}

fn free_energy_and_gradients_agree_with(
    gpu: WgpuBackend,
    config: ModelConfig,
    sequences: usize,
    steps: usize,
) {
    let data = observations(&config, sequences, steps);
    let model = Model::<f32>::init_on(&CpuBackend, config, sequences, steps, 7).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0);
    assert_same_free_energy_and_gradients(
        free_energy(&CpuBackend, &model, &data, draw, true).unwrap(),
        free_energy(&gpu, &model, &data, draw, true).unwrap(),
    );
}

#[test]
fn free_energy_and_every_gradient_match_the_cpu_backend() {
    let Some(gpu) = gpu() else { return };
    // 160 rows: three row blocks of the row pass (the last short), five row tiles of the
    // column pass.
    free_energy_and_gradients_agree(gpu, 4, 40);
}

#[test]
fn many_groups_and_chunks_match_the_cpu_backend() {
    let Some(gpu) = gpu() else { return };
    // 4-row chunks of 63 rows (the last short); 15 column tiles in 4 splits of 4 (the last
    // short), so the input gradient is reduced from partials.
    free_energy_and_gradients_agree(
        gpu.clone().with_tiling(Tiling {
            target_workgroups: 4,
            max_splits: 64,
            max_chunk_bytes: 8 << 10,
            ..every_call()
        }),
        3,
        21,
    );
    // The same with the splits capped below what the workgroup target asks for: 3 splits
    // of 5 tiles.
    free_energy_and_gradients_agree(
        gpu.with_tiling(Tiling {
            target_workgroups: 4,
            max_splits: 3,
            max_chunk_bytes: 8 << 10,
            ..every_call()
        }),
        3,
        21,
    );
}

/// The register-blocked output-layer kernels compute what the CPU computes: one chunk
/// (160 rows: two row blocks of 128, the last short; 480 columns: four tiles of 128, the
/// last short), then many small chunks with several column splits and row ranges each, one
/// split walking many tiles (both tile depths), and learning with the layers resident,
/// with and without hidden read-out layers and biases.
#[test]
fn the_blocked_output_kernels_match_the_cpu_backend() {
    let Some(gpu) = gpu() else { return };
    let blocked = |tiling: Tiling| {
        gpu.clone().with_tiling(Tiling {
            output_kernels: OutputKernels::Blocked,
            ..tiling
        })
    };
    free_energy_and_gradients_agree(blocked(every_call()), 4, 40);
    // 4-row chunks of 63 rows (the last short), each chunk's d W added to the earlier
    // ones'; 4 column tiles of 128 (the last short), one split each, so partial input
    // gradients are reduced.
    free_energy_and_gradients_agree(
        blocked(Tiling {
            target_workgroups: 8,
            max_splits: 64,
            max_chunk_bytes: 8 << 10,
            ..every_call()
        }),
        3,
        21,
    );
    // Enough rows for several ranges of d W in one chunk: 3 x 60 = 180 rows in ranges of
    // 16 or more.
    free_energy_and_gradients_agree(
        blocked(Tiling {
            target_workgroups: 64,
            ..every_call()
        }),
        3,
        60,
    );
    // Chunks cut to whole 128-row blocks: 150 rows of vision fit the chunk's bytes, 128
    // are taken, so 300 rows run as 128, 128 and 44.
    free_energy_and_gradients_agree(
        blocked(Tiling {
            max_chunk_bytes: 150 * 480 * 4,
            ..every_call()
        }),
        6,
        50,
    );
    // One split and one row range per chunk: each workgroup walks many tiles (four column
    // tiles of the forward product, 30 of the input gradient, 10 row tiles of d W), so
    // every double buffer is filled and emptied many times; with both tile depths, and
    // then the default cut with the shallower tiles of an adapter with 16 KiB of workgroup
    // memory (lavapipe has 32: the cases above run the deeper).
    for depth in [BlockedDepth::Deep, BlockedDepth::Shallow] {
        free_energy_and_gradients_agree(
            blocked(Tiling {
                target_workgroups: 1,
                blocked_depth: Some(depth),
                ..every_call()
            }),
            4,
            40,
        );
    }
    free_energy_and_gradients_agree(
        blocked(Tiling {
            blocked_depth: Some(BlockedDepth::Shallow),
            ..every_call()
        }),
        4,
        40,
    );
    learning_with_resident_weights(blocked(every_call()), config(), None);
    learning_with_resident_weights(blocked(every_call()), other_readouts(), None);
    // Top hidden layers of whole vec4s (48 and 8 units): no padding lane to sum the
    // output biases in, so the weight gradient's threads add them themselves
    // (`blocked_weight_grad.wgsl`); the widths above (50, 10, 30) sum them in the lane.
    let mut whole_vec4s = config();
    whole_vec4s.exteroceptive_readout.hidden = vec![12, 48];
    whole_vec4s.proprioceptive_readout.hidden = vec![8];
    learning_with_resident_weights(blocked(every_call()), whole_vec4s, None);
}

/// The default output kernels (`OutputKernels::Auto`) are the blocked ones for a call of
/// one whole 128-row block or more (learning's batches) and the fused ones for fewer
/// (online inference's 30-row window): each call gives, bit for bit, the results of the
/// kernels it should pick, and not those of the others (their sums run in another order).
#[test]
fn the_default_output_kernels_are_blocked_for_batches_and_fused_for_windows() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 4, 2).unwrap();
    let k = config.vision.dims();
    let loss = |output_kernels, rows: usize| {
        let tiling = Tiling {
            output_kernels,
            ..every_call()
        };
        vision_loss(&gpu, &model, tiling, rows, k)
    };
    let (fused, blocked) = (OutputKernels::Fused, OutputKernels::Blocked);
    for (rows, picked, other) in [
        (128, blocked, fused),
        (127, fused, blocked),
        (30, fused, blocked),
    ] {
        assert_eq!(OutputKernels::Auto.for_rows(rows), picked, "{rows} rows");
        let auto = loss(OutputKernels::Auto, rows);
        let expected = loss(picked, rows);
        assert_eq!(auto.row_loss, expected.row_loss, "{rows} rows: loss");
        assert_eq!(auto.grad_in, expected.grad_in, "{rows} rows: d input");
        assert_eq!(auto.grad_w, expected.grad_w, "{rows} rows: d W");
        let not_picked = loss(other, rows);
        assert_ne!(
            auto.grad_w, not_picked.grad_w,
            "{rows} rows: the other kernels' d W"
        );
    }
}

/// The blocked kernels read the targets and the error gradient as vec4s where a row's
/// observed columns are a multiple of 4 (`Tiling::vector_io`), one value at a time
/// otherwise: the same arithmetic either way, over several chunks, splits and a short last
/// tile; with 478 of the 480 columns observed the scalar path runs whatever the tiling.
/// The same bits on lavapipe; another driver may fuse a multiply-add in one variant and
/// not the other, so the check allows f32 rounding (1e-6), far below a misplaced value's
/// error.
#[test]
fn the_blocked_kernels_give_the_same_results_with_vec4_or_scalar_access() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 4, 2).unwrap();
    let dims = config.vision.dims();
    for (rows, k) in [(300, dims), (300, dims - 4), (140, dims - 2)] {
        let loss = |vector_io| {
            let tiling = Tiling {
                output_kernels: OutputKernels::Blocked,
                target_workgroups: 8,
                max_chunk_bytes: 130 * dims * 4,
                vector_io,
                ..every_call()
            };
            vision_loss(&gpu, &model, tiling, rows, k)
        };
        let (vectors, scalars) = (loss(true), loss(false));
        let losses = |l: &[f64]| l.iter().map(|&v| v as f32).collect::<Vec<_>>();
        let (v_loss, s_loss) = (losses(&vectors.row_loss), losses(&scalars.row_loss));
        let shape = format!("{rows} x {k}");
        assert_close(&format!("{shape}: loss"), &s_loss, &v_loss, 1e-6);
        let (v_in, s_in) = (&vectors.grad_in, &scalars.grad_in);
        assert_close(&format!("{shape}: d input"), s_in, v_in, 1e-6);
        let (Some(v_w), Some(s_w)) = (&vectors.grad_w, &scalars.grad_w) else {
            panic!("{shape}: no weight gradients")
        };
        assert_close(&format!("{shape}: d W"), s_w, v_w, 1e-6);
        let (v_b, s_b) = (vectors.grad_b.as_ref(), scalars.grad_b.as_ref());
        assert_eq!(v_b.is_some(), s_b.is_some(), "{shape}: d b");
        if let (Some(v_b), Some(s_b)) = (v_b, s_b) {
            assert_close(&format!("{shape}: d b"), s_b, v_b, 1e-6);
        }
        assert!(vectors.row_loss.iter().all(|l| l.is_finite() && *l > 0.0));
    }
}

/// The vision output layer's loss and gradients on `gpu` under `tiling`, for `rows` rows
/// of made-up top hidden activations and targets, `k` columns observed.
fn vision_loss(
    gpu: &WgpuBackend,
    model: &Model<f32>,
    tiling: Tiling,
    rows: usize,
    k: usize,
) -> pvrnn_core::assembled::OutputLoss<f32> {
    let hidden = *model.config.exteroceptive_readout.hidden.last().unwrap();
    let dims = model.config.vision.dims();
    let layer = pvrnn_wgpu::GpuOutputLayer::upload(gpu.gpu().clone(), tiling, &model.params);
    let input: Vec<f32> = (0..rows * hidden)
        .map(|i| (i * 7919 % 113) as f32 / 113.0 - 0.5)
        .collect();
    let target_data: Vec<f32> = (0..rows * dims)
        .map(|i| (i * 104_729 % 97) as f32 / 97.0)
        .collect();
    let targets: Vec<&[f32]> = target_data.chunks_exact(dims).collect();
    let call = layer.loss(
        Modality::Exteroceptive,
        &input,
        rows,
        k,
        k,
        &targets,
        None,
        true,
    );
    pvrnn_core::deferred::now(call.expect("every call on the GPU"))
}

/// Learning with the output layers resident on the GPU (weights, biases and RAdam moments
/// updated there, `radam.wgsl`) follows the CPU's learning iteration by iteration, through
/// both RAdam phases (momentum only, then rectified); bringing the weights back in the
/// middle of a run changes nothing, and a checkpoint written from the GPU's state resumes
/// on the CPU where the GPU would have gone.
#[test]
fn learning_with_resident_weights_follows_the_cpu() {
    let Some(gpu) = gpu() else { return };
    learning_with_resident_weights(gpu.clone(), config(), None);
    // One hidden layer without a bias for vision, no output bias; proprioception with no
    // hidden layer (its output layer reads the module states directly).
    learning_with_resident_weights(gpu, other_readouts(), None);
}

/// With the recurrence on the GPU the whole iteration stays there (`DeviceIteration`): the
/// recurrent weights and every adaptive variable too, with their moments; only the
/// free-energy terms come back. It follows the CPU iteration by iteration, as above, for
/// sequences of one length (each copy between layouts one dispatch) and of several
/// (per window), with and without prior biases and hidden read-out layers.
#[test]
fn whole_learning_iterations_on_the_device_follow_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let gpu = gpu.with_recurrence_on_gpu(true);
    learning_with_resident_weights(gpu.clone(), config(), None);
    let mut other = other_readouts();
    other.prior_bias = !other.prior_bias;
    learning_with_resident_weights(gpu, other, Some(vec![21, 9, 16]));
}

fn other_readouts() -> ModelConfig {
    let mut other = config();
    other.exteroceptive_readout.hidden = vec![50];
    other.exteroceptive_readout.hidden_bias = false;
    other.exteroceptive_readout.output_bias = false;
    other.proprioceptive_readout.hidden = vec![];
    other
}

/// Calls with less work than `Tiling::min_work` stay on the CPU (a round trip would cost
/// more); larger ones, or all with the threshold at 0, go to the GPU.
#[test]
fn small_calls_stay_on_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 4, 2).unwrap();
    let (n, hidden) = (30, 10);
    let k = config.proprio_dims;
    let input = vec![0.1f32; n * hidden];
    let row = vec![0.2f32; k];
    let targets: Vec<&[f32]> = (0..n).map(|_| row.as_slice()).collect();
    let layer = |min_work| {
        pvrnn_wgpu::GpuOutputLayer::upload(
            gpu.gpu().clone(),
            Tiling {
                min_work,
                ..Tiling::default()
            },
            &model.params,
        )
    };
    let work = n * k * hidden;
    for (min_work, on_gpu) in [(work + 1, false), (work, true), (0, true)] {
        let layer = layer(min_work);
        let loss = layer.loss(
            Modality::Proprioceptive,
            &input,
            n,
            k,
            k,
            &targets,
            None,
            false,
        );
        assert_eq!(loss.is_some(), on_gpu, "loss with min_work {min_work}");
        let dims = config.proprio_dims;
        let predict = layer.predict(Modality::Proprioceptive, &input, n);
        assert_eq!(
            predict.is_some(),
            n * dims * hidden >= min_work,
            "predict with min_work {min_work}"
        );
    }
    // The default keeps a step of online inference's proprioception on the CPU.
    assert!(Tiling::default().min_work > n * k * hidden);
}

/// A learner's loaded model computes with the device's weights everywhere, also where the
/// host would run the read-outs' hidden layers (full read-outs, `LoadedModel::readout`):
/// after an update on the device, its results match a CPU model loaded from the weights
/// brought back, and not one loaded from the host's stale copy.
#[test]
fn a_learners_model_reads_out_with_the_device_weights() {
    let Some(gpu) = gpu() else { return };
    for config in [config(), other_readouts()] {
        let data = observations(&config, 2, 12);
        let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 2, 12, 3).unwrap();
        let mut optimizer = Trainer::new(model.clone(), NoiseMode::Zero)
            .state()
            .1
            .clone();
        let learner = gpu
            .learner(&model, &optimizer)
            .expect("a learner on the GPU");
        let draw = NoiseDraw::training(NoiseMode::Zero, 0);
        free_energy(learner.as_ref(), &model, &data, draw, true).unwrap();
        // A large step, so that stale weights would show.
        optimizer.config.lr = 0.05;
        learner.update(&optimizer.begin_step());
        let mut current = model.params.clone();
        {
            let mut values: Vec<&mut Tensor<f32>> = current
                .named_mut()
                .into_iter()
                .filter(|(_, _, role)| *role == pvrnn_core::params::Role::Trainable)
                .map(|(_, t, _)| t)
                .collect();
            for &i in learner.resident() {
                let value = values[i].data_mut();
                let (mut m, mut v) = (vec![0f32; value.len()], vec![0f32; value.len()]);
                learner.download(i, value, &mut m, &mut v);
            }
        }
        let on_device = learner.load(&model.params, &config);
        let fresh = CpuBackend.load(&current, &config);
        let stale = CpuBackend.load(&model.params, &config);
        let n = 5;
        for modality in Modality::ALL {
            let d_width = config.module(modality.module()).d;
            let d: Vec<f32> = (0..n * d_width)
                .map(|i| ((i * 7 % 11) as f32 / 11.0) - 0.5)
                .collect();
            let got = on_device.readout(modality, &d, n).unwrap();
            assert_close(
                &format!("{} read-out", modality.name()),
                &fresh.readout(modality, &d, n).unwrap(),
                &got,
                1e-4,
            );
            let off = stale
                .readout(modality, &d, n)
                .unwrap()
                .iter()
                .zip(&got)
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                off > 1e-3,
                "{}: the update changed nothing",
                modality.name()
            );
        }
        // Learning's evaluation with every read-out of every step.
        let eps: Vec<Vec<f32>> = pvrnn_core::ModuleId::ALL
            .iter()
            .map(|id| vec![0.1; 12 * config.module(*id).z])
            .collect();
        let windows: Vec<Window<'_, f32>> = (0..2)
            .map(|s| Window {
                len: 12,
                h0: None,
                posterior: Posterior::Prior,
                eps: std::array::from_fn(|m| eps[m].as_slice()),
                targets: Modality::ALL
                    .map(|modality| (0..12).map(|t| data.step(modality, s, t)).collect()),
            })
            .collect();
        let request = Request {
            observed: Observed::all(&config),
            ablation: Ablation::default(),
            grads: Grads::All,
            full_outputs: FullOutputs::AllSteps,
            resident_targets: None,
        };
        // And with a modality unobserved (vision): its full read-outs too.
        let vision_unobserved = Request {
            observed: Observed {
                vision_levels: 0,
                proprio: true,
            },
            grads: Grads::Adaptive,
            ..request
        };
        for request in [request, vision_unobserved] {
            let a = fresh.evaluate(&windows, &request).unwrap();
            let b = on_device.evaluate(&windows, &request).unwrap();
            for (wa, wb) in a.windows.iter().zip(&b.windows) {
                for mi in 0..2 {
                    assert_close("full read-outs", &wa.outputs[mi], &wb.outputs[mi], 1e-4);
                    let (la, lb) = (&wa.accuracy[mi], &wb.accuracy[mi]);
                    for (x, y) in la.iter().zip(lb) {
                        assert!(
                            (x - y).abs() <= 1e-5 * x.abs().max(1e-6),
                            "accuracy {x} vs {y}"
                        );
                    }
                }
            }
        }
    }
}

fn learning_with_resident_weights(
    gpu: WgpuBackend,
    config: ModelConfig,
    lengths: Option<Vec<usize>>,
) {
    // Small chunks and row ranges: the column pass accumulates the output layer's weight
    // gradient over several chunks, the hidden layers' over several ranges of rows.
    // No call is worth a round trip (`min_work`): the resident read-outs must run on the
    // GPU all the same, or the host would compute with its stale copies.
    let output_kernels = gpu.tiling().output_kernels;
    let gpu = gpu.with_tiling(Tiling {
        target_workgroups: 4,
        max_splits: 64,
        max_chunk_bytes: 8 << 10,
        weight_rows_per_split: 16,
        min_work: usize::MAX,
        output_kernels,
        ..Tiling::default()
    });
    assert!(gpu.resident_learning());
    let gpu_recurrence = gpu.recurrence_on_gpu();
    let mut config = config;
    config.train.optimizer.weight_decay = 1e-3;
    let data = observations(&config, 3, 21);
    let data = match lengths {
        Some(lengths) => Observations::new(
            data.tensor(Modality::Exteroceptive).clone(),
            data.tensor(Modality::Proprioceptive).clone(),
            Some(lengths),
        )
        .unwrap(),
        None => data,
    };
    let model = Model::<f32>::init_on(&CpuBackend, config, 3, 21, 7).unwrap();
    let noise = NoiseMode::Sampled { seed: 3 };
    let mut cpu = Trainer::new(model.clone(), noise);
    let mut on_gpu = Trainer::new(model.clone(), noise).with_backend(Box::new(gpu.clone()));
    let mut synced = Trainer::new(model.clone(), noise).with_backend(Box::new(gpu.clone()));
    // With the recurrence on the device, an iteration is encoded once and replayed after,
    // and the next iteration is queued before the free energy is read back
    // (`Learner::guards_updates`). This run gets a new learner every iteration: each of
    // its iterations is encoded anew from the weights brought back, and none is evaluated
    // ahead of the update before it.
    let mut anew = Some(Trainer::new(model, noise));
    let iterations = 10;
    for i in 0..iterations {
        let a = cpu.step(&data).unwrap().total;
        let read_backs = gpu.gpu().read_backs();
        let encodings = gpu.gpu().iterations_encoded();
        let recurrence_parts = gpu.gpu().recurrence_parts_encoded();
        let b = on_gpu.step(&data).unwrap().total;
        // The first step queues the next iteration too; every later one the iteration
        // after it.
        let first = u64::from(i == 0);
        if gpu_recurrence {
            // One submission's results: the free-energy terms.
            assert_eq!(
                gpu.gpu().read_backs() - read_backs,
                1 + first,
                "read-backs per iteration"
            );
            assert_eq!(
                gpu.gpu().iterations_encoded() - encodings,
                u64::from(i == 0),
                "iteration {i}: encoded only the first time"
            );
            assert_eq!(
                gpu.gpu().recurrence_parts_encoded() - recurrence_parts,
                u64::from(i == 0),
                "iteration {i}: the recurrence part encoded only the first time"
            );
            let encodings = gpu.gpu().iterations_encoded();
            let recurrence_parts = gpu.gpu().recurrence_parts_encoded();
            let mut fresh = anew.take().unwrap().with_backend(Box::new(gpu.clone()));
            let d = fresh.step(&data).unwrap().total;
            assert!(gpu.gpu().iterations_encoded() > encodings);
            assert!(gpu.gpu().recurrence_parts_encoded() > recurrence_parts);
            assert_eq!(b, d, "iteration {i}: F replayed and encoded anew");
            anew = Some(fresh);
        }
        let c = synced.step(&data).unwrap().total;
        assert!(
            (a - b).abs() <= 1e-5 * a.abs(),
            "iteration {i}: cpu F {a}, gpu F {b}"
        );
        // The read-back does not disturb the device's state.
        assert_eq!(b, c, "iteration {i}: F after bringing the weights back");
        if i == 0 {
            // Both read-outs, hidden layers included, stay on the device; with the
            // recurrence there, everything.
            let resident = on_gpu.resident_tensors();
            let whole = gpu_recurrence;
            let readouts: Vec<String> = pvrnn_core::train::trainable_names(cpu.model())
                .into_iter()
                .filter(|n| whole || n.contains(".out.") || n.contains(".fnn."))
                .collect();
            assert_eq!(resident.len(), readouts.len(), "{resident:?}");
            assert!(
                readouts.iter().all(|n| resident.contains(n)),
                "{resident:?}"
            );
        }
        if i % 3 == 1 {
            synced.model();
        }
    }
    assert!(cpu.state().1.step > 6, "the rectified phase was reached");
    let (cpu_model, cpu_opt) = cpu.state();
    let (cpu_model, cpu_opt) = (cpu_model.clone(), cpu_opt.clone());
    let names = pvrnn_core::train::trainable_names(&cpu_model);
    if let Some(anew) = anew.as_mut().filter(|_| gpu_recurrence) {
        assert!(
            state_bits(&mut on_gpu) == state_bits(anew),
            "weights and moments replayed and queued ahead differ from those encoded anew"
        );
    }
    {
        let (gpu_model, gpu_opt) = on_gpu.state();
        assert_eq!(gpu_opt.step, cpu_opt.step);
        for ((name, a, _), (_, b, _)) in cpu_model
            .params
            .named()
            .into_iter()
            .zip(gpu_model.params.named())
        {
            assert_close(&name, a.data(), b.data(), 1e-4);
        }
        for (i, name) in names.iter().enumerate() {
            assert_close(&format!("m of {name}"), &cpu_opt.m[i], &gpu_opt.m[i], 1e-3);
            assert_close(&format!("v of {name}"), &cpu_opt.v[i], &gpu_opt.v[i], 1e-3);
        }
    }
    // A checkpoint of the GPU run resumes on the CPU where the GPU run goes on.
    let dir = std::env::temp_dir().join(format!("pvrnn-learner-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("checkpoint.safetensors");
    pvrnn_core::io::save_checkpoint(&path, &mut on_gpu, None).unwrap();
    let mut resumed = pvrnn_core::io::load_checkpoint(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    for i in 0..3 {
        let a = resumed.step(&data).unwrap().total;
        let b = on_gpu.step(&data).unwrap().total;
        assert!(
            (a - b).abs() <= 1e-5 * a.abs(),
            "resumed iteration {i}: cpu F {a}, gpu F {b}"
        );
    }
}

/// A diverged evaluation's mark on the device (`finite_check.wgsl`) skips the update
/// queued behind it: a step on data whose free energy is not finite fails, and the next
/// steps on sane data learn exactly as if that step had never been taken.
#[test]
fn a_diverged_evaluation_skips_the_update_behind_it() {
    let Some(gpu) = gpu() else { return };
    let gpu = gpu.with_recurrence_on_gpu(true);
    let config = config();
    let sane = observations(&config, 2, 12);
    // Squared errors past f32's range: the free energy is infinite.
    let huge = {
        let scaled = |t: &pvrnn_core::Tensor<f32>| {
            let values = t.data().iter().map(|v| 1e30 * v).collect();
            pvrnn_core::Tensor::from_vec(t.shape(), values).unwrap()
        };
        Observations::new(
            scaled(sane.tensor(Modality::Exteroceptive)),
            scaled(sane.tensor(Modality::Proprioceptive)),
            None,
        )
        .unwrap()
    };
    let model = Model::<f32>::init_on(&CpuBackend, config, 2, 12, 5).unwrap();
    let noise = NoiseMode::Sampled { seed: 4 };
    let mut interrupted = Trainer::new(model.clone(), noise).with_backend(Box::new(gpu.clone()));
    let mut straight = Trainer::new(model, noise).with_backend(Box::new(gpu));
    interrupted.step(&sane).unwrap();
    straight.step(&sane).unwrap();
    match interrupted.step(&huge) {
        Err(pvrnn_core::Error::Numerical(_)) => {}
        other => panic!("expected the divergence, got {other:?}"),
    }
    for i in 0..2 {
        let a = interrupted.step(&sane).unwrap().total;
        let b = straight.step(&sane).unwrap().total;
        assert_eq!(
            a.to_bits(),
            b.to_bits(),
            "iteration {i} after the diverged step"
        );
    }
    assert!(
        state_bits(&mut interrupted) == state_bits(&mut straight),
        "the update after a diverged evaluation was skipped too"
    );
}

/// Every value of a run's weights, adaptive variables and optimiser moments, as bits.
fn state_bits(trainer: &mut Trainer<f32>) -> Vec<u32> {
    let (model, optimizer) = trainer.state();
    let values = model.params.named().into_iter().map(|(_, t, _)| t.data());
    let adaptive = model.adaptive.named().into_iter().map(|(_, t)| t.data());
    let moments = optimizer.m.iter().chain(&optimizer.v).map(Vec::as_slice);
    values
        .chain(adaptive)
        .chain(moments)
        .flat_map(|v| v.iter().map(|x| x.to_bits()))
        .collect()
}

/// Learning's targets stay on the GPU between iterations (keyed by the observations' id):
/// the same data again reuses them, other data is uploaded beside them (runs sharing one
/// GPU keep theirs), data unused for a while is freed, and everything agrees with the CPU.
#[test]
fn resident_targets_follow_the_data() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 2, 10, 4).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 2 }, 0);
    let first = observations(&config, 2, 10);
    // Same shapes, other values: a stale cache would give the first data's free energy.
    let second = {
        let x = first
            .tensor(Modality::Exteroceptive)
            .data()
            .iter()
            .map(|v| -0.5 * v)
            .collect();
        let p = first.tensor(Modality::Proprioceptive).data().to_vec();
        Observations::new(
            Tensor::from_vec(first.tensor(Modality::Exteroceptive).shape(), x).unwrap(),
            Tensor::from_vec(first.tensor(Modality::Proprioceptive).shape(), p).unwrap(),
            None,
        )
        .unwrap()
    };
    assert_ne!(first.id(), second.id());
    let agree = |data: &Observations<f32>| {
        let (cpu, _) = free_energy(&CpuBackend, &model, data, draw, false).unwrap();
        let (on_gpu, _) = free_energy(&gpu, &model, data, draw, false).unwrap();
        assert!(
            (cpu.total - on_gpu.total).abs() <= 1e-5 * cpu.total.abs(),
            "cpu {} gpu {}",
            cpu.total,
            on_gpu.total
        );
    };
    let uploads = || gpu.gpu().resident_uploads();
    agree(&first);
    // One upload per modality whose output layer runs on the GPU.
    let per_data = uploads();
    assert!(per_data > 0);
    for data in [&first, &second, &first, &second] {
        agree(data);
    }
    assert_eq!(
        uploads(),
        2 * per_data,
        "alternating data re-uploaded its targets"
    );
    // The first data's targets go once unused for long enough (a second, and 64 look-ups
    // of any data: more than 64 calls, whichever output layers run here); using it again
    // uploads them.
    std::thread::sleep(std::time::Duration::from_millis(1100));
    for _ in 0..70 {
        agree(&second);
    }
    assert_eq!(uploads(), 2 * per_data);
    agree(&first);
    assert_eq!(uploads(), 3 * per_data, "stale targets were not freed");
}

/// Runs sharing one device from several threads (`pvrnn experiment --jobs N --backend
/// wgpu`): each gets its own results. (One thread's poll of the device can map another's
/// read-back; the other must still wait for it, not find it missing.)
#[test]
fn threads_sharing_the_device_each_get_their_own_results() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 3 }, 0);
    let runs: Vec<(Model<f32>, Observations<f32>)> = (0..4)
        .map(|k| {
            let model = Model::<f32>::init_on(&CpuBackend, config.clone(), 2, 8, 10 + k).unwrap();
            (model, observations(&config, 2, 8))
        })
        .collect();
    std::thread::scope(|scope| {
        for (model, data) in &runs {
            let gpu = &gpu;
            scope.spawn(move || {
                let (cpu, _) = free_energy(&CpuBackend, model, data, draw, true).unwrap();
                for _ in 0..200 {
                    let (on_gpu, _) = free_energy(gpu, model, data, draw, true).unwrap();
                    assert!(
                        (cpu.total - on_gpu.total).abs() <= 1e-5 * cpu.total.abs(),
                        "cpu {} gpu {}",
                        cpu.total,
                        on_gpu.total
                    );
                }
            });
        }
    });
}

/// Windows of 30 steps, the prior's biases learned too, the recurrent weight gradients
/// summed over 3 windows: a partial sum per window, added in window order.
#[test]
fn the_recurrence_on_the_gpu_gives_the_same_free_energy_and_gradients() {
    let Some(gpu) = gpu() else { return };
    let mut config = config();
    config.prior_bias = true;
    let gpu = gpu.with_recurrence_on_gpu(true);
    free_energy_and_gradients_agree_with(gpu, config, 3, 30);
}

/// Where the recurrent weight gradients' partial sums (one per weight and window) do not
/// fit one binding, one thread per weight sums over all of a network's windows instead
/// (`recurrence_weights.wgsl` without `PARTIALS`): the paper's modules over more two-step
/// windows than the adapter's binding holds partial sums for, against the CPU. Skipped
/// where that takes more than 4,000 windows (a GPU's larger bindings).
#[test]
fn weight_gradients_over_more_windows_than_partial_sums_fit_match_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let gpu = gpu.with_recurrence_on_gpu(true);
    let config = paper_modules();
    // The modules' matrices: fewer floats than the packed weights, so more windows than
    // the partial sums need.
    let probe = Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 2, 7).unwrap();
    let modules = [
        "executive",
        "associative",
        "exteroceptive",
        "proprioceptive",
    ];
    let weights: usize = probe
        .params
        .named()
        .iter()
        .filter(|(name, ..)| modules.iter().any(|m| name.starts_with(&format!("{m}.w_"))))
        .map(|(_, t, _)| t.len())
        .sum();
    let descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    let instance = wgpu::Instance::new(descriptor);
    let adapter = wgpu::util::initialize_adapter_from_env_or_default(&instance, None);
    let binding = pollster::block_on(adapter)
        .unwrap()
        .limits()
        .max_storage_buffer_binding_size;
    let windows = binding as usize / (4 * weights) + 1;
    if windows > 4000 {
        eprintln!("skipped: {windows} windows");
        return;
    }
    let data = observations(&config, windows, 2);
    let model = Model::<f32>::init_on(&CpuBackend, config, windows, 2, 7).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0);
    assert_same_free_energy_and_gradients(
        free_energy(&CpuBackend, &model, &data, draw, true).unwrap(),
        free_energy(&gpu, &model, &data, draw, true).unwrap(),
    );
}

/// The tests' small read-outs with the paper's four modules (and prior biases): the
/// recurrence kernels' shapes at the paper's scale.
fn paper_modules() -> ModelConfig {
    let mut config = config();
    config.prior_bias = true;
    let paper = ModelConfig::default();
    (config.executive, config.associative) = (paper.executive, paper.associative);
    (config.exteroceptive, config.proprioceptive) = (paper.exteroceptive, paper.proprioceptive);
    config
}

/// The recurrence kernels' workgroup width (`Tiling::recurrence_threads`) changes which
/// thread computes a sum and how its loads are issued, not the sum: with the paper's
/// modules, the default (one thread per item of a step's widest phase, 384), the width
/// before (128 threads: up to three dot products per thread), 32 threads, 256 (WebGPU's
/// default limit), and the default width with each step's loads issued where they are
/// used rather than at the step's start (`Tiling::recurrence_early_loads`) give bit for bit
/// the same free energy and gradients for one call, and the same whole learning iterations
/// on the device.
#[test]
fn the_recurrence_kernels_give_the_same_sums_at_any_width() {
    let Some(gpu) = gpu() else { return };
    let wide = gpu.with_recurrence_on_gpu(true);
    let config = paper_modules();
    let data = observations(&config, 3, 21);
    let model = Model::<f32>::init_on(&CpuBackend, config, 3, 21, 7).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0);
    let noise = NoiseMode::Sampled { seed: 3 };
    let (f_wide, g_wide) = free_energy(&wide, &model, &data, draw, true).unwrap();
    let g_wide = g_wide.unwrap();
    let mut wide_learner = Trainer::new(model.clone(), noise).with_backend(Box::new(wide.clone()));
    let wide_steps: Vec<f64> = (0..3)
        .map(|_| wide_learner.step(&data).unwrap().total)
        .collect();
    // The last: the default width with each step's loads where they are used
    // (`Tiling::recurrence_early_loads` off; the narrower widths cannot issue them early).
    for (threads, early) in [
        (Some(128), true),
        (Some(32), true),
        (Some(256), true),
        (None, false),
    ] {
        let narrow = wide.clone().with_tiling(Tiling {
            recurrence_threads: threads,
            recurrence_early_loads: early,
            ..wide.tiling()
        });
        let threads = format!("{threads:?} threads, early loads {early}");
        let (f, g) = free_energy(&narrow, &model, &data, draw, true).unwrap();
        assert_eq!(f_wide.total, f.total, "{threads}");
        let g = g.unwrap();
        for ((name, a, _), (_, b, _)) in g_wide.params.named().into_iter().zip(g.params.named()) {
            assert_eq!(a.data(), b.data(), "{threads}: {name}");
        }
        for m in 0..4 {
            assert_eq!(g_wide.adaptive.a_mu[m].data(), g.adaptive.a_mu[m].data());
            assert_eq!(
                g_wide.adaptive.a_sigma[m].data(),
                g.adaptive.a_sigma[m].data()
            );
        }
        let mut learner = Trainer::new(model.clone(), noise).with_backend(Box::new(narrow));
        for (i, &expected) in wide_steps.iter().enumerate() {
            let total = learner.step(&data).unwrap().total;
            assert_eq!(expected, total, "{threads}, iteration {i}");
        }
    }
}

/// The paper's modules over a window of 300 steps, at the kernels' default width: the
/// free energy and every gradient as the CPU's. Short windows hide some faults: on
/// lavapipe (Mesa 22.3.6) the kernels at 32 threads per window, and at 128 with the loops
/// before 2026-11-28, leave the CPU after about 290 steps (one 8-lane batch computes
/// wrong sums from then on, the same every run; at 64 only the gradients do), while 96,
/// 128, 256 and 384 threads agree with it to 3e-8. The old loops at 128 threads agreed
/// with the CPU on an H200 at the paper's scale (8.3e-8 over six iterations, 2026-11-26),
/// so this looks like lavapipe's, not the kernels'; the defaults stay clear of it.
#[test]
fn the_recurrence_kernels_match_the_cpu_over_long_windows() {
    let Some(gpu) = gpu() else { return };
    let config = paper_modules();
    let data = observations(&config, 1, 300);
    let model = Model::<f32>::init_on(&CpuBackend, config, 1, 300, 7).unwrap();
    let draw = NoiseDraw::training(NoiseMode::Sampled { seed: 5 }, 0);
    assert_same_free_energy_and_gradients(
        free_energy(&CpuBackend, &model, &data, draw, true).unwrap(),
        free_energy(&gpu.with_recurrence_on_gpu(true), &model, &data, draw, true).unwrap(),
    );
}

/// Every field of every window's states and the adaptive variables' gradients, from the
/// recurrence kernels against `cpu::recurrent`: windows of different lengths in one
/// dispatch, one starting from a held state, one whose posterior is the prior, and an
/// ablated module.
#[test]
fn the_recurrence_kernels_match_the_cpu_state_by_state() {
    let Some(gpu) = gpu() else { return };
    let gpu = gpu.with_recurrence_on_gpu(true);
    let mut config = config();
    // The prior's optional biases too, with values that matter.
    config.prior_bias = true;
    let mut model = Model::<f32>::init_on(&CpuBackend, config.clone(), 3, 9, 11).unwrap();
    for (name, t, _) in model.params.named_mut() {
        if name.contains("b_prior") {
            for (i, v) in t.data_mut().iter_mut().enumerate() {
                *v = 0.3 * (1.7 * i as f32).sin();
            }
        }
    }
    let data = observations(&config, 3, 9);
    let wave = |n: usize, phase: f32| -> Vec<f32> {
        (0..n).map(|i| (0.37 * i as f32 + phase).sin()).collect()
    };
    let dims = |m: usize| {
        (
            model.config.module(pvrnn_core::ModuleId::ALL[m]).d,
            model.config.module(pvrnn_core::ModuleId::ALL[m]).z,
        )
    };
    let lens = [9, 4, 7];
    let eps: Vec<[Vec<f32>; 4]> = lens
        .iter()
        .enumerate()
        .map(|(w, &len)| std::array::from_fn(|m| wave(len * dims(m).1, w as f32 + m as f32)))
        .collect();
    let h0: [Vec<f32>; 4] = std::array::from_fn(|m| wave(dims(m).0, 2.0 + m as f32));
    let windows: Vec<Window<'_, f32>> = lens
        .iter()
        .enumerate()
        .map(|(w, &len)| {
            let a = &model.adaptive;
            let rows = |m: usize| 0..len * dims(m).1;
            Window {
                len,
                h0: (w == 1).then(|| std::array::from_fn(|m| h0[m].as_slice())),
                posterior: if w == 2 {
                    Posterior::Prior
                } else {
                    Posterior::Adaptive {
                        a_mu: std::array::from_fn(|m| {
                            &a.a_mu[m].data()[w * 9 * dims(m).1..][rows(m)]
                        }),
                        a_sigma: std::array::from_fn(|m| {
                            &a.a_sigma[m].data()[w * 9 * dims(m).1..][rows(m)]
                        }),
                    }
                },
                eps: std::array::from_fn(|m| eps[w][m].as_slice()),
                targets: std::array::from_fn(|mi| {
                    let modality = Modality::ALL[mi];
                    let x = data.tensor(modality);
                    let width = x.shape()[2];
                    (0..len)
                        .map(|t| &x.data()[(w * 9 + t) * width..][..width])
                        .collect()
                }),
            }
        })
        .collect();
    let request = Request {
        observed: Observed::all(&config),
        ablation: Ablation([false, true, false, false]),
        grads: Grads::Adaptive,
        full_outputs: FullOutputs::None,
        resident_targets: None,
    };
    // The kernels take this batch (a `None` would leave it to the CPU, and the comparison
    // below would compare the CPU with itself).
    let direct = GpuRecurrence::upload(gpu.gpu().clone(), gpu.tiling(), &model.params, &config);
    assert!(direct.forward_on_gpu(&windows, &request.ablation).is_some());
    let on_cpu = CpuBackend
        .load(&model.params, &config)
        .evaluate(&windows, &request)
        .unwrap();
    let on_gpu = gpu
        .load(&model.params, &config)
        .evaluate(&windows, &request)
        .unwrap();
    for (w, (a, b)) in on_cpu.windows.iter().zip(&on_gpu.windows).enumerate() {
        let (a, b): (&WindowResult<f32>, &WindowResult<f32>) = (a, b);
        let fields = |t: &Trace<f32>, m: usize| {
            let s = &t.modules[m];
            [
                ("h0", s.h0.clone()),
                ("d0", s.d0.clone()),
                ("h", s.h.clone()),
                ("d", s.d.clone()),
                ("mu_p", s.mu_p.clone()),
                ("pre_mu_p", s.pre_mu_p.clone()),
                ("log_sigma_p", s.log_sigma_p.clone()),
                ("inv_var_p", s.inv_var_p.clone()),
                ("mu_q", s.mu_q.clone()),
                ("log_sigma_q", s.log_sigma_q.clone()),
                ("sigma_q", s.sigma_q.clone()),
                ("z", s.z.clone()),
            ]
        };
        for m in 0..4 {
            for ((name, x), (_, y)) in fields(&a.trace, m).into_iter().zip(fields(&b.trace, m)) {
                assert_close(&format!("window {w} module {m} {name}"), &x, &y, 1e-5);
            }
            for (k, l) in a.trace.modules[m].kl.iter().zip(&b.trace.modules[m].kl) {
                assert!(
                    (k - l).abs() <= 1e-5 * k.abs().max(1.0),
                    "window {w} module {m} kl: {k} vs {l}"
                );
            }
            let grads = |r: &WindowResult<f32>| {
                (
                    r.grad_a_mu.clone().unwrap()[m].clone(),
                    r.grad_a_sigma.clone().unwrap()[m].clone(),
                )
            };
            let ((mu_a, sigma_a), (mu_b, sigma_b)) = (grads(a), grads(b));
            assert_close(
                &format!("window {w} module {m} dF/da_mu"),
                &mu_a,
                &mu_b,
                1e-4,
            );
            assert_close(
                &format!("window {w} module {m} dF/da_sigma"),
                &sigma_a,
                &sigma_b,
                1e-4,
            );
        }
        // The ablated module's z is exactly 0.
        assert!(b.trace.modules[1].z.iter().all(|&z| z == 0.0));
    }
}

#[test]
fn online_inference_and_read_outs_match_the_cpu_backend() {
    let Some(gpu) = gpu() else { return };
    online_inference_agrees(gpu);
}

/// `with_recurrence_on_gpu` is a learning option: online inference keeps the recurrence
/// on the CPU (`Backend::load_for_inference`), so a run is bit for bit the one without it,
/// with the same read-backs (the GPU's recurrence would add two per update).
#[test]
fn online_inference_keeps_the_recurrence_on_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let data = observations(&config, 1, 8);
    let model = Arc::new(Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 8, 3).unwrap());
    let mut settings = InferenceSettings::from_config(&config, 2);
    settings.window = 4;
    settings.iterations = 3;
    let run = |backend: &WgpuBackend| {
        let before = backend.gpu().read_backs();
        let run = whole_run(backend, &model, &settings, &data);
        (run, backend.gpu().read_backs() - before)
    };
    let (plain, plain_read_backs) = run(&gpu);
    let (learning_option, read_backs) = run(&gpu.clone().with_recurrence_on_gpu(true));
    assert!(plain_read_backs > 0, "the output layers ran on the GPU");
    assert_eq!(read_backs, plain_read_backs);
    let totals =
        |r: &pvrnn_core::infer::Run<f32>| r.free_energy.iter().map(|f| f.total).collect::<Vec<_>>();
    assert_eq!(totals(&learning_option), totals(&plain));
    for mi in 0..2 {
        assert_eq!(
            learning_option.recon.as_ref().unwrap()[mi].data(),
            plain.recon.as_ref().unwrap()[mi].data()
        );
    }
}

/// Online inference over the first sequence of `data`, with every output.
fn whole_run(
    backend: &dyn Backend<f32>,
    model: &Arc<Model<f32>>,
    settings: &InferenceSettings,
    data: &Observations<f32>,
) -> pvrnn_core::infer::Run<f32> {
    run_sequence_on(
        backend,
        model.clone(),
        settings.clone(),
        data,
        0,
        true,
        &mut |_, _| {},
    )
    .unwrap()
}

fn online_inference_agrees(gpu: WgpuBackend) {
    let config = config();
    let data = observations(&config, 1, 12);
    let model = Arc::new(Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 12, 3).unwrap());
    let mut settings = InferenceSettings::from_config(&config, 2);
    settings.window = 6;
    settings.iterations = 5;
    // The lower resolution and proprioception observed: the loss sees 96 of 480 columns,
    // the reconstruction covers all of them.
    settings.observed = Observed {
        vision_levels: 1,
        proprio: true,
    };
    let run = |backend: &dyn Backend<f32>| whole_run(backend, &model, &settings, &data);
    let (cpu, gpu_run) = (run(&CpuBackend), run(&gpu));
    for (a, b) in cpu.free_energy.iter().zip(&gpu_run.free_energy) {
        assert!(
            (a.total - b.total).abs() <= 1e-4 * a.total.abs(),
            "{} vs {}",
            a.total,
            b.total
        );
    }
    for mi in 0..2 {
        assert_close(
            "reconstruction",
            cpu.recon.as_ref().unwrap()[mi].data(),
            gpu_run.recon.as_ref().unwrap()[mi].data(),
            1e-3,
        );
    }
    // The explorer's read-out of stored states.
    let d = cpu.modules[Modality::Exteroceptive.module().index()]
        .d
        .clone();
    let n = d.len() / config.exteroceptive.d;
    let on_cpu = CpuBackend.load(&model.params, &model.config);
    let on_gpu = gpu.load(&model.params, &model.config);
    assert_close(
        "readout",
        &on_cpu.readout(Modality::Exteroceptive, &d, n).unwrap(),
        &on_gpu.readout(Modality::Exteroceptive, &d, n).unwrap(),
        1e-5,
    );
}

#[test]
fn the_adapter_is_named() {
    let Some(gpu) = gpu() else { return };
    assert!(!gpu.adapter_name().trim().is_empty());
}

/// A step whose updates diverge on the GPU (non-finite output-layer results come back as
/// they are, not clamped) restarts from the step's start at half the rate, as the CPU's
/// does.
#[test]
fn a_diverging_step_restarts_on_the_gpu_as_on_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let config = config();
    let data = observations(&config, 1, 4);
    let model = Arc::new(Model::<f32>::init_on(&CpuBackend, config.clone(), 1, 4, 2).unwrap());
    let first_step = |backend: &dyn Backend<f32>, lr: f64| {
        let mut settings = InferenceSettings::from_config(&config, 3);
        settings.window = 4;
        settings.iterations = 20;
        settings.optimizer.lr = lr;
        let mut inference =
            OnlineInference::with_backend(model.clone(), settings, backend).unwrap();
        inference.step(
            data.step(Modality::Exteroceptive, 0, 0),
            data.step(Modality::Proprioceptive, 0, 0),
        )
    };
    // The smallest power of two that diverges on the CPU.
    let (exponent, cpu) = (0..80)
        .find_map(|e| match first_step(&CpuBackend, 2f64.powi(e)) {
            Ok(out) if out.rate_halvings > 0 => Some((e, out)),
            _ => None,
        })
        .expect("some rate diverges");
    let on_gpu = first_step(&gpu, 2f64.powi(exponent)).unwrap();
    assert_eq!(on_gpu.rate_halvings, cpu.rate_halvings);
    for mi in 0..2 {
        assert_close("reconstruction", &cpu.recon[mi], &on_gpu.recon[mi], 1e-3);
    }
    // A rate that diverges at every halving: both give up with the same error.
    let hopeless = (exponent..exponent + 40)
        .find_map(|e| {
            first_step(&CpuBackend, 2f64.powi(e))
                .err()
                .map(|err| (e, err))
        })
        .expect("a large enough rate diverges at every halving");
    let on_gpu = first_step(&gpu, 2f64.powi(hopeless.0))
        .unwrap_err()
        .to_string();
    let on_cpu = hopeless.1.to_string();
    assert!(on_gpu.contains("restarted 30 times"), "{on_gpu}");
    assert_eq!(on_gpu.split(" (").next(), on_cpu.split(" (").next());
}
