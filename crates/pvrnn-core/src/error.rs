//! One error type for everything a user can get wrong: files, shapes, values, settings.

/// Everything that can go wrong in the core; every message names the file, tensor or setting.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid configuration: {0}")]
    Config(String),

    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },

    #[error("{what}: not a readable safetensors file: {detail}")]
    Format { what: String, detail: String },

    #[error("{what}: missing tensor `{name}`")]
    MissingTensor { what: String, name: String },

    #[error("{what}: tensor `{name}` has shape {found:?}, expected {expected}")]
    Shape {
        what: String,
        name: String,
        found: Vec<usize>,
        expected: String,
    },

    #[error("{what}: tensor `{name}` has dtype {found}, expected {expected}")]
    Dtype {
        what: String,
        name: String,
        found: String,
        expected: &'static str,
    },

    #[error("{what}: tensor `{name}` holds a non-finite value ({value}) at index {index:?}")]
    NonFinite {
        what: String,
        name: String,
        index: Vec<usize>,
        value: f64,
    },

    #[error("{what}: unexpected tensor `{name}` (not part of this model's configuration)")]
    UnexpectedTensor { what: String, name: String },

    /// A model and data (or two files) that do not fit together.
    #[error("{0}")]
    Mismatch(String),

    /// A value outside its valid range (a command-line option, an observation condition).
    #[error("{0}")]
    InvalidArgument(String),

    /// Learning or inference diverged.
    #[error("{0}")]
    Numerical(String),

    /// The compute device could not do what was asked (its memory ran out).
    #[error("{0}")]
    Device(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub(crate) fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }
}
