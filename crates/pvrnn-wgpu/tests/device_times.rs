//! The profile's device times (`pvrnn bench --profile`): in a test binary of its own,
//! because profiling is global to a process and the other tests' iterations would count
//! in it.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))] // the profile is native only

mod common;

use common::{config, observations};

use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::train::Trainer;
use pvrnn_core::{Model, NoiseMode};
use pvrnn_wgpu::WgpuBackend;

/// While profiling, each part of a whole iteration on the device and of its update runs in
/// a pass of its own, timed by the device (`timing.rs`): every part is in the profile once
/// per iteration (an evaluation once more: the last step queued the next iteration's,
/// `Tiling::queue_ahead`), and the free energies are those of a run without profiling.
#[test]
fn the_profile_times_each_part_of_a_whole_iteration_on_the_device() {
    let gpu = match WgpuBackend::new() {
        Ok(gpu) => gpu,
        Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
            eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
            return;
        }
        Err(e) => panic!("{e} (set PVRNN_SKIP_WGPU=1 to skip the GPU tests)"),
    };
    if !gpu.gpu().has_timestamps() {
        eprintln!("skipped: {} has no timestamp queries", gpu.adapter_name());
        return;
    }
    let gpu = gpu.with_recurrence_on_gpu(true);
    let config = config();
    let data = observations(&config, 2, 12);
    let model = Model::<f32>::init_on(&CpuBackend, config, 2, 12, 4).unwrap();
    let noise = NoiseMode::Sampled { seed: 2 };
    let mut plain = Trainer::new(model.clone(), noise).with_backend(Box::new(gpu.clone()));
    let mut timed = Trainer::new(model, noise).with_backend(Box::new(gpu.clone()));
    let iterations = 3;
    let expected: Vec<f64> = (0..iterations)
        .map(|_| plain.step(&data).unwrap().total)
        .collect();
    pvrnn_core::profile::enable(true);
    let totals: Vec<f64> = (0..iterations)
        .map(|_| timed.step(&data).unwrap().total)
        .collect();
    gpu.gpu().wait_idle().unwrap();
    let phases = pvrnn_core::profile::take();
    pvrnn_core::profile::enable(false);
    assert_eq!(expected, totals);
    let evaluations = iterations as u64 + 1;
    for (part, times) in [
        ("device: inputs into the recurrence's layout", evaluations),
        ("device: recurrence forward", evaluations),
        (
            "device: read-outs (hidden and output layers, forward and backward)",
            evaluations,
        ),
        ("device: recurrence backward", evaluations),
        ("device: recurrent weight gradients", evaluations),
        ("device: gradients into the optimiser's layout", evaluations),
        ("device: optimiser (RAdam)", iterations as u64),
        (
            "device: recurrent weights transposed for the forward kernel",
            iterations as u64,
        ),
    ] {
        let found = phases.iter().find(|(name, _, _)| *name == part);
        let Some(&(_, seconds, count)) = found else {
            panic!("{part} is not in the profile: {phases:?}");
        };
        assert_eq!(count, times, "{part}");
        assert!(seconds > 0.0 && seconds < 60.0, "{part}: {seconds} s");
    }
}
