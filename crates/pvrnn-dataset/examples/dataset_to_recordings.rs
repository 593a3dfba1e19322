//! Writes a dataset folder back out as recordings (`meta.json`, `proprio.csv` and a PNG per
//! camera and frame in a folder per sequence), the form `pvrnn import` reads: a round trip
//! for checking an import pipeline, and paper-scale input for timing `pvrnn import`.
//!
//!     cargo run --release -p pvrnn-dataset --example dataset_to_recordings -- caresim recordings
//!     pvrnn import --from recordings --out caresim-imported
#![allow(clippy::unwrap_used)] // a tool run by hand: a failure should stop it loudly

use std::path::PathBuf;

use pvrnn_dataset::Dataset;
use pvrnn_dataset::import::{self, LayoutFile, RecordingLayout};

fn main() {
    let mut args = std::env::args().skip(1).map(PathBuf::from);
    let (Some(from), Some(out)) = (args.next(), args.next()) else {
        eprintln!("usage: dataset_to_recordings DATASET_DIR OUT_DIR");
        std::process::exit(2);
    };
    let dataset = Dataset::open(&from).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1);
    });
    let manifest = &dataset.manifest;
    let layout = RecordingLayout {
        cameras: manifest.cameras.clone(),
        image_size: manifest.image_size,
        channels: manifest.channels(),
    };
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(
        out.join(import::LAYOUT),
        serde_json::to_string_pretty(&LayoutFile::from(&layout)).unwrap() + "\n",
    )
    .unwrap();
    for s in &dataset.sequences {
        import::write_recording(
            s,
            &layout,
            &out.join(pvrnn_dataset::file_stem(&s.info.name)),
        )
        .unwrap();
    }
    eprintln!(
        "wrote {} recordings to {}",
        dataset.sequences.len(),
        out.display()
    );
}
