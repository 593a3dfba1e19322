//! Finds wiping's variability factor whose trajectory spread matches repositioning's at
//! factor 1 (the `Variability::MATCHED` preset), by bisection over the 9 learning trials of
//! seed 0.
#![allow(clippy::unwrap_used)] // an example script: a failed unwrap is a failed run
use caresim::variability::trajectory_spread;
use caresim::{DatasetSpec, Task, TrialSpec, Variability};
use pvrnn_dataset::Split;

fn learning(task: Task, wiping: f64) -> Vec<TrialSpec> {
    let spec = DatasetSpec {
        tasks: vec![task],
        variability: Variability {
            repositioning: 1.0,
            wiping,
        },
        ..DatasetSpec::default()
    };
    spec.trials()
        .into_iter()
        .filter(|t| t.split == Split::Learn)
        .collect()
}

fn main() {
    let target = trajectory_spread(&learning(Task::Repositioning, 1.0));
    println!("repositioning at 1: {target:.5} m");
    let paper = trajectory_spread(&learning(Task::Wiping, 1.0));
    println!("wiping at 1: {paper:.5} m");
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..8 {
        let mid = 0.5 * (lo + hi);
        let spread = trajectory_spread(&learning(Task::Wiping, mid));
        println!("wiping at {mid:.4}: {spread:.5} m");
        if spread > target {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    println!("matched wiping factor ~ {:.3}", 0.5 * (lo + hi));
}
