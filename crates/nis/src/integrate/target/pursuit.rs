//! The iterations of one run to a [`Target`]: each planned from those before it, its share of
//! the estimate fixed before it is drawn (the module docs of [`super`]).

use std::time::Instant;

use super::{Target, AIM, RESULT_ITERATIONS};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::integrate::diagnostics::{ADVICE_MET, ADVICE_MORE};
use crate::integrate::result::{IntegrationResult, Iteration, Stop};

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

/// What the limits leave for the next iteration.
#[derive(Clone, Copy)]
struct Room {
    /// Evaluations the evaluations and seconds left pay for.
    affordable: f64,
    /// The limit that runs out first.
    bound_by: Stop,
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

    /// The error bar that meets the target at the estimate so far (`prior`'s before the first
    /// iteration).
    pub(crate) fn wanted(&self, prior: &Prior) -> f64 {
        self.target
            .error_for(self.estimate().unwrap_or(prior.estimate))
    }

    /// The evaluations of one of [`RESULT_ITERATIONS`] equal iterations that would meet the
    /// target (aiming at [`AIM`] of it) at `prior`'s variance per evaluation; `None` when the
    /// target error is zero. Methods whose iterations grow towards it size them by it.
    pub(crate) fn iteration_goal(&self, prior: &Prior) -> Option<f64> {
        let wanted = self.wanted(prior);
        (wanted > 0.0).then(|| prior.var_per_eval / (AIM * wanted).powi(2) / RESULT_ITERATIONS)
    }

    /// Wall-clock seconds since the start, the same on every rank of `comm` (their largest).
    pub(crate) fn elapsed(&self, comm: &Comm) -> f64 {
        comm.max(self.started.elapsed().as_secs_f64())
    }

    /// What the limits leave at `elapsed` for a sampler of `seconds_per_eval`.
    fn room(&self, elapsed: f64, seconds_per_eval: f64) -> Room {
        let evals = self
            .target
            .max_evals
            .saturating_sub(self.spent_before + self.evals) as f64;
        let seconds = self
            .target
            .max_seconds
            .map_or(f64::INFINITY, |s| s - elapsed);
        let seconds_per_eval = seconds_per_eval.max(0.0);
        let affordable = if seconds_per_eval > 0.0 {
            evals.min(seconds / seconds_per_eval)
        } else {
            evals
        };
        let bound_by = if evals <= seconds / seconds_per_eval.max(f64::MIN_POSITIVE) {
            Stop::MaxEvals
        } else {
            Stop::MaxSeconds
        };
        Room {
            affordable,
            bound_by,
        }
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
        let var_per_eval = if self.sum_evals > 0.0 && !self.adapting {
            self.var_evals / self.sum_evals
        } else {
            prior.var_per_eval
        };
        let wanted = self.wanted(&prior);
        if wanted == 0.0 && var_per_eval == 0.0 {
            return Err(Error::Config(
                "precision target: only rel_err was given, and the integrand was zero at every \
                 point sampled so far, so no relative error can be met; give abs_err"
                    .into(),
            ));
        }
        let aim = (AIM * wanted).powi(2);
        let room = self.room(elapsed, prior.seconds_per_eval);
        if self.remaining > 0.0 && self.round_evals > 0 && self.var >= aim {
            // The iterations so far already spend the whole variance allowed (one of them was
            // far noisier than planned): no share left can bring it down.
            self.close_round();
        }
        if self.remaining <= 0.0 {
            // A round is over: met, or extended, or out of evaluations or time.
            if self.var.sqrt() <= wanted {
                self.stop = Some(Stop::Target);
                return Ok(None);
            }
            if room.affordable < least as f64 {
                self.stop = Some(room.bound_by);
                return Ok(None);
            }
            self.extend(aim, var_per_eval, least, room.affordable);
        }
        Ok(Some(self.step(aim, var_per_eval, least, chunk, room)))
    }

    /// Ends the current round early, its shares normalised to one, for an extension to dilute.
    fn close_round(&mut self) {
        let kept = 1.0 - self.remaining;
        self.shares.iter_mut().for_each(|a| *a /= kept);
        self.weighted /= kept;
        self.var /= kept * kept;
        self.remaining = 0.0;
    }

    /// Starts an extension: M more evaluations and their share b = M/(N + M), the rounds so far
    /// (N evaluations, variance v) keeping 1 − b, as a mean pooled by evaluations would; M the
    /// fewest with (1 − b)²·v + b²·V/M at `aim` (found by bisection on ln M), at most
    /// `affordable`.
    fn extend(&mut self, aim: f64, var_per_eval: f64, least: u64, affordable: f64) {
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

    /// The next iteration of the current round: the evaluations that bring Σ a²V/n to `aim`
    /// when the rest of the share goes to them, drawn in pieces of about `chunk`.
    fn step(&mut self, aim: f64, var_per_eval: f64, least: u64, chunk: u64, room: Room) -> Step {
        let r = self.remaining;
        // At most twice the round's smallest plan: a round that an iteration far noisier than
        // planned (a heavy tail) has set back ends near its plan, and an extension dilutes it,
        // instead of spreading what is left of its share thinly over many more evaluations.
        let left = aim - self.var;
        // No room (an extension that the limits keep short of the aim): the round spends what
        // it was planned with, and the limit then ends the run.
        let mut needed = if left > 0.0 {
            (r * r * var_per_eval / left).ceil().max(least as f64)
        } else {
            (self.round_plan - self.round_evals as f64).max(least as f64)
        };
        let planned = self.round_evals as f64 + needed;
        if self.round_plan == 0.0 || planned < self.round_plan {
            self.round_plan = planned;
        }
        needed = needed.min((2.0 * self.round_plan - self.round_evals as f64).max(least as f64));
        let (needed, limited) = if needed > room.affordable {
            (room.affordable.max(least as f64), true)
        } else {
            (needed, false)
        };
        let chunk = chunk.max(least) as f64;
        let evals = if needed <= 1.5 * chunk { needed } else { chunk };
        let last = evals >= needed;
        if last && limited {
            self.stop = Some(room.bound_by);
        }
        let share = if last { r } else { r * evals / needed };
        Step {
            evals: evals as u64,
            share,
        }
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
                crate::integrate::Source::Final,
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
