//! 3×3 convolutions with zero ("same") padding on NHWC images, as im2col followed by one `gemm`
//! (Chellapilla et al. 2006): the patches of every output pixel become one row of a
//! `[n·h·w, 9·c_in]` matrix, and the convolution is that matrix times the `[9·c_in, c_out]`
//! weights — the dense kernels of [`super::dense`] do the rest. The backward pass is the same in
//! reverse: the input gradient is the patch gradient (g_out · Wᵀ) scattered back (col2im), the
//! weight gradient is patchesᵀ · g_out.
//!
//! Layout: activations `[n, h, w, c]` row-major (channels last: a pixel's channels are
//! contiguous, so a coupling's per-pixel spline parameters are too); weights `[(ky, kx, c_in),
//! c_out]` row-major, then `c_out` biases. Single-threaded like every kernel here: callers run
//! fixed chunks of images in parallel.

use super::{dense, elementwise};

/// Taps of a 3×3 kernel.
pub const TAPS: usize = 9;

/// The shape of one convolution on a chunk of images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Images.
    pub n: usize,
    pub h: usize,
    pub w: usize,
    pub c_in: usize,
    pub c_out: usize,
}

impl Shape {
    /// Output pixels of the chunk, n·h·w (the rows of the patch matrix).
    pub fn pixels(&self) -> usize {
        self.n * self.h * self.w
    }

    /// Length of the patch matrix.
    pub fn col_len(&self) -> usize {
        self.pixels() * TAPS * self.c_in
    }

    /// Number of weights (without biases).
    pub fn weight_len(&self) -> usize {
        TAPS * self.c_in * self.c_out
    }
}

/// Fills the patch matrix: `col[p, (ky·3 + kx)·c + ci] = x[p + (ky − 1, kx − 1), ci]`, zero
/// outside the image.
pub fn im2col(x: &[f32], s: Shape, col: &mut [f32]) {
    let (h, w, c) = (s.h, s.w, s.c_in);
    assert!(x.len() >= s.pixels() * c && col.len() >= s.col_len());
    let row_len = TAPS * c;
    for img in 0..s.n {
        for y in 0..h {
            for xx in 0..w {
                let p = (img * h + y) * w + xx;
                let row = &mut col[p * row_len..(p + 1) * row_len];
                for ky in 0..3 {
                    for kx in 0..3 {
                        let dst = &mut row[(ky * 3 + kx) * c..(ky * 3 + kx + 1) * c];
                        let (sy, sx) = (y + ky, xx + kx);
                        if sy == 0 || sx == 0 || sy > h || sx > w {
                            dst.fill(0.0);
                        } else {
                            let q = (img * h + sy - 1) * w + sx - 1;
                            dst.copy_from_slice(&x[q * c..(q + 1) * c]);
                        }
                    }
                }
            }
        }
    }
}

/// The adjoint of [`im2col`]: adds every patch entry of `g_col` back onto the pixel it came
/// from. Overwrites `g_x`.
pub fn col2im(g_col: &[f32], s: Shape, g_x: &mut [f32]) {
    let (h, w, c) = (s.h, s.w, s.c_in);
    assert!(g_x.len() >= s.pixels() * c && g_col.len() >= s.col_len());
    g_x[..s.pixels() * c].fill(0.0);
    let row_len = TAPS * c;
    for img in 0..s.n {
        for y in 0..h {
            for xx in 0..w {
                let p = (img * h + y) * w + xx;
                let row = &g_col[p * row_len..(p + 1) * row_len];
                for ky in 0..3 {
                    for kx in 0..3 {
                        let (sy, sx) = (y + ky, xx + kx);
                        if sy == 0 || sx == 0 || sy > h || sx > w {
                            continue;
                        }
                        let q = (img * h + sy - 1) * w + sx - 1;
                        let src = &row[(ky * 3 + kx) * c..(ky * 3 + kx + 1) * c];
                        for (g, v) in g_x[q * c..(q + 1) * c].iter_mut().zip(src) {
                            *g += v;
                        }
                    }
                }
            }
        }
    }
}

/// `out = conv(x) + b` (`[n, h, w, c_out]`); `col` is scratch of at least [`Shape::col_len`].
pub fn forward(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    out: &mut [f32],
    s: Shape,
    col: &mut [f32],
) {
    im2col(x, s, col);
    let shape = dense::Shape::rows(s.pixels(), TAPS * s.c_in, s.c_out);
    dense::forward(col, weight, bias, out, shape);
}

/// ∂L/∂x from ∂L/∂out (overwrites `g_x`); `col` is scratch of at least [`Shape::col_len`].
pub fn backward_input(g_out: &[f32], weight: &[f32], g_x: &mut [f32], s: Shape, col: &mut [f32]) {
    let shape = dense::Shape::rows(s.pixels(), TAPS * s.c_in, s.c_out);
    dense::backward_input(g_out, weight, col, shape);
    col2im(col, s, g_x);
}

/// ∂L/∂weights and ∂L/∂bias from the layer's input `x` and ∂L/∂out; adds to `g_w` and `g_b`
/// when `accumulate`, else overwrites. `col` is scratch of at least [`Shape::col_len`].
pub fn backward_weights(
    x: &[f32],
    g_out: &[f32],
    g_w: &mut [f32],
    g_b: &mut [f32],
    s: Shape,
    col: &mut [f32],
    accumulate: bool,
) {
    im2col(x, s, col);
    let k = TAPS * s.c_in;
    let shape = dense::Shape::rows(s.pixels(), k, s.c_out);
    dense::backward_weights_block(col, g_out, g_w, shape, 0..k, accumulate);
    let mut sums = vec![0.0; s.c_out];
    elementwise::column_sums(&g_out[..s.pixels() * s.c_out], s.c_out, 0, &mut sums);
    for (g, v) in g_b.iter_mut().zip(&sums) {
        *g = if accumulate { *g + v } else { *v };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::dense::tests::filled;

    /// The textbook convolution, in f64: the reference the fused kernels are checked against.
    fn naive(x: &[f32], wt: &[f32], b: &[f32], s: Shape) -> Vec<f64> {
        let (h, w, ci, co) = (s.h as isize, s.w as isize, s.c_in, s.c_out);
        let mut out = vec![0.0; s.pixels() * co];
        for img in 0..s.n as isize {
            for y in 0..h {
                for xx in 0..w {
                    for o in 0..co {
                        let mut acc = b[o] as f64;
                        for ky in 0..3isize {
                            for kx in 0..3isize {
                                let (sy, sx) = (y + ky - 1, xx + kx - 1);
                                if sy < 0 || sx < 0 || sy >= h || sx >= w {
                                    continue;
                                }
                                for c in 0..ci {
                                    let xi = (((img * h + sy) * w + sx) as usize) * ci + c;
                                    let wi = ((ky * 3 + kx) as usize * ci + c) * co + o;
                                    acc += x[xi] as f64 * wt[wi] as f64;
                                }
                            }
                        }
                        out[(((img * h + y) * w + xx) as usize) * co + o] = acc;
                    }
                }
            }
        }
        out
    }

    const SHAPES: [Shape; 4] = [
        Shape {
            n: 1,
            h: 1,
            w: 1,
            c_in: 1,
            c_out: 1,
        },
        Shape {
            n: 2,
            h: 3,
            w: 4,
            c_in: 2,
            c_out: 3,
        },
        Shape {
            n: 3,
            h: 7,
            w: 5,
            c_in: 5,
            c_out: 4,
        },
        Shape {
            n: 2,
            h: 8,
            w: 8,
            c_in: 16,
            c_out: 9,
        },
    ];

    #[test]
    fn conv_forward_matches_the_naive_convolution() {
        for s in SHAPES {
            let x = filled(s.pixels() * s.c_in, 1);
            let wt = filled(s.weight_len(), 2);
            let b = filled(s.c_out, 3);
            let mut out = vec![0.0; s.pixels() * s.c_out];
            let mut col = vec![0.0; s.col_len()];
            forward(&x, &wt, &b, &mut out, s, &mut col);
            let want = naive(&x, &wt, &b, s);
            for (a, b) in out.iter().zip(&want) {
                assert!((*a as f64 - b).abs() < 1e-4, "{s:?}: {a} vs {b}");
            }
        }
    }

    /// L = Σ g ⊙ conv(x): its gradients are the backward kernels' outputs. Checked against
    /// central differences of the naive convolution (linear, so differences are exact up to
    /// rounding) in every input and every weight.
    #[test]
    fn conv_backward_matches_finite_differences() {
        for s in SHAPES {
            let x = filled(s.pixels() * s.c_in, 4);
            let wt = filled(s.weight_len(), 5);
            let b = filled(s.c_out, 6);
            let g = filled(s.pixels() * s.c_out, 7);
            let loss = |x: &[f32], wt: &[f32], b: &[f32]| -> f64 {
                naive(x, wt, b, s)
                    .iter()
                    .zip(&g)
                    .map(|(o, g)| o * *g as f64)
                    .sum()
            };
            let mut col = vec![0.0; s.col_len()];
            let mut g_x = vec![7.0; s.pixels() * s.c_in];
            backward_input(&g, &wt, &mut g_x, s, &mut col);
            let mut g_w = vec![7.0; s.weight_len()];
            let mut g_b = vec![7.0; s.c_out];
            backward_weights(&x, &g, &mut g_w, &mut g_b, s, &mut col, false);
            let h = 0.25f32;
            let fd = |v: &mut Vec<f32>, i: usize, f: &dyn Fn(&[f32]) -> f64| {
                let old = v[i];
                v[i] = old + h;
                let p = f(v);
                v[i] = old - h;
                let m = f(v);
                v[i] = old;
                (p - m) / (2.0 * h as f64)
            };
            let mut xv = x.clone();
            for i in 0..x.len() {
                let want = fd(&mut xv, i, &|xv| loss(xv, &wt, &b));
                assert!(
                    (g_x[i] as f64 - want).abs() < 1e-3,
                    "{s:?} x[{i}]: {} vs {want}",
                    g_x[i]
                );
            }
            let mut wv = wt.clone();
            for i in 0..wt.len() {
                let want = fd(&mut wv, i, &|wv| loss(&x, wv, &b));
                assert!(
                    (g_w[i] as f64 - want).abs() < 1e-3,
                    "{s:?} w[{i}]: {} vs {want}",
                    g_w[i]
                );
            }
            let mut bv = b.clone();
            for i in 0..b.len() {
                let want = fd(&mut bv, i, &|bv| loss(&x, &wt, bv));
                assert!((g_b[i] as f64 - want).abs() < 1e-3, "{s:?} b[{i}]");
            }
            // Accumulation over two halves of the chunk equals the whole.
            if s.n > 1 {
                let half = Shape { n: s.n / 2, ..s };
                let rest = Shape {
                    n: s.n - s.n / 2,
                    ..s
                };
                let (mut g_w2, mut g_b2) = (vec![0.0; s.weight_len()], vec![0.0; s.c_out]);
                backward_weights(&x, &g, &mut g_w2, &mut g_b2, half, &mut col, false);
                let (xo, go) = (half.pixels() * s.c_in, half.pixels() * s.c_out);
                backward_weights(
                    &x[xo..],
                    &g[go..],
                    &mut g_w2,
                    &mut g_b2,
                    rest,
                    &mut col,
                    true,
                );
                assert!(g_w.iter().zip(&g_w2).all(|(a, b)| (a - b).abs() < 1e-3));
                assert!(g_b.iter().zip(&g_b2).all(|(a, b)| (a - b).abs() < 1e-3));
            }
        }
    }
}
