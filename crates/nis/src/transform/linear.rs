//! Piecewise-linear coupling transform: a piecewise-constant density on K equal bins
//! (Müller et al. 2019, Sec. 2.1, Eq. 5). The network predicts K bin logits Q̂; Q = softmax(Q̂)
//! are the bin masses, the density in bin b is K·Q_b, and C(x) = α·Q_b + Σ_{k<b} Q_k with α the
//! relative position of x in its bin. Bin widths are fixed: the paper's Appendix A shows why
//! learnable widths cannot be trained by these gradients.

use super::{equal_bin, softmax_floor, softmax_floor_backward, with_scratch, Transform};

/// Smallest bin mass, as a fraction of the mean mass 1/K: the density never falls below this
/// value, which keeps log-densities finite and importance weights f/q bounded. It is also mass
/// the flow cannot take away from where the integrand vanishes — every transformed dimension of
/// every layer wastes up to this share — so it is small: 1e-2 put a floor of ~0.08 under the
/// relative variance of a 4-d Gaussian. (The f32 inverse's error is ~ulp(y)/density, so the
/// round trip is within 1e-5 wherever the density is above ~1e-2, and exact up to that rounding
/// below.)
pub const MIN_BIN_MASS: f64 = 1e-3;

/// Piecewise-linear transform with `bins` equal bins; `bins` parameters per dimension.
#[derive(Clone, Copy, Debug)]
pub struct Linear {
    pub bins: usize,
}

impl Transform for Linear {
    fn param_count(&self) -> usize {
        self.bins
    }

    #[inline]
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        let k = self.bins;
        with_scratch(k, |q| {
            softmax_floor(&p[..k], MIN_BIN_MASS, q);
            let (b, alpha) = equal_bin(x, k);
            let cdf: f64 = q[..b].iter().sum();
            let y = (cdf + alpha * q[b]).clamp(0.0, 1.0);
            (y, (k as f64 * q[b]).ln())
        })
    }

    #[inline]
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
        let k = self.bins;
        with_scratch(k, |q| {
            softmax_floor(&p[..k], MIN_BIN_MASS, q);
            let mut cdf = 0.0;
            let mut b = 0;
            while b + 1 < k && cdf + q[b] <= y {
                cdf += q[b];
                b += 1;
            }
            let alpha = ((y - cdf) / q[b]).clamp(0.0, 1.0);
            let x = ((b as f64 + alpha) / k as f64).clamp(0.0, 1.0);
            (x, (k as f64 * q[b]).ln())
        })
    }

    fn bin_edges(&self, _p: &[f32]) -> Vec<f64> {
        (0..=self.bins)
            .map(|i| i as f64 / self.bins as f64)
            .collect()
    }

    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64 {
        let k = self.bins;
        with_scratch(2 * k, |buf| {
            let (q, g_q) = buf.split_at_mut(k);
            softmax_floor(&p[..k], MIN_BIN_MASS, q);
            let (b, alpha) = equal_bin(x, k);
            g_q.fill(0.0);
            g_q[..b].fill(g_y);
            g_q[b] = g_y * alpha + g_log_det / q[b];
            softmax_floor_backward(q, g_q, MIN_BIN_MASS, &mut g_p[..k]);
            // The density is constant inside a bin: only y depends on x.
            g_y * k as f64 * q[b]
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::testing;

    #[test]
    fn linear_batched_equals_per_scalar() {
        for bins in [1, 2, 5, 16, 32] {
            testing::check_batch(&Linear { bins });
        }
    }

    #[test]
    fn linear_round_trips_and_gradients() {
        for bins in [1, 2, 5, 32] {
            testing::check_transform(&Linear { bins }, true);
        }
    }

    #[test]
    fn linear_density_is_bin_mass_times_bins() {
        let t = Linear { bins: 4 };
        let p = [0.0, (3.0f32).ln(), 0.0, 0.0];
        let (_, ld) = t.forward(&p, 0.3);
        let mass = MIN_BIN_MASS / 4.0 + (1.0 - MIN_BIN_MASS) * 3.0 / 6.0;
        assert!((ld - (4.0 * mass).ln()).abs() < 1e-6);
    }
}
