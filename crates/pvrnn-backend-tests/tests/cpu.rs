//! The suite on the CPU backend, in both precisions.

use std::sync::Arc;

use pvrnn_core::cpu::CpuBackend;

pvrnn_backend_tests::backend_suite!(cpu_f64, f64, Some(Arc::new(CpuBackend)));
pvrnn_backend_tests::backend_suite!(cpu_f32, f32, Some(Arc::new(CpuBackend)));
