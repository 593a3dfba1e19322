//! The profile's device times (`pvrnn bench --profile`): in a test binary of its own,
//! because profiling is global to a process and the other tests' iterations would count
//! in it.
#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed run
#![cfg(not(target_arch = "wasm32"))] // the profile is native only

mod common;

use std::sync::Mutex;

use common::{config, observations};

use pvrnn_core::cpu::CpuBackend;
use pvrnn_core::train::Trainer;
use pvrnn_core::{Model, NoiseMode};
use pvrnn_wgpu::WgpuBackend;

/// Profiling is global to the process: the tests take turns.
static PROFILE: Mutex<()> = Mutex::new(());

/// The parts of a whole iteration's submission, in the profile.
const PARTS: [&str; 6] = [
    "device: inputs into the recurrence's layout",
    "device: recurrence forward",
    "device: read-outs (hidden and output layers, forward and backward)",
    "device: recurrence backward",
    "device: recurrent weight gradients",
    "device: gradients into the optimiser's layout",
];

/// The GPU backend with the recurrence on the device, if the machine has one with
/// timestamps (`None`: skipped).
fn timed_gpu() -> Option<WgpuBackend> {
    let gpu = match WgpuBackend::new() {
        Ok(gpu) => gpu,
        Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
            eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
            return None;
        }
        Err(e) => panic!("{e} (set PVRNN_SKIP_WGPU=1 to skip the GPU tests)"),
    };
    if !gpu.gpu().has_timestamps() {
        eprintln!("skipped: {} has no timestamp queries", gpu.adapter_name());
        return None;
    }
    Some(gpu.with_recurrence_on_gpu(true))
}

/// `iterations` learning iterations on `gpu` while profiling, checked against the same
/// iterations without: the profile's phases.
fn profiled(gpu: &WgpuBackend, iterations: usize) -> Vec<(&'static str, f64, u64)> {
    let _turn = PROFILE.lock().unwrap_or_else(|e| e.into_inner());
    let config = config();
    let data = observations(&config, 2, 12);
    let model = Model::<f32>::init_on(&CpuBackend, config, 2, 12, 4).unwrap();
    let noise = NoiseMode::Sampled { seed: 2 };
    let mut plain = Trainer::new(model.clone(), noise).with_backend(Box::new(gpu.clone()));
    let mut timed = Trainer::new(model, noise).with_backend(Box::new(gpu.clone()));
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
    phases
}

/// While profiling, each part of a whole iteration on the device and of its update runs in
/// a pass of its own, timed by the device (`timing.rs`): every part is in the profile once
/// per iteration (an evaluation once more: the last step queued the next iteration's,
/// `Learner::guards_updates`), and the free energies are those of a run without profiling.
#[test]
fn the_profile_times_each_part_of_a_whole_iteration_on_the_device() {
    let Some(gpu) = timed_gpu() else { return };
    let iterations = 3;
    let phases = profiled(&gpu, iterations);
    let evaluations = iterations as u64 + 1;
    let parts = PARTS.iter().map(|&part| (part, evaluations));
    for (part, times) in parts.chain([
        ("device: optimiser (RAdam)", iterations as u64),
        (
            "device: recurrent weights transposed for the forward kernel",
            iterations as u64,
        ),
    ]) {
        let found = phases.iter().find(|(name, _, _)| *name == part);
        let Some(&(_, seconds, count)) = found else {
            panic!("{part} is not in the profile: {phases:?}");
        };
        assert_eq!(count, times, "{part}");
        assert!(seconds > 0.0 && seconds < 60.0, "{part}: {seconds} s");
    }
    assert!(
        !phases
            .iter()
            .any(|(name, ..)| name.starts_with("device: kernel ")),
        "kernels timed apart without being asked: {phases:?}"
    );
}

/// With `WgpuOptions::profile_kernels` every dispatch of the submission is timed apart: each
/// kernel is in the profile under its label, as often as it runs, and the kernels' times
/// add up to the parts' (each pass's time goes to both).
#[test]
fn the_profile_times_each_kernel_when_asked() {
    let Some(gpu) = timed_gpu() else { return };
    let iterations = 2;
    let phases = profiled(&gpu.with_kernel_profile(true), iterations);
    let evaluations = iterations as u64 + 1;
    let kernels: Vec<_> = phases
        .iter()
        .filter(|(name, ..)| name.starts_with("device: kernel "))
        .collect();
    let count_of = |label: &str| {
        let name = format!("device: kernel {label}");
        kernels.iter().find(|(n, ..)| *n == name).map(|k| k.2)
    };
    assert_eq!(
        count_of("recurrence forward"),
        Some(evaluations),
        "{kernels:?}"
    );
    assert_eq!(
        count_of("recurrence backward"),
        Some(evaluations),
        "{kernels:?}"
    );
    assert!(count_of("dense forward").is_some_and(|n| n % evaluations == 0 && n > 0));
    assert!(
        !kernels.iter().any(|(name, ..)| name.ends_with("unnamed")),
        "{kernels:?}"
    );
    let parts: f64 = PARTS
        .iter()
        .map(|&part| {
            phases
                .iter()
                .find(|(n, ..)| *n == part)
                .map_or(0.0, |p| p.1)
        })
        .sum();
    let timed: f64 = kernels.iter().map(|k| k.1).sum();
    assert!(parts > 0.0, "{phases:?}");
    assert!(
        (parts - timed).abs() <= 1e-9 * parts,
        "the parts' {parts} s against the kernels' {timed} s"
    );
}
