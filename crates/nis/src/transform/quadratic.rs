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
use super::{softmax_floor, softmax_floor_backward, with_scratch_of, Real, Transform};

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
/// (docs/results/integration.md, "f32 splines"). The price: a round trip loses a few f32 ulps of y rather
/// than half of one, and the spline the parameters denote moves by the f32 rounding of its knots
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

/// The knots of a group of scalars ([`Quadratic::knots`] per lane) and their work buffers.
struct LaneKnots {
    /// The group's parameters, transposed: `p[j][lane]`.
    p: Vec<[f32; LANES]>,
    w: Vec<Lane>,
    v: Vec<Lane>,
    e: Vec<Lane>,
    norm: Lane,
    /// [`Knots::x_tot`] and [`Knots::y_tot`] per lane.
    x_tot: Lane,
    y_tot: Lane,
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
            x_tot: splat(0.0),
            y_tot: splat(0.0),
            x_at: vec![splat(0.0); k],
            y_at: vec![splat(0.0); k],
        }
    }

    /// Loads scalars `first..first + LANES` of `n` and normalises their knots.
    #[inline(always)]
    fn compute(&mut self, p: &[f32], first: usize, n: usize) {
        let k = self.w.len();
        batch::gather(p, first, n, 0, &mut self.p);
        batch::softmax_floor(&self.p[..k], MIN_W, &mut self.w);
        batch::exponentials(&self.p[k..], &mut self.e);
        let mut norm = splat(-0.0);
        for i in 0..k {
            for l in 0..LANES {
                norm[l] += 0.5 * (self.e[i][l] + self.e[i + 1][l]) * self.w[i][l];
            }
        }
        let mut scale = splat(0.0);
        for l in 0..LANES {
            scale[l] = (1.0 - MIN_V) / norm[l];
        }
        for j in 0..=k {
            for l in 0..LANES {
                self.v[j][l] = MIN_V + scale[l] * self.e[j][l];
            }
        }
        self.norm = norm;
        let (mut x_tot, mut y_tot) = (splat(0.0), splat(0.0));
        for i in 0..k {
            for l in 0..LANES {
                x_tot[l] += self.w[i][l];
                y_tot[l] += 0.5 * (self.v[i][l] + self.v[i + 1][l]) * self.w[i][l];
            }
        }
        self.x_tot = x_tot;
        self.y_tot = y_tot;
    }

    /// Each lane's bin (as [`Quadratic::locate`]): the last
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
            let (mut y, mut x, mut c) = ([0.0f32; BLOCK], [0.0f32; BLOCK], [0.0f32; BLOCK]);
            for j in 1..k {
                let (w0, v0, v1) = (&w[j - 1], &v[j - 1], &v[j]);
                for l in 0..BLOCK {
                    let at = l0 + l;
                    // Quadratic::locate's running sums and conditions, literally.
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
fn run_lanes(k: usize, p: &[f32], t: &mut [f64], log_det: &mut [f64], inverse: bool) {
    let n = t.len();
    if n == 0 {
        return;
    }
    with_lane_scratch(k, |scratch| {
        let kn = &mut scratch.knots;
        for first in (0..n).step_by(LANES) {
            kn.compute(p, first, n);
            // Scaled as in Quadratic::forward_in and Quadratic::inverse_in.
            let mut ts = batch::load(t, first);
            let total = if inverse { &kn.y_tot } else { &kn.x_tot };
            for l in 0..LANES {
                ts[l] *= total[l];
            }
            let at = kn.locate(&ts, inverse);
            let (x_tot, y_tot) = (&kn.x_tot, &kn.y_tot);
            let (mut out, mut q) = (splat(0.0), splat(0.0));
            if inverse {
                for l in 0..LANES {
                    let (w, v0) = (at.w[l], at.v0[l]);
                    let dv = at.v1[l] - v0;
                    // As Quadratic::inverse_in: the cancellation-free root of the bin's quadratic.
                    let a = 0.5 * dv * w;
                    let bq = v0 * w;
                    let c = (ts[l] - at.cdf[l]).max(0.0);
                    let disc = (bq * bq + 4.0 * a * c).max(0.0);
                    let alpha = (2.0 * c / (bq + disc.sqrt())).clamp(0.0, 1.0);
                    out[l] = ((at.edge[l] + alpha * w) / x_tot[l]).clamp(0.0, 1.0);
                    q[l] = (v0 + alpha * dv) * (x_tot[l] / y_tot[l]);
                }
            } else {
                for l in 0..LANES {
                    let (w, v0) = (at.w[l], at.v0[l]);
                    let dv = at.v1[l] - v0;
                    let alpha = ((ts[l] - at.edge[l]) / w).clamp(0.0, 1.0);
                    let y = at.cdf[l] + w * alpha * (v0 + 0.5 * alpha * dv);
                    out[l] = (y / y_tot[l]).clamp(0.0, 1.0);
                    q[l] = (v0 + alpha * dv) * (x_tot[l] / y_tot[l]);
                }
            }
            let lanes = LANES.min(n - first);
            for (t, o) in t[first..first + lanes].iter_mut().zip(&out) {
                *t = *o as f64;
            }
            for (ld, q) in log_det[first..first + lanes].iter_mut().zip(&q) {
                *ld += (*q as f64).ln();
            }
        }
    });
}

/// The batched [`Quadratic::backward_in`], [`LANES`] scalars at a time.
#[multiversion(targets = "simd")]
fn backward_lanes(
    k: usize,
    p: &[f32],
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
            kn.compute(p, first, n);
            let mut xl = batch::load(x, first);
            for l in 0..LANES {
                xl[l] *= kn.x_tot[l];
            }
            let g_y = batch::load(g, first);
            let g_ld = batch::load(g_log_det, first);
            let at = kn.locate(&xl, false);
            // The bin's own terms, as Quadratic::backward_in writes them.
            let mut own = [[0.0f32; LANES]; 4];
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
                    let below = (i as f32) < at.b[l];
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
                scale[l] = (1.0 - MIN_V) / kn.norm[l];
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
                    out[l] = (gv[l] * scale[l] - s[l] * dn) * e[l];
                }
            }
            batch::softmax_floor_backward(&kn.w, g_w, MIN_W, &mut g_params[..k]);
            let lanes = LANES.min(n - first);
            batch::scatter(g_params, first, lanes, n, 0, g_p);
            for (g, v) in g[first..first + lanes].iter_mut().zip(&g_x) {
                *g = *v as f64;
            }
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
