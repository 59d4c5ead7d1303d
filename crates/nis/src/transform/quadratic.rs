//! Piecewise-quadratic coupling transform: a piecewise-linear density on K adaptive bins
//! (Müller et al. 2019, Sec. 2.2; details in Müller et al. 2018, "Neural Importance Sampling").
//!
//! The network predicts K width logits Ŵ and K+1 vertex logits V̂. Widths are W = softmax(Ŵ);
//! vertex heights are V_j = exp(V̂_j) / Σ_k ½(exp V̂_k + exp V̂_{k+1})·W_k, the normalisation that
//! makes the trapezoids' total area one. Inside bin b at relative position α the density is
//! V_b + α(V_{b+1} − V_b) and the CDF a quadratic in α. Unlike bin widths of the piecewise-linear
//! transform, these widths get correct gradients because the density is continuous.

use super::{softmax_floor, softmax_floor_backward, with_scratch_of, Real, Transform};
use lanes::{backward_lanes, run_lanes};

mod lanes;

/// Smallest bin width as a fraction of the mean width 1/K: no bin collapses to zero.
pub const MIN_BIN_WIDTH: f64 = 1e-3;
/// Smallest vertex height (density), mixed in as `V = m + (1 − m)·Ṽ` so that the area stays one.
/// It keeps log-densities finite; see [`super::linear::MIN_BIN_MASS`] for why it is small.
pub const MIN_DENSITY: f64 = 1e-3;

/// The floors in the transform's working precision.
const MIN_W: f32 = MIN_BIN_WIDTH as f32;
const MIN_V: f32 = MIN_DENSITY as f32;

/// Piecewise-quadratic transform with `bins` adaptive bins; `2·bins + 1` parameters per dimension.
///
/// Unlike the other transforms it computes in f32 (x and y enter and leave as f64 holding f32
/// values; only ln C' is taken in f64): its knots, bin search and evaluation are the integrator's
/// and the path guide's hottest code, and f32 runs twice the lanes per instruction
/// (docs/results/integration.md, "Flow throughput against bare gemm and PyTorch", the row "f32
/// splines"). The price: a round trip loses a few f32 ulps of y rather than half of one, and the spline the parameters denote moves by the f32 rounding of its knots
/// (a few 1e-6 of y). Sampling and density stay consistent with each other, which is what keeps
/// an importance-sampling estimate unbiased. The tests check the f64 twin of the same code by
/// finite differences and the f32 transform against it, with bounds derived from the rounding.
#[derive(Clone, Copy, Debug)]
pub struct Quadratic {
    pub bins: usize,
}

/// Normalised widths W, vertex heights V and the pieces needed to differentiate them.
struct Knots<'a, R> {
    w: &'a mut [R],
    v: &'a mut [R],
    /// exp(V̂ − max V̂) and the normaliser N = Σ ½(E_k + E_{k+1}) W_k.
    e: &'a mut [R],
    norm: R,
    /// The totals Σ W_k and Σ ½(V_k + V_{k+1})W_k as computed: one in exact arithmetic, off by
    /// the sums' rounding here. x and y are scaled by them, so that the spline as computed maps
    /// [0, 1] onto [0, 1] and its density integrates to one (see [`Quadratic::forward_in`]).
    x_tot: R,
    y_tot: R,
}

/// The per-scalar spline in precision `R`: f32 for the [`Transform`] methods, f64 for the tests'
/// reference.
impl Quadratic {
    /// Scratch values one call needs: the knots and the backward pass's gradient buffers.
    fn scratch(&self) -> usize {
        5 * self.bins + 3
    }

    /// Computes the knots into the front of `buf`; returns them and the rest of `buf`.
    #[inline]
    fn knots<'a, R: Real>(&self, p: &[f32], buf: &'a mut [R]) -> (Knots<'a, R>, &'a mut [R]) {
        let k = self.bins;
        let (w, rest) = buf.split_at_mut(k);
        let (v, rest) = rest.split_at_mut(k + 1);
        let (e, rest) = rest.split_at_mut(k + 1);
        softmax_floor(&p[..k], R::of(MIN_BIN_WIDTH), w);
        R::exponentials(&p[k..2 * k + 1], e);
        let half = R::of(0.5);
        let norm = (0..k).fold(R::of(-0.0), |n, i| n + half * (e[i] + e[i + 1]) * w[i]);
        let m = R::of(MIN_DENSITY);
        let scale = (R::of(1.0) - m) / norm;
        for j in 0..=k {
            v[j] = m + scale * e[j];
        }
        let (mut x_tot, mut y_tot) = (R::of(0.0), R::of(0.0));
        for i in 0..k {
            x_tot += w[i];
            y_tot += half * (v[i] + v[i + 1]) * w[i];
        }
        let kn = Knots {
            w,
            v,
            e,
            norm,
            x_tot,
            y_tot,
        };
        (kn, rest)
    }

    /// The bin of `t` (a point in x, or in y when `in_y`): (b, left edge X_b, CDF Y_b there),
    /// from the running sums X_j = Σ_{i<j} W_i and Y_j = Σ_{i<j} ½(V_i + V_{i+1})W_i in the
    /// lanes' order, as the last j whose X_j (Y_j) the point reaches. The last bin takes whatever
    /// rounding leaves.
    #[inline]
    fn locate<R: Real>(&self, kn: &Knots<R>, t: R, in_y: bool) -> (usize, R, R) {
        let zero = R::of(0.0);
        let (mut b, mut edge, mut cdf) = (0, zero, zero);
        let (mut x_run, mut y_run) = (zero, zero);
        for j in 1..self.bins {
            y_run += R::of(0.5) * (kn.v[j - 1] + kn.v[j]) * kn.w[j - 1];
            x_run += kn.w[j - 1];
            let below = t < y_run;
            let reached = if in_y { !below } else { t >= x_run };
            if reached {
                (b, edge, cdf) = (j, x_run, y_run);
            }
        }
        (b, edge, cdf)
    }

    /// y = C(x) and C'(x). The knots' widths and masses sum to one only up to rounding (in f32,
    /// by up to ~K ulps, which is a sizeable part of a narrow last bin): x is scaled onto
    /// [0, Σ W] and y from [0, Σ mass] (and the density by their ratio), so that C(1) = 1 and the
    /// density integrates to one as computed. In exact arithmetic both totals are one.
    #[inline]
    fn forward_in<R: Real>(&self, p: &[f32], x: R, buf: &mut [R]) -> (R, R) {
        let (kn, _) = self.knots(p, buf);
        let xs = x * kn.x_tot;
        let (b, edge, cdf) = self.locate(&kn, xs, false);
        let w = kn.w[b];
        let alpha = ((xs - edge) / w).clamp01();
        let (v0, dv) = (kn.v[b], kn.v[b + 1] - kn.v[b]);
        let y = ((cdf + w * alpha * (v0 + R::of(0.5) * alpha * dv)) / kn.y_tot).clamp01();
        (y, (v0 + alpha * dv) * (kn.x_tot / kn.y_tot))
    }

    /// x = C⁻¹(y) and C'(x).
    #[inline]
    fn inverse_in<R: Real>(&self, p: &[f32], y: R, buf: &mut [R]) -> (R, R) {
        let (kn, _) = self.knots(p, buf);
        let ys = y * kn.y_tot;
        let (b, edge, cdf) = self.locate(&kn, ys, true);
        let w = kn.w[b];
        let (v0, dv) = (kn.v[b], kn.v[b + 1] - kn.v[b]);
        // Solve a·α² + bq·α − c = 0 with a = ½·ΔV·W, bq = V_b·W, c = y − Y_b ≥ 0. The textbook root
        // (−bq + √(bq² + 4ac))/(2a) cancels catastrophically when a → 0; the equivalent
        // 2c/(bq + √(bq² + 4ac)) never does, since bq > 0.
        let zero = R::of(0.0);
        let a = R::of(0.5) * dv * w;
        let bq = v0 * w;
        let c = (ys - cdf).max(zero);
        let disc = (bq * bq + R::of(4.0) * a * c).max(zero);
        let alpha = (R::of(2.0) * c / (bq + disc.sqrt())).clamp01();
        let x = ((edge + alpha * w) / kn.x_tot).clamp01();
        (x, (v0 + alpha * dv) * (kn.x_tot / kn.y_tot))
    }

    /// The bin edges as the bin search sums them (the last exactly 1).
    fn bin_edges_in<R: Real>(&self, p: &[f32], buf: &mut [R]) -> Vec<f64> {
        let (kn, _) = self.knots(p, buf);
        let mut edges = vec![0.0];
        let mut x = R::of(0.0);
        for &w in &kn.w[..self.bins - 1] {
            x += w;
            edges.push(x.widen());
        }
        edges.push(1.0);
        edges
    }

    /// Reverse mode at x: writes ∂L/∂p into `g_p` and returns ∂L/∂x, for L with ∂L/∂y = `g_y`
    /// and ∂L/∂ln C' = `g_log_det`.
    #[inline]
    fn backward_in<R: Real>(
        &self,
        p: &[f32],
        x: R,
        g_y: R,
        g_log_det: R,
        g_p: &mut [f32],
        buf: &mut [R],
    ) -> R {
        let k = self.bins;
        let (zero, half, one) = (R::of(0.0), R::of(0.5), R::of(1.0));
        let (kn, rest) = self.knots(p, buf);
        let (g_w, rest) = rest.split_at_mut(k);
        let g_v = &mut rest[..k + 1];
        g_w.fill(zero);
        g_v.fill(zero);
        // At the point the forward pass evaluated; the totals' gradients are zero (both are one).
        let xs = x * kn.x_tot;
        let (b, edge, _) = self.locate(&kn, xs, false);
        let w = kn.w[b];
        let alpha = ((xs - edge) / w).clamp01();
        let (v0, v1) = (kn.v[b], kn.v[b + 1]);
        let dv = v1 - v0;
        let q = v0 + alpha * dv;

        // log q with q = V_b(1 − α) + V_{b+1}α.
        let g_q = g_log_det / q;
        // y = Y_b + W_b(αV_b + ½α²ΔV): ∂y/∂α = W_b·q.
        let g_alpha = g_y * w * q + g_q * dv;
        g_v[b] += g_y * w * (alpha - half * alpha * alpha) + g_q * (one - alpha);
        g_v[b + 1] += g_y * w * half * alpha * alpha + g_q * alpha;
        g_w[b] += g_y * alpha * (v0 + half * alpha * dv);
        // α = (x − X_b)/W_b.
        let g_x = g_alpha / w;
        let g_edge = -g_alpha / w;
        g_w[b] -= g_alpha * alpha / w;
        // Y_b = Σ_{i<b} ½(V_i + V_{i+1})W_i and X_b = Σ_{i<b} W_i.
        for i in 0..b {
            let t = half * g_y * kn.w[i];
            g_v[i] += t;
            g_v[i + 1] += t;
            g_w[i] += g_y * half * (kn.v[i] + kn.v[i + 1]) + g_edge;
        }
        // V_j = m + (1 − m)·E_j/N with N = Σ ½(E_i + E_{i+1})W_i.
        let scale = (one - R::of(MIN_DENSITY)) / kn.norm;
        let s = (0..=k).fold(R::of(-0.0), |s, j| s + g_v[j] * kn.e[j]) * scale / kn.norm;
        for i in 0..k {
            g_w[i] -= s * half * (kn.e[i] + kn.e[i + 1]);
        }
        for j in 0..=k {
            let left = if j > 0 { kn.w[j - 1] } else { zero };
            let right = if j < k { kn.w[j] } else { zero };
            let dn = half * (left + right);
            g_p[k + j] = ((g_v[j] * scale - s * dn) * kn.e[j]).widen() as f32;
        }
        softmax_floor_backward(kn.w, g_w, R::of(MIN_BIN_WIDTH), &mut g_p[..k]);
        g_x
    }
}

impl Transform for Quadratic {
    fn param_count(&self) -> usize {
        2 * self.bins + 1
    }

    #[inline]
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        let (y, q) = with_scratch_of(self.scratch(), |buf| self.forward_in(p, x as f32, buf));
        (y as f64, (q as f64).ln())
    }

    #[inline]
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
        let (x, q) = with_scratch_of(self.scratch(), |buf| self.inverse_in(p, y as f32, buf));
        (x as f64, (q as f64).ln())
    }

    fn bin_edges(&self, p: &[f32]) -> Vec<f64> {
        with_scratch_of(self.scratch(), |buf| self.bin_edges_in::<f32>(p, buf))
    }

    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64 {
        with_scratch_of(self.scratch(), |buf| {
            let g_x = self.backward_in(p, x as f32, g_y as f32, g_log_det as f32, g_p, buf);
            g_x as f64
        })
    }

    fn forward_batch(&self, p: &[f32], x: &mut [f64], log_det: &mut [f64]) {
        run_lanes(self.bins, p, x, log_det, false);
    }

    fn inverse_batch(&self, p: &[f32], y: &mut [f64], log_det: &mut [f64]) {
        run_lanes(self.bins, p, y, log_det, true);
    }

    fn backward_batch(
        &self,
        p: &[f32],
        x: &[f64],
        g: &mut [f64],
        g_log_det: &[f64],
        g_p: &mut [f32],
    ) {
        backward_lanes(self.bins, p, x, g, g_log_det, g_p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::testing;

    /// The same spline computed in f64 (from the same f32 exponentials, widened, as the other
    /// f64 splines take them): the reference the f32 transform is checked against, itself
    /// checked by finite differences.
    struct Reference {
        bins: usize,
    }

    impl Reference {
        fn run<T>(&self, op: impl FnOnce(&Quadratic, &mut [f64]) -> T) -> T {
            let s = Quadratic { bins: self.bins };
            op(&s, &mut vec![0.0; s.scratch()])
        }
    }

    impl Transform for Reference {
        fn param_count(&self) -> usize {
            2 * self.bins + 1
        }
        fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
            let (y, q) = self.run(|s, buf| s.forward_in(p, x, buf));
            (y, q.ln())
        }
        fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
            let (x, q) = self.run(|s, buf| s.inverse_in(p, y, buf));
            (x, q.ln())
        }
        fn bin_edges(&self, p: &[f32]) -> Vec<f64> {
            self.run(|s, buf| s.bin_edges_in(p, buf))
        }
        fn backward(&self, p: &[f32], x: f64, g_y: f64, g_ld: f64, g_p: &mut [f32]) -> f64 {
            self.run(|s, buf| s.backward_in(p, x, g_y, g_ld, g_p, buf))
        }
    }

    #[test]
    fn quadratic_batched_equals_per_scalar() {
        for bins in [1, 2, 5, 16, 32] {
            testing::check_batch(&Quadratic { bins });
        }
    }

    #[test]
    fn quadratic_round_trips_and_gradients() {
        for bins in [1, 2, 5, 32] {
            testing::check_transform(&Reference { bins }, true);
            testing::check_transform_at(&Quadratic { bins }, true, (f32::EPSILON / 2.0) as f64);
        }
    }

    /// The f32 transform against the f64 reference at points away from the bin edges, on
    /// parameters of the scales a trained conditioner puts out. The two denote slightly different
    /// splines. The two share their exponentials, so the f32 roundings of the K-term sums and of
    /// what follows, ≤ (2K + 10)·u, separate them; δ also allows 6ε, the reach of the f32 exp's
    /// relative error ε < 4e-7 into a bin's mass ½(V_b + V_{b+1})W_b (2ε through the widths'
    /// softmax, 3ε through the normaliser N, ε its own), so the same bound holds against an f64
    /// spline with exact exponentials. So y, a sum of bin masses ≤ 1, moves by at most
    /// δ = 6ε + (2K + 10)·u; the density at a point ≥ 1e-3 from the
    /// nearest edge by its knots' relative error δ plus its slope times the edges' shift (≤ δ);
    /// each gradient entry by a like relative amount of the largest.
    #[test]
    fn the_f32_spline_agrees_with_the_f64_reference() {
        let u = (f32::EPSILON / 2.0) as f64;
        for bins in [1, 2, 5, 16, 32] {
            let (t, r) = (Quadratic { bins }, Reference { bins });
            let delta = 6.0 * 4e-7 + (2.0 * bins as f64 + 10.0) * u;
            for (set, scale) in [0.5f32, 2.0, 5.0].into_iter().enumerate() {
                let p = testing::random_params(t.param_count(), scale, 300 + set as u64);
                let edges = r.bin_edges(&p);
                let knots = r.run(|s, buf| {
                    let (kn, _) = s.knots(&p, buf);
                    (kn.w.to_vec(), kn.v.to_vec())
                });
                for i in 0..400 {
                    let x = ((i as f64 + 0.5) / 400.0) as f32 as f64;
                    let b = edges[1..].iter().position(|&e| x < e).unwrap_or(bins - 1);
                    let d = (x - edges[b]).min(edges[b + 1] - x);
                    if d < 1e-3 {
                        continue;
                    }
                    let (w, v0, v1) = (knots.0[b], knots.1[b], knots.1[b + 1]);
                    let ((y, ld), (y_ref, ld_ref)) = (t.forward(&p, x), r.forward(&p, x));
                    assert!(
                        (y - y_ref).abs() <= delta,
                        "bins {bins}, set {set}: y {y} vs {y_ref}"
                    );
                    let (q, q_ref) = (ld.exp(), ld_ref.exp());
                    let q_tol = delta * (v0.max(v1) + (v1 - v0).abs() / w) + 4.0 * u * q_ref;
                    assert!(
                        (q - q_ref).abs() <= q_tol,
                        "bins {bins}, set {set}: C'({x}) = {q} vs {q_ref}"
                    );
                    // The inverse at the reference's y lands where the reference's inverse does,
                    // within the y error over the density.
                    let (x_back, x_ref) = (t.inverse(&p, y_ref).0, r.inverse(&p, y_ref).0);
                    assert!(
                        (x_back - x_ref).abs()
                            <= (delta + f32_half_ulp(y_ref)) / q_ref.min(q) * 2.0,
                        "bins {bins}, set {set}: inverse {x_back} vs {x_ref}"
                    );
                    let (g_y, g_ld) = (0.3, -0.7);
                    let mut g = vec![0.0f32; t.param_count()];
                    let mut g_ref = vec![0.0f32; t.param_count()];
                    let g_x = t.backward(&p, x, g_y, g_ld, &mut g);
                    let g_x_ref = r.backward(&p, x, g_y, g_ld, &mut g_ref);
                    let big = g_ref
                        .iter()
                        .fold(g_x_ref.abs(), |m, g| m.max(g.abs() as f64));
                    // The gradient divides by W and V (1/W ≤ K/1e-3 for the narrowest bin, V of
                    // the bin): relative knot errors δ grow by at most that ratio.
                    let g_tol = 4.0 * delta * (1.0 + (v1 - v0).abs() / (w * q_ref)) * big;
                    assert!(
                        (g_x - g_x_ref).abs() <= g_tol,
                        "bins {bins}, set {set}: dL/dx {g_x} vs {g_x_ref}"
                    );
                    for (j, (a, b)) in g.iter().zip(&g_ref).enumerate() {
                        assert!(
                            (a - b).abs() as f64 <= g_tol,
                            "bins {bins}, set {set}: dL/dp[{j}] {a} vs {b} at {x}"
                        );
                    }
                }
            }
        }
    }

    /// Half the spacing of f32 values around y.
    fn f32_half_ulp(y: f64) -> f64 {
        let y = y as f32;
        0.5 * (f32::from_bits(y.to_bits() + 1) - y) as f64
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
