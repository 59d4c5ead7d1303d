//! What training saw, to check the final sampler against: a uniform reservoir sample (Vitter's
//! algorithm R) of the training points where f ≠ 0, with |f| (component 0). Training draws from
//! every stage of the flow, the early broad ones and the defensive uniform share included, so its
//! points reach regions the trained flow may have abandoned. The final sampler's largest weight
//! |f|/q at those points, over the largest weight its own estimate drew, says whether it gives
//! far less density than f needs somewhere it no longer samples: the flank of a peak that
//! training found and the flow then dropped, which no figure of the estimate's own weights can
//! show (docs/results/robustness.md measures which runs it catches).
//!
//! Each kept point also keeps the density q_t of the sampler that drew it, so the points are an
//! importance sample of f in their own right: (1/N) Σ |f|/q_t over those of them in a region R
//! estimates ∫_R |f| without bias (Horvitz–Thompson, scaled by the reservoir's inclusion rate).
//! With R where the final sampler's weight exceeds anything its estimate drew, that is the mass
//! the estimate could not see ([`Recall::mass`]): a dropped peak carries much of it, a thin tail
//! little.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::comm::Comm;
use crate::error::Result;
use crate::flow::mixture::DefensiveMixture;
use crate::flow::{Density, Flow};

/// Points kept at most (per rank): 2¹⁶, a few MB, one batch of density evaluations at the end.
const CAPACITY: usize = 1 << 16;

/// The reservoir of training points (module docs).
#[derive(Clone, Debug)]
pub(crate) struct TrainingMemory {
    dim: usize,
    x: Vec<f32>,
    /// |f| of every kept point.
    f: Vec<f64>,
    /// ln q_t of every kept point: the density of the sampler that drew it.
    log_q: Vec<f64>,
    /// Points with f ≠ 0 offered.
    seen: u64,
    /// Points offered, zeros included.
    offered: u64,
    /// The final sampler's weight |f|/q of every kept point once computed (the flow is frozen
    /// until the next training, which clears it).
    recalled: Option<Vec<f64>>,
}

/// What the kept training points say about the final sampler (module docs), over all ranks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Recall {
    /// The largest weight |f|/q the final sampler gives a kept point (`None`: none kept).
    pub largest: Option<f64>,
    /// The estimate of ∫ |f| over the region where the final weight exceeds the threshold.
    pub mass: f64,
    /// Its standard error.
    pub mass_err: f64,
    /// The kept points in that region.
    pub beyond: u64,
}

impl TrainingMemory {
    /// An empty reservoir for `dim`-dimensional points.
    pub(crate) fn new(dim: usize) -> TrainingMemory {
        TrainingMemory {
            dim,
            x: Vec::new(),
            f: Vec::new(),
            log_q: Vec::new(),
            seen: 0,
            offered: 0,
            recalled: None,
        }
    }

    /// Forgets the points (a new training starts).
    pub(crate) fn clear(&mut self) {
        self.x.clear();
        self.f.clear();
        self.log_q.clear();
        self.seen = 0;
        self.offered = 0;
        self.recalled = None;
    }

    /// Offers the points `x` (n × dim) drawn with densities `exp(log_q)`, with integrand values
    /// `fx` (n × k, component 0 kept), choosing which to keep from `rng`. Zeros are not kept:
    /// their weight is zero (they still count towards the mass estimate's N).
    pub(crate) fn observe(
        &mut self,
        x: &[f32],
        log_q: &[f64],
        fx: &[f64],
        k: usize,
        rng: &mut Pcg64Mcg,
    ) {
        self.recalled = None;
        self.offered += log_q.len() as u64;
        for ((p, v), l) in x.chunks_exact(self.dim).zip(fx.chunks_exact(k)).zip(log_q) {
            let v = v[0].abs();
            if v == 0.0 || !v.is_finite() {
                continue;
            }
            self.seen += 1;
            if self.f.len() < CAPACITY {
                self.x.extend_from_slice(p);
                self.f.push(v);
                self.log_q.push(*l);
                continue;
            }
            let j = rng.random_range(0..self.seen);
            if (j as usize) < CAPACITY {
                let j = j as usize;
                self.x[j * self.dim..(j + 1) * self.dim].copy_from_slice(p);
                self.f[j] = v;
                self.log_q[j] = *l;
            }
        }
    }

    /// The kept points (row-major, `dim` each).
    pub(crate) fn points(&self) -> &[f32] {
        &self.x
    }

    /// Multiplies each kept point's |f| by its entry of `factors` (one per kept point): the
    /// integrand changed since training by a known factor (a multi-channel part whose channel
    /// weights moved after its training).
    pub(crate) fn rescale(&mut self, factors: &[f64]) {
        debug_assert_eq!(factors.len(), self.f.len());
        for (f, s) in self.f.iter_mut().zip(factors) {
            *f *= s;
        }
        self.recalled = None;
    }

    /// What the kept points say about `sampler` ([`Recall`]) over all ranks of `comm`, the
    /// region being where its weight |f|/q_mix exceeds `threshold`; the weights are computed
    /// once per training, as `sampler` is frozen until the next.
    pub(crate) fn recall(
        &mut self,
        sampler: &DefensiveMixture<Flow>,
        threshold: f64,
        comm: &Comm,
    ) -> Result<Recall> {
        if self.recalled.is_none() {
            let w = if self.f.is_empty() {
                Ok(Vec::new())
            } else {
                sampler.log_density(&self.x, None).map(|log_q| {
                    self.f
                        .iter()
                        .zip(&log_q)
                        .map(|(f, l)| f * (-l).exp())
                        .collect()
                })
            };
            // A failure on any rank stops every rank here.
            self.recalled = Some(comm.check(w)?);
        }
        let recalled = self.recalled.as_deref().unwrap_or_default();
        // Each kept point stands for seen/kept of the nonzero points offered on its rank.
        let inclusion = if self.f.is_empty() {
            0.0
        } else {
            self.seen as f64 / self.f.len() as f64
        };
        let (mut sum, mut sum_sq, mut beyond) = (0.0, 0.0, 0.0);
        for ((w, f), l) in recalled.iter().zip(&self.f).zip(&self.log_q) {
            if *w > threshold {
                let y = inclusion * f * (-l).exp();
                sum += y;
                sum_sq += y * y;
                beyond += 1.0;
            }
        }
        let mut sums = [sum, sum_sq, beyond, self.offered as f64];
        comm.sum_f64(&mut sums);
        let largest = comm.max(recalled.iter().copied().fold(0.0, f64::max));
        let n = sums[3];
        // The terms are independent, not identical: Σy²/N² bounds the variance of their mean.
        let (mass, mass_err) = if n > 0.0 {
            (sums[0] / n, sums[1].sqrt() / n)
        } else {
            (0.0, 0.0)
        };
        Ok(Recall {
            largest: (largest > 0.0).then_some(largest),
            mass,
            mass_err,
            beyond: sums[2] as u64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::FlowConfig;
    use rand::SeedableRng;

    #[test]
    fn the_reservoir_keeps_a_uniform_sample_of_the_nonzero_points() {
        // 3·CAPACITY points with f = their index + 1, every other one zero: at most CAPACITY
        // kept, only nonzero ones, and their mean index near the mean of all (uniform sample).
        let mut m = TrainingMemory::new(1);
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let n = 3 * CAPACITY;
        let x: Vec<f32> = (0..n).map(|i| i as f32 / n as f32).collect();
        let f: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 0.0 } else { (i + 1) as f64 })
            .collect();
        m.observe(&x, &vec![0.0; n], &f, 1, &mut rng);
        assert_eq!(m.f.len(), CAPACITY);
        assert_eq!(m.seen as usize, n / 2);
        assert!(m.f.iter().all(|v| *v > 0.0));
        // The mean of a uniform sample of 1, 3, …, n − 1 (plus one): n/2, with sd ≈ n/√12/√CAP.
        let mean = m.f.iter().sum::<f64>() / CAPACITY as f64;
        let sd = n as f64 / 12f64.sqrt() / (CAPACITY as f64).sqrt();
        assert!((mean - n as f64 / 2.0).abs() < 5.0 * sd, "{mean}");
        m.clear();
        assert!(m.f.is_empty() && m.x.is_empty() && m.seen == 0 && m.offered == 0);
    }

    #[test]
    fn under_the_uniform_sampler_the_largest_weight_is_the_largest_f() {
        // An untrained flow is uniform, and so is its mixture: q = 1, w = |f|.
        let sampler = DefensiveMixture::new(Flow::new(FlowConfig::new(2)).unwrap(), 0.1).unwrap();
        let mut m = TrainingMemory::new(2);
        let comm = Comm::default();
        assert_eq!(m.recall(&sampler, 0.0, &comm).unwrap().largest, None);
        let mut rng = Pcg64Mcg::seed_from_u64(2);
        m.observe(
            &[0.1, 0.2, 0.5, 0.5, 0.9, 0.3],
            &[0.0; 3],
            &[2.0, -7.0, 0.0],
            1,
            &mut rng,
        );
        let r = m.recall(&sampler, 3.0, &comm).unwrap();
        assert!((r.largest.unwrap() - 7.0).abs() < 1e-4, "{r:?}");
        // Only the point of |f| = 7 lies beyond 3; it is one of the three points offered.
        assert_eq!(r.beyond, 1);
        assert!((r.mass - 7.0 / 3.0).abs() < 1e-12 && (r.mass_err - 7.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn the_mass_beyond_the_threshold_is_estimated_without_bias_from_a_subsample() {
        // f = 1 + 9·[x₀ > 0.8] on the unit square, drawn from the uniform density, 3·CAPACITY
        // points so that the reservoir keeps a third. The final
        // sampler is uniform too, so its weight is f and the region beyond 5 is x₀ > 0.8, of
        // mass 10 · 0.2 = 2. Per point y = 10·[x₀ > 0.8] has variance 16: the estimate from
        // CAPACITY points has sd 4/√CAPACITY, and the error bar Σy²/N² reads 10·√(0.2/CAPACITY).
        let sampler = DefensiveMixture::new(Flow::new(FlowConfig::new(2)).unwrap(), 0.1).unwrap();
        let comm = Comm::default();
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        let n = 3 * CAPACITY;
        let x: Vec<f32> = (0..2 * n).map(|_| rng.random::<f32>()).collect();
        let f: Vec<f64> = x
            .chunks_exact(2)
            .map(|p| if p[0] > 0.8 { 10.0 } else { 1.0 })
            .collect();
        let mut m = TrainingMemory::new(2);
        m.observe(&x, &vec![0.0; n], &f, 1, &mut rng);
        let r = m.recall(&sampler, 5.0, &comm).unwrap();
        let sd = 4.0 / (CAPACITY as f64).sqrt();
        assert!(
            (r.mass_err / sd - 10.0 * 0.2f64.sqrt() / 4.0).abs() < 0.05,
            "{r:?}"
        );
        assert!((r.mass - 2.0).abs() < 4.0 * sd, "{r:?}");
        // The same points said to be drawn with q = ½ on x₀ > ½ (3/2 elsewhere): the estimate
        // is then of ∫ f/q over x₀ > 0.8 = 4, which shows that q_t enters the weight.
        let log_q: Vec<f64> = x
            .chunks_exact(2)
            .map(|p| if p[0] > 0.5 { 0.5f64.ln() } else { 1.5f64.ln() })
            .collect();
        let mut m = TrainingMemory::new(2);
        m.observe(&x, &log_q, &f, 1, &mut rng);
        let r = m.recall(&sampler, 5.0, &comm).unwrap();
        assert!((r.mass - 4.0).abs() < 8.0 * sd, "{r:?}");
    }
}
