//! A multilayer perceptron with ReLU hidden layers whose weights live in a slice of the flow's
//! flat parameter vector. Activations are row-major `[rows, features]` (the output layer's in
//! the MLP's [`Layout`]) and kept per chunk of rows (the tape), so a backward pass can reuse
//! what the forward pass computed.
//!
//! Layout of one layer's parameters: weights `[in, out]` row-major, then the `out` biases.

use rand::Rng;

use rayon::prelude::*;

use crate::kernels;
use crate::kernels::dense::{self, Shape};
use crate::kernels::elementwise;
use crate::kernels::CHUNK_ROWS;

pub use crate::kernels::dense::Layout;

/// The row-major `[n, o]` copy of the feature-major `[o, n]` matrix `m`. For a chunk of a few
/// rows a row at a time (contiguous stores, and the reads a few cache lines per feature); for
/// many rows, whose features lie whole pages apart (the reads of a row would thrash the
/// cache), a block of rows at a time, each feature's values for the block read as one run.
fn rows_of_features(m: &[f32], n: usize, o: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; n * o];
    if n <= 128 {
        for (r, row) in out.chunks_exact_mut(o).enumerate() {
            for (v, column) in row.iter_mut().zip(m.chunks_exact(n)) {
                *v = column[r];
            }
        }
        return out;
    }
    const BLOCK: usize = 8;
    for r0 in (0..n).step_by(BLOCK) {
        let r1 = (r0 + BLOCK).min(n);
        for (c, column) in m.chunks_exact(n).take(o).enumerate() {
            for (r, &v) in (r0..r1).zip(&column[r0..r1]) {
                out[r * o + c] = v;
            }
        }
    }
    out
}

/// Shape of an MLP: `dims[0]` inputs, `dims[1..len−1]` hidden ReLU layers, `dims[len−1]` outputs.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    pub dims: Vec<usize>,
    /// How the output layer's activations (and the gradients at them) are laid out; the hidden
    /// layers' are row-major.
    pub output: Layout,
}

/// Activations of one chunk of rows: `acts[0]` is the input, `acts[last]` the output.
#[derive(Clone, Debug, Default)]
pub struct MlpTape {
    pub rows: usize,
    pub acts: Vec<Vec<f32>>,
}

/// An MLP's forward pass over a batch ([`Mlp::forward_batch`]): its outputs, and what its
/// backward pass needs.
#[derive(Clone, Debug, Default)]
pub struct BatchForward {
    chunks: Vec<MlpTape>,
}

impl BatchForward {
    /// The outputs, chunk after chunk, each in the MLP's output layout (row-major for
    /// [`Layout::Rows`]).
    pub fn outputs(&self) -> impl Iterator<Item = &f32> {
        self.chunks
            .iter()
            .flat_map(|t| t.acts.last().expect("an MLP has an output layer"))
    }
}

impl Mlp {
    /// Number of layers with weights.
    pub fn layers(&self) -> usize {
        self.dims.len() - 1
    }

    /// Layer `j`'s shape at `rows` rows.
    fn shape(&self, j: usize, rows: usize) -> Shape {
        let out = if j + 1 == self.layers() {
            self.output
        } else {
            Layout::Rows
        };
        Shape {
            n: rows,
            i: self.dims[j],
            o: self.dims[j + 1],
            out,
        }
    }

    /// Offsets of layer `j`'s weights and biases within this MLP's parameters.
    fn offsets(&self, j: usize) -> (usize, usize) {
        let mut off = 0;
        for l in 0..j {
            off += (self.dims[l] + 1) * self.dims[l + 1];
        }
        (off, off + self.dims[j] * self.dims[j + 1])
    }

    /// Total number of parameters.
    pub fn param_count(&self) -> usize {
        self.dims.windows(2).map(|d| (d[0] + 1) * d[1]).sum()
    }

    /// He-uniform weights and zero biases for hidden layers; an all-zero output layer, so a new
    /// conditioner outputs zeros (the identity transform for every spline).
    pub fn init(&self, params: &mut [f32], rng: &mut impl Rng) {
        params.fill(0.0);
        for j in 0..self.layers() - 1 {
            let (w, _) = self.offsets(j);
            let bound = (6.0 / self.dims[j].max(1) as f32).sqrt();
            for p in &mut params[w..w + self.dims[j] * self.dims[j + 1]] {
                *p = bound * (2.0 * rng.random::<f32>() - 1.0);
            }
        }
    }

    /// A tape for `rows` rows with the input `acts[0]` allocated (to be filled by the caller);
    /// the forward pass allocates the other layers' activations.
    pub fn tape(&self, rows: usize) -> MlpTape {
        let mut acts = vec![Vec::new(); self.dims.len()];
        acts[0] = vec![0.0; rows * self.dims[0]];
        MlpTape { rows, acts }
    }

    /// Layer `j`'s weights (`[in, out]` row-major) and biases within this MLP's parameters.
    pub fn layer_params<'a>(&self, params: &'a [f32], j: usize) -> (&'a [f32], &'a [f32]) {
        let (wo, bo) = self.offsets(j);
        (&params[wo..bo], &params[bo..bo + self.dims[j + 1]])
    }

    /// Forward pass of one chunk: fills `tape.acts[1..]` from `tape.acts[0]`.
    pub fn forward(&self, params: &[f32], tape: &mut MlpTape) {
        self.forward_from(params, tape, 0);
    }

    /// Forward pass of one chunk from layer `first` on: fills `tape.acts[first + 1..]` from
    /// `tape.acts[first]` (after its activation), leaving the earlier activations alone, so a
    /// caller that computed the first layers some other way (e.g. with a part of the input shared
    /// by many rows precomputed) runs the rest.
    pub fn forward_from(&self, params: &[f32], tape: &mut MlpTape, first: usize) {
        for j in first..self.layers() {
            let shape = self.shape(j, tape.rows);
            let (wo, bo) = self.offsets(j);
            let (prev, next) = tape.acts.split_at_mut(j + 1);
            let out = &mut next[0];
            let b = &params[bo..bo + shape.o];
            dense::forward_into(&prev[j], &params[wo..bo], b, out, shape);
            if j + 1 < self.layers() {
                elementwise::relu(out);
            }
        }
    }

    /// Backward pass over all chunks of a batch. `g_out[c]` is ∂L/∂output of chunk `c` (laid out
    /// as the output). Writes ∂L/∂parameters into `grads` (overwriting) and returns ∂L/∂input
    /// per chunk when asked. Chunks are reduced in groups (`kernels::sum_in_groups`), so the
    /// sums do not depend on the thread count.
    pub fn backward(
        &self,
        params: &[f32],
        tapes: &[&MlpTape],
        g_out: Vec<Vec<f32>>,
        grads: &mut [f32],
        want_input_grad: bool,
    ) -> Option<Vec<Vec<f32>>> {
        let items: Vec<_> = g_out.into_iter().zip(tapes).collect();
        let g_in = kernels::sum_in_groups(items, grads, |(g, tape), part| {
            self.backward_chunk(params, tape, g, part, want_input_grad)
        });
        want_input_grad.then(|| g_in.into_iter().flatten().collect())
    }

    /// Forward pass over a whole batch (`input`, `dims[0]` features per row), in parallel
    /// chunks of rows, kept for [`Mlp::backward_batch`].
    pub fn forward_batch(&self, params: &[f32], input: &[f32]) -> BatchForward {
        let width = self.dims[0];
        let chunks = input
            .par_chunks(CHUNK_ROWS * width.max(1))
            .map(|x| {
                let mut tape = self.tape(x.len() / width.max(1));
                tape.acts[0].copy_from_slice(x);
                self.forward(params, &mut tape);
                tape
            })
            .collect();
        BatchForward { chunks }
    }

    /// The gradient of a loss with ∂L/∂output `g_out` (laid out as
    /// [`BatchForward::outputs`]) with respect to the parameters, written into `grads`
    /// (overwriting), through the batch `forward` ran.
    pub fn backward_batch(
        &self,
        params: &[f32],
        forward: &BatchForward,
        g_out: &[f32],
        grads: &mut [f32],
    ) {
        let outputs = self.dims[self.dims.len() - 1];
        let mut at = 0;
        let g_out = forward
            .chunks
            .iter()
            .map(|t| {
                let part = g_out[at..at + t.rows * outputs].to_vec();
                at += t.rows * outputs;
                part
            })
            .collect();
        let tapes: Vec<&MlpTape> = forward.chunks.iter().collect();
        self.backward(params, &tapes, g_out, grads, false);
    }

    /// Reverse mode of one chunk: its ∂L/∂parameters added into `grads`, and its ∂L/∂input
    /// returned when asked. A chunk's whole chain runs in one work item, so a backward pass over
    /// many layers is one parallel loop, not one per layer.
    pub(crate) fn backward_chunk(
        &self,
        params: &[f32],
        tape: &MlpTape,
        g_out: Vec<f32>,
        grads: &mut [f32],
        want_input_grad: bool,
    ) -> Option<Vec<f32>> {
        let (deltas, g_in) = self.backward_deltas(params, tape, g_out, want_input_grad);
        self.add_param_gradients(tape, &deltas, grads);
        g_in
    }

    /// Reverse mode of one chunk through the layers, without the parameter gradients (those
    /// are [`Mlp::add_param_gradients`]'s): `deltas[j]`, ∂L/∂(output of layer `j`)
    /// through its activation, row-major, for every layer, and ∂L/∂input when asked.
    fn backward_deltas(
        &self,
        params: &[f32],
        tape: &MlpTape,
        g_out: Vec<f32>,
        want_input_grad: bool,
    ) -> (Vec<Vec<f32>>, Option<Vec<f32>>) {
        let mut deltas = vec![Vec::new(); self.layers()];
        let mut g = g_out;
        // The deltas are kept row-major: `gemm` computes a weight gradient from a feature-major
        // one more slowly (`nis bench flow` compares the dense layers with bare `gemm`), so a
        // feature-major output's delta is transposed once, here, for its weight gradient.
        let rows = |j: usize, g: Vec<f32>| match self.shape(j, tape.rows) {
            Shape {
                n,
                o,
                out: Layout::Features,
                ..
            } => rows_of_features(&g, n, o),
            _ => g,
        };
        for j in (0..self.layers()).rev() {
            if j == 0 && !want_input_grad {
                deltas[0] = rows(0, g);
                return (deltas, None);
            }
            let shape = self.shape(j, tape.rows);
            let (wo, bo) = self.offsets(j);
            // Gradient with respect to this layer's input, through the previous ReLU.
            let mut g_in = vec![0.0; tape.rows * shape.i];
            dense::backward_input(&g, &params[wo..bo], &mut g_in, shape);
            if j > 0 {
                elementwise::relu_backward(&tape.acts[j], &mut g_in);
            }
            deltas[j] = rows(j, std::mem::replace(&mut g, g_in));
        }
        (deltas, Some(g))
    }

    /// Adds one chunk's ∂L/∂parameters into `grads`, from its tape and its
    /// [`Mlp::backward_deltas`]: one weight-gradient product and one column sum per layer.
    fn add_param_gradients(&self, tape: &MlpTape, deltas: &[Vec<f32>], grads: &mut [f32]) {
        let mut sums = Vec::new();
        for (j, delta) in deltas.iter().enumerate() {
            let (i, o) = (self.dims[j], self.dims[j + 1]);
            let (wo, bo) = self.offsets(j);
            let shape = Shape::rows(tape.rows, i, o);
            dense::backward_weights_block(
                &tape.acts[j],
                delta,
                &mut grads[wo..bo],
                shape,
                0..i,
                true,
            );
            sums.resize(o, 0.0);
            elementwise::column_sums(&delta[..tape.rows * o], o, 0, &mut sums);
            for (g, s) in grads[bo..bo + o].iter_mut().zip(&sums) {
                *g += s;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn forward_from_a_split_first_layer_matches_forward() {
        // The first layer computed in two parts (the last inputs' contribution plus the bias,
        // then the first inputs' accumulated onto it), the rest by `forward_from`.
        let mlp = Mlp {
            dims: vec![7, 5, 4, 3],
            output: Layout::Features,
        };
        let mut params = vec![0.0; mlp.param_count()];
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        mlp.init(&mut params, &mut rng);
        for p in params.iter_mut() {
            *p += rng.random::<f32>() - 0.5;
        }
        let rows = 9;
        let mut whole = mlp.tape(rows);
        for v in whole.acts[0].iter_mut() {
            *v = rng.random();
        }
        mlp.forward(&params, &mut whole);
        let (w, b) = mlp.layer_params(&params, 0);
        let (head, o) = (3, 5);
        let x = &whole.acts[0];
        let first: Vec<f32> = x.chunks_exact(7).flat_map(|r| r[..head].to_vec()).collect();
        let rest: Vec<f32> = x.chunks_exact(7).flat_map(|r| r[head..].to_vec()).collect();
        let mut split = mlp.tape(rows);
        split.acts[1] = vec![0.0; rows * o];
        let (rest_shape, first_shape) =
            (Shape::rows(rows, 7 - head, o), Shape::rows(rows, head, o));
        dense::forward(&rest, &w[head * o..], b, &mut split.acts[1], rest_shape);
        dense::accumulate(&first, &w[..head * o], &mut split.acts[1], first_shape);
        elementwise::relu(&mut split.acts[1]);
        mlp.forward_from(&params, &mut split, 1);
        for (a, b) in whole.acts.iter().zip(&split.acts).skip(1) {
            for (a, b) in a.iter().zip(b) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + a.abs()), "{a} vs {b}");
            }
        }
    }

    /// The loss Σ_c Σ g_c · output_c over chunks of the given inputs, in f64.
    fn linear_loss(mlp: &Mlp, params: &[f32], inputs: &[Vec<f32>], g: &[Vec<f32>]) -> f64 {
        let i = mlp.dims[0];
        inputs
            .iter()
            .zip(g)
            .map(|(x, g)| {
                let mut tape = mlp.tape(x.len() / i);
                tape.acts[0].copy_from_slice(x);
                mlp.forward(params, &mut tape);
                let out = tape.acts.last().unwrap();
                out.iter()
                    .zip(g)
                    .map(|(&o, &g)| o as f64 * g as f64)
                    .sum::<f64>()
            })
            .sum()
    }

    #[test]
    fn more_chunks_than_gradient_groups_sum_to_the_chunks_gradients_on_any_thread_count() {
        // 40 chunks: groups of three (the last of one), more groups than a pool has threads.
        let rows: Vec<usize> = (0..40).map(|c| 1 + (c * 7) % 11).collect();
        assert!(rows.len() > 2 * crate::kernels::GRADIENT_GROUPS);
        let (mlp, params, _, g, tapes) = random_chunks(Layout::Rows, &rows, 12);
        let refs: Vec<&MlpTape> = tapes.iter().collect();
        let run = |threads| {
            crate::flow::tests::run_threads(threads, || {
                let mut grads = vec![f32::NAN; params.len()];
                let g_in = mlp.backward(&params, &refs, g.clone(), &mut grads, true);
                (grads, g_in.unwrap())
            })
        };
        let (grads, g_in) = run(1);
        let (grads3, g_in3) = run(3);
        assert!(grads
            .iter()
            .zip(&grads3)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(g_in, g_in3);
        // Each chunk on its own: its input gradient bit for bit, in chunk order, and the
        // parameter gradients summing (in f64) to the batch's up to f32 rounding.
        let mut sum = vec![0.0f64; params.len()];
        for c in 0..rows.len() {
            let mut one = vec![f32::NAN; params.len()];
            let g_one = mlp.backward(&params, &refs[c..=c], vec![g[c].clone()], &mut one, true);
            assert_eq!(g_one.unwrap()[0], g_in[c], "chunk {c}");
            for (s, v) in sum.iter_mut().zip(&one) {
                *s += f64::from(*v);
            }
        }
        let scale = sum.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (a, b)) in grads.iter().zip(&sum).enumerate() {
            // 40 f32 additions of terms up to `scale`: a few dozen ulps of it at most.
            assert!(
                (f64::from(*a) - b).abs() <= 64.0 * f64::from(f32::EPSILON) * scale,
                "param {k}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn rows_of_features_transposes_few_and_many_rows() {
        // Both loops: up to 128 rows a row at a time, more a block of rows at a time (with a
        // partial last block).
        for (n, o) in [(5, 3), (128, 33), (301, 17)] {
            let m: Vec<f32> = (0..n * o).map(|k| k as f32).collect();
            let rows = rows_of_features(&m, n, o);
            for r in 0..n {
                for c in 0..o {
                    assert_eq!(rows[r * o + c], m[c * n + r], "{n} × {o}: ({r}, {c})");
                }
            }
        }
    }

    #[test]
    fn backward_over_chunks_matches_finite_differences() {
        check_backward_over_chunks(Layout::Rows);
        check_backward_over_chunks(Layout::Features);
    }

    /// A 4 → 6 → 5 → 3 MLP with perturbed initial weights, chunks of `rows` random inputs, a
    /// random gradient at each chunk's outputs, and the chunks' forward tapes.
    type Chunks = (Mlp, Vec<f32>, Vec<Vec<f32>>, Vec<Vec<f32>>, Vec<MlpTape>);
    fn random_chunks(output: Layout, rows: &[usize], seed: u64) -> Chunks {
        let mlp = Mlp {
            dims: vec![4, 6, 5, 3],
            output,
        };
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut params = vec![0.0; mlp.param_count()];
        mlp.init(&mut params, &mut rng);
        for p in params.iter_mut() {
            *p += 0.5 * (rng.random::<f32>() - 0.5);
        }
        let inputs: Vec<Vec<f32>> = rows
            .iter()
            .map(|&n| (0..n * 4).map(|_| rng.random::<f32>()).collect())
            .collect();
        let g: Vec<Vec<f32>> = rows
            .iter()
            .map(|&n| (0..n * 3).map(|_| rng.random::<f32>() - 0.5).collect())
            .collect();
        let tapes: Vec<MlpTape> = inputs
            .iter()
            .map(|x| {
                let mut tape = mlp.tape(x.len() / 4);
                tape.acts[0].copy_from_slice(x);
                mlp.forward(&params, &mut tape);
                tape
            })
            .collect();
        (mlp, params, inputs, g, tapes)
    }

    /// Three layers over two chunks of different sizes: every parameter's gradient and every
    /// input's, against central differences of a loss linear in the outputs (laid out as
    /// `output`, as are the gradients at them).
    fn check_backward_over_chunks(output: Layout) {
        let (mlp, params, inputs, g, tapes) = random_chunks(output, &[3, 5], 11);
        let refs: Vec<&MlpTape> = tapes.iter().collect();
        let mut grads = vec![f32::NAN; params.len()];
        let g_in = mlp
            .backward(&params, &refs, g.clone(), &mut grads, true)
            .unwrap();
        // h well above f32 rounding of the O(1) loss and below the ReLU kinks' reach here.
        let h = 1e-3f32;
        let tol = |fd: f64| 2e-3 + 1e-2 * fd.abs();
        for k in 0..params.len() {
            let (mut up, mut down) = (params.clone(), params.clone());
            up[k] += h;
            down[k] -= h;
            let fd = (linear_loss(&mlp, &up, &inputs, &g) - linear_loss(&mlp, &down, &inputs, &g))
                / (2.0 * h as f64);
            assert!(
                (grads[k] as f64 - fd).abs() < tol(fd),
                "param {k}: {} vs {fd}",
                grads[k]
            );
        }
        for c in 0..inputs.len() {
            for k in 0..inputs[c].len() {
                let (mut up, mut down) = (inputs.clone(), inputs.clone());
                up[c][k] += h;
                down[c][k] -= h;
                let fd = (linear_loss(&mlp, &params, &up, &g)
                    - linear_loss(&mlp, &params, &down, &g))
                    / (2.0 * h as f64);
                let got = g_in[c][k] as f64;
                assert!((got - fd).abs() < tol(fd), "input {c}/{k}: {got} vs {fd}");
            }
        }
        // Without input gradients: the same parameter gradients, bit for bit.
        let mut again = vec![f32::NAN; params.len()];
        assert!(mlp.backward(&params, &refs, g, &mut again, false).is_none());
        assert!(grads
            .iter()
            .zip(&again)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
