//! Adam (Kingma & Ba 2015) on the device, as `nis::nn::Adam` updates: clipping by the
//! gradient's norm (summed in f64 in a fixed order), the step size with its bias corrections and
//! decay formed on the host, the update itself a kernel (kernels/flow.cuh, `nis_adam`).

use cudarc::driver::{CudaSlice, PushKernelArg};
use nis::nn::AdamConfig;

use crate::error::GpuError;
use crate::flow::GpuFlow;
use crate::gpu::grid;

/// Adam on the device (`nis::nn::Adam`'s update: clipping by the gradient's norm, summed in
/// f64 in a fixed order, bias corrections and decay formed on the host).
pub struct GpuAdam {
    config: AdamConfig,
    /// The number of parameters it updates.
    n: usize,
    m: CudaSlice<f32>,
    v: CudaSlice<f32>,
    step: u64,
}

/// The step size of Adam's update `t` (from 1): the decayed learning rate with both moments'
/// bias corrections, as `nis::nn::Adam::step` forms it.
pub(crate) fn step_size(c: &AdamConfig, t: u64) -> f32 {
    let lr = c.learning_rate * c.decay.powf((t - 1) as f32);
    let t = t as i32;
    lr * (1.0 - c.beta2.powi(t)).sqrt() / (1.0 - c.beta1.powi(t))
}

/// Values per partial sum of the gradient's norm.
const NORM_CHUNK: usize = 4096;

impl GpuAdam {
    /// Adam for the parameters of `flow`.
    pub fn new(flow: &GpuFlow<'_>, config: AdamConfig) -> Result<GpuAdam, GpuError> {
        config
            .validate()
            .map_err(|e| GpuError::InvalidInput(e.to_string()))?;
        let n = flow.plan.params.len().max(1);
        let stream = &flow.gpu.stream;
        Ok(GpuAdam {
            config,
            n: flow.plan.params.len(),
            m: stream.alloc_zeros(n)?,
            v: stream.alloc_zeros(n)?,
            step: 0,
        })
    }

    /// One update of `flow`'s parameters with the gradient `grad`; returns the gradient's norm.
    pub fn step(&mut self, flow: &mut GpuFlow<'_>, grad: &CudaSlice<f32>) -> Result<f64, GpuError> {
        let gpu = flow.gpu;
        let stream = &gpu.stream;
        let n = flow.plan.params.len();
        if n != self.n || grad.len() < n {
            return Err(GpuError::InvalidInput(format!(
                "Adam of {} parameters asked to update {n} with a gradient of {} values",
                self.n,
                grad.len()
            )));
        }
        let chunks = n.div_ceil(NORM_CHUNK).max(1);
        let mut partial = stream.alloc_zeros::<f64>(chunks)?;
        let (len, chunk) = (n as i64, NORM_CHUNK as i64);
        let mut launch = stream.launch_builder(&gpu.kernels.sum_squares);
        launch.arg(grad).arg(&len).arg(&chunk).arg(&mut partial);
        // SAFETY: one thread per chunk of the n gradient values.
        unsafe { launch.launch(grid(chunks)?) }?;
        let norm = stream.clone_dtoh(&partial)?.iter().sum::<f64>().sqrt();
        if !norm.is_finite() {
            return Err(GpuError::InvalidInput(format!(
                "the gradient's norm is {norm}"
            )));
        }
        let c = self.config;
        let scale = match c.clip_norm {
            Some(limit) if norm > limit as f64 => (limit as f64 / norm) as f32,
            _ => 1.0f32,
        };
        self.step += 1;
        let lr_t = step_size(&c, self.step);
        let mut launch = stream.launch_builder(&gpu.kernels.adam);
        launch
            .arg(&mut flow.params)
            .arg(grad)
            .arg(&mut self.m)
            .arg(&mut self.v)
            .arg(&len)
            .arg(&lr_t)
            .arg(&c.beta1)
            .arg(&c.beta2)
            .arg(&c.eps)
            .arg(&scale);
        // SAFETY: all four buffers hold at least n values.
        unsafe { launch.launch(grid(n)?) }?;
        Ok(norm)
    }
}
