//! Dense (fully connected) layers on f32 matrices, via `gemm`. Inputs are row-major
//! `[rows, features]`; a layer's output (and the gradient at it) is laid out as its [`Shape`]
//! says: row-major, or feature-major for a consumer that works across rows.

use gemm::{gemm, Parallelism};

/// How a dense layer's output, and the gradient with respect to it, lie in memory.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Layout {
    /// `[rows, features]`: a row's features side by side (the next layer's input).
    #[default]
    Rows,
    /// `[features, rows]`: one feature's values over the rows side by side, so a kernel that
    /// works across rows (the spline lanes) reads them without a transpose. `gemm` runs
    /// [`backward_weights_block`] from a gradient in this layout at about half its row-major
    /// speed; [`crate::nn::Mlp`] transposes its output's gradient for it.
    Features,
}

/// A dense layer's shape at a batch: `n` rows of `i` inputs and `o` outputs, and the layout of
/// its `n × o` output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    pub n: usize,
    pub i: usize,
    pub o: usize,
    pub out: Layout,
}

impl Shape {
    /// A layer whose output is row-major.
    pub fn rows(n: usize, i: usize, o: usize) -> Shape {
        Shape {
            n,
            i,
            o,
            out: Layout::Rows,
        }
    }

    /// The column and row strides of the output (as `gemm` takes them: column first).
    fn out_strides(self) -> (isize, isize) {
        match self.out {
            Layout::Rows => (1, self.o as isize),
            Layout::Features => (self.n as isize, 1),
        }
    }
}

/// `out[n×o] = x[n×i] · w[i×o] + b`.
pub fn forward(x: &[f32], w: &[f32], b: &[f32], out: &mut [f32], shape: Shape) {
    let Shape { n, o, .. } = shape;
    assert!(b.len() == o && out.len() >= n * o);
    match shape.out {
        Layout::Rows => {
            // The first row, then the rows filled so far copied after themselves: log₂ n
            // copies instead of a short copy per row (which cost the guide's hidden layers a
            // call to memmove each).
            let out = &mut out[..n * o];
            if n > 0 {
                out[..o].copy_from_slice(b);
            }
            let mut filled = o.min(out.len());
            while filled < out.len() {
                let m = filled.min(out.len() - filled);
                out.copy_within(..m, filled);
                filled += m;
            }
        }
        Layout::Features => {
            for (column, &b) in out[..n * o].chunks_exact_mut(n.max(1)).zip(b) {
                column.fill(b);
            }
        }
    }
    accumulate(x, w, out, shape);
}

/// [`forward`] into a vector, resized to `n × o` without first zeroing what the bias then
/// overwrites (a chunk's activations are allocated afresh for every pass).
pub fn forward_into(x: &[f32], w: &[f32], b: &[f32], out: &mut Vec<f32>, shape: Shape) {
    let Shape { n, o, .. } = shape;
    assert!(b.len() == o);
    out.clear();
    out.reserve(n * o);
    match shape.out {
        // As in `forward`: the first row, then doubling copies.
        Layout::Rows if n > 0 => {
            out.extend_from_slice(b);
            while out.len() < n * o {
                out.extend_from_within(..out.len().min(n * o - out.len()));
            }
        }
        Layout::Rows => {}
        Layout::Features => {
            for &b in b {
                out.resize(out.len() + n, b);
            }
        }
    }
    accumulate(x, w, out, shape);
}

/// `out[n×o] += x[n×i] · w[i×o]`: a dense layer whose output already holds a part computed
/// elsewhere (e.g. the bias plus the contribution of inputs shared by many rows).
pub fn accumulate(x: &[f32], w: &[f32], out: &mut [f32], shape: Shape) {
    let Shape { n, i, o, .. } = shape;
    assert!(x.len() >= n * i && w.len() == i * o && out.len() >= n * o);
    if n == 0 || i == 0 || o == 0 {
        return;
    }
    let (out_cs, out_rs) = shape.out_strides();
    // SAFETY: the asserts above bound every index the strides reach: dst n×o in its layout
    // (within n·o), lhs n×i with row stride i, rhs i×o with row stride o, column strides 1.
    unsafe {
        gemm(
            n,
            o,
            i,
            out.as_mut_ptr(),
            out_cs,
            out_rs,
            true,
            x.as_ptr(),
            1,
            i as isize,
            w.as_ptr(),
            1,
            o as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

/// `g_x[n×i] = g_out[n×o] · wᵀ` (overwrites `g_x`, row-major; `g_out` in the shape's layout).
pub fn backward_input(g_out: &[f32], w: &[f32], g_x: &mut [f32], shape: Shape) {
    let Shape { n, i, o, .. } = shape;
    assert!(g_out.len() >= n * o && w.len() == i * o && g_x.len() >= n * i);
    if n == 0 || i == 0 {
        return;
    }
    if o == 0 {
        g_x[..n * i].fill(0.0);
        return;
    }
    let (g_cs, g_rs) = shape.out_strides();
    // SAFETY: dst n×i (row stride i), lhs = g_out n×o in its layout (within n·o), rhs = wᵀ read
    // from w (i×o) as an o×i matrix with row stride 1 and column stride o; all within the
    // asserted lengths.
    unsafe {
        gemm(
            n,
            i,
            o,
            g_x.as_mut_ptr(),
            1,
            i as isize,
            false,
            g_out.as_ptr(),
            g_cs,
            g_rs,
            w.as_ptr(),
            o as isize,
            1,
            0.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

/// `g_w[rows, :] (+)= x[:, rows]ᵀ · g_out` over the `n` rows of `shape`, for the block `rows` of
/// the `i×o` weight gradient; adds to the block when `accumulate`, else overwrites. One block is
/// one work item that walks the batch's chunks in order, so weight gradients do not depend on how
/// blocks are scheduled.
pub fn backward_weights_block(
    x: &[f32],
    g_out: &[f32],
    g_w_block: &mut [f32],
    shape: Shape,
    rows: std::ops::Range<usize>,
    accumulate: bool,
) {
    let Shape { n, i, o, .. } = shape;
    let (r0, m) = (rows.start, rows.len());
    assert!(x.len() >= n * i && g_out.len() >= n * o && g_w_block.len() == m * o && r0 + m <= i);
    if n == 0 {
        if !accumulate {
            g_w_block.fill(0.0);
        }
        return;
    }
    let (g_cs, g_rs) = shape.out_strides();
    // SAFETY: dst m×o (row stride o); lhs = xᵀ rows r0..r0+m: element (r, c) = x[c·i + r0 + r],
    // row stride 1, column stride i, c < n; rhs = g_out n×o in its layout (within n·o).
    unsafe {
        gemm(
            m,
            o,
            n,
            g_w_block.as_mut_ptr(),
            1,
            o as isize,
            accumulate,
            x.as_ptr().add(r0),
            i as isize,
            1,
            g_out.as_ptr(),
            g_cs,
            g_rs,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn naive(a: &[f32], b: &[f32], n: usize, k: usize, m: usize) -> Vec<f32> {
        let mut c = vec![0.0f32; n * m];
        for r in 0..n {
            for j in 0..m {
                c[r * m + j] = (0..k)
                    .map(|t| a[r * k + t] as f64 * b[t * m + j] as f64)
                    .sum::<f64>() as f32;
            }
        }
        c
    }

    fn transpose(a: &[f32], r: usize, c: usize) -> Vec<f32> {
        let mut t = vec![0.0; r * c];
        for i in 0..r {
            for j in 0..c {
                t[j * r + i] = a[i * c + j];
            }
        }
        t
    }

    /// Deterministic test values in [−1, 1).
    pub(crate) fn filled(len: usize, seed: u32) -> Vec<f32> {
        (0..len)
            .map(|t| {
                (((t as u32).wrapping_mul(2654435761).wrapping_add(seed)) % 1000) as f32 / 500.0
                    - 1.0
            })
            .collect()
    }

    #[test]
    fn dense_kernels_match_naive_products() {
        for layout in [Layout::Rows, Layout::Features] {
            // A row-major n×o matrix in `layout`.
            let laid = |m: &[f32], n: usize, o: usize| match layout {
                Layout::Rows => m.to_vec(),
                Layout::Features => transpose(m, n, o),
            };
            for (n, i, o) in [(1, 1, 1), (7, 5, 3), (33, 64, 17), (300, 40, 70)] {
                let shape = |n| Shape {
                    n,
                    i,
                    o,
                    out: layout,
                };
                let x = filled(n * i, 1);
                let w = filled(i * o, 2);
                let b = filled(o, 3);
                let g = filled(n * o, 4);
                let mut out = vec![0.0; n * o];
                forward(&x, &w, &b, &mut out, shape(n));
                let want = laid(&naive(&x, &w, n, i, o), n, o);
                let bias = laid(&b.repeat(n), n, o);
                for ((out, want), b) in out.iter().zip(&want).zip(&bias) {
                    assert!((out - want - b).abs() < 1e-4);
                }
                let mut gx = vec![0.0; n * i];
                backward_input(&laid(&g, n, o), &w, &mut gx, shape(n));
                let want = naive(&g, &transpose(&w, i, o), n, o, i);
                assert!(gx.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-4));
                let want = naive(&transpose(&x, n, i), &g, i, n, o);
                let split = i / 2;
                let mut gw = vec![0.0; i * o];
                let (lo, hi) = gw.split_at_mut(split * o);
                // Two row blocks, the second accumulated over two halves of the batch (each half
                // a matrix of its own, as a chunk of rows is).
                backward_weights_block(&x, &laid(&g, n, o), lo, shape(n), 0..split, false);
                let h = n / 2;
                let upper = laid(&g[..h * o], h, o);
                backward_weights_block(&x, &upper, hi, shape(h), split..i, false);
                let lower = laid(&g[h * o..], n - h, o);
                backward_weights_block(&x[h * i..], &lower, hi, shape(n - h), split..i, true);
                assert!(gw.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-3));
            }
        }
    }
}
