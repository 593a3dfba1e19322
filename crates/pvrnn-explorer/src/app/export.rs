//! Export: the shown run's traces as CSV, and the window as a PNG picture. On the desktop the
//! files go to the export folder (default `pvrnn-exports/` in the working directory; the
//! status line names each file); in the browser they download.

use std::sync::{Arc, Mutex};

use super::*;

/// A picture the renderer hands back after a screenshot request.
pub(super) type PendingShot = Arc<Mutex<Option<Arc<egui::ColorImage>>>>;

/// Encodes an image as PNG.
pub fn png_bytes(image: &egui::ColorImage) -> Result<Vec<u8>, String> {
    let [w, h] = image.size;
    let rgba: Vec<u8> = image.pixels.iter().flat_map(|c| c.to_array()).collect();
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &rgba,
        w as u32,
        h as u32,
        image::ColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .map_err(|e| format!("cannot encode the picture: {e}"))?;
    Ok(out.into_inner())
}

/// A file name from free text (sequence names, conditions).
fn file_name(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

impl ExplorerApp {
    /// The shown run's traces as CSV: per computed step, its subtask, the window's free
    /// energy, the reconstruction errors, every module's mu_p, sigma_p, mu_q, sigma_q and d
    /// per unit, and the reconstructed proprioception (model units).
    pub fn run_csv(&self) -> Option<String> {
        let bundle = self.bundle.as_ref()?;
        let key = self.current_key()?;
        let trace = &self.store.get(&key)?.trace;
        let seq = bundle.dataset.by_name(&key.sequence)?;
        let mut header = vec![
            "t".to_string(),
            "subtask".into(),
            "free_energy".into(),
            "recon_error_vision".into(),
            "recon_error_proprio".into(),
        ];
        for (m, id) in ModuleId::ALL.iter().enumerate() {
            for field in ["mu_p", "sigma_p", "mu_q", "sigma_q"] {
                header.extend((0..trace.z[m]).map(|k| format!("{}.{field}{k}", id.name())));
            }
            header.extend((0..trace.d[m]).map(|k| format!("{}.d{k}", id.name())));
        }
        let dims = bundle.model.config.proprio_dims;
        header.extend((0..dims).map(|k| format!("proprio_recon{k}")));
        let mut out = header.join(",");
        out.push('\n');
        for t in 0..trace.steps {
            let mut row = vec![
                t.to_string(),
                seq.subtask
                    .get(t)
                    .and_then(|&s| seq.info.subtasks.get(s as usize).cloned())
                    .unwrap_or_default(),
                trace.free_energy[t].to_string(),
                trace.recon_error[t][0].to_string(),
                trace.recon_error[t][1].to_string(),
            ];
            for (m, states) in trace.modules.iter().enumerate() {
                let (z, d) = (trace.z[m], trace.d[m]);
                for v in [&states.mu_p, &states.sigma_p, &states.mu_q, &states.sigma_q] {
                    row.extend(v[t * z..(t + 1) * z].iter().map(f32::to_string));
                }
                row.extend(states.d[t * d..(t + 1) * d].iter().map(f32::to_string));
            }
            row.extend(
                trace.proprio_recon[t * dims..(t + 1) * dims]
                    .iter()
                    .map(f32::to_string),
            );
            out.push_str(&row.join(","));
            out.push('\n');
        }
        Some(out)
    }

    /// Where exported files go on the desktop.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn set_export_dir(&mut self, dir: std::path::PathBuf) {
        self.export_dir = dir;
    }

    /// Saves (desktop) or downloads (web) an exported file and says where it went.
    fn save_export(&mut self, name: &str, bytes: &[u8], mime: &str) {
        #[cfg(not(target_arch = "wasm32"))]
        {
            let _ = mime;
            let path = self.export_dir.join(name);
            let result = std::fs::create_dir_all(&self.export_dir)
                .and_then(|()| std::fs::write(&path, bytes));
            self.status = match result {
                Ok(()) => Status::Info(format!("saved {}", path.display())),
                Err(e) => Status::Error(format!("cannot save {}: {e}", path.display())),
            };
        }
        #[cfg(target_arch = "wasm32")]
        {
            self.status = match crate::browser::download(name, bytes, mime) {
                Ok(()) => Status::Info(format!("downloaded {name}")),
                Err(e) => Status::Error(format!("cannot download {name}: {e}")),
            };
        }
    }

    fn export_stem(&self) -> String {
        self.current_key().map_or("explorer".into(), |k| {
            file_name(&format!(
                "{}-{}-t{}",
                k.sequence,
                condition_label(&k.condition),
                self.view.t
            ))
        })
    }

    /// Writes the shown run's traces as CSV.
    pub fn export_csv(&mut self) {
        match self.run_csv() {
            Some(csv) => {
                let name = format!("{}.csv", self.export_stem());
                self.save_export(&name, csv.as_bytes(), "text/csv");
            }
            None => self.status = Status::Error("no run to export yet".into()),
        }
    }

    /// Asks the renderer for a picture of the window; saved when it arrives.
    pub(super) fn request_picture(&mut self, ctx: &egui::Context) {
        let pending = self.pending_shot.clone();
        let repaint = ctx.clone();
        ctx.request_screenshot(move |image| {
            if let Ok(mut slot) = pending.lock() {
                *slot = Some(image);
            }
            repaint.request_repaint();
        });
    }

    /// Saves a picture of the window to `path` once the view's runs are computed, then
    /// closes the window: `pvrnn-explorer --screenshot FILE`, a smoke test of the desktop
    /// app (it needs a display: `xvfb-run` gives one).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn screenshot_and_close(&mut self, path: std::path::PathBuf) {
        self.screenshot = Some((path, false));
    }

    /// Saves a picture that arrived (called from `logic`); with `--screenshot`, asks for it
    /// when the view is ready and closes the window after saving it.
    pub(super) fn take_picture(&mut self, ctx: &egui::Context) {
        #[cfg(not(target_arch = "wasm32"))]
        if let Some((path, asked)) = self.screenshot.clone() {
            // Ready: the shown run is complete (or failed), nothing else is computing, and
            // a drive the address names has been driven.
            let shown_done = self
                .current_run()
                .is_some_and(|e| e.complete || e.error.is_some());
            let driven = !self.driving() && !self.drive_pending();
            if !asked && (self.bundle.is_none() || (shown_done && self.idle() && driven)) {
                self.screenshot = Some((path.clone(), true));
                self.request_picture(ctx);
            }
            let shot = self.pending_shot.lock().ok().and_then(|mut s| s.take());
            if let Some(image) = shot {
                let saved = png_bytes(&image)
                    .and_then(|png| std::fs::write(&path, png).map_err(|e| e.to_string()));
                match saved {
                    // The renderer (the smoke tests check which drew the picture) and what
                    // computed its live run.
                    Ok(()) => {
                        eprintln!(
                            "saved {} ({}; {})",
                            path.display(),
                            self.renderer_label,
                            self.compute_label
                        );
                        // What a drive from `--view` came to.
                        if self.view.drive.is_some() {
                            eprintln!("drive: {:?}", self.status);
                        }
                    }
                    Err(e) => eprintln!("cannot save {}: {e}", path.display()),
                }
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            }
            return;
        }
        let _ = ctx;
        let shot = self.pending_shot.lock().ok().and_then(|mut s| s.take());
        if let Some(image) = shot {
            match png_bytes(&image) {
                Ok(png) => {
                    let name = format!("{}.png", self.export_stem());
                    self.save_export(&name, &png, "image/png");
                }
                Err(e) => self.status = Status::Error(e),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pictures_encode_as_png_and_names_are_safe() {
        let image = egui::ColorImage::new([3, 2], vec![Color32::from_rgb(10, 200, 30); 6]);
        let png = png_bytes(&image).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!((back.width(), back.height()), (3, 2));
        assert_eq!(back.get_pixel(2, 1).0, [10, 200, 30]);
        assert_eq!(file_name("wiping 650/test#0"), "wiping_650_test_0");
    }
}
