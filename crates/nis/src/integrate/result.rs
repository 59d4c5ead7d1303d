//! What an integration reports: [`IntegrationResult`], its [`Iteration`]s, and
//! [`ComponentEstimates`] for vector-valued integrands, a multi-channel [`ChannelReport`] and why a
//! run to a target stopped ([`Stop`]). Imports nothing above the statistics it reports;
//! [`super::Accumulator`] makes it.

use serde::{Deserialize, Serialize};

use super::convergence::Convergence;
pub use super::iteration::{Iteration, IterationComponents, Source};

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
    /// it (the final phase's, and the kept training batches' for NIS with training reused; a
    /// multi-channel integral's parts' estimates), never those that only adapted the sampler (a
    /// sign pilot, a part's adaptation, a weight network's fit): the evaluations of the printed
    /// table's rows, `n_eval` less its "adapting" row. One definition for every method.
    pub rel_var_per_eval: f64,
    /// Unweighting efficiency mean(|w|)/max(|w|) of the final phase's weights.
    pub unweighting_efficiency: f64,
    /// PSIS's Pareto k̂ of the |w| tail of the weights that make the estimate: above [`PARETO_K_LIMIT`](super::PARETO_K_LIMIT) the error bar
    /// cannot be trusted (`NaN`, `null` in JSON, when it cannot be fitted). See
    /// [`diagnostics`](super::diagnostics).
    #[serde(default)]
    pub pareto_k: f64,
    /// The k̂ above which this result warns: [`PARETO_K_LIMIT`](super::PARETO_K_LIMIT) plus the
    /// noise of a k̂ fitted to its tail ([`diagnostics::pareto_k_threshold`](super::diagnostics::pareto_k_threshold);
    /// `null` in JSON without a fit).
    #[serde(default)]
    pub pareto_k_limit: f64,
    /// How probable a largest tail weight as small as the one seen is under the tail k̂ was
    /// fitted to: below [`TAIL_END_P`](super::diagnostics::TAIL_END_P) the weights end within the
    /// sample, and k̂ does not warn if `var_rel_err` is settled too
    /// ([`Reliability::k_warns`](super::diagnostics::Reliability::k_warns); `null` in JSON
    /// without a fit).
    #[serde(default)]
    pub tail_end_p: f64,
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
    /// Whether the sampler had converged (not part of the JSON summary).
    #[serde(skip)]
    pub convergence: Convergence,
    /// The iterations that make the estimate, in order: pooled training batches first (NIS with
    /// `reuse_training`), then the final phase's (not part of the JSON summary). Their
    /// evaluations add up to `n_eval` less those that only adapted the sampler.
    #[serde(skip)]
    pub iterations: Vec<Iteration>,
    /// Every channel's contribution, for a multi-channel integral (`None` otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channels: Option<ChannelReport>,
    /// Why a run to a precision target stopped (`None` for a run on a budget).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop: Option<Stop>,
    /// The PSIS tail and moments of the weights that made the estimate, to judge a sum of
    /// results by (a multi-channel integral's parts; not part of the JSON summary).
    #[serde(skip)]
    pub tail: Option<super::diagnostics::WeightTail>,
    /// The method whose sampler made the estimate when it is not the integrator's own: NIS
    /// integrating to a target leaves it to VEGAS+ when that gets there sooner with no warning
    /// (`NisConfig::race_vegas`); `None` otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub answered_by: Option<super::method::Method>,
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
    /// Its reliability figures ([`super::diagnostics::Reliability::warning`] gives the k̂ warning they make).
    pub fn reliability(&self) -> super::diagnostics::Reliability {
        super::diagnostics::Reliability {
            pareto_k: self.pareto_k,
            pareto_k_limit: self.pareto_k_limit,
            tail_end_p: self.tail_end_p,
            ess: self.ess,
            var_rel_err: self.var_rel_err,
        }
    }

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

/// A readable summary, as `vegas`'s `result.summary()`: the final phase's iterations (a
/// multi-channel result: each channel's share and, split by sign, F⁺ and F⁻), the result, and
/// every component of a vector-valued integrand.
impl std::fmt::Display for IntegrationResult {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(c) = &self.channels {
            return self.fmt_channels(c, f);
        }
        writeln!(
            f,
            "{:>5}  {:<8}  {:>24}  {:>10}",
            "itn", "source", "estimate ± std_err", "evals"
        )?;
        for (i, it) in self.iterations.iter().enumerate() {
            writeln!(
                f,
                "{:>5}  {:<8}  {:>12.6e} ± {:<9.2e}  {:>10}",
                i + 1,
                it.source.label(),
                it.estimate,
                it.variance.sqrt(),
                it.evals
            )?;
        }
        let estimated: u64 = self.iterations.iter().map(|i| i.evals).sum();
        self.fmt_adapting(estimated, 5, f)?;
        self.fmt_summary(estimated, f)
    }
}

impl IntegrationResult {
    /// The table of a multi-channel result: a row per channel (its share ∫ α_k f of the
    /// integral, which moves with the weights a_k, and the evaluations of its parts' estimates),
    /// F⁺ and F⁻ when split by sign (the same evaluations, by sign), then the rest.
    fn fmt_channels(&self, c: &ChannelReport, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:>7}  {:>8}  {:>24}  {:>10}",
            "channel", "weight", "share ± std_err", "evals"
        )?;
        for k in 0..c.means.len() {
            writeln!(
                f,
                "{k:>7}  {:>8.4}  {:>12.6e} ± {:<9.2e}  {:>10}",
                c.weights[k], c.means[k], c.std_errs[k], c.evals[k]
            )?;
        }
        if let Some(s) = &c.signs {
            writeln!(
                f,
                "{:>7}  {:>8}  {:>12.6e} ± {:<9.2e}  {:>10}",
                "f > 0", "", s.positive, s.positive_err, s.positive_evals
            )?;
            writeln!(
                f,
                "{:>7}  {:>8}  {:>12.6e} ± {:<9.2e}  {:>10}  ({:.1}% of the events negative)",
                "f < 0",
                "",
                s.negative,
                s.negative_err,
                s.negative_evals,
                100.0 * s.negative_fraction
            )?;
        }
        let estimated = c.evals.iter().sum();
        self.fmt_adapting(estimated, 7, f)?;
        self.fmt_summary(estimated, f)
    }

    /// The row of the evaluations that only adapted, when there are any (`estimated` made the
    /// estimate), its first column `first` wide as the table's.
    fn fmt_adapting(
        &self,
        estimated: u64,
        first: usize,
        f: &mut std::fmt::Formatter<'_>,
    ) -> std::fmt::Result {
        if self.n_eval > estimated {
            writeln!(
                f,
                "{:>first$}  {:<8}  {:>24}  {:>10}",
                "",
                "adapting",
                "(not in the estimate)",
                self.n_eval - estimated
            )?;
        }
        Ok(())
    }

    /// The result's line, and what follows it; `estimated` evaluations made the estimate (the
    /// n of its variance per evaluation, which the line names).
    fn fmt_summary(&self, estimated: u64, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "result {:.8e} ± {:.3e}   χ²/dof {:.2}   k̂ {:.2}   ESS {:.3e}   n_eval {}   \
             rel.var/eval {:.3e} (of the {} in the estimate)   unw.eff {:.4}   {:.2} s",
            self.value,
            self.std_err,
            self.chi2_per_dof,
            self.pareto_k,
            self.ess,
            self.n_eval,
            self.rel_var_per_eval,
            estimated,
            self.unweighting_efficiency,
            self.seconds
        )?;
        if let Some(m) = self.answered_by {
            write!(
                f,
                "\nestimated by {}: it met the target first, with no warning",
                m.label()
            )?;
        }
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

/// Why a run to a precision target ([`Target`](super::Target)) stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// The error bar met the target.
    Target,
    /// `max_evals` was reached first.
    MaxEvals,
    /// `max_seconds` was reached first.
    MaxSeconds,
}

impl Stop {
    /// The name JSON and the front ends use.
    pub fn name(self) -> &'static str {
        match self {
            Stop::Target => "target",
            Stop::MaxEvals => "max_evals",
            Stop::MaxSeconds => "max_seconds",
        }
    }
}

/// Every channel's contribution to a multi-channel estimate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelReport {
    /// The a-priori weights a_k the estimate used (summing to one).
    pub weights: Vec<f64>,
    /// Each channel's contribution F_k = ∫ α_k f (F⁺_k − F⁻_k when split by sign).
    pub means: Vec<f64>,
    /// Their standard errors.
    pub std_errs: Vec<f64>,
    /// The estimate's evaluations in each channel.
    pub evals: Vec<u64>,
    /// F⁺ and F⁻ when the integrand was split by sign.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signs: Option<SignReport>,
}

/// The positive and negative parts of a signed integral, F = F⁺ − F⁻.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SignReport {
    /// F⁺ = ∫ max(f, 0).
    pub positive: f64,
    pub positive_err: f64,
    /// F⁻ = ∫ max(−f, 0).
    pub negative: f64,
    pub negative_err: f64,
    /// F⁻/(F⁺ + F⁻): the share of unweighted events that carry a negative weight.
    pub negative_fraction: f64,
    /// The estimate's evaluations of the f > 0 parts (every channel's).
    #[serde(default)]
    pub positive_evals: u64,
    /// The estimate's evaluations of the f < 0 parts.
    #[serde(default)]
    pub negative_evals: u64,
}
