//! Each kernel's label, kept by pipeline, so that the profile can name the kernel of each
//! dispatch it times apart (`WgpuOptions::profile_kernels`, `timing.rs`).

/// Each kernel's label, by pipeline, for timing every dispatch of a submission apart
/// (`WgpuOptions::profile_kernels`): the profile then lists `device: kernel <label>` beside
/// the parts. Native only (nothing is kept in the browser, where profiling is off).
#[derive(Debug, Default)]
pub(crate) struct KernelNames {
    #[cfg(not(target_arch = "wasm32"))]
    labels: std::sync::Mutex<Vec<(wgpu::ComputePipeline, &'static str)>>,
}

impl KernelNames {
    /// Remembers `pipeline`'s label.
    pub(crate) fn register(&self, pipeline: &wgpu::ComputePipeline, label: &'static str) {
        #[cfg(not(target_arch = "wasm32"))]
        self.labels
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((pipeline.clone(), label));
        #[cfg(target_arch = "wasm32")]
        let _ = (pipeline, label);
    }

    /// The profile's phase for `pipeline`'s dispatches: `device: kernel <label>`.
    #[cfg(not(target_arch = "wasm32"))]
    pub(crate) fn phase(&self, pipeline: &wgpu::ComputePipeline) -> &'static str {
        let label = self
            .labels
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .find(|(p, _)| p == pipeline)
            .map_or("unnamed", |(_, label)| *label);
        kernel_phase(label)
    }

    #[cfg(target_arch = "wasm32")]
    pub(crate) fn phase(&self, _pipeline: &wgpu::ComputePipeline) -> &'static str {
        "device: kernel"
    }
}

/// `device: kernel <label>`, made once per label (the profile keeps `&'static str`
/// names; there are a few dozen kernels).
#[cfg(not(target_arch = "wasm32"))]
fn kernel_phase(label: &'static str) -> &'static str {
    static PHASES: std::sync::Mutex<Vec<(&'static str, &'static str)>> =
        std::sync::Mutex::new(Vec::new());
    let mut phases = PHASES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, phase)) = phases.iter().find(|(l, _)| *l == label) {
        return phase;
    }
    let phase: &'static str = Box::leak(format!("device: kernel {label}").into_boxed_str());
    phases.push((label, phase));
    phase
}
