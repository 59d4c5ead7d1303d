//! A conditioned flow's per-context cache, for many queries at one context (Müller et al. 2019,
//! "Neural Importance Sampling", §5: a path guide asks its flow, conditioned on a path vertex,
//! for a sample, the density of another direction and a selection probability at every vertex).
//!
//! The first dense layer of a coupling's conditioner splits along its input,
//! `W·[enc(x_A); c] + b = W_A·enc(x_A) + (W_c·c + b)`, and the second term depends on the
//! context alone. [`ContextLayers`] holds `W_c` and `b` of every coupling side by side, and of
//! any other network whose input is the same context (a guide's selection network), so one
//! matrix product per batch of contexts gives their share of every first layer, a
//! [`ContextCache`]. A query at a cached context ([`Flow::log_density_cached`],
//! [`Flow::inverse_cached`]) then adds only `W_A·enc(x_A)` and runs each conditioner from its
//! second layer on, through the coupling layers' own code and the flow's one layer loop
//! (`Composed::run_chunks`). Its result is the flow's own up to f32 rounding, as the first
//! layer's sums run in another order.
//!
//! ```
//! use nis::flow::context::ContextLayers;
//! use nis::flow::{Density, Flow, FlowConfig};
//! let flow = Flow::new(FlowConfig { context_dim: 3, ..FlowConfig::new(2) }).unwrap();
//! let layers = ContextLayers::new(&flow, &[]).unwrap();
//! // Two contexts, cached once; three points, each at one of them.
//! let contexts = [0.1f32, 0.2, 0.3, 0.7, 0.8, 0.9];
//! let mut cache = Default::default();
//! layers.cache(2, |rows, out| out.copy_from_slice(&contexts[rows.start * 3..rows.end * 3]), &mut cache);
//! let log_q = flow.log_density_cached(&[0.5, 0.5, 0.1, 0.9, 0.3, 0.3], &cache, &[0, 1, 1]).unwrap();
//! assert_eq!(log_q.len(), 3);
//! ```

use std::ops::Range;

use rayon::prelude::*;

use super::composed::{Composed, Direction};
use super::coupling::Coupling;
use super::{Density, Flow};
use crate::error::{Error, Result};
use crate::kernels::dense::{self, Shape};
use crate::kernels::{elementwise, in_pool, CHUNK_ROWS};
use crate::nn::mlp::{Mlp, MlpTape};

/// The context's columns of the first layer of every coupling's conditioner of a flow, then of
/// other networks fed the same context, side by side (`context_dim × width`), with their
/// biases. Built from the flow's parameters as they are; build it anew when they change.
#[derive(Clone, Debug, Default)]
pub struct ContextLayers {
    context_dim: usize,
    weights: Vec<f32>,
    bias: Vec<f32>,
    /// Where each network's first layer starts in a cache row: the couplings', then the others'.
    offsets: Vec<usize>,
    couplings: usize,
    /// The flow's parameter version the weights were taken from.
    version: u64,
}

/// The share of the context in every first layer of [`ContextLayers`] at a batch of contexts,
/// before the activation: one row of `width` numbers per context.
#[derive(Clone, Debug, Default)]
pub struct ContextCache {
    rows: Vec<f32>,
    width: usize,
    offsets: Vec<usize>,
    couplings: usize,
    version: u64,
}

impl ContextLayers {
    /// The context's share of the first layers of `flow`'s couplings and of `others` (each an
    /// MLP with its parameters, whose whole input is the flow's context).
    pub fn new(flow: &Flow, others: &[(&Mlp, &[f32])]) -> Result<ContextLayers> {
        let cdim = flow.context_dim;
        if cdim == 0 {
            return Err(Error::Config(
                "a context cache needs a conditioned flow".into(),
            ));
        }
        let mut parts: Vec<(&[f32], &[f32])> = flow
            .layers
            .iter()
            .map(|c| c.context_share(&flow.params, cdim))
            .collect();
        for (mlp, params) in others {
            if mlp.dims[0] != cdim || params.len() != mlp.param_count() {
                return Err(Error::Dimension {
                    what: "inputs of a network sharing the flow's context",
                    expected: cdim,
                    got: mlp.dims[0],
                });
            }
            parts.push(mlp.layer_params(params, 0));
        }
        let mut offsets = Vec::with_capacity(parts.len());
        let mut width = 0;
        for (_, b) in &parts {
            offsets.push(width);
            width += b.len();
        }
        let mut weights = vec![0.0; cdim * width];
        let mut bias = Vec::with_capacity(width);
        for ((w, b), &off) in parts.iter().zip(&offsets) {
            let o = b.len();
            for (r, row) in w.chunks_exact(o).enumerate() {
                weights[r * width + off..r * width + off + o].copy_from_slice(row);
            }
            bias.extend_from_slice(b);
        }
        Ok(ContextLayers {
            context_dim: cdim,
            weights,
            bias,
            offsets,
            couplings: flow.layers.len(),
            version: flow.version(),
        })
    }

    /// Numbers per context in a cache row.
    pub fn width(&self) -> usize {
        self.bias.len()
    }

    /// Fills `cache` (overwriting it) for `contexts` contexts, in parallel chunks of rows:
    /// `encode(rows, out)` writes the context features of the contexts `rows` into `out`
    /// (`rows.len() × context_dim`, as the flow's context).
    pub fn cache(
        &self,
        contexts: usize,
        encode: impl Fn(Range<usize>, &mut [f32]) + Sync,
        cache: &mut ContextCache,
    ) {
        let (cdim, width) = (self.context_dim, self.width());
        cache.rows.clear();
        cache.rows.resize(contexts * width, 0.0);
        cache.width = width;
        cache.offsets.clone_from(&self.offsets);
        cache.couplings = self.couplings;
        cache.version = self.version;
        if width == 0 {
            return;
        }
        cache
            .rows
            .par_chunks_mut(CHUNK_ROWS * width)
            .enumerate()
            .for_each(|(c, out)| {
                let n = out.len() / width;
                let mut features = vec![0.0f32; n * cdim];
                encode(c * CHUNK_ROWS..c * CHUNK_ROWS + n, &mut features);
                dense::forward(
                    &features,
                    &self.weights,
                    &self.bias,
                    out,
                    Shape::rows(n, cdim, width),
                );
            });
    }
}

impl ContextCache {
    /// Contexts in the cache.
    pub fn len(&self) -> usize {
        self.rows.len().checked_div(self.width).unwrap_or(0)
    }

    /// Whether the cache holds no context.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Network `k`'s first-layer share (`k` counts the couplings, then the others) at the
    /// contexts `contexts`, `contexts.len() × out` row-major.
    fn gather(&self, k: usize, out: usize, contexts: &[usize]) -> Vec<f32> {
        let off = self.offsets[k];
        let mut first = vec![0.0f32; contexts.len() * out];
        for (row, &v) in first.chunks_exact_mut(out.max(1)).zip(contexts) {
            let at = v * self.width + off;
            row.copy_from_slice(&self.rows[at..at + out]);
        }
        first
    }

    /// The outputs of `others[k]` of [`ContextLayers::new`] (`mlp` with `params`) at every
    /// cached context, from its cached first layer on, in the MLP's output layout chunk by
    /// chunk (row-major for [`crate::kernels::dense::Layout::Rows`]).
    pub fn other_outputs(&self, k: usize, mlp: &Mlp, params: &[f32]) -> Result<Vec<f32>> {
        let index = self.couplings + k;
        if index >= self.offsets.len() || params.len() != mlp.param_count() {
            return Err(Error::Config(format!(
                "the cache holds no network {k} besides the flow's couplings, or not of that shape"
            )));
        }
        let h = mlp.dims[1];
        let all: Vec<usize> = (0..self.len()).collect();
        let outputs: Vec<Vec<f32>> = in_pool(|| {
            all.par_chunks(CHUNK_ROWS)
                .map(|rows| {
                    let mut acts = vec![Vec::new(); mlp.dims.len()];
                    acts[1] = self.gather(index, h, rows);
                    let mut tape = MlpTape {
                        rows: rows.len(),
                        acts,
                    };
                    if mlp.layers() > 1 {
                        elementwise::relu(&mut tape.acts[1]);
                    }
                    mlp.forward_from(params, &mut tape, 1);
                    tape.acts.pop().expect("an MLP has an output layer")
                })
                .collect()
        });
        Ok(outputs.concat())
    }
}

impl Composed<Coupling> {
    /// The unconditioned flow this conditioned one is at the context `ctx` (its `context_dim`
    /// features): every conditioner's first layer keeps its rows for the encoded x_A and takes
    /// the context's share W_c·c into its bias, so both give the same map and density up to f32
    /// rounding. For a context sampled many times, with every tool of an unconditioned flow (a
    /// channel of a shared multi-channel flow).
    pub fn at_context(&self, ctx: &[f32]) -> Result<Flow> {
        let cdim = self.context_dim;
        if cdim == 0 || ctx.len() != cdim {
            return Err(Error::Dimension {
                what: "context features of a conditioned flow",
                expected: cdim,
                got: ctx.len(),
            });
        }
        let mut config = self.config().clone();
        config.context_dim = 0;
        let mut out = Flow::new(config)?;
        let mut params = Vec::with_capacity(out.params.len());
        for c in &self.layers {
            let mlp = c.mlp();
            let src = c.params(&self.params);
            for j in 0..mlp.layers() {
                let (w, b) = mlp.layer_params(src, j);
                if j > 0 {
                    params.extend_from_slice(w);
                    params.extend_from_slice(b);
                    continue;
                }
                let o = b.len();
                let keep = (mlp.dims[0] - cdim) * o;
                params.extend_from_slice(&w[..keep]);
                let mut bias = b.to_vec();
                for (row, &v) in w[keep..].chunks_exact(o).zip(ctx) {
                    if v != 0.0 {
                        bias.iter_mut().zip(row).for_each(|(b, w)| *b += v * w);
                    }
                }
                params.extend_from_slice(&bias);
            }
        }
        debug_assert_eq!(params.len(), out.params.len());
        out.params_mut().copy_from_slice(&params);
        Ok(out)
    }

    /// ln q of the points `x` (`dim` values each), point `i` at the cached context
    /// `contexts[i]`: [`super::Density::log_density`] from a [`ContextCache`].
    pub fn log_density_cached(
        &self,
        x: &[f32],
        cache: &ContextCache,
        contexts: &[usize],
    ) -> Result<Vec<f64>> {
        let mut u = x.to_vec();
        self.run_cached(&mut u, cache, contexts, Direction::Forward)
    }

    /// The points of the latents `z` and ln|det ∂x/∂z|, point `i` at the cached context
    /// `contexts[i]`: [`super::Bijection::inverse`] from a [`ContextCache`].
    pub fn inverse_cached(
        &self,
        z: &[f32],
        cache: &ContextCache,
        contexts: &[usize],
    ) -> Result<(Vec<f32>, Vec<f64>)> {
        let mut x = z.to_vec();
        let log_q = self.run_cached(&mut x, cache, contexts, Direction::Inverse)?;
        Ok((x, log_q.into_iter().map(|l| -l).collect()))
    }

    /// Runs every coupling over `u` in place in `direction`, each conditioner started from the
    /// cache; returns ln q per row of the data-side points.
    fn run_cached(
        &self,
        u: &mut [f32],
        cache: &ContextCache,
        contexts: &[usize],
        direction: Direction,
    ) -> Result<Vec<f64>> {
        if cache.version != self.version() || cache.couplings != self.layers.len() {
            return Err(Error::Config(
                "the context cache was built before the parameters changed, or for another flow"
                    .into(),
            ));
        }
        if u.len() != contexts.len() * self.dim {
            return Err(Error::Dimension {
                what: "points at cached contexts",
                expected: contexts.len() * self.dim,
                got: u.len(),
            });
        }
        if let Some(&bad) = contexts.iter().find(|&&v| v >= cache.len()) {
            return Err(Error::Dimension {
                what: "index of a cached context",
                expected: cache.len(),
                got: bad,
            });
        }
        let (log_q, _) = self.run_chunks(u, CHUNK_ROWS, direction, false, |c, l, rows| {
            let coupling = &self.layers[l];
            let at = &contexts[c * CHUNK_ROWS..c * CHUNK_ROWS + rows.log_det.len()];
            let first = cache.gather(l, coupling.mlp().dims[1], at);
            coupling.apply_cached(&self.params, first, rows, direction)
        });
        Ok(log_q)
    }
}
