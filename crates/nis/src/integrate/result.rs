//! What an integration reports ([`IntegrationResult`], with [`ComponentEstimates`] for
//! vector-valued integrands) and the accumulators that pool a final phase's iterations into it.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::comm::Comm;

/// The outcome of an integration, the same for every method.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
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
    /// The final phase's iterations of component 0 (not part of the JSON summary).
    #[serde(skip)]
    pub iterations: Vec<Iteration>,
    /// Every component's estimate, for integrands with more than one component (`None` for
    /// scalar integrands, whose one component is `value` ± `std_err`; see
    /// [`IntegrationResult::estimates`] for a view that covers both).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub components: Option<ComponentEstimates>,
}

/// Combined standard errors by which two estimates of one integral may differ before
/// [`disagreements`] reports them: at 5σ an honest pair disagrees once in ~1.7 million.
pub const DISAGREEMENT_SIGMAS: f64 = 5.0;

/// The pairs of `results` (labelled estimates of the same integral) that differ by more than
/// `sigmas` combined standard errors, |a − b| > sigmas·√(σ_a² + σ_b²), each as a sentence: one of
/// the two has missed part of the integrand, or its error bar is too small.
///
/// ```
/// use nis::integrate::{disagreements, IntegrationResult};
/// let r = |value: f64, std_err: f64| IntegrationResult { value, std_err, ..Default::default() };
/// let (a, b, c) = (r(1.0, 0.01), r(1.02, 0.01), r(0.5, 0.001));
/// let found = disagreements(&[("nis", &a), ("vegas+", &b), ("uniform", &c)], 5.0);
/// assert_eq!(found.len(), 2); // c disagrees with both; a and b agree (1.4σ)
/// assert!(found[0].contains("nis") && found[0].contains("uniform"));
/// ```
pub fn disagreements(results: &[(&str, &IntegrationResult)], sigmas: f64) -> Vec<String> {
    let mut out = Vec::new();
    for (i, (la, a)) in results.iter().enumerate() {
        for (lb, b) in &results[i + 1..] {
            let combined = a.std_err.hypot(b.std_err);
            let apart = (a.value - b.value).abs();
            if apart > sigmas * combined || (combined == 0.0 && apart > 0.0) {
                out.push(format!(
                    "{la} ({:.6e} ± {:.1e}) and {lb} ({:.6e} ± {:.1e}) disagree by {:.1} combined \
                     standard errors: one of them has missed part of the integrand or \
                     underestimates its error",
                    a.value,
                    a.std_err,
                    b.value,
                    b.std_err,
                    apart / combined
                ));
            }
        }
    }
    out
}

impl IntegrationResult {
    /// Every component's mean, standard error and covariance, also for a scalar integrand (then
    /// one component: `value`, `std_err`, `std_err²`): what `r.mean`, `r.sdev` and `r.cov` of the
    /// `vegas` package hold.
    pub fn estimates(&self) -> ComponentEstimates {
        self.components
            .clone()
            .unwrap_or_else(|| ComponentEstimates {
                mean: vec![self.value],
                std_err: vec![self.std_err],
                cov: vec![self.std_err * self.std_err],
            })
    }
}

/// A readable summary, as `vegas`'s `result.summary()`: the final phase's iterations, the result,
/// and every component of a vector-valued integrand.
impl std::fmt::Display for IntegrationResult {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:>5}  {:>24}  {:>10}",
            "itn", "estimate ± std_err", "evals"
        )?;
        for (i, it) in self.iterations.iter().enumerate() {
            writeln!(
                f,
                "{:>5}  {:>12.6e} ± {:<9.2e}  {:>10}",
                i + 1,
                it.estimate,
                it.variance.sqrt(),
                it.evals
            )?;
        }
        write!(
            f,
            "result {:.8e} ± {:.3e}   χ²/dof {:.2}   n_eval {}   rel.var/eval {:.3e}   unw.eff {:.4}   {:.2} s",
            self.value,
            self.std_err,
            self.chi2_per_dof,
            self.n_eval,
            self.rel_var_per_eval,
            self.unweighting_efficiency,
            self.seconds
        )?;
        if let Some(c) = &self.components {
            for (j, (m, e)) in c.mean.iter().zip(&c.std_err).enumerate() {
                write!(f, "\ncomponent {j}: {m:.8e} ± {e:.3e}")?;
            }
        }
        Ok(())
    }
}

/// Estimates of all k components of a vector-valued integrand, from the same points.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ComponentEstimates {
    /// The estimate of ∫ f_j, per component j.
    pub mean: Vec<f64>,
    /// Its standard error, per component (the square root of `cov`'s diagonal).
    pub std_err: Vec<f64>,
    /// The k × k covariance of the estimates, row-major: `cov[i * k + j]` = Cov(mean_i, mean_j).
    pub cov: Vec<f64>,
}

/// One iteration of a final phase.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Iteration {
    /// The iteration's estimate of the integral.
    pub estimate: f64,
    /// The variance of that estimate.
    pub variance: f64,
    /// Its evaluations of the integrand.
    pub evals: u64,
}

/// Accumulates the final phase: weights per iteration, pooled in order.
#[derive(Clone, Debug, Default)]
pub struct Accumulator {
    /// The iterations so far.
    pub iterations: Vec<Iteration>,
    max_abs_w: f64,
    sum_abs_w: f64,
    n: u64,
}

impl Accumulator {
    /// Adds one iteration of i.i.d. weights w_i = f_i/q_i.
    pub fn add_weights(&mut self, w: &[f64]) {
        self.add_weights_across(&Comm::default(), w);
    }

    /// Adds one iteration of i.i.d. weights drawn by all ranks of `comm`, this rank's share
    /// being `w` (possibly empty): the count, the sum and then the squared deviations from the
    /// pooled mean are reduced over the ranks, so the iteration is the one all weights together
    /// make. Every rank must call it together.
    pub fn add_weights_across(&mut self, comm: &Comm, w: &[f64]) {
        let mut sums = [w.len() as f64, w.iter().sum::<f64>()];
        comm.sum_f64(&mut sums);
        let [n, sum] = sums;
        let mean = sum / n;
        let var = if n > 1.0 {
            comm.sum(w.iter().map(|v| (v - mean).powi(2)).sum::<f64>()) / (n - 1.0) / n
        } else {
            0.0
        };
        self.add_iteration_across(comm, mean, var, n as u64, w);
    }

    /// Adds one iteration with its own estimate and variance (e.g. stratified), and the weights
    /// (scaled so that their mean estimates the integral) for the unweighting efficiency.
    pub fn add_iteration(&mut self, estimate: f64, variance: f64, w: &[f64]) {
        self.add_iteration_across(&Comm::default(), estimate, variance, w.len() as u64, w);
    }

    /// [`Accumulator::add_iteration`] for an iteration of `evals` evaluations over all ranks of
    /// `comm`, whose estimate and variance every rank knows already, this rank's weights being
    /// `w`. Every rank must call it together.
    pub fn add_iteration_across(
        &mut self,
        comm: &Comm,
        estimate: f64,
        variance: f64,
        evals: u64,
        w: &[f64],
    ) {
        self.iterations.push(Iteration {
            estimate,
            variance,
            evals,
        });
        let mut max = [w.iter().fold(self.max_abs_w, |m, v| m.max(v.abs()))];
        comm.max_f64(&mut max);
        self.max_abs_w = max[0];
        // Rank 0 carries the running sum, so one process adds exactly as it always did.
        let start = if comm.is_root() { self.sum_abs_w } else { 0.0 };
        self.sum_abs_w = comm.sum(w.iter().fold(start, |s, v| s + v.abs()));
        self.n += evals;
    }

    /// The final result. Iterations have (nearly) equal sizes, so their evaluation-weighted mean
    /// is the pooled mean — unbiased, unlike an inverse-variance weighting.
    pub fn finish(
        &self,
        n_eval: u64,
        started: Instant,
        warnings: Vec<String>,
    ) -> IntegrationResult {
        let total: f64 = self.iterations.iter().map(|i| i.evals as f64).sum();
        let value = self
            .iterations
            .iter()
            .map(|i| i.estimate * i.evals as f64)
            .sum::<f64>()
            / total;
        let var: f64 = self
            .iterations
            .iter()
            .map(|i| i.variance * (i.evals as f64 / total).powi(2))
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
            .map(|i| i.variance * (i.evals as f64).powi(2))
            .sum::<f64>()
            / total;
        let chi2 = if k > 1 && mean_var_per_eval > 0.0 {
            self.iterations
                .iter()
                .map(|i| (i.estimate - value).powi(2) * i.evals as f64 / mean_var_per_eval)
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
            iterations: self.iterations.clone(),
            components: None,
        }
    }
}

/// Accumulates the final phase of a vector-valued integrand: per iteration the mean vector and
/// the covariance of that mean, pooled like [`Accumulator`] pools a scalar.
#[derive(Clone, Debug)]
pub(crate) struct ComponentAccumulator {
    k: usize,
    /// (mean, covariance of the mean (k × k), evaluations) per iteration.
    iterations: Vec<(Vec<f64>, Vec<f64>, u64)>,
}

impl ComponentAccumulator {
    /// An empty accumulator for `k` components.
    pub(crate) fn new(k: usize) -> ComponentAccumulator {
        ComponentAccumulator {
            k,
            iterations: Vec::new(),
        }
    }

    /// Adds one iteration of i.i.d. weight vectors (`n × k`, row-major) drawn by all ranks of
    /// `comm`, this rank's share being `w`: sums, then the products of deviations from the pooled
    /// means, are reduced over the ranks. Every rank must call it together.
    pub(crate) fn add_weights_across(&mut self, comm: &Comm, w: &[f64]) {
        let k = self.k;
        let mut mean = vec![0.0; k + 1];
        for row in w.chunks_exact(k) {
            for (m, v) in mean.iter_mut().zip(row) {
                *m += v;
            }
        }
        mean[k] = (w.len() / k) as f64;
        comm.sum_f64(&mut mean);
        let nf = mean.pop().unwrap_or(0.0);
        let n = nf as usize;
        mean.iter_mut().for_each(|m| *m /= nf);
        let mut cov = vec![0.0; k * k];
        if n > 1 {
            for row in w.chunks_exact(k) {
                for i in 0..k {
                    let di = row[i] - mean[i];
                    for j in 0..k {
                        cov[i * k + j] += di * (row[j] - mean[j]);
                    }
                }
            }
            comm.sum_f64(&mut cov);
            cov.iter_mut().for_each(|c| *c = *c / (nf - 1.0) / nf);
        }
        self.iterations.push((mean, cov, n as u64));
    }

    /// Adds one iteration with its own estimate and covariance (e.g. stratified).
    pub(crate) fn add_iteration(&mut self, mean: Vec<f64>, cov: Vec<f64>, evals: u64) {
        self.iterations.push((mean, cov, evals));
    }

    /// The pooled estimates: the evaluation-weighted mean of the iterations and its covariance.
    pub(crate) fn finish(&self) -> ComponentEstimates {
        let k = self.k;
        let total: f64 = self.iterations.iter().map(|i| i.2 as f64).sum();
        let mut mean = vec![0.0; k];
        let mut cov = vec![0.0; k * k];
        for (m, c, n) in &self.iterations {
            let share = *n as f64 / total;
            for j in 0..k {
                mean[j] += m[j] * *n as f64;
            }
            for (a, b) in cov.iter_mut().zip(c) {
                *a += b * share.powi(2);
            }
        }
        mean.iter_mut().for_each(|m| *m /= total);
        let std_err = (0..k).map(|j| cov[j * k + j].sqrt()).collect();
        ComponentEstimates { mean, std_err, cov }
    }
}

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
