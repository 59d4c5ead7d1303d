//! Lanes for the batched spline kernels: a group of [`LANES`] scalars is processed together, each
//! per-bin quantity stored as one `[f32; LANES]` (structure of arrays: bin-major, scalar-minor),
//! so every step of knot normalisation, bin search and evaluation is a fixed-width loop over the
//! lanes that the compiler vectorises (the kernels calling these are compiled per instruction set
//! with `multiversion`; everything here is `#[inline(always)]` to be compiled with them).
//!
//! The lane helpers repeat the scalar helpers' arithmetic operation for operation, in the same
//! order (sums start from −0, as the scalar code's folds do), so a batched kernel gives bit for
//! bit the numbers of the per-scalar reference: the integrator's results do not depend on which
//! ran.

use crate::kernels::elementwise::exp;

/// Scalars per group: four AVX-512 registers of f32, eight of AVX2.
pub(crate) const LANES: usize = 64;

/// One value per lane.
pub(crate) type Lane = [f32; LANES];

/// A lane of `v`.
#[inline(always)]
pub(crate) fn splat(v: f32) -> Lane {
    [v; LANES]
}

/// Copies parameters `from..from + out.len()` of scalars `first..first + LANES` of `n` into
/// `out[j][lane]`, from the feature-major `p` (parameter j of scalar i at `p[j·n + i]`, as
/// [`super::Transform::forward_batch`] takes them): a row of lanes is a slice of `p`. Lanes past
/// the last scalar repeat it, so they compute something finite that the caller discards.
#[inline(always)]
pub(crate) fn gather(p: &[f32], first: usize, n: usize, from: usize, out: &mut [[f32; LANES]]) {
    let full = first + LANES <= n;
    for (j, o) in out.iter_mut().enumerate() {
        let row = &p[(from + j) * n..(from + j + 1) * n];
        if full {
            o.copy_from_slice(&row[first..first + LANES]);
        } else {
            for (l, o) in o.iter_mut().enumerate() {
                *o = row[(first + l).min(n - 1)];
            }
        }
    }
}

/// e^(l − max l) per lane, as [`super::Real::exponentials`] for f32: writes `out` and returns
/// the lanes' sums.
#[inline(always)]
pub(crate) fn exponentials(logits: &[[f32; LANES]], out: &mut [Lane]) -> Lane {
    let mut max = [f32::NEG_INFINITY; LANES];
    for row in logits {
        for l in 0..LANES {
            max[l] = max[l].max(row[l]);
        }
    }
    for (o, row) in out.iter_mut().zip(logits) {
        for l in 0..LANES {
            o[l] = exp(row[l] - max[l]);
        }
    }
    let mut sum = splat(-0.0);
    for o in out[..logits.len()].iter() {
        for l in 0..LANES {
            sum[l] += o[l];
        }
    }
    sum
}

/// [`super::softmax_floor`] per lane, in f32.
#[inline(always)]
pub(crate) fn softmax_floor(logits: &[[f32; LANES]], floor: f32, out: &mut [Lane]) {
    let k = logits.len();
    let sum = exponentials(logits, &mut out[..k]);
    let base = floor / k as f32;
    let mut scale = splat(0.0);
    for l in 0..LANES {
        scale[l] = (1.0 - floor) / sum[l];
    }
    for o in out[..k].iter_mut() {
        for l in 0..LANES {
            o[l] = base + scale[l] * o[l];
        }
    }
}

/// [`super::softmax_floor_backward`] per lane: ∂L/∂logits of lane l into `g_logits[j][l]`.
#[inline(always)]
pub(crate) fn softmax_floor_backward(
    out: &[Lane],
    g_out: &[Lane],
    floor: f32,
    g_logits: &mut [[f32; LANES]],
) {
    let k = g_logits.len();
    let base = floor / k as f32;
    let inv = 1.0 / (1.0 - floor);
    let mut dot = splat(-0.0);
    for i in 0..k {
        for l in 0..LANES {
            dot[l] += (out[i][l] - base) * inv * g_out[i][l];
        }
    }
    for j in 0..k {
        for l in 0..LANES {
            g_logits[j][l] = (out[j][l] - base) * (g_out[j][l] - dot[l]);
        }
    }
}

/// Writes `g[j][lane]` back to parameter gradients `from..` of the group's real scalars (the
/// first `lanes` from `first`, of `n`) in the feature-major `g_p`: the reverse of [`gather`].
#[inline(always)]
pub(crate) fn scatter(
    g: &[[f32; LANES]],
    first: usize,
    lanes: usize,
    n: usize,
    from: usize,
    g_p: &mut [f32],
) {
    for (j, v) in g.iter().enumerate() {
        let at = (from + j) * n + first;
        g_p[at..at + lanes].copy_from_slice(&v[..lanes]);
    }
}

/// The group's lanes of a per-scalar slice, padded by repeating the last scalar.
#[inline(always)]
pub(crate) fn load(v: &[f64], first: usize) -> Lane {
    let n = v.len();
    let mut out = splat(0.0);
    for (l, o) in out.iter_mut().enumerate() {
        *o = v[(first + l).min(n - 1)] as f32;
    }
    out
}
