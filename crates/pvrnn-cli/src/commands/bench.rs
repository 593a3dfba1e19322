//! `pvrnn bench`: learning and online inference at the paper's scale on random data.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use pvrnn_core::backend::Backend;
use pvrnn_core::infer::{InferenceSettings, OnlineInference};
use pvrnn_core::train::Trainer;
use pvrnn_core::{Modality, Model, ModelConfig, NoiseMode, Observations, Observed, Tensor};
use rayon::prelude::*;
use serde::Serialize;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn bench --threads 2\n  pvrnn bench --threads 2 --json > bench.json\n  pvrnn bench --backend wgpu --only train --profile\n  pvrnn bench --backend wgpu --gpu-recurrence --only train --networks 5\n  pvrnn bench --backend wgpu --gpu-recurrence --only train --profile --profile-kernels"
)]
pub struct Args {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Training sequences (paper: 18).
    #[arg(long, default_value_t = 18)]
    sequences: usize,
    /// Steps per sequence (paper: ~300).
    #[arg(long, default_value_t = 300)]
    steps: usize,
    /// Networks trained together (seeds 0, 1, ...), every iteration of all of them queued
    /// before the host waits for any (`pvrnn_core::train::step_together`); the figures are
    /// per iteration of all of them, and network-iterations per second.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    networks: u32,
    /// Timed training iterations (after one warm-up iteration).
    #[arg(long, default_value_t = 3)]
    train_iterations: usize,
    /// Timed inference steps per condition, after the window is full.
    #[arg(long, default_value_t = 10)]
    infer_steps: usize,
    /// Run only one part: `train` or `infer` (the other's figures are reported as null).
    #[arg(long)]
    only: Option<Part>,
    /// Also say where the time goes: milliseconds per phase (noise, weights, recurrence,
    /// read-outs, optimiser) per training iteration and per inference step; with
    /// `--backend wgpu --gpu-recurrence`, also the device's own time per part of an
    /// iteration ("device: ...", from timestamp queries where the GPU has them).
    #[arg(long)]
    profile: bool,
    /// With `--profile --backend wgpu --gpu-recurrence`: each dispatch of a training
    /// iteration in a timed pass of its own, so that the profile lists each kernel's device
    /// time (`device: kernel <label>`) beside each part's. The parts then take longer than
    /// in the default profile: the device drains between the passes.
    #[arg(long, requires = "profile")]
    profile_kernels: bool,
    #[command(flatten)]
    backend: crate::util::BackendArgs,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    Train,
    Infer,
}

#[derive(Serialize, Debug)]
struct Report {
    /// `cpu`, or `wgpu on` and the adapter: name (driver, API).
    backend: String,
    threads: usize,
    /// The CPU, its cores and the threads used (`pvrnn_eval::machine::describe`).
    machine: String,
    sequences: usize,
    steps: usize,
    /// Networks trained together (`--networks`).
    networks: usize,
    /// Mean seconds per full-batch training iteration (of all the networks together).
    train_iter_s: Option<f64>,
    train_iter_min_s: Option<f64>,
    /// Network-iterations per second: networks / mean seconds per iteration.
    network_iterations_per_s: Option<f64>,
    /// Device memory held by buffers after training (wgpu's allocation counter: resident
    /// weights, moments and data, and the pool's reusable buffers), in MB; null on the CPU.
    gpu_buffer_mb: Option<f64>,
    /// Total free energy of the first network at the warm-up and each timed iteration: the
    /// same seeded data and noise on every backend, so two backends' runs can be compared
    /// number by number.
    train_free_energy: Vec<f64>,
    /// Online inference steps per second at a full window (H = 30, 50 iterations).
    infer_p16_steps_per_s: Option<f64>,
    infer_full_steps_per_s: Option<f64>,
    /// Peak resident memory of the process after training (data included), and at the end.
    train_peak_rss_mb: f64,
    peak_rss_mb: f64,
    /// With --profile: per part (`train`, `infer_p16`, `infer_full`), milliseconds per
    /// phase per iteration or step; indented phases are parts of the one above.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    profile: Vec<PartProfile>,
}

#[derive(Serialize, Debug)]
struct PartProfile {
    part: &'static str,
    phases: Vec<PhaseTime>,
}

#[derive(Serialize, Debug)]
struct PhaseTime {
    phase: String,
    ms: f64,
    /// Times the phase was entered (or a device's time added to it) per unit: a kernel's
    /// dispatches per iteration, with `--profile-kernels`.
    times: f64,
}

/// The profiler's sums so far, per unit of work (`units` iterations or steps).
fn take_profile(part: &'static str, units: usize) -> PartProfile {
    PartProfile {
        part,
        phases: pvrnn_core::profile::take()
            .into_iter()
            .map(|(phase, seconds, times)| PhaseTime {
                phase: phase.to_string(),
                ms: seconds * 1e3 / units.max(1) as f64,
                times: times as f64 / units.max(1) as f64,
            })
            .collect(),
    }
}

/// Peak resident set size (VmHWM) in MB, where the OS reports it.
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn random_tensor(shape: &[usize], seed: u64) -> Tensor<f32> {
    let n: usize = shape.iter().product();
    let mut data = vec![0f32; n];
    data.par_chunks_mut(1 << 16)
        .enumerate()
        .for_each(|(c, chunk)| {
            let mut s = (seed ^ (c as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)) | 1;
            for v in chunk {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                *v = ((s >> 40) as f32 / (1u64 << 24) as f32) * 1.8 - 0.9;
            }
        });
    Tensor::from_vec(shape, data).expect("sized")
}

fn infer_rate(
    backend: &dyn Backend<f32>,
    model: &Arc<Model<f32>>,
    data: &Observations<f32>,
    observed: Observed,
    timed: usize,
    profile: bool,
) -> Result<f64> {
    let mut settings = InferenceSettings::from_config(&model.config, 1);
    settings.observed = observed;
    let window = settings.window;
    let mut inf = OnlineInference::with_backend(model.clone(), settings, backend)?;
    let steps = data.lengths()[0];
    anyhow::ensure!(
        steps >= window + timed,
        "need at least {} steps for the inference benchmark",
        window + timed
    );
    let step = |inf: &mut OnlineInference<f32>, t: usize| {
        inf.step(
            data.step(Modality::Exteroceptive, 0, t),
            data.step(Modality::Proprioceptive, 0, t),
        )
    };
    for t in 0..window {
        step(&mut inf, t)?;
    }
    pvrnn_core::profile::enable(profile);
    let start = Instant::now();
    for t in window..window + timed {
        step(&mut inf, t)?;
    }
    Ok(timed as f64 / start.elapsed().as_secs_f64())
}

/// What [`train_networks`] measured, and the first network it trained.
struct Trained {
    backend_name: String,
    times: Vec<f64>,
    free_energies: Vec<f64>,
    profile: Vec<PartProfile>,
    train_peak: f64,
    gpu_buffer_mb: Option<f64>,
    model: Model<f32>,
}

/// Trains `--networks` networks together on `data`: the warm-up iteration, then the timed
/// ones.
fn train_networks(
    a: &Args,
    config: &ModelConfig,
    data: &Observations<f32>,
    say: &dyn Fn(&str),
) -> Result<Trained> {
    let (s, t) = (a.sequences, a.steps);
    let networks = a.networks as usize;
    // One device for all the networks: they share its queue.
    let mut options = a.backend.wgpu_options();
    options.profile_kernels = a.profile_kernels;
    let (backend, backend_name, gpu) = a.backend.open_with(options)?;
    let backend: Arc<dyn Backend<f32>> = Arc::from(backend);
    let mut trainers = Vec::with_capacity(networks);
    for seed in 0..networks as u64 {
        let model = Model::<f32>::init(config.clone(), s, t, seed)?;
        trainers.push(
            Trainer::new(model, NoiseMode::Sampled { seed })
                .with_backend(Box::new(backend.clone())),
        );
    }
    let data_per_network = vec![data; networks];

    let (mut times, mut free_energies) = (Vec::new(), Vec::new());
    let step_all = |trainers: &mut [Trainer<f32>]| -> Result<f64> {
        let mut members: Vec<&mut Trainer<f32>> = trainers.iter_mut().collect();
        let reports = pvrnn_core::train::step_together(&mut members, &data_per_network)?;
        let mut first = f64::NAN;
        for (k, report) in reports.into_iter().enumerate() {
            let report = report?;
            if k == 0 {
                first = report.total;
            }
        }
        Ok(first)
    };
    if a.only != Some(Part::Infer) {
        say(&format!(
            "training {networks} network(s): 1 warm-up iteration..."
        ));
        free_energies.push(step_all(&mut trainers)?);
        pvrnn_core::profile::enable(a.profile);
        for i in 0..a.train_iterations {
            let start = Instant::now();
            free_energies.push(step_all(&mut trainers)?);
            times.push(start.elapsed().as_secs_f64());
            say(&format!("  iteration {}: {:.3} s", i + 1, times[i]));
        }
    }
    let mut profile = Vec::new();
    if a.profile && a.only != Some(Part::Infer) {
        // The device's own times arrive when it has run the last iteration's update.
        if let Some(device) = &gpu {
            device.wait_idle()?;
        }
        profile.push(take_profile("train", a.train_iterations));
    }
    let train_peak = peak_rss_mb();
    let gpu_buffer_mb = gpu
        .as_ref()
        .and_then(|device| device.buffer_memory())
        .map(|bytes| bytes as f64 / 1e6);
    Ok(Trained {
        backend_name,
        times,
        free_energies,
        profile,
        train_peak,
        gpu_buffer_mb,
        model: trainers.swap_remove(0).into_model(),
    })
}

pub fn run(a: Args) -> Result<()> {
    let config = ModelConfig::default();
    let (s, t) = (a.sequences, a.steps);
    let say = |msg: &str| {
        if !a.json {
            eprintln!("{msg}");
        }
    };
    say(&format!(
        "preparing {s} x {t} random sequences ({} vision + {} proprio dims)...",
        config.vision.dims(),
        config.proprio_dims
    ));
    let data = Observations::new(
        random_tensor(&[s, t, config.vision.dims()], 1),
        random_tensor(&[s, t, config.proprio_dims], 2),
        None,
    )?;
    let inference_backend = a.backend.open()?.0;
    let trained = train_networks(&a, &config, &data, &say)?;
    let (times, free_energies, mut profile) =
        (trained.times, trained.free_energies, trained.profile);
    let (backend_name, train_peak, gpu_buffer_mb) = (
        trained.backend_name,
        trained.train_peak,
        trained.gpu_buffer_mb,
    );
    let model = Arc::new(trained.model);

    let (mut p16, mut full) = (None, None);
    if a.only != Some(Part::Train) {
        say("online inference, proprio + 16x16 observed...");
        p16 = Some(infer_rate(
            inference_backend.as_ref(),
            &model,
            &data,
            Observed {
                vision_levels: 1,
                proprio: true,
            },
            a.infer_steps,
            a.profile,
        )?);
        if a.profile {
            profile.push(take_profile("infer_p16", a.infer_steps));
        }
        say("online inference, everything observed...");
        full = Some(infer_rate(
            inference_backend.as_ref(),
            &model,
            &data,
            Observed::all(&config),
            a.infer_steps,
            a.profile,
        )?);
        if a.profile {
            profile.push(take_profile("infer_full", a.infer_steps));
        }
    }
    let mean = (!times.is_empty()).then(|| times.iter().sum::<f64>() / times.len() as f64);
    let min = (!times.is_empty()).then(|| times.iter().copied().fold(f64::INFINITY, f64::min));

    let report = Report {
        backend: backend_name,
        threads: rayon::current_num_threads(),
        machine: pvrnn_eval::machine::describe(rayon::current_num_threads()),
        sequences: s,
        steps: t,
        networks: a.networks as usize,
        train_iter_s: mean,
        train_iter_min_s: min,
        network_iterations_per_s: mean.map(|m| f64::from(a.networks) / m),
        gpu_buffer_mb,
        train_free_energy: free_energies,
        infer_p16_steps_per_s: p16,
        infer_full_steps_per_s: full,
        train_peak_rss_mb: train_peak,
        peak_rss_mb: peak_rss_mb(),
        profile,
    };
    if a.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report, &config);
    }
    Ok(())
}

/// The bench's figures as a table on stdout.
fn print_report(report: &Report, config: &ModelConfig) {
    println!("backend                          {}", report.backend);
    println!("threads                          {}", report.threads);
    println!("machine                          {}", report.machine);
    if let (Some(mean), Some(min)) = (report.train_iter_s, report.train_iter_min_s) {
        let (s, t, n) = (report.sequences, report.steps, report.networks);
        println!("training iteration ({s} x {t})     {mean:.3} s (min {min:.3} s)");
        if n > 1 {
            println!(
                "networks together                {n}: {:.1} network-iterations/s",
                n as f64 / mean
            );
        }
        let terms: Vec<String> = report
            .train_free_energy
            .iter()
            .map(|f| format!("{f:.9}"))
            .collect();
        println!("free energy per iteration        {}", terms.join(" "));
    }
    if let (Some(p16), Some(full)) = (report.infer_p16_steps_per_s, report.infer_full_steps_per_s) {
        println!(
            "inference, proprio + 16x16       {p16:.1} steps/s (H = {}, {} iterations)",
            config.inference.window, config.inference.iterations
        );
        println!("inference, everything observed   {full:.1} steps/s");
    }
    println!(
        "peak memory after training       {:.0} MB",
        report.train_peak_rss_mb
    );
    println!(
        "peak memory                      {:.0} MB",
        report.peak_rss_mb
    );
    if let Some(mb) = report.gpu_buffer_mb {
        println!("GPU buffers after training       {mb:.0} MB");
    }
    for part in &report.profile {
        let unit = if part.part == "train" {
            "iteration"
        } else {
            "step"
        };
        println!("where the time goes, {} (ms per {unit}):", part.part);
        for p in &part.phases {
            // How often a phase ran per unit, where not once (a kernel's dispatches).
            let times = if p.times == 1.0 {
                String::new()
            } else {
                format!("  ({:.3} per {unit})", p.times)
            };
            println!("  {:40} {:9.2}{times}", p.phase, p.ms);
        }
    }
}
