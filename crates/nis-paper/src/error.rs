//! Typed errors of the experiments: the library's own, and those of images, data sets and
//! figures. Only front ends (the CLI) turn them into messages.

use std::path::PathBuf;

/// Everything that can go wrong in an experiment, as a value.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An error of the `nis` library (flows, training, files).
    #[error(transparent)]
    Nis(#[from] nis::Error),
    /// An error of the path tracer (scenes, images, guides).
    #[error(transparent)]
    Render(#[from] nis_render::Error),
    /// An error of the GPU back end (no GPU, out of GPU memory, a flow it does not run).
    #[cfg(feature = "cuda")]
    #[error(transparent)]
    Gpu(#[from] nis_cuda::GpuError),
    /// A setting that describes no valid experiment.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// An operating-system error while reading or writing a file.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file that cannot be read as an image (missing, unreadable, not PNG/JPEG).
    #[error("image {path}: {reason}")]
    Image { path: PathBuf, reason: String },
    /// A target that is no usable density: empty, all black, negative or non-finite.
    #[error("target {name}: {reason}")]
    Target { name: String, reason: String },
    /// A data file that exists but cannot be read as the images it should hold.
    #[error("data file {path}: {reason}")]
    Data { path: PathBuf, reason: String },
    /// A data file that is not there.
    #[error("data file {path} not found: run scripts/setup/fetch-data.sh (it fetches the image sets into data/)")]
    MissingData { path: PathBuf },
    /// A figure (PNG plot or false-colour image) that could not be drawn or encoded.
    #[error("figure: {0}")]
    Figure(String),
}

/// Shorthand for results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
