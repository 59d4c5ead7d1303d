//! The coupling flow on the GPU: sampling with ln q and the log-density, batch-major, every layer
//! on the device. Per coupling: the one-blob code of x_A (a kernel), the conditioner's dense
//! layers (cuBLAS SGEMM, then a bias-and-ReLU kernel), the transforms of x_B (a kernel, one
//! thread per row, adding ln C' to the row's ln q in f64) — the CPU flow's arithmetic
//! (`nis::flow::coupling`), so both give the same numbers to f32 rounding.

use cudarc::driver::{CudaSlice, PushKernelArg};
use nis::flow::Flow;

use crate::error::GpuError;
use crate::gpu::{grid, Gpu};
use crate::plan::Plan;

/// Points and their ln q, on the device.
pub struct DeviceSamples {
    /// Row-major points, `n × D`.
    pub x: CudaSlice<f32>,
    /// ln q of each point.
    pub log_q: CudaSlice<f64>,
}

/// One coupling's index lists on the device.
pub(crate) struct Indices {
    pub a: CudaSlice<i32>,
    pub b: CudaSlice<i32>,
}

/// A [`Flow`]'s copy on a GPU. Its weights are the flow's at the time of the copy.
pub struct GpuFlow<'g> {
    pub(crate) gpu: &'g Gpu,
    pub(crate) plan: Plan,
    pub(crate) params: CudaSlice<f32>,
    pub(crate) indices: Vec<Indices>,
}

impl std::fmt::Debug for GpuFlow<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuFlow")
            .field("dim", &self.plan.dim)
            .field("couplings", &self.plan.steps.len())
            .finish()
    }
}

impl<'g> GpuFlow<'g> {
    /// Copies `flow` onto `gpu`; an error where the flow uses what the GPU does not run.
    pub fn new(gpu: &'g Gpu, flow: &Flow) -> Result<GpuFlow<'g>, GpuError> {
        let plan = Plan::of(flow)?;
        let stream = &gpu.stream;
        let params = stream.clone_htod(&plan.params)?;
        // A one-element list stands for an empty one: the driver allocates no zero-length buffer.
        let upload = |v: &[i32]| stream.clone_htod(if v.is_empty() { &[0][..] } else { v });
        let indices = plan
            .steps
            .iter()
            .map(|s| {
                Ok(Indices {
                    a: upload(&s.a)?,
                    b: upload(&s.b)?,
                })
            })
            .collect::<Result<_, GpuError>>()?;
        Ok(GpuFlow {
            gpu,
            plan,
            params,
            indices,
        })
    }

    /// The dimension D.
    pub fn dim(&self) -> usize {
        self.plan.dim
    }

    /// `n` points drawn from the flow with their ln q, left on the device. The latents are the
    /// counter-based stream `seed` (kernels/flow.cuh, `nis_uniform_at`): the same seed gives the
    /// same points on a given card.
    pub fn sample(&self, n: usize, seed: u64) -> Result<DeviceSamples, GpuError> {
        let len = self.values_of(n)?;
        let stream = &self.gpu.stream;
        // SAFETY: the uniform kernel writes every value before anything reads it.
        let mut x = unsafe { stream.alloc::<f32>(len) }?;
        let count = len as u64;
        let mut launch = stream.launch_builder(&self.gpu.kernels.uniform);
        launch.arg(&mut x).arg(&count).arg(&seed);
        // SAFETY: the kernel writes `count` floats into `x`, which holds at least that many.
        unsafe { launch.launch(grid(len)?) }?;
        let log_q = self.run(&mut x, n, true)?;
        Ok(DeviceSamples { x, log_q })
    }

    /// The points of the latents `z` (`n × D`, row-major, in [0, 1]) and their ln q, on the host:
    /// the flow's inverse as [`nis::Bijection::inverse`] computes it (with ln q = −its log-det).
    pub fn sample_latents(&self, z: &[f32]) -> Result<(Vec<f32>, Vec<f64>), GpuError> {
        let n = self.check_points(z, "latents")?;
        let stream = &self.gpu.stream;
        let mut x = stream.clone_htod(z)?;
        let log_q = self.run(&mut x, n, true)?;
        Ok((stream.clone_dtoh(&x)?, stream.clone_dtoh(&log_q)?))
    }

    /// ln q(x) of each row of `x` (`n × D`, row-major, in [0, 1]).
    pub fn log_density(&self, x: &[f32]) -> Result<Vec<f64>, GpuError> {
        let n = self.check_points(x, "points")?;
        let stream = &self.gpu.stream;
        let mut u = stream.clone_htod(x)?;
        let log_q = self.run(&mut u, n, false)?;
        Ok(stream.clone_dtoh(&log_q)?)
    }

    /// ln q of the `n` rows already on the device in `x`.
    pub fn log_density_device(
        &self,
        x: &CudaSlice<f32>,
        n: usize,
    ) -> Result<CudaSlice<f64>, GpuError> {
        let len = self.values_of(n)?;
        if x.len() < len {
            return Err(GpuError::InvalidInput(format!(
                "{n} points of dimension {} need {len} values, the buffer holds {}",
                self.plan.dim,
                x.len()
            )));
        }
        let mut u = self.gpu.stream.clone_dtod(x)?;
        self.run(&mut u, n, false)
    }

    /// The number of values of `n` points: an error for none, or for more than the kernels
    /// and the dense layers' 32-bit sizes address.
    pub(crate) fn values_of(&self, n: usize) -> Result<usize, GpuError> {
        let widest = self.plan.widest().max(self.plan.dim);
        if n == 0 || i32::try_from(n).is_err() || n.checked_mul(widest).is_none() {
            return Err(GpuError::InvalidInput(format!(
                "a batch of {n} points: at least 1 and at most {} on the GPU",
                i32::MAX
            )));
        }
        Ok(n * self.plan.dim)
    }

    /// The flow's parameters, copied to the host (laid out as `nis::Density::params`).
    pub fn params(&self) -> Result<Vec<f32>, GpuError> {
        Ok(self.gpu.stream.clone_dtoh(&self.params)?)
    }

    /// Checks that `v` holds whole rows of finite values in [0, 1]; returns the row count.
    pub(crate) fn check_points(&self, v: &[f32], what: &str) -> Result<usize, GpuError> {
        let d = self.plan.dim;
        if v.is_empty() || v.len() % d != 0 {
            return Err(GpuError::InvalidInput(format!(
                "{what}: {} values are not a positive number of rows of {d}",
                v.len()
            )));
        }
        if let Some(i) = v.iter().position(|t| !(0.0..=1.0).contains(t)) {
            return Err(GpuError::InvalidInput(format!(
                "{what}: value {i} is {}, outside [0, 1]",
                v[i]
            )));
        }
        let n = v.len() / d;
        self.values_of(n)?;
        Ok(n)
    }

    /// Runs every coupling over the `n` rows of `u` in place (latent to data when `inverse`);
    /// returns ln q per row.
    fn run(
        &self,
        u: &mut CudaSlice<f32>,
        n: usize,
        inverse: bool,
    ) -> Result<CudaSlice<f64>, GpuError> {
        let stream = &self.gpu.stream;
        let mut log_q = stream.alloc_zeros::<f64>(n)?;
        // Two buffers of the widest activation, each layer reading one and writing the other.
        let widest = self.plan.widest();
        // SAFETY: each layer writes the part of a buffer it hands on (encoding, SGEMM, or a
        // memset for a layer without inputs) before the next reads it.
        let mut bufs = unsafe {
            [
                stream.alloc::<f32>(n * widest)?,
                stream.alloc::<f32>(n * widest)?,
            ]
        };
        for l in self.plan.order(inverse) {
            let step = &self.plan.steps[l];
            let enc = step.encoded();
            if enc > 0 {
                self.encode(l, u, &mut bufs[0].slice_mut(0..n * enc), n)?;
            }
            let mut cur = 0;
            for (j, d) in step.dense.iter().enumerate() {
                let [a, b] = &mut bufs;
                let (src, dst) = if cur == 0 { (&*a, b) } else { (&*b, a) };
                let relu = j + 1 < step.dense.len();
                let x = src.slice(0..n * d.inputs);
                self.dense(d, relu, &x, &mut dst.slice_mut(0..n * d.outputs), n)?;
                cur = 1 - cur;
            }
            let out_w = step.dense.last().map_or(0, |d| d.outputs);
            let out = bufs[cur].slice(0..n * out_w);
            self.transform(l, &out, u, &mut log_q, n, inverse)?;
        }
        Ok(log_q)
    }
}
