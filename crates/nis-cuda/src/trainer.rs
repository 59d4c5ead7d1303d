//! Training a flow on the GPU against an integrand evaluated on the host.

use nis::nn::AdamConfig;

use crate::adam::GpuAdam;
use crate::error::GpuError;
use crate::flow::GpuFlow;

/// One training batch's Monte Carlo estimate of ∫ f: the mean of f/q and its variance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchEstimate {
    pub mean: f64,
    pub variance: f64,
}

/// A flow on the GPU learning an integrand evaluated on the host: each step draws a batch on
/// the device, hands its points to `f`, forms the loss's weights in f64 (`nis::loss::weights`,
/// normalised by their sum, as the CPU trainer does), and takes one Adam step.
pub struct GpuTrainer<'g> {
    pub flow: GpuFlow<'g>,
    adam: GpuAdam,
    loss: nis::loss::Loss,
}

impl<'g> GpuTrainer<'g> {
    /// A trainer of `flow` minimising `loss` with Adam.
    pub fn new(
        flow: GpuFlow<'g>,
        loss: nis::loss::Loss,
        adam: AdamConfig,
    ) -> Result<GpuTrainer<'g>, GpuError> {
        let adam = GpuAdam::new(&flow, adam)?;
        Ok(GpuTrainer { flow, adam, loss })
    }

    /// One step on `n` fresh points of stream `seed`; `f` gets the points (`n × D`, row-major)
    /// and writes the integrand's values. Returns the batch's estimate of ∫ f.
    pub fn step(
        &mut self,
        n: usize,
        seed: u64,
        f: &mut dyn FnMut(&[f32], &mut [f64]),
    ) -> Result<BatchEstimate, GpuError> {
        let stream = self.flow.gpu.stream.clone();
        let s = self.flow.sample(n, seed)?;
        let x: Vec<f32> = stream.clone_dtoh(&s.x)?;
        let log_q: Vec<f64> = stream.clone_dtoh(&s.log_q)?;
        let mut values = vec![0.0f64; n];
        f(&x[..n * self.flow.dim()], &mut values);
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(GpuError::InvalidInput(format!(
                "the integrand is {} at point {i}",
                values[i]
            )));
        }
        let ratio: Vec<f64> = values
            .iter()
            .zip(&log_q)
            .map(|(v, l)| v * (-l).exp())
            .collect();
        let mean = ratio.iter().sum::<f64>() / n as f64;
        let variance =
            ratio.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n.max(2) - 1) as f64;
        let w = nis::loss::weights(self.loss, &values, &log_q, &log_q)
            .map_err(|e| GpuError::InvalidInput(e.to_string()))?;
        let w = stream.clone_htod(&w.w)?;
        let grad = self.flow.gradient(&s.x, &w, n)?;
        self.adam.step(&mut self.flow, &grad)?;
        Ok(BatchEstimate { mean, variance })
    }
}
