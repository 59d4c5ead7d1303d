//! Whether an error bar can be trusted, read off the weights that made it.
//!
//! The standard error of a Monte Carlo estimate is the sample standard deviation of its weights
//! w = f/q over √n. When the weights are heavy-tailed (the sampler puts too little mass where |f|
//! is large), that sample deviation is itself dominated by a few weights and is usually too small:
//! the estimate is unbiased, yet single runs land tens of error bars away from the truth while
//! χ²/dof between iterations looks fine (each iteration misses the same rare large weights). Three
//! figures, each computed in bounded memory while the weights stream past:
//!
//! - **Pareto k̂** (Vehtari, Simpson, Gelman, Yao, Gabry, "Pareto smoothed importance sampling"):
//!   the shape of a generalized Pareto distribution fitted to the M = ⌈min(n/5, 3√n)⌉ largest |w|
//!   above the (M+1)-th largest, by Zhang and Stephens' estimator with PSIS's weak prior. The
//!   weights have a finite variance only if the true k < 1/2; a k̂ above [`PARETO_K_LIMIT`] (1/2)
//!   by more than its noise ([`pareto_k_threshold`]: a one-sided test at 5 % of k > 1/2) says
//!   the error bar is not to be trusted.
//!   Kept: a min-heap of the M + 1 largest |w| (M grows as √n: 30 000 values at n = 10⁸).
//! - **Where the tail ends** ([`TAIL_END_P`]): the probability, under the fitted tail, that the
//!   largest of its M weights is no larger than the largest seen, F(x₍M₎)^M (the extreme order
//!   statistic's law, a goodness-of-fit check at the far end of the fit). Weights that are
//!   bounded (NIS mixes a uniform density into its flow, so f/q_mix ≤ max f/λ) can be
//!   locally heavy at the top 1 % and then stop: a flow that cannot follow a steep rise of f at
//!   the cube's face gives a run of weights up to a ceiling, k̂ > 1/2 and a largest weight far
//!   below where a tail of that shape reaches. There the sample has seen the weights' whole
//!   range, so its moments are those of the weights; k̂ then does not warn if the variance
//!   estimate is also accurate ([`SETTLED_VAR_REL_ERR`]): a few points on a sharp peak end the
//!   tail too, but they leave the error bar itself uncertain.
//! - **Effective sample size** (Σ|w|)²/Σw²: the number of equally weighted samples that would
//!   carry as much information; a small ESS/n says a few weights carry the estimate.
//! - **Relative error of the variance estimate**, √Var(s²)/s² ≈ √((m₄/s⁴ − (n−3)/(n−1))/n) from
//!   the streamed central moments: how far the error bar itself may be off (its own error is
//!   about half of that).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// The limit on k: 1/2, where the weights' variance, and with it the error bar, stops existing.
/// A result warns when its k̂ lies above it by more than its noise ([`pareto_k_threshold`]).
/// PSIS's own practical threshold is 0.7, for the reliability of a (smoothed) mean; for error
/// bars `nis bench coverage` measured 1/2 as the one that works (docs/results/robustness.md,
/// "Coverage of the error bars over seeds": at 0.7 the runs left unflagged undercover).
pub const PARETO_K_LIMIT: f64 = 0.5;

/// How many of its standard errors k̂ must lie above [`PARETO_K_LIMIT`] for a result to warn: a
/// one-sided test at 5 % that the true k exceeds 1/2, so that a converged sampler whose k sits
/// just below 1/2 does not warn on a third of its runs by the noise of k̂ alone
/// (docs/results/robustness.md, "The k̂ warning as a test").
pub const PARETO_K_Z: f64 = 1.645;

/// The k̂ above which a result whose k̂ was fitted to `tail` weights warns:
/// [`PARETO_K_LIMIT`] + [`PARETO_K_Z`]·(1 + k)/√M at k = 1/2, (1 + k)/√M being the standard
/// error of a generalized Pareto shape fitted to M exceedances (the maximum-likelihood
/// asymptotics, which Zhang and Stephens' estimator attains): 0.64 at M = 300 (10⁴ weights),
/// 0.58 at M = 949 (10⁵), 0.525 at M = 9,487 (10⁷). Infinite without a fit.
pub fn pareto_k_threshold(tail: usize) -> f64 {
    if tail == 0 {
        return f64::INFINITY;
    }
    PARETO_K_LIMIT + PARETO_K_Z * (1.0 + PARETO_K_LIMIT) / (tail as f64).sqrt()
}

/// Below this probability of the largest tail weight under the fitted tail
/// ([`Reliability::tail_end_p`]) the tail ends within the sample: a test at 0.1 % that the fit
/// reaches as far as its own largest weight, so a true tail of shape k̂ is taken for one that
/// ends about once in a thousand runs (measured in the tests below).
pub const TAIL_END_P: f64 = 1e-3;

/// The largest relative error of the variance estimate ([`Reliability::var_rel_err`]) at which
/// a tail that ends within the sample ([`TAIL_END_P`]) quiets k̂. With the weights' moments
/// sound, the normal interval's error is at most 0.56·√(kurtosis/n) (Berry–Esseen), about
/// 0.56 times this: 6 %. A sharp peak that a few points found ends the tail too, but its
/// kurtosis leaves both the error bar and the normal interval uncertain, and k̂ warns.
pub const SETTLED_VAR_REL_ERR: f64 = 0.1;

/// What a warning tells the user to do, at the end of its sentence: a run may have stopped
/// short, so more evaluations are the first remedy.
pub(crate) const ADVICE_MORE: &str = "use more evaluations, check with a second seed, or use \
     channels for a multi-peaked integrand";

/// What a warning tells the user to do once a run has met its precision target, in place of
/// [`ADVICE_MORE`]: more evaluations are what the target already decided.
pub(crate) const ADVICE_MET: &str = "the run met its target, and more evaluations would not show \
     what it missed: check the answer with a second seed, or use channels for a multi-peaked \
     integrand";

/// The fewest tail weights k̂ is fitted to; with fewer (n < 25) it is not reported.
const MIN_TAIL: usize = 5;

/// The number of tail weights PSIS fits to for `n` weights: ⌈min(n/5, 3√n)⌉.
pub fn tail_len(n: u64) -> usize {
    let n = n as f64;
    (0.2 * n).min(3.0 * n.sqrt()).ceil() as usize
}

/// PSIS's k̂ of `n` weights from their largest values `top` (any order; at least the M + 1
/// largest): the M largest above the (M+1)-th; NaN with too few. With the M it was fitted to
/// (0 without a fit) and the tail's [`Reliability::tail_end_p`] (NaN without a fit).
fn k_hat(mut top: Vec<f64>, n: u64) -> (f64, usize, f64) {
    top.sort_by(f64::total_cmp);
    let m = tail_len(n).min(top.len().saturating_sub(1));
    if n < 25 || m < MIN_TAIL {
        return (f64::NAN, 0, f64::NAN);
    }
    let tail = &top[top.len() - m - 1..];
    let x: Vec<f64> = tail[1..].iter().map(|v| v - tail[0]).collect();
    match gpd_fit(&x) {
        Some(fit) => (fit.k, m, fit.largest_p(x[m - 1], m)),
        None => (f64::NAN, 0, f64::NAN),
    }
}

/// A generalized Pareto distribution fitted to exceedances.
#[derive(Clone, Copy, Debug)]
struct GpdFit {
    /// The shape PSIS reports, drawn towards 1/2 by its prior.
    k: f64,
    /// The shape and scale of the fit itself, before the prior.
    k_fit: f64,
    sigma: f64,
}

impl GpdFit {
    /// The probability that the largest of `m` exceedances of the fitted distribution is at most
    /// `largest`: F(largest)^m, F(x) = 1 − (1 + k·x/σ)^(−1/k). 1 for a fit with k ≤ 0 (a
    /// bounded fit has no far end to miss).
    fn largest_p(&self, largest: f64, m: usize) -> f64 {
        let (k, sigma) = (self.k_fit, self.sigma);
        if k <= 0.0 || sigma <= 0.0 || !sigma.is_finite() {
            return 1.0;
        }
        let survival = (-(k * largest / sigma).ln_1p() / k).exp();
        (m as f64 * (-survival).ln_1p()).exp()
    }
}

/// The effective sample size (Σ|w|)²/Σw² of weights with these sums (0 for all zero).
fn ess(sum_abs: f64, sum_sq: f64) -> f64 {
    if sum_sq > 0.0 {
        sum_abs * sum_abs / sum_sq
    } else {
        0.0
    }
}

/// The shape k̂ of a generalized Pareto distribution fitted to exceedances `x` (non-negative,
/// sorted ascending, not all zero) by Zhang and Stephens' (2009) empirical-Bayes estimator, with
/// the weakly informative prior PSIS puts on it (10 pseudo-observations at k = 1/2).
/// `None` when there are too few exceedances or they are all equal.
pub fn gpd_shape(x: &[f64]) -> Option<f64> {
    gpd_fit(x).map(|fit| fit.k)
}

/// [`gpd_shape`] with the fit's own shape and scale (σ = −k/θ̂ for the fit's θ̂ = −k/σ).
fn gpd_fit(x: &[f64]) -> Option<GpdFit> {
    let n = x.len();
    if n < MIN_TAIL || x[n - 1] <= 0.0 || x[0] == x[n - 1] {
        return None;
    }
    let nf = n as f64;
    // Candidate values of θ = −k/σ on a grid that Zhang and Stephens derive from the largest
    // exceedance and the first quartile; each weighted by its profile likelihood.
    let m = 30 + (nf.sqrt() as usize);
    let quartile = x[((nf / 4.0 + 0.5) as usize).max(1) - 1].max(f64::MIN_POSITIVE);
    let theta: Vec<f64> = (1..=m)
        .map(|j| 1.0 / x[n - 1] + (1.0 - (m as f64 / (j as f64 - 0.5)).sqrt()) / (3.0 * quartile))
        .collect();
    let shape_at = |t: f64| x.iter().map(|&v| (-t * v).ln_1p()).sum::<f64>() / nf;
    let log_lik: Vec<f64> = theta
        .iter()
        .map(|&t| {
            let k = shape_at(t);
            nf * ((-t / k).ln() - k - 1.0)
        })
        .collect();
    // Posterior weights 1/Σ_j exp(ℓ_j − ℓ_i), robust to the scale of ℓ; a NaN ℓ (θ = 0 exactly)
    // gets no weight.
    let weights: Vec<f64> = log_lik
        .iter()
        .map(|&li| {
            let s: f64 = log_lik.iter().map(|&lj| (lj - li).exp()).sum();
            if s.is_finite() && s > 0.0 {
                1.0 / s
            } else {
                0.0
            }
        })
        .collect();
    let total: f64 = weights.iter().sum();
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    let theta_hat = theta.iter().zip(&weights).map(|(t, w)| t * w).sum::<f64>() / total;
    let k_fit = shape_at(theta_hat);
    // PSIS's prior: shrink towards 1/2 as if 10 more observations had it.
    let k = (nf * k_fit + 10.0 * 0.5) / (nf + 10.0);
    k.is_finite().then_some(GpdFit {
        k,
        k_fit,
        sigma: -k_fit / theta_hat,
    })
}

/// The reliability figures of one result's weights (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reliability {
    /// PSIS's k̂ of the |w| tail (`NaN` when it cannot be fitted: fewer than 25 weights, or a
    /// tail of equal weights).
    pub pareto_k: f64,
    /// The k̂ above which the error bar cannot be trusted, for the tail k̂ was fitted to
    /// ([`pareto_k_threshold`]; infinite without a fit).
    pub pareto_k_limit: f64,
    /// The probability, under the tail k̂ was fitted to, that the largest of its weights is no
    /// larger than the largest seen: below [`TAIL_END_P`] the weights stop short of where such
    /// a tail reaches, and k̂ does not warn if `var_rel_err` is settled too
    /// ([`Reliability::k_warns`]; `NaN` without a fit).
    pub tail_end_p: f64,
    /// (Σ|w|)²/Σw².
    pub ess: f64,
    /// √Var(s²)/s², the relative error of the variance estimate (`NaN` for fewer than 4 weights
    /// or zero variance).
    pub var_rel_err: f64,
}

impl Reliability {
    /// Whether k̂ says the error bar cannot be trusted: above its limit, unless the tail ends
    /// within the sample ([`TAIL_END_P`]) and the variance estimate is accurate
    /// ([`SETTLED_VAR_REL_ERR`]).
    pub fn k_warns(&self) -> bool {
        let settled = self.tail_end_p < TAIL_END_P && self.var_rel_err <= SETTLED_VAR_REL_ERR;
        self.pareto_k > self.pareto_k_limit && !settled
    }

    /// A sentence for the user when the error bar cannot be trusted, else `None`.
    pub fn warning(&self) -> Option<String> {
        self.k_warns().then(|| {
            format!(
                "the weights f/q are heavy-tailed (Pareto k̂ = {:.2}, above {PARETO_K_LIMIT} \
                 beyond its noise: the limit is {:.2} for this tail; effective sample size \
                 {:.0}): the error bar cannot be trusted and is probably too small; \
                 {ADVICE_MORE}",
                self.pareto_k, self.pareto_k_limit, self.ess
            )
        })
    }
}

/// Streams weights into the figures of [`Reliability`] in memory that does not grow with n
/// beyond the PSIS tail (⌈3√n⌉ + 1 values for the planned n).
#[derive(Clone, Debug)]
pub struct WeightTail {
    capacity: usize,
    /// The largest |w| so far (as f64 bits: for non-negative floats the bit order is the numeric
    /// order), smallest on top.
    heap: BinaryHeap<Reverse<u64>>,
    n: u64,
    sum_abs: f64,
    sum_sq: f64,
    /// Mean and central moment sums M₂, M₃, M₄ of w, merged batch by batch (Pébay's formulas).
    mean: f64,
    m2: f64,
    m3: f64,
    m4: f64,
}

impl WeightTail {
    /// For about `planned` weights in all: keeps the PSIS tail of that many, plus the cutoff.
    pub fn new(planned: u64) -> WeightTail {
        WeightTail::with_capacity(tail_len(planned.max(1)) + 1)
    }

    /// No weights yet, keeping the `capacity` largest.
    fn with_capacity(capacity: usize) -> WeightTail {
        WeightTail {
            capacity,
            heap: BinaryHeap::new(),
            n: 0,
            sum_abs: 0.0,
            sum_sq: 0.0,
            mean: 0.0,
            m2: 0.0,
            m3: 0.0,
            m4: 0.0,
        }
    }

    /// Keeps |w| (as its bits) if it is among the `capacity` largest so far.
    fn offer(&mut self, bits: u64) {
        if self.heap.len() < self.capacity {
            self.heap.push(Reverse(bits));
        } else if self.heap.peek().is_some_and(|Reverse(low)| bits > *low) {
            self.heap.pop();
            self.heap.push(Reverse(bits));
        }
    }

    /// Adds a batch of weights.
    pub fn add(&mut self, w: &[f64]) {
        if w.is_empty() {
            return;
        }
        for &v in w {
            let a = v.abs();
            self.sum_abs += a;
            self.sum_sq += a * a;
            self.offer(a.to_bits());
        }
        // The batch's own central moments, two-pass, then merged into the running ones.
        let nb = w.len() as f64;
        let mb = w.iter().sum::<f64>() / nb;
        let (mut b2, mut b3, mut b4) = (0.0, 0.0, 0.0);
        for &v in w {
            let d = v - mb;
            let d2 = d * d;
            b2 += d2;
            b3 += d2 * d;
            b4 += d2 * d2;
        }
        self.merge_central(w.len() as u64, mb, [b2, b3, b4]);
    }

    /// Merges the mean `mb` and central moment sums `[M₂, M₃, M₄]` of `count` further weights
    /// (Pébay's formulas).
    fn merge_central(&mut self, count: u64, mb: f64, [b2, b3, b4]: [f64; 3]) {
        if count == 0 {
            return;
        }
        let nb = count as f64;
        let na = self.n as f64;
        let n = na + nb;
        let delta = mb - self.mean;
        let (d2, d3, d4) = (delta * delta, delta.powi(3), delta.powi(4));
        self.m4 += b4
            + d4 * na * nb * (na * na - na * nb + nb * nb) / n.powi(3)
            + 6.0 * d2 * (na * na * b2 + nb * nb * self.m2) / (n * n)
            + 4.0 * delta * (na * b3 - nb * self.m3) / n;
        self.m3 +=
            b3 + d3 * na * nb * (na - nb) / (n * n) + 3.0 * delta * (na * b2 - nb * self.m2) / n;
        self.m2 += b2 + d2 * na * nb / n;
        self.mean += delta * nb / n;
        self.n += count;
    }

    /// The weights seen.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// The count, Σ|w| and Σw² of the weights seen (sums that add over ranks).
    pub fn sums(&self) -> [f64; 3] {
        [self.n as f64, self.sum_abs, self.sum_sq]
    }

    /// An empty tail of the same capacity.
    pub fn emptied(&self) -> WeightTail {
        WeightTail::with_capacity(self.capacity)
    }

    /// Adds the weights `later` saw (after these): the largest of both heaps, the sums added and
    /// the central moments merged. The top |w| of the union are among the tops of the parts, so
    /// the tail is the one of all the weights together.
    pub fn merge(&mut self, later: &WeightTail) {
        for &Reverse(bits) in &later.heap {
            self.offer(bits);
        }
        self.sum_abs += later.sum_abs;
        self.sum_sq += later.sum_sq;
        self.merge_central(later.n, later.mean, [later.m2, later.m3, later.m4]);
    }

    /// The state as numbers, to send to other processes ([`WeightTail::from_words`]).
    pub fn to_words(&self) -> Vec<f64> {
        let mut out = vec![
            self.capacity as f64,
            self.n as f64,
            self.sum_abs,
            self.sum_sq,
            self.mean,
            self.m2,
            self.m3,
            self.m4,
        ];
        out.extend(self.heap.iter().map(|Reverse(b)| f64::from_bits(*b)));
        out
    }

    /// The tail [`WeightTail::to_words`] gave `words` (empty for fewer words than its header).
    pub fn from_words(words: &[f64]) -> WeightTail {
        if words.len() < 8 {
            return WeightTail::new(1);
        }
        WeightTail {
            capacity: words[0] as usize,
            heap: words[8..].iter().map(|v| Reverse(v.to_bits())).collect(),
            n: words[1] as u64,
            sum_abs: words[2],
            sum_sq: words[3],
            mean: words[4],
            m2: words[5],
            m3: words[6],
            m4: words[7],
        }
    }

    /// The figures of a sum of independent estimates, each the mean of one tail's weights, for
    /// the weights w·`scale` of every tail pooled: with scale 1/n of each tail's count, every
    /// pooled weight is its point's share of the sum, so k̂ reads the tail of the points that
    /// move the sum (a part whose weights are small beside the others' weighs little). Only
    /// the pooled values above every full heap's smallest kept value are known to be the pooled
    /// tail; k̂ is fitted to at most PSIS's M of those. `var_rel_err` is that of the sum's
    /// variance Σ s²·n·σ², from each tail's: Var = Σ s⁴·n²·Var(σ̂²).
    pub fn pooled(tails: &[(&WeightTail, f64)]) -> Reliability {
        let n: u64 = tails.iter().map(|(t, _)| t.n).sum();
        let known = tails
            .iter()
            .filter(|(t, _)| t.heap.len() >= t.capacity)
            .filter_map(|(t, s)| t.heap.peek().map(|Reverse(b)| f64::from_bits(*b) * s))
            .fold(0.0f64, f64::max);
        let top: Vec<f64> = tails
            .iter()
            .flat_map(|(t, s)| t.heap.iter().map(move |Reverse(b)| f64::from_bits(*b) * s))
            .filter(|v| *v >= known)
            .collect();
        let sum_abs: f64 = tails.iter().map(|(t, s)| t.sum_abs * s).sum();
        let sum_sq: f64 = tails.iter().map(|(t, s)| t.sum_sq * s * s).sum();
        let (pareto_k, m, tail_end_p) = k_hat(top, n);
        // Σ s²·n·σ² and Σ s⁴·n²·Var(σ̂²) over the tails (NaN when one has no variance).
        let (var, var_var) = tails.iter().fold((0.0, 0.0), |(a, b), (t, s)| {
            let nt = t.n as f64;
            match t.variance_and_its_variance() {
                Some((v, vv)) => (a + s * s * nt * v, b + s.powi(4) * nt * nt * vv),
                None => (f64::NAN, f64::NAN),
            }
        });
        let var_rel_err = if var > 0.0 {
            var_var.sqrt() / var
        } else {
            f64::NAN
        };
        Reliability {
            pareto_k,
            pareto_k_limit: pareto_k_threshold(m),
            tail_end_p,
            ess: ess(sum_abs, sum_sq),
            var_rel_err,
        }
    }

    /// The weights' variance σ² ≈ M₂/n and the variance of its estimate,
    /// (m₄ − σ⁴·(n−3)/(n−1))/n with m₄ = M₄/n (`None` for fewer than 4 weights or no spread).
    fn variance_and_its_variance(&self) -> Option<(f64, f64)> {
        if self.n < 4 || self.m2 <= 0.0 {
            return None;
        }
        let nf = self.n as f64;
        let var = self.m2 / nf;
        let fourth = self.m4 / nf;
        Some((
            var,
            (fourth - var * var * (nf - 3.0) / (nf - 1.0)).max(0.0) / nf,
        ))
    }

    /// The figures for the weights so far.
    pub fn reliability(&self) -> Reliability {
        let n = self.n;
        // The PSIS tail of the weights seen: the M largest above the (M+1)-th.
        let top: Vec<f64> = self
            .heap
            .iter()
            .map(|Reverse(b)| f64::from_bits(*b))
            .collect();
        let (pareto_k, m, tail_end_p) = k_hat(top, n);
        let ess = ess(self.sum_abs, self.sum_sq);
        let var_rel_err = self
            .variance_and_its_variance()
            .map_or(f64::NAN, |(var, var_var)| var_var.sqrt() / var);
        Reliability {
            pareto_k,
            pareto_k_limit: pareto_k_threshold(m),
            tail_end_p,
            ess,
            var_rel_err,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn rng(seed: u64) -> rand_pcg::Pcg64Mcg {
        rand_pcg::Pcg64Mcg::seed_from_u64(seed)
    }

    /// The share of `runs` runs of `n` Pareto weights u^(−k) (a tail of shape k) whose k̂ warns.
    fn warned_share(k: f64, n: u64, runs: u64, seed: u64) -> f64 {
        let mut r = rng(seed);
        let mut warned = 0;
        for _ in 0..runs {
            let mut tail = WeightTail::new(n);
            let w: Vec<f64> = (0..n).map(|_| (1.0 - r.random::<f64>()).powf(-k)).collect();
            tail.add(&w);
            let rel = tail.reliability();
            assert_eq!(rel.pareto_k_limit, pareto_k_threshold(tail_len(n)));
            warned += rel.warning().is_some() as u64;
        }
        warned as f64 / runs as f64
    }

    #[test]
    fn the_k_hat_warning_is_a_test_at_five_per_cent_with_power_beyond_it() {
        // At the boundary k = 1/2 the warning fires on about 5 % of the runs (the test's level;
        // 400 runs: binomial σ = 0.011), at 10⁴ weights (M = 300) and at 10⁵ (M = 949).
        for (n, seed) in [(10_000, 1), (100_000, 2)] {
            let at = warned_share(0.5, n, 400, seed);
            assert!((0.015..=0.085).contains(&at), "n = {n}: {at}");
        }
        // Just below it, where a plain k̂ > 1/2 flagged a quarter of the runs, almost never.
        let below = warned_share(0.45, 10_000, 400, 3);
        assert!(below <= 0.02, "{below}");
        // Weights of infinite variance, k = 0.75: the power the standard error predicts,
        // P(k̂ > 0.64) ≈ 0.86 at M = 300 (σ ≈ 1.75/√M), nearly 1 at M = 949.
        let above = warned_share(0.75, 10_000, 200, 4);
        assert!(above >= 0.75, "{above}");
        let above = warned_share(0.75, 100_000, 100, 5);
        assert!(above >= 0.97, "{above}");
    }

    /// Of `runs` runs of `n` weights from `draw`, the share whose k̂ lies above its limit, and
    /// the share of those whose tail ends within the sample with a settled variance estimate.
    fn settled_shares(
        n: u64,
        runs: u64,
        seed: u64,
        draw: impl Fn(&mut rand_pcg::Pcg64Mcg) -> f64,
    ) -> (f64, f64) {
        let mut r = rng(seed);
        let (mut above, mut settled) = (0u64, 0u64);
        for _ in 0..runs {
            let mut tail = WeightTail::new(n);
            let w: Vec<f64> = (0..n).map(|_| draw(&mut r)).collect();
            tail.add(&w);
            let rel = tail.reliability();
            if rel.pareto_k > rel.pareto_k_limit {
                above += 1;
                settled += !rel.k_warns() as u64;
            }
        }
        (
            above as f64 / runs as f64,
            settled as f64 / above.max(1) as f64,
        )
    }

    #[test]
    fn a_tail_that_goes_on_is_not_taken_for_one_that_ends() {
        // Pareto weights of infinite variance: their largest weight is where the fitted tail
        // reaches, so the test at 0.1 % quiets almost none (400 runs each: 2 allowed).
        for (k, n, seed) in [(0.6, 100_000, 11), (0.75, 10_000, 12), (1.0, 100_000, 13)] {
            let (above, settled) =
                settled_shares(n, 400, seed, |r| (1.0 - r.random::<f64>()).powf(-k));
            assert!(above > 0.3, "k = {k}: {above}");
            assert!(settled * above * 400.0 <= 2.0, "k = {k}: {settled}");
        }
    }

    #[test]
    fn a_locally_heavy_tail_that_stops_short_does_not_warn() {
        // Weights spread evenly over [0.6, 1.4] but for their top 1 %, which rises from 1.4 as
        // t^(−3/2) for t uniform on [t₀, 0.01] up to a ceiling of 3.4 (as a flow that cannot
        // follow a steep rise of f at a face of the cube gives): heavy in shape there, so k̂
        // lies above its limit, but the largest weight lies far below where such a tail reaches
        // and the variance estimate is accurate: no warning.
        let t0: f64 = 2e-4;
        let c = 2.0 / (t0.powf(-1.5) - 1e3);
        let (above, settled) = settled_shares(100_000, 100, 14, |r| {
            let t = r.random::<f64>();
            if t < 0.01 {
                1.4 + c * ((t0 + t * (1.0 - 100.0 * t0)).powf(-1.5) - 1e3)
            } else {
                0.6 + 0.8 * r.random::<f64>()
            }
        });
        assert!(above > 0.5, "{above}");
        assert!(settled > 0.95, "{settled}");
        // w = 1 + c·t^(−3/2), t uniform on [t₀, 1]: a sharp peak that few points find, cut
        // off at 700 times the typical weight, ends its tail too but leaves the variance
        // estimate uncertain (its relative error about 0.2): k̂ warns.
        let (above, settled) = settled_shares(100_000, 100, 15, |r| {
            1.0 + 0.002 * (t0 + (1.0 - t0) * r.random::<f64>()).powf(-1.5)
        });
        assert!(above > 0.5, "{above}");
        assert!(settled < 0.05, "{settled}");
    }

    #[test]
    fn tails_merged_from_parts_are_the_tail_of_the_whole() {
        // What ranks do before `finish`: each keeps the tail of its own weights, and the parts,
        // sent as words and merged in order, must give the figures of all the weights together:
        // the same top |w| (so the same k̂, exactly), the same n, and sums and moments equal up
        // to the rounding of summing in another order.
        let mut r = rng(21);
        let n = 30_001u64;
        let w: Vec<f64> = (0..n)
            .map(|_| (1.0 - r.random::<f64>()).powf(-0.7) - 0.9)
            .collect();
        let mut whole = WeightTail::new(n);
        for chunk in w.chunks(4_096) {
            whole.add(chunk);
        }
        let mut merged = whole.emptied();
        for part in [&w[..1], &w[1..12_345], &w[12_345..12_345], &w[12_345..]] {
            let mut t = whole.emptied();
            for chunk in part.chunks(4_096) {
                t.add(chunk);
            }
            merged.merge(&WeightTail::from_words(&t.to_words()));
        }
        let sorted = |t: &WeightTail| {
            let mut v: Vec<u64> = t.heap.iter().map(|Reverse(b)| *b).collect();
            v.sort_unstable();
            v
        };
        assert_eq!(merged.n, n);
        assert_eq!(sorted(&merged), sorted(&whole));
        let (a, b) = (whole.reliability(), merged.reliability());
        assert_eq!(a.pareto_k.to_bits(), b.pareto_k.to_bits());
        assert!(
            (a.ess / b.ess - 1.0).abs() < 1e-12,
            "{} vs {}",
            a.ess,
            b.ess
        );
        assert!(
            (a.var_rel_err / b.var_rel_err - 1.0).abs() < 1e-9,
            "{} vs {}",
            a.var_rel_err,
            b.var_rel_err
        );
    }

    #[test]
    fn pooled_tails_judge_the_points_that_move_the_sum() {
        let tail_of = |seed: u64, n: u64, xi: f64| {
            let mut r = rng(seed);
            let mut t = WeightTail::new(n);
            let w: Vec<f64> = (0..n)
                .map(|_| (1.0 - r.random::<f64>()).powf(-xi))
                .collect();
            t.add(&w);
            t
        };
        // One tail pooled alone is that tail (k̂ exactly at scale 1; neither k̂ nor the ESS
        // depends on the scale but by rounding).
        let heavy = tail_of(6, 100_000, 0.8);
        let own = heavy.reliability();
        let alone = WeightTail::pooled(&[(&heavy, 1.0)]);
        assert_eq!(alone.pareto_k.to_bits(), own.pareto_k.to_bits());
        let scaled = WeightTail::pooled(&[(&heavy, 1e-5)]);
        assert!((scaled.pareto_k - own.pareto_k).abs() < 1e-9);
        assert!((scaled.ess / own.ess - 1.0).abs() < 1e-12);
        // So is the relative error of its variance estimate, at any scale.
        for r in [alone, scaled] {
            assert!(
                (r.var_rel_err / own.var_rel_err - 1.0).abs() < 1e-9,
                "{r:?}"
            );
        }
        // Two samples of one distribution at one scale: the tail of the two merged.
        let other = tail_of(7, 100_000, 0.8);
        let mut merged = WeightTail::new(200_000);
        merged.merge(&heavy);
        merged.merge(&other);
        let two = WeightTail::pooled(&[(&heavy, 1.0), (&other, 1.0)]);
        assert!((two.pareto_k - merged.reliability().pareto_k).abs() < 0.05);
        // The sum of two parts' means (equal counts, scale 1): its variance n·(v₁ + v₂) is
        // estimated with the variance n²·(r₁²v₁² + r₂²v₂²) from each part's variance v and
        // relative error r.
        let (r1, r2) = (
            heavy.reliability().var_rel_err,
            other.reliability().var_rel_err,
        );
        let (v1, v2) = (heavy.m2 / heavy.n as f64, other.m2 / other.n as f64);
        let want = ((r1 * v1).powi(2) + (r2 * v2).powi(2)).sqrt() / (v1 + v2);
        assert!(
            (two.var_rel_err / want - 1.0).abs() < 1e-9,
            "{} vs {want}",
            two.var_rel_err
        );
        // A heavy-tailed part whose points move the sum little (its weights a thousandth of a
        // light part's) leaves k̂ to the light part, and warns when it does move the sum.
        let light = tail_of(8, 100_000, 0.2);
        let quiet = WeightTail::pooled(&[(&heavy, 1e-3), (&light, 1.0)]);
        assert!(
            quiet.pareto_k < 0.4 && quiet.warning().is_none(),
            "{quiet:?}"
        );
        let loud = WeightTail::pooled(&[(&heavy, 1.0), (&light, 1e-3)]);
        assert!(loud.pareto_k > 0.6 && loud.warning().is_some(), "{loud:?}");
    }

    #[test]
    fn k_hat_recovers_the_tail_index_of_pareto_weights() {
        // w = U^(−ξ) has a Pareto tail with shape ξ. With n = 10⁵ weights PSIS fits M = 949 of
        // them; the estimator's standard deviation is about (1 + ξ)/√M ≈ 0.04–0.06, and the
        // prior moves k̂ by at most 10/(M + 10)·|ξ − 1/2| < 0.01: 4σ + that bias allowed.
        for (seed, xi) in [(1u64, 0.2f64), (2, 0.5), (3, 0.8), (4, 1.2)] {
            let mut r = rng(seed);
            let n = 100_000u64;
            let mut tail = WeightTail::new(n);
            let w: Vec<f64> = (0..n)
                .map(|_| (1.0 - r.random::<f64>()).powf(-xi))
                .collect();
            for chunk in w.chunks(7_777) {
                tail.add(chunk);
            }
            let k = tail.reliability().pareto_k;
            let sd = (1.0 + xi) / (tail_len(n) as f64).sqrt();
            assert!((k - xi).abs() < 4.0 * sd + 0.01, "ξ = {xi}: k̂ = {k}");
        }
    }

    #[test]
    fn bounded_weights_have_a_negative_k_hat_and_no_warning() {
        // Uniform weights: the exceedances over a high cutoff are uniform, a GPD with k = −1.
        let mut r = rng(5);
        let mut tail = WeightTail::new(50_000);
        let w: Vec<f64> = (0..50_000).map(|_| r.random::<f64>()).collect();
        tail.add(&w);
        let rel = tail.reliability();
        assert!(rel.pareto_k < 0.0, "k̂ = {}", rel.pareto_k);
        assert!(rel.warning().is_none());
        // ESS of uniform weights: n·E[w]²/E[w²] = n·(1/4)/(1/3) = 0.75 n, to within 3% here.
        assert!((rel.ess / 50_000.0 - 0.75).abs() < 0.02, "ESS {}", rel.ess);
    }

    #[test]
    fn streaming_moments_match_a_two_pass_computation_on_uneven_batches() {
        let mut r = rng(6);
        let w: Vec<f64> = (0..10_001)
            .map(|_| (-r.random::<f64>().ln()).powi(2) - 1.0)
            .collect();
        let mut tail = WeightTail::new(w.len() as u64);
        let mut start = 0;
        for len in [1, 2, 3, 500, 4_000, 5_495] {
            tail.add(&w[start..start + len]);
            start += len;
        }
        assert_eq!(start, w.len());
        let n = w.len() as f64;
        let mean = w.iter().sum::<f64>() / n;
        let m2: f64 = w.iter().map(|v| (v - mean).powi(2)).sum();
        let m4: f64 = w.iter().map(|v| (v - mean).powi(4)).sum();
        assert!((tail.mean - mean).abs() < 1e-12 * mean.abs().max(1.0));
        assert!((tail.m2 / m2 - 1.0).abs() < 1e-10);
        assert!((tail.m4 / m4 - 1.0).abs() < 1e-10);
        // The relative error of s² for exponential-squared weights is large but finite.
        let rel = tail.reliability().var_rel_err;
        let s2 = m2 / n;
        let expected = ((m4 / n / (s2 * s2) - (n - 3.0) / (n - 1.0)) / n).sqrt();
        assert!((rel / expected - 1.0).abs() < 1e-9);
    }

    #[test]
    fn the_variance_error_estimate_matches_the_spread_of_variance_estimates() {
        // 400 samples of s² from n = 500 exponential weights: the spread of s²/σ² over the
        // samples against the reported relative error (its own sampling error is ~10% here,
        // and the spread over 400 samples is good to 1/√800 ≈ 3.5%): within 25%.
        let mut r = rng(7);
        let (n, reps) = (500, 400);
        let mut s2s = Vec::new();
        let mut reported = 0.0;
        for _ in 0..reps {
            let w: Vec<f64> = (0..n).map(|_| -r.random::<f64>().ln()).collect();
            let mut tail = WeightTail::new(n as u64);
            tail.add(&w);
            reported += tail.reliability().var_rel_err / reps as f64;
            let mean = w.iter().sum::<f64>() / n as f64;
            s2s.push(w.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64);
        }
        // σ² = 1 for Exp(1).
        let spread = (s2s.iter().map(|s| (s - 1.0).powi(2)).sum::<f64>() / reps as f64).sqrt();
        assert!(
            (reported / spread - 1.0).abs() < 0.25,
            "{reported} vs {spread}"
        );
    }

    #[test]
    fn too_few_or_equal_weights_give_no_k_hat() {
        let mut t = WeightTail::new(10);
        t.add(&[1.0; 10]);
        assert!(t.reliability().pareto_k.is_nan());
        let mut t = WeightTail::new(1_000);
        t.add(&[2.5; 1_000]);
        let rel = t.reliability();
        assert!(rel.pareto_k.is_nan() && rel.warning().is_none());
        assert_eq!(rel.ess, 1_000.0);
        assert!(rel.var_rel_err.is_nan());
        let empty = WeightTail::new(100).reliability();
        assert!(empty.pareto_k.is_nan() && empty.ess == 0.0);
    }

    #[test]
    fn the_heap_keeps_only_the_psis_tail() {
        let mut t = WeightTail::new(1_000_000);
        let mut r = rng(8);
        for _ in 0..100 {
            let w: Vec<f64> = (0..10_000).map(|_| r.random::<f64>()).collect();
            t.add(&w);
        }
        assert_eq!(t.heap.len(), tail_len(1_000_000) + 1);
        assert_eq!(tail_len(1_000_000), 3_000);
    }
}
