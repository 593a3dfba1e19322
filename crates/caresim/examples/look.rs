//! Renders a few frames of a trial at high resolution for a person to look at.
//! `cargo run --release -p caresim --example look [TASK] [HEIGHT_MM] [REVISION]`
#![allow(clippy::unwrap_used)] // an example script: a failed unwrap is a failed run
use caresim::*;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let task = Task::parse(args.get(1).map(String::as_str).unwrap_or("repositioning")).unwrap();
    let height: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(650);
    let spec = TrialSpec {
        task,
        bed_height_mm: height,
        split: pvrnn_dataset::Split::Learn,
        index: 0,
        seed: 7,
        variability: 1.0,
        revision: args
            .get(3)
            .map_or(Revision::default(), |r| Revision::parse(r).unwrap()),
    };
    let mut sim = Simulation::new(spec);
    let n = sim.len();
    let picks = [0, n / 6, n / 3, n / 2, 2 * n / 3, 5 * n / 6, n - 1];
    let size = 192;
    let mut sheet = image::RgbImage::new((size * picks.len()) as u32, (size * 2) as u32);
    let mut worst = [[0.0f64; 2]; 3];
    for t in 0..n {
        let r = sim.step();
        for a in 0..2 {
            let st = r.plan.subtask as usize;
            worst[st][a] = worst[st][a].max(r.ik_position_error[a]);
            if r.ik_position_error[a] > 0.01 && t % 10 == 0 {
                eprintln!(
                    "  t={t} arm {a} err {:.3} target {:.3?} q {:.2?}",
                    r.ik_position_error[a], r.plan.hands[a].position, r.q[a]
                );
            }
        }
        if let Some(col) = picks.iter().position(|&p| p == t) {
            for cam in 0..2 {
                let f = sim.render(cam, true, size, 2);
                for y in 0..size {
                    for x in 0..size {
                        let i = (y * size + x) * 3;
                        sheet.put_pixel(
                            (col * size + x) as u32,
                            (cam * size + y) as u32,
                            image::Rgb([f.rgb[i], f.rgb[i + 1], f.rgb[i + 2]]),
                        );
                    }
                }
            }
            eprintln!(
                "t={t} subtask={} lift={:.2} forces={:?} tcpL={:.3?} tcpR={:.3?}",
                r.plan.subtask,
                r.plan.lift,
                r.plan.forces,
                r.tcp[0].translation,
                r.tcp[1].translation
            );
        }
    }
    eprintln!("len {n}, worst IK errors {worst:?}");
    sheet
        .save(format!("/tmp/look_{}.png", task.name()))
        .unwrap();
}
