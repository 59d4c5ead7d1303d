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

use super::{check_dim, evaluate, Accumulator, Integrand, IntegrationResult, Progress};
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
        }
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

/// The VEGAS+ integrator.
pub struct Vegas {
    pub config: VegasConfig,
}

impl Vegas {
    /// A VEGAS+ integrator with the given settings.
    pub fn new(config: VegasConfig) -> Result<Vegas> {
        let c = &config;
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
        Ok(Vegas { config })
    }

    /// Integrates `f` over [0, 1]^dim with `evals` evaluations in all.
    pub fn integrate(
        &self,
        f: &dyn Integrand,
        dim: usize,
        evals: u64,
        seed: u64,
        progress: Progress,
    ) -> Result<IntegrationResult> {
        check_dim(f, dim)?;
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
        c.increments = c
            .increments
            .min((evals as usize / c.iterations / 10).max(1));
        let c = &c;
        let started = Instant::now();
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
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
        let mut map = Map::new(dim, c.increments);
        // Damped σ_h estimates driving the allocation; start equal.
        let mut sigma = vec![1.0f64; cubes];
        let mut acc = Accumulator::default();
        let mut n_eval = 0u64;
        let (mut y, mut x, mut inc) = (vec![0.0; dim], Vec::new(), vec![0usize; dim]);
        for it in 0..c.iterations {
            // Allocate points to hypercubes ∝ σ_h^β, at least min_per_cube each.
            let weights: Vec<f64> = sigma.iter().map(|s| s.powf(c.beta)).collect();
            let wsum: f64 = weights.iter().sum();
            let spare = per_iter.saturating_sub(cubes * c.min_per_cube) as f64;
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
                    c.min_per_cube + extra
                })
                .collect();
            let total: usize = counts.iter().sum();
            x.clear();
            x.reserve(total * dim);
            let mut jacs = Vec::with_capacity(total);
            let mut incs = Vec::with_capacity(total * dim);
            let mut point = vec![0.0; dim];
            for (h, &nh) in counts.iter().enumerate() {
                for _ in 0..nh {
                    let mut k = h;
                    for yd in y.iter_mut() {
                        *yd = ((k % strata) as f64 + rng.random::<f64>()) / strata as f64;
                        k /= strata;
                    }
                    jacs.push(map.apply(&y, &mut point, &mut inc));
                    x.extend_from_slice(&point);
                    incs.extend_from_slice(&inc);
                }
            }
            let fx = evaluate(f, &x, dim)?;
            n_eval += total as u64;
            // Per hypercube: mean and variance of f·J; the estimate Σ_h V_h·mean_h.
            let volume = 1.0 / cubes as f64;
            let (mut estimate, mut variance) = (0.0, 0.0);
            let mut grid_acc = vec![0.0; dim * c.increments];
            let mut w_eff = Vec::with_capacity(total);
            let mut start = 0;
            for (h, &nh) in counts.iter().enumerate() {
                let fj: Vec<f64> = (start..start + nh).map(|i| fx[i] * jacs[i]).collect();
                let mean = fj.iter().sum::<f64>() / nh as f64;
                let var = fj.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nh - 1) as f64;
                estimate += volume * mean;
                variance += volume * volume * var / nh as f64;
                for (k, v) in fj.iter().enumerate() {
                    // ∫(fJ)² dy from this cube's samples: each stands for V_h/n_h of y-space.
                    let contrib = v * v * volume / nh as f64;
                    for d in 0..dim {
                        grid_acc[d * c.increments + incs[(start + k) * dim + d]] += contrib;
                    }
                    w_eff.push(v * volume * total as f64 / nh as f64);
                }
                sigma[h] = 0.5 * sigma[h] + 0.5 * (volume * var.sqrt());
                start += nh;
            }
            if sigma.iter().all(|s| *s == 0.0) {
                sigma.fill(1.0);
            }
            if it >= c.warmup {
                acc.add_iteration(estimate, variance, &w_eff);
            }
            map.adapt(&grid_acc, c.alpha);
            progress(
                n_eval,
                evals,
                if it < c.warmup {
                    "vegas: adapting"
                } else {
                    "vegas: estimating"
                },
            );
        }
        Ok(acc.finish(n_eval, started, Vec::new()))
    }
}
