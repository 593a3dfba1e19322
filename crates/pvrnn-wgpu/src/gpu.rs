//! The device, its queue, and the compiled kernels (one set per hidden width).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Why no GPU could be used.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found ({0}); install a Vulkan, Metal or DX12 driver (on Debian, \
         `mesa-vulkan-drivers` gives the CPU's lavapipe device) or use `--backend cpu`"
    )]
    NoAdapter(String),
    #[error("the GPU adapter {adapter} refused a device: {reason}")]
    NoDevice { adapter: String, reason: String },
}

/// Kernels compiled for one hidden width (the width is a constant of the WGSL source, so
/// the tiles are fixed-size arrays in workgroup memory).
#[derive(Debug)]
pub(crate) struct Kernels {
    pub(crate) output_loss: wgpu::ComputePipeline,
    pub(crate) reduce: wgpu::ComputePipeline,
    pub(crate) predict: wgpu::ComputePipeline,
}

/// Learning targets kept on the device: which observations, and how they were cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ResidentKey {
    pub(crate) observations: u64,
    pub(crate) rows: usize,
    pub(crate) columns: usize,
    pub(crate) chunk_rows: usize,
}

/// One modality's resident targets: a buffer per chunk of rows.
pub(crate) type Resident = Option<(ResidentKey, Arc<Vec<wgpu::Buffer>>)>;

/// An open GPU: device, queue and kernels, shared by every model loaded on it.
#[derive(Debug)]
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    kernels: Mutex<HashMap<usize, Arc<Kernels>>>,
    /// Per modality, the learning targets of the latest run (uploaded once, not per
    /// iteration; a new run replaces them).
    pub(crate) resident: Mutex<[Resident; 2]>,
}

impl Gpu {
    /// Opens an adapter and a device with the adapter's own limits (larger buffers than
    /// WebGPU's defaults where the hardware allows them).
    pub fn new() -> Result<Self, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(
            &instance, None,
        ))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pvrnn"),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoDevice {
            adapter: info.name.clone(),
            reason: e.to_string(),
        })?;
        Ok(Self {
            device,
            queue,
            info,
            kernels: Mutex::new(HashMap::new()),
            resident: Mutex::new([None, None]),
        })
    }

    /// "name (driver, API)".
    pub fn describe(&self) -> String {
        let i = &self.info;
        let driver = [i.driver.as_str(), i.driver_info.as_str()]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect::<Vec<_>>()
            .join(" ");
        if driver.is_empty() {
            format!("{} ({:?})", i.name, i.backend)
        } else {
            format!("{} ({driver}, {:?})", i.name, i.backend)
        }
    }

    /// Whether the adapter is a CPU implementation (lavapipe, SwiftShader, WARP): correct,
    /// but slower than the CPU backend, so not chosen unless asked for.
    pub fn is_cpu(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    pub(crate) fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// The kernels for hidden width `hl`, compiled on first use.
    pub(crate) fn kernels(&self, hl: usize) -> Arc<Kernels> {
        let mut cache = self.kernels.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .entry(hl)
            .or_insert_with(|| Arc::new(self.compile(hl)))
            .clone()
    }

    fn compile(&self, hl: usize) -> Kernels {
        let source = |text: &str| {
            text.replace("{{HL}}", &hl.to_string())
                .replace("{{HALF}}", &hl.div_ceil(2).to_string())
                .replace("{{TC_HL}}", &(32 * hl).to_string())
                .replace("{{TR_HL}}", &(16 * hl).to_string())
        };
        let pipeline = |label: &str, text: &str| {
            let module = self
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(label),
                    source: wgpu::ShaderSource::Wgsl(source(text).into()),
                });
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    module: &module,
                    entry_point: Some("main"),
                    compilation_options: Default::default(),
                    cache: None,
                })
        };
        Kernels {
            output_loss: pipeline("output_loss", include_str!("shaders/output_loss.wgsl")),
            reduce: pipeline("reduce", include_str!("shaders/reduce.wgsl")),
            predict: pipeline("predict", include_str!("shaders/predict.wgsl")),
        }
    }
}
