//! Piecewise-quadratic coupling transform: a piecewise-linear density on K adaptive bins
//! (Müller et al. 2019, Sec. 2.2; details in Müller et al. 2018, "Neural Importance Sampling").
//!
//! The network predicts K width logits Ŵ and K+1 vertex logits V̂. Widths are W = softmax(Ŵ);
//! vertex heights are V_j = exp(V̂_j) / Σ_k ½(exp V̂_k + exp V̂_{k+1})·W_k, the normalisation that
//! makes the trapezoids' total area one. Inside bin b at relative position α the density is
//! V_b + α(V_{b+1} − V_b) and the CDF a quadratic in α. Unlike bin widths of the piecewise-linear
//! transform, these widths get correct gradients because the density is continuous.

use super::{
    edges_from_widths, exponentials, softmax_floor, softmax_floor_backward, with_scratch, Transform,
};

/// Smallest bin width as a fraction of the mean width 1/K: no bin collapses to zero.
pub const MIN_BIN_WIDTH: f64 = 1e-3;
/// Smallest vertex height (density), mixed in as `V = m + (1 − m)·Ṽ` so that the area stays one.
/// It keeps log-densities finite; see [`super::linear::MIN_BIN_MASS`] for why it is small.
pub const MIN_DENSITY: f64 = 1e-3;

/// Piecewise-quadratic transform with `bins` adaptive bins; `2·bins + 1` parameters per dimension.
#[derive(Clone, Copy, Debug)]
pub struct Quadratic {
    pub bins: usize,
}

/// Normalised widths W, vertex heights V and the pieces needed to differentiate them.
struct Knots<'a> {
    w: &'a mut [f64],
    v: &'a mut [f64],
    /// exp(V̂ − max V̂) and the normaliser N = Σ ½(E_k + E_{k+1}) W_k.
    e: &'a mut [f64],
    norm: f64,
}

impl Quadratic {
    /// Scratch values one call needs: the knots and the backward pass's gradient buffers.
    fn scratch(&self) -> usize {
        5 * self.bins + 3
    }

    /// Computes the knots into the front of `buf`; returns them and the rest of `buf`.
    #[inline]
    fn knots<'a>(&self, p: &[f32], buf: &'a mut [f64]) -> (Knots<'a>, &'a mut [f64]) {
        let k = self.bins;
        let (w, rest) = buf.split_at_mut(k);
        let (v, rest) = rest.split_at_mut(k + 1);
        let (e, rest) = rest.split_at_mut(k + 1);
        softmax_floor(&p[..k], MIN_BIN_WIDTH, w);
        exponentials(&p[k..2 * k + 1], e);
        let norm: f64 = (0..k).map(|i| 0.5 * (e[i] + e[i + 1]) * w[i]).sum();
        let scale = (1.0 - MIN_DENSITY) / norm;
        for j in 0..=k {
            v[j] = MIN_DENSITY + scale * e[j];
        }
        (Knots { w, v, e, norm }, rest)
    }

    #[inline]
    fn inverse_in(&self, p: &[f32], y: f64, buf: &mut [f64]) -> (f64, f64) {
        let k = self.bins;
        let (kn, _) = self.knots(p, buf);
        let (mut b, mut edge, mut cdf) = (0, 0.0, 0.0);
        loop {
            let mass = 0.5 * (kn.v[b] + kn.v[b + 1]) * kn.w[b];
            if b + 1 == k || y < cdf + mass {
                break;
            }
            edge += kn.w[b];
            cdf += mass;
            b += 1;
        }
        let w = kn.w[b];
        let (v0, dv) = (kn.v[b], kn.v[b + 1] - kn.v[b]);
        // Solve a·α² + bq·α − c = 0 with a = ½·ΔV·W, bq = V_b·W, c = y − Y_b ≥ 0. The textbook root
        // (−bq + √(bq² + 4ac))/(2a) cancels catastrophically when a → 0; the equivalent
        // 2c/(bq + √(bq² + 4ac)) never does, since bq > 0.
        let a = 0.5 * dv * w;
        let bq = v0 * w;
        let c = (y - cdf).max(0.0);
        let disc = (bq * bq + 4.0 * a * c).max(0.0);
        let alpha = (2.0 * c / (bq + disc.sqrt())).clamp(0.0, 1.0);
        let x = (edge + alpha * w).clamp(0.0, 1.0);
        (x, (v0 + alpha * dv).ln())
    }

    /// Bin of `x`: (b, left edge X_b, CDF at X_b). The last bin takes whatever rounding leaves.
    #[inline]
    fn locate(&self, kn: &Knots, x: f64) -> (usize, f64, f64) {
        let (mut b, mut edge, mut cdf) = (0, 0.0, 0.0);
        while b + 1 < self.bins && x >= edge + kn.w[b] {
            edge += kn.w[b];
            cdf += 0.5 * (kn.v[b] + kn.v[b + 1]) * kn.w[b];
            b += 1;
        }
        (b, edge, cdf)
    }
}

impl Transform for Quadratic {
    fn param_count(&self) -> usize {
        2 * self.bins + 1
    }

    #[inline]
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        with_scratch(self.scratch(), |buf| {
            let (kn, _) = self.knots(p, buf);
            let (b, edge, cdf) = self.locate(&kn, x);
            let w = kn.w[b];
            let alpha = ((x - edge) / w).clamp(0.0, 1.0);
            let (v0, dv) = (kn.v[b], kn.v[b + 1] - kn.v[b]);
            let y = (cdf + w * alpha * (v0 + 0.5 * alpha * dv)).clamp(0.0, 1.0);
            (y, (v0 + alpha * dv).ln())
        })
    }

    #[inline]
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
        with_scratch(self.scratch(), |buf| self.inverse_in(p, y, buf))
    }

    fn bin_edges(&self, p: &[f32]) -> Vec<f64> {
        with_scratch(self.scratch(), |buf| {
            let (kn, _) = self.knots(p, buf);
            edges_from_widths(kn.w)
        })
    }

    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64 {
        with_scratch(self.scratch(), |buf| {
            self.backward_in(p, x, g_y, g_log_det, g_p, buf)
        })
    }
}

impl Quadratic {
    #[inline]
    fn backward_in(
        &self,
        p: &[f32],
        x: f64,
        g_y: f64,
        g_log_det: f64,
        g_p: &mut [f32],
        buf: &mut [f64],
    ) -> f64 {
        let k = self.bins;
        let (kn, rest) = self.knots(p, buf);
        let (g_w, rest) = rest.split_at_mut(k);
        let g_v = &mut rest[..k + 1];
        g_w.fill(0.0);
        g_v.fill(0.0);
        let (b, edge, _) = self.locate(&kn, x);
        let w = kn.w[b];
        let alpha = ((x - edge) / w).clamp(0.0, 1.0);
        let (v0, v1) = (kn.v[b], kn.v[b + 1]);
        let dv = v1 - v0;
        let q = v0 + alpha * dv;

        // log q with q = V_b(1 − α) + V_{b+1}α.
        let g_q = g_log_det / q;
        // y = Y_b + W_b(αV_b + ½α²ΔV): ∂y/∂α = W_b·q.
        let g_alpha = g_y * w * q + g_q * dv;
        g_v[b] += g_y * w * (alpha - 0.5 * alpha * alpha) + g_q * (1.0 - alpha);
        g_v[b + 1] += g_y * w * 0.5 * alpha * alpha + g_q * alpha;
        g_w[b] += g_y * alpha * (v0 + 0.5 * alpha * dv);
        // α = (x − X_b)/W_b.
        let g_x = g_alpha / w;
        let g_edge = -g_alpha / w;
        g_w[b] -= g_alpha * alpha / w;
        // Y_b = Σ_{i<b} ½(V_i + V_{i+1})W_i and X_b = Σ_{i<b} W_i.
        for i in 0..b {
            g_v[i] += 0.5 * g_y * kn.w[i];
            g_v[i + 1] += 0.5 * g_y * kn.w[i];
            g_w[i] += g_y * 0.5 * (kn.v[i] + kn.v[i + 1]) + g_edge;
        }
        // V_j = m + (1 − m)·E_j/N with N = Σ ½(E_i + E_{i+1})W_i.
        let scale = (1.0 - MIN_DENSITY) / kn.norm;
        let s: f64 = (0..=k).map(|j| g_v[j] * kn.e[j]).sum::<f64>() * scale / kn.norm;
        for i in 0..k {
            g_w[i] -= s * 0.5 * (kn.e[i] + kn.e[i + 1]);
        }
        for j in 0..=k {
            let dn =
                0.5 * (if j > 0 { kn.w[j - 1] } else { 0.0 } + if j < k { kn.w[j] } else { 0.0 });
            g_p[k + j] = ((g_v[j] * scale - s * dn) * kn.e[j]) as f32;
        }
        softmax_floor_backward(kn.w, g_w, MIN_BIN_WIDTH, &mut g_p[..k]);
        g_x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::testing;

    #[test]
    fn quadratic_round_trips_and_gradients() {
        for bins in [1, 2, 5, 32] {
            testing::check_transform(&Quadratic { bins }, true);
        }
    }

    #[test]
    fn quadratic_density_integrates_to_one() {
        let t = Quadratic { bins: 7 };
        let p = testing::random_params(t.param_count(), 3.0, 11);
        let n = 20000;
        let sum: f64 = (0..n)
            .map(|i| t.forward(&p, (i as f64 + 0.5) / n as f64).1.exp())
            .sum();
        assert!((sum / n as f64 - 1.0).abs() < 1e-6);
    }
}
