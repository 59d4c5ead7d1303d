//! Every evaluation counts: training batches replayed in later steps ([`ReplayBuffer`],
//! [`NisConfig::replay_batches`](super::NisConfig)), and the last training batches in the estimate
//! ([`NisConfig::reuse_training`](super::NisConfig)): they join the final phase's iterations with
//! shares fixed before each batch is drawn, so that the combined estimate stays unbiased.
//!
//! # Replay
//! A batch's points X_i ~ q_s (the flow as it stood) stay valid training data after the flow has
//! moved on: every loss here has the gradient −Σ w_i ∇ ln q(X_i; θ) with weights built from
//! f_i/q_s(X_i) (see [`crate::loss`]), so a kept batch with its ln q_s gives an unbiased (up to
//! the normalisation Adam absorbs) gradient of the current flow's loss, at the cost of a forward
//! and backward pass but no evaluation of the integrand (MadNIS's buffered training, Heimel et
//! al. 2023). Kept batches are replayed newest first, in turn, so the choice draws no random
//! numbers and the training stream, and with it determinism, is untouched.
//!
//! # Training in the estimate
//! Each training batch b is drawn from the defensive mixture q_b of the flow as it stands before
//! the batch, so its mean weight I_b = mean f/q_b estimates ∫ f without bias given everything
//! before it: E[I_b | past] = I, whatever the tempered target the flow is learning (β only
//! enters the loss, never the weights f/q). The estimate is
//!
//!   Î = Σ_b a_b·I_b + a_F·I_F,   a_b fixed by the batches before b,   a_F = 1 − Σ_b a_b,
//!
//! with I_F the final phase's pooled estimate. Every share is known before its batch's points are
//! drawn (a_F before the final phase starts) and the shares sum to one by construction, not by
//! dividing by a random total, so Î − I = Σ a_j·(I_j − I) is a sum of martingale differences:
//! E[Î] = I exactly. (Weights normalised by their random sum, Σ w_b I_b / Σ w_b, are not
//! unbiased in general even for predictable w_b: the total depends on earlier batches' values.)
//! For the same reason Var(Î) = Σ E[a_j²·Var(I_j | past)], estimated without bias by
//! Σ a_j²·V_j with each batch's own variance estimate V_j = s_j²/n_j (the i.i.d. formula, which
//! errs high for a batch with fixed counts of each mixture component).
//!
//! The shares: batch b (among the last `reuse_training` of the batches, fixed in advance — the
//! early ones come from a nearly uniform, possibly tempered flow) takes from what is left, r, the
//! part π_b·r with
//!
//!   π_b = n_b·ρ_b / (n_b·ρ_b + M_b + g_b·N_F),   ρ_b = min_{c<b} s_c² / s_{b−1}²  ∈ [0, 1],
//!
//! where M_b counts the training evaluations still to come after b, N_F the final phase's, s_c²
//! is batch c's per-point variance of f/q, and g_b ≥ 1 the final phase's predicted gain per
//! evaluation over a training batch. This is inverse-variance weighting of b (predicted as noisy
//! as its predecessor) against later batches as good as the best so far and a final phase g_b
//! times better, using only earlier batches: with equal variances and g = 1 every kept
//! evaluation gets weight 1/N (the pooled mean), and a batch whose predecessor was noisier than
//! the best gets proportionally less. Since the flow only improves on average, the assumption
//! errs on the side of giving training batches too little rather than too much. The window
//! matters: with all batches kept (1), the early ones, whose best-so-far is itself poor, get
//! nearly count shares and the error bar grows (docs/ESTIMATE.md).
//!
//! g_b: an i.i.d. final phase is no better than a training batch (g = 1). A stratified one
//! ([`super::stratified_latent`]) is, by as much as its latent grid and allocation gain, and the training
//! batches predict it: their flow share was drawn from uniform latents z (redrawn from a copy
//! of the training stream), so post-stratifying its weights on the final phase's own grid
//! (Cochran's post-stratification) measures what stratifying them would have given. A batch of
//! 256 points (the default) on the ~7000 hypercubes of a budget of 10⁶ leaves few hypercubes
//! with two points, but each such pair is an unbiased sample of its hypercube's variance, so the last
//! batches are pooled until they hold [`POST_STRATIFIED_DF`] within-hypercube degrees of
//! freedom: g_b = (i.i.d. over within-hypercube mean square) × the allocation's gain estimated
//! from the pairs' differences ([`PostStratified::allocation_gain`]). Both come from batches
//! before b, so the shares stay predictable and the estimate unbiased whatever the prediction's
//! error; the error costs only efficiency. It is asymmetric: a prediction too good hands the
//! final phase more (at worst everything: the final phase alone), one too poor over-weights
//! noisier training batches. So where the estimate must guess (the within-hypercube spread from
//! pairs) it errs towards the final phase; measured on the suite it over-predicts g in 2-d
//! (where the final phase gains most and training can add little) and is close in 4–8
//! (docs/results/integration.md).
//!
//! For display and χ²/dof, consecutive kept batches are pooled into as many groups as the final
//! phase has iterations (a group's estimate Σ a_b I_b / Σ a_b, its variance Σ a_b² V_b / (Σ a_b)²);
//! χ² then compares every group and final iteration with the combined estimate by its own
//! variance. The reliability figures (k̂, ESS, var_rel_err) see the kept batches' weights too; the
//! unweighting efficiency stays the final sampler's.

use std::collections::VecDeque;

use super::post_stratified::{post_stratified, PostStratified};
use super::stratified_latent::FinalPlan;
use super::NisConfig;
use crate::comm::Comm;
use crate::error::Result;
use crate::flow::mixture::{mix_log_density, MixtureBatch};
use crate::integrate::diagnostics::WeightTail;
use crate::integrate::moments::Moments;
use crate::integrate::{Accumulator, Iteration, Source};

/// The last `capacity` training batches (the flow's share of each), for off-policy replay.
pub(super) struct ReplayBuffer {
    capacity: usize,
    /// Oldest first.
    batches: VecDeque<Replayed>,
    /// Replay steps so far: which batch is next.
    turn: usize,
}

/// A kept batch: points (`n × D`), the target the flow learns at them, and ln q_s of the density
/// that drew them.
pub(super) struct Replayed {
    pub(super) x: Vec<f32>,
    pub(super) target: Vec<f64>,
    pub(super) log_q: Vec<f64>,
}

impl ReplayBuffer {
    /// Keeps up to `capacity` batches (0: none).
    pub(super) fn new(capacity: usize) -> ReplayBuffer {
        ReplayBuffer {
            capacity,
            batches: VecDeque::with_capacity(capacity),
            turn: 0,
        }
    }

    /// Keeps a batch, dropping the oldest when full.
    pub(super) fn push(&mut self, x: Vec<f32>, target: Vec<f64>, log_q: Vec<f64>) {
        if self.capacity == 0 {
            return;
        }
        if self.batches.len() == self.capacity {
            self.batches.pop_front();
        }
        self.batches.push_back(Replayed { x, target, log_q });
    }

    /// The batch to replay next: the newest, then older ones in turn (`None` while empty).
    pub(super) fn next(&mut self) -> Option<&Replayed> {
        let len = self.batches.len();
        if len == 0 {
            return None;
        }
        let i = len - 1 - self.turn % len;
        self.turn += 1;
        self.batches.get(i)
    }
}

/// The kept training batches of one `integrate` call, pooled into groups, with the share left for
/// the final phase.
pub(super) struct TrainingPieces {
    k: usize,
    /// Evaluations per batch (all ranks).
    batch: u64,
    /// Training batches planned, and the index of the first that may enter the estimate.
    batches: usize,
    first_kept: usize,
    /// Kept batches per group.
    per_group: usize,
    final_evals: u64,
    /// The share not yet given (the final phase's once training is over).
    remaining: f64,
    /// Per-point variance of f/q (component 0) of the previous batch, and the smallest so far.
    previous_var: Option<f64>,
    best_var: f64,
    /// The variance per evaluation of every batch, in order (for the convergence figures).
    history: Vec<f64>,
    /// How the final phase's stratified latent is predicted, when it has one.
    stratified: Option<StratifiedFinal>,
    groups: Vec<Group>,
    /// This rank's weights (component 0) of the batches that entered.
    tail: WeightTail,
}

/// What predicts the final phase's variance per evaluation when it stratifies the flow's latent:
/// the last batches post-stratified on the final phase's own grid.
struct StratifiedFinal {
    /// Strata per axis of the final phase's latent grid.
    grid: Vec<usize>,
    /// The sums of squares of the last batches, oldest first: as few as hold
    /// [`POST_STRATIFIED_DF`] within-hypercube degrees of freedom.
    recent: VecDeque<PostStratified>,
}

/// Within-hypercube degrees of freedom pooled for the prediction. A batch of n points on H
/// hypercubes has about n − H·(1 − e^(−n/H)) of them (pairs sharing a hypercube): ~5 for the
/// default 256 points on the ~7000 of a budget of 10⁶ (~70 for 1024), so a few hundred batches
/// (a few dozen of 1024) are pooled.
const POST_STRATIFIED_DF: f64 = 2000.0;

/// The smallest share a training batch enters with. Smaller ones come from a predicted final
/// phase ~10⁹ or more times better per evaluation (ridge d8: pairs in a hypercube mostly two
/// zeros, a gain of ~10¹⁷⁰, shares of ~10⁻¹⁷⁰ whose squares underflow).
const MIN_SHARE: f64 = 1e-9;

/// Consecutive kept batches: Σ a_b·mean_b, Σ a_b²·Cov_b, Σ a_b, their evaluations and the
/// largest and summed |w| of their weights (component 0).
struct Group {
    weighted_mean: Vec<f64>,
    weighted_cov: Vec<f64>,
    share: f64,
    evals: u64,
    max_abs_w: f64,
    sum_abs_w: f64,
    batches: usize,
}

impl TrainingPieces {
    /// The plan for `batches` training batches followed by the final phase `final_plan`, for an
    /// integrand of `k` components; `None` when no batch would enter (reuse off, or no batch).
    pub(super) fn plan(
        config: &NisConfig,
        final_plan: &FinalPlan,
        batches: usize,
        k: usize,
    ) -> Option<TrainingPieces> {
        let kept = (config.reuse_training * batches as f64).floor() as usize;
        // The first batch has no predecessor to predict its variance: it never enters.
        let kept = kept.min(batches.saturating_sub(1));
        if kept == 0 {
            return None;
        }
        let batch = config.batch as u64;
        let stratified = final_plan.grid().map(|grid| StratifiedFinal {
            grid: grid.to_vec(),
            recent: VecDeque::new(),
        });
        Some(TrainingPieces {
            k,
            batch,
            batches,
            first_kept: batches - kept,
            per_group: kept.div_ceil(final_plan.iterations),
            final_evals: final_plan.evals,
            remaining: 1.0,
            previous_var: None,
            best_var: f64::INFINITY,
            history: Vec::new(),
            stratified,
            groups: Vec::new(),
            tail: WeightTail::new(kept as u64 * batch),
        })
    }

    /// The share of batch `index`, from the batches before it only.
    fn share(&self, index: usize) -> f64 {
        let Some(previous) = self.previous_var else {
            return 0.0;
        };
        if index < self.first_kept {
            return 0.0;
        }
        // ρ = best/previous in [0, 1]; 0/0 (constant weights) is 1.
        let rho = if previous > 0.0 {
            (self.best_var / previous).min(1.0)
        } else {
            1.0
        };
        let later = ((self.batches - 1 - index) as u64 * self.batch) as f64;
        let n = self.batch as f64 * rho;
        let share = self.remaining * n / (n + later + self.final_evals as f64 * self.final_gain());
        // A share this small adds nothing measurable, and its square (a group's variance is
        // Σ a_b²·V_b / (Σ a_b)²) may leave f64's range: 0/0. Dropping it is decided from
        // earlier batches too, so the estimate stays unbiased.
        if share >= MIN_SHARE {
            share
        } else {
            0.0
        }
    }

    /// g: the predicted variance per evaluation of a training batch over the final phase's: 1
    /// for an i.i.d. final phase; for a stratified one, the gain of the last batches
    /// post-stratified on the final phase's grid (proportional stratification times the
    /// allocation's).
    fn final_gain(&self) -> f64 {
        let Some(s) = &self.stratified else {
            return 1.0;
        };
        s.recent
            .iter()
            .fold(PostStratified::default(), |a, b| a.plus(*b))
            .gain()
    }

    /// Batch `index` of training, as this rank drew it (`b`, the flow's share from the latents
    /// `z`) and evaluated it (`fx`, `n × k`): its share is fixed from the earlier batches, then
    /// its moments (merged over the ranks of `comm` in rank order) enter its group and predict
    /// the next batch's variance, and its flow share post-stratified on `z` the final phase's.
    pub(super) fn observe(
        &mut self,
        index: usize,
        b: &MixtureBatch,
        z: &[f32],
        fx: &[f64],
        comm: &Comm,
    ) {
        let w = batch_weights(b, fx, self.k);
        self.observe_weights(index, &w, z, comm);
    }

    /// Whether [`TrainingPieces::observe`] needs the latents of the flow's share.
    pub(super) fn needs_latents(&self) -> bool {
        self.stratified.is_some()
    }

    /// [`TrainingPieces::observe`] for this rank's weights f/q (`n × k`) of batch `index`, the
    /// first `z.len()/D` of them drawn by the flow from the latents `z`.
    fn observe_weights(&mut self, index: usize, w: &[f64], z: &[f32], comm: &Comm) {
        let share = self.share(index);
        if let Some(s) = self.stratified.as_mut() {
            let n_q = z.len() / s.grid.len();
            let flow_share: Vec<f64> = w.iter().step_by(self.k).take(n_q).copied().collect();
            let mut sums = post_stratified(z, &flow_share, &s.grid).to_array();
            // Plain sums, reduced in the fixed order of the rank count: every rank predicts the
            // same, with one reduction instead of a gather of every rank's sums.
            comm.sum_f64(&mut sums);
            s.recent.push_back(PostStratified::from_array(sums));
            // Drop the oldest while the rest hold enough degrees of freedom.
            while s.recent.len() > 1
                && s.recent.iter().skip(1).map(|p| p.within_df).sum::<f64>() >= POST_STRATIFIED_DF
            {
                s.recent.pop_front();
            }
        }
        let mut m = Moments::new(self.k);
        m.add(w);
        let m = m.across(comm);
        let (mean, cov) = m.mean_and_cov_of_mean();
        let var = cov[0] * m.n() as f64;
        if share > 0.0 {
            self.remaining -= share;
            let column: Vec<f64> = w.iter().step_by(self.k).copied().collect();
            self.tail.add(&column);
            let (max_abs_w, sum_abs_w) = m.abs_w();
            let k = self.k;
            if self
                .groups
                .last()
                .is_none_or(|g| g.batches == self.per_group)
            {
                self.groups.push(Group {
                    weighted_mean: vec![0.0; k],
                    weighted_cov: vec![0.0; k * k],
                    share: 0.0,
                    evals: 0,
                    max_abs_w: 0.0,
                    sum_abs_w: 0.0,
                    batches: 0,
                });
            }
            let g = self.groups.last_mut().expect("a group");
            g.weighted_mean
                .iter_mut()
                .zip(&mean)
                .for_each(|(a, v)| *a += share * v);
            g.weighted_cov
                .iter_mut()
                .zip(&cov)
                .for_each(|(a, v)| *a += share * share * v);
            g.share += share;
            g.evals += m.n();
            g.max_abs_w = g.max_abs_w.max(max_abs_w);
            g.sum_abs_w += sum_abs_w;
            g.batches += 1;
        }
        self.history.push(var);
        self.previous_var = Some(var);
        self.best_var = self.best_var.min(var);
    }

    /// Puts the groups into the final phase's accumulator, before its iterations (call it first).
    pub(super) fn add_to(&self, acc: &mut Accumulator) -> Result<()> {
        for g in self.groups.iter().filter(|g| g.share > 0.0) {
            let mean: Vec<f64> = g.weighted_mean.iter().map(|v| v / g.share).collect();
            let cov: Vec<f64> = g
                .weighted_cov
                .iter()
                .map(|v| v / (g.share * g.share))
                .collect();
            acc.add(Iteration::new(
                Source::Training,
                mean,
                cov,
                g.evals,
                g.max_abs_w,
                g.sum_abs_w,
            ))?;
        }
        acc.observe_tail(&self.tail);
        acc.set_training_variances(self.history.clone());
        Ok(())
    }

    /// The share of every iteration of `acc` (the groups', then the final phase's iterations by
    /// their evaluations out of what is left): they sum to one.
    pub(super) fn shares(&self, iterations: &[Iteration]) -> Vec<f64> {
        let groups: Vec<f64> = self
            .groups
            .iter()
            .filter(|g| g.share > 0.0)
            .map(|g| g.share)
            .collect();
        let finals = &iterations[groups.len()..];
        let total: u64 = finals.iter().map(|i| i.evals).sum();
        let mut shares = groups;
        shares.extend(
            finals
                .iter()
                .map(|i| self.remaining * i.evals as f64 / total as f64),
        );
        shares
    }
}

/// The weights f/q (`n × k`) of a training batch, q being the mixture with the batch's own share
/// of uniform points, n_u/n: with the counts fixed per batch this is the balance heuristic, whose
/// mean is unbiased for exactly those counts.
pub(super) fn batch_weights(b: &MixtureBatch, fx: &[f64], k: usize) -> Vec<f64> {
    let n = b.log_q_mix.len();
    let n_u = b.uniform_log_q.len();
    let lambda = n_u as f64 / n as f64;
    b.density_part
        .log_q
        .iter()
        .chain(&b.uniform_log_q)
        .zip(fx.chunks_exact(k))
        .flat_map(|(&l, v)| {
            let inv_q = (-mix_log_density(lambda, l)).exp();
            v.iter().map(move |v| v * inv_q)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use std::time::Instant;

    /// `n` weights of mean 1 with an exponential's skew, spread `scale`: 1 + scale·(E − 1).
    fn skewed(n: usize, scale: f64, rng: &mut rand_pcg::Pcg64Mcg) -> Vec<f64> {
        (0..n)
            .map(|_| 1.0 + scale * (-(1.0 - rng.random::<f64>()).ln() - 1.0))
            .collect()
    }

    /// The mean and variance of the mean of `w`.
    fn mean_var(w: &[f64]) -> (f64, f64) {
        let n = w.len() as f64;
        let m = w.iter().sum::<f64>() / n;
        (
            m,
            w.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0) / n,
        )
    }

    /// A synthetic integration of ∫ = 1 (training batches whose spread falls from 3 to 1, then a
    /// final phase at spread 1), combined by the shares of this module and, for comparison, by
    /// the naive inverse-variance weighting of the same pieces: (ours, ±, naive). `stratified`:
    /// the shares predict a stratified final phase from the batches post-stratified on latents
    /// z that the weights depend on (×(½ + z), mean 1), so g varies with the data.
    fn run(seed: u64, stratified: bool) -> (f64, f64, f64) {
        let config = NisConfig {
            batch: 256,
            reuse_training: 0.5,
            final_iterations: 4,
            stratify: stratified.then(Default::default),
            ..NisConfig::default()
        };
        let (batches, final_evals) = (20, 4 * 512);
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut pieces = TrainingPieces::plan(
            &config,
            &FinalPlan::new(&config, 1, final_evals),
            batches,
            1,
        )
        .unwrap();
        let (mut naive_sum, mut naive_norm) = (0.0, 0.0);
        for b in 0..batches {
            let scale = 1.0 + 2.0 * (batches - 1 - b) as f64 / (batches - 1) as f64;
            let mut w = skewed(256, scale, &mut rng);
            let z: Vec<f32> = if stratified {
                (0..256).map(|_| rng.random::<f32>()).collect()
            } else {
                Vec::new()
            };
            w.iter_mut()
                .zip(&z)
                .for_each(|(w, z)| *w *= 0.5 + *z as f64);
            pieces.observe_weights(b, &w, &z, &Comm::default());
            if b >= batches / 2 {
                let (m, v) = mean_var(&w);
                (naive_sum, naive_norm) = (naive_sum + m / v, naive_norm + 1.0 / v);
            }
        }
        let mut acc = Accumulator::new(final_evals);
        pieces.add_to(&mut acc).unwrap();
        for _ in 0..4 {
            let w = skewed(512, 1.0, &mut rng);
            let (m, v) = mean_var(&w);
            (naive_sum, naive_norm) = (naive_sum + m / v, naive_norm + 1.0 / v);
            acc.add_weights(&w).unwrap();
        }
        let shares = pieces.shares(acc.iterations());
        assert!(
            (shares.iter().sum::<f64>() - 1.0).abs() < 1e-12,
            "{shares:?}"
        );
        assert!(shares.iter().all(|a| *a >= 0.0));
        let r = acc.finish(Some(&shares), 0, Instant::now());
        (r.value, r.std_err, naive_sum / naive_norm)
    }

    #[test]
    fn reused_training_is_unbiased_and_covers_where_inverse_variance_weights_are_biased() {
        // 2000 runs of ∫ = 1. Ours: |error| ≤ 2σ in at least the binomial mean − 3 sd of the
        // nominal 95.45% (2000·0.9545 − 3·9.3 = 1881), and a mean error within 3.5 of its
        // standard errors. The naive weighting of the same pieces by their own variance
        // estimates (batches with a large mean have a large variance estimate when the weights
        // are skewed) must fail the same mean-error test: by about −μ₃/(nσ²) = −2/n here.
        let reps = 2000;
        let runs: Vec<(f64, f64, f64)> = (0..reps).map(|s| run(s, false)).collect();
        let covered = runs
            .iter()
            .filter(|r| (r.0 - 1.0).abs() <= 2.0 * r.1)
            .count();
        let pull_of_mean = |errors: Vec<f64>| {
            let n = errors.len() as f64;
            let m = errors.iter().sum::<f64>() / n;
            let sd = (errors.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            m / (sd / n.sqrt())
        };
        let ours = pull_of_mean(runs.iter().map(|r| r.0 - 1.0).collect());
        let naive = pull_of_mean(runs.iter().map(|r| r.2 - 1.0).collect());
        eprintln!(
            "covered {covered}/{reps}, pull of the mean error: ours {ours:.2}, naive {naive:.2}"
        );
        assert!(covered >= 1881, "only {covered}/{reps} within 2σ");
        assert!(
            ours.abs() <= 3.5,
            "mean error {ours:.2} standard errors from zero"
        );
        assert!(
            naive < -3.5,
            "the naive weighting went undetected: {naive:.2}"
        );
        // The same with shares that predict a stratified final phase from the data.
        let runs: Vec<(f64, f64, f64)> = (0..reps).map(|s| run(10_000 + s, true)).collect();
        let covered = runs
            .iter()
            .filter(|r| (r.0 - 1.0).abs() <= 2.0 * r.1)
            .count();
        let ours = pull_of_mean(runs.iter().map(|r| r.0 - 1.0).collect());
        eprintln!("stratified: covered {covered}/{reps}, pull of the mean error {ours:.2}");
        assert!(
            covered >= 1881,
            "stratified: only {covered}/{reps} within 2σ"
        );
        assert!(ours.abs() <= 3.5, "stratified: mean error {ours:.2} σ");
    }

    #[test]
    fn a_final_phase_predicted_vastly_better_takes_everything_without_a_nan() {
        // Weights 1 in every other hypercube of the final phase's grid and ~10⁻¹⁰⁰ in the rest
        // (as an integrand that vanishes off a ridge): the post-stratified prediction makes the
        // final phase ~10²⁰⁰ times better, so a batch's share would be ~10⁻²⁰⁰, its square 0,
        // and a group's variance 0/0 (found on ridge d8 at 10⁶ evaluations, seed 3: shares of
        // 10⁻¹⁷⁰). Such batches must not enter.
        let config = NisConfig {
            batch: 256,
            reuse_training: 0.5,
            final_iterations: 4,
            stratify: Some(Default::default()),
            ..NisConfig::default()
        };
        let (batches, final_evals) = (20, 4 * 4096);
        let mut pieces = TrainingPieces::plan(
            &config,
            &FinalPlan::new(&config, 1, final_evals),
            batches,
            1,
        )
        .unwrap();
        let cells = pieces.stratified.as_ref().unwrap().grid[0] as f64;
        assert!(cells > 1.0, "{cells}");
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        for b in 0..batches {
            let z: Vec<f32> = (0..256).map(|_| rng.random::<f32>()).collect();
            let w: Vec<f64> = z
                .iter()
                .map(|&z| {
                    let cube = (z as f64 * cells).floor() as u64;
                    if cube % 2 == 0 {
                        1e-100 * z as f64
                    } else {
                        1.0
                    }
                })
                .collect();
            pieces.observe_weights(b, &w, &z, &Comm::default());
        }
        assert!(pieces.final_gain() > 1e160, "{}", pieces.final_gain());
        let mut acc = Accumulator::new(final_evals);
        pieces.add_to(&mut acc).unwrap();
        for _ in 0..4 {
            let w = skewed(4096, 1.0, &mut rng);
            acc.add_weights(&w).unwrap();
        }
        let shares = pieces.shares(acc.iterations());
        assert_eq!(shares.len(), 4, "no training group entered: {shares:?}");
        assert!((shares.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let r = acc.finish(Some(&shares), 0, Instant::now());
        assert!(r.value.is_finite() && r.std_err.is_finite() && r.std_err > 0.0);
    }

    #[test]
    fn shares_use_only_earlier_batches_and_favour_none_over_the_final_phase() {
        let config = NisConfig {
            batch: 100,
            reuse_training: 0.5,
            final_iterations: 2,
            stratify: None,
            ..NisConfig::default()
        };
        // Too few batches, or none kept: nothing to reuse.
        assert!(TrainingPieces::plan(&config, &FinalPlan::new(&config, 1, 1000), 1, 1).is_none());
        let off = NisConfig {
            reuse_training: 0.0,
            ..config.clone()
        };
        assert!(TrainingPieces::plan(&off, &FinalPlan::new(&off, 1, 1000), 10, 1).is_none());
        let mut p =
            TrainingPieces::plan(&config, &FinalPlan::new(&config, 1, 1000), 10, 1).unwrap();
        assert_eq!(p.first_kept, 5);
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
        for b in 0..10 {
            let before = p.share(b);
            let w = skewed(100, 1.0, &mut rng);
            p.observe_weights(b, &w, &[], &Comm::default());
            if b < 5 {
                assert_eq!(before, 0.0);
            } else {
                // At most the batch's count share of what is left.
                let after = (9 - b) as f64 * 100.0 + 1000.0;
                assert!(before > 0.0 && before <= p.remaining + before);
                assert!(before / (p.remaining + before) <= 100.0 / (100.0 + after) + 1e-15);
            }
        }
        // Equal weights: every kept evaluation weighs the same, 1/(500 + 1000).
        let mut p =
            TrainingPieces::plan(&config, &FinalPlan::new(&config, 1, 1000), 10, 1).unwrap();
        for b in 0..10 {
            p.observe_weights(b, &[2.0; 100], &[], &Comm::default());
        }
        assert!(
            (p.remaining - 1000.0 / 1500.0).abs() < 1e-12,
            "{}",
            p.remaining
        );
    }

    #[test]
    fn a_final_phase_predicted_better_by_post_stratification_takes_more_of_the_estimate() {
        // Weights 1 + z₀ + 3·z₁ of the latents: smooth, so the final phase's stratified latent
        // (8 × 7 hypercubes for its 500 points per iteration) has ~50× less variance per point.
        let stratified = NisConfig {
            batch: 200,
            reuse_training: 0.5,
            final_iterations: 2,
            ..NisConfig::default()
        };
        let iid = NisConfig {
            stratify: None,
            ..stratified.clone()
        };
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(2);
        let mut with =
            TrainingPieces::plan(&stratified, &FinalPlan::new(&stratified, 2, 1000), 20, 1)
                .unwrap();
        let mut without =
            TrainingPieces::plan(&iid, &FinalPlan::new(&iid, 2, 1000), 20, 1).unwrap();
        let grid = with.stratified.as_ref().unwrap().grid.clone();
        assert_eq!(grid.iter().product::<usize>(), 56, "{grid:?}");
        for b in 0..20 {
            // The batch's one uniform point last, as a mixture batch holds it.
            let z: Vec<f32> = (0..2 * 199).map(|_| rng.random::<f32>()).collect();
            let mut w: Vec<f64> = z
                .chunks_exact(2)
                .map(|p| 1.0 + p[0] as f64 + 3.0 * p[1] as f64)
                .collect();
            w.push(2.5);
            with.observe_weights(b, &w, &z, &Comm::default());
            without.observe_weights(b, &w, &[], &Comm::default());
        }
        let within: f64 = grid
            .iter()
            .zip([1.0, 9.0])
            .map(|(&s, c)| c / (s * s) as f64)
            .sum::<f64>()
            / 12.0;
        let gain = (10.0 / 12.0) / within;
        // ~20·(199 − 56·(1 − e^(−3.6))) ≈ 2900 degrees of freedom pooled: 4σ ≈ ±11%, and the
        // total's 199 of each batch a little more.
        let predicted = with.final_gain();
        assert!(
            (predicted / gain - 1.0).abs() < 0.2,
            "{predicted} vs {gain}"
        );
        assert_eq!(without.final_gain(), 1.0);
        assert!(with.remaining > without.remaining && with.remaining < 1.0);
        // Inverse-variance shares: the kept 2000 training points against 1000 final ones ~50×
        // better per point.
        let expected = 1.0 - 2000.0 / (2000.0 + 1000.0 * gain);
        assert!((with.remaining - expected).abs() < 0.1 * (1.0 - expected));
    }

    #[test]
    fn the_latents_redrawn_from_a_copy_of_the_stream_are_those_the_flow_sampled() {
        use crate::flow::mixture::{DefensiveMixture, Record};
        let flow = crate::flow::mixture::tests::noisy_flow();
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
        let mut copy = rng.clone();
        let sampler = DefensiveMixture::new(flow.clone(), 0.1).unwrap();
        let (b, _) = super::super::draw(&sampler, 500, &mut rng, Record::DensityShare).unwrap();
        let z = crate::flow::uniform_latents(b.density_part.len() * 2, &mut copy);
        let (back, _) = crate::flow::Bijection::forward(&flow, &b.density_part.x, None).unwrap();
        let worst = z
            .iter()
            .zip(&back)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{worst}");
    }

    #[test]
    fn the_replay_buffer_keeps_the_newest_batches_and_replays_them_newest_first_in_turn() {
        let mut r = ReplayBuffer::new(3);
        assert!(r.next().is_none());
        for b in 0..5 {
            r.push(vec![b as f32], vec![b as f64], vec![0.0]);
        }
        // Batches 2, 3, 4 kept; replayed 4, 3, 2, 4, …
        let seen: Vec<f64> = (0..4).map(|_| r.next().unwrap().target[0]).collect();
        assert_eq!(seen, [4.0, 3.0, 2.0, 4.0]);
        let mut none = ReplayBuffer::new(0);
        none.push(vec![0.0], vec![1.0], vec![0.0]);
        assert!(none.next().is_none());
    }
}
