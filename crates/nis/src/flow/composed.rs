//! A flow as a composition of layers: h = h_L ∘ … ∘ h_1, q(x) = Π_l |det ∂h_l/∂u| (Müller et al.
//! 2019, Eq. 2), in the shape of zuko's `ComposedTransform` and nflows' `CompositeTransform`.
//!
//! [`Composed`] is the one loop that runs a stack of layers in either direction over a batch, and
//! the one implementation of [`Density`] and [`Bijection`] for every flow: the coupling flow
//! ([`crate::flow::Flow`], MLP conditioners) and RealNVP's multi-scale flow
//! ([`crate::flow::multiscale::MultiScale`], convolutional conditioners) differ only in their
//! [`Layer`]. A batch is cut into chunks of [`Layer::chunk_rows`] rows that run in parallel;
//! the chunk size depends on the batch's row count only and each layer's backward pass reduces
//! gradients in a fixed order, so results do not depend on the thread count.

use rand::RngCore;
use rayon::prelude::*;

use super::density::{check_context, check_points, next_version};
use super::{Bijection, Density, Evaluated, Samples, Tape};
use crate::error::Result;
use crate::kernels::in_pool;

/// Which way a chunk goes through a layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Data to latent: y_B = C(x_B).
    Forward,
    /// Latent to data: x_B = C⁻¹(y_B).
    Inverse,
}

/// One chunk of a batch as a layer sees it.
pub struct Rows<'a> {
    /// The rows, `dim` values each, transformed in place.
    pub u: &'a mut [f32],
    pub dim: usize,
    /// The rows' context features, if the flow is conditional.
    pub ctx: Option<&'a [f32]>,
    /// Each row's running ln|det|, to which the layer adds its own.
    pub log_det: &'a mut [f64],
}

/// What a layer kept of one chunk for the backward pass: its input (data side) and its
/// conditioner's activations.
#[derive(Clone, Debug)]
pub struct LayerTape<R> {
    pub input: Vec<f32>,
    pub record: R,
}

/// A chunk's tapes, one per layer in data-to-latent order.
pub type ChunkTape<R> = Vec<LayerTape<R>>;

/// A layer of a composed flow: an invertible map of some coordinates of each row given the
/// others (and the context), with its log-determinant.
pub trait Layer: Clone + std::fmt::Debug + Send + Sync + 'static {
    /// What the layer's conditioner keeps of a chunk for the backward pass.
    type Record: Send + Sync + 'static;
    /// What a flow of these layers is built from (kept for saving and inspection).
    type Config: Clone + std::fmt::Debug + Send + Sync + 'static;

    /// Rows per parallel work item in a batch of `rows` rows: a function of `rows` alone, never
    /// of the thread count, so results do not depend on the number of threads.
    fn chunk_rows(rows: usize) -> usize;

    /// Runs the conditioner on `rows` and transforms them in place in `direction`, adding each
    /// row's ln|det| of the data-to-latent map. Returns the conditioner's record.
    fn apply(&self, params: &[f32], rows: Rows<'_>, direction: Direction) -> Self::Record;

    /// The gradient of L = −Σ w_i ln q(x_i) through a whole stack of these layers, written into
    /// `grads`, from the chunks' tapes and ∂L/∂ln q = −w. A stack reduces gradients in its own
    /// fixed order (both flows chunk by chunk, the coupling flow in groups of consecutive
    /// chunks, then summed in chunk or group order).
    fn backward_stack(
        stack: &Composed<Self>,
        chunks: &[ChunkTape<Self::Record>],
        weights: &[f32],
        grads: &mut [f32],
    );
}

/// A stack of layers with their parameters in one flat vector.
#[derive(Clone, Debug)]
pub struct Composed<L: Layer> {
    pub(crate) config: L::Config,
    pub(crate) layers: Vec<L>,
    pub(crate) params: Vec<f32>,
    pub(crate) dim: usize,
    pub(crate) context_dim: usize,
    /// Bumped whenever the parameters may change, so a stale tape is detected.
    version: u64,
}

impl<L: Layer> Composed<L> {
    /// A stack of `layers` on [0, 1]^`dim` with initial parameters `params`.
    pub(crate) fn from_parts(
        config: L::Config,
        layers: Vec<L>,
        params: Vec<f32>,
        dim: usize,
        context_dim: usize,
    ) -> Composed<L> {
        Composed {
            config,
            layers,
            params,
            dim,
            context_dim,
            version: next_version(),
        }
    }

    /// The config this flow was built from.
    pub fn config(&self) -> &L::Config {
        &self.config
    }

    /// The layers, in data-to-latent order.
    pub fn layers(&self) -> &[L] {
        &self.layers
    }

    /// Runs all layers over `u` in place, chunk-parallel; returns ln q per row (of the data-side
    /// points) and, when `record`, the tape.
    pub(crate) fn run(
        &self,
        u: &mut [f32],
        ctx: Option<&[f32]>,
        direction: Direction,
        record: bool,
    ) -> (Vec<f64>, Option<Tape>) {
        let (dim, cdim) = (self.dim, self.context_dim);
        let rows = u.len() / dim;
        let chunk = L::chunk_rows(rows).max(1);
        let (log_q, chunks) = self.run_chunks(u, chunk, direction, record, |c, l, rows| {
            let ctx =
                ctx.map(|ctx| &ctx[c * chunk * cdim..(c * chunk + rows.log_det.len()) * cdim]);
            self.layers[l].apply(&self.params, Rows { ctx, ..rows }, direction)
        });
        let tape = record.then(|| Tape::new(self.version, rows, chunks));
        (log_q, tape)
    }

    /// The one layer loop: cuts `u` into chunks of `chunk` rows that run in parallel, and sends
    /// each chunk through the layers in `direction`'s order, layer `l` of chunk `c` by
    /// `apply(c, l, rows)` (whose `ctx` is `None`: `apply` brings the chunk's context). Returns
    /// ln q per row and, when `record`, each chunk's tapes in data-to-latent order.
    pub(crate) fn run_chunks(
        &self,
        u: &mut [f32],
        chunk: usize,
        direction: Direction,
        record: bool,
        apply: impl Fn(usize, usize, Rows<'_>) -> L::Record + Sync,
    ) -> (Vec<f64>, Vec<ChunkTape<L::Record>>) {
        let dim = self.dim;
        let mut log_q = vec![0.0f64; u.len() / dim];
        let chunks: Vec<ChunkTape<L::Record>> = in_pool(|| {
            u.par_chunks_mut(chunk * dim)
                .zip(log_q.par_chunks_mut(chunk))
                .enumerate()
                .map(|(c, (u, log_q))| {
                    let mut tapes = Vec::new();
                    let order: Vec<usize> = match direction {
                        Direction::Forward => (0..self.layers.len()).collect(),
                        Direction::Inverse => (0..self.layers.len()).rev().collect(),
                    };
                    for l in order {
                        let input = (record && direction == Direction::Forward).then(|| u.to_vec());
                        let rows = Rows {
                            u: &mut *u,
                            dim,
                            ctx: None,
                            log_det: &mut *log_q,
                        };
                        let out = apply(c, l, rows);
                        if record {
                            // Inverse: after the layer, u holds the layer's input (data side).
                            let input = input.unwrap_or_else(|| u.to_vec());
                            tapes.push(LayerTape { input, record: out });
                        }
                    }
                    if direction == Direction::Inverse {
                        tapes.reverse();
                    }
                    tapes
                })
                .collect()
        });
        (log_q, chunks)
    }

    /// The parameters' version: bumped whenever they may change.
    pub(crate) fn version(&self) -> u64 {
        self.version
    }

    fn check_points(&self, x: &[f32]) -> Result<usize> {
        check_points(
            x,
            self.dim,
            "points (length must be a multiple of the dimension)",
        )
    }

    fn draw(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut dyn RngCore,
        record: bool,
    ) -> Result<Samples> {
        check_context(n, self.context_dim, ctx)?;
        let mut x = super::uniform_latents(n * self.dim, rng);
        let (log_q, tape) = self.run(&mut x, ctx, Direction::Inverse, record);
        Ok(Samples { x, log_q, tape })
    }

    fn pass(
        &self,
        x: &[f32],
        ctx: Option<&[f32]>,
        direction: Direction,
        record: bool,
    ) -> Result<(Vec<f32>, Vec<f64>, Option<Tape>)> {
        let n = self.check_points(x)?;
        check_context(n, self.context_dim, ctx)?;
        let mut u = x.to_vec();
        let (log_q, tape) = self.run(&mut u, ctx, direction, record);
        Ok((u, log_q, tape))
    }
}

impl<L: Layer> Density for Composed<L> {
    fn dim(&self) -> usize {
        self.dim
    }

    fn context_dim(&self) -> usize {
        self.context_dim
    }

    fn sample(&self, n: usize, ctx: Option<&[f32]>, rng: &mut dyn RngCore) -> Result<Samples> {
        self.draw(n, ctx, rng, false)
    }

    fn sample_for_training(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut dyn RngCore,
    ) -> Result<Samples> {
        self.draw(n, ctx, rng, true)
    }

    fn log_density(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Vec<f64>> {
        Ok(self.pass(x, ctx, Direction::Forward, false)?.1)
    }

    fn log_density_for_training(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Evaluated> {
        let (_, log_q, tape) = self.pass(x, ctx, Direction::Forward, true)?;
        Ok(Evaluated {
            log_q,
            tape: tape.expect("recorded"),
        })
    }

    fn params(&self) -> &[f32] {
        &self.params
    }

    fn params_mut(&mut self) -> &mut [f32] {
        self.version = next_version();
        &mut self.params
    }

    fn backward(&self, tape: &Tape, weights: &[f32]) -> Result<Vec<f32>> {
        let chunks: &Vec<ChunkTape<L::Record>> = tape.records(self.version, weights.len())?;
        let mut grads = vec![0.0f32; self.params.len()];
        in_pool(|| L::backward_stack(self, chunks, weights, &mut grads));
        Ok(grads)
    }
}

impl<L: Layer> Bijection for Composed<L> {
    fn forward(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)> {
        let (z, log_det, _) = self.pass(x, ctx, Direction::Forward, false)?;
        Ok((z, log_det))
    }

    fn inverse(&self, z: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)> {
        let (x, log_q, _) = self.pass(z, ctx, Direction::Inverse, false)?;
        Ok((x, log_q.into_iter().map(|l| -l).collect()))
    }
}
