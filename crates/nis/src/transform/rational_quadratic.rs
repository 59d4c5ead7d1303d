//! Monotone rational-quadratic spline (Durkan, Bekasov, Murray, Papamakarios 2019, "Neural Spline
//! Flows", Sec. 3.1; the spline of Gregory & Delbourgo 1982), on [0, 1] without tails.
//!
//! K adaptive bins with widths w_k, heights h_k and K+1 knot derivatives d_k. Inside bin k at
//! relative position ξ, with slope s = h/w,
//!   C = y_k + h·(s ξ² + d_k ξ(1−ξ)) / (s + (d_{k+1} + d_k − 2s) ξ(1−ξ)).
//! Unlike the unbounded-domain original (whose boundary derivatives are 1 to meet linear tails),
//! the two boundary derivatives are learned too: on [0, 1] nothing forces the density at the ends.

use super::{edges_from_widths, softmax_floor, softmax_floor_backward, with_scratch, Transform};
use crate::kernels::elementwise;

/// Smallest bin width as a fraction of the mean width.
pub const MIN_BIN_WIDTH: f64 = 1e-3;
/// Smallest bin slope h/w: heights are `h_k = m·w_k + (1 − m)·softmax_k`, which still sum to one.
pub const MIN_SLOPE: f64 = 1e-3;
/// Smallest knot derivative; `d = MIN_DERIVATIVE + softplus(d̂ + DERIVATIVE_SHIFT)` is 1 at d̂ = 0,
/// so zero parameters give the identity.
pub const MIN_DERIVATIVE: f64 = 1e-3;

/// softplus⁻¹(1 − MIN_DERIVATIVE) = ln(e^{1−m} − 1).
fn derivative_shift() -> f64 {
    ((1.0 - MIN_DERIVATIVE).exp() - 1.0).ln()
}

/// Rational-quadratic spline with `bins` bins; `3·bins + 1` parameters per dimension.
#[derive(Clone, Copy, Debug)]
pub struct RationalQuadratic {
    pub bins: usize,
}

struct Knots<'a> {
    w: &'a mut [f64],
    h: &'a mut [f64],
    /// softmax of the height logits, before the slope floor is mixed in.
    h_soft: &'a mut [f64],
    d: &'a mut [f64],
}

/// One bin's local quantities.
struct Bin {
    b: usize,
    x0: f64,
    y0: f64,
}

impl RationalQuadratic {
    /// Scratch values one call needs: the knots and the backward pass's gradient buffers.
    fn scratch(&self) -> usize {
        7 * self.bins + 1
    }

    /// Computes the knots into the front of `buf`; returns them and the rest of `buf`.
    #[inline]
    fn knots<'a>(&self, p: &[f32], buf: &'a mut [f64]) -> (Knots<'a>, &'a mut [f64]) {
        let k = self.bins;
        let (w, rest) = buf.split_at_mut(k);
        let (h, rest) = rest.split_at_mut(k);
        let (h_soft, rest) = rest.split_at_mut(k);
        let (d, rest) = rest.split_at_mut(k + 1);
        softmax_floor(&p[..k], MIN_BIN_WIDTH, w);
        softmax_floor(&p[k..2 * k], 0.0, h_soft);
        for i in 0..k {
            h[i] = MIN_SLOPE * w[i] + (1.0 - MIN_SLOPE) * h_soft[i];
        }
        elementwise::softplus_shifted(&p[2 * k..3 * k + 1], derivative_shift() as f32, d);
        for dj in d.iter_mut() {
            *dj += MIN_DERIVATIVE;
        }
        (Knots { w, h, h_soft, d }, rest)
    }

    #[inline]
    fn locate_x(&self, kn: &Knots, x: f64) -> Bin {
        let (mut b, mut x0, mut y0) = (0, 0.0, 0.0);
        while b + 1 < self.bins && x >= x0 + kn.w[b] {
            x0 += kn.w[b];
            y0 += kn.h[b];
            b += 1;
        }
        Bin { b, x0, y0 }
    }
}

impl Transform for RationalQuadratic {
    fn param_count(&self) -> usize {
        3 * self.bins + 1
    }

    #[inline]
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        with_scratch(self.scratch(), |buf| self.forward_in(p, x, buf))
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

impl RationalQuadratic {
    #[inline]
    fn forward_in(&self, p: &[f32], x: f64, buf: &mut [f64]) -> (f64, f64) {
        let (kn, _) = self.knots(p, buf);
        let Bin { b, x0, y0 } = self.locate_x(&kn, x);
        let (w, h, d0, d1) = (kn.w[b], kn.h[b], kn.d[b], kn.d[b + 1]);
        let s = h / w;
        let xi = ((x - x0) / w).clamp(0.0, 1.0);
        let t = xi * (1.0 - xi);
        let den = s + (d1 + d0 - 2.0 * s) * t;
        let y = (y0 + h * (s * xi * xi + d0 * t) / den).clamp(0.0, 1.0);
        let dnum = d1 * xi * xi + 2.0 * s * t + d0 * (1.0 - xi) * (1.0 - xi);
        (y, 2.0 * s.ln() + dnum.ln() - 2.0 * den.ln())
    }

    #[inline]
    fn inverse_in(&self, p: &[f32], y: f64, buf: &mut [f64]) -> (f64, f64) {
        let k = self.bins;
        let (kn, _) = self.knots(p, buf);
        let (mut b, mut x0, mut y0) = (0, 0.0, 0.0);
        while b + 1 < k && y >= y0 + kn.h[b] {
            x0 += kn.w[b];
            y0 += kn.h[b];
            b += 1;
        }
        let (w, h, d0, d1) = (kn.w[b], kn.h[b], kn.d[b], kn.d[b + 1]);
        let s = h / w;
        let dy = (y - y0).clamp(0.0, h);
        let sum = d1 + d0 - 2.0 * s;
        // Durkan et al. Eq. 6–8: a ξ² + b ξ + c = 0, taking the root that lies in [0, 1] in the
        // cancellation-free form 2c/(−b − √(b² − 4ac)).
        let a = h * (s - d0) + dy * sum;
        let bb = h * d0 - dy * sum;
        let c = -s * dy;
        let disc = (bb * bb - 4.0 * a * c).max(0.0);
        let xi = if c == 0.0 {
            0.0
        } else {
            (2.0 * c / (-bb - disc.sqrt())).clamp(0.0, 1.0)
        };
        let x = (x0 + xi * w).clamp(0.0, 1.0);
        let t = xi * (1.0 - xi);
        let den = s + sum * t;
        let dnum = d1 * xi * xi + 2.0 * s * t + d0 * (1.0 - xi) * (1.0 - xi);
        (x, 2.0 * s.ln() + dnum.ln() - 2.0 * den.ln())
    }

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
        let (g_hh, rest) = rest.split_at_mut(k);
        let g_soft = &mut rest[..k];
        g_w.fill(0.0);
        g_hh.fill(0.0);
        let Bin { b, x0, .. } = self.locate_x(&kn, x);
        let (w, h, d0, d1) = (kn.w[b], kn.h[b], kn.d[b], kn.d[b + 1]);
        let s = h / w;
        let xi = ((x - x0) / w).clamp(0.0, 1.0);
        let t = xi * (1.0 - xi);
        let num = h * (s * xi * xi + d0 * t);
        let den = s + (d1 + d0 - 2.0 * s) * t;
        let dnum = d1 * xi * xi + 2.0 * s * t + d0 * (1.0 - xi) * (1.0 - xi);

        // Reverse sweep over y = y_b + num/den and log_det = 2 ln s + ln dnum − 2 ln den.
        let (mut g_s, mut g_h, mut g_d0, mut g_d1, mut g_xi, mut g_t) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let g_num = g_y / den;
        let mut g_den = -g_y * num / (den * den);
        g_s += 2.0 * g_log_det / s;
        let g_dnum = g_log_det / dnum;
        g_den -= 2.0 * g_log_det / den;
        // num = h(sξ² + d0 t)
        g_h += g_num * (s * xi * xi + d0 * t);
        g_s += g_num * h * xi * xi;
        g_d0 += g_num * h * t;
        g_xi += g_num * h * 2.0 * s * xi;
        g_t += g_num * h * d0;
        // den = s + (d1 + d0 − 2s) t
        g_s += g_den * (1.0 - 2.0 * t);
        g_d0 += g_den * t;
        g_d1 += g_den * t;
        g_t += g_den * (d1 + d0 - 2.0 * s);
        // dnum = d1 ξ² + 2 s t + d0 (1 − ξ)²
        g_d1 += g_dnum * xi * xi;
        g_xi += g_dnum * (2.0 * d1 * xi - 2.0 * d0 * (1.0 - xi));
        g_s += g_dnum * 2.0 * t;
        g_t += g_dnum * 2.0 * s;
        g_d0 += g_dnum * (1.0 - xi) * (1.0 - xi);
        // t = ξ − ξ²
        g_xi += g_t * (1.0 - 2.0 * xi);
        // s = h/w, ξ = (x − x_b)/w
        g_h += g_s / w;
        let g_w_b = -g_s * h / (w * w) - g_xi * xi / w;
        let g_x = g_xi / w;
        let g_x0 = -g_xi / w;

        for i in 0..b {
            g_w[i] += g_x0;
            g_hh[i] += g_y; // y_b = Σ_{i<b} h_i
        }
        g_hh[b] += g_h;
        g_w[b] += g_w_b;
        // h_i = m w_i + (1 − m) softmax_i
        for i in 0..k {
            g_w[i] += MIN_SLOPE * g_hh[i];
            g_soft[i] = (1.0 - MIN_SLOPE) * g_hh[i];
        }
        softmax_floor_backward(kn.w, g_w, MIN_BIN_WIDTH, &mut g_p[..k]);
        softmax_floor_backward(kn.h_soft, g_soft, 0.0, &mut g_p[k..2 * k]);
        // Only the bin's two knot derivatives carry gradient; d = m + softplus(d̂ + shift).
        g_p[2 * k..3 * k + 1].fill(0.0);
        let mut sig = [0.0f64; 2];
        elementwise::sigmoid_shifted(
            &p[2 * k + b..2 * k + b + 2],
            derivative_shift() as f32,
            &mut sig,
        );
        g_p[2 * k + b] = (g_d0 * sig[0]) as f32;
        g_p[2 * k + b + 1] = (g_d1 * sig[1]) as f32;
        g_x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::testing;

    #[test]
    fn rational_quadratic_batched_equals_per_scalar() {
        for bins in [1, 2, 5, 16, 32] {
            testing::check_batch(&RationalQuadratic { bins });
        }
    }

    #[test]
    fn rational_quadratic_round_trips_and_gradients() {
        for bins in [1, 2, 5, 32] {
            testing::check_transform(&RationalQuadratic { bins }, false);
        }
    }
}
