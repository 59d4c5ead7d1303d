//! Whether the sampler had converged when it made the estimate, read off what the integrator
//! already has (no extra evaluations): the iterations of the estimate and, for NIS, the
//! variance of every training batch. An unconverged sampler gives weights whose variance is
//! dominated by regions it rarely samples, so its error bar is too small without the weights'
//! tail showing it (docs/results/robustness.md measures which figure catches which run).

use serde::{Deserialize, Serialize};

use super::diagnostics::ADVICE_MORE;
use super::iteration::{Iteration, Source};

/// The convergence figures of one result; `None` where a figure is undefined (no training
/// batches in the estimate, too few iterations or batches).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Convergence {
    /// n/ESS − 1 = E\[w²\]/E\[|w|\]² − 1 of the weights that make the estimate: the χ² divergence
    /// of |f|/∫|f| from the sampler, 0 for the sampler NIS aims at; the estimate rests on about
    /// n/(1 + divergence) equally weighted points.
    pub divergence: Option<f64>,
    /// (training − final)/√(σ_t² + σ_f²): the pull between the pooled estimate of the training
    /// batches kept in the estimate and the final phase's (NIS with `reuse_training`).
    pub training_pull: Option<f64>,
    /// max |w| / Σ|w| of the final phase's weights: the share of the estimate one point carries.
    pub max_weight_share: Option<f64>,
    /// The training batches' variance per evaluation, geometric mean of the last quarter over
    /// that of the quarter before (NIS): well below 1 when training stopped while still improving.
    pub training_trend: Option<f64>,
    /// The final phase's variance per evaluation over the last training quarter's (geometric
    /// mean): far above 1 when the final phase met weights that training never saw.
    pub final_over_training: Option<f64>,
    /// The final iterations' variance per evaluation, second half over first half: below 1 when
    /// the sampler still improved during them (VEGAS+ adapts between its iterations).
    pub final_trend: Option<f64>,
    /// NIS: the largest weight |f|/q the final sampler gives a point its training drew, over the
    /// largest weight of the final phase: far above 1 where the flow dropped a region training
    /// saw f in, and also where its tails are only thinner than f's (`nis/memory.rs`); a figure,
    /// not a warning: [`Convergence::missing_mass`] says whether that region matters.
    #[serde(default)]
    pub training_weight_ratio: Option<f64>,
    /// NIS: ∫|f| over the region where the final sampler's weight exceeds the largest of its
    /// final phase, estimated from the training points with the densities that drew them, in
    /// units of the result's standard error: what the estimate could not see.
    #[serde(default)]
    pub missing_mass: Option<f64>,
    /// The standard error of [`Convergence::missing_mass`], in the same units.
    #[serde(default)]
    pub missing_mass_err: Option<f64>,
    /// How many kept training points lie in that region.
    #[serde(default)]
    pub recalled_beyond: Option<u64>,
    /// NIS: the largest weight the final sampler gives a training point over n_final·σ: how
    /// many standard errors one final draw there would move the estimate.
    #[serde(default)]
    pub recalled_shift: Option<f64>,
}

/// The smallest training batches per quarter for a trend (fewer: `None`).
const MIN_QUARTER: usize = 2;

impl Convergence {
    /// The figures of `iterations` (the estimate's, in order) and `training_var`, the variance per
    /// evaluation of every training batch in order (empty for methods without one).
    pub fn of(iterations: &[Iteration], training_var: &[f64]) -> Convergence {
        let finals: Vec<&Iteration> = iterations
            .iter()
            .filter(|i| i.source == Source::Final)
            .collect();
        let kept: Vec<&Iteration> = iterations
            .iter()
            .filter(|i| i.source == Source::Training)
            .collect();
        let (final_mean, final_var) = pooled(&finals);
        let training_pull = (!kept.is_empty() && !finals.is_empty()).then(|| {
            let (t, tv) = pooled(&kept);
            (t - final_mean) / (tv + final_var).sqrt()
        });
        let sum_abs: f64 = finals.iter().map(|i| i.sum_abs_w).sum();
        let max_abs = finals.iter().fold(0.0f64, |m, i| m.max(i.max_abs_w));
        let max_weight_share = (sum_abs > 0.0).then(|| max_abs / sum_abs);
        let quarter = training_var.len() / 4;
        let n = training_var.len();
        let (training_trend, last_quarter) = if quarter >= MIN_QUARTER {
            let last = log_mean(&training_var[n - quarter..]);
            let before = log_mean(&training_var[n - 2 * quarter..n - quarter]);
            (
                last.zip(before).map(|(l, b)| (l - b).exp()),
                last.map(f64::exp),
            )
        } else {
            (None, None)
        };
        let per_eval = |its: &[&Iteration]| -> Option<f64> {
            let evals: u64 = its.iter().map(|i| i.evals).sum();
            (evals > 0).then(|| {
                its.iter()
                    .map(|i| i.variance * (i.evals as f64).powi(2))
                    .sum::<f64>()
                    / evals as f64
            })
        };
        let final_over_training = per_eval(&finals)
            .zip(last_quarter)
            .filter(|(_, t)| *t > 0.0)
            .map(|(f, t)| f / t);
        let half = finals.len() / 2;
        let final_trend = if half >= 1 {
            per_eval(&finals[finals.len() - half..])
                .zip(per_eval(&finals[..half]))
                .filter(|(_, a)| *a > 0.0)
                .map(|(b, a)| b / a)
        } else {
            None
        };
        Convergence {
            divergence: None,
            training_pull: training_pull.filter(|z| z.is_finite()),
            max_weight_share,
            training_trend,
            final_over_training,
            final_trend,
            ..Convergence::default()
        }
    }
}

/// The mean of iterations pooled by their evaluations, and its variance.
fn pooled(its: &[&Iteration]) -> (f64, f64) {
    let total: f64 = its.iter().map(|i| i.evals as f64).sum();
    if total == 0.0 {
        return (f64::NAN, f64::NAN);
    }
    (
        its.iter().map(|i| i.estimate * i.evals as f64).sum::<f64>() / total,
        its.iter()
            .map(|i| i.variance * (i.evals as f64 / total).powi(2))
            .sum(),
    )
}

/// The mean of ln v over the positive values (`None` when there are none).
fn log_mean(v: &[f64]) -> Option<f64> {
    let logs: Vec<f64> = v.iter().filter(|x| **x > 0.0).map(|x| x.ln()).collect();
    (!logs.is_empty()).then(|| logs.iter().sum::<f64>() / logs.len() as f64)
}

/// A convergence warning: a short label for tables and the sentence for the user.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvergenceWarning {
    /// A short name of the figure that fired.
    pub label: &'static str,
    /// What the user should do.
    pub sentence: String,
}

impl Convergence {
    /// The warnings these figures give: the divergence and the missing mass (see each limit).
    pub fn warnings(&self) -> Vec<ConvergenceWarning> {
        let mut out = Vec::new();
        if let Some(d) = self.divergence.filter(|d| *d > DIVERGENCE_LIMIT) {
            out.push(ConvergenceWarning {
                label: "divergence",
                sentence: format!(
                    "the sampler is far from the integrand's shape (χ² divergence {d:.1}: the \
                     estimate rests on {:.0}% of its points): it may have missed a peak, which \
                     no error bar shows; {ADVICE_MORE}",
                    100.0 / (1.0 + d)
                ),
            });
        }
        out.extend(self.recalled_warnings());
        out
    }

    /// The warnings of the training points the final sampler is judged by: the missing mass
    /// and the hole (NIS adds them once the final phase is done).
    pub fn recalled_warnings(&self) -> Vec<ConvergenceWarning> {
        let mut out: Vec<ConvergenceWarning> = self.missing_mass_warning().into_iter().collect();
        if out.is_empty() {
            out.extend(self.hole_warning());
        }
        out
    }

    /// The warning of [`Convergence::recalled_shift`] above [`HOLE_LIMIT`].
    pub fn hole_warning(&self) -> Option<ConvergenceWarning> {
        let s = self.recalled_shift.filter(|s| *s > HOLE_LIMIT)?;
        Some(ConvergenceWarning {
            label: "hole",
            sentence: format!(
                "the final flow has a hole where its training saw f: at a point training \
                 evaluated, its density is so low that one draw there would move the estimate by \
                 {s:.0} error bars. The training points there carry little of ∫|f| (they may \
                 be the flanks of a peak the flow dropped), so how much the estimate misses is \
                 unknown, and no error bar shows it; {ADVICE_MORE}"
            ),
        })
    }

    /// The warning of [`Convergence::missing_mass`] above [`MISSING_MASS_LIMIT`] (NIS adds it
    /// once the final phase is done).
    pub fn missing_mass_warning(&self) -> Option<ConvergenceWarning> {
        let m = self.missing_mass.filter(|m| *m > MISSING_MASS_LIMIT)?;
        let e = self.missing_mass_err.unwrap_or(f64::NAN);
        Some(ConvergenceWarning {
            label: "missing mass",
            sentence: format!(
                "the training saw f where the final flow samples too rarely to see it: those \
                 points estimate the integral there at {m:.1} ± {e:.1} times the error bar, \
                 which the estimate leaves out, so the answer is probably short by about that \
                 much; {ADVICE_MORE}"
            ),
        })
    }
}

/// The missing mass, in standard errors of the result, above which a result warns: beyond it
/// the part of ∫|f| that the estimate could not see would move the answer by more than its error
/// bar. Chosen by the sweep of limits in docs/results/robustness.md, "The k̂ warning as a
/// test".
pub const MISSING_MASS_LIMIT: f64 = 1.0;

/// The shift ([`Convergence::recalled_shift`], in error bars) above which a result warns of a
/// hole. Under an honest error bar σ, the region where one draw moves the estimate by s error
/// bars holds at most σ/s of ∫|f| (Cauchy–Schwarz on the weights' second moment), so a point
/// there is no evidence of missing mass by itself; a hole this deep is rare in converged flows
/// and common where a peak was dropped. Chosen by the sweep of limits in
/// docs/results/robustness.md, "The k̂ warning as a test".
pub const HOLE_LIMIT: f64 = 100.0;

/// The divergence above which a result warns: its estimate then rests on fewer than a quarter of
/// its points. Chosen by the sweep of limits in docs/results/robustness.md, "The k̂ warning as
/// a test".
pub const DIVERGENCE_LIMIT: f64 = 3.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrate::{integrator, IntegrationResult, Method, Settings};

    fn it(source: Source, estimate: f64, variance: f64, evals: u64) -> Iteration {
        Iteration {
            estimate,
            variance,
            evals,
            source,
            max_abs_w: 2.0,
            sum_abs_w: evals as f64,
            components: None,
        }
    }

    #[test]
    fn the_figures_read_the_iterations_and_the_training_variances() {
        // Training pooled: 1.0 ± √(0.02/4); final: 1.3 ± √(0.01/4 + 0.04/4).
        let its = [
            it(Source::Training, 0.9, 0.01, 100),
            it(Source::Training, 1.1, 0.01, 100),
            it(Source::Final, 1.3, 0.01, 100),
            it(Source::Final, 1.3, 0.04, 100),
        ];
        // Variance per evaluation falling by 10× between the last two quarters of 8 batches.
        let var = [50.0, 40.0, 30.0, 20.0, 10.0, 10.0, 1.0, 1.0];
        let c = Convergence::of(&its, &var);
        let z = (1.0 - 1.3) / (0.005f64 + 0.0125).sqrt();
        assert!((c.training_pull.unwrap() - z).abs() < 1e-12);
        assert_eq!(c.max_weight_share, Some(2.0 / 200.0));
        assert!((c.training_trend.unwrap() - 0.1).abs() < 1e-12);
        // Final per evaluation (0.01·100 + 0.04·100)/2 = 2.5 over the last quarter's 1.
        assert!((c.final_over_training.unwrap() - 2.5).abs() < 1e-12);
        assert!((c.final_trend.unwrap() - 4.0).abs() < 1e-12);
        // Without training: only the final phase's figures.
        let c = Convergence::of(&its[2..], &[]);
        assert_eq!(
            (c.training_pull, c.training_trend, c.final_over_training),
            (None, None, None)
        );
        assert!(c.max_weight_share.is_some() && c.final_trend.is_some());
    }

    #[test]
    fn the_missing_mass_warns_above_its_limit_and_a_hole_only_without_it() {
        let labels = |c: &Convergence| c.warnings().iter().map(|w| w.label).collect::<Vec<_>>();
        let mut c = Convergence {
            missing_mass: Some(0.5 * MISSING_MASS_LIMIT),
            missing_mass_err: Some(0.1),
            recalled_shift: Some(0.5 * HOLE_LIMIT),
            ..Convergence::default()
        };
        assert!(labels(&c).is_empty());
        c.recalled_shift = Some(2.0 * HOLE_LIMIT);
        assert_eq!(labels(&c), ["hole"]);
        c.missing_mass = Some(2.0 * MISSING_MASS_LIMIT);
        assert_eq!(labels(&c), ["missing mass"]);
        let w = c.missing_mass_warning().unwrap().sentence;
        assert!(w.contains("2.0 ± 0.1 times the error bar"), "{w}");
    }

    /// The divergence of the uniform density from a Gaussian exp(−|x − ½|²/α²) on [0, 1]^d
    /// (narrow enough to ignore the edges): ∫g²/(∫g)² − 1 = (1/(α√(2π)))^d − 1.
    fn uniform_divergence(alpha: f64, d: i32) -> f64 {
        (1.0 / (alpha * (2.0 * std::f64::consts::PI).sqrt())).powi(d) - 1.0
    }

    /// NIS with `train_fraction` of `evals` training and an i.i.d. final phase, whose weights
    /// are drawn from the sampler itself (a stratified one moves points towards the peak).
    fn nis_result(name: &str, dim: usize, train_fraction: f64, evals: u64) -> IntegrationResult {
        let f = crate::integrands::by_name(name, Some(dim)).unwrap();
        let mut s = Settings::default().seed(3);
        s.nis.train_fraction = train_fraction;
        s.nis.stratify = None;
        integrator(Method::Nis, dim, &s)
            .unwrap()
            .integrate(&f, evals)
            .unwrap()
    }

    #[test]
    fn an_untrained_flow_on_a_sharp_peak_warns_and_a_trained_one_on_a_broad_peak_does_not() {
        // gauss-sharp (α = 0.1) d = 4 with too little training for one batch: the flow is as it
        // was initialised, uniform, whose divergence is (1/(0.1·√(2π)))⁴ − 1 ≈ 250, ~80× the
        // limit; its weights are bounded, so 2·10⁴ of them estimate it far better than that.
        let prior = uniform_divergence(0.1, 4);
        assert!(prior > 50.0 * DIVERGENCE_LIMIT);
        let r = nis_result("gauss-sharp", 4, 0.005, 20_000);
        let d = r.convergence.divergence.unwrap();
        assert!(
            d > prior / 2.0 && d < prior * 2.0,
            "divergence {d}, uniform's {prior}"
        );
        assert!(
            r.warnings.iter().any(|w| w.contains("χ² divergence")),
            "{:?}",
            r.warnings
        );
        // gauss (α = 0.2) d = 4 at 2·10⁵ evaluations: uniform sampling would warn
        // ((1/(0.2·√(2π)))⁴ − 1 ≈ 15), the trained flow must not.
        assert!(uniform_divergence(0.2, 4) > 3.0 * DIVERGENCE_LIMIT);
        let r = nis_result("gauss", 4, 0.4, 200_000);
        let d = r.convergence.divergence.unwrap();
        assert!(d < DIVERGENCE_LIMIT, "divergence {d}");
        assert!(r.convergence.warnings().is_empty());
        assert!(!r.warnings.iter().any(|w| w.contains("χ² divergence")));
    }
}
