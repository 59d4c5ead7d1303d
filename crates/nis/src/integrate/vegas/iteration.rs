//! One VEGAS+ iteration (Lepage 2021, Sec. 3): every hypercube's points drawn through the map,
//! evaluated, the stratified estimate and its variance, the map trained on the target's values,
//! and each hypercube's contribution to the variance for the next allocation.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::map::Map;
use crate::comm::Comm;
use crate::error::Result;
use crate::integrate::adaptive_strata::Strata;
use crate::integrate::{evaluate, Integrand, Iteration, IterationComponents, Source, TrainOn};

/// What one iteration measures, the same for every iteration of a call.
pub(super) struct Measure<'a> {
    pub(super) f: &'a dyn Integrand,
    pub(super) comm: &'a Comm,
    pub(super) k: usize,
    pub(super) train_on: TrainOn,
    /// V_h of every hypercube.
    pub(super) volume: f64,
}

/// One iteration's estimate and variance, its evaluations over all ranks, this rank's weights
/// whose plain mean is the estimate, and every component's estimates (k > 1).
pub(super) struct Measured {
    pub(super) estimate: f64,
    pub(super) variance: f64,
    pub(super) evals: u64,
    pub(super) w_eff: Vec<f64>,
    components: Option<IterationComponents>,
}

impl Measure<'_> {
    /// Draws `counts[h]` points in every hypercube h over all ranks (each rank its share, from
    /// its own stream `rng`), evaluates them, trains `map` on the target's values and writes each
    /// hypercube's contribution to the target's variance into `contribution_var`.
    pub(super) fn iteration(
        &self,
        map: &mut Map,
        strata: &Strata,
        rng: &mut Pcg64Mcg,
        counts: &[usize],
        contribution_var: &mut [f64],
    ) -> Result<Measured> {
        let (comm, k, volume) = (self.comm, self.k, self.volume);
        let dim = strata.per_axis.len();
        let total: usize = counts.iter().sum();
        let mine: Vec<usize> = counts
            .iter()
            .map(|&n| comm.share(n as u64) as usize)
            .collect();
        let local: usize = mine.iter().sum();
        let mut x = Vec::new();
        let (jacs, incs) = draw(strata, map, &mine, rng, &mut x);
        // The failure flag of the iteration: an error on any rank stops every rank here.
        let fx = comm.check(evaluate(self.f, &x, dim))?;
        // The sampler adapts to f itself unless told otherwise: then no copy, no second pass.
        let adapts_to_f = k == 1 && self.train_on == TrainOn::Component(0);
        let target = if adapts_to_f {
            Vec::new()
        } else {
            self.train_on.target(&fx, k)
        };
        let cube = Cubes {
            counts,
            mine: &mine,
            fx: &fx,
            jacs: &jacs,
            k,
        };
        // Per hypercube, over all ranks: mean and variance of f·J (and of the target's
        // values·J when the sampler adapts to something else).
        let (means, vars) = cube.moments(comm, |i| fx[i * k] * jacs[i]);
        let t_vars = (!adapts_to_f).then(|| cube.moments(comm, |i| target[i] * jacs[i]).1);
        // The weights whose plain mean is the estimate; the map learns the target's values.
        let mut w_eff = Vec::with_capacity(local);
        for (h, r) in cube.ranges().enumerate() {
            let n_all = counts[h] as f64;
            for i in r {
                let fj = fx[i * k] * jacs[i];
                w_eff.push(fj * volume * total as f64 / n_all);
                // The map adapts to the target (component 0 of a scalar: f).
                let v = if adapts_to_f { fj } else { target[i] * jacs[i] };
                map.add_training(&incs[i * dim..(i + 1) * dim], (v * volume).powi(2));
            }
        }
        map.reduce_training(comm);
        let (estimate, variance) = stratified_estimate(
            counts,
            &means,
            &vars,
            t_vars.as_deref(),
            volume,
            contribution_var,
        );
        let components = (k > 1).then(|| {
            let (mean, cov) = cube.components(comm, volume);
            IterationComponents { mean, cov }
        });
        Ok(Measured {
            estimate,
            variance,
            evals: total as u64,
            w_eff,
            components,
        })
    }
}

impl Measured {
    /// The iteration for the estimate: the largest |w| and Σ|w| reduced over the ranks.
    pub(super) fn iteration(self, comm: &Comm) -> Iteration {
        let mut max_abs_w = [self.w_eff.iter().fold(0.0f64, |m, v| m.max(v.abs()))];
        comm.max_f64(&mut max_abs_w);
        Iteration {
            estimate: self.estimate,
            variance: self.variance,
            evals: self.evals,
            source: Source::Final,
            max_abs_w: max_abs_w[0],
            sum_abs_w: comm.sum(self.w_eff.iter().fold(0.0, |s, v| s + v.abs())),
            components: self.components,
        }
    }
}

/// This rank's `mine[h]` points of every hypercube h of `strata`, uniform in it, through `map`:
/// the points into `x` (`n × d`, cleared first), and their Jacobians and increments (`n × d`).
fn draw(
    strata: &Strata,
    map: &Map,
    mine: &[usize],
    rng: &mut Pcg64Mcg,
    x: &mut Vec<f64>,
) -> (Vec<f64>, Vec<usize>) {
    let dim = strata.per_axis.len();
    let local: usize = mine.iter().sum();
    x.clear();
    x.reserve(local * dim);
    let mut jacs = Vec::with_capacity(local);
    let mut incs = Vec::with_capacity(local * dim);
    let (mut y, mut point, mut inc) = (vec![0.0; dim], vec![0.0; dim], vec![0usize; dim]);
    let mut corner = vec![0usize; dim];
    for (h, &nh) in mine.iter().enumerate() {
        strata.corner(h, &mut corner);
        for _ in 0..nh {
            for ((yd, &c), &s) in y.iter_mut().zip(&corner).zip(&strata.per_axis) {
                *yd = (c as f64 + rng.random::<f64>()) / s as f64;
            }
            jacs.push(map.apply(&y, &mut point, &mut inc));
            x.extend_from_slice(&point);
            incs.extend_from_slice(&inc);
        }
    }
    (jacs, incs)
}

/// The stratified estimate Σ_h V_h·mean_h and its variance Σ_h V_h²·Var_h/n_h from every
/// hypercube's `counts`, `means` and `vars` (of f·J; V_h = `volume`), and each hypercube's
/// contribution to the variance of the target the strata adapt to (`t_vars`, or f's) into
/// `contribution_var`.
fn stratified_estimate(
    counts: &[usize],
    means: &[f64],
    vars: &[f64],
    t_vars: Option<&[f64]>,
    volume: f64,
    contribution_var: &mut [f64],
) -> (f64, f64) {
    let (mut estimate, mut variance) = (0.0, 0.0);
    for (h, &nh) in counts.iter().enumerate() {
        estimate += volume * means[h];
        variance += volume * volume * vars[h] / nh as f64;
        let t_var = t_vars.map_or(vars[h], |t| t[h]);
        contribution_var[h] = volume * volume * t_var / nh as f64;
    }
    (estimate, variance)
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
