//! VEGAS+ (Lepage 1978; Lepage 2021, "Adaptive multidimensional integration: VEGAS enhanced"): a
//! separable importance map — per dimension a piecewise-linear map y ↦ x with `increments` bins
//! whose widths adapt so each carries an equal share of ∫(f·J)² — combined with stratified
//! sampling in y over `strata^d` hypercubes whose sample counts adapt as n_h ∝ σ_h^β.
//!
//! Departure from the `vegas` package, and why: the map and the stratification adapt after every
//! iteration, but the first `warmup` iterations only teach them, and the estimate pools the
//! remaining ones with *equal* weights (all iterations have the same number of points). Each
//! iteration is unbiased given the map it used, so this pooled mean is unbiased and its variance
//! is the sum of theirs. The package instead averages iterations with inverse-variance weights,
//! which is biased when the variances are estimated from the same samples.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use super::result::ComponentAccumulator;
use super::{
    check_budget, check_dim, evaluate, report, Accumulator, Integrand, IntegrationResult,
    Integrator, Method, Progress, TrainOn,
};
use crate::comm::Comm;
use crate::error::{Error, Result};

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
    /// Iterations in all (0: by dimension — 10 for d ≤ 2, 40 for d ≤ 4, 80 above — but with at
    /// least 20 000 points each and at least 5 iterations). Few large
    /// iterations stratify finely, which low dimensions need; many small ones adapt the map more
    /// often, which high dimensions need (measured on the suite at 2·10⁶ evaluations).
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

    fn validate(&self) -> Result<()> {
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

/// The separable map: per dimension, `increments + 1` edges from 0 to 1.
#[derive(Clone, Debug)]
struct Map {
    dim: usize,
    n: usize,
    edges: Vec<f64>,
}

impl Map {
    fn new(dim: usize, n: usize) -> Map {
        let edges = (0..dim)
            .flat_map(|_| (0..=n).map(move |i| i as f64 / n as f64))
            .collect();
        Map { dim, n, edges }
    }

    /// x(y) and the Jacobian dx/dy, plus each coordinate's increment index.
    fn apply(&self, y: &[f64], x: &mut [f64], inc: &mut [usize]) -> f64 {
        let mut jac = 1.0;
        for d in 0..self.dim {
            let t = y[d] * self.n as f64;
            let i = (t as usize).min(self.n - 1);
            let e = &self.edges[d * (self.n + 1)..];
            let w = e[i + 1] - e[i];
            x[d] = e[i] + (t - i as f64) * w;
            inc[d] = i;
            jac *= self.n as f64 * w;
        }
        jac
    }

    /// Moves the edges so each increment carries an equal share of the smoothed, compressed
    /// Σ(f·J)² in `acc` (per dimension, per increment).
    fn adapt(&mut self, acc: &[f64], alpha: f64) {
        let n = self.n;
        for d in 0..self.dim {
            let a = &acc[d * n..(d + 1) * n];
            // Smooth with the neighbours.
            let mut s: Vec<f64> = (0..n)
                .map(|i| {
                    let lo = if i > 0 { a[i - 1] } else { a[i] };
                    let hi = if i + 1 < n { a[i + 1] } else { a[i] };
                    if n == 1 {
                        a[i]
                    } else if i == 0 || i + 1 == n {
                        (a[i] + if i == 0 { hi } else { lo }) / 2.0
                    } else {
                        (lo + a[i] + hi) / 3.0
                    }
                })
                .collect();
            let sum: f64 = s.iter().sum();
            if sum <= 0.0 || !sum.is_finite() {
                continue;
            }
            // Compress: ((1 − r)/ln(1/r))^α with r the share, so no increment dominates.
            for v in s.iter_mut() {
                let r = *v / sum;
                *v = if r <= 0.0 {
                    0.0
                } else if r >= 1.0 {
                    1.0
                } else {
                    ((1.0 - r) / (-r.ln())).powf(alpha)
                };
            }
            let total: f64 = s.iter().sum();
            if total <= 0.0 {
                continue;
            }
            let per = total / n as f64;
            let old: Vec<f64> = self.edges[d * (n + 1)..(d + 1) * (n + 1)].to_vec();
            let new = &mut self.edges[d * (n + 1)..(d + 1) * (n + 1)];
            let (mut i, mut acc_s) = (0usize, 0.0f64);
            for k in 1..n {
                let target = per * k as f64;
                while i < n && acc_s + s[i] < target {
                    acc_s += s[i];
                    i += 1;
                }
                let i = i.min(n - 1);
                let frac = if s[i] > 0.0 {
                    (target - acc_s) / s[i]
                } else {
                    0.0
                };
                new[k] = old[i] + frac.clamp(0.0, 1.0) * (old[i + 1] - old[i]);
            }
            new[0] = 0.0;
            new[n] = 1.0;
        }
    }
}

/// The VEGAS+ integrator: its map, its stratification's σ_h estimates and its random stream
/// persist between calls, so a second [`Integrator::integrate`] continues adapting them.
pub struct Vegas {
    config: VegasConfig,
    dim: usize,
    /// Built by the first call (its increments are capped by that call's budget).
    map: Option<Map>,
    /// Damped σ_h estimates driving the allocation, one per hypercube (reset when a call's
    /// budget gives another number of hypercubes).
    sigma: Vec<f64>,
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
    per_iter: usize,
    strata: usize,
    cubes: usize,
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
            sigma: Vec::new(),
            comm: Comm::default(),
            progress: None,
        })
    }

    /// Its settings.
    pub fn config(&self) -> &VegasConfig {
        &self.config
    }

    fn plan(&self, evals: u64) -> Plan {
        let dim = self.dim;
        let mut c = self.config.clone();
        if c.iterations == 0 {
            let by_dim: u64 = match dim {
                0..=2 => 10,
                3..=4 => 40,
                _ => 80,
            };
            // Small budgets: no fewer than 20 000 points per iteration (5 iterations at least);
            // maps and strata adapted from a few hundred points are noise, and their weights
            // heavy-tailed enough to under-cover.
            c.iterations = by_dim.min((evals / 20_000).max(5)) as usize;
            c.warmup = c.iterations.div_ceil(4);
        }
        // Increments each need several points per iteration to be adapted from.
        let increments = c
            .increments
            .min((evals as usize / c.iterations / 10).max(1));
        let per_iter = (evals / c.iterations as u64).max(c.min_per_cube as u64 * 2) as usize;
        // Strata per dimension: as many hypercubes as leave min_per_cube points each.
        let strata = (((per_iter / c.min_per_cube) as f64)
            .powf(1.0 / dim as f64)
            .floor() as usize)
            .max(1);
        let cubes = strata
            .checked_pow(dim as u32)
            .filter(|&n| n <= per_iter)
            .unwrap_or(1);
        let strata = if cubes == 1 { 1 } else { strata };
        Plan {
            iterations: c.iterations,
            warmup: c.warmup,
            increments,
            per_iter,
            strata,
            cubes,
        }
    }
}

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
    fn integrate(&mut self, f: &dyn Integrand, evals: u64) -> Result<IntegrationResult> {
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
        check_budget(
            Method::Vegas,
            evals,
            (plan.iterations * 2 * min_per_cube) as u64,
            "two per hypercube of every iteration",
        )?;
        let started = Instant::now();
        let (strata, cubes, per_iter) = (plan.strata, plan.cubes, plan.per_iter);
        let map = self
            .map
            .get_or_insert_with(|| Map::new(dim, plan.increments));
        let increments = map.n;
        if self.sigma.len() != cubes {
            // Start equal.
            self.sigma = vec![1.0f64; cubes];
        }
        let sigma = &mut self.sigma;
        let rng = &mut self.rng;
        let comm = &self.comm;
        let mut acc = Accumulator::default();
        let mut comps = ComponentAccumulator::new(k);
        let mut n_eval = 0u64;
        let (mut y, mut x, mut inc) = (vec![0.0; dim], Vec::new(), vec![0usize; dim]);
        // The sampler adapts to f itself unless told otherwise: then no copy, no second pass.
        let adapts_to_f = k == 1 && train_on == TrainOn::Component(0);
        for it in 0..plan.iterations {
            // Allocate points to hypercubes ∝ σ_h^β, at least min_per_cube each.
            let weights: Vec<f64> = sigma.iter().map(|s| s.powf(beta)).collect();
            let wsum: f64 = weights.iter().sum();
            let spare = per_iter.saturating_sub(cubes * min_per_cube) as f64;
            // Cumulative rounding hands out exactly the spare points.
            let mut cum = 0.0;
            let mut given = 0usize;
            let counts: Vec<usize> = weights
                .iter()
                .map(|w| {
                    cum += if wsum > 0.0 {
                        spare * w / wsum
                    } else {
                        spare / cubes as f64
                    };
                    let upto = cum.round() as usize;
                    let extra = upto.saturating_sub(given);
                    given += extra;
                    min_per_cube + extra
                })
                .collect();
            let total: usize = counts.iter().sum();
            // Every rank draws its share of each hypercube's points from its own stream.
            let mine: Vec<usize> = counts
                .iter()
                .map(|&n| comm.share(n as u64) as usize)
                .collect();
            let local: usize = mine.iter().sum();
            x.clear();
            x.reserve(local * dim);
            let mut jacs = Vec::with_capacity(local);
            let mut incs = Vec::with_capacity(local * dim);
            let mut point = vec![0.0; dim];
            for (h, &nh) in mine.iter().enumerate() {
                for _ in 0..nh {
                    let mut kk = h;
                    for yd in y.iter_mut() {
                        *yd = ((kk % strata) as f64 + rng.random::<f64>()) / strata as f64;
                        kk /= strata;
                    }
                    jacs.push(map.apply(&y, &mut point, &mut inc));
                    x.extend_from_slice(&point);
                    incs.extend_from_slice(&inc);
                }
            }
            let fx = comm.check(evaluate(f, &x, dim))?;
            let target = if adapts_to_f {
                Vec::new()
            } else {
                train_on.target(&fx, k)
            };
            n_eval += total as u64;
            let cube = Cubes {
                counts: &counts,
                mine: &mine,
                fx: &fx,
                jacs: &jacs,
                k,
            };
            // Per hypercube, over all ranks: mean and variance of f·J (and of the target's
            // values·J when the sampler adapts to something else), Σ(f·J)² per map increment.
            let volume = 1.0 / cubes as f64;
            let (means, vars) = cube.moments(comm, |i| fx[i * k] * jacs[i]);
            let (t_vars, t_values) = if adapts_to_f {
                (None, None)
            } else {
                (
                    Some(cube.moments(comm, |i| target[i] * jacs[i]).1),
                    Some(&target),
                )
            };
            let mut grid_acc = vec![0.0; dim * increments];
            let mut w_eff = Vec::with_capacity(local);
            let mut start = 0;
            for (h, &nh) in mine.iter().enumerate() {
                let n_all = counts[h] as f64;
                for i in start..start + nh {
                    let fj = fx[i * k] * jacs[i];
                    w_eff.push(fj * volume * total as f64 / n_all);
                    // The map adapts to the target (component 0 of a scalar: f).
                    let v = t_values.map_or(fj, |t| t[i] * jacs[i]);
                    // ∫(fJ)² dy from this cube's samples: each stands for V_h/n_h of y-space.
                    let contrib = v * v * volume / n_all;
                    for d in 0..dim {
                        grid_acc[d * increments + incs[i * dim + d]] += contrib;
                    }
                }
                start += nh;
            }
            comm.sum_f64(&mut grid_acc);
            let (mut estimate, mut variance) = (0.0, 0.0);
            for (h, &nh) in counts.iter().enumerate() {
                estimate += volume * means[h];
                variance += volume * volume * vars[h] / nh as f64;
                let t_var = t_vars.as_ref().map_or(vars[h], |t| t[h]);
                sigma[h] = 0.5 * sigma[h] + 0.5 * (volume * t_var.sqrt());
            }
            if sigma.iter().all(|s| *s == 0.0) {
                sigma.fill(1.0);
            }
            let component_estimates = (k > 1).then(|| cube.components(comm, volume));
            if it >= plan.warmup {
                acc.add_iteration_across(comm, estimate, variance, total as u64, &w_eff);
                if let Some((mean_k, cov_k)) = component_estimates {
                    comps.add_iteration(mean_k, cov_k, total as u64);
                }
            }
            map.adapt(&grid_acc, alpha);
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
        let mut r = acc.finish(n_eval, started, Vec::new());
        if k > 1 {
            r.components = Some(comps.finish());
        }
        Ok(r)
    }
}

/// One iteration's points by hypercube: how many every rank drew in each (`counts`) and how
/// many this rank drew (`mine`, its points in cube order), with their values (`fx`, `n × k`),
/// and the map's Jacobians.
struct Cubes<'a> {
    counts: &'a [usize],
    mine: &'a [usize],
    fx: &'a [f64],
    jacs: &'a [f64],
    k: usize,
}

impl Cubes<'_> {
    /// This rank's points of each hypercube, as index ranges.
    fn ranges(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.mine.iter().scan(0, |start, &nh| {
            *start += nh;
            Some(*start - nh..*start)
        })
    }

    /// Per hypercube, the mean and the sample variance of `value(i)` over the points of all
    /// ranks: sums, then squared deviations from the means, reduced over the ranks (two passes,
    /// as over one process's points).
    fn moments(&self, comm: &Comm, value: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>) {
        let mut means: Vec<f64> = self.ranges().map(|r| r.map(&value).sum()).collect();
        comm.sum_f64(&mut means);
        for (m, &n) in means.iter_mut().zip(self.counts) {
            *m /= n as f64;
        }
        let mut vars: Vec<f64> = self
            .ranges()
            .zip(&means)
            .map(|(r, m)| r.map(|i| (value(i) - m).powi(2)).sum())
            .collect();
        comm.sum_f64(&mut vars);
        for (v, &n) in vars.iter_mut().zip(self.counts) {
            *v /= (n - 1) as f64;
        }
        (means, vars)
    }

    /// Every component's estimate Σ_h V_h·mean_h and its covariance Σ_h V_h²·Cov_h/n_h, the
    /// hypercubes' means and covariances taken over the points of all ranks.
    fn components(&self, comm: &Comm, volume: f64) -> (Vec<f64>, Vec<f64>) {
        let (k, cubes) = (self.k, self.counts.len());
        let mut m = vec![0.0; cubes * k];
        for (h, r) in self.ranges().enumerate() {
            for i in r {
                for a in 0..k {
                    m[h * k + a] += self.fx[i * k + a] * self.jacs[i];
                }
            }
        }
        comm.sum_f64(&mut m);
        for (h, &n) in self.counts.iter().enumerate() {
            m[h * k..(h + 1) * k]
                .iter_mut()
                .for_each(|a| *a /= n as f64);
        }
        // Σ (f_a·J − m_a)(f_b·J − m_b), each product formed once so the matrix is exactly
        // symmetric.
        let mut sums = vec![0.0; cubes * k * k];
        for (h, r) in self.ranges().enumerate() {
            let (m, sum) = (
                &m[h * k..(h + 1) * k],
                &mut sums[h * k * k..(h + 1) * k * k],
            );
            for i in r {
                let (row, jac) = (&self.fx[i * k..(i + 1) * k], self.jacs[i]);
                for a in 0..k {
                    let da = row[a] * jac - m[a];
                    for b in 0..k {
                        sum[a * k + b] += da * (row[b] * jac - m[b]);
                    }
                }
            }
        }
        comm.sum_f64(&mut sums);
        let (mut mean, mut cov) = (vec![0.0; k], vec![0.0; k * k]);
        for (h, &n) in self.counts.iter().enumerate() {
            let nh = n as f64;
            let scale = volume * volume / (nh - 1.0) / nh;
            for (c, s) in cov.iter_mut().zip(&sums[h * k * k..(h + 1) * k * k]) {
                *c += scale * s;
            }
            for (a, v) in mean.iter_mut().zip(&m[h * k..(h + 1) * k]) {
                *a += volume * v;
            }
        }
        (mean, cov)
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
