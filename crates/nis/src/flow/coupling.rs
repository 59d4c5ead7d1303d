//! One coupling layer (Dinh et al. 2014, Müller et al. 2019 Def. 1): y_A = x_A and
//! y_B = C(x_B; m(x_A, context)). The conditioner m is the one-blob encoding of x_A (plus raw
//! context features) fed to an MLP whose outputs are the transforms' unnormalised parameters.
//! Everything here works on one chunk of rows; the flow runs chunks in parallel.

use crate::kernels::elementwise;
use crate::nn::mlp::{Mlp, MlpTape};
use crate::spline::{with_spline, Spline, Transform};

/// A coupling layer's partition and conditioner; its weights live in the flow's parameter vector
/// at `offset..offset + mlp.param_count()`.
#[derive(Clone, Debug)]
pub struct Coupling {
    pub a: Vec<usize>,
    pub b: Vec<usize>,
    pub mlp: Mlp,
    pub offset: usize,
}

/// Which way a chunk goes through the layer.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Data to latent: y_B = C(x_B).
    Forward,
    /// Latent to data: x_B = C⁻¹(y_B).
    Inverse,
}

impl Coupling {
    /// This layer's parameters within the flow's.
    pub fn params<'a>(&self, all: &'a [f32]) -> &'a [f32] {
        &all[self.offset..self.offset + self.mlp.param_count()]
    }

    /// Fills the conditioner input (`tape.acts[0]`) from x_A and the context.
    fn encode(&self, u: &[f32], dim: usize, ctx: Option<&[f32]>, blob: usize, tape: &mut MlpTape) {
        let width = self.mlp.dims[0];
        let na = self.a.len();
        if width == 0 {
            return;
        }
        let cdim = width - na * blob;
        let mut s = vec![0.0f32; na];
        for (r, row) in tape.acts[0].chunks_exact_mut(width).enumerate() {
            for (k, &a) in self.a.iter().enumerate() {
                s[k] = u[r * dim + a];
            }
            elementwise::one_blob(&s, blob, &mut row[..na * blob]);
            if let Some(ctx) = ctx {
                row[na * blob..].copy_from_slice(&ctx[r * cdim..(r + 1) * cdim]);
            }
        }
    }

    /// Runs the conditioner and transforms x_B in place (rows of `u`, `dim` wide), adding each
    /// row's log C' to `log_det`. Returns the conditioner's tape.
    pub fn apply(
        &self,
        params: &[f32],
        transform: Transform,
        blob: usize,
        u: &mut [f32],
        dim: usize,
        ctx: Option<&[f32]>,
        log_det: &mut [f64],
        direction: Direction,
    ) -> MlpTape {
        let rows = log_det.len();
        let mut tape = self.mlp.tape(rows);
        self.encode(u, dim, ctx, blob, &mut tape);
        self.mlp.forward(self.params(params), &mut tape);
        let out = tape.acts.last().expect("an MLP has an output layer");
        let np = transform.param_count();
        let width = self.b.len() * np;
        with_spline!(transform, s => {
            for r in 0..rows {
                let row = &out[r * width..(r + 1) * width];
                for (k, &d) in self.b.iter().enumerate() {
                    let p = &row[k * np..(k + 1) * np];
                    let v = u[r * dim + d] as f64;
                    let (v, ld) = match direction {
                        Direction::Forward => s.forward(p, v),
                        Direction::Inverse => s.inverse(p, v),
                    };
                    u[r * dim + d] = v as f32;
                    log_det[r] += ld;
                }
            }
        });
        tape
    }

    /// Reverse mode through the transforms of one chunk. `input` is the layer's input (x side),
    /// `g_u` holds ∂L/∂output on entry and ∂L/∂input for the B dimensions on exit (the A part is
    /// completed by [`Coupling::encoding_backward`]); `g_log_det[r]` is ∂L/∂log C' of row r.
    /// Returns ∂L/∂(conditioner output).
    pub fn spline_backward(
        &self,
        transform: Transform,
        tape: &MlpTape,
        input: &[f32],
        dim: usize,
        g_u: &mut [f32],
        g_log_det: &[f32],
    ) -> Vec<f32> {
        let rows = tape.rows;
        let out = tape.acts.last().expect("an MLP has an output layer");
        let np = transform.param_count();
        let width = self.b.len() * np;
        let mut g_out = vec![0.0f32; rows * width];
        with_spline!(transform, s => {
            for r in 0..rows {
                for (k, &d) in self.b.iter().enumerate() {
                    let at = r * width + k * np;
                    let g_x = s.backward(
                        &out[at..at + np],
                        input[r * dim + d] as f64,
                        g_u[r * dim + d] as f64,
                        g_log_det[r] as f64,
                        &mut g_out[at..at + np],
                    );
                    g_u[r * dim + d] = g_x as f32;
                }
            }
        });
        g_out
    }

    /// Adds the conditioner's dependence on x_A to `g_u`, from ∂L/∂(encoded input).
    pub fn encoding_backward(
        &self,
        blob: usize,
        tape: &MlpTape,
        input: &[f32],
        dim: usize,
        g_enc: &[f32],
        g_u: &mut [f32],
    ) {
        let width = self.mlp.dims[0];
        let na = self.a.len();
        let mut s = vec![0.0f32; na];
        let mut g_s = vec![0.0f32; na];
        for r in 0..tape.rows {
            for (k, &a) in self.a.iter().enumerate() {
                s[k] = input[r * dim + a];
            }
            let e = &tape.acts[0][r * width..r * width + na * blob];
            let g_e = &g_enc[r * width..r * width + na * blob];
            elementwise::one_blob_backward(&s, blob, e, g_e, &mut g_s);
            for (k, &a) in self.a.iter().enumerate() {
                g_u[r * dim + a] += g_s[k];
            }
        }
    }
}
