//! One recording folder for `pvrnn import`: the input is split into its `meta.json`, its
//! `proprio.csv` and one camera frame (separated by 0xFF 0xFE), written to a scratch folder
//! with the other frames valid, and imported: an error or a sequence, never a panic.
#![no_main]
use std::path::PathBuf;
use std::sync::OnceLock;

use pvrnn_dataset::import::{RecordingLayout, import_sequence};

const FRAMES: usize = 3;

fn layout() -> RecordingLayout {
    RecordingLayout::paper(&["left".into()], 8)
}

/// A scratch folder with valid frames for every step but the first.
fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("pvrnn-fuzz-recording-{}", std::process::id()));
        let left = dir.join("left");
        std::fs::create_dir_all(&left).expect("scratch folder");
        for t in 1..FRAMES {
            image::save_buffer(
                left.join(format!("{t:06}.png")),
                &[128u8; 8 * 8 * 3],
                8,
                8,
                image::ExtendedColorType::Rgb8,
            )
            .expect("a valid frame");
        }
        dir
    })
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let mut parts = data.split(|&b| b == 0xFF).map(|p| p.strip_prefix(&[0xFE]).unwrap_or(p));
    let (meta, csv, frame) = (
        parts.next().unwrap_or_default(),
        parts.next().unwrap_or_default(),
        parts.next().unwrap_or_default(),
    );
    let dir = scratch();
    let written = std::fs::write(dir.join("meta.json"), meta)
        .and_then(|()| std::fs::write(dir.join("proprio.csv"), csv))
        .and_then(|()| std::fs::write(dir.join("left").join("000000.png"), frame));
    if written.is_ok() {
        let _ = import_sequence(dir, "fuzzed", &layout());
    }
});
