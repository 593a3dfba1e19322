//! Each proprioceptive channel of a caresim dataset's learning split: its range, its sensor
//! noise estimated from the data (std of step differences over sqrt 2) and that noise in
//! model units under the paper's min-max normalisation (range to [-0.9, 0.9]). A channel
//! whose noise is large in model units carries little else.
//!
//! `cargo run --release -p caresim --example channel_noise [SEED] [LEARN_PER_HEIGHT] [REVISION]`
#![allow(clippy::unwrap_used)] // an example script: a failed unwrap is a failed run
use caresim::{DatasetSpec, Revision, simulate_proprioception};
use pvrnn_dataset::{Split, proprio_noise_std, proprio_ranges};

fn main() {
    let mut args = std::env::args().skip(1);
    let seed = args.next().map_or(0, |a| a.parse().unwrap());
    let learn_per_height = args.next().map_or(3, |a| a.parse().unwrap());
    let revision = args
        .next()
        .map_or(Revision::default(), |a| Revision::parse(&a).unwrap());
    let spec = DatasetSpec {
        seed,
        learn_per_height,
        revision,
        ..DatasetSpec::default()
    };
    let trials: Vec<_> = spec
        .trials()
        .into_iter()
        .filter(|t| t.split == Split::Learn)
        .collect();
    let sequences = std::thread::scope(|scope| {
        let workers: Vec<_> = trials
            .chunks(trials.len().div_ceil(2).max(1))
            .map(|chunk| {
                scope.spawn(move || {
                    chunk
                        .iter()
                        .map(simulate_proprioception)
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect::<Vec<_>>()
    });
    let refs: Vec<_> = sequences.iter().collect();
    let ranges = proprio_ranges(&refs);
    let noise = proprio_noise_std(&refs);
    println!(
        "caresim revision {revision}, seed {seed}, {} learning sequences",
        refs.len()
    );
    println!("channel\trange\tnoise_std\tnoise_model_units");
    for (i, std) in noise.iter().enumerate() {
        let name = if i < 14 {
            format!("joint{}", i + 1)
        } else {
            format!("torque{}", i - 13)
        };
        let range = ranges.proprio_max[i] - ranges.proprio_min[i];
        println!(
            "{name}\t{range:.5}\t{std:.5}\t{:.4}",
            ranges.noise_to_model(i, *std)
        );
    }
}
