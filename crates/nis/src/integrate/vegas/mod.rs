//! VEGAS+ (Lepage 1978; Lepage 2021, "Adaptive multidimensional integration: VEGAS enhanced",
//! arXiv:2009.05112): a separable importance map (`map.rs`) combined with adaptive stratified
//! sampling in y over hypercubes (`adaptive_strata.rs`), both adapted after every iteration as G. P.
//! Lepage's `vegas` package adapts them (its defaults: α = 0.5, β = 0.75, a quarter of the points
//! spread evenly, increments and strata from the points per iteration; docs/results/integration.md compares
//! the two on the suite).
//!
//! Departure from the package, and why: the first `warmup` iterations only teach the map and the
//! strata, and the estimate pools the remaining ones with *equal* weights (all iterations have
//! the same number of points). Each iteration is unbiased given the map it used, so this pooled
//! mean is unbiased and its variance is the sum of theirs. The package instead averages
//! iterations with inverse-variance weights, which is biased when the variances are estimated
//! from the same samples: an iteration whose points happened to miss part of the integrand has
//! both a low estimate and a low variance, and weighs more. Equal weights, though, waste the later
//! iterations of a still-improving map, so the result iterations here get shares fixed before
//! their points are drawn, from the trend of the earlier variances (`shares.rs`).

mod iteration;
mod map;
mod shares;
mod to_target;

use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use super::adaptive_strata::Strata;
use super::{
    check_budget, check_dim, report, Accumulator, Integrand, IntegrationResult, Integrator, Method,
    Progress, Target, TrainOn,
};
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::kernels::in_pool;
use iteration::Measure;
use map::Map;
use shares::{next_share, Trend};

/// VEGAS+ settings (the map and stratification defaults follow the `vegas` package: 1000
/// increments, α = 0.5, β = 0.75).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VegasConfig {
    /// Increments of the map per dimension.
    pub increments: usize,
    /// Damping of the map's adaptation (0: none, larger: faster).
    pub alpha: f64,
    /// Damping of the stratification's adaptation (0: equal counts).
    pub beta: f64,
    /// Iterations in all (0: 20, a quarter of them warm-up, as the package's documentation runs
    /// it, but fewer when that would leave under 4000 points per iteration, and at least 5).
    pub iterations: usize,
    /// Of those, the first ones whose estimates are discarded (0 with `iterations` 0: a quarter).
    pub warmup: usize,
    /// Fewest points per hypercube.
    pub min_per_cube: usize,
    /// Seed of the random points.
    pub seed: u64,
    /// The component of a vector-valued integrand the map and the strata adapt to.
    pub train_on: TrainOn,
}

impl Default for VegasConfig {
    fn default() -> Self {
        VegasConfig {
            increments: 1000,
            alpha: 0.5,
            beta: 0.75,
            iterations: 0,
            warmup: 0,
            min_per_cube: 2,
            seed: 0,
            train_on: TrainOn::default(),
        }
    }
}

impl VegasConfig {
    /// A builder starting from the defaults.
    pub fn builder() -> VegasConfigBuilder {
        VegasConfigBuilder(VegasConfig::default())
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let c = self;
        let auto = c.iterations == 0 && c.warmup == 0;
        if c.increments == 0
            || (!auto && c.iterations <= c.warmup)
            || c.min_per_cube < 2
            || c.alpha < 0.0
            || c.beta < 0.0
        {
            return Err(Error::Config(format!(
                "VEGAS needs increments ≥ 1, more iterations than warm-up ones and ≥ 2 points per \
                 hypercube: {c:?}"
            )));
        }
        Ok(())
    }
}

/// Builds a [`VegasConfig`] with named setters.
///
/// ```
/// use nis::integrate::vegas::VegasConfig;
/// let c = VegasConfig::builder().alpha(1.0).iterations(20).warmup(5).seed(2).build().unwrap();
/// assert_eq!((c.alpha, c.iterations, c.warmup, c.seed), (1.0, 20, 5, 2));
/// assert!(VegasConfig::builder().iterations(3).warmup(3).build().is_err());
/// ```
#[derive(Clone, Debug)]
pub struct VegasConfigBuilder(VegasConfig);

impl VegasConfigBuilder {
    /// Sets [`VegasConfig::increments`].
    pub fn increments(mut self, increments: usize) -> Self {
        self.0.increments = increments;
        self
    }
    /// Sets [`VegasConfig::alpha`].
    pub fn alpha(mut self, alpha: f64) -> Self {
        self.0.alpha = alpha;
        self
    }
    /// Sets [`VegasConfig::beta`].
    pub fn beta(mut self, beta: f64) -> Self {
        self.0.beta = beta;
        self
    }
    /// Sets [`VegasConfig::iterations`].
    pub fn iterations(mut self, iterations: usize) -> Self {
        self.0.iterations = iterations;
        self
    }
    /// Sets [`VegasConfig::warmup`].
    pub fn warmup(mut self, warmup: usize) -> Self {
        self.0.warmup = warmup;
        self
    }
    /// Sets [`VegasConfig::min_per_cube`].
    pub fn min_per_cube(mut self, min_per_cube: usize) -> Self {
        self.0.min_per_cube = min_per_cube;
        self
    }
    /// Sets [`VegasConfig::seed`].
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// Sets [`VegasConfig::train_on`].
    pub fn train_on(mut self, train_on: TrainOn) -> Self {
        self.0.train_on = train_on;
        self
    }
    /// The checked settings.
    pub fn build(self) -> Result<VegasConfig> {
        self.0.validate()?;
        Ok(self.0)
    }
}

/// The VEGAS+ integrator: its map, its stratification's weights and its random stream persist
/// between calls, so a second [`Integrator::integrate`] continues adapting them.
pub struct Vegas {
    config: VegasConfig,
    dim: usize,
    /// Built by the first call (its increments are capped by that call's budget).
    map: Option<Map>,
    /// The hypercubes and their weights (replaced when a call's budget gives other hypercubes).
    strata: Option<Strata>,
    rng: Pcg64Mcg,
    /// The ranks that share every iteration (one process by default).
    comm: Comm,
    progress: Option<Box<dyn Progress>>,
}

/// One call's plan: iterations, warm-up, points per iteration and the stratification.
struct Plan {
    iterations: usize,
    warmup: usize,
    increments: usize,
    /// Points of an iteration; the first `extra` iterations get one more, so a call makes
    /// exactly its budget of evaluations.
    per_iter: usize,
    extra: usize,
    strata: Strata,
}

impl Vegas {
    /// A VEGAS+ integrator in `dim` dimensions with the given settings.
    pub fn new(dim: usize, config: VegasConfig) -> Result<Vegas> {
        config.validate()?;
        if dim == 0 {
            return Err(Error::Config("dimension must be at least 1".into()));
        }
        Ok(Vegas {
            rng: Pcg64Mcg::seed_from_u64(config.seed),
            config,
            dim,
            map: None,
            strata: None,
            comm: Comm::default(),
            progress: None,
        })
    }

    /// Its settings.
    pub fn config(&self) -> &VegasConfig {
        &self.config
    }

    fn plan(&self, evals: u64) -> Plan {
        let mut c = self.config.clone();
        if c.iterations == 0 {
            // As the package's documentation runs it: a few iterations that only adapt, then
            // those that make the estimate, ITERATIONS in all, each of at least MIN_PER_ITER
            // points (maps and strata adapted from a few hundred points are noise).
            c.iterations = (ITERATIONS as u64).min((evals / MIN_PER_ITER).max(5)) as usize;
            c.warmup = c.iterations.div_ceil(4);
        }
        // Increments each need several points per iteration to be adapted from.
        let increments = c
            .increments
            .min((evals as usize / c.iterations / 10).max(1));
        let per_iter = (evals / c.iterations as u64).max(c.min_per_cube as u64 * 2) as usize;
        let extra = evals.saturating_sub((per_iter * c.iterations) as u64) as usize;
        Plan {
            iterations: c.iterations,
            warmup: c.warmup,
            increments,
            per_iter,
            extra: extra.min(c.iterations),
            strata: Strata::plan(self.dim, per_iter, c.min_per_cube),
        }
    }
}

impl Vegas {
    /// Makes the map (of `increments` per axis) on the first call, and takes `strata` unless the
    /// ones adapted so far have the same hypercubes (then their weights are kept).
    fn adopt(&mut self, increments: usize, strata: Strata) {
        let dim = self.dim;
        self.map.get_or_insert_with(|| Map::new(dim, increments));
        if !self.strata.as_ref().is_some_and(|s| s.same_cubes(&strata)) {
            self.strata = Some(strata);
        }
    }
}

/// Iterations of a call by default (a quarter of them warm-up), as in the `vegas` package's
/// documented use (`integ(f, nitn=…)` to adapt, then again for the result).
const ITERATIONS: usize = 20;
/// Fewest points per iteration when the number of iterations is chosen by the budget.
const MIN_PER_ITER: u64 = 4000;

impl Integrator for Vegas {
    fn method(&self) -> Method {
        Method::Vegas
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn set_progress(&mut self, progress: Option<Box<dyn Progress>>) {
        self.progress = progress;
    }

    fn set_comm(&mut self, comm: Comm) {
        self.rng = Pcg64Mcg::seed_from_u64(comm.stream_seed(self.config.seed));
        self.comm = comm;
    }

    /// `evals` evaluations in all: the first `warmup` iterations only adapt the map and strata,
    /// the others also make the estimate (and keep adapting them for the next call).
    /// Runs on a worker of rayon's pool (`kernels::in_pool`), as the NIS integrator does.
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        in_pool(|| self.run(f, evals))
    }

    fn integrate_to(&mut self, f: &dyn Integrand, target: &Target) -> Result<IntegrationResult> {
        in_pool(|| self.run_to(f, target))
    }

    fn check_target(&self, target: &Target) -> Result<()> {
        self.check_target_plan(target)
    }
}

impl Vegas {
    /// The iterations of [`Integrator::integrate`].
    fn run(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
        let dim = self.dim;
        check_dim(f, dim)?;
        let k = f.components();
        let train_on = self.config.train_on;
        train_on.check(k)?;
        let (min_per_cube, alpha, beta) = (
            self.config.min_per_cube,
            self.config.alpha,
            self.config.beta,
        );
        let plan = self.plan(evals);
        let per_iter = plan.per_iter;
        // Every hypercube gets min_per_cube points; the plan leaves room for them.
        check_budget(
            Method::Vegas,
            evals,
            (plan.iterations * 2 * min_per_cube) as u64,
            "two per hypercube of every iteration",
        )?;
        let started = Instant::now();
        self.adopt(plan.increments, plan.strata);
        let map = self.map.as_mut().expect("made by adopt");
        let strata = self.strata.as_mut().expect("set by adopt");
        let cubes = strata.cubes;
        let volume = 1.0 / cubes as f64;
        let rng = &mut self.rng;
        let comm = &self.comm;
        let mut acc = Accumulator::new((per_iter * (plan.iterations - plan.warmup)) as u64);
        let mut n_eval = 0u64;
        let mut contribution_var = vec![0.0; cubes];
        // Every iteration's variance (warm-up included) and the result iterations' shares.
        let (mut history, mut shares, mut remaining) = (Vec::new(), Vec::new(), 1.0);
        let measure = Measure {
            f,
            comm,
            k,
            train_on,
            volume,
        };
        for it in 0..plan.iterations {
            let counts = strata.allocate(per_iter + usize::from(it < plan.extra), min_per_cube);
            let measured = measure.iteration(map, strata, rng, &counts, &mut contribution_var)?;
            let variance = measured.variance;
            n_eval += measured.evals;
            if it >= plan.warmup {
                // The share was fixed by the history before this iteration's points.
                let trend = if it == plan.warmup {
                    Trend::Cautious
                } else {
                    Trend::Fitted
                };
                let share = next_share(remaining, plan.iterations - it, &history, trend);
                remaining -= share;
                shares.push(share);
                acc.observe(&measured.w_eff);
                acc.add(measured.iteration(comm))?;
            }
            history.push(variance);
            strata.adapt(&contribution_var, beta);
            map.adapt(alpha);
            report(
                &mut self.progress,
                n_eval,
                evals,
                if it < plan.warmup {
                    "vegas: adapting"
                } else {
                    "vegas: estimating"
                },
            );
        }
        acc.reduce_tail(comm);
        Ok(acc.finish(Some(&shares), n_eval, started))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builder_setter_sets_its_field() {
        let c = VegasConfig::builder()
            .increments(50)
            .alpha(1.5)
            .beta(0.5)
            .iterations(12)
            .warmup(3)
            .min_per_cube(4)
            .seed(8)
            .train_on(TrainOn::Component(2))
            .build()
            .unwrap();
        let expected = VegasConfig {
            increments: 50,
            alpha: 1.5,
            beta: 0.5,
            iterations: 12,
            warmup: 3,
            min_per_cube: 4,
            seed: 8,
            train_on: TrainOn::Component(2),
        };
        assert_eq!(c, expected);
        for bad in [
            VegasConfig::builder().increments(0),
            VegasConfig::builder().alpha(-1.0),
            VegasConfig::builder().beta(-1.0),
            VegasConfig::builder().min_per_cube(1),
            VegasConfig::builder().iterations(4).warmup(4),
        ] {
            assert!(matches!(bad.build(), Err(Error::Config(_))));
        }
        assert!(Vegas::new(0, VegasConfig::default()).is_err());
    }

    #[test]
    fn shares_add_up_to_one_and_follow_a_falling_variance() {
        // Constant variances: equal shares.
        let (mut remaining, mut shares) = (1.0, Vec::new());
        for left in (1..=5).rev() {
            let a = next_share(remaining, left, &[2.0; 6], Trend::Fitted);
            remaining -= a;
            shares.push(a);
        }
        assert!(shares.iter().all(|a| (a - 0.2).abs() < 1e-12), "{shares:?}");
        assert!(remaining.abs() < 1e-15);
        // Variances falling ×0.5 per iteration: each share twice the one before, as
        // inverse-variance weights would be.
        let mut history: Vec<f64> = (0..4).map(|i| 0.5f64.powi(i)).collect();
        let (mut remaining, mut shares) = (1.0, Vec::new());
        for left in (1..=4).rev() {
            let a = next_share(remaining, left, &history, Trend::Fitted);
            remaining -= a;
            shares.push(a);
            history.push(history.last().unwrap() * 0.5);
        }
        for w in shares.windows(2) {
            assert!((w[1] / w[0] - 2.0).abs() < 1e-9, "{shares:?}");
        }
        assert!((shares.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // Growing, zero or non-finite variances: equal shares of what remains.
        for h in [[1.0, 2.0, 4.0], [0.0, 0.0, 0.0], [1.0, 1.0, f64::INFINITY]] {
            assert!((next_share(0.6, 3, &h, Trend::Fitted) - 0.2).abs() < 1e-12);
        }
    }

    #[test]
    fn the_first_result_share_reads_a_noisy_warm_up_as_a_possible_fall() {
        // Warm-up variances of VEGAS+ on gauss d = 16 (seed 1, relative): noise around no trend,
        // and the result iterations then fell 3000-fold. The fitted trend is flat and gives the
        // first of 15 result iterations an equal share; the cautious one a small one.
        let warm_up = [2.13e4, 7.74e3, 1.26e4, 1.66e5, 8.05e3];
        let fitted = next_share(1.0, 15, &warm_up, Trend::Fitted);
        let cautious = next_share(1.0, 15, &warm_up, Trend::Cautious);
        assert!((fitted - 1.0 / 15.0).abs() < 1e-12, "{fitted}");
        assert!(cautious < 0.01, "{cautious}");
        // Variances on an exact trend (flat, or falling ×0.6 per iteration) leave no doubt:
        // both readings agree.
        let falling: Vec<f64> = (0..5).map(|i| 0.6f64.powi(i)).collect();
        for h in [vec![3.0; 5], falling] {
            let (a, b) = (
                next_share(1.0, 15, &h, Trend::Fitted),
                next_share(1.0, 15, &h, Trend::Cautious),
            );
            assert!((a - b).abs() < 1e-12 * a, "{a} {b}");
        }
        // Too few variances for a fit: equal shares either way.
        assert_eq!(next_share(0.9, 3, &[1.0, 5.0], Trend::Cautious), 0.3);
    }

    #[test]
    fn a_second_call_keeps_the_adapted_map() {
        // A peak at 0.2 in each coordinate: after a call the map's increments crowd around it.
        let f = |x: &[f64]| (-((x[0] - 0.2).powi(2) + (x[1] - 0.2).powi(2)) / 0.002).exp();
        let mut v = Vegas::new(2, VegasConfig::builder().seed(1).build().unwrap()).unwrap();
        v.integrate(&f, 20_000).unwrap();
        let edges = v.map.as_ref().unwrap().edges.clone();
        let n = v.map.as_ref().unwrap().n;
        // Half the increments lie within ±0.1 of the peak (a uniform map puts a fifth there).
        let near = edges[..=n]
            .iter()
            .filter(|e| (*e - 0.2).abs() < 0.1)
            .count();
        assert!(near > n / 2, "{near} of {n}");
        v.integrate(&f, 20_000).unwrap();
        let after = &v.map.as_ref().unwrap().edges;
        assert_eq!(after.len(), edges.len());
        assert_ne!(after, &edges, "the map adapted further");
    }
}
