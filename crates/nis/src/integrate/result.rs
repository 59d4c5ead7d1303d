//! What an integration reports ([`IntegrationResult`], with [`ComponentEstimates`] for
//! vector-valued integrands) and the accumulators that pool a final phase's iterations into it.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::diagnostics::WeightTail;
use crate::comm::Comm;
use crate::error::{Error, Result};

/// The outcome of an integration, the same for every method.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct IntegrationResult {
    /// The estimate of ∫ f.
    pub value: f64,
    /// Its standard error.
    pub std_err: f64,
    /// χ² per degree of freedom of the final phase's iteration estimates around their mean (for
    /// NIS with training in the estimate, of the pooled training pieces too; docs/ESTIMATE.md).
    pub chi2_per_dof: f64,
    /// All evaluations of the integrand, training included.
    pub n_eval: u64,
    /// Var(f/q)/F² per evaluation of the estimate: n·std_err²/value², n the evaluations that make
    /// it (the final phase's, and the kept training batches' for NIS with training reused).
    pub rel_var_per_eval: f64,
    /// Unweighting efficiency mean(|w|)/max(|w|) of the final phase's weights.
    pub unweighting_efficiency: f64,
    /// PSIS's Pareto k̂ of the |w| tail of the weights that make the estimate: above [`PARETO_K_LIMIT`](super::PARETO_K_LIMIT) the error bar
    /// cannot be trusted (`NaN`, `null` in JSON, when it cannot be fitted). See
    /// [`diagnostics`](super::diagnostics).
    #[serde(default)]
    pub pareto_k: f64,
    /// Effective sample size (Σ|w|)²/Σw² of the weights that make the estimate.
    #[serde(default)]
    pub ess: f64,
    /// Relative error of the variance estimate behind `std_err` (√Var(s²)/s²).
    #[serde(default)]
    pub var_rel_err: f64,
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
            "result {:.8e} ± {:.3e}   χ²/dof {:.2}   k̂ {:.2}   ESS {:.3e}   n_eval {}   \
             rel.var/eval {:.3e}   unw.eff {:.4}   {:.2} s",
            self.value,
            self.std_err,
            self.chi2_per_dof,
            self.pareto_k,
            self.ess,
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

/// Accumulates the final phase: weights per iteration, pooled in order, and the reliability
/// figures of all its weights.
#[derive(Clone, Debug)]
pub struct Accumulator {
    /// The iterations so far.
    pub iterations: Vec<Iteration>,
    max_abs_w: f64,
    sum_abs_w: f64,
    n: u64,
    /// Evaluations of pieces added without their weights ([`Accumulator::add_piece`]).
    piece_evals: u64,
    tail: WeightTail,
}

impl Accumulator {
    /// For a final phase of about `planned` evaluations in all (sizes the PSIS tail it keeps).
    pub fn new(planned: u64) -> Accumulator {
        Accumulator {
            iterations: Vec::new(),
            max_abs_w: 0.0,
            sum_abs_w: 0.0,
            n: 0,
            piece_evals: 0,
            tail: WeightTail::new(planned),
        }
    }

    /// Adds one iteration of i.i.d. weights w_i = f_i/q_i; an error when their variance does
    /// not fit in an f64 (see [`Accumulator::add_iteration`]).
    pub fn add_weights(&mut self, w: &[f64]) -> Result<()> {
        let mut m = Moments::new(1);
        m.add(w);
        self.observe(w);
        self.add_moments(&m)
    }

    /// Feeds a chunk of an iteration's weights (component 0) to the reliability figures: with
    /// [`Accumulator::add_moments`] for iterations that arrive in chunks.
    pub fn observe(&mut self, w: &[f64]) {
        self.tail.add(w);
    }

    /// Adds one iteration of i.i.d. weights that arrived in chunks (component 0 of
    /// [`Moments`]; each chunk also [`observe`](Accumulator::observe)d): an iteration of any
    /// size in the memory of one chunk. An error when its variance does not fit in an f64.
    pub fn add_moments(&mut self, m: &Moments) -> Result<()> {
        let (mean, cov) = m.mean_and_cov_of_mean();
        check_representable(mean[0], cov[0], m.max_abs_w)?;
        self.iterations.push(Iteration {
            estimate: mean[0],
            variance: cov[0],
            evals: m.n,
        });
        self.max_abs_w = self.max_abs_w.max(m.max_abs_w);
        self.sum_abs_w += m.sum_abs_w;
        self.n += m.n;
        Ok(())
    }

    /// Adds one iteration with its own estimate and variance (e.g. stratified), and the weights
    /// (scaled so that their mean estimates the integral) for the unweighting efficiency and the
    /// reliability figures. An error when the estimate or its variance is not finite.
    pub fn add_iteration(&mut self, estimate: f64, variance: f64, w: &[f64]) -> Result<()> {
        check_representable(
            estimate,
            variance,
            w.iter().fold(0.0f64, |m, v| m.max(v.abs())),
        )?;
        self.iterations.push(Iteration {
            estimate,
            variance,
            evals: w.len() as u64,
        });
        for v in w {
            self.max_abs_w = self.max_abs_w.max(v.abs());
            self.sum_abs_w += v.abs();
        }
        self.n += w.len() as u64;
        self.tail.add(w);
        Ok(())
    }

    /// [`Accumulator::add_iteration`] for an iteration of `evals` evaluations over all ranks of
    /// `comm`, whose estimate and variance every rank knows already, this rank's weights being
    /// `w`: the largest |w| and Σ|w| are reduced over the ranks (the tail stays this rank's until
    /// [`Accumulator::reduce_tail`]). Every rank must call it together; with one process it is
    /// `add_iteration`.
    pub fn add_iteration_across(
        &mut self,
        comm: &Comm,
        estimate: f64,
        variance: f64,
        evals: u64,
        w: &[f64],
    ) -> Result<()> {
        if comm.size() == 1 {
            return self.add_iteration(estimate, variance, w);
        }
        let max = w.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let sum = w.iter().fold(0.0f64, |s, v| s + v.abs());
        self.add_observed_iteration(comm, estimate, variance, evals, max, sum)?;
        self.tail.add(w);
        Ok(())
    }

    /// Adds a piece of the estimate made elsewhere (e.g. pooled training batches) with its
    /// estimate, variance, evaluations and largest |w|: it counts in the estimate, χ² and the
    /// variance per evaluation, not in the unweighting efficiency (the final sampler's). Its
    /// weights reach the reliability figures through [`Accumulator::observe_tail`]. An error when
    /// the variance does not fit in an f64.
    pub fn add_piece(
        &mut self,
        estimate: f64,
        variance: f64,
        evals: u64,
        max_abs_w: f64,
    ) -> Result<()> {
        check_representable(estimate, variance, max_abs_w)?;
        self.iterations.push(Iteration {
            estimate,
            variance,
            evals,
        });
        self.piece_evals += evals;
        Ok(())
    }

    /// Adds the weights `tail` saw (this rank's) to the reliability figures.
    pub fn observe_tail(&mut self, tail: &WeightTail) {
        self.tail.merge(tail);
    }

    /// Adds one iteration of `evals` evaluations over all ranks of `comm` whose estimate and
    /// variance every rank knows already (e.g. stratified, drawn in chunks): this rank's weights
    /// for the reliability figures (for a stratified iteration, the sampler's own f/q) were
    /// [`observe`](Accumulator::observe)d chunk by chunk, and their largest |w| and Σ|w| are
    /// these; both are reduced over the ranks.
    /// Every rank must call it together. An error when the estimate or its variance is not finite.
    pub fn add_observed_iteration(
        &mut self,
        comm: &Comm,
        estimate: f64,
        variance: f64,
        evals: u64,
        max_abs_w: f64,
        sum_abs_w: f64,
    ) -> Result<()> {
        let mut max = [max_abs_w];
        comm.max_f64(&mut max);
        check_representable(estimate, variance, max[0])?;
        self.iterations.push(Iteration {
            estimate,
            variance,
            evals,
        });
        self.max_abs_w = self.max_abs_w.max(max[0]);
        self.sum_abs_w += comm.sum(sum_abs_w);
        self.n += evals;
        Ok(())
    }

    /// Makes the reliability figures those of every rank's weights: the ranks' tails are
    /// gathered and merged in rank order (see [`WeightTail::merge`]). Call it on every rank
    /// before [`Accumulator::finish`]; with one process it changes nothing.
    pub fn reduce_tail(&mut self, comm: &Comm) {
        if comm.size() == 1 {
            return;
        }
        let parts = comm.all_gather_bytes(f64s_to_bytes(&self.tail.to_words()));
        let mut all = self.tail.emptied();
        for p in parts {
            all.merge(&WeightTail::from_words(&bytes_to_f64s(&p)));
        }
        self.tail = all;
    }

    /// The final result. Iterations have (nearly) equal sizes, so their evaluation-weighted mean
    /// is the pooled mean — unbiased, unlike an inverse-variance weighting.
    pub fn finish(
        &self,
        n_eval: u64,
        started: Instant,
        warnings: Vec<String>,
    ) -> IntegrationResult {
        self.finish_with(None, n_eval, started, warnings)
    }

    /// The final result as Σ a_i·estimate_i with the given shares a_i (one per iteration, summing
    /// to one). Unbiased when each a_i was fixed before iteration i's points were drawn; the
    /// variance Σ a_i²·variance_i is then unbiased too (the iterations' errors are martingale
    /// differences). χ² uses each iteration's own variance, as the shares expect them to differ.
    pub fn finish_weighted(
        &self,
        shares: &[f64],
        n_eval: u64,
        started: Instant,
        warnings: Vec<String>,
    ) -> IntegrationResult {
        assert_eq!(
            shares.len(),
            self.iterations.len(),
            "one share per iteration"
        );
        self.finish_with(Some(shares), n_eval, started, warnings)
    }

    /// With `shares` None, the evaluation-weighted pooled mean.
    fn finish_with(
        &self,
        shares: Option<&[f64]>,
        n_eval: u64,
        started: Instant,
        warnings: Vec<String>,
    ) -> IntegrationResult {
        let total: f64 = self.iterations.iter().map(|i| i.evals as f64).sum();
        let own_variances = shares.is_some();
        let (value, var) = match shares {
            Some(a) => (
                self.iterations
                    .iter()
                    .zip(a)
                    .map(|(i, a)| i.estimate * a)
                    .sum::<f64>(),
                self.iterations
                    .iter()
                    .zip(a)
                    .map(|(i, a)| i.variance * a * a)
                    .sum::<f64>(),
            ),
            None => (
                self.iterations
                    .iter()
                    .map(|i| i.estimate * i.evals as f64)
                    .sum::<f64>()
                    / total,
                self.iterations
                    .iter()
                    .map(|i| i.variance * (i.evals as f64 / total).powi(2))
                    .sum::<f64>(),
            ),
        };
        let k = self.iterations.len();
        let chi2 = if k < 2 {
            f64::NAN
        } else if own_variances {
            if self.iterations.iter().all(|i| i.variance > 0.0) {
                self.iterations
                    .iter()
                    .map(|i| (i.estimate - value).powi(2) / i.variance)
                    .sum::<f64>()
                    / (k - 1) as f64
            } else {
                f64::NAN
            }
        } else {
            // χ² of the iteration estimates around their mean, against the variance an
            // iteration of its size has by the pooled estimate (iterations are of nearly equal
            // size). Dividing by each iteration's own variance estimate instead pulls χ² far
            // below 1 for heavy-tailed weights, whose large deviations come with large variance
            // estimates.
            //
            // Per-evaluation variance of each iteration (variance of its mean × its size),
            // averaged over the iterations weighted by their sizes.
            let mean_var_per_eval = self
                .iterations
                .iter()
                .map(|i| i.variance * (i.evals as f64).powi(2))
                .sum::<f64>()
                / total;
            if mean_var_per_eval > 0.0 {
                self.iterations
                    .iter()
                    .map(|i| (i.estimate - value).powi(2) * i.evals as f64 / mean_var_per_eval)
                    .sum::<f64>()
                    / (k - 1) as f64
            } else {
                f64::NAN
            }
        };
        let mut warnings = warnings;
        let zero = self.max_abs_w == 0.0;
        let mut reliability = self.tail.reliability();
        // Weights equal up to floating-point rounding (a constant integrand under a sampler
        // whose Jacobians round): their spread is noise, neither a tail nor a χ² to warn about.
        let rounding = var.sqrt() <= ROUNDING * value.abs();
        if rounding {
            reliability.pareto_k = f64::NAN;
        }
        if zero {
            warnings.push(
                "the integrand was zero at every sampled point: the estimate is 0 ± 0, which \
                 only says that no sample found where it is not zero"
                    .into(),
            );
        } else if chi2 > 3.0 && !rounding {
            warnings.push(format!(
                "χ²/dof = {chi2:.2} between iterations: the weights are heavy-tailed or the \
                 sampler misses part of the integrand; the error bar may be too small"
            ));
        }
        if let Some(w) = reliability.warning() {
            warnings.push(w);
        }
        IntegrationResult {
            value,
            std_err: var.sqrt(),
            chi2_per_dof: if zero { 0.0 } else { chi2 },
            n_eval,
            rel_var_per_eval: if zero {
                0.0
            } else {
                (self.n + self.piece_evals) as f64 * var / (value * value)
            },
            unweighting_efficiency: if zero {
                0.0
            } else {
                self.sum_abs_w / self.n as f64 / self.max_abs_w
            },
            pareto_k: reliability.pareto_k,
            ess: reliability.ess,
            var_rel_err: reliability.var_rel_err,
            seconds: started.elapsed().as_secs_f64(),
            warnings,
            iterations: self.iterations.clone(),
            components: None,
        }
    }
}

/// A relative standard error below which the weights differ only by rounding.
const ROUNDING: f64 = 1e-12;

/// An error when an iteration's estimate or variance is not finite, or its largest weight's square
/// leaves f64's normal range: such weights make variances that overflow, or underflow to a false
/// "± 0", whoever computed them.
fn check_representable(estimate: f64, variance: f64, max_abs_w: f64) -> Result<()> {
    let square = max_abs_w * max_abs_w;
    let representable = max_abs_w == 0.0 || square.is_normal();
    if estimate.is_finite() && variance.is_finite() && representable {
        return Ok(());
    }
    if representable {
        // Weights whose squares fit cannot make this: a defect of the estimator, named as such.
        return Err(Error::Config(format!(
            "an iteration's estimate {estimate:e} or its variance {variance:e} is not finite \
             although its weights f/q (up to {max_abs_w:.3e}) are representable: please report \
             this with the command that gave it"
        )));
    }
    Err(Error::Config(format!(
        "the weights f/q reach {max_abs_w:.3e}: the variance of their mean does not fit in an \
         f64 (squares beyond ~10^±308), so no error bar can be given; multiply the integrand by \
         a constant that brings its values nearer 1"
    )))
}

/// The moments of one iteration's i.i.d. weight vectors (`k` components), added chunk by chunk:
/// each chunk's mean and co-moments by two passes, merged into the running ones with the
/// pairwise update of Chan, Golub and LeVeque (1979), which keeps the accuracy of two passes
/// without holding the iteration. A single chunk gives the two-pass numbers exactly.
#[derive(Clone, Debug)]
pub struct Moments {
    k: usize,
    n: u64,
    mean: Vec<f64>,
    /// Σ (w_i − mean)(w_j − mean) over the weights so far, `k × k`.
    comoment: Vec<f64>,
    /// Σ |w| and max |w| of component 0 (for the unweighting efficiency).
    sum_abs_w: f64,
    max_abs_w: f64,
}

impl Moments {
    /// No weights yet, `k` components per weight.
    pub fn new(k: usize) -> Moments {
        Moments {
            k,
            n: 0,
            mean: vec![0.0; k],
            comoment: vec![0.0; k * k],
            sum_abs_w: 0.0,
            max_abs_w: 0.0,
        }
    }

    /// Weights so far.
    pub fn n(&self) -> u64 {
        self.n
    }

    /// Adds a chunk of weight vectors (`m × k`, row-major).
    pub fn add(&mut self, w: &[f64]) {
        let k = self.k;
        let m = w.len() / k;
        if m == 0 {
            return;
        }
        let mf = m as f64;
        let mut mean = vec![0.0; k];
        for row in w.chunks_exact(k) {
            for (a, v) in mean.iter_mut().zip(row) {
                *a += v;
            }
        }
        mean.iter_mut().for_each(|a| *a /= mf);
        let mut comoment = vec![0.0; k * k];
        for row in w.chunks_exact(k) {
            for i in 0..k {
                let di = row[i] - mean[i];
                for j in 0..k {
                    comoment[i * k + j] += di * (row[j] - mean[j]);
                }
            }
        }
        for row in w.chunks_exact(k) {
            self.sum_abs_w += row[0].abs();
            self.max_abs_w = self.max_abs_w.max(row[0].abs());
        }
        self.merge_central(m as u64, mean, comoment);
    }

    /// Merges the mean and co-moments of `nb` further weights (Chan, Golub and LeVeque).
    fn merge_central(&mut self, nb: u64, mean: Vec<f64>, comoment: Vec<f64>) {
        let k = self.k;
        if nb == 0 {
            return;
        }
        if self.n == 0 {
            (self.mean, self.comoment, self.n) = (mean, comoment, nb);
            return;
        }
        let (na, nb_f) = (self.n as f64, nb as f64);
        let n = na + nb_f;
        let delta: Vec<f64> = mean.iter().zip(&self.mean).map(|(b, a)| b - a).collect();
        for i in 0..k {
            for j in 0..k {
                self.comoment[i * k + j] +=
                    comoment[i * k + j] + delta[i] * delta[j] * na * nb_f / n;
            }
        }
        for (a, d) in self.mean.iter_mut().zip(&delta) {
            *a += d * nb_f / n;
        }
        self.n += nb;
    }

    /// Adds the weights `later` holds (after these): the pairwise merge of their moments.
    pub fn merge(&mut self, later: &Moments) {
        assert_eq!(self.k, later.k, "moments of as many components");
        self.sum_abs_w += later.sum_abs_w;
        self.max_abs_w = self.max_abs_w.max(later.max_abs_w);
        self.merge_central(later.n, later.mean.clone(), later.comoment.clone());
    }

    /// The moments of every rank's weights of `comm`, merged in rank order (this rank's being
    /// these), on every rank. Every rank must call it together; with one process, a copy.
    pub fn across(&self, comm: &Comm) -> Moments {
        Moments::across_each(std::slice::from_ref(self), comm)
            .pop()
            .expect("one")
    }

    /// [`Moments::across`] for many moments at once, in one gather (e.g. one per hypercube of a
    /// stratified iteration): each merged over the ranks in rank order. All must have the same
    /// number of components, and every rank must pass as many.
    pub(crate) fn across_each(parts: &[Moments], comm: &Comm) -> Vec<Moments> {
        if comm.size() == 1 {
            return parts.to_vec();
        }
        let k = parts.first().map_or(1, |m| m.k);
        let stride = 3 + k + k * k;
        let mut words = Vec::with_capacity(parts.len() * stride);
        for m in parts {
            assert_eq!(m.k, k, "moments of as many components");
            words.extend_from_slice(&[m.n as f64, m.sum_abs_w, m.max_abs_w]);
            words.extend_from_slice(&m.mean);
            words.extend_from_slice(&m.comoment);
        }
        let mut all = vec![Moments::new(k); parts.len()];
        for part in comm.all_gather_bytes(f64s_to_bytes(&words)) {
            for (a, w) in all
                .iter_mut()
                .zip(bytes_to_f64s(&part).chunks_exact(stride))
            {
                a.merge(&Moments {
                    k,
                    n: w[0] as u64,
                    sum_abs_w: w[1],
                    max_abs_w: w[2],
                    mean: w[3..3 + k].to_vec(),
                    comoment: w[3 + k..].to_vec(),
                });
            }
        }
        all
    }

    /// The mean and the covariance of the mean (`k × k`; zero for fewer than two weights).
    pub fn mean_and_cov_of_mean(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n as f64;
        let cov = if self.n > 1 {
            self.comoment.iter().map(|c| c / (n - 1.0) / n).collect()
        } else {
            vec![0.0; self.k * self.k]
        };
        (self.mean.clone(), cov)
    }
}

/// Numbers as little-endian bytes, to cross processes.
pub(crate) fn f64s_to_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The numbers [`f64s_to_bytes`] made.
pub(crate) fn bytes_to_f64s(b: &[u8]) -> Vec<f64> {
    b.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect()
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

    /// Adds one iteration of weight vectors that arrived in chunks.
    pub(crate) fn add_moments(&mut self, m: &Moments) {
        let (mean, cov) = m.mean_and_cov_of_mean();
        self.iterations.push((mean, cov, m.n));
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

    /// Σ a_i·mean_i and Σ a_i²·Cov_i with the given shares (see [`Accumulator::finish_weighted`]).
    pub(crate) fn finish_weighted(&self, shares: &[f64]) -> ComponentEstimates {
        let k = self.k;
        let mut mean = vec![0.0; k];
        let mut cov = vec![0.0; k * k];
        for ((m, c, _), share) in self.iterations.iter().zip(shares) {
            for j in 0..k {
                mean[j] += m[j] * share;
            }
            for (a, b) in cov.iter_mut().zip(c) {
                *a += b * share.powi(2);
            }
        }
        let std_err = (0..k).map(|j| cov[j * k + j].sqrt()).collect();
        ComponentEstimates { mean, std_err, cov }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn chunked_moments_equal_the_two_pass_ones() {
        // Weights with a large offset and a spread of 1e-3: a one-pass sum of squares would lose
        // about half the digits here; the merged two-pass moments keep them.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let k = 2;
        let w: Vec<f64> = (0..3001 * k)
            .map(|i| 1e4 * (1 + i % k) as f64 + 1e-3 * rng.random::<f64>())
            .collect();
        let mut whole = Moments::new(k);
        whole.add(&w);
        for chunk in [1, 7, 1000, 4096] {
            let mut parts = Moments::new(k);
            for c in w.chunks(chunk * k) {
                parts.add(c);
            }
            let ((m1, c1), (m2, c2)) = (whole.mean_and_cov_of_mean(), parts.mean_and_cov_of_mean());
            assert_eq!(parts.n(), 3001);
            for (a, b) in m1.iter().zip(&m2) {
                assert!(
                    (a - b).abs() <= 1e-12 * a.abs(),
                    "chunk {chunk}: mean {a} vs {b}"
                );
            }
            for (a, b) in c1.iter().zip(&c2) {
                assert!(
                    (a - b).abs() <= 1e-8 * c1[0].abs(),
                    "chunk {chunk}: cov {a} vs {b}"
                );
            }
        }
        // The variance of the mean of the uniform spread: (1e-3)²/12/n, to 10% (n = 3001).
        let var = whole.mean_and_cov_of_mean().1[0];
        assert!((var / (1e-6 / 12.0 / 3001.0) - 1.0).abs() < 0.1, "{var}");
    }

    #[test]
    fn moments_merged_from_parts_equal_the_two_pass_ones() {
        // What `Moments::across` does with the ranks' parts, in rank order: the pooled mean and
        // covariance of all the weights, to the accuracy of the chunked ones above.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(12);
        let k = 2;
        let w: Vec<f64> = (0..2999 * k)
            .map(|i| 1e4 * (1 + i % k) as f64 + 1e-3 * rng.random::<f64>())
            .collect();
        let mut whole = Moments::new(k);
        whole.add(&w);
        let mut merged = Moments::new(k);
        for part in [
            &w[..2 * k],
            &w[2 * k..2 * k],
            &w[2 * k..1000 * k],
            &w[1000 * k..],
        ] {
            let mut m = Moments::new(k);
            m.add(part);
            merged.merge(&m);
        }
        assert_eq!(merged.n(), 2999);
        assert_eq!(
            merged.sum_abs_w.to_bits(),
            {
                let mut s = 0.0;
                for part in [&w[..2 * k], &w[2 * k..1000 * k], &w[1000 * k..]] {
                    s += part.iter().step_by(k).map(|v| v.abs()).sum::<f64>();
                }
                s
            }
            .to_bits()
        );
        assert_eq!(merged.max_abs_w, whole.max_abs_w);
        let ((m1, c1), (m2, c2)) = (whole.mean_and_cov_of_mean(), merged.mean_and_cov_of_mean());
        for (a, b) in m1.iter().zip(&m2) {
            assert!((a - b).abs() <= 1e-12 * a.abs(), "mean {a} vs {b}");
        }
        for (a, b) in c1.iter().zip(&c2) {
            assert!((a - b).abs() <= 1e-8 * c1[0].abs(), "cov {a} vs {b}");
        }
        // One process: `across` is the identity, bit for bit.
        let same = whole.across(&Comm::default());
        assert_eq!(same.mean_and_cov_of_mean(), whole.mean_and_cov_of_mean());
    }

    #[test]
    fn chi2_per_dof_of_iid_iterations_averages_one() {
        // 200 runs of 10 iterations × 1000 uniform weights: χ²/dof has 9 degrees of freedom,
        // σ = √(2/9) = 0.47 per run, so the mean over 200 runs is 1 ± 0.033; 3.5σ allowed.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let started = Instant::now();
        let mut sum = 0.0;
        for _ in 0..200 {
            let mut acc = Accumulator::new(10_000);
            for _ in 0..10 {
                let w: Vec<f64> = (0..1000).map(|_| rng.random::<f64>()).collect();
                acc.add_weights(&w).unwrap();
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
