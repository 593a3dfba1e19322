//! The scripted trials' fastest joint steps: per trial, the largest change of any joint in
//! one step (rad per 0.1 s) and where it is, against the Franka Panda's speed limits that
//! `caresim::env` can enforce.
//!
//!   cargo run --release -p caresim --example joint_speeds [SEED] [REVISION]

use caresim::env::MAX_JOINT_SPEED;
use caresim::{DatasetSpec, Revision, Simulation};

fn main() {
    let mut args = std::env::args().skip(1);
    let seed = args
        .next()
        .map_or(0, |s| s.parse().expect("SEED: a number"));
    let revision = match args.next().as_deref() {
        None | Some("2") => Revision::R2,
        Some("1") => Revision::R1,
        Some(other) => panic!("REVISION: 1 or 2, not {other}"),
    };
    let spec = DatasetSpec {
        seed,
        revision,
        ..DatasetSpec::default()
    };
    let mut over = 0;
    let mut fastest: f64 = 0.0;
    for trial in spec.trials() {
        let mut sim = Simulation::new(trial.clone());
        let mut last = sim.step().q;
        let mut worst = (0.0, 0, 0, 0);
        for step in 1..sim.len() {
            let q = sim.step().q;
            for arm in 0..2 {
                for j in 0..7 {
                    let d = (q[arm][j] - last[arm][j]).abs();
                    if d > MAX_JOINT_SPEED[j] * 0.1 {
                        over += 1;
                    }
                    if d > worst.0 {
                        worst = (d, step, arm, j);
                    }
                }
            }
            last = q;
        }
        fastest = fastest.max(worst.0);
        println!(
            "{}: fastest joint step {:.3} rad at step {} ({} arm, joint {})",
            trial.name(),
            worst.0,
            worst.1,
            ["left", "right"][worst.2],
            worst.3 + 1
        );
    }
    println!(
        "fastest over all trials: {fastest:.3} rad per step; joint steps over the Panda's limits: {over}"
    );
}
