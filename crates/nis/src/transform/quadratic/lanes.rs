//! The piecewise-quadratic transform over groups of [`LANES`] scalars at once (the batch
//! kernels of [`super::Quadratic`]): each lane's knots, the forward and inverse maps, and their
//! backward pass, vectorised across lanes.

use multiversion::multiversion;

use super::{MIN_V, MIN_W};
use crate::transform::batch::{self, splat, Lane, LANES};

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
pub(super) fn run_lanes(k: usize, p: &[f32], t: &mut [f64], log_det: &mut [f64], inverse: bool) {
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
pub(super) fn backward_lanes(
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
