//! `pvrnn import`: real robot recordings into the dataset format.

use std::path::PathBuf;

use anyhow::{Context, Result};
use pvrnn_dataset::{import, preview, previews_dir};

use crate::util;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn import --from tests/data/one-arm --out my-robot/dataset\n  pvrnn import --from recordings/ --out mine/ --cameras left,right --image-size 64"
)]
pub struct Args {
    /// Folder of recordings: one sub-folder per sequence with meta.json, a folder of frames
    /// per camera and proprio.csv, and optionally recordings.json naming the robot's
    /// cameras, image size and channels (see docs/dataset.md).
    #[arg(long)]
    from: PathBuf,
    /// Dataset folder to write.
    #[arg(long)]
    out: PathBuf,
    /// Camera folder names, in the order the model sees them [default: recordings.json's,
    /// else left,right].
    #[arg(long, value_delimiter = ',')]
    cameras: Option<Vec<String>>,
    /// Square image size in pixels after centre crop and area resampling [default:
    /// recordings.json's, else 64].
    #[arg(long)]
    image_size: Option<usize>,
    /// Skip the contact sheets and animations.
    #[arg(long)]
    no_previews: bool,
}

pub fn run(a: Args) -> Result<()> {
    let mut layout = import::RecordingLayout::of_recordings(&a.from)?;
    if let Some(cameras) = a.cameras {
        layout.cameras = cameras;
    }
    if let Some(size) = a.image_size {
        anyhow::ensure!(size >= 2, "--image-size must be at least 2");
        layout.image_size = size;
    }
    let bar = util::progress(0, "import");
    let dataset = import::import_recordings(&a.from, &layout, &mut |done, total, name| {
        bar.set_length(total as u64);
        bar.set_message(name.to_string());
        bar.set_position(done as u64);
    })?;
    bar.set_position(dataset.sequences.len() as u64);
    bar.finish();
    dataset.write(&a.out)?;
    if !a.no_previews {
        let dir = previews_dir(&a.out);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        for s in &dataset.sequences {
            let stem = pvrnn_dataset::file_stem(&s.info.name);
            preview::write_contact_sheet(s, &dir.join(format!("{stem}.png")))?;
            preview::write_animation(s, &dir.join(format!("{stem}.gif")), 2, 10)?;
        }
    }
    eprintln!(
        "wrote {} ({} sequences)",
        a.out.display(),
        dataset.sequences.len()
    );
    Ok(())
}
