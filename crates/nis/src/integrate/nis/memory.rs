//! What training saw, to check the final sampler against: a uniform reservoir sample (Vitter's
//! algorithm R) of the training points where f ≠ 0, with |f| (component 0). Training draws from
//! every stage of the flow, the early broad ones and the defensive uniform share included, so its
//! points reach regions the trained flow may have abandoned. The final sampler's largest weight
//! |f|/q at those points, over the largest weight its own estimate drew, says whether it gives
//! far less density than f needs somewhere it no longer samples: the flank of a peak that
//! training found and the flow then dropped, which no figure of the estimate's own weights can
//! show (docs/results/robustness.md measures which runs it catches).

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
    seen: u64,
    /// [`TrainingMemory::largest_weight`] once computed (the flow is frozen until the next
    /// training, which clears it).
    largest: Option<Option<f64>>,
}

impl TrainingMemory {
    /// An empty reservoir for `dim`-dimensional points.
    pub(crate) fn new(dim: usize) -> TrainingMemory {
        TrainingMemory {
            dim,
            x: Vec::new(),
            f: Vec::new(),
            seen: 0,
            largest: None,
        }
    }

    /// Forgets the points (a new training starts).
    pub(crate) fn clear(&mut self) {
        self.x.clear();
        self.f.clear();
        self.seen = 0;
        self.largest = None;
    }

    /// Offers the points `x` (n × dim) with integrand values `fx` (n × k, component 0 kept),
    /// choosing which to keep from `rng`. Zeros are not kept: their weight is zero.
    pub(crate) fn observe(&mut self, x: &[f32], fx: &[f64], k: usize, rng: &mut Pcg64Mcg) {
        self.largest = None;
        for (p, v) in x.chunks_exact(self.dim).zip(fx.chunks_exact(k)) {
            let v = v[0].abs();
            if v == 0.0 || !v.is_finite() {
                continue;
            }
            self.seen += 1;
            if self.f.len() < CAPACITY {
                self.x.extend_from_slice(p);
                self.f.push(v);
                continue;
            }
            let j = rng.random_range(0..self.seen);
            if (j as usize) < CAPACITY {
                let j = j as usize;
                self.x[j * self.dim..(j + 1) * self.dim].copy_from_slice(p);
                self.f[j] = v;
            }
        }
    }

    /// The largest weight |f|/q_mix that `sampler` gives a kept point, over all ranks of `comm`
    /// (`None` when no rank kept one); computed once per training, as `sampler` is frozen until
    /// the next.
    pub(super) fn largest_weight(
        &mut self,
        sampler: &DefensiveMixture<Flow>,
        comm: &Comm,
    ) -> Result<Option<f64>> {
        if let Some(known) = self.largest {
            return Ok(known);
        }
        let local = if self.f.is_empty() {
            Ok(0.0)
        } else {
            sampler.log_density(&self.x, None).map(|log_q| {
                self.f
                    .iter()
                    .zip(&log_q)
                    .map(|(f, l)| f * (-l).exp())
                    .fold(0.0, f64::max)
            })
        };
        // A failure on any rank stops every rank here.
        let mut largest = [comm.check(local)?];
        comm.max_f64(&mut largest);
        let known = (largest[0] > 0.0).then_some(largest[0]);
        self.largest = Some(known);
        Ok(known)
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
        m.observe(&x, &f, 1, &mut rng);
        assert_eq!(m.f.len(), CAPACITY);
        assert_eq!(m.seen as usize, n / 2);
        assert!(m.f.iter().all(|v| *v > 0.0));
        // The mean of a uniform sample of 1, 3, …, n − 1 (plus one): n/2, with sd ≈ n/√12/√CAP.
        let mean = m.f.iter().sum::<f64>() / CAPACITY as f64;
        let sd = n as f64 / 12f64.sqrt() / (CAPACITY as f64).sqrt();
        assert!((mean - n as f64 / 2.0).abs() < 5.0 * sd, "{mean}");
        m.clear();
        assert!(m.f.is_empty() && m.x.is_empty() && m.seen == 0);
    }

    #[test]
    fn under_the_uniform_sampler_the_largest_weight_is_the_largest_f() {
        // An untrained flow is uniform, and so is its mixture: q = 1, w = |f|.
        let sampler = DefensiveMixture::new(Flow::new(FlowConfig::new(2)).unwrap(), 0.1).unwrap();
        let mut m = TrainingMemory::new(2);
        let comm = Comm::default();
        assert_eq!(m.largest_weight(&sampler, &comm).unwrap(), None);
        let mut rng = Pcg64Mcg::seed_from_u64(2);
        m.observe(
            &[0.1, 0.2, 0.5, 0.5, 0.9, 0.3],
            &[2.0, -7.0, 0.0],
            1,
            &mut rng,
        );
        let w = m.largest_weight(&sampler, &comm).unwrap().unwrap();
        assert!((w - 7.0).abs() < 1e-4, "{w}");
    }
}
