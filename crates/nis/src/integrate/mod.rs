//! Integration: the [`Integrand`] interface, the estimators behind one result type —
//! neural importance sampling ([`nis::NisIntegrator`]), VEGAS+ ([`vegas::Vegas`]) and plain Monte
//! Carlo ([`uniform`]) — and the statistics they share.
//!
//! Every method has an adaptive phase whose evaluations only teach the sampler, and a final phase
//! with the sampler frozen whose evaluations alone make the estimate: the result is then an
//! unbiased mean of i.i.d. (or stratified) weights, and its error bar is the honest standard
//! error of that mean. The final phase is split into iterations whose spread gives χ²/dof.

pub mod nis;
pub mod uniform;
pub mod unweight;
pub mod vegas;

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A function to integrate over [0, 1]^d, evaluated in batches.
///
/// Closures `Fn(&[f64]) -> f64 + Sync` are integrands (evaluated in parallel):
/// ```
/// use nis::integrate::Integrand;
/// let f = |x: &[f64]| x[0] * x[1];
/// let mut out = [0.0; 2];
/// f.eval_batch(&[0.5, 0.5, 1.0, 0.25], 2, &mut out);
/// assert_eq!(out, [0.25, 0.25]);
/// ```
pub trait Integrand: Sync {
    /// Writes f at each of the `out.len()` points of `x` (row-major, `dim` coordinates each).
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]);
    /// The dimension this integrand is defined in, if it has a fixed one.
    fn dim(&self) -> Option<usize> {
        None
    }
}

impl<F: Fn(&[f64]) -> f64 + Sync> Integrand for F {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) {
        // Fixed-size chunks: each value is computed independently, so the split only affects speed.
        out.par_chunks_mut(256)
            .zip(x.par_chunks(256 * dim))
            .for_each(|(out, x)| {
                for (o, p) in out.iter_mut().zip(x.chunks_exact(dim)) {
                    *o = self(p);
                }
            });
    }
}

/// Evaluates `f` at `x`, rejecting NaN and ±∞ with an error that names the point.
pub fn evaluate(f: &dyn Integrand, x: &[f64], dim: usize) -> Result<Vec<f64>> {
    let mut out = vec![0.0; x.len() / dim];
    f.eval_batch(x, dim, &mut out);
    if let Some(i) = out.iter().position(|v| !v.is_finite()) {
        return Err(Error::Integrand {
            point: x[i * dim..(i + 1) * dim].to_vec(),
            value: out[i],
        });
    }
    Ok(out)
}

/// Checks an integrand's declared dimension against the one asked for.
pub fn check_dim(f: &dyn Integrand, dim: usize) -> Result<()> {
    if dim == 0 {
        return Err(Error::Config("dimension must be at least 1".into()));
    }
    match f.dim() {
        Some(d) if d != dim => Err(Error::Dimension {
            what: "integrand dimension",
            expected: d,
            got: dim,
        }),
        _ => Ok(()),
    }
}

/// The outcome of an integration, the same for every method.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct IntegrationResult {
    /// The estimate of ∫ f.
    pub value: f64,
    /// Its standard error.
    pub std_err: f64,
    /// χ² per degree of freedom of the final phase's iteration estimates around their mean.
    pub chi2_per_dof: f64,
    /// All evaluations of the integrand, training included.
    pub n_eval: u64,
    /// Var(f/q)/F² per evaluation of the final phase: n_final·std_err²/value².
    pub rel_var_per_eval: f64,
    /// Unweighting efficiency mean(|w|)/max(|w|) of the final phase's weights.
    pub unweighting_efficiency: f64,
    /// Wall time.
    pub seconds: f64,
    /// Things the user should know (not part of the JSON summary).
    #[serde(skip)]
    pub warnings: Vec<String>,
}

/// Accumulates the final phase: weights per iteration, pooled in order.
#[derive(Clone, Debug, Default)]
pub struct Accumulator {
    /// (estimate, variance of that estimate, evaluations) per iteration.
    pub iterations: Vec<(f64, f64, u64)>,
    max_abs_w: f64,
    sum_abs_w: f64,
    n: u64,
}

impl Accumulator {
    /// Adds one iteration of i.i.d. weights w_i = f_i/q_i.
    pub fn add_weights(&mut self, w: &[f64]) {
        let n = w.len() as f64;
        let mean = w.iter().sum::<f64>() / n;
        let var = if w.len() > 1 {
            w.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n
        } else {
            0.0
        };
        self.add_iteration(mean, var, w);
    }

    /// Adds one iteration with its own estimate and variance (e.g. stratified), and the weights
    /// (scaled so that their mean estimates the integral) for the unweighting efficiency.
    pub fn add_iteration(&mut self, estimate: f64, variance: f64, w: &[f64]) {
        self.iterations.push((estimate, variance, w.len() as u64));
        for v in w {
            self.max_abs_w = self.max_abs_w.max(v.abs());
            self.sum_abs_w += v.abs();
        }
        self.n += w.len() as u64;
    }

    /// The final result. Iterations have (nearly) equal sizes, so their evaluation-weighted mean
    /// is the pooled mean — unbiased, unlike an inverse-variance weighting.
    pub fn finish(
        &self,
        n_eval: u64,
        started: Instant,
        warnings: Vec<String>,
    ) -> IntegrationResult {
        let total: f64 = self.iterations.iter().map(|i| i.2 as f64).sum();
        let value = self
            .iterations
            .iter()
            .map(|i| i.0 * i.2 as f64)
            .sum::<f64>()
            / total;
        let var: f64 = self
            .iterations
            .iter()
            .map(|i| i.1 * (i.2 as f64 / total).powi(2))
            .sum();
        // χ² of the iteration estimates around their mean, against the variance an iteration of
        // its size has by the pooled estimate (iterations are of nearly equal size). Dividing by
        // each iteration's own variance estimate instead pulls χ² far below 1 for heavy-tailed
        // weights, whose large deviations come with large variance estimates.
        let k = self.iterations.len();
        // Per-evaluation variance of each iteration (variance of its mean × its size), averaged
        // over the iterations weighted by their sizes.
        let mean_var_per_eval = self
            .iterations
            .iter()
            .map(|i| i.1 * (i.2 as f64).powi(2))
            .sum::<f64>()
            / total;
        let chi2 = if k > 1 && mean_var_per_eval > 0.0 {
            self.iterations
                .iter()
                .map(|i| (i.0 - value).powi(2) * i.2 as f64 / mean_var_per_eval)
                .sum::<f64>()
                / (k - 1) as f64
        } else {
            f64::NAN
        };
        let mut warnings = warnings;
        let zero = self.max_abs_w == 0.0;
        if zero {
            warnings.push(
                "the integrand was zero at every sampled point: the estimate is 0 ± 0, which \
                 only says that no sample found where it is not zero"
                    .into(),
            );
        } else if chi2 > 3.0 {
            warnings.push(format!(
                "χ²/dof = {chi2:.2} between iterations: the weights are heavy-tailed or the \
                 sampler misses part of the integrand; the error bar may be too small"
            ));
        }
        IntegrationResult {
            value,
            std_err: var.sqrt(),
            chi2_per_dof: if zero { 0.0 } else { chi2 },
            n_eval,
            rel_var_per_eval: if zero {
                0.0
            } else {
                self.n as f64 * var / (value * value)
            },
            unweighting_efficiency: if zero {
                0.0
            } else {
                self.sum_abs_w / self.n as f64 / self.max_abs_w
            },
            seconds: started.elapsed().as_secs_f64(),
            warnings,
        }
    }
}

/// Reports progress: evaluations done so far, evaluations planned, and a short status.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64, &str);

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn chi2_per_dof_of_iid_iterations_averages_one() {
        // 200 runs of 10 iterations × 1000 uniform weights: χ²/dof has 9 degrees of freedom,
        // σ = √(2/9) = 0.47 per run, so the mean over 200 runs is 1 ± 0.033; 3.5σ allowed.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let started = Instant::now();
        let mut sum = 0.0;
        for _ in 0..200 {
            let mut acc = Accumulator::default();
            for _ in 0..10 {
                let w: Vec<f64> = (0..1000).map(|_| rng.random::<f64>()).collect();
                acc.add_weights(&w);
            }
            let r = acc.finish(10_000, started, Vec::new());
            assert!((r.value - 0.5).abs() < 5.0 * r.std_err);
            // Var(U)/E[U]² = (1/12)/(1/4) = 1/3 per evaluation.
            assert!((r.rel_var_per_eval - 1.0 / 3.0).abs() < 0.03);
            sum += r.chi2_per_dof;
        }
        let mean = sum / 200.0;
        assert!((mean - 1.0).abs() < 0.12, "mean χ²/dof {mean}");
    }
}
