//! One coupling layer (Dinh et al. 2014, Müller et al. 2019 Def. 1): y_A = x_A and
//! y_B = C(x_B; m(x_A, context)). The layer is built from three independent parts, as zuko's
//! `GeneralCouplingTransform`: its mask (the partition A, B), its conditioner m (the one-blob
//! encoding of x_A, plus raw context features, fed to an MLP whose outputs are the transforms'
//! unnormalised parameters) and its kind of 1-D transform C. Everything here works on one chunk
//! of rows; [`super::composed::Composed`] runs chunks in parallel.

use super::composed::{ChunkTape, Composed, Direction, Layer, Rows};
use super::config::FlowConfig;
use crate::kernels;
use crate::kernels::dense::{self, Shape};
use crate::kernels::elementwise;
use crate::nn::encoding::OneBlob;
use crate::nn::mlp::{Mlp, MlpTape};
use crate::transform::{Transform, TransformKind};

/// A coupling layer: its partition, conditioner and transform; its weights live in the flow's
/// parameter vector at `offset..offset + mlp.param_count()`.
#[derive(Clone, Debug)]
pub struct Coupling {
    /// The dimensions left alone and fed to the conditioner (the mask's A).
    a: Vec<usize>,
    /// The dimensions transformed (B).
    b: Vec<usize>,
    /// How x_A enters the conditioner.
    encoding: OneBlob,
    /// The conditioner: encoded x_A and the context in, |B| × the transform's parameters out.
    mlp: Mlp,
    /// The 1-D transform of each B dimension.
    transform: TransformKind,
    /// Where this layer's weights start in the flow's parameters.
    offset: usize,
}

impl Coupling {
    /// The layer transforming `b` given `a` with `transform`, its conditioner `mlp` taking
    /// `encoding` of x_A (then the context) and its weights at `offset` in the flow's.
    pub(crate) fn new(
        a: Vec<usize>,
        b: Vec<usize>,
        encoding: OneBlob,
        mlp: Mlp,
        transform: TransformKind,
        offset: usize,
    ) -> Coupling {
        Coupling {
            a,
            b,
            encoding,
            mlp,
            transform,
            offset,
        }
    }

    /// This layer's parameters within the flow's.
    pub fn params<'a>(&self, all: &'a [f32]) -> &'a [f32] {
        &all[self.param_range()]
    }

    /// Where this layer's parameters lie in the flow's.
    pub fn param_range(&self) -> std::ops::Range<usize> {
        self.offset..self.offset + self.mlp.param_count()
    }

    /// The dimensions left alone and fed to the conditioner (the mask's A).
    pub fn a(&self) -> &[usize] {
        &self.a
    }

    /// The dimensions this layer transforms (the mask's B).
    pub fn b(&self) -> &[usize] {
        &self.b
    }

    /// The conditioner.
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }

    /// The 1-D transform of each B dimension.
    pub fn transform(&self) -> TransformKind {
        self.transform
    }

    /// How x_A enters the conditioner.
    pub fn encoding(&self) -> OneBlob {
        self.encoding
    }

    /// The conditioner's first layer's share of the context: its weights' rows for the context
    /// inputs of `context_dim` features (`[context_dim, out]` row-major), and its biases.
    pub(crate) fn context_share<'a>(
        &self,
        params: &'a [f32],
        context_dim: usize,
    ) -> (&'a [f32], &'a [f32]) {
        let (w, b) = self.mlp.layer_params(self.params(params), 0);
        // Rows of W are inputs: the encoded x_A first, then the context.
        (&w[(self.mlp.dims[0] - context_dim) * b.len()..], b)
    }

    /// The conditioner's input width: the encoded A dimensions, then the context features.
    fn encoded_width(&self) -> usize {
        self.encoding.width(self.a.len())
    }

    /// Fills the conditioner input (`tape.acts[0]`) from x_A and the context.
    fn encode(&self, u: &[f32], dim: usize, ctx: Option<&[f32]>, tape: &mut MlpTape) {
        let width = self.mlp.dims[0];
        if width == 0 {
            return;
        }
        let enc = self.encoded_width();
        let cdim = width - enc;
        let mut s = vec![0.0f32; self.a.len()];
        for (r, row) in tape.acts[0].chunks_exact_mut(width).enumerate() {
            for (k, &a) in self.a.iter().enumerate() {
                s[k] = u[r * dim + a];
            }
            self.encoding.encode(&s, &mut row[..enc]);
            if let Some(ctx) = ctx {
                row[enc..].copy_from_slice(&ctx[r * cdim..(r + 1) * cdim]);
            }
        }
    }

    /// Transforms the B dimensions of the `log_det.len()` rows of `u` (`dim` values each) in
    /// place in `direction`, with the conditioner's output `out` for those rows, adding each
    /// row's log C' to `log_det`. One B dimension at a time over all rows: the transform's
    /// batched kernel sees a column.
    fn transform_rows(
        &self,
        out: &[f32],
        u: &mut [f32],
        dim: usize,
        log_det: &mut [f64],
        direction: Direction,
    ) {
        let n = log_det.len();
        let np = self.transform.param_count();
        let mut v = vec![0.0f64; n];
        for (k, &d) in self.b.iter().enumerate() {
            for r in 0..n {
                v[r] = u[r * dim + d] as f64;
            }
            // The conditioner's output is feature-major: dimension k's parameters, then the next's.
            let p = &out[k * np * n..(k + 1) * np * n];
            match direction {
                Direction::Forward => self.transform.forward_batch(p, &mut v, log_det),
                Direction::Inverse => self.transform.inverse_batch(p, &mut v, log_det),
            }
            for r in 0..n {
                u[r * dim + d] = v[r] as f32;
            }
        }
    }

    /// Reverse mode through the transforms of one chunk. `input` is the layer's input (x side),
    /// `g_u` holds ∂L/∂output on entry and ∂L/∂input for the B dimensions on exit (the A part is
    /// completed by [`Coupling::encoding_backward`]); `g_log_det[r]` is ∂L/∂log C' of row r.
    /// Returns ∂L/∂(conditioner output).
    fn transform_backward(
        &self,
        tape: &MlpTape,
        input: &[f32],
        dim: usize,
        g_u: &mut [f32],
        g_log_det: &[f32],
    ) -> Vec<f32> {
        let rows = tape.rows;
        let out = tape.acts.last().expect("an MLP has an output layer");
        let np = self.transform.param_count();
        let mut g_out = vec![0.0f32; rows * self.b.len() * np];
        // One B dimension at a time over all rows: the transform's batched kernel sees a column.
        let (mut x, mut g) = (vec![0.0f64; rows], vec![0.0f64; rows]);
        let g_ld: Vec<f64> = g_log_det.iter().map(|&v| v as f64).collect();
        for (k, &d) in self.b.iter().enumerate() {
            for r in 0..rows {
                x[r] = input[r * dim + d] as f64;
                g[r] = g_u[r * dim + d] as f64;
            }
            // The conditioner's output is feature-major: dimension k's parameters, then the next's.
            let part = k * np * rows..(k + 1) * np * rows;
            let (p, g_p) = (&out[part.clone()], &mut g_out[part]);
            self.transform.backward_batch(p, &x, &mut g, &g_ld, g_p);
            for r in 0..rows {
                g_u[r * dim + d] = g[r] as f32;
            }
        }
        g_out
    }

    /// Adds the conditioner's dependence on x_A to `g_u`, from ∂L/∂(encoded input).
    fn encoding_backward(
        &self,
        tape: &MlpTape,
        input: &[f32],
        dim: usize,
        g_enc: &[f32],
        g_u: &mut [f32],
    ) {
        let width = self.mlp.dims[0];
        let enc = self.encoded_width();
        let na = self.a.len();
        let mut s = vec![0.0f32; na];
        let mut g_s = vec![0.0f32; na];
        for r in 0..tape.rows {
            for (k, &a) in self.a.iter().enumerate() {
                s[k] = input[r * dim + a];
            }
            let e = &tape.acts[0][r * width..r * width + enc];
            let g_e = &g_enc[r * width..r * width + enc];
            self.encoding.backward(&s, e, g_e, &mut g_s);
            for (k, &a) in self.a.iter().enumerate() {
                g_u[r * dim + a] += g_s[k];
            }
        }
    }
}

impl Coupling {
    /// [`Layer::apply`] for rows whose context's share of the conditioner's first layer,
    /// `W_c·c + b`, is already known: `first` holds it per row (`rows × dims[1]`, before the
    /// activation, see [`super::context`]). Adds `W_A·enc(x_A)`, runs the conditioner from its
    /// second layer on and transforms x_B in place; `rows.ctx` is not read.
    pub(crate) fn apply_cached(
        &self,
        params: &[f32],
        first: Vec<f32>,
        rows: Rows<'_>,
        direction: Direction,
    ) -> MlpTape {
        let Rows {
            u, dim, log_det, ..
        } = rows;
        let n = log_det.len();
        let mlp = &self.mlp;
        let p = self.params(params);
        let h = mlp.dims[1];
        let mut acts = vec![Vec::new(); mlp.dims.len()];
        acts[1] = first;
        let mut tape = MlpTape { rows: n, acts };
        let enc_w = self.encoded_width();
        let mut enc = vec![0.0f32; n * enc_w];
        let mut s = vec![0.0f32; self.a.len()];
        for (r, e) in enc.chunks_exact_mut(enc_w.max(1)).enumerate().take(n) {
            for (k, &a) in self.a.iter().enumerate() {
                s[k] = u[r * dim + a];
            }
            self.encoding.encode(&s, e);
        }
        let (w, _) = mlp.layer_params(p, 0);
        let first = &mut tape.acts[1];
        dense::accumulate(&enc, &w[..enc_w * h], first, Shape::rows(n, enc_w, h));
        if mlp.layers() > 1 {
            elementwise::relu(first);
        }
        mlp.forward_from(p, &mut tape, 1);
        let out = tape.acts.last().expect("an MLP has an output layer");
        self.transform_rows(out, u, dim, log_det, direction);
        tape
    }
}

impl Layer for Coupling {
    type Record = MlpTape;
    type Config = FlowConfig;
    fn chunk_rows(rows: usize) -> usize {
        kernels::chunk_rows(rows)
    }

    /// Runs the conditioner and transforms x_B in place, adding each row's log C' to `log_det`.
    fn apply(&self, params: &[f32], rows: Rows<'_>, direction: Direction) -> MlpTape {
        let Rows {
            u,
            dim,
            ctx,
            log_det,
        } = rows;
        let n = log_det.len();
        let mut tape = self.mlp.tape(n);
        self.encode(u, dim, ctx, &mut tape);
        self.mlp.forward(self.params(params), &mut tape);
        let out = tape.acts.last().expect("an MLP has an output layer");
        self.transform_rows(out, u, dim, log_det, direction);
        tape
    }

    /// Each chunk's whole reverse chain through the stack (the transforms' reverse mode, the
    /// conditioner's, the encoding's), adding its parameter gradients as it goes, in the groups
    /// of consecutive chunks of `kernels::sum_in_groups`: one parallel loop per backward
    /// pass, where a loop per coupling made a 256-point training step wait for its slowest
    /// chunk six times, and sums that do not depend on the thread count.
    fn backward_stack(
        stack: &Composed<Coupling>,
        chunks: &[ChunkTape<MlpTape>],
        weights: &[f32],
        grads: &mut [f32],
    ) {
        let dim = stack.dim;
        // Each chunk's first row in the batch.
        let starts: Vec<usize> = chunks
            .iter()
            .scan(0, |next, c| {
                let start = *next;
                *next += c[0].record.rows;
                Some(start)
            })
            .collect();
        let chain = |c: usize, part: &mut [f32]| {
            let tape = &chunks[c];
            let rows = tape[0].record.rows;
            let g_ld: Vec<f32> = weights[starts[c]..starts[c] + rows]
                .iter()
                .map(|w| -w)
                .collect();
            // ∂L/∂u; the latent's density is constant, so it starts at zero.
            let mut g_u = vec![0.0f32; tape[0].input.len()];
            for (l, coupling) in stack.layers.iter().enumerate().rev() {
                let params = coupling.params(&stack.params);
                let t = &tape[l];
                let g_out = coupling.transform_backward(&t.record, &t.input, dim, &mut g_u, &g_ld);
                // The first layer's input is the fixed x: no gradient needed below it.
                let want = l > 0 && !coupling.a.is_empty();
                let range = coupling.param_range();
                let g_enc =
                    coupling
                        .mlp
                        .backward_chunk(params, &t.record, g_out, &mut part[range], want);
                if let Some(g_enc) = g_enc {
                    coupling.encoding_backward(&t.record, &t.input, dim, &g_enc, &mut g_u);
                }
            }
        };
        kernels::sum_in_groups((0..chunks.len()).collect(), grads, chain);
    }
}
