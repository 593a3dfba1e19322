//! A kernel's source compiled into a pipeline, with wgpu's runtime checks or, for the audited
//! output-layer kernels, without them ([`RuntimeChecks`]); and the kernels of one shape for
//! every model (RAdam, the finite check, the strided copy, the hidden read-out layers),
//! compiled on first use.

use std::sync::{Arc, OnceLock};

use super::Gpu;

/// Which kernels keep wgpu's runtime checks (bounds, loop bounding, integer division)
/// natively (`WgpuOptions::checks`, `pvrnn --wgpu-checks`); the browser's WebGPU checks
/// every kernel regardless.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RuntimeChecks {
    /// Every kernel but the audited output-layer ones (`Gpu::audited_pipeline`), whose
    /// checks cost them a fourth of their time on an H200 (docs/gpu.md).
    #[default]
    Audited,
    /// Every kernel: to rule the unchecked ones out when a result looks wrong.
    All,
    /// No kernel: to measure what the checks cost.
    None,
}

impl std::str::FromStr for RuntimeChecks {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "audited" => Ok(Self::Audited),
            "all" => Ok(Self::All),
            "none" => Ok(Self::None),
            other => Err(format!(
                "unknown runtime checks {other:?}: `audited`, `all` or `none`"
            )),
        }
    }
}

/// The hidden read-out layers' kernels (shapes are parameters, so one set serves every
/// layer).
#[derive(Debug)]
pub(crate) struct DenseKernels {
    pub(crate) forward: wgpu::ComputePipeline,
    pub(crate) backward: wgpu::ComputePipeline,
    pub(crate) weights: wgpu::ComputePipeline,
    pub(crate) weights_reduce: wgpu::ComputePipeline,
}

impl Gpu {
    /// The RAdam update of a resident tensor (`shaders/radam.wgsl`), compiled on first use.
    pub(crate) fn radam_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        self.compiled_once(&self.radam_kernel, "radam", shader!("radam.wgsl"))
    }

    /// The divergence mark of a learning run (`shaders/finite_check.wgsl`), compiled on
    /// first use.
    pub(crate) fn finite_check_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        let source = shader!("finite_check.wgsl");
        self.compiled_once(&self.finite_check_kernel, "finite check", source)
    }

    /// The strided copy between layouts (`shaders/strided_copy.wgsl`), compiled on first use.
    pub(crate) fn copy_kernel(&self) -> Arc<wgpu::ComputePipeline> {
        let source = shader!("strided_copy.wgsl");
        self.compiled_once(&self.copy_kernel, "strided copy", source)
    }

    /// A one-kernel shader kept in `cell`, compiled at its first use.
    fn compiled_once(
        &self,
        cell: &OnceLock<Arc<wgpu::ComputePipeline>>,
        label: &'static str,
        source: &str,
    ) -> Arc<wgpu::ComputePipeline> {
        cell.get_or_init(|| Arc::new(self.pipeline(label, source.into())))
            .clone()
    }

    /// The hidden read-out layers' kernels, compiled on first use.
    pub(crate) fn dense_kernels(&self) -> Arc<DenseKernels> {
        self.dense_kernels
            .get_or_init(|| {
                Arc::new(DenseKernels {
                    forward: self.pipeline("dense forward", shader!("dense_forward.wgsl").into()),
                    backward: self
                        .pipeline("dense backward", shader!("dense_backward.wgsl").into()),
                    weights: self.pipeline("dense weights", shader!("dense_weights.wgsl").into()),
                    weights_reduce: self.pipeline(
                        "dense weights reduce",
                        shader!("dense_weights_reduce.wgsl").into(),
                    ),
                })
            })
            .clone()
    }

    /// `source` compiled with wgpu's runtime checks (bounds, loop bounding, division),
    /// unless [`RuntimeChecks::None`].
    pub(super) fn pipeline(&self, label: &'static str, source: String) -> wgpu::ComputePipeline {
        self.compile_pipeline(label, source, self.checks == RuntimeChecks::None)
    }

    /// `source` compiled without wgpu's runtime checks, unless [`RuntimeChecks::All`]:
    /// for the output-layer kernels only (fused and blocked), whose every index is bounded by the shapes
    /// the host sized their buffers with (see their sources). The checks cost them a fourth
    /// of their time on an H200 (docs/gpu.md).
    pub(super) fn audited_pipeline(
        &self,
        label: &'static str,
        source: String,
    ) -> wgpu::ComputePipeline {
        self.compile_pipeline(label, source, self.checks != RuntimeChecks::All)
    }

    #[allow(unsafe_code)] // trusted shader modules: see the SAFETY note
    fn compile_pipeline(
        &self,
        label: &'static str,
        source: String,
        unchecked: bool,
    ) -> wgpu::ComputePipeline {
        let descriptor = wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        };
        let module = if unchecked {
            // SAFETY: by default only the output-layer kernels (`audited_pipeline`):
            // every index they form is bounded by the row, column and split counts the host
            // sized their buffers and dispatches with (dead threads read index 0 and write
            // nothing; tile indices stay below the tile sizes, which are multiples of the
            // steps), their loops are bounded by uniform counts and their divisors are
            // nonzero constants. Every kernel only with `RuntimeChecks::None`, which is for
            // measuring what the checks cost. The browser's WebGPU checks regardless.
            unsafe {
                self.device.create_shader_module_trusted(
                    descriptor,
                    wgpu::ShaderRuntimeChecks::unchecked(),
                )
            }
        } else {
            self.device.create_shader_module(descriptor)
        };
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
        self.kernel_names.register(&pipeline, label);
        pipeline
    }
}
