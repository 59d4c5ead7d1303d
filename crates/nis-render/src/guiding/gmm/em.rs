//! Fitting the mixtures (Vorba et al. 2014, §5): weighted expectation–maximisation in its
//! on-line, *stepwise* form (Cappé & Moulines 2009, "On-line Expectation–Maximization Algorithm
//! for Latent Data Models"), with a maximum-a-posteriori M-step.
//!
//! Each training iteration brings a batch of weighted disk points (weight `radiance / pdf`). The
//! E-step computes every point's responsibilities and the batch's normalised sufficient
//! statistics `Σ γw`, `Σ γw x`, `Σ γw x xᵀ`; these are blended into the running statistics with
//! step size `η_t = t^(−exponent)` at the `t`-th fitted iteration, and the M-step turns the
//! blend into weights, means and covariances under a Dirichlet prior on the weights and a
//! `σ₀² I` prior on the covariances, which keeps components that receive little weight
//! well-defined.

use glam::DVec2;

use super::mixture::{Component, Mixture};
use super::GmmConfig;

/// Farthest a mean may be from the disk centre (keeps the in-disk mass integrand smooth).
const MAX_MEAN_RADIUS: f64 = 0.999;

/// Normalised weighted sufficient statistics of a mixture: per component `Σ γw`, `Σ γw x`
/// and `Σ γw x xᵀ` over `Σ w = 1`.
#[derive(Clone, Debug, Default)]
struct SufficientStatistics {
    s0: Vec<f64>,
    s1: Vec<DVec2>,
    s2: Vec<[f64; 3]>,
}

impl SufficientStatistics {
    fn zero(k: usize) -> Self {
        Self {
            s0: vec![0.0; k],
            s1: vec![DVec2::ZERO; k],
            s2: vec![[0.0; 3]; k],
        }
    }

    /// `(1 − η) self + η batch`.
    fn blend(&self, batch: &SufficientStatistics, eta: f64) -> SufficientStatistics {
        let mix = |a: f64, b: f64| (1.0 - eta) * a + eta * b;
        SufficientStatistics {
            s0: (0..self.s0.len())
                .map(|k| mix(self.s0[k], batch.s0[k]))
                .collect(),
            s1: (0..self.s1.len())
                .map(|k| (1.0 - eta) * self.s1[k] + eta * batch.s1[k])
                .collect(),
            s2: (0..self.s2.len())
                .map(|k| std::array::from_fn(|i| mix(self.s2[k][i], batch.s2[k][i])))
                .collect(),
        }
    }
}

/// A mixture learned by stepwise EM, with the running statistics it is fitted from.
#[derive(Clone, Debug)]
pub(super) struct OnlineMixture {
    pub(super) mixture: Mixture,
    stats: SufficientStatistics,
    /// Iterations fitted so far (`t` of stepwise EM).
    steps: u32,
}

impl OnlineMixture {
    /// The initial mixture of `k` components ([`Mixture::initial`]), nothing fitted yet.
    pub(super) fn initial(k: usize) -> Self {
        OnlineMixture {
            mixture: Mixture::initial(k),
            stats: SufficientStatistics::zero(k),
            steps: 0,
        }
    }

    /// Stepwise EM over one iteration's samples `(disk point, weight)` with `Σ weight > 0`.
    pub(super) fn fit(&mut self, samples: &[(DVec2, f64)], config: &GmmConfig) {
        let m = &mut self.mixture;
        let k = m.components.len();
        let total: f64 = samples.iter().map(|s| s.1).sum();
        self.steps += 1;
        let eta = f64::from(self.steps).powf(-config.step_exponent);
        let mut blended = self.stats.clone();
        let mut log_g = vec![0.0; k];
        for _ in 0..config.em_steps {
            let mut batch = SufficientStatistics::zero(k);
            let log_w: Vec<f64> = m.components.iter().map(|c| c.weight.ln()).collect();
            for &(x, w) in samples {
                for ((g, c), lw) in log_g.iter_mut().zip(&m.components).zip(&log_w) {
                    *g = lw + c.log_density(x);
                }
                let max = log_g.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let sum: f64 = log_g.iter().map(|g| (g - max).exp()).sum();
                for j in 0..k {
                    let gw = (log_g[j] - max).exp() / sum * w / total;
                    batch.s0[j] += gw;
                    batch.s1[j] += gw * x;
                    batch.s2[j][0] += gw * x.x * x.x;
                    batch.s2[j][1] += gw * x.x * x.y;
                    batch.s2[j][2] += gw * x.y * x.y;
                }
            }
            blended = self.stats.blend(&batch, eta);
            m.maximise(&blended, config);
        }
        self.stats = blended;
        for c in &mut m.components {
            c.inside = c.disk_mass();
        }
        m.finish();
    }
}

impl Mixture {
    /// MAP M-step: Dirichlet prior on the weights, conjugate (inverse-Wishart-like) prior
    /// `σ₀² I` on the covariances, none on the means (which stay in the disk, being weighted
    /// means of disk points). In-disk masses are left for the end of [`OnlineMixture::fit`].
    fn maximise(&mut self, s: &SufficientStatistics, config: &GmmConfig) {
        let k = self.components.len();
        let a = config.prior_strength;
        let pseudo = a / k as f64;
        let s_total: f64 = s.s0.iter().sum();
        for j in 0..k {
            let old = self.components[j];
            let s0 = s.s0[j];
            let weight = (s0 + pseudo) / (s_total + a);
            let mut mean = if s0 > 1e-12 { s.s1[j] / s0 } else { old.mean };
            if mean.length() > MAX_MEAN_RADIUS {
                mean *= MAX_MEAN_RADIUS / mean.length();
            }
            let scatter = [
                (s.s2[j][0] - s0 * mean.x * mean.x).max(0.0),
                s.s2[j][1] - s0 * mean.x * mean.y,
                (s.s2[j][2] - s0 * mean.y * mean.y).max(0.0),
            ];
            let prior = a * config.prior_variance;
            let cov = [
                (scatter[0] + prior) / (s0 + a),
                scatter[1] / (s0 + a),
                (scatter[2] + prior) / (s0 + a),
            ];
            self.components[j] = Component::without_mass(weight, mean, cov);
        }
        self.finish();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_em_recovers_two_gaussians_on_the_disk() {
        // Points on a grid over the disk weighted by a two-Gaussian density: weighted EM
        // (with a negligible prior) recovers the weights, means and covariances.
        let truth = [
            (0.7, DVec2::new(0.3, 0.2), [0.010, 0.004, 0.020]),
            (0.3, DVec2::new(-0.4, -0.3), [0.015, 0.0, 0.005]),
        ];
        let gaussians = truth.map(|(w, m, c)| Component::new(w, m, c));
        let density = |x: DVec2| -> f64 {
            gaussians
                .iter()
                .map(|g| g.weight * g.log_density(x).exp())
                .sum()
        };
        let n = 200;
        let points: Vec<(DVec2, f64)> = (0..n * n)
            .map(|i| {
                let x = DVec2::new(
                    -1.0 + (2 * (i % n) + 1) as f64 / n as f64,
                    -1.0 + (2 * (i / n) + 1) as f64 / n as f64,
                );
                (x, density(x))
            })
            .filter(|(x, _)| x.length_squared() < 1.0)
            .collect();
        let config = GmmConfig {
            components: 2,
            em_steps: 60,
            prior_strength: 1e-6,
            ..GmmConfig::default()
        };
        let mut online = OnlineMixture::initial(2);
        online.fit(&points, &config);
        let m = &online.mixture;
        // Component 0 starts at the centre, component 1 at (0.5, 0): match by the means.
        let mut found: Vec<&Component> = m.components.iter().collect();
        found.sort_by(|a, b| b.mean.x.total_cmp(&a.mean.x));
        for ((w, mean, cov), c) in truth.iter().zip(found) {
            assert!((c.weight - w).abs() < 1e-3, "weight {} vs {w}", c.weight);
            assert!(
                (c.mean - *mean).length() < 1e-3,
                "mean {} vs {mean}",
                c.mean
            );
            let det = cov[0] * cov[2] - cov[1] * cov[1];
            let inv = [cov[2] / det, -cov[1] / det, cov[0] / det];
            for (a, b) in c.inv.iter().zip(inv) {
                assert!(
                    (a - b).abs() < 1e-2 * b.abs().max(1.0),
                    "inverse {:?} vs {inv:?}",
                    c.inv
                );
            }
        }
        // The disk density integrates to one: the uniform part holds what left the disk.
        let cell = (2.0 / n as f64).powi(2);
        let total: f64 = points.iter().map(|&(x, _)| m.pdf_disk(x) * cell).sum();
        assert!((total - 1.0).abs() < 2e-3, "{total}");
    }
}
