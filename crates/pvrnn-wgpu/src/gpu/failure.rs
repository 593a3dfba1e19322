//! The device's failures: work that allocates run in a scope that turns running out of
//! memory into an error naming what failed ([`Gpu::allocating`]), and the first failure no
//! scope caught, recorded instead of wgpu's panic and reported by everything after it
//! ([`Gpu::failure`]).

use std::sync::{Arc, Mutex};

use super::Gpu;

impl Gpu {
    /// The device's first failure, if it has failed: running out of memory (or an internal
    /// error) in work that no checked allocation scope covers, such as a read-out's call
    /// on whatever thread evaluates, or a read-back that could not be made. From then on
    /// the device's results mean nothing: loaded models report this instead of them
    /// ([`pvrnn_core::assembled::DeviceHealth`]), and so do learners and checkpoints.
    pub fn failure(&self) -> Option<pvrnn_core::Error> {
        let failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        failed.clone().map(pvrnn_core::Error::Device)
    }

    /// The slot [`Self::failure`] reads, for a read-back to record a failure in.
    pub(crate) fn failure_slot(&self) -> Arc<Mutex<Option<String>>> {
        self.failed.clone()
    }

    /// Runs `make`, work that allocates device memory, with running out of memory caught:
    /// an [`pvrnn_core::Error::Device`] saying what could not be done (`what`) on which
    /// adapter, instead of wgpu's uncaptured-error panic. A failed allocation leaves invalid
    /// buffers that the rest of `make` then touches: those validation errors are caught too
    /// (the inner scope). Every allocation of a learning run passes here: the resident
    /// buffers when its learners are made, the targets and scratch of its first iteration.
    pub(crate) fn allocating<T>(
        &self,
        what: impl FnOnce() -> String,
        make: impl FnOnce() -> T,
    ) -> pvrnn_core::Result<T> {
        let out_of_memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let invalid = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let made = make();
        let invalid = pvrnn_core::deferred::now(invalid.pop());
        let out_of_memory = pvrnn_core::deferred::now(out_of_memory.pop());
        let failed =
            |error: &wgpu::Error| format!("{} could not {} ({error})", self.describe(), what());
        match (out_of_memory, invalid) {
            (None, None) => Ok(made),
            (Some(error), _) => Err(pvrnn_core::Error::Device(format!(
                "{}: out of memory; train fewer networks at once (`--cohort` / `--networks`; docs/gpu.md gives the memory per network)",
                failed(&error)
            ))),
            (None, Some(error)) => Err(pvrnn_core::Error::Device(failed(&error))),
        }
    }
}

/// wgpu's handler of the errors no scope caught. Running out of memory (or an internal
/// error) is recorded as the device's failure ([`Gpu::failure`]), not wgpu's default panic;
/// the validation errors that follow it (work binding the buffers it left invalid) are its
/// consequence. A validation error with no failure before it is a kernel or a binding this
/// crate got wrong: a bug, which panics as wgpu's default handler does.
pub(super) fn failure_recorder(
    adapter: String,
    failed: Arc<Mutex<Option<String>>>,
) -> impl Fn(wgpu::Error) + Send + Sync + 'static {
    move |error| {
        let already = failed.lock().map_or(true, |f| f.is_some());
        match error {
            wgpu::Error::Validation { .. } if !already => panic!("wgpu error: {error}"),
            wgpu::Error::OutOfMemory { .. } => record_failure(
                &failed,
                format!(
                    "{adapter}: out of memory ({error}); evaluate or train fewer networks at \
                     once, or use `--backend cpu` (docs/gpu.md gives the memory per network)"
                ),
            ),
            _ => record_failure(&failed, format!("{adapter}: {error}")),
        }
    }
}

/// Keeps the first failure only: those after it are its consequences.
pub(crate) fn record_failure(failed: &Mutex<Option<String>>, why: String) {
    let mut failed = failed.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_none() {
        *failed = Some(why);
    }
}

impl pvrnn_core::assembled::DeviceHealth for Gpu {
    fn failure(&self) -> Option<pvrnn_core::Error> {
        Gpu::failure(self)
    }
}

#[cfg(all(test, not(target_arch = "wasm32")))]
mod tests {
    use super::*;
    use crate::gpu::RuntimeChecks;

    /// An out-of-memory no scope catches (a read-out's call on whatever thread evaluates)
    /// is the device's failure: wgpu's handler records it instead of panicking, the
    /// validation errors it causes are taken as its consequence, and every later
    /// evaluation, learning step and checkpoint on the device fails naming it. A real one
    /// is provoked in the CLI's tests (`a_read_out_the_device_memory_cannot_hold_is_a_clear_error`).
    #[test]
    fn a_failure_no_scope_catches_fails_every_later_evaluation_and_checkpoint() {
        use pvrnn_core::backend::Backend;
        use pvrnn_core::config::{ModuleConfig, VisionLayout};
        use pvrnn_core::free_energy::{NoiseDraw, free_energy};
        use pvrnn_core::noise::NoiseMode;
        use pvrnn_core::{Model, ModelConfig, Observations, Tensor, train::Trainer};

        let gpu = match Gpu::new(RuntimeChecks::default()) {
            Ok(gpu) => Arc::new(gpu),
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let backend = crate::WgpuBackend::on(gpu.clone(), crate::WgpuOptions::default());
        let mut config = ModelConfig::default();
        let module = |d, z| ModuleConfig {
            d,
            z,
            tau: [2.0, 4.0],
        };
        config.executive = module(4, 2);
        config.associative = module(4, 2);
        config.exteroceptive = module(6, 3);
        config.proprioceptive = module(4, 2);
        config.exteroceptive_readout.hidden = vec![8];
        config.proprioceptive_readout.hidden = vec![6];
        config.vision = VisionLayout {
            cameras: 1,
            channels: 3,
            resolutions: vec![4],
        };
        config.proprio_dims = 4;
        let (sequences, steps) = (2, 5);
        let (vision, proprio) = (config.vision.dims(), config.proprio_dims);
        let data: Observations<f32> = Observations::new(
            Tensor::from_vec(
                &[sequences, steps, vision],
                vec![0.1; sequences * steps * vision],
            )
            .unwrap(),
            Tensor::from_vec(
                &[sequences, steps, proprio],
                vec![-0.2; sequences * steps * proprio],
            )
            .unwrap(),
            None,
        )
        .unwrap();
        let model = Model::init_on(&backend, config, sequences, steps, 7).unwrap();
        let noise = NoiseDraw::evaluation(NoiseMode::Zero);
        assert!(free_energy(&backend, &model, &data, noise, true).is_ok());
        let mut trainer =
            Trainer::new_on(Box::new(backend.clone()), model.clone(), NoiseMode::Zero);
        trainer.step(&data).unwrap();
        let checkpoint = std::env::temp_dir().join(format!(
            "pvrnn-device-failure-{}.safetensors",
            std::process::id()
        ));
        pvrnn_core::io::save_checkpoint(&checkpoint, &mut trainer, None).unwrap();
        let before = std::fs::read(&checkpoint).unwrap();

        let handler = failure_recorder(gpu.describe(), gpu.failure_slot());
        let source = || Box::new(std::io::Error::other("no memory left")) as wgpu::ErrorSource;
        handler(wgpu::Error::OutOfMemory { source: source() });
        // Work binding what the failure left invalid: its consequence, not a panic.
        handler(wgpu::Error::Validation {
            source: source(),
            description: "a buffer is invalid".into(),
        });
        let failure = gpu.failure().expect("the failure is recorded").to_string();
        assert!(
            failure.contains("out of memory") && failure.contains(&gpu.describe()),
            "{failure}"
        );
        let names_it = |result: pvrnn_core::Result<()>, what: &str| match result {
            Err(e) => assert_eq!(e.to_string(), failure, "{what}"),
            Ok(()) => panic!("{what} succeeded on a failed device"),
        };
        names_it(
            free_energy(&backend, &model, &data, noise, true).map(|_| ()),
            "an evaluation",
        );
        let loaded = backend.load(&model.params, &model.config);
        names_it(
            loaded
                .readout(pvrnn_core::Modality::Proprioceptive, &[0.0; 4], 1)
                .map(|_| ()),
            "a read-out",
        );
        names_it(trainer.step(&data).map(|_| ()), "a learning step");
        names_it(
            pvrnn_core::io::save_checkpoint(&checkpoint, &mut trainer, None),
            "a checkpoint",
        );
        assert_eq!(
            std::fs::read(&checkpoint).unwrap(),
            before,
            "the last checkpoint stays"
        );
        std::fs::remove_file(&checkpoint).ok();

        // A validation error with no failure before it is a bug in this crate: it panics,
        // as wgpu's own handler does.
        let fresh = failure_recorder(gpu.describe(), Arc::default());
        let bug = std::panic::catch_unwind(|| {
            fresh(wgpu::Error::Validation {
                source: source(),
                description: "a kernel got wrong".into(),
            })
        });
        assert!(bug.is_err());
    }

    /// A buffer over the device's size limit stands in for one that does not fit its
    /// memory (lavapipe allocates host memory, which a test cannot exhaust): both leave an
    /// invalid buffer whose later uses fail validation too.
    #[test]
    fn allocations_the_device_refuses_are_an_error_naming_what_failed() {
        let gpu = match Gpu::new(RuntimeChecks::default()) {
            Ok(gpu) => gpu,
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let small = gpu.allocating(
            || "make a small buffer".into(),
            || gpu.scratch("small", 16, wgpu::BufferUsages::empty()),
        );
        assert!(small.is_ok());
        let too_large = gpu.device.limits().max_buffer_size.saturating_add(4);
        let refused = gpu.allocating(
            || "make a buffer too large".into(),
            || {
                let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("too large"),
                    size: too_large,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                gpu.queue.write_buffer(&buffer, 0, &[0; 4]);
                buffer
            },
        );
        match refused {
            Err(pvrnn_core::Error::Device(message)) => {
                assert!(
                    message.contains("could not make a buffer too large")
                        && message.contains(&gpu.describe()),
                    "{message}"
                );
            }
            other => panic!("expected a device error, got {other:?}"),
        }
        // The device is still usable.
        let after = gpu.allocating(
            || "make a small buffer".into(),
            || gpu.scratch("small", 16, wgpu::BufferUsages::empty()),
        );
        assert!(after.is_ok());
    }
}
