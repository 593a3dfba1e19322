//! A URL hash on a running explorer: read, kept within a small bundle's range (sequence,
//! time, vision levels), and drawn for one frame; never a panic, and the view stays valid.
#![no_main]
use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::{Model, ModelConfig};
use pvrnn_dataset::{Dataset, Sequence, SequenceInfo, Split};
use pvrnn_explorer::{Bundle, ExplorerApp, ViewState};

/// One 6-step test sequence (and a learning one) of 4x4 images and a model with small modules.
fn bundle() -> Bundle {
    {
        let mut c = ModelConfig::default();
        let m = |d, z| ModuleConfig { d, z, tau: [2.0, 4.0] };
        (c.executive, c.associative, c.exteroceptive, c.proprioceptive) =
            (m(4, 2), m(4, 2), m(4, 2), m(4, 2));
        c.exteroceptive_readout.hidden = vec![4, 4];
        c.proprioceptive_readout.hidden = vec![4];
        c.vision = VisionLayout { cameras: 2, channels: 3, resolutions: vec![2, 4] };
        c.inference.window = 2;
        c.inference.iterations = 1;
        let steps = 6;
        // A learning sequence as well as the test one: the bundle takes the proprioception
        // ranges from the learning split.
        let sequence = |name: &str, split| Sequence {
            info: SequenceInfo {
                name: name.into(),
                file: format!("{name}.safetensors"),
                task: "wiping".into(),
                bed_height_mm: None,
                split,
                seed: None,
                length: steps,
                subtasks: vec!["one".into()],
            },
            cameras: 2,
            image_size: 4,
            images: (0..steps * 2 * 4 * 4 * 3).map(|i| (i * 7 % 256) as u8).collect(),
            joints: (0..steps * 14).map(|i| (i as f32 * 0.1).sin()).collect(),
            torques: (0..steps * 14).map(|i| (i as f32 * 0.1).cos()).collect(),
            subtask: vec![0; steps],
            extra: Vec::new(),
            images_without_robot: None,
        };
        let sequences = vec![sequence("learn", Split::Learn), sequence("only", Split::Test)];
        let dataset = Dataset::new("fuzz", vec!["l".into(), "r".into()], 4, sequences)
            .expect("a valid dataset");
        let model = Model::<f32>::init(c, 1, steps, 1).expect("a valid model");
        Bundle::new("fuzz".into(), model, dataset).expect("a valid bundle")
    }
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(hash) = std::str::from_utf8(data) else {
        return;
    };
    let mut app = ExplorerApp::new(Some(bundle()), ViewState::default());
    app.apply_hash(hash);
    let ctx = egui::Context::default();
    let input = egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(1200.0, 800.0),
        )),
        ..Default::default()
    };
    let mut out = ctx.run_ui(input, |ui| app.show(ui));
    out.textures_delta.clear(); // nothing draws here
    let view = app.view();
    assert!(view.t < 6, "time {} outside the sequence", view.t);
    let _ = view.to_hash();
});
