//! Why a GPU call failed: each a typed error, none a panic or an abort.

use thiserror::Error;

/// The GPU back end's errors.
#[derive(Debug, Error)]
pub enum GpuError {
    /// No CUDA driver library (`libcuda.so`) could be loaded, or it found no usable device.
    #[error("no usable CUDA GPU: {0}")]
    NoDevice(String),
    /// A CUDA library the back end needs (NVRTC, cuBLAS) could not be loaded.
    #[error("CUDA library {library} could not be loaded: {reason}")]
    Library {
        library: &'static str,
        reason: String,
    },
    /// The driver reported an error (out of memory among them).
    #[error("CUDA driver: {0}")]
    Driver(String),
    /// NVRTC could not compile the kernels.
    #[error("compiling the CUDA kernels: {0}")]
    Compile(String),
    /// cuBLAS reported an error.
    #[error("cuBLAS: {0}")]
    Blas(String),
    /// The flow or the call uses something the GPU back end does not do.
    #[error("not on the GPU: {0}")]
    Unsupported(String),
    /// Bad input (sizes, values).
    #[error("invalid input: {0}")]
    InvalidInput(String),
}
