//! The final phase with a stratified latent: the flow maps z ∈ [0,1]^D, uniform, to x with
//! density q(x), so ∫ g(x) q(x) dx = ∫ g(x(z)) dz, and that integral over the latent cube can be
//! sampled as VEGAS+ samples its y-space (Lepage 2021, Sec. 3): cut into hypercubes h of volume
//! V_h, n_h points uniform in each, the estimate Σ_h V_h·mean_h with variance
//! Σ_h V_h²·Var_h/n_h, and the n_h of the next iteration allocated by the measured variances
//! ([`crate::integrate::adaptive_strata`], damped by β).
//!
//! The defensive mixture q_mix = λ·uniform + (1 − λ)·q is kept as a sum of two integrals,
//! ∫ f = ∫ (1 − λ)·f/q_mix · q dx + ∫ λ·f/q_mix dx (the two weights add up to one wherever
//! q_mix > 0), each estimated by its own points: the first over the flow's stratified latent,
//! the second over x itself, stratified with equal counts (the mixture as a whole cannot be
//! stratified in a latent: it has no inverse). This is the balance heuristic of multiple
//! importance sampling with fixed counts, so it is unbiased for any counts; with counts in
//! proportion λ : 1 − λ and one hypercube each it is exactly the i.i.d. final phase's estimator.
//! The counts of the two parts follow Neyman's allocation (n_c ∝ c·σ_c, the uniform part never
//! below λ), measured on the iteration before.
//!
//! Why the whole is unbiased: within an iteration every hypercube's mean is unbiased for its
//! part of the integral whatever its count, and the counts of iteration t depend only on the
//! points of iterations before t; the iterations are pooled with weights fixed by their sizes.
//! So each iteration's error has mean zero given the past (a martingale difference), the pooled
//! estimate is unbiased, and its variance is the sum of the iterations' (stratified) variances.
//! The reliability figures (k̂, ESS, unweighting efficiency) see the sampler's own weights
//! f/q_mix, not the stratified estimate's N·V_h/n_h-scaled ones, which would measure the
//! allocation.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::config::{NisConfig, Stratify};
use crate::comm::Comm;
use crate::error::Result;
use crate::flow::mixture::DefensiveMixture;
use crate::flow::{Bijection, Density, Flow};
use crate::integrate::adaptive_strata::Strata;
use crate::integrate::moments::{Moments, CHUNK};
use crate::integrate::{evaluate, Iteration, Source, TrainOn};

/// A final phase's layout, made once before training (whose kept batches predict it) and then
/// followed: its evaluations, iterations, and the flow latent's hypercubes when it stratifies.
pub(super) struct FinalPlan {
    pub(super) evals: u64,
    pub(super) iterations: usize,
    /// The fewest evaluations an iteration needs, and why.
    pub(super) least: u64,
    pub(super) why: &'static str,
    /// The hypercubes of the flow's latent and their settings (`None`: i.i.d. latents).
    pub(super) latent: Option<(Strata, Stratify)>,
}

impl FinalPlan {
    /// The plan of a final phase of `evals` evaluations in `dim` dimensions under `config`.
    pub(super) fn new(config: &NisConfig, dim: usize, evals: u64) -> FinalPlan {
        let iterations = config.final_iterations;
        let lambda = config.uniform_fraction;
        match config.stratify {
            Some(s) => FinalPlan {
                evals,
                iterations,
                // `min_per_cube` in every hypercube, and two uniform points (for their variance)
                // when λ > 0.
                least: (s.min_per_cube + if lambda > 0.0 { 2 } else { 0 }) as u64,
                why: "min_per_cube and two uniform points per iteration of the final phase",
                latent: Some((plan(dim, evals / iterations as u64, lambda, s), s)),
            },
            None => FinalPlan {
                evals,
                iterations,
                least: 2,
                why: "two per iteration of the final phase, after training",
                latent: None,
            },
        }
    }

    /// Strata per axis of the latent grid, when the final phase stratifies.
    pub(super) fn grid(&self) -> Option<&[usize]> {
        self.latent.as_ref().map(|(s, _)| s.per_axis.as_slice())
    }
}

/// The stratification of one final phase: its hypercubes, their adapted allocation, and what a
/// chunk of points needs to know.
pub(super) struct LatentStrata {
    strata: Strata,
    settings: Stratify,
    /// Share λ of the uniform component in q_mix.
    lambda: f64,
    /// Share of the next iteration's points drawn uniformly: λ at first, then the share the
    /// measured standard deviations of the two parts call for (Neyman's allocation), at least λ.
    uniform_share: f64,
    /// Components of the integrand.
    k: usize,
    train_on: TrainOn,
}

impl LatentStrata {
    /// The final phase's hypercubes `strata` (see [`FinalPlan`]), for a mixture of uniform share
    /// `lambda` and an integrand of `k` components.
    pub(super) fn new(
        strata: Strata,
        settings: Stratify,
        lambda: f64,
        k: usize,
        train_on: TrainOn,
    ) -> LatentStrata {
        LatentStrata {
            strata,
            settings,
            lambda,
            uniform_share: lambda,
            k,
            train_on,
        }
    }

    /// [`LatentStrata::new`] on the hypercubes planned for iterations of about `per_iter` points
    /// of a scalar integrand.
    #[cfg(test)]
    fn planned(dim: usize, per_iter: u64, lambda: f64, settings: Stratify) -> LatentStrata {
        let strata = plan(dim, per_iter, lambda, settings);
        LatentStrata::new(strata, settings, lambda, 1, TrainOn::default())
    }

    /// One iteration of `n` evaluations over all ranks: this rank's share of every hypercube's
    /// points and of the uniform ones drawn from `rng`, evaluated in chunks of bounded memory;
    /// each chunk's weights go to `observe`. Adapts the allocation for the next iteration.
    pub(super) fn iteration(
        &mut self,
        sampler: &DefensiveMixture<Flow>,
        f: &dyn crate::integrate::Integrand,
        n: u64,
        rng: &mut Pcg64Mcg,
        comm: &Comm,
        observe: &mut dyn FnMut(&[f64]),
    ) -> Result<Iteration> {
        let flow = &sampler.density;
        let (dim, k) = (flow.dim(), self.k);
        let (n_u, n_q) = split(n, self.uniform_share);
        let counts = self
            .strata
            .allocate(n_q as usize, self.settings.min_per_cube);
        let evals = counts.iter().sum::<usize>() as u64 + n_u;
        // The uniform part stratified in x with equal counts, two points per hypercube: as
        // many hypercubes as that allows (it gets few points, too few to adapt an allocation),
        // at most max_cubes (planning from 8·max_cubes points gives that many).
        let planned = (4 * n_u as usize).min(self.settings.max_cubes.saturating_mul(8));
        let uniform_strata = Strata::plan(dim, planned, UNIFORM_PER_CUBE);
        let uniform_counts = if n_u == 0 {
            vec![0; uniform_strata.cubes]
        } else {
            uniform_strata.allocate(n_u as usize, UNIFORM_PER_CUBE)
        };
        let adapts_to_f = k == 1 && self.train_on == TrainOn::Component(0);
        let target = (!adapts_to_f).then_some(self.train_on);
        let (mut max_abs_w, mut sum_abs_w) = (0.0f64, 0.0);
        // The reliability figures see the sampler's own weights f/q_mix (those of the i.i.d.
        // final phase and of unweighting), not the stratified estimate's N·V_h/n_h-scaled ones:
        // those would measure the allocation (a cube given few points scales its weights up),
        // and an allocation adapted to the variances shows a Pareto k̂ > 1 on a flow whose own
        // weights have k̂ < 0.1.
        let mut weigh = |w: &[f64]| {
            let w0: Vec<f64> = w.chunks_exact(k).map(|r| r[0]).collect();
            for v in &w0 {
                max_abs_w = max_abs_w.max(v.abs());
                sum_abs_w += v.abs();
            }
            observe(&w0);
        };
        let drawn = (|| {
            let flow_part = Cubes {
                strata: &self.strata,
                counts: &counts,
            }
            .draw(comm, rng, k, target, &mut weigh, &mut |z| {
                let (x, neg_log_q) = flow.inverse(z, None)?;
                let log_q: Vec<f64> = neg_log_q.iter().map(|l| -l).collect();
                mixture_weights(sampler, f, &x, &log_q)
            })?;
            let uniform_part = Cubes {
                strata: &uniform_strata,
                counts: &uniform_counts,
            }
            .draw(comm, rng, k, None, &mut weigh, &mut |x| {
                let log_q = flow.log_density(x, None)?;
                mixture_weights(sampler, f, x, &log_q)
            })?;
            Ok((flow_part, uniform_part))
        })();
        let ((g, t), (u, _)) = comm.check(drawn)?;
        let g = Moments::across_each(&g, comm);
        let t = Moments::across_each(&t, comm);
        let u = Moments::across_each(&u, comm);
        let (mean, cov) = self.estimate_and_adapt(&g, &t, &u, n_u > 0);
        let mut max = [max_abs_w];
        comm.max_f64(&mut max);
        let sum_abs_w = comm.sum(sum_abs_w);
        Ok(Iteration::new(
            Source::Final,
            mean,
            cov,
            evals,
            max[0],
            sum_abs_w,
        ))
    }

    /// The iteration's estimate Σ_h V_h·(1 − λ)·mean_h + Σ_h' V_h'·λ·mean_h' (every component)
    /// and its covariance from the flow part's hypercubes `g` (with the target's moments `t` when
    /// the sampler adapts to another target) and the uniform part's `u`, all over every rank;
    /// adapts the next iteration's allocation: the hypercubes' by their contributions to the
    /// variance, the two parts' by Neyman's rule when the uniform part has points.
    fn estimate_and_adapt(
        &mut self,
        g: &[Moments],
        t: &[Moments],
        u: &[Moments],
        has_uniform: bool,
    ) -> (Vec<f64>, Vec<f64>) {
        let k = self.k;
        // Σ_h V_h·(1 − λ)·mean_h + Σ_h' V_h'·λ·mean_h', and its covariance.
        let (mut mean, mut cov) = (vec![0.0; k], vec![0.0; k * k]);
        let cubes = self.strata.cubes;
        let mut contribution_var = vec![0.0; cubes];
        // Σ_h a_h·σ_h of each part, its standard deviation per point under Neyman's allocation.
        let mut add = |m: &Moments, a: f64| {
            let (mh, ch) = m.mean_and_cov_of_mean();
            mean.iter_mut().zip(&mh).for_each(|(s, v)| *s += a * v);
            cov.iter_mut().zip(&ch).for_each(|(s, v)| *s += a * a * v);
            (a * (ch[0] * m.n() as f64).max(0.0).sqrt(), a * a * ch[0])
        };
        let lambda = self.lambda;
        let a = (1.0 - lambda) / cubes as f64;
        let mut sigma_q = 0.0;
        for (h, m) in g.iter().enumerate() {
            let (sigma, var) = add(m, a);
            sigma_q += sigma;
            contribution_var[h] = t
                .get(h)
                .map_or(var, |t| a * a * t.mean_and_cov_of_mean().1[0]);
        }
        let a_u = lambda / u.len() as f64;
        let sigma_u: f64 = u.iter().map(|m| add(m, a_u).0).sum();
        if has_uniform && sigma_u + sigma_q > 0.0 && (sigma_u + sigma_q).is_finite() {
            // The two parts' points in proportion to their standard deviations (the variance
            // Σ c²σ_c²/n_c is least for n_c ∝ c·σ_c), never fewer uniform ones than λ asks for,
            // nor more than half; fixed before the next iteration's points, so still unbiased.
            self.uniform_share = (sigma_u / (sigma_u + sigma_q)).clamp(lambda, MAX_UNIFORM_SHARE);
        }
        self.strata.adapt(&contribution_var, self.settings.beta);
        (mean, cov)
    }
}

/// The hypercubes of a final phase of iterations of about `per_iter` points: as VEGAS+ plans
/// them for the flow's share of those points, at most `settings.max_cubes`.
fn plan(dim: usize, per_iter: u64, lambda: f64, settings: Stratify) -> Strata {
    let (_, n_q) = split(per_iter, lambda);
    // Planning from fewer points gives fewer hypercubes: the even quarter fills max_cubes.
    let cap = (settings.max_cubes as f64 * settings.min_per_cube as f64
        / (1.0 - crate::integrate::adaptive_strata::ADAPTIVE_SHARE))
        .min(usize::MAX as f64) as usize;
    Strata::plan(dim, (n_q as usize).min(cap), settings.min_per_cube)
}

/// One iteration's hypercubes and their points over all ranks.
struct Cubes<'a> {
    strata: &'a Strata,
    counts: &'a [usize],
}

/// Per hypercube, the moments of f/q_mix (`k` components) and, when the sampler adapts to
/// another target, of that target's values.
type CubeMoments = (Vec<Moments>, Vec<Moments>);

impl Cubes<'_> {
    /// This rank's share of every hypercube's points, uniform in it, drawn from `rng` in cube
    /// order and evaluated in chunks of bounded memory: `eval` maps a chunk of points of the
    /// unit cube to their weights f/q_mix; `weigh` sees every chunk's weights.
    fn draw(
        &self,
        comm: &Comm,
        rng: &mut Pcg64Mcg,
        k: usize,
        target: Option<TrainOn>,
        weigh: &mut dyn FnMut(&[f64]),
        eval: &mut dyn FnMut(&[f32]) -> Result<Vec<f64>>,
    ) -> Result<CubeMoments> {
        let (cubes, dim) = (self.strata.cubes, self.strata.per_axis.len());
        let mut g = vec![Moments::new(k); cubes];
        let mut t = if target.is_some() {
            vec![Moments::new(1); cubes]
        } else {
            Vec::new()
        };
        let mine: Vec<usize> = self
            .counts
            .iter()
            .map(|&c| comm.share(c as u64) as usize)
            .collect();
        let mut corner = vec![0usize; dim];
        let (mut h, mut done_in_h) = (0, 0);
        while h < cubes {
            let (mut z, mut cube_of) = (Vec::new(), Vec::new());
            while h < cubes && cube_of.len() < CHUNK {
                let take = (mine[h] - done_in_h).min(CHUNK - cube_of.len());
                self.strata.corner(h, &mut corner);
                for _ in 0..take {
                    for (&c, &s) in corner.iter().zip(&self.strata.per_axis) {
                        z.push(((c as f64 + rng.random::<f64>()) / s as f64) as f32);
                    }
                    cube_of.push(h);
                }
                done_in_h += take;
                if done_in_h == mine[h] {
                    (h, done_in_h) = (h + 1, 0);
                }
            }
            if cube_of.is_empty() {
                continue;
            }
            let w = eval(&z)?;
            let values = target.map(|t| t.target(&w, k));
            // Runs of one hypercube.
            let mut start = 0;
            while start < cube_of.len() {
                let c = cube_of[start];
                let end = start + cube_of[start..].iter().take_while(|&&b| b == c).count();
                g[c].add(&w[start * k..end * k]);
                if let Some(v) = &values {
                    t[c].add(&v[start..end]);
                }
                start = end;
            }
            weigh(&w);
        }
        Ok((g, t))
    }
}

/// Points per hypercube of the uniform part (equal counts: enough for each one's variance).
const UNIFORM_PER_CUBE: usize = 2;

/// Most of an iteration's points the uniform part may take: the flow is the sampler.
const MAX_UNIFORM_SHARE: f64 = 0.5;

/// Uniform and flow points of an iteration of `n` whose uniform part has the share `share` (λ,
/// or Neyman's allocation): n_u = round(share·n), at least two when share > 0 (for the uniform
/// part's variance; unlike [`crate::flow::mixture::uniform_count`], which draws a mixture's
/// batch), and the rest.
fn split(n: u64, share: f64) -> (u64, u64) {
    let n_u = if share > 0.0 {
        ((share * n as f64).round() as u64).max(2)
    } else {
        0
    };
    (n_u, n.saturating_sub(n_u))
}

/// f/q_mix at the points `x` where the flow has ln q, `n × k` row-major.
fn mixture_weights(
    sampler: &DefensiveMixture<Flow>,
    f: &dyn crate::integrate::Integrand,
    x: &[f32],
    log_q: &[f64],
) -> Result<Vec<f64>> {
    let x64: Vec<f64> = x.iter().map(|&v| v as f64).collect();
    let fx = evaluate(f, &x64, sampler.density.dim())?;
    Ok(fx
        .chunks_exact(f.components())
        .zip(log_q)
        .flat_map(|(v, &l)| {
            let inv_q = (-sampler.mix_log_density(l)).exp();
            v.iter().map(move |v| v * inv_q)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use rand::SeedableRng;

    use super::*;
    use crate::flow::Flow;
    use crate::integrate::Accumulator;

    /// A 2-d flow far from uniform, and far from f.
    fn flow() -> Flow {
        crate::flow::mixture::tests::noisy_flow()
    }

    /// ∫ 20·x⁹·y dx dy = 1 over the unit square: a steep edge q knows nothing about.
    fn integrand(x: &[f64]) -> f64 {
        20.0 * x[0].powi(9) * x[1]
    }

    /// A stratified final phase of `iterations` × `per_iter` points from `seed`: its estimate
    /// and standard error, pooled as the integrator pools them.
    fn run(flow: &Flow, lambda: f64, settings: Stratify, seed: u64) -> (f64, f64) {
        let (iterations, per_iter) = (4, 2000);
        let f = integrand;
        let mut latent = LatentStrata::planned(2, per_iter, lambda, settings);
        let sampler = DefensiveMixture::new(flow.clone(), lambda).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let comm = Comm::default();
        let mut acc = Accumulator::new(iterations * per_iter);
        for _ in 0..iterations {
            let s = latent
                .iteration(&sampler, &f, per_iter, &mut rng, &comm, &mut |w| {
                    acc.observe(w)
                })
                .unwrap();
            assert_eq!(s.evals, per_iter);
            acc.add(s).unwrap();
        }
        let r = acc.finish(None, iterations * per_iter, Instant::now());
        (r.value, r.std_err)
    }

    /// The mean and the sample variance of `v`.
    fn mean_var(v: &[f64]) -> (f64, f64) {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        (
            m,
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0),
        )
    }

    /// Bands of `SIGMAS` standard deviations of the sampling distributions below.
    const SIGMAS: f64 = 4.0;

    #[test]
    fn stratified_estimates_are_unbiased_and_their_error_bars_cover() {
        let flow = flow();
        let seeds = 400;
        for lambda in [0.0, 0.05] {
            let runs: Vec<(f64, f64)> = (0..seeds)
                .map(|s| run(&flow, lambda, Stratify::default(), s))
                .collect();
            let pulls: Vec<f64> = runs.iter().map(|(v, e)| (v - 1.0) / e).collect();
            let s = seeds as f64;
            let values: Vec<f64> = runs.iter().map(|r| r.0).collect();
            let (mean, spread) = mean_var(&values);
            // The mean of the estimates ~ N(1, spread/S): unbiased. (The mean pull is not the
            // test: with a few points per hypercube of a skewed f/q, a low estimate comes with a
            // low variance estimate, which pulls it below zero without any bias; measured −0.15
            // at λ = 0 over 1600 seeds, the estimates' mean 0.99977 ± 0.00039.)
            assert!(
                (mean - 1.0).abs() < SIGMAS * (spread / s).sqrt(),
                "λ {lambda}: {mean}"
            );
            // Coverage of ±1σ and ±2σ within binomial bands of S seeds.
            for (k, p) in [(1.0, 0.6827), (2.0, 0.9545)] {
                let inside = pulls.iter().filter(|z| z.abs() < k).count() as f64 / s;
                let band = SIGMAS * (p * (1.0 - p) / s).sqrt();
                assert!((inside - p).abs() < band, "λ {lambda}: {k}σ: {inside}");
            }
            // The stratified variance estimate against the spread of the estimates over the
            // seeds: their ratio's sampling error is about √(2/(S − 1)).
            let claimed = runs.iter().map(|r| r.1 * r.1).sum::<f64>() / s;
            let ratio = spread / claimed;
            assert!(
                (ratio - 1.0).abs() < SIGMAS * (2.0 / (s - 1.0)).sqrt(),
                "λ {lambda}: spread/claimed = {ratio}"
            );
        }
    }

    #[test]
    fn one_hypercube_is_the_iid_estimate_and_more_hypercubes_beat_it() {
        let flow = flow();
        let seeds = 300;
        let one = Stratify {
            max_cubes: 1,
            ..Stratify::default()
        };
        let (iterations, per_iter) = (4usize, 2000usize);
        // The i.i.d. final phase's estimate: the mean of f/q over all its points.
        let sampler = DefensiveMixture::new(flow.clone(), 0.0).unwrap();
        let iid: Vec<f64> = (0..seeds)
            .map(|s| {
                let mut rng = Pcg64Mcg::seed_from_u64(s);
                let n = iterations * per_iter;
                let (_, w) = super::super::weights(&sampler, &integrand, n, &mut rng).unwrap();
                w.iter().sum::<f64>() / w.len() as f64
            })
            .collect();
        let single: Vec<f64> = (0..seeds)
            .map(|s| run(&flow, 0.0, one, 1000 + s).0)
            .collect();
        let many: Vec<f64> = (0..seeds)
            .map(|s| run(&flow, 0.0, Stratify::default(), 2000 + s).0)
            .collect();
        let s = seeds as f64;
        let (m_iid, v_iid) = mean_var(&iid);
        let (m_one, v_one) = mean_var(&single);
        let (_, v_many) = mean_var(&many);
        // Same mean (two-sample z) and same variance (ratio within its sampling error, doubled for
        // two samples).
        let se = ((v_iid + v_one) / s).sqrt();
        assert!((m_iid - m_one).abs() < SIGMAS * se, "{m_iid} vs {m_one}");
        let ratio = v_one / v_iid;
        assert!(
            (ratio - 1.0).abs() < SIGMAS * (4.0 / (s - 1.0)).sqrt(),
            "variance one cube / i.i.d. = {ratio}"
        );
        // 2000 points per iteration give 15 × 15 hypercubes: less variance on a smooth f (measured
        // 0.24 of it).
        assert!(
            v_many < 0.5 * v_iid,
            "stratified {v_many} vs i.i.d. {v_iid}"
        );
    }

    #[test]
    fn estimates_do_not_depend_on_the_thread_count() {
        let flow = flow();
        let on = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| run(&flow, 0.05, Stratify::default(), 7))
        };
        let one = on(1);
        assert_eq!(one.0.to_bits(), on(3).0.to_bits());
        assert_eq!(one.1.to_bits(), on(3).1.to_bits());
    }

    #[test]
    fn hypercubes_follow_the_plan_and_the_cap() {
        let flow = flow();
        let latent = LatentStrata::planned(2, 50_000, 0.0, Stratify::default());
        assert_eq!(latent.strata.per_axis, vec![79, 79]);
        let capped = Stratify {
            max_cubes: 100,
            ..Stratify::default()
        };
        let latent = LatentStrata::planned(2, 50_000, 0.0, capped);
        assert_eq!(latent.strata.per_axis, vec![10, 10]);
        // An iteration makes exactly its points, the uniform ones included.
        let mut latent = LatentStrata::planned(2, 1001, 0.1, capped);
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let s = latent
            .iteration(
                &DefensiveMixture::new(flow.clone(), 0.1).unwrap(),
                &integrand,
                1001,
                &mut rng,
                &Comm::default(),
                &mut |_| {},
            )
            .unwrap();
        assert_eq!(s.evals, 1001);
        // Half the points uniform, more than 8·max_cubes of them: the uniform part's hypercubes
        // are capped too, and the counts still add up.
        let mut latent = LatentStrata::planned(2, 10_000, 0.5, capped);
        let s = latent
            .iteration(
                &DefensiveMixture::new(flow.clone(), 0.5).unwrap(),
                &integrand,
                10_000,
                &mut rng,
                &Comm::default(),
                &mut |_| {},
            )
            .unwrap();
        assert_eq!(s.evals, 10_000);
        assert!(
            (s.estimate - 1.0).abs() < 5.0 * s.variance.sqrt(),
            "{}",
            s.estimate
        );
    }
}
