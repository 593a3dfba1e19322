//! Random search of rest postures: exact IK on both tasks, elbows as low as possible.
#![allow(clippy::unwrap_used)] // an example script: a failed unwrap is a failed run
use caresim::scene::{Mount, Robot};
use caresim::*;
use glam::DVec3;
fn score(mount: Mount) -> (f64, f64) {
    let (mut err, mut elbow) = (0.0f64, 0.0f64);
    for task in Task::ALL {
        for h in [590, 710] {
            let spec = TrialSpec {
                task,
                bed_height_mm: h,
                split: pvrnn_dataset::Split::Learn,
                index: 0,
                seed: 3,
                variability: 1.0,
                revision: caresim::Revision::default(),
            };
            let mut sim = Simulation::with_robot(spec, Robot::with_mount(mount));
            for _ in 0..sim.len() {
                let r = sim.step();
                err = err.max(r.ik_position_error[0]).max(r.ik_position_error[1]);
                for a in 0..2 {
                    let k = sim.robot.arms[a].fk(&r.q[a]);
                    elbow = elbow
                        .max(k.joints[3].translation.z)
                        .max(k.joints[4].translation.z);
                }
            }
            if err > 1e-3 {
                return (err, elbow);
            }
        }
    }
    (err, elbow)
}
fn main() {
    let mut s = 12345u64;
    let mut u = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut best = (f64::INFINITY, [0.0; 7]);
    for i in 0..40 {
        let rest = if i == 0 {
            [0.0, 0.45, 0.0, -1.9, 0.0, 2.1, 0.8]
        } else {
            [
                u() - 0.5,
                -0.3 + 1.5 * u(),
                -1.5 + 3.0 * u(),
                -2.6 + 1.6 * u(),
                -1.0 + 2.0 * u(),
                0.8 + 1.7 * u(),
                0.785,
            ]
        };
        let m = Mount {
            base: DVec3::new(0.0, 0.21, 1.17),
            axis: DVec3::NEG_Z,
            rest,
        };
        let (err, elbow) = score(m);
        if err < 1e-3 && elbow < best.0 {
            best = (elbow, rest);
            eprintln!("{i}: elbow {elbow:.3} err {err:.5} rest {rest:.3?}");
        }
    }
    println!("best elbow {:.3} rest {:.3?}", best.0, best.1);
}
