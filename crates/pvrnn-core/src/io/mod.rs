//! safetensors files: models (spec tensor names, configuration as JSON metadata `config`),
//! checkpoints (a model plus optimiser state), gradients (`grad.` prefix), inputs
//! (`x_extero`, `x_proprio`) and inference runs.
//!
//! Every reader checks the header, dtypes, shapes and values and names the file and tensor
//! in its error; files are written to a temporary name and renamed, so an interrupted write
//! never leaves a half-written file under the real name.
//!
//! One job per file:
//! - `tensor_file.rs`: reading a safetensors file and checking its tensors ([`TensorFile`]).
//! - `write.rs`: the tensors to write ([`OutTensor`]) and their bytes with a canonical
//!   header ([`to_bytes`]).
//! - `atomic.rs`: writing a file atomically ([`write_atomic`]).
//! - `model.rs`: model files ([`save_model`], [`load_model`], [`model_from_file`]).
//! - `checkpoint.rs`: checkpoints, a model plus the optimiser's state ([`save_checkpoint`],
//!   [`load_checkpoint`]).
//! - `gradients.rs`: gradient files ([`save_gradients`]).
//! - `inputs.rs`: model inputs ([`load_observations`], [`save_observations`]).
//! - `runs.rs`: inference runs ([`save_runs`], [`load_runs`], [`StateStorage`]).

mod atomic;
mod checkpoint;
mod gradients;
mod inputs;
mod model;
mod runs;
mod tensor_file;
mod write;

pub use atomic::write_atomic;
pub use checkpoint::{
    checkpoint_from_bytes, checkpoint_iteration, is_checkpoint, load_checkpoint,
    load_checkpoint_on, save_checkpoint,
};
pub use gradients::save_gradients;
pub use inputs::{load_observations, observations_from_file, save_observations};
pub use model::{
    load_model, model_from_bytes, model_from_file, model_to_bytes, model_to_bytes_f16, save_model,
    save_model_at,
};
pub use runs::{LoadedRun, StateStorage, load_runs, runs_to_bytes, save_runs};
pub use tensor_file::TensorFile;
pub use write::{OutTensor, to_bytes};

/// Identifies what kind of file a safetensors file is (metadata key `format`).
pub const MODEL_FORMAT: &str = "pvrnn-model/1";
pub const CHECKPOINT_FORMAT: &str = "pvrnn-checkpoint/1";
pub const RUN_FORMAT: &str = "pvrnn-inference/1";
const OPTIMIZER_PREFIX: &str = "radam.";
/// A model file's metadata key for the training iteration it was taken at
/// ([`save_model_at`]; a checkpoint keeps it in its learning state).
const TRAINED_ITERATIONS: &str = "trained_iterations";
