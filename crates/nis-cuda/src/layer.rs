//! One coupling's launches, shared by every pass: the one-blob code of x_A, a dense layer of the
//! conditioner (SGEMM, then bias and ReLU), and the transforms of x_B.

use cudarc::cublas::sys::cublasOperation_t::{CUBLAS_OP_N, CUBLAS_OP_T};
use cudarc::cublas::{Gemm, GemmConfig};
use cudarc::driver::{CudaSlice, CudaView, CudaViewMut, PushKernelArg};

use crate::error::GpuError;
use crate::flow::GpuFlow;
use crate::gpu::{grid, grid_2d};
use crate::plan::Dense;

/// Column-major SGEMM C = op(A)·op(B) (row-major callers pass transposed roles).
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm(
    flow: &GpuFlow<'_>,
    (ta, tb): (bool, bool),
    (m, n, k): (usize, usize, usize),
    a: &CudaView<'_, f32>,
    lda: usize,
    b: &CudaView<'_, f32>,
    ldb: usize,
    c: &mut CudaViewMut<'_, f32>,
    ldc: usize,
) -> Result<(), GpuError> {
    let op = |t| if t { CUBLAS_OP_T } else { CUBLAS_OP_N };
    let cfg = GemmConfig {
        transa: op(ta),
        transb: op(tb),
        m: m as i32,
        n: n as i32,
        k: k as i32,
        alpha: 1.0f32,
        lda: lda as i32,
        ldb: ldb as i32,
        beta: 0.0f32,
        ldc: ldc as i32,
    };
    // SAFETY: the callers' views hold the shapes the config names.
    unsafe { flow.gpu.blas.gemm(cfg, a, b, c) }?;
    Ok(())
}

impl GpuFlow<'_> {
    /// The conditioner input of coupling `l` for the `n` rows of `u`: the one-blob code of each
    /// A dimension, into `enc` (`n × encoded`).
    pub(crate) fn encode(
        &self,
        l: usize,
        u: &CudaSlice<f32>,
        enc: &mut CudaViewMut<'_, f32>,
        n: usize,
    ) -> Result<(), GpuError> {
        let step = &self.plan.steps[l];
        let (dim, na, k, rows) = (
            self.plan.dim as i32,
            step.a.len() as i32,
            step.blob_bins as i32,
            n as i64,
        );
        let mut launch = self.gpu.stream.launch_builder(&self.gpu.kernels.encode);
        launch
            .arg(u)
            .arg(&dim)
            .arg(&self.indices[l].a)
            .arg(&na)
            .arg(&k)
            .arg(enc)
            .arg(&rows);
        // SAFETY: one thread per value of enc's n × na·k reads its row's A value of u.
        unsafe { launch.launch(grid_2d(n, step.encoded())?) }?;
        Ok(())
    }

    /// Dense layer `d` over `n` rows: y = x·W + b (`x` n × inputs, `y` n × outputs, row-major),
    /// then the ReLU when `relu`.
    pub(crate) fn dense(
        &self,
        d: &Dense,
        relu: bool,
        x: &CudaView<'_, f32>,
        y: &mut CudaViewMut<'_, f32>,
        n: usize,
    ) -> Result<(), GpuError> {
        let gpu = self.gpu;
        if d.inputs > 0 {
            // Row-major Y[n, o] = X[n, i]·W[i, o] is column-major Yᵀ = Wᵀ·Xᵀ.
            let w = self
                .params
                .slice(d.weights..d.weights + d.inputs * d.outputs);
            let (o, i) = (d.outputs, d.inputs);
            gemm(self, (false, false), (o, n, i), &w, o, x, i, y, o)?;
        } else {
            gpu.stream.memset_zeros(y)?;
        }
        let bias = self.params.slice(d.biases..d.biases + d.outputs);
        let (rows, o, relu) = (n as i64, d.outputs as i32, relu as i32);
        let mut launch = gpu.stream.launch_builder(&gpu.kernels.bias_act);
        launch.arg(y).arg(&bias).arg(&rows).arg(&o).arg(&relu);
        // SAFETY: y holds n × o values, bias o; one thread per value.
        unsafe { launch.launch(grid_2d(n, d.outputs)?) }?;
        Ok(())
    }

    /// Coupling `l`'s transforms of the B dimensions of the `n` rows of `u`, in place (latent to
    /// data when `inverse`), with the conditioner's output `out`, adding ln C' to `log_q`.
    pub(crate) fn transform(
        &self,
        l: usize,
        out: &CudaView<'_, f32>,
        u: &mut CudaSlice<f32>,
        log_q: &mut CudaSlice<f64>,
        n: usize,
        inverse: bool,
    ) -> Result<(), GpuError> {
        let step = &self.plan.steps[l];
        let (kind, bins, inv, rows, dim, nb) = (
            step.kind as i32,
            step.bins as i32,
            inverse as i32,
            n as i64,
            self.plan.dim as i32,
            step.b.len() as i32,
        );
        let mut launch = self.gpu.stream.launch_builder(&self.gpu.kernels.coupling);
        launch
            .arg(&kind)
            .arg(&bins)
            .arg(&inv)
            .arg(out)
            .arg(u)
            .arg(log_q)
            .arg(&rows)
            .arg(&dim)
            .arg(&self.indices[l].b)
            .arg(&nb);
        // SAFETY: out holds n rows of nb × np parameters; u n rows of dim; log_q n values.
        unsafe { launch.launch(grid(n)?) }?;
        Ok(())
    }
}
