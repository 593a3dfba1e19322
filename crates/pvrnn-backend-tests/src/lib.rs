//! The backend test suite: the checks every backend of pvrnn-core's seam must pass, written
//! once, generic over the float type, and run on each backend as its own named tests (as
//! candle's `test_device!` runs one suite per device). A backend's test file is one line
//! per backend and precision:
//!
//! ```ignore
//! pvrnn_backend_tests::backend_suite!(cpu_f64, f64, Some(std::sync::Arc::new(CpuBackend)));
//! ```
//!
//! which generates `cpu_f64::learning_gradients_match_finite_differences` and the others,
//! so a failure names its backend and does not hide the other backends' results.
//!
//! The references do not depend on the backend under test: gradients are compared with
//! central finite differences of the free energy computed in f64 on the CPU, for the same
//! values rounded to the backend's precision; the small calls with their definitions. The
//! tolerance is the precision's ([`SuiteReal`]).
//!
//! - [`gradients`]: analytic gradients against central finite differences (learning with
//!   optional biases, slow-first taus, a log-sigma bound, unequal lengths; an inference
//!   window from a held state under partial observation and ablation), unobserved rows
//!   without gradient, the accuracy normalisation.
//! - [`contract`]: the small calls of a loaded model against `evaluate` and their
//!   definitions.
//! - [`branching`]: a run continued from its own state is the same run, and a branch shares
//!   its past.
//! - [`learning`]: learning lowers the free energy and online inference then tracks the
//!   sequence; runs stepped together equal each run alone; a diverging iteration leaves
//!   the run as it was.
//! - [`fixtures`]: the small models and data the checks run on.
//!
//! The backends' test files: `tests/cpu.rs` (also run as WebAssembly under Node) and
//! `tests/wgpu.rs` (the first adapter the machine offers: lavapipe in CI).
#![allow(clippy::unwrap_used)] // a test suite: a failed unwrap is a failed test

pub mod branching;
pub mod contract;
pub mod fixtures;
pub mod gradients;
pub mod learning;

use pvrnn_core::Real;
use pvrnn_core::backend::Backend;

/// A backend as the suite holds it (a learning run owns a handle to it).
pub type Shared<T> = std::sync::Arc<dyn Backend<T>>;

/// A precision the suite runs in, and how close to an f64 reference its results must be.
pub trait SuiteReal: Real {
    /// Allowed |result - reference| for a value that only rounding separates from its f64
    /// reference (a product of the same inputs, a read-out).
    fn rounding_tolerance(reference: f64) -> f64;

    /// Allowed |analytic - numeric| for a gradient whose finite-difference reference is
    /// `numeric`.
    fn gradient_tolerance(numeric: f64) -> f64;
}

impl SuiteReal for f64 {
    fn rounding_tolerance(reference: f64) -> f64 {
        1e-12 + 1e-10 * reference.abs()
    }

    /// With h = 1e-5 the truncation error of a central difference is ~h^2 F''' ~ 1e-10 and
    /// rounding ~1e-16 F / h ~ 1e-10, so a wrong term (even a missing 1/tau or a sign)
    /// fails by orders of magnitude.
    fn gradient_tolerance(numeric: f64) -> f64 {
        1e-7 + 1e-5 * numeric.abs()
    }
}

impl SuiteReal for f32 {
    fn rounding_tolerance(reference: f64) -> f64 {
        1e-5 + 1e-4 * reference.abs()
    }

    /// Measured (2026-11-27, CPU and lavapipe): the suite's f32 gradients are within about
    /// 1e-7 + 1e-6 |g| of the f64 finite differences on the same rounded values; this
    /// leaves a margin of about ten for other summation orders (a GPU's). A wrong term
    /// still fails by orders of magnitude.
    fn gradient_tolerance(numeric: f64) -> f64 {
        1e-6 + 2e-5 * numeric.abs()
    }
}

/// `values` rounded to `T` and back: what a backend in `T` sees of f64 inputs.
pub fn rounded<T: Real>(values: &[f64]) -> Vec<f64> {
    values.iter().map(|&v| T::from_f64(v).to_f64()).collect()
}

/// Every check of the suite, one `#[test]` each, on the backend `$backend` (an expression
/// giving `Option<Shared<$real>>`; `None` skips, for a device the machine lacks when the
/// caller allows it), in a module `$name`.
#[macro_export]
macro_rules! backend_suite {
    ($name:ident, $real:ty, $backend:expr) => {
        mod $name {
            #[allow(unused_imports)]
            use super::*;

            fn backend() -> Option<$crate::Shared<$real>> {
                $backend
            }
            $crate::backend_suite!(@tests $real;
                branching::a_run_continued_from_its_state_is_the_same_run_and_a_branch_shares_its_past,
                contract::prior_preactivations_are_the_prior_layers_of_the_state,
                contract::the_prior_rollout_and_the_readouts_agree_with_evaluate,
                gradients::learning_gradients_match_finite_differences,
                gradients::gradients_with_optional_biases_and_slow_first_taus,
                gradients::gradients_with_a_log_sigma_bound,
                gradients::gradients_with_unequal_sequence_lengths_and_zero_noise,
                gradients::inference_window_gradients_match_finite_differences,
                gradients::unobserved_outputs_get_no_weight_gradient,
                gradients::full_accuracy_normalisation_scales_by_the_observed_fraction,
                learning::learning_lowers_free_energy_and_online_inference_tracks_the_sequence,
                learning::learning_runs_stepped_together_equal_each_run_alone,
                learning::a_changed_noise_takes_effect_at_the_next_iteration,
                learning::a_diverging_iteration_leaves_the_run_as_it_was,
            );
        }
    };
    (@tests $real:ty; $($module:ident :: $check:ident),* $(,)?) => {
        $(
            #[cfg_attr(not(target_arch = "wasm32"), test)]
            #[cfg_attr(target_arch = "wasm32", wasm_bindgen_test::wasm_bindgen_test)]
            fn $check() {
                match backend() {
                    Some(backend) => $crate::$module::$check::<$real>(&backend),
                    None => eprintln!("skipped: the backend is not available here"),
                }
            }
        )*
    };
}
