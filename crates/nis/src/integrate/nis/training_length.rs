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
//!
//! The rule also paces the annealing (the tempered target |f|^β, β rising to 1, that lets the
//! flow find every mode before it sharpens). Annealing need only be slow while the flow lags the
//! tempered target, which the effective sample size of each batch's tempered weights |f|^β/q_mix
//! measures, as adaptive tempering in sequential Monte Carlo does (Jasra, Stephens, Doucet,
//! Tsagaris 2011). The pace at which β rises doubles after every [`PACE_WINDOW`] batches whose
//! ESS fractions all reach [`TRACKING_ESS`], up to [`MAX_PACE`] times the slow pace, and falls
//! back to the slow pace at the first batch below it (docs/results/integration.md, "Precision
//! targets", gives the measurements that set them).

use crate::integrate::Target;

/// Batches over which the tempered target |f|^β rises to |f| in target mode, in `dim`
/// dimensions, at the slow pace; the rule decides from [`SETTLE_BATCHES`] after. Finding every
/// mode takes longer in more dimensions: on camel-sharp d = 16 (two peaks), 50 such batches, and
/// 25 per dimension, left seed 1 with one peak of two (0.50 ± 5·10⁻⁴ of 1, no warning); 40 per
/// dimension found both on seeds 1–3.
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
/// The most times faster than the slow pace that β rises while the flow tracks the tempered
/// target.
const MAX_PACE: f64 = 16.0;
/// Batches of tracking after which the pace doubles.
const PACE_WINDOW: usize = 10;
/// The ESS fraction of the tempered weights that every batch of the window must reach for the
/// fast pace. On the suite's multi-peaked cells at d ≥ 8 no window of the slow annealing reaches
/// it; on gauss d = 16 nearly every window does.
const TRACKING_ESS: f64 = 0.8;

/// Batches after which training pauses when asked ([`TrainingLength::pause_after_probe`]):
/// enough for a median time per batch and a median of the tempered weights' ESS.
const PROBE_BATCHES: usize = PACE_WINDOW;
/// The median ESS fraction of the tempered weights over the first [`PROBE_BATCHES`] above which
/// the integrand counts as smooth: between the smooth cells (gauss d = 8 and 16, camel d = 4 and
/// 8) and the sharp or multi-peaked ones of docs/results/integration.md, "Precision targets".
const SMOOTH_ESS: f64 = 0.6;

/// The measurements of one training batch (over all ranks).
#[derive(Clone, Copy, Debug)]
pub(super) struct BatchReport {
    /// Variance per evaluation of the batch's weights f/q_mix.
    pub(super) var_per_eval: f64,
    /// The batch's mean weight.
    pub(super) estimate: f64,
    /// Seconds spent drawing and evaluating the batch's points, per point.
    pub(super) seconds_per_eval: f64,
    /// Seconds spent evaluating the integrand alone, per point (what another sampler's points
    /// would cost).
    pub(super) integrand_seconds_per_eval: f64,
    /// Seconds the whole batch took, its training step included.
    pub(super) seconds: f64,
    /// The ESS fraction (Σw)²/(n·Σw²) of the tempered weights w = |f|^β/q_mix of the batch
    /// (1 once β = 1: it only paces the annealing).
    pub(super) tempered_ess: f64,
}

/// The decision rule of the module docs, fed one [`BatchReport`] per batch.
pub(super) struct TrainingLength {
    target: Target,
    /// Batches of annealing at the slow pace (see [`anneal_batches`]).
    anneal: usize,
    /// The tempered target's exponent at the first batch.
    beta_from: f64,
    /// The exponent of the next batch.
    beta: f64,
    /// Batches trained when β reached 1.
    annealed_at: Option<usize>,
    /// How many times the slow pace β rises at, and the batch at which it last changed.
    pace: (f64, usize),
    /// Batches after which training stops whatever the trend says.
    max_batches: usize,
    /// Seconds of training after which it stops (a share of `max_seconds`).
    max_seconds: f64,
    /// Whether to stop once after [`PROBE_BATCHES`] batches.
    pause: bool,
    log_var: Vec<f64>,
    estimates: Vec<f64>,
    seconds_per_eval: Vec<f64>,
    integrand_seconds_per_eval: Vec<f64>,
    seconds: Vec<f64>,
    ess: Vec<f64>,
}

impl TrainingLength {
    /// For `target`, annealing from |f|^`beta_from` over `anneal` batches at the slow pace
    /// (`beta_from` = 1: none, for a flow trained before) and training at most `max_batches`
    /// batches and `max_seconds` seconds.
    pub(super) fn new(
        target: Target,
        anneal: usize,
        beta_from: f64,
        max_batches: usize,
        max_seconds: f64,
    ) -> TrainingLength {
        let annealed = beta_from >= 1.0 || anneal == 0;
        TrainingLength {
            target,
            anneal,
            beta_from,
            beta: if annealed { 1.0 } else { beta_from },
            annealed_at: annealed.then_some(0),
            pace: (1.0, 0),
            max_batches,
            max_seconds,
            pause: false,
            log_var: Vec::new(),
            estimates: Vec::new(),
            seconds_per_eval: Vec::new(),
            integrand_seconds_per_eval: Vec::new(),
            seconds: Vec::new(),
            ess: Vec::new(),
        }
    }

    /// Stops training once, after [`PROBE_BATCHES`] batches, so that the road's strategies
    /// (`integrate/strategies.rs`) can race VEGAS+ with [`TrainingLength::slow_seconds_left`]
    /// known and look for a smooth integrand ([`TrainingLength::smooth`]); the next batch goes
    /// on as if it had not stopped.
    pub(super) fn pause_after_probe(&mut self) {
        self.pause = true;
    }

    /// Whether training stopped after the probe's batches.
    pub(super) fn paused(&self) -> bool {
        self.pause && self.log_var.len() == PROBE_BATCHES
    }

    /// Whether the probe's batches show a smooth integrand: their tempered weights' median ESS
    /// fraction reaches [`SMOOTH_ESS`], where a cheaper flow is as good (`integrate/strategies.rs`).
    /// A batch whose weights are all zero (no point hit f) counts as far from smooth.
    pub(super) fn smooth(&self) -> bool {
        if self.ess.len() < PROBE_BATCHES {
            return false;
        }
        let ess: Vec<f64> = (0..PROBE_BATCHES)
            .map(|i| {
                let zero = self.estimates[i] == 0.0 && self.log_var[i] == f64::NEG_INFINITY;
                if zero {
                    0.0
                } else {
                    self.ess[i]
                }
            })
            .collect();
        median(&ess) >= SMOOTH_ESS
    }

    /// Whether `batches` batches and `seconds` seconds leave room to train afresh: the annealing
    /// and the settling at the slow pace, at the median time of the batches so far.
    pub(super) fn room_to_restart(&self, batches: usize, seconds: f64) -> bool {
        let need = self.anneal + SETTLE_BATCHES;
        batches >= need && seconds >= self.slow_seconds(need)
    }

    /// The batches trained so far.
    pub(super) fn batches(&self) -> usize {
        self.log_var.len()
    }

    /// The seconds the annealing and the settling would still take at the slow pace
    /// ([`anneal_batches`] + [`SETTLE_BATCHES`] in all) at the median time of the batches so far:
    /// NIS's training at its slowest, without the estimate, the time a rival must beat.
    pub(super) fn slow_seconds_left(&self) -> f64 {
        self.slow_seconds((self.anneal + SETTLE_BATCHES).saturating_sub(self.batches()))
    }

    /// `batches` batches at the median time of the batches so far.
    fn slow_seconds(&self, batches: usize) -> f64 {
        batches as f64 * median(&self.seconds)
    }

    /// The tempered target's exponent β for the next batch.
    pub(super) fn beta(&self) -> f64 {
        self.beta
    }

    /// Whether β reached 1 with the last batch (and was below 1 before it).
    pub(super) fn just_annealed(&self) -> bool {
        self.annealed_at
            .is_some_and(|a| a > 0 && a == self.ess.len())
    }

    /// Raises β after a batch by 1/`anneal` of its span times the pace (module docs).
    fn advance_beta(&mut self) {
        if self.annealed_at.is_some() {
            return;
        }
        let n = self.ess.len();
        let (pace, since) = self.pace;
        self.pace = if self.ess[n - 1] < TRACKING_ESS {
            (1.0, n)
        } else if n - since >= PACE_WINDOW {
            ((2.0 * pace).min(MAX_PACE), n)
        } else {
            (pace, since)
        };
        self.beta += (1.0 - self.beta_from) / self.anneal as f64 * self.pace.0;
        // Rounding must not leave β a hair below 1 for one more batch.
        if self.beta >= 1.0 - 1e-9 {
            self.beta = 1.0;
            self.annealed_at = Some(n);
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
        self.integrand_seconds_per_eval
            .push(b.integrand_seconds_per_eval);
        self.seconds.push(b.seconds);
        self.ess.push(b.tempered_ess);
        self.advance_beta();
        let n = self.log_var.len();
        if self.paused() {
            return false;
        }
        if n >= self.max_batches || self.seconds() >= self.max_seconds {
            return false;
        }
        let settled = self.annealed_at.is_some_and(|a| n >= a + SETTLE_BATCHES);
        if !settled || n % CHECK_EVERY != 0 {
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

    /// The seconds of every batch so far.
    pub(super) fn seconds(&self) -> f64 {
        self.seconds.iter().sum()
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
        let w = latest_window(n);
        Some((
            median(&self.log_var[n - w..]).exp(),
            self.estimates[n - w..].iter().sum::<f64>() / w as f64,
            median(&self.seconds_per_eval[n - w..]),
        ))
    }

    /// The seconds per point of the integrand alone over the last window (as [`Self::latest`]'s;
    /// `None` before any batch): what a rival sampler's points cost.
    pub(super) fn integrand_seconds_per_eval(&self) -> Option<f64> {
        let n = self.integrand_seconds_per_eval.len();
        (n > 0).then(|| median(&self.integrand_seconds_per_eval[n - latest_window(n)..]))
    }
}

/// The batches of the last window after `n` (at least one): the latest fifth.
fn latest_window(n: usize) -> usize {
    (n / 5).clamp(1, n)
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

    /// Batches until the rule stops, annealing from β = 0.1 over 50 batches at the slow pace.
    fn run_with(
        var: impl Fn(usize) -> f64,
        ess: f64,
        per_eval: f64,
        step: f64,
        target: Target,
    ) -> usize {
        let mut rule = TrainingLength::new(target, 50, 0.1, 5_000, f64::INFINITY);
        let mut n = 0;
        loop {
            n += 1;
            let go_on = rule.go_on(BatchReport {
                var_per_eval: var(n),
                estimate: 1.0,
                seconds_per_eval: per_eval,
                integrand_seconds_per_eval: per_eval,
                seconds: 256.0 * per_eval + step,
                tempered_ess: ess,
            });
            if !go_on {
                return n;
            }
        }
    }

    fn run(var: impl Fn(usize) -> f64, per_eval: f64, step: f64, target: Target) -> usize {
        run_with(var, 0.5, per_eval, step, target)
    }

    fn report(ess: f64) -> BatchReport {
        BatchReport {
            var_per_eval: 1.0,
            estimate: 1.0,
            seconds_per_eval: 1e-6,
            integrand_seconds_per_eval: 1e-6,
            seconds: 1e-3,
            tempered_ess: ess,
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
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 30, f64::INFINITY);
        assert_eq!((1..).find(|_| !rule.go_on(report(0.5))), Some(30));
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 1000, 0.0105);
        assert_eq!((1..).find(|_| !rule.go_on(report(0.5))), Some(11));
    }

    #[test]
    fn training_pauses_once_after_the_probe_and_says_what_it_saw() {
        let probe = |ess: f64| {
            let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 5_000, f64::INFINITY);
            rule.pause_after_probe();
            let n = (1..).find(|_| !rule.go_on(report(ess))).unwrap();
            assert!(rule.paused());
            (n, rule.smooth(), rule)
        };
        let (n, smooth, rule) = probe(SMOOTH_ESS);
        assert_eq!((n, smooth), (PROBE_BATCHES, true));
        // 100 batches of 1 ms each to train afresh.
        assert!(rule.room_to_restart(100, 0.1) && !rule.room_to_restart(99, 1.0));
        assert!(!rule.room_to_restart(100, 0.099));
        // Batches that saw only zeros are not smooth, whatever their (trivial) ESS.
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 5_000, f64::INFINITY);
        rule.pause_after_probe();
        let zero = BatchReport {
            var_per_eval: 0.0,
            estimate: 0.0,
            tempered_ess: 1.0,
            ..report(1.0)
        };
        while rule.go_on(zero) {}
        assert!(rule.paused() && !rule.smooth());
        let (n, smooth, mut rule) = probe(0.9 * SMOOTH_ESS);
        assert_eq!((n, smooth), (PROBE_BATCHES, false));
        // 50 batches of annealing and 50 of settling at 1 ms each: 90 left after the 10th.
        assert!((rule.slow_seconds_left() - 0.09).abs() < 1e-12);
        // Going on, it trains as it would have without the pause (flat variance: 100 batches).
        let more = (1..).find(|_| !rule.go_on(report(0.5))).unwrap();
        assert!(!rule.paused());
        assert_eq!(PROBE_BATCHES + more, 100);
    }

    #[test]
    fn the_integrand_cost_is_apart_from_the_flows() {
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 5_000, f64::INFINITY);
        assert_eq!(rule.integrand_seconds_per_eval(), None);
        for i in 0..10 {
            rule.go_on(BatchReport {
                seconds_per_eval: 1e-5,
                integrand_seconds_per_eval: if i == 9 { 1e-3 } else { 1e-7 },
                ..report(0.5)
            });
        }
        // The last window (two batches of ten): its upper median, the slow last batch.
        assert_eq!(rule.integrand_seconds_per_eval(), Some(1e-3));
        assert_eq!(rule.latest().map(|l| l.2), Some(1e-5));
        for _ in 0..2 {
            rule.go_on(BatchReport {
                integrand_seconds_per_eval: 1e-7,
                ..report(0.5)
            });
        }
        assert_eq!(rule.integrand_seconds_per_eval(), Some(1e-7));
    }

    #[test]
    fn annealing_speeds_up_only_while_the_flow_tracks_the_tempered_target() {
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 5_000, f64::INFINITY);
        let mut betas = vec![rule.beta()];
        while rule.beta() < 1.0 {
            rule.go_on(report(0.9));
            betas.push(rule.beta());
        }
        // Nine batches at the slow pace, ten at twice it, then 4×: 9 + 20 + 6 × 4 ≥ 50.
        assert_eq!(betas.len() - 1, 25);
        let slow = 0.9 / 50.0;
        assert!((betas[9] - (0.1 + 9.0 * slow)).abs() < 1e-12);
        assert!((betas[19] - (0.1 + 29.0 * slow)).abs() < 1e-12);
        assert!(betas.windows(2).all(|w| w[1] > w[0]));
        assert!(rule.just_annealed());
        // A batch below the ESS threshold brings back the slow pace, which doubles only after
        // ten batches of tracking.
        let mut rule = TrainingLength::new(Target::rel(1e-4), 50, 0.1, 5_000, f64::INFINITY);
        let ess = [0.9; 14].into_iter().chain([0.79]).chain([0.9; 9]);
        for e in ess {
            rule.go_on(report(e));
        }
        let expected = 0.1 + (9.0 + 2.0 * 5.0 + 10.0) * slow;
        assert!((rule.beta() - expected).abs() < 1e-12, "{}", rule.beta());
        // Flat variance: the rule stops at its first decision 50 batches after the annealing
        // (at 25 here), however long that took.
        assert_eq!(run_with(|_| 1.0, 0.9, 1e-5, 1e-3, Target::rel(1e-4)), 80);
        let mut trained = TrainingLength::new(Target::rel(1e-4), 50, 1.0, 5_000, f64::INFINITY);
        assert!(trained.beta() == 1.0 && !trained.just_annealed());
        assert_eq!((1..).find(|_| !trained.go_on(report(0.5))), Some(50));
    }
}
