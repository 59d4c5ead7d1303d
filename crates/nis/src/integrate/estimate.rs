//! Pools an estimate's iterations into its result: each [`Iteration`] is added one way
//! ([`Accumulator::add`]), its weights seen by the reliability figures as they are drawn
//! ([`Accumulator::observe`]), and [`Accumulator::finish`] pools them, by their evaluations or by
//! shares fixed before each was drawn (docs/ESTIMATE.md), with χ²/dof and the warnings.

use std::time::Instant;

use super::convergence::Convergence;
use super::diagnostics::{WeightTail, ADVICE_MORE};
use super::integrand::column;
use super::moments::{bytes_to_f64s, f64s_to_bytes, Moments, CHUNK};
use super::result::{ComponentEstimates, IntegrationResult, Iteration, Source};
use crate::comm::Comm;
use crate::error::{Error, Result};

/// Accumulates an estimate's iterations, in order, and the reliability figures of their weights.
#[derive(Clone, Debug)]
pub struct Accumulator {
    iterations: Vec<Iteration>,
    /// This rank's weights (component 0) of every iteration, for k̂, ESS and var_rel_err.
    tail: WeightTail,
    /// The variance per evaluation of every training batch, in order (NIS), for [`Convergence`].
    training_var: Vec<f64>,
    /// Whether the sampler was learned from the integrand: only then can a large divergence
    /// mean mass the sampler never found (for plain MC it is the integrand's own peakedness).
    learned: bool,
    /// Whether the iterations all come from one frozen sampler, also when pooled by shares (a
    /// run to a target): χ² then compares them with the variance per evaluation they share.
    frozen: bool,
}

impl Accumulator {
    /// For an estimate of about `planned` evaluations in all (sizes the PSIS tail it keeps).
    pub fn new(planned: u64) -> Accumulator {
        Accumulator {
            iterations: Vec::new(),
            tail: WeightTail::new(planned),
            training_var: Vec::new(),
            learned: true,
            frozen: false,
        }
    }

    /// [`Accumulator::new`] for a sampler that was not learned from the integrand (plain MC):
    /// its result reports the convergence figures without the divergence warning.
    pub fn for_fixed_sampler(planned: u64) -> Accumulator {
        Accumulator {
            learned: false,
            ..Accumulator::new(planned)
        }
    }

    /// Marks the iterations as drawn from one frozen sampler (see the field `frozen`).
    pub(crate) fn set_frozen_sampler(&mut self) {
        self.frozen = true;
    }

    /// The iterations so far.
    pub fn iterations(&self) -> &[Iteration] {
        &self.iterations
    }

    /// Adds one iteration. An error when its estimate or variance is not finite, or its weights'
    /// squares leave f64's range.
    pub fn add(&mut self, iteration: Iteration) -> Result<()> {
        check_representable(iteration.estimate, iteration.variance, iteration.max_abs_w)?;
        self.iterations.push(iteration);
        Ok(())
    }

    /// Feeds this rank's weights (component 0, as the sampler gives them) to the reliability
    /// figures, chunk by chunk as an iteration draws them.
    pub fn observe(&mut self, w: &[f64]) {
        self.tail.add(w);
    }

    /// The divergence n/ESS − 1 of every rank's weights so far (`None` before any, or for
    /// weights all zero): what [`Accumulator::finish`] will report if the weights to come look
    /// alike, for a run that must decide before it ends (the same on every rank).
    pub fn divergence_so_far(&self, comm: &Comm) -> Option<f64> {
        let mut s = self.tail.sums();
        comm.sum_f64(&mut s);
        let [n, sum_abs, sum_sq] = s;
        (sum_abs > 0.0).then(|| n * sum_sq / (sum_abs * sum_abs) - 1.0)
    }

    /// Adds the weights another tail saw (this rank's, e.g. of training batches) to the
    /// reliability figures.
    pub fn observe_tail(&mut self, tail: &WeightTail) {
        self.tail.merge(tail);
    }

    /// Sets the variance per evaluation of every training batch, in order, for the convergence
    /// figures.
    pub fn set_training_variances(&mut self, var: Vec<f64>) {
        self.training_var = var;
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

    /// The result of `n_eval` evaluations in all, started at `started`. With `shares` None, the
    /// iterations are pooled by their evaluations (they have nearly equal sizes: the pooled mean,
    /// unbiased unlike an inverse-variance weighting); with shares a_i (one per iteration,
    /// summing to one) the estimate is Σ a_i·estimate_i with variance Σ a_i²·variance_i, unbiased
    /// when each a_i was fixed before iteration i's points were drawn (the iterations' errors are
    /// martingale differences), and χ² uses each iteration's own variance.
    pub fn finish(
        &self,
        shares: Option<&[f64]>,
        n_eval: u64,
        started: Instant,
    ) -> IntegrationResult {
        if let Some(a) = shares {
            assert_eq!(a.len(), self.iterations.len(), "one share per iteration");
        }
        let (value, var) = self.pooled(shares);
        let chi2 = chi2_per_dof(&self.iterations, value, shares.is_some() && !self.frozen);
        let finals = || self.iterations.iter().filter(|i| i.source == Source::Final);
        let max_abs_w = finals().fold(0.0f64, |m, i| m.max(i.max_abs_w));
        let sum_abs_w: f64 = finals().map(|i| i.sum_abs_w).sum();
        let final_evals: u64 = finals().map(|i| i.evals).sum();
        let all_evals: u64 = self.iterations.iter().map(|i| i.evals).sum();
        let zero = max_abs_w == 0.0;
        let mut reliability = self.tail.reliability();
        // Weights equal up to floating-point rounding (a constant integrand under a sampler
        // whose Jacobians round): their spread is noise, neither a tail nor a χ² to warn about.
        let rounding = var.sqrt() <= ROUNDING * value.abs();
        if rounding {
            reliability.pareto_k = f64::NAN;
        }
        let mut warnings = Vec::new();
        if zero {
            warnings.push(
                "the integrand was zero at every sampled point: the estimate is 0 ± 0, which \
                 only says that no sample found where it is not zero"
                    .into(),
            );
        } else if chi2 > CHI2_LIMIT && !rounding {
            warnings.push(chi2_warning(chi2));
        }
        if let Some(w) = reliability.warning() {
            warnings.push(w);
        }
        let mut convergence = Convergence::of(&self.iterations, &self.training_var);
        convergence.divergence =
            (reliability.ess > 0.0).then(|| self.tail.count() as f64 / reliability.ess - 1.0);
        if !zero && !rounding && self.learned {
            warnings.extend(convergence.warnings().into_iter().map(|w| w.sentence));
        }
        IntegrationResult {
            value,
            std_err: var.sqrt(),
            chi2_per_dof: if zero { 0.0 } else { chi2 },
            n_eval,
            rel_var_per_eval: if zero {
                0.0
            } else {
                all_evals as f64 * var / (value * value)
            },
            unweighting_efficiency: if zero {
                0.0
            } else {
                sum_abs_w / final_evals as f64 / max_abs_w
            },
            pareto_k: reliability.pareto_k,
            pareto_k_limit: reliability.pareto_k_limit,
            tail_end_p: reliability.tail_end_p,
            ess: reliability.ess,
            var_rel_err: reliability.var_rel_err,
            seconds: started.elapsed().as_secs_f64(),
            warnings,
            convergence,
            iterations: self.iterations.clone(),
            components: self.components(shares),
            channels: None,
            stop: None,
            tail: Some(self.tail.clone()),
            answered_by: None,
        }
    }

    /// The estimate and its variance: Σ a_i·estimate_i and Σ a_i²·variance_i, a_i the shares or
    /// each iteration's evaluations over all.
    fn pooled(&self, shares: Option<&[f64]>) -> (f64, f64) {
        let its = &self.iterations;
        match shares {
            Some(a) => (
                its.iter().zip(a).map(|(i, a)| i.estimate * a).sum(),
                its.iter().zip(a).map(|(i, a)| i.variance * a * a).sum(),
            ),
            None => {
                let total: f64 = its.iter().map(|i| i.evals as f64).sum();
                (
                    its.iter().map(|i| i.estimate * i.evals as f64).sum::<f64>() / total,
                    its.iter()
                        .map(|i| i.variance * (i.evals as f64 / total).powi(2))
                        .sum(),
                )
            }
        }
    }

    /// Every component's pooled estimate and covariance, pooled as [`Accumulator::pooled`]
    /// pools component 0; `None` for a scalar integrand.
    fn components(&self, shares: Option<&[f64]>) -> Option<ComponentEstimates> {
        let parts: Vec<_> = self
            .iterations
            .iter()
            .map(|i| i.components.as_ref().map(|c| (c, i.evals)))
            .collect::<Option<_>>()?;
        let k = parts.first()?.0.mean.len();
        let mut mean = vec![0.0; k];
        let mut cov = vec![0.0; k * k];
        match shares {
            Some(a) => {
                for ((c, _), share) in parts.iter().zip(a) {
                    for j in 0..k {
                        mean[j] += c.mean[j] * share;
                    }
                    for (s, v) in cov.iter_mut().zip(&c.cov) {
                        *s += v * share.powi(2);
                    }
                }
            }
            None => {
                let total: f64 = parts.iter().map(|p| p.1 as f64).sum();
                for (c, n) in &parts {
                    let share = *n as f64 / total;
                    for j in 0..k {
                        mean[j] += c.mean[j] * *n as f64;
                    }
                    for (s, v) in cov.iter_mut().zip(&c.cov) {
                        *s += v * share.powi(2);
                    }
                }
                mean.iter_mut().for_each(|m| *m /= total);
            }
        }
        let std_err = (0..k).map(|j| cov[j * k + j].sqrt()).collect();
        Some(ComponentEstimates { mean, std_err, cov })
    }

    /// Adds one iteration of i.i.d. weights w_i = f_i/q_i of the final phase (one process).
    #[cfg(test)]
    pub(crate) fn add_weights(&mut self, w: &[f64]) -> Result<()> {
        let mut m = Moments::new(1);
        m.add(w);
        self.observe(w);
        self.add(m.iteration(Source::Final))
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

/// The χ²/dof between iterations above which a result warns: for 2 degrees of freedom a
/// converged sampler passes it with probability e⁻³ ≈ 0.05, for 9 with 0.001.
pub const CHI2_LIMIT: f64 = 3.0;

/// The warning of a χ²/dof above [`CHI2_LIMIT`].
pub(crate) fn chi2_warning(chi2: f64) -> String {
    format!(
        "χ²/dof = {chi2:.2} between iterations: the weights are heavy-tailed or the sampler \
         misses part of the integrand, and the error bar may be too small; {ADVICE_MORE}"
    )
}

/// χ² per degree of freedom of `its` around `value` (NaN for fewer than two): against each
/// iteration's own variance when `own_variances` (a sampler that adapts between them),
/// else against the pooled variance per evaluation (one fixed sampler).
pub(crate) fn chi2_per_dof(its: &[Iteration], value: f64, own_variances: bool) -> f64 {
    let k = its.len();
    if k < 2 {
        return f64::NAN;
    }
    if own_variances {
        return if its.iter().all(|i| i.variance > 0.0) {
            its.iter()
                .map(|i| (i.estimate - value).powi(2) / i.variance)
                .sum::<f64>()
                / (k - 1) as f64
        } else {
            f64::NAN
        };
    }
    // Against the variance an iteration of its size has by the pooled estimate (iterations
    // are of nearly equal size, or of one frozen sampler): dividing by each iteration's own variance estimate instead
    // pulls χ² far below 1 for heavy-tailed weights, whose large deviations come with large
    // variance estimates. The per-evaluation variance of each iteration, averaged over the
    // iterations weighted by their sizes:
    let total: f64 = its.iter().map(|i| i.evals as f64).sum();
    let mean_var_per_eval = its
        .iter()
        .map(|i| i.variance * (i.evals as f64).powi(2))
        .sum::<f64>()
        / total;
    if mean_var_per_eval > 0.0 {
        its.iter()
            .map(|i| (i.estimate - value).powi(2) * i.evals as f64 / mean_var_per_eval)
            .sum::<f64>()
            / (k - 1) as f64
    } else {
        f64::NAN
    }
}

/// One iteration of `n` i.i.d. weights over all ranks of `comm`, the loop of every method that
/// draws i.i.d. points: this rank's share drawn by `draw` (m → the `m × k` weights of m new
/// points) in chunks of at most [`CHUNK`], each chunk's component 0 seen by `acc`'s reliability
/// figures, and the ranks' moments merged in rank order. An error on any rank stops every rank.
pub(crate) fn iid_iteration(
    comm: &Comm,
    n: u64,
    k: usize,
    acc: &mut Accumulator,
    mut draw: impl FnMut(usize) -> Result<Vec<f64>>,
) -> Result<Iteration> {
    let mine = comm.share(n);
    let mut moments = Moments::new(k);
    let mut drawn = Ok(());
    while drawn.is_ok() && moments.n() < mine {
        let m = (mine - moments.n()).min(CHUNK as u64) as usize;
        drawn = draw(m).map(|w| {
            acc.observe(&column(&w, k, 0));
            moments.add(&w);
        });
    }
    comm.check(drawn)?;
    Ok(moments.across(comm).iteration(Source::Final))
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
            let mut acc = Accumulator::new(10_000);
            for _ in 0..10 {
                let w: Vec<f64> = (0..1000).map(|_| rng.random::<f64>()).collect();
                acc.add_weights(&w).unwrap();
            }
            let r = acc.finish(None, 10_000, started);
            assert!((r.value - 0.5).abs() < 5.0 * r.std_err);
            // Var(U)/E[U]² = (1/12)/(1/4) = 1/3 per evaluation.
            assert!((r.rel_var_per_eval - 1.0 / 3.0).abs() < 0.03);
            sum += r.chi2_per_dof;
        }
        let mean = sum / 200.0;
        assert!((mean - 1.0).abs() < 0.12, "mean χ²/dof {mean}");
    }
}
