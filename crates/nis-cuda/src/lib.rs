//! The coupling flow of `nis` on NVIDIA GPUs (Müller et al. 2019's flows, batch-major on the
//! device as tiny-cuda-nn and MadSpace run them): the CUDA driver, NVRTC and cuBLAS are loaded at
//! run time (`cudarc`), so this crate builds and its CPU tests run on machines without CUDA, and
//! a machine without a GPU gets [`GpuError::NoDevice`] before anything runs.
//!
//! The elementwise kernels (kernels/flow.cuh) are written once: NVRTC compiles them for the card
//! at the first [`Gpu::open`] of the process, and the build script compiles the same bodies for
//! the CPU, where the tests check them against `nis`'s transforms.
//!
//! ```no_run
//! use nis::flow::{Flow, FlowConfig};
//! let flow = Flow::new(FlowConfig::new(4)).unwrap();
//! let gpu = nis_cuda::Gpu::open(0)?;
//! let on_gpu = nis_cuda::GpuFlow::new(&gpu, &flow)?;
//! let samples = on_gpu.sample(1 << 16, 7)?; // points and ln q, on the device
//! # Ok::<(), nis_cuda::GpuError>(())
//! ```

mod adam;
mod error;
mod flow;
mod gpu;
#[doc(hidden)]
pub mod harness;
mod layer;
mod plan;
mod train;
mod trainer;

pub use adam::GpuAdam;
pub use error::GpuError;
pub use flow::{DeviceSamples, GpuFlow};
pub use gpu::Gpu;
pub use trainer::{BatchEstimate, GpuTrainer};
