//! The explorer's own benchmarks (`pvrnn-explorer --bench-frames N`, `--bench-live`):
//! frames drawn headless, layout and tessellation timed, no GPU.

use eframe::egui;
use web_time::{Duration, Instant};

use super::ExplorerApp;

/// Draws `frames` frames headless (layout and tessellation, no GPU) while scrubbing through
/// the first sequence, and prints the time per frame.
pub fn bench_frames(mut app: ExplorerApp, frames: usize) {
    let ctx = egui::Context::default();
    let input = || egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(1440.0, 920.0),
        )),
        ..Default::default()
    };
    // Let the shown run finish first: scrubbing is measured on computed runs.
    while !app.idle() {
        app.compute(Duration::from_millis(200));
    }
    let len = app.sequence_len().max(1);
    // Headless: no textures are uploaded, so their deltas are dropped on purpose.
    ctx.run_ui(input(), |ui| app.show(ui))
        .textures_delta
        .clear();
    let mut times = Vec::with_capacity(frames);
    for i in 0..frames {
        app.view_mut().t = (i * 7) % len;
        let start = Instant::now();
        let mut out = ctx.run_ui(input(), |ui| app.show(ui));
        out.textures_delta.clear();
        let _ = ctx.tessellate(out.shapes, out.pixels_per_point);
        times.push(start.elapsed().as_secs_f64() * 1000.0);
    }
    times.sort_by(f64::total_cmp);
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    let p95 = times[(times.len() * 95 / 100).min(times.len() - 1)];
    println!(
        "{frames} frames while scrubbing: mean {mean:.2} ms, 95th percentile {p95:.2} ms per frame (layout + tessellation, one thread)"
    );
}

/// Computes the shown run live while drawing frames headless as a window would (at most 60
/// per second, vsync, and only as often as the app asks to be repainted), first in the
/// frame loop (slices of each frame's budget), then on a background thread, and prints the
/// steps per second of each; with a branch in the view (`branch=` in `--view`), then the
/// branch's, timed from the run's end (it continues from the run's kept states). `make`
/// gives a fresh app each time (the run not yet computed).
#[cfg(not(target_arch = "wasm32"))]
pub fn bench_live(make: impl Fn() -> ExplorerApp) {
    const FRAME: Duration = Duration::from_micros(16_667);
    for (label, background) in [
        ("in the frame loop", false),
        ("on a background thread", true),
    ] {
        let mut app = make();
        let ctx = egui::Context::default();
        if background {
            app.compute_in_background(&ctx);
        }
        let input = || egui::RawInput {
            screen_rect: Some(egui::Rect::from_min_size(
                egui::Pos2::ZERO,
                egui::vec2(1440.0, 920.0),
            )),
            ..Default::default()
        };
        let start = Instant::now();
        let mut frames = 0usize;
        // With a branch in the view, it is computed after its run and timed from then.
        let done = |app: &ExplorerApp, key: Option<crate::condition::RunKey>| {
            key.and_then(|k| app.run(&k))
                .is_some_and(|r| r.complete || r.error.is_some())
        };
        let mut run_done: Option<(f64, usize)> = None;
        loop {
            if run_done.is_none() && done(&app, app.current_key()) {
                let steps = app.current_run().map_or(0, |r| r.trace.steps);
                run_done = Some((start.elapsed().as_secs_f64(), frames));
                report_run(&app, label, steps, start.elapsed().as_secs_f64(), frames);
            }
            if run_done.is_some() && (app.view.branch.is_none() || done(&app, app.branch_key())) {
                break;
            }
            let frame = Instant::now();
            let mut out = ctx.run_ui(input(), |ui| app.show(ui));
            out.textures_delta.clear();
            // The next frame when the app asked for it (the background thread asks when
            // results arrive), but not sooner than vsync.
            let wanted = out
                .viewport_output
                .get(&egui::ViewportId::ROOT)
                .map_or(FRAME, |v| v.repaint_delay)
                .clamp(FRAME, crate::runs::REPAINT_EVERY);
            let _ = ctx.tessellate(out.shapes, out.pixels_per_point);
            frames += 1;
            if let Some(rest) = wanted.checked_sub(frame.elapsed()) {
                std::thread::sleep(rest);
            }
            if start.elapsed() > Duration::from_secs(600) {
                println!("{label}: not finished in 10 minutes");
                break;
            }
        }
        let (Some((run_seconds, run_frames)), Some(b)) = (run_done, app.view.branch) else {
            continue;
        };
        let seconds = start.elapsed().as_secs_f64() - run_seconds;
        let steps = app
            .branch_key()
            .and_then(|k| app.run(&k))
            .map_or(0, |r| r.trace.steps.saturating_sub(b.at));
        println!(
            "branch {label} at step {} ({}): {steps} steps computed in {seconds:.1} s = {:.2} \
             steps/s, {:.0} frames/s",
            b.at,
            super::condition_label(&b.condition),
            steps as f64 / seconds,
            (frames - run_frames) as f64 / seconds,
        );
    }
}

/// Prints a finished live run's speed.
#[cfg(not(target_arch = "wasm32"))]
fn report_run(app: &ExplorerApp, label: &str, steps: usize, seconds: f64, frames: usize) {
    let key = app
        .current_key()
        .map(|k| super::condition_label(&k.condition));
    println!(
        "live run {label}: {steps} steps in {seconds:.1} s = {:.2} steps/s, {:.0} frames/s ({})",
        steps as f64 / seconds,
        frames as f64 / seconds,
        key.unwrap_or_default()
    );
}
