//! Piecewise-quadratic coupling transform: a piecewise-linear density on K adaptive bins
//! (Müller et al. 2019, Sec. 2.2; details in Müller et al. 2018, "Neural Importance Sampling").
//!
//! The network predicts K width logits Ŵ and K+1 vertex logits V̂. Widths are W = softmax(Ŵ);
//! vertex heights are V_j = exp(V̂_j) / Σ_k ½(exp V̂_k + exp V̂_{k+1})·W_k, the normalisation that
//! makes the trapezoids' total area one. Inside bin b at relative position α the density is
//! V_b + α(V_{b+1} − V_b) and the CDF a quadratic in α. Unlike bin widths of the piecewise-linear
//! transform, these widths get correct gradients because the density is continuous.

use multiversion::multiversion;

use super::batch::{self, splat, Lane, LANES};
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

    fn forward_batch(&self, p: &[f32], stride: usize, x: &mut [f64], log_det: &mut [f64]) {
        run_lanes(self.bins, p, stride, x, log_det, false);
    }

    fn inverse_batch(&self, p: &[f32], stride: usize, y: &mut [f64], log_det: &mut [f64]) {
        run_lanes(self.bins, p, stride, y, log_det, true);
    }

    fn backward_batch(
        &self,
        p: &[f32],
        stride: usize,
        x: &[f64],
        g: &mut [f64],
        g_log_det: &[f64],
        g_p: &mut [f32],
    ) {
        backward_lanes(self.bins, p, stride, x, g, g_log_det, g_p);
    }
}

/// The knots of a group of scalars ([`Quadratic::knots`] per lane) and their work buffers.
struct LaneKnots {
    /// The group's parameters, transposed: `p[j][lane]`.
    p: Vec<[f32; LANES]>,
    w: Vec<Lane>,
    v: Vec<Lane>,
    e: Vec<Lane>,
    norm: Lane,
    /// The left edge X_b and the CDF there, per bin (X_0 = Y_0 = 0).
    x_at: Vec<Lane>,
    y_at: Vec<Lane>,
}

impl LaneKnots {
    fn new(k: usize) -> LaneKnots {
        LaneKnots {
            p: vec![[0.0; LANES]; 2 * k + 1],
            w: vec![splat(0.0); k],
            v: vec![splat(0.0); k + 1],
            e: vec![splat(0.0); k + 1],
            norm: splat(0.0),
            x_at: vec![splat(0.0); k],
            y_at: vec![splat(0.0); k],
        }
    }

    /// Loads scalars `first..first + LANES` of `n` and normalises their knots.
    #[inline(always)]
    fn compute(&mut self, p: &[f32], stride: usize, first: usize, n: usize) {
        let k = self.w.len();
        batch::gather(p, stride, first, n, 0, &mut self.p);
        batch::softmax_floor(&self.p[..k], MIN_BIN_WIDTH, &mut self.w);
        batch::exponentials(&self.p[k..], &mut self.e);
        let mut norm = splat(-0.0);
        for i in 0..k {
            for l in 0..LANES {
                norm[l] += 0.5 * (self.e[i][l] + self.e[i + 1][l]) * self.w[i][l];
            }
        }
        for j in 0..=k {
            for l in 0..LANES {
                let scale = (1.0 - MIN_DENSITY) / norm[l];
                self.v[j][l] = MIN_DENSITY + scale * self.e[j][l];
            }
        }
        self.norm = norm;
    }

    /// Each lane's bin (as [`Quadratic::locate`] for x, or the inverse's search for y): the last
    /// bin whose left edge (in x) or left CDF value (in y) the point reaches. Edges and CDF values
    /// rise with the bin, so that is the count of edges reached: counted without a branch, then
    /// the bin's quantities are gathered lane by lane.
    #[inline(always)]
    fn locate(&mut self, t: &Lane, in_y: bool) -> Located {
        let k = self.w.len();
        let (w, v) = (&self.w, &self.v);
        let (x_at, y_at) = (&mut self.x_at, &mut self.y_at);
        let mut count = splat(0.0);
        // A block of lanes at a time, its running sums and counts in registers across the bins
        // (bin-major over all 64 lanes, every sum went through memory and back).
        const BLOCK: usize = 8;
        const _: () = assert!(LANES % BLOCK == 0);
        for l0 in (0..LANES).step_by(BLOCK) {
            let (mut y, mut x, mut c) = ([0.0f64; BLOCK], [0.0f64; BLOCK], [0.0f64; BLOCK]);
            for j in 1..k {
                let (w0, v0, v1) = (&w[j - 1], &v[j - 1], &v[j]);
                for l in 0..BLOCK {
                    let at = l0 + l;
                    // The scalar searches' running sums and conditions, literally (the
                    // conditions differ for NaN only).
                    y[l] += 0.5 * (v0[at] + v1[at]) * w0[at];
                    x[l] += w0[at];
                    let below = t[at] < y[l];
                    let reached = if in_y { !below } else { t[at] >= x[l] };
                    c[l] += if reached { 1.0 } else { 0.0 };
                }
                y_at[j][l0..l0 + BLOCK].copy_from_slice(&y);
                x_at[j][l0..l0 + BLOCK].copy_from_slice(&x);
            }
            count[l0..l0 + BLOCK].copy_from_slice(&c);
        }
        let mut at = Located {
            b: count,
            edge: splat(0.0),
            cdf: splat(0.0),
            w: splat(0.0),
            v0: splat(0.0),
            v1: splat(0.0),
        };
        for l in 0..LANES {
            let b = count[l] as usize;
            at.edge[l] = x_at[b][l];
            at.cdf[l] = y_at[b][l];
            at.w[l] = w[b][l];
            at.v0[l] = v[b][l];
            at.v1[l] = v[b + 1][l];
        }
        at
    }
}

/// A lane's bin b (as a float), its left edge X_b, the CDF there, its width and vertex heights.
struct Located {
    b: Lane,
    edge: Lane,
    cdf: Lane,
    w: Lane,
    v0: Lane,
    v1: Lane,
}

/// The batched forward (`inverse` false) or inverse of [`Quadratic`], [`LANES`] scalars at a time.
#[multiversion(targets = "simd")]
fn run_lanes(
    k: usize,
    p: &[f32],
    stride: usize,
    t: &mut [f64],
    log_det: &mut [f64],
    inverse: bool,
) {
    let n = t.len();
    if n == 0 {
        return;
    }
    with_lane_scratch(k, |scratch| {
        let kn = &mut scratch.knots;
        for first in (0..n).step_by(LANES) {
            kn.compute(p, stride, first, n);
            let tin = batch::load(t, first);
            let at = kn.locate(&tin, inverse);
            let (mut out, mut q) = (splat(0.0), splat(0.0));
            if inverse {
                for l in 0..LANES {
                    let (w, v0) = (at.w[l], at.v0[l]);
                    let dv = at.v1[l] - v0;
                    // As Quadratic::inverse_in: the cancellation-free root of the bin's quadratic.
                    let a = 0.5 * dv * w;
                    let bq = v0 * w;
                    let c = (tin[l] - at.cdf[l]).max(0.0);
                    let disc = (bq * bq + 4.0 * a * c).max(0.0);
                    let alpha = (2.0 * c / (bq + disc.sqrt())).clamp(0.0, 1.0);
                    out[l] = (at.edge[l] + alpha * w).clamp(0.0, 1.0);
                    q[l] = v0 + alpha * dv;
                }
            } else {
                for l in 0..LANES {
                    let (w, v0) = (at.w[l], at.v0[l]);
                    let dv = at.v1[l] - v0;
                    let alpha = ((tin[l] - at.edge[l]) / w).clamp(0.0, 1.0);
                    out[l] = (at.cdf[l] + w * alpha * (v0 + 0.5 * alpha * dv)).clamp(0.0, 1.0);
                    q[l] = v0 + alpha * dv;
                }
            }
            let lanes = LANES.min(n - first);
            t[first..first + lanes].copy_from_slice(&out[..lanes]);
            for (ld, q) in log_det[first..first + lanes].iter_mut().zip(&q) {
                *ld += q.ln();
            }
        }
    });
}

/// The batched [`Quadratic::backward`], [`LANES`] scalars at a time.
#[multiversion(targets = "simd")]
fn backward_lanes(
    k: usize,
    p: &[f32],
    stride: usize,
    x: &[f64],
    g: &mut [f64],
    g_log_det: &[f64],
    g_p: &mut [f32],
) {
    let n = x.len();
    if n == 0 {
        return;
    }
    with_lane_scratch(k, |scratch| {
        let LaneScratch {
            knots: kn,
            g_w,
            g_v,
            g_params,
        } = scratch;
        for first in (0..n).step_by(LANES) {
            kn.compute(p, stride, first, n);
            let xl = batch::load(x, first);
            let g_y = batch::load(g, first);
            let g_ld = batch::load(g_log_det, first);
            let at = kn.locate(&xl, false);
            // The bin's own terms, as Quadratic::backward_in writes them.
            let mut own = [[0.0f64; LANES]; 4];
            let (mut g_x, mut g_edge) = (splat(0.0), splat(0.0));
            for l in 0..LANES {
                let (w, v0) = (at.w[l], at.v0[l]);
                let alpha = ((xl[l] - at.edge[l]) / w).clamp(0.0, 1.0);
                let dv = at.v1[l] - v0;
                let q = v0 + alpha * dv;
                let g_q = g_ld[l] / q;
                let g_alpha = g_y[l] * w * q + g_q * dv;
                own[0][l] = g_y[l] * w * (alpha - 0.5 * alpha * alpha) + g_q * (1.0 - alpha);
                own[1][l] = g_y[l] * w * 0.5 * alpha * alpha + g_q * alpha;
                own[2][l] = g_y[l] * alpha * (v0 + 0.5 * alpha * dv);
                own[3][l] = g_alpha * alpha / w;
                g_x[l] = g_alpha / w;
                g_edge[l] = -g_alpha / w;
            }
            // Into the lanes' own bins (b and b + 1 for the vertex heights), zero elsewhere.
            for row in g_w.iter_mut().chain(g_v.iter_mut()) {
                *row = splat(0.0);
            }
            for l in 0..LANES {
                let b = at.b[l] as usize;
                g_v[b][l] = 0.0 + own[0][l];
                g_v[b + 1][l] = 0.0 + own[1][l];
                g_w[b][l] = 0.0 + own[2][l] - own[3][l];
            }
            // Y_b = Σ_{i<b} ½(V_i + V_{i+1})W_i and X_b = Σ_{i<b} W_i.
            // Rows taken before the lane loops, so that no index is checked inside them, and
            // additions of a selected term (0 above the lane's bin) rather than selected stores, so
            // that the loops vectorise without masked memory access. The sums start from +0 and never
            // become −0, so adding +0 leaves them bit for bit as the scalar code's skipped additions.
            for i in 0..k {
                let (lower, upper) = g_v.split_at_mut(i + 1);
                let (gv0, gv1, gw) = (&mut lower[i], &mut upper[0], &mut g_w[i]);
                let (w, v0, v1) = (&kn.w[i], &kn.v[i], &kn.v[i + 1]);
                for l in 0..LANES {
                    let below = (i as f64) < at.b[l];
                    let t = 0.5 * g_y[l] * w[l];
                    let g_wi = g_y[l] * 0.5 * (v0[l] + v1[l]) + g_edge[l];
                    let (t, g_wi) = if below { (t, g_wi) } else { (0.0, 0.0) };
                    gv0[l] += t;
                    gv1[l] += t;
                    gw[l] += g_wi;
                }
            }
            // V_j = m + (1 − m)·E_j/N with N = Σ ½(E_i + E_{i+1})W_i.
            let mut s = splat(-0.0);
            for j in 0..=k {
                for l in 0..LANES {
                    s[l] += g_v[j][l] * kn.e[j][l];
                }
            }
            let mut scale = splat(0.0);
            for l in 0..LANES {
                scale[l] = (1.0 - MIN_DENSITY) / kn.norm[l];
                s[l] = s[l] * scale[l] / kn.norm[l];
            }
            for i in 0..k {
                let (gw, e0, e1) = (&mut g_w[i], &kn.e[i], &kn.e[i + 1]);
                for l in 0..LANES {
                    gw[l] -= s[l] * 0.5 * (e0[l] + e1[l]);
                }
            }
            let zero = splat(0.0);
            for j in 0..=k {
                let left = if j > 0 { &kn.w[j - 1] } else { &zero };
                let right = if j < k { &kn.w[j] } else { &zero };
                let (gv, e, out) = (&g_v[j], &kn.e[j], &mut g_params[k + j]);
                for l in 0..LANES {
                    let dn = 0.5 * (left[l] + right[l]);
                    out[l] = ((gv[l] * scale[l] - s[l] * dn) * e[l]) as f32;
                }
            }
            batch::softmax_floor_backward(&kn.w, g_w, MIN_BIN_WIDTH, &mut g_params[..k]);
            let lanes = LANES.min(n - first);
            batch::scatter(g_params, stride, first, lanes, 0, g_p);
            g[first..first + lanes].copy_from_slice(&g_x[..lanes]);
        }
    });
}

/// A thread's work buffers for the lane kernels of `k` bins: the knots and the backward pass's
/// per-bin gradients. Every value is written before it is read (`LaneKnots::compute` and the
/// per-group zeroing), except the running sums' zeroth rows, which stay 0.
struct LaneScratch {
    knots: LaneKnots,
    g_w: Vec<Lane>,
    g_v: Vec<Lane>,
    g_params: Vec<[f32; LANES]>,
}

thread_local! {
    static LANE_SCRATCH: std::cell::RefCell<Option<LaneScratch>> = const { std::cell::RefCell::new(None) };
}

/// Runs `op` on this thread's [`LaneScratch`] for `k` bins, made on first use (or when `k` changes)
/// instead of allocated and zeroed on every call: a call sees one chunk of rows, often a single
/// group of lanes, and the buffers are tens of kilobytes.
fn with_lane_scratch<R>(k: usize, op: impl FnOnce(&mut LaneScratch) -> R) -> R {
    LANE_SCRATCH.with(|slot| {
        let mut slot = slot.borrow_mut();
        let scratch = match &mut *slot {
            Some(s) if s.g_w.len() == k => s,
            other => other.insert(LaneScratch {
                knots: LaneKnots::new(k),
                g_w: vec![splat(0.0); k],
                g_v: vec![splat(0.0); k + 1],
                g_params: vec![[0.0f32; LANES]; 2 * k + 1],
            }),
        };
        op(scratch)
    })
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
    fn quadratic_batched_equals_per_scalar() {
        for bins in [1, 2, 5, 16, 32] {
            testing::check_batch(&Quadratic { bins });
        }
    }

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
