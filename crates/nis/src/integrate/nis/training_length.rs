//! How long NIS trains when it integrates to a precision target: while training still shortens
//! the predicted time to the target (issue 40, "training length that pays for itself").
//!
//! After every batch the rule knows the batch's variance per evaluation V_b of the weights f/q
//! (an i.i.d. sample of the flow as it stood), its estimate, and its wall time split into drawing
//! plus evaluating (c_e per point) and the training step. With the target error σ_t the estimate
//! still needs about V/σ_t² evaluations, V/σ_t²·c_e seconds. Training W more batches costs their
//! time and is predicted to lower V by the factor its recent trend gives, e^(−s·W), s the fall of
//! the median ln V_b per batch between the last two windows of W batches (medians, because single
//! heavy-tailed batches would set the trend). Training goes on while the time it saves exceeds the
//! time it costs: a cheap integrand stops early, an expensive one trains long.

use crate::integrate::Target;

/// Batches over which the tempered target |f|^β rises to |f| in target mode, in `dim`
/// dimensions; the rule decides from [`SETTLE_BATCHES`] after. Finding every mode takes longer
/// in more dimensions: on camel-sharp d = 16 (two peaks), 50 such batches, and 25 per dimension,
/// left seed 1 with one peak of two (0.50 ± 5·10⁻⁴ of 1, no warning); 40 per dimension found
/// both on seeds 1–3.
pub(super) fn anneal_batches(dim: usize) -> usize {
    (40 * dim).max(50)
}
/// Batches after the annealing before the rule first decides (its windows need batches of the
/// plain target).
pub(super) const SETTLE_BATCHES: usize = 50;
/// The rule decides every this many batches.
const CHECK_EVERY: usize = 10;
/// Fewest batches in a window of the trend.
const MIN_WINDOW: usize = 10;

/// The measurements of one training batch (over all ranks).
#[derive(Clone, Copy, Debug)]
pub(super) struct BatchReport {
    /// Variance per evaluation of the batch's weights f/q_mix.
    pub(super) var_per_eval: f64,
    /// The batch's mean weight.
    pub(super) estimate: f64,
    /// Seconds spent drawing and evaluating the batch's points, per point.
    pub(super) seconds_per_eval: f64,
    /// Seconds the whole batch took, its training step included.
    pub(super) seconds: f64,
}

/// The decision rule of the module docs, fed one [`BatchReport`] per batch.
pub(super) struct TrainingLength {
    target: Target,
    /// Batches of annealing (see [`anneal_batches`]).
    anneal: usize,
    /// Batches after which training stops whatever the trend says.
    max_batches: usize,
    /// Seconds of training after which it stops (a share of `max_seconds`).
    max_seconds: f64,
    log_var: Vec<f64>,
    estimates: Vec<f64>,
    seconds_per_eval: Vec<f64>,
    seconds: Vec<f64>,
}

impl TrainingLength {
    /// For `target`, annealing over `anneal` batches and training at most `max_batches` batches
    /// and `max_seconds` seconds.
    pub(super) fn new(
        target: Target,
        anneal: usize,
        max_batches: usize,
        max_seconds: f64,
    ) -> TrainingLength {
        TrainingLength {
            target,
            anneal,
            max_batches,
            max_seconds,
            log_var: Vec::new(),
            estimates: Vec::new(),
            seconds_per_eval: Vec::new(),
            seconds: Vec::new(),
        }
    }

    /// Records one batch and says whether to train another.
    pub(super) fn go_on(&mut self, b: BatchReport) -> bool {
        self.log_var.push(if b.var_per_eval > 0.0 {
            b.var_per_eval.ln()
        } else {
            f64::NEG_INFINITY
        });
        self.estimates.push(b.estimate);
        self.seconds_per_eval.push(b.seconds_per_eval);
        self.seconds.push(b.seconds);
        let n = self.log_var.len();
        if n >= self.max_batches || self.seconds.iter().sum::<f64>() >= self.max_seconds {
            return false;
        }
        if n < self.anneal + SETTLE_BATCHES || n % CHECK_EVERY != 0 {
            return true;
        }
        let w = (n / 5).max(MIN_WINDOW);
        let now = median(&self.log_var[n - w..]);
        let before = median(&self.log_var[n - 2 * w..n - w]);
        if now == f64::NEG_INFINITY {
            // Zero variance: the flow (or the integrand) leaves nothing to learn.
            return false;
        }
        let fall = ((before - now) / w as f64).max(0.0);
        let estimate = self.estimates[n - w..].iter().sum::<f64>() / w as f64;
        let wanted = self.target.error_for(estimate);
        if wanted <= 0.0 {
            return true;
        }
        let per_eval = median(&self.seconds_per_eval[n - w..]);
        let per_batch = self.seconds[n - w..].iter().sum::<f64>() / w as f64;
        let estimate_seconds = now.exp() / (wanted * wanted) * per_eval;
        let saved = estimate_seconds * (1.0 - (-fall * w as f64).exp());
        saved > per_batch * w as f64
    }

    /// Batches of annealing.
    pub(super) fn anneal(&self) -> usize {
        self.anneal
    }

    /// The variance per evaluation of every batch so far, in order.
    pub(super) fn variances(&self) -> Vec<f64> {
        self.log_var.iter().map(|l| l.exp()).collect()
    }

    /// The variance per evaluation and the estimate of the last window, the prior of the
    /// estimate's first iteration, and the seconds per evaluation of drawing and evaluating.
    pub(super) fn latest(&self) -> Option<(f64, f64, f64)> {
        let n = self.log_var.len();
        if n == 0 {
            return None;
        }
        let w = (n / 5).clamp(1, n);
        Some((
            median(&self.log_var[n - w..]).exp(),
            self.estimates[n - w..].iter().sum::<f64>() / w as f64,
            median(&self.seconds_per_eval[n - w..]),
        ))
    }
}

/// The median of `v` (the upper one of an even count); NaNs sort last.
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    s[s.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(var: impl Fn(usize) -> f64, per_eval: f64, step: f64, target: Target) -> usize {
        let mut rule = TrainingLength::new(target, 50, 5_000, f64::INFINITY);
        let mut n = 0;
        loop {
            n += 1;
            let go_on = rule.go_on(BatchReport {
                var_per_eval: var(n),
                estimate: 1.0,
                seconds_per_eval: per_eval,
                seconds: 256.0 * per_eval + step,
            });
            if !go_on {
                return n;
            }
        }
    }

    #[test]
    fn an_expensive_integrand_trains_longer_than_a_cheap_one() {
        // V falls 1% per batch towards a floor of 0.01 (relative variance of a converged flow).
        let var = |n: usize| 0.01 + 10.0 * (-0.01 * n as f64).exp();
        let t = Target::rel(1e-3);
        let cheap = run(var, 1e-7, 1e-3, t);
        let costly = run(var, 1e-5, 1e-3, t);
        assert!(cheap >= 100);
        assert!(costly > 2 * cheap, "cheap {cheap}, costly {costly}");
        // A looser target needs fewer evaluations, so training pays off sooner.
        let loose = run(var, 1e-5, 1e-3, Target::rel(1e-2));
        assert!(loose < costly, "loose {loose}, tight {costly}");
    }

    #[test]
    fn training_stops_when_the_variance_stops_falling_and_at_the_limits() {
        let flat = run(|_| 1.0, 1e-5, 1e-3, Target::rel(1e-4));
        assert_eq!(flat, 100);
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 30, f64::INFINITY);
        let report = BatchReport {
            var_per_eval: 1.0,
            estimate: 1.0,
            seconds_per_eval: 1e-6,
            seconds: 1e-3,
        };
        assert_eq!((1..).find(|_| !rule.go_on(report)), Some(30));
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 1000, 0.0105);
        assert_eq!((1..).find(|_| !rule.go_on(report)), Some(11));
    }
}
