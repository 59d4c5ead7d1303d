//! Integrating to a requested precision: a [`Target`] error (Cuba's `epsrel`/`epsabs`, met when
//! the error bar is below max(abs_err, rel_err·|I|)) under limits on evaluations and wall time,
//! for every method ([`super::Integrator::integrate_to`]).
//!
//! A stopping rule that watches the running error is a sequential test: stopping as soon as the
//! error looks small favours runs whose mean and variance were both low by chance. Here the
//! estimate is Σ a_i·I_i over the iterations of a frozen (or, for VEGAS+, still adapting) sampler
//! with every share a_i fixed *before* iteration i draws its points, from the iterations before it
//! ([`Pursuit`]): the error is then a sum of martingale differences whatever the stopping rule,
//! and the estimate is unbiased, as for the reused training batches (docs/ESTIMATE.md, "Precision
//! targets"). The plan aims at 0.95 of the target so that a round usually meets it; a round that
//! does not (its variance was underestimated, or a heavy-tailed weight spent its whole variance)
//! is extended, diluted by new evaluations as a pooled mean would be: the one step whose share
//! depends on the round's own error (its bias on heavy-tailed weights is measured in
//! docs/ESTIMATE.md, "Precision targets").

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::diagnostics::{ADVICE_MET, ADVICE_MORE};
use super::result::{IntegrationResult, Iteration, Stop};
use crate::comm::Comm;
use crate::error::{Error, Result};

/// Evaluations a target may spend when no `max_evals` is given.
pub const DEFAULT_MAX_EVALS: u64 = 100_000_000;

/// The plan aims at this fraction of the target error, so that a round usually meets it.
pub(crate) const AIM: f64 = 0.95;

/// A precision to integrate to, and the limits of the attempt.
///
/// ```
/// use nis::integrate::{uniform::{PlainMc, PlainMcConfig}, Integrator, Target};
/// let mut integ = PlainMc::new(2, PlainMcConfig::default())?;
/// let r = integ.integrate_to(&|x: &[f64]| x[0] * x[1], &Target::rel(1e-2))?;
/// assert!(r.std_err <= 1e-2 * r.value.abs());
/// # Ok::<(), nis::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Target {
    /// Relative error to reach: std_err ≤ rel_err·|value|.
    pub rel_err: Option<f64>,
    /// Absolute error to reach: std_err ≤ abs_err (either one met is enough, as in Cuba).
    pub abs_err: Option<f64>,
    /// The most evaluations to spend, training included.
    pub max_evals: u64,
    /// The most wall-clock seconds to spend (training included); `None`: no limit.
    pub max_seconds: Option<f64>,
}

impl Default for Target {
    fn default() -> Self {
        Target {
            rel_err: None,
            abs_err: None,
            max_evals: DEFAULT_MAX_EVALS,
            max_seconds: None,
        }
    }
}

impl Target {
    /// A relative error, within [`DEFAULT_MAX_EVALS`].
    pub fn rel(rel_err: f64) -> Target {
        Target {
            rel_err: Some(rel_err),
            ..Target::default()
        }
    }

    /// An absolute error, within [`DEFAULT_MAX_EVALS`].
    pub fn abs(abs_err: f64) -> Target {
        Target {
            abs_err: Some(abs_err),
            ..Target::default()
        }
    }

    /// Sets [`Target::max_evals`].
    pub fn max_evals(mut self, max_evals: u64) -> Target {
        self.max_evals = max_evals;
        self
    }

    /// Sets [`Target::max_seconds`].
    pub fn max_seconds(mut self, seconds: f64) -> Target {
        self.max_seconds = Some(seconds);
        self
    }

    /// The target the front ends' options describe: `None` when neither error is given (a run on
    /// a budget), an error when a limit is given without an error to reach. `max_evals` defaults
    /// to [`DEFAULT_MAX_EVALS`]. Not checked: [`Target::check`] does that, before a run.
    pub fn from_options(
        rel_err: Option<f64>,
        abs_err: Option<f64>,
        max_evals: Option<u64>,
        max_seconds: Option<f64>,
    ) -> Result<Option<Target>> {
        if rel_err.is_none() && abs_err.is_none() {
            if max_evals.is_some() || max_seconds.is_some() {
                return Err(Error::Config(
                    "precision target: max_evals and max_seconds limit a run to a target; give \
                     rel_err or abs_err too (or evals for a fixed budget)"
                        .into(),
                ));
            }
            return Ok(None);
        }
        Ok(Some(Target {
            rel_err,
            abs_err,
            max_evals: max_evals.unwrap_or(DEFAULT_MAX_EVALS),
            max_seconds,
        }))
    }

    /// The error bar that meets the target for an estimate `value`: max(abs_err, rel_err·|value|).
    pub fn error_for(&self, value: f64) -> f64 {
        let rel = self.rel_err.map_or(0.0, |r| r * value.abs());
        rel.max(self.abs_err.unwrap_or(0.0))
    }

    /// An error, before anything is evaluated, when the target cannot be met or its limits
    /// contradict each other; `least` is the fewest evaluations `method` needs for one estimate.
    pub fn check(&self, method: &str, least: u64) -> Result<()> {
        let bad = |why: String| Err(Error::Config(format!("precision target: {why}")));
        if self.rel_err.is_none() && self.abs_err.is_none() {
            return bad("give rel_err, abs_err or both".into());
        }
        for (name, v) in [("rel_err", self.rel_err), ("abs_err", self.abs_err)] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return bad(format!("{name} must be a positive number, got {v}"));
                }
            }
        }
        if let Some(s) = self.max_seconds {
            if !(s.is_finite() && s > 0.0) {
                return bad(format!("max_seconds must be a positive number, got {s}"));
            }
        }
        if self.max_evals < least {
            return bad(format!(
                "max_evals = {} is below the {least} evaluations {method} needs for one estimate",
                self.max_evals
            ));
        }
        Ok(())
    }
}

/// The next iteration a [`Pursuit`] asks for: its evaluations and its share of the estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Step {
    pub(crate) evals: u64,
    pub(crate) share: f64,
}

/// What the sampler is known to do before an iteration: its variance per evaluation, the
/// estimate to scale a relative target by, and the seconds an evaluation costs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Prior {
    pub(crate) var_per_eval: f64,
    pub(crate) estimate: f64,
    pub(crate) seconds_per_eval: f64,
}

impl Prior {
    /// The evaluations the estimate is predicted to need for `target` (aiming at [`AIM`] of
    /// it), at most `cap`; `cap` when the target error is zero.
    pub(crate) fn evals_to(&self, target: &Target, cap: f64) -> f64 {
        let wanted = target.error_for(self.estimate);
        if wanted > 0.0 {
            (self.var_per_eval / (AIM * wanted).powi(2)).min(cap)
        } else {
            cap
        }
    }
}

/// The iterations of one run to a target: plans each from those before it, fixes its share
/// before it is drawn, and says when to stop (module docs).
pub(crate) struct Pursuit {
    target: Target,
    started: Instant,
    /// Evaluations spent before the first iteration of the estimate (training, pilot).
    spent_before: u64,
    /// Evaluations of the estimate's iterations so far.
    evals: u64,
    shares: Vec<f64>,
    /// Share of the estimate not yet given to an iteration.
    remaining: f64,
    /// Σ a_i·I_i and Σ a_i²·V_i over the iterations so far.
    weighted: f64,
    var: f64,
    /// Σ n_i²·V_i and Σ n_i: the iterations' variance per evaluation, pooled by evaluations.
    var_evals: f64,
    sum_evals: f64,
    extensions: usize,
    /// The fewest evaluations the current round was planned with so far, and those it has drawn.
    round_plan: f64,
    round_evals: u64,
    stop: Option<Stop>,
    /// The sampler still adapts: the prior (the latest iteration) predicts the next iteration,
    /// not the iterations pooled.
    adapting: bool,
}

impl Pursuit {
    /// A run to `target` started at `started`, `spent_before` evaluations already spent.
    pub(crate) fn new(target: Target, started: Instant, spent_before: u64) -> Pursuit {
        Pursuit {
            target,
            started,
            spent_before,
            evals: 0,
            shares: Vec::new(),
            remaining: 1.0,
            weighted: 0.0,
            var: 0.0,
            var_evals: 0.0,
            sum_evals: 0.0,
            extensions: 0,
            round_plan: 0.0,
            round_evals: 0,
            stop: None,
            adapting: false,
        }
    }

    /// For a sampler that keeps adapting between iterations (VEGAS+): the caller's prior, kept
    /// up to date with the latest iteration, predicts the next.
    pub(crate) fn adapting(mut self) -> Pursuit {
        self.adapting = true;
        self
    }

    /// The shares of the iterations so far, in order (they sum to one once the run stops).
    pub(crate) fn shares(&self) -> &[f64] {
        &self.shares
    }

    /// The estimate of the iterations so far, their shares normalised (`None` before the first).
    pub(crate) fn estimate(&self) -> Option<f64> {
        (self.sum_evals > 0.0)
            .then(|| self.weighted / (1.0 - self.remaining).max(f64::MIN_POSITIVE))
    }

    /// The variance of [`Pursuit::estimate`] (`None` before the first iteration).
    pub(crate) fn variance(&self) -> Option<f64> {
        (self.sum_evals > 0.0)
            .then(|| self.var / (1.0 - self.remaining).max(f64::MIN_POSITIVE).powi(2))
    }

    /// Wall-clock seconds since the start, the same on every rank of `comm` (their largest).
    pub(crate) fn elapsed(&self, comm: &Comm) -> f64 {
        comm.max(self.started.elapsed().as_secs_f64())
    }

    /// Evaluations still allowed, and seconds (∞ without a time limit), at `elapsed`.
    fn left(&self, elapsed: f64) -> (u64, f64) {
        let evals = self
            .target
            .max_evals
            .saturating_sub(self.spent_before + self.evals);
        let seconds = self
            .target
            .max_seconds
            .map_or(f64::INFINITY, |s| s - elapsed);
        (evals, seconds)
    }

    /// The next iteration, of at least `least` and preferably `chunk` evaluations, or `None`
    /// when the run is over (see [`Pursuit::stop`]). `prior` describes the sampler until the
    /// iterations themselves measure it; `elapsed` is [`Pursuit::elapsed`]. An error when only a
    /// relative error was asked for and the integrand was zero everywhere so far.
    pub(crate) fn next(
        &mut self,
        prior: Prior,
        least: u64,
        chunk: u64,
        elapsed: f64,
    ) -> Result<Option<Step>> {
        if self.stop.is_some() {
            return Ok(None);
        }
        let estimate = self.estimate().unwrap_or(prior.estimate);
        let var_per_eval = if self.sum_evals > 0.0 && !self.adapting {
            self.var_evals / self.sum_evals
        } else {
            prior.var_per_eval
        };
        let wanted = self.target.error_for(estimate);
        if wanted == 0.0 && var_per_eval == 0.0 {
            return Err(Error::Config(
                "precision target: only rel_err was given, and the integrand was zero at every \
                 point sampled so far, so no relative error can be met; give abs_err"
                    .into(),
            ));
        }
        let aim = (AIM * wanted).powi(2);
        let (evals_left, seconds_left) = self.left(elapsed);
        let seconds_per_eval = prior.seconds_per_eval.max(0.0);
        let affordable = if seconds_per_eval > 0.0 {
            (evals_left as f64).min(seconds_left / seconds_per_eval)
        } else {
            evals_left as f64
        };
        let bound_by = || {
            if (evals_left as f64) <= seconds_left / seconds_per_eval.max(f64::MIN_POSITIVE) {
                Stop::MaxEvals
            } else {
                Stop::MaxSeconds
            }
        };
        if self.remaining > 0.0 && self.round_evals > 0 && self.var >= aim {
            // The iterations so far already spend the whole variance allowed (one of them was
            // far noisier than planned): no share left can bring it down, so the round ends
            // here, its shares normalised to one, and the extension below dilutes it.
            let kept = 1.0 - self.remaining;
            self.shares.iter_mut().for_each(|a| *a /= kept);
            self.weighted /= kept;
            self.var /= kept * kept;
            self.remaining = 0.0;
        }
        if self.remaining <= 0.0 {
            // A round is over: met, or extended, or out of evaluations or time.
            if self.var.sqrt() <= wanted {
                self.stop = Some(Stop::Target);
                return Ok(None);
            }
            if affordable < least as f64 {
                self.stop = Some(bound_by());
                return Ok(None);
            }
            // The extension: M more evaluations and their share b = M/(N + M), the rounds so far
            // (N evaluations, variance v) keeping 1 − b, as a mean pooled by evaluations would;
            // M the fewest with (1 − b)²·v + b²·V/M at the aim (found by bisection on ln M).
            let (v, n) = (self.var, self.evals as f64);
            let combined = |m: f64| {
                let b = m / (n + m);
                (1.0 - b).powi(2) * v + b * b * var_per_eval / m
            };
            let (mut lo, mut hi) = (least as f64, affordable.max(least as f64));
            if combined(hi) <= aim {
                for _ in 0..60 {
                    let mid = (lo * hi).sqrt();
                    if combined(mid) <= aim {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
            }
            let more = hi.ceil();
            let b = more / (n + more);
            self.shares.iter_mut().for_each(|a| *a *= 1.0 - b);
            self.weighted *= 1.0 - b;
            self.var *= (1.0 - b).powi(2);
            self.remaining = b;
            self.extensions += 1;
            self.round_plan = more;
            self.round_evals = 0;
        }
        let r = self.remaining;
        // Evaluations that bring Σ a²V/n to the aim when the rest of the share goes to them; at
        // most twice the round's smallest plan: a round that an iteration far noisier than planned
        // (a heavy tail) has set back ends near its plan, and an extension dilutes it, instead
        // of spreading what is left of its share thinly over many more evaluations.
        let room = aim - self.var;
        // No room (an extension that the limits keep short of the aim): the round spends what
        // it was planned with, and the limit then ends the run.
        let mut needed = if room > 0.0 {
            (r * r * var_per_eval / room).ceil().max(least as f64)
        } else {
            (self.round_plan - self.round_evals as f64).max(least as f64)
        };
        let planned = self.round_evals as f64 + needed;
        if self.round_plan == 0.0 || planned < self.round_plan {
            self.round_plan = planned;
        }
        needed = needed.min((2.0 * self.round_plan - self.round_evals as f64).max(least as f64));
        let (needed, limited) = if needed > affordable {
            (affordable.max(least as f64), true)
        } else {
            (needed, false)
        };
        let chunk = chunk.max(least) as f64;
        let evals = if needed <= 1.5 * chunk { needed } else { chunk };
        let last = evals >= needed;
        if last && limited {
            self.stop = Some(bound_by());
        }
        let share = if last { r } else { r * evals / needed };
        Ok(Some(Step {
            evals: evals as u64,
            share,
        }))
    }

    /// Counts `n` evaluations spent outside the estimate's iterations (a part's own warm-up)
    /// against `max_evals`.
    pub(crate) fn spend(&mut self, n: u64) {
        self.spent_before += n;
    }

    /// Records the iteration drawn for `step`.
    pub(crate) fn record(&mut self, step: Step, iteration: &Iteration) {
        self.shares.push(step.share);
        self.weighted += step.share * iteration.estimate;
        self.var += step.share * step.share * iteration.variance;
        self.remaining = if step.share >= self.remaining {
            0.0
        } else {
            self.remaining - step.share
        };
        let n = iteration.evals as f64;
        self.evals += iteration.evals;
        self.round_evals += iteration.evals;
        self.var_evals += n * n * iteration.variance;
        self.sum_evals += n;
    }

    /// Why the run stopped (`None` while it goes on).
    #[cfg(test)]
    pub(crate) fn stop(&self) -> Option<Stop> {
        self.stop
    }

    /// Puts the stop reason into `result`, with a warning when a limit, not the target, ended the
    /// run: how far the error was from the target and how many evaluations would have met it.
    pub(crate) fn finish(&self, result: &mut IntegrationResult) {
        let stop = self.stop.unwrap_or(Stop::Target);
        result.stop = Some(stop);
        let wanted = self.target.error_for(result.value);
        if stop == Stop::Target || result.std_err <= wanted {
            result.stop = Some(Stop::Target);
            for w in &mut result.warnings {
                *w = w.replace(ADVICE_MORE, ADVICE_MET);
            }
            return;
        }
        let limit = match stop {
            Stop::MaxEvals => format!("max_evals = {}", self.target.max_evals),
            _ => format!("max_seconds = {}", self.target.max_seconds.unwrap_or(0.0)),
        };
        // At the measured variance per evaluation, σ falls as 1/√n.
        let factor = (result.std_err / wanted).powi(2);
        let more = self.evals as f64 * (factor - 1.0);
        result.warnings.push(format!(
            "the target error {wanted:.2e} was not met: {limit} stopped the run at ± {:.2e}; \
             about {more:.1e} more evaluations of the estimate (×{factor:.1} its {}) would \
             meet it at the variance measured: raise the limit or loosen the target",
            result.std_err, self.evals
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pursuit of `target` whose iterations all have the variance per evaluation `var` (prior:
    /// 1, estimate 1), each of about `chunk` evaluations, run to its end.
    fn pursue(target: Target, var: f64, chunk: u64) -> Pursuit {
        let prior = Prior {
            var_per_eval: 1.0,
            estimate: 1.0,
            seconds_per_eval: 0.0,
        };
        let mut p = Pursuit::new(target, Instant::now(), 0);
        let mut steps = 0;
        while let Some(step) = p.next(prior, 10, chunk, 0.0).unwrap() {
            let n = step.evals;
            let cov = vec![var / n as f64];
            let it = Iteration::new(
                super::super::Source::Final,
                vec![1.0],
                cov,
                n,
                1.0,
                n as f64,
            );
            p.record(step, &it);
            steps += 1;
            assert!(steps < 100);
        }
        p
    }

    #[test]
    fn bad_targets_are_refused_before_any_evaluation() {
        let ok = Target::rel(1e-3);
        assert!(ok.check("nis", 100).is_ok());
        for t in [
            Target::default(),
            Target::rel(0.0),
            Target::rel(-1e-3),
            Target::rel(f64::NAN),
            Target::abs(f64::INFINITY),
            ok.max_seconds(0.0),
            ok.max_seconds(f64::NAN),
            ok.max_evals(99),
        ] {
            let e = t.check("nis", 100).unwrap_err().to_string();
            assert!(e.contains("precision target"), "{e}");
        }
    }

    #[test]
    fn either_error_meets_the_target() {
        let t = Target {
            rel_err: Some(1e-2),
            abs_err: Some(1e-3),
            ..Target::default()
        };
        assert_eq!(t.error_for(1.0), 1e-2);
        assert_eq!(t.error_for(0.01), 1e-3);
    }

    #[test]
    fn shares_sum_to_one_and_the_last_iteration_meets_the_plan() {
        // Iterations of exactly the planned variance: the first round meets the target.
        let p = pursue(Target::rel(1e-2), 1.0, 2_000);
        assert_eq!(p.stop(), Some(Stop::Target));
        let total: f64 = p.shares().iter().sum();
        assert!((total - 1.0).abs() < 1e-12);
        // V/(0.95·σ)² = 11 080 evaluations, in iterations of about 2000.
        assert!((11_000..11_200).contains(&p.evals), "{}", p.evals);
        assert!(p.var.sqrt() <= 1e-2);
    }

    #[test]
    fn a_round_that_misses_is_extended_and_a_limit_ends_the_run() {
        // The iterations are 4× noisier than the prior said: the plan adapts, and any round
        // that ends short of the target is extended until it is met.
        let p = pursue(Target::rel(1e-2), 4.0, 5_000);
        assert_eq!(p.stop(), Some(Stop::Target));
        assert!(p.var.sqrt() <= 1e-2);
        assert!((p.shares().iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // The same with room for 20 000 evaluations: the limit ends it, short of the target.
        let p = pursue(Target::rel(1e-2).max_evals(20_000), 4.0, 5_000);
        assert_eq!(p.stop(), Some(Stop::MaxEvals));
        assert!(p.evals <= 20_000);
        assert!((p.shares().iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_warning_on_a_run_that_met_its_target_does_not_ask_for_more_evaluations() {
        let warned = |p: &Pursuit| {
            let mut r = IntegrationResult {
                value: 1.0,
                std_err: p.var.sqrt(),
                warnings: vec![format!("the weights are heavy-tailed; {ADVICE_MORE}")],
                ..IntegrationResult::default()
            };
            p.finish(&mut r);
            r.warnings
        };
        let met = warned(&pursue(Target::rel(1e-2), 1.0, 2_000));
        assert!(
            met[0].ends_with(ADVICE_MET) && !met[0].contains(ADVICE_MORE),
            "{met:?}"
        );
        // Stopped by a limit short of the target: more evaluations are the remedy.
        let short = warned(&pursue(Target::rel(1e-2).max_evals(20_000), 4.0, 5_000));
        assert!(short[0].ends_with(ADVICE_MORE), "{short:?}");
        assert!(short[1].contains("was not met"), "{short:?}");
    }

    #[test]
    fn a_relative_target_of_a_zero_integral_is_an_error() {
        let mut p = Pursuit::new(Target::rel(1e-2), Instant::now(), 0);
        let zero = Prior {
            var_per_eval: 0.0,
            estimate: 0.0,
            seconds_per_eval: 0.0,
        };
        let e = p.next(zero, 10, 100, 0.0).unwrap_err().to_string();
        assert!(e.contains("abs_err"), "{e}");
    }
}
