//! Opening a GPU: the adapter (`WGPU_BACKEND` and `WGPU_ADAPTER_NAME` choose), a device
//! with the adapter's own limits, and why none could be used ([`GpuError`]); and a look at
//! what would be opened without opening it ([`probe`]).

use std::collections::HashMap;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex, OnceLock};

use super::Gpu;
use super::failure::failure_recorder;
use super::pipelines::RuntimeChecks;
use super::targets::ResidentTargets;

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
    #[error("waiting for the GPU adapter {adapter} failed: {reason}")]
    Wait { adapter: String, reason: String },
}

impl Gpu {
    /// Opens an adapter and a device with the adapter's own limits (larger buffers than
    /// WebGPU's defaults where the hardware allows them), its kernels checked as `checks`
    /// says.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new(checks: RuntimeChecks) -> Result<Self, GpuError> {
        pollster::block_on(Self::open(checks))
    }

    /// [`Self::new`] without blocking: the only way in the browser, where the adapter and
    /// the device arrive through the event loop.
    pub async fn open(checks: RuntimeChecks) -> Result<Self, GpuError> {
        let adapter = adapter().await?;
        let info = adapter.get_info();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("pvrnn"),
                required_limits: adapter.limits(),
                // For the profile's device times (`timing.rs`, native only), where the
                // adapter has them.
                required_features: if cfg!(target_arch = "wasm32") {
                    wgpu::Features::empty()
                } else {
                    adapter.features() & wgpu::Features::TIMESTAMP_QUERY
                },
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoDevice {
                adapter: info.name.clone(),
                reason: e.to_string(),
            })?;
        let failed = Arc::new(Mutex::new(None));
        device.on_uncaptured_error(Arc::new(failure_recorder(describe(&info), failed.clone())));
        Ok(Self {
            device,
            queue,
            info,
            kernels: Mutex::new(HashMap::new()),
            recurrence_kernels: Mutex::default(),
            radam_kernel: OnceLock::new(),
            finite_check_kernel: OnceLock::new(),
            copy_kernel: OnceLock::new(),
            dense_kernels: OnceLock::new(),
            resident: Mutex::new(ResidentTargets::default()),
            pool: Arc::default(),
            read_backs: AtomicU64::new(0),
            iterations_encoded: AtomicU64::new(0),
            recurrence_parts_encoded: AtomicU64::new(0),
            checks,
            kernel_names: Default::default(),
            failed,
        })
    }
}

/// The adapter [`Gpu::open`] takes: Vulkan, Metal, DX12 (and WebGPU) unless `WGPU_BACKEND`
/// says otherwise (OpenGL has no use for compute here, and probing it through EGL beside
/// eframe's own GL context panics inside wgpu-hal: BadAccess in make_current, seen under
/// Xvfb); `WGPU_ADAPTER_NAME` picks one by name.
async fn adapter() -> Result<wgpu::Adapter, GpuError> {
    let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    descriptor.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let instance = wgpu::Instance::new(descriptor);
    wgpu::util::initialize_adapter_from_env_or_default(&instance, None)
        .await
        .map_err(|e| GpuError::NoAdapter(e.to_string()))
}

/// What [`Gpu::open`] would open, without opening a device: a cheap look at the machine
/// (the explorer picks its renderer with it) as `(its description, whether it is a CPU
/// implementation)`.
pub async fn probe() -> Result<(String, bool), GpuError> {
    let info = adapter().await?.get_info();
    Ok((describe(&info), is_cpu(&info)))
}

/// [`probe`], blocking.
#[cfg(not(target_arch = "wasm32"))]
pub fn probe_now() -> Result<(String, bool), GpuError> {
    pollster::block_on(probe())
}

pub(super) fn is_cpu(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

pub(super) fn describe(i: &wgpu::AdapterInfo) -> String {
    // Browsers may withhold the adapter's name.
    let name = if i.name.trim().is_empty() {
        "unnamed adapter"
    } else {
        i.name.as_str()
    };
    let driver = [i.driver.as_str(), i.driver_info.as_str()]
        .into_iter()
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join(" ");
    if driver.is_empty() {
        format!("{name} ({:?})", i.backend)
    } else {
        format!("{name} ({driver}, {:?})", i.backend)
    }
}
