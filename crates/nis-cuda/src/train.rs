//! The training step on the GPU: the score-function gradient of L = −Σ_i w_i ln q(x_i; θ) (the
//! KL, χ² and NLL losses differ only in the weights w, `nis::loss::weights`) through the whole
//! stack, as `nis::Density::backward` computes it on the CPU (Adam, which applies it: adam.rs).
//!
//! The pass runs data to latent and keeps each coupling's input and its conditioner's
//! activations (the tape); the reverse sweep runs latent to data: the transforms' reverse mode
//! (a kernel per coupling), the conditioner's (SGEMMs for ∂L/∂W = Xᵀ·δ, ∂L/∂X = δ·Wᵀ, and
//! ∂L/∂b = δᵀ·1, so every sum has cuBLAS's fixed order), and the encoding's.

use cudarc::driver::{CudaSlice, PushKernelArg};

use crate::error::GpuError;
use crate::flow::GpuFlow;
use crate::gpu::grid;
use crate::layer::gemm;

/// One coupling's share of the tape: its data-side input, its conditioner's input (the
/// encoding) and each dense layer's output (after the ReLU for hidden layers).
struct LayerTape {
    input: CudaSlice<f32>,
    encoded: Option<CudaSlice<f32>>,
    acts: Vec<CudaSlice<f32>>,
}

impl GpuFlow<'_> {
    /// The gradient of L = −Σ_i w_i ln q(x_i; θ) with respect to the flow's parameters (laid out
    /// as `nis::Density::params`), at the `n` points on the device in `x` with the weights `w`
    /// (one per point, on the device). Returns the gradient, on the device.
    pub fn gradient(
        &self,
        x: &CudaSlice<f32>,
        w: &CudaSlice<f32>,
        n: usize,
    ) -> Result<CudaSlice<f32>, GpuError> {
        let dim = self.plan.dim;
        let len = self.values_of(n)?;
        if x.len() < len || w.len() < n {
            return Err(GpuError::InvalidInput(format!(
                "{n} points of dimension {dim} with their weights: got {} values and {} weights",
                x.len(),
                w.len()
            )));
        }
        let stream = &self.gpu.stream;
        let k = &self.gpu.kernels;
        let (rows, dim_i) = (n as i64, dim as i32);
        // The forward pass, data to latent, keeping the tape.
        let mut u = stream.clone_dtod(x)?;
        let mut log_q = stream.alloc_zeros::<f64>(n)?;
        let mut tapes = Vec::with_capacity(self.plan.steps.len());
        for (l, step) in self.plan.steps.iter().enumerate() {
            let input = stream.clone_dtod(&u)?;
            let enc_w = step.encoded();
            let encoded = if enc_w > 0 {
                // SAFETY: the encoding writes all n × enc_w values.
                let mut enc = unsafe { stream.alloc::<f32>(n * enc_w) }?;
                self.encode(l, &u, &mut enc.slice_mut(0..n * enc_w), n)?;
                Some(enc)
            } else {
                None
            };
            let mut acts: Vec<CudaSlice<f32>> = Vec::with_capacity(step.dense.len());
            for (j, d) in step.dense.iter().enumerate() {
                // SAFETY: the SGEMM (or, without inputs, a memset) writes all of it.
                let mut y = unsafe { stream.alloc::<f32>(n * d.outputs) }?;
                let src = if j == 0 {
                    encoded.as_ref()
                } else {
                    acts.last()
                };
                let relu = j + 1 < step.dense.len();
                // A layer without inputs reads nothing: any buffer stands for its empty input.
                let x = src.unwrap_or(&u).slice(0..n * d.inputs);
                self.dense(d, relu, &x, &mut y.slice_mut(0..n * d.outputs), n)?;
                acts.push(y);
            }
            let out_w = step.dense.last().map_or(0, |d| d.outputs);
            let out = acts
                .last()
                .ok_or_else(|| GpuError::Unsupported("a conditioner without layers".into()))?
                .slice(0..n * out_w);
            self.transform(l, &out, &mut u, &mut log_q, n, false)?;
            tapes.push(LayerTape {
                input,
                encoded,
                acts,
            });
        }
        // ∂L/∂ln C' of every row is −w; ∂L/∂u starts at zero (the latent's density is constant).
        let g_ld = {
            let host: Vec<f32> = stream.clone_dtoh(&w.slice(0..n))?;
            stream.clone_htod(&host.iter().map(|v| -v).collect::<Vec<f32>>())?
        };
        let mut g_u = stream.alloc_zeros::<f32>(n * dim)?;
        let mut grads = stream.alloc_zeros::<f32>(self.plan.params.len().max(1))?;
        let ones = stream.clone_htod(&vec![1.0f32; n])?;
        for (l, step) in self.plan.steps.iter().enumerate().rev() {
            let idx = &self.indices[l];
            let tape = &tapes[l];
            let out_w = step.dense.last().map_or(0, |d| d.outputs);
            // SAFETY: the transforms' reverse mode writes every parameter's gradient of every row.
            let mut delta = unsafe { stream.alloc::<f32>(n * out_w) }?;
            let (kind, bins, nb) = (step.kind as i32, step.bins as i32, step.b.len() as i32);
            let mut launch = stream.launch_builder(&k.coupling_backward);
            launch
                .arg(&kind)
                .arg(&bins)
                .arg(tape.acts.last().expect("an output layer"))
                .arg(&tape.input)
                .arg(&mut g_u)
                .arg(&g_ld)
                .arg(&mut delta)
                .arg(&rows)
                .arg(&dim_i)
                .arg(&idx.b)
                .arg(&nb);
            // SAFETY: the tape's buffers hold n rows of their widths; delta n × out_w.
            unsafe { launch.launch(grid(n)?) }?;
            // The first coupling's input is the fixed x: no gradient is needed below it.
            let want_input = l > 0 && !step.a.is_empty();
            for (j, d) in step.dense.iter().enumerate().rev() {
                if d.inputs > 0 {
                    let src = if j == 0 {
                        tape.encoded
                            .as_ref()
                            .expect("a layer with inputs has an encoding")
                    } else {
                        &tape.acts[j - 1]
                    };
                    // ∂L/∂W (row-major [in, out]) = Xᵀ·δ: column-major (δᵀ)·X.
                    let dv = delta.slice(0..n * d.outputs);
                    let xv = src.slice(0..n * d.inputs);
                    let mut gw = grads.slice_mut(d.weights..d.weights + d.inputs * d.outputs);
                    gemm(
                        self,
                        (false, true),
                        (d.outputs, d.inputs, n),
                        &dv,
                        d.outputs,
                        &xv,
                        d.inputs,
                        &mut gw,
                        d.outputs,
                    )?;
                }
                {
                    // ∂L/∂b = δᵀ·1.
                    let dv = delta.slice(0..n * d.outputs);
                    let ov = ones.slice(0..n);
                    let mut gb = grads.slice_mut(d.biases..d.biases + d.outputs);
                    gemm(
                        self,
                        (false, false),
                        (d.outputs, 1, n),
                        &dv,
                        d.outputs,
                        &ov,
                        n,
                        &mut gb,
                        d.outputs,
                    )?;
                }
                if d.inputs == 0 || (j == 0 && !want_input) {
                    continue;
                }
                // ∂L/∂X = δ·Wᵀ: column-major (Wᵀ)ᵀ·δᵀ, Wᵀ being W as stored, [out, in].
                // SAFETY: the SGEMM below writes all of it.
                let mut prev = unsafe { stream.alloc::<f32>(n * d.inputs) }?;
                {
                    let wv = self
                        .params
                        .slice(d.weights..d.weights + d.inputs * d.outputs);
                    let dv = delta.slice(0..n * d.outputs);
                    let mut pv = prev.slice_mut(0..n * d.inputs);
                    gemm(
                        self,
                        (true, false),
                        (d.inputs, n, d.outputs),
                        &wv,
                        d.outputs,
                        &dv,
                        d.outputs,
                        &mut pv,
                        d.inputs,
                    )?;
                }
                if j > 0 {
                    let len = (n * d.inputs) as i64;
                    let mut launch = stream.launch_builder(&k.relu_backward);
                    launch.arg(&mut prev).arg(&tape.acts[j - 1]).arg(&len);
                    // SAFETY: both hold n × inputs values.
                    unsafe { launch.launch(grid(n * d.inputs)?) }?;
                    delta = prev;
                } else {
                    let enc = tape
                        .encoded
                        .as_ref()
                        .expect("a layer with inputs has an encoding");
                    let (na, kb, width) =
                        (step.a.len() as i32, step.blob_bins as i32, d.inputs as i32);
                    let mut launch = stream.launch_builder(&k.encode_backward);
                    launch
                        .arg(&tape.input)
                        .arg(&dim_i)
                        .arg(&idx.a)
                        .arg(&na)
                        .arg(&kb)
                        .arg(enc)
                        .arg(&prev)
                        .arg(&width)
                        .arg(&mut g_u)
                        .arg(&rows);
                    // SAFETY: one thread per (row, A dimension), within the buffers' rows.
                    unsafe { launch.launch(grid(n * step.a.len())?) }?;
                }
            }
        }
        Ok(grads)
    }
}
