//! One GPU: its context and stream, cuBLAS on that stream, and the kernels of kernels/flow.cuh
//! compiled by NVRTC for the card's architecture, once per process.

use std::sync::{Arc, Mutex};

use cudarc::cublas::CudaBlas;
use cudarc::driver::sys::CUdevice_attribute;
use cudarc::driver::{CudaContext, CudaFunction, CudaStream, DriverError, LaunchConfig};
use cudarc::nvrtc::{compile_ptx_with_opts, CompileError, CompileOptions, Ptx};

use crate::error::GpuError;

/// The kernels' source, shared with the CPU harness.
const SOURCE: &str = include_str!("../kernels/flow.cuh");

/// Threads per block of the elementwise kernels.
const BLOCK: u32 = 256;

impl From<DriverError> for GpuError {
    fn from(e: DriverError) -> GpuError {
        GpuError::Driver(e.to_string())
    }
}

impl From<CompileError> for GpuError {
    fn from(e: CompileError) -> GpuError {
        match e {
            CompileError::CompileError { log, .. } => {
                GpuError::Compile(log.to_string_lossy().into_owned())
            }
            other => GpuError::Compile(other.to_string()),
        }
    }
}

impl From<cudarc::cublas::result::CublasError> for GpuError {
    fn from(e: cudarc::cublas::result::CublasError) -> GpuError {
        GpuError::Blas(e.to_string())
    }
}

/// The compiled kernels, per target architecture: NVRTC runs once per process and card kind.
static PTX: Mutex<Vec<(String, Ptx)>> = Mutex::new(Vec::new());

/// The kernels of kernels/flow.cuh on one context.
pub(crate) struct Kernels {
    pub uniform: CudaFunction,
    pub encode: CudaFunction,
    pub bias_act: CudaFunction,
    pub coupling: CudaFunction,
    pub coupling_backward: CudaFunction,
    pub encode_backward: CudaFunction,
    pub relu_backward: CudaFunction,
    pub sum_squares: CudaFunction,
    pub adam: CudaFunction,
}

/// A GPU ready to run flows: context, stream, cuBLAS handle, kernels.
pub struct Gpu {
    pub(crate) ctx: Arc<CudaContext>,
    pub(crate) stream: Arc<CudaStream>,
    pub(crate) blas: CudaBlas,
    pub(crate) kernels: Kernels,
    name: String,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gpu").field("name", &self.name).finish()
    }
}

/// Whether the CUDA libraries can be loaded; the loaders of `cudarc` panic where they cannot, so
/// this is asked before any call into them.
fn check_libraries() -> Result<(), GpuError> {
    // SAFETY: each probe dlopens the library (running its initialisers) and closes it again;
    // the CUDA libraries' initialisers have no preconditions.
    if !unsafe { cudarc::driver::sys::is_culib_present() } {
        return Err(GpuError::NoDevice(
            "the CUDA driver library (libcuda.so.1) was not found: no NVIDIA driver on this \
             machine"
                .into(),
        ));
    }
    let missing = |library: &'static str| GpuError::Library {
        library,
        reason: "not found on the library path (LD_LIBRARY_PATH); it ships with the CUDA \
                 toolkit and with the nvidia-*-cu13 Python packages"
            .into(),
    };
    // SAFETY: as above.
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return Err(missing("NVRTC (libnvrtc.so.13)"));
    }
    // SAFETY: as above.
    if !unsafe { cudarc::cublas::sys::is_culib_present() } {
        return Err(missing("cuBLAS (libcublas.so.13)"));
    }
    Ok(())
}

impl Gpu {
    /// Opens GPU `ordinal`: a clear error where there is no driver, no such device or no CUDA
    /// library, before anything runs.
    pub fn open(ordinal: usize) -> Result<Gpu, GpuError> {
        check_libraries()?;
        let count = CudaContext::device_count().map_err(|e| GpuError::NoDevice(e.to_string()))?;
        if ordinal >= count.max(0) as usize {
            return Err(GpuError::NoDevice(format!(
                "GPU {ordinal} asked for, the driver sees {count}"
            )));
        }
        let ctx = CudaContext::new(ordinal)?;
        let stream = ctx.default_stream();
        let blas = CudaBlas::new(stream.clone())?;
        let major =
            ctx.attribute(CUdevice_attribute::CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR)?;
        let minor =
            ctx.attribute(CUdevice_attribute::CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR)?;
        let arch = format!("compute_{major}{minor}");
        let ptx = {
            let mut cache = PTX.lock().unwrap_or_else(|p| p.into_inner());
            match cache.iter().find(|(a, _)| *a == arch) {
                Some((_, ptx)) => ptx.clone(),
                None => {
                    let ptx = compile_ptx_with_opts(
                        SOURCE,
                        CompileOptions {
                            options: vec![format!("--gpu-architecture={arch}")],
                            ..Default::default()
                        },
                    )?;
                    cache.push((arch, ptx.clone()));
                    ptx
                }
            }
        };
        let module = ctx.load_module(ptx)?;
        let kernels = Kernels {
            uniform: module.load_function("nis_uniform")?,
            encode: module.load_function("nis_encode")?,
            bias_act: module.load_function("nis_bias_act")?,
            coupling: module.load_function("nis_coupling")?,
            coupling_backward: module.load_function("nis_coupling_backward")?,
            encode_backward: module.load_function("nis_encode_backward")?,
            relu_backward: module.load_function("nis_relu_backward")?,
            sum_squares: module.load_function("nis_sum_squares")?,
            adam: module.load_function("nis_adam")?,
        };
        let name = ctx.name()?;
        Ok(Gpu {
            ctx,
            stream,
            blas,
            kernels,
            name,
        })
    }

    /// The card's name, as the driver gives it.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Waits for everything queued on the GPU.
    pub fn synchronize(&self) -> Result<(), GpuError> {
        Ok(self.stream.synchronize()?)
    }

    /// The context (for callers that allocate or copy themselves).
    pub fn context(&self) -> &Arc<CudaContext> {
        &self.ctx
    }

    /// The stream every call of this GPU runs on.
    pub fn stream(&self) -> &Arc<CudaStream> {
        &self.stream
    }
}

/// A launch of `n` threads in blocks of [`BLOCK`].
pub(crate) fn grid(n: usize) -> Result<LaunchConfig, GpuError> {
    let blocks = n.div_ceil(BLOCK as usize);
    let blocks = u32::try_from(blocks.max(1))
        .map_err(|_| GpuError::InvalidInput(format!("{n} threads do not fit one launch")))?;
    Ok(LaunchConfig {
        grid_dim: (blocks, 1, 1),
        block_dim: (BLOCK, 1, 1),
        shared_mem_bytes: 0,
    })
}

/// A launch over a row-major `rows × cols` matrix, one thread a value: blocks of 8 rows × 32
/// columns on a 2-D grid (rows along x, columns along y).
pub(crate) fn grid_2d(rows: usize, cols: usize) -> Result<LaunchConfig, GpuError> {
    let bx = u32::try_from(rows.div_ceil(8).max(1))
        .ok()
        .filter(|&b| b < 1 << 31);
    let by = u32::try_from(cols.div_ceil(32).max(1))
        .ok()
        .filter(|&b| b <= 65_535);
    match (bx, by) {
        (Some(bx), Some(by)) => Ok(LaunchConfig {
            grid_dim: (bx, by, 1),
            block_dim: (32, 8, 1),
            shared_mem_bytes: 0,
        }),
        _ => Err(GpuError::InvalidInput(format!(
            "a {rows} × {cols} matrix does not fit one launch"
        ))),
    }
}
