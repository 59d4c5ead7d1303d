//! The flow: a stack of coupling layers on [0, 1]^D with a uniform latent.
//!
//! Data x maps to latent z = h_L ∘ … ∘ h_1(x); the density is exact,
//! q(x) = Π_l |det ∂h_l/∂u| (Müller et al. 2019, Eq. 2), and sampling runs the layers backwards
//! from z ~ U[0,1]^D. Batches are cut into chunks of [`CHUNK_ROWS`] rows that run in parallel;
//! gradients are reduced in a fixed order, so results do not depend on the thread count.
//!
//! ```
//! use nis::flow::{Flow, FlowConfig};
//! use rand::SeedableRng;
//! let flow = Flow::new(FlowConfig::new(3)).unwrap();
//! let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
//! let s = flow.sample(1000, None, &mut rng).unwrap();
//! // A new flow is the identity: the uniform density, log q = 0.
//! assert!(s.log_q.iter().all(|l| l.abs() < 1e-6));
//! let log_q = flow.log_density(&s.x, None).unwrap();
//! assert!((log_q[0] - s.log_q[0]).abs() < 1e-6);
//! ```

pub mod config;
pub mod coupling;
pub mod mask;

pub use config::FlowConfig;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::kernels::CHUNK_ROWS;
use crate::nn::mlp::{Mlp, MlpTape};
use crate::spline::Spline;
use coupling::{Coupling, Direction};

/// A normalizing flow on the unit hypercube.
#[derive(Clone, Debug)]
pub struct Flow {
    config: FlowConfig,
    couplings: Vec<Coupling>,
    params: Vec<f32>,
    /// Bumped whenever the parameters may change, so a stale tape is detected.
    version: u64,
}

/// What a batch's forward or inverse pass recorded for a later backward pass.
#[derive(Clone, Debug)]
pub struct Tape {
    version: u64,
    rows: usize,
    chunks: Vec<ChunkTape>,
}

#[derive(Clone, Debug)]
struct ChunkTape {
    /// Per coupling layer: its input u (x side, rows × D) and its conditioner's activations.
    layers: Vec<(Vec<f32>, MlpTape)>,
}

/// Points drawn from the flow with their log-density, and optionally the tape of the pass that
/// made them (for the on-policy training step, which then needs no second network pass).
#[derive(Clone, Debug)]
pub struct Samples {
    /// Row-major points, `n × D`.
    pub x: Vec<f32>,
    /// ln q(x) of each point.
    pub log_q: Vec<f64>,
    pub tape: Option<Tape>,
}

impl Samples {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.log_q.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.log_q.is_empty()
    }
}

/// Log-densities of given points, with the tape of the forward pass.
#[derive(Clone, Debug)]
pub struct Evaluated {
    pub log_q: Vec<f64>,
    pub tape: Tape,
}

impl Flow {
    /// Builds a flow from its config, with weights initialised from `config.seed`: hidden layers
    /// at random and output layers at zero, so the new flow is the identity and q is uniform.
    pub fn new(config: FlowConfig) -> Result<Flow> {
        config.validate()?;
        let np = config.transform.param_count();
        let mut offset = 0;
        let mut couplings = Vec::new();
        for (a, b) in mask::partitions(config.dim, config.coupling_count()) {
            let mut dims = vec![a.len() * config.blob_bins + config.context_dim];
            dims.extend(std::iter::repeat_n(
                config.hidden_width,
                config.hidden_layers,
            ));
            dims.push(b.len() * np);
            let mlp = Mlp { dims };
            let len = mlp.param_count();
            couplings.push(Coupling { a, b, mlp, offset });
            offset += len;
        }
        let mut params = vec![0.0; offset];
        let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
        for c in &couplings {
            c.mlp.init(
                &mut params[c.offset..c.offset + c.mlp.param_count()],
                &mut rng,
            );
        }
        Ok(Flow {
            config,
            couplings,
            params,
            version: 0,
        })
    }

    /// The config this flow was built from.
    pub fn config(&self) -> &FlowConfig {
        &self.config
    }

    /// Dimension D.
    pub fn dim(&self) -> usize {
        self.config.dim
    }

    /// Number of trainable parameters.
    pub fn param_count(&self) -> usize {
        self.params.len()
    }

    /// All parameters, flat.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Mutable access to the parameters; invalidates tapes recorded before.
    pub fn params_mut(&mut self) -> &mut [f32] {
        self.version += 1;
        &mut self.params
    }

    /// The coupling layers, in data-to-latent order.
    pub fn couplings(&self) -> &[Coupling] {
        &self.couplings
    }

    /// Draws `n` points with their log-density.
    pub fn sample(&self, n: usize, ctx: Option<&[f32]>, rng: &mut impl Rng) -> Result<Samples> {
        self.sample_impl(n, ctx, rng, false)
    }

    /// Draws `n` points and keeps the tape for [`Flow::backward`] (the on-policy training step).
    pub fn sample_for_training(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut impl Rng,
    ) -> Result<Samples> {
        self.sample_impl(n, ctx, rng, true)
    }

    fn sample_impl(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut impl Rng,
        record: bool,
    ) -> Result<Samples> {
        self.check_context(n, ctx)?;
        // Uniform latents drawn sequentially: the stream does not depend on the thread count.
        let mut x: Vec<f32> = (0..n * self.dim()).map(|_| rng.random::<f32>()).collect();
        let (log_q, tape) = self.run(&mut x, ctx, Direction::Inverse, record);
        Ok(Samples { x, log_q, tape })
    }

    /// ln q(x) of each row of `x` (`n × D`, inside [0, 1]).
    pub fn log_density(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Vec<f64>> {
        Ok(self.forward(x, ctx)?.1)
    }

    /// ln q(x) with the tape for [`Flow::backward`] (training on given points).
    pub fn log_density_for_training(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Evaluated> {
        let n = self.check_points(x)?;
        self.check_context(n, ctx)?;
        let mut z = x.to_vec();
        let (log_q, tape) = self.run(&mut z, ctx, Direction::Forward, true);
        Ok(Evaluated {
            log_q,
            tape: tape.expect("recorded"),
        })
    }

    /// Data to latent: z = h(x) and ln|det ∂z/∂x| = ln q(x).
    pub fn forward(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)> {
        let n = self.check_points(x)?;
        self.check_context(n, ctx)?;
        let mut z = x.to_vec();
        let (log_det, _) = self.run(&mut z, ctx, Direction::Forward, false);
        Ok((z, log_det))
    }

    /// Latent to data: x = h⁻¹(z) and ln|det ∂x/∂z| = −ln q(x).
    pub fn inverse(&self, z: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)> {
        let n = self.check_points(z)?;
        self.check_context(n, ctx)?;
        let mut x = z.to_vec();
        let (log_q, _) = self.run(&mut x, ctx, Direction::Inverse, false);
        Ok((x, log_q.into_iter().map(|l| -l).collect()))
    }

    /// Runs all layers over `u` in place, chunk-parallel; returns ln q per row and the tape.
    fn run(
        &self,
        u: &mut [f32],
        ctx: Option<&[f32]>,
        direction: Direction,
        record: bool,
    ) -> (Vec<f64>, Option<Tape>) {
        let dim = self.dim();
        let rows = u.len() / dim;
        let cdim = self.config.context_dim;
        let mut log_q = vec![0.0f64; rows];
        let chunks: Vec<Option<ChunkTape>> = u
            .par_chunks_mut(CHUNK_ROWS * dim)
            .zip(log_q.par_chunks_mut(CHUNK_ROWS))
            .enumerate()
            .map(|(c, (u, log_q))| {
                let ctx = ctx.map(|ctx| {
                    let r0 = c * CHUNK_ROWS;
                    &ctx[r0 * cdim..(r0 + log_q.len()) * cdim]
                });
                let mut layers: Vec<(Vec<f32>, MlpTape)> = Vec::new();
                let order: Vec<usize> = match direction {
                    Direction::Forward => (0..self.couplings.len()).collect(),
                    Direction::Inverse => (0..self.couplings.len()).rev().collect(),
                };
                for l in order {
                    let input = (record && direction == Direction::Forward).then(|| u.to_vec());
                    let tape = self.couplings[l].apply(
                        &self.params,
                        self.config.transform,
                        self.config.blob_bins,
                        u,
                        dim,
                        ctx,
                        log_q,
                        direction,
                    );
                    if record {
                        // Inverse: after the layer, u holds the layer's input (x side).
                        let input = input.unwrap_or_else(|| u.to_vec());
                        layers.push((input, tape));
                    }
                }
                if direction == Direction::Inverse {
                    layers.reverse();
                }
                record.then_some(ChunkTape { layers })
            })
            .collect();
        let tape = record.then(|| Tape {
            version: self.version,
            rows,
            chunks: chunks.into_iter().map(|c| c.expect("recorded")).collect(),
        });
        (log_q, tape)
    }

    /// Gradient of L = −Σ_i w_i ln q(x_i; θ) with respect to all parameters, for the points
    /// whose pass recorded `tape`, with x held fixed (the score-function gradients of DESIGN.md).
    pub fn backward(&self, tape: &Tape, weights: &[f32]) -> Result<Vec<f32>> {
        check_tape(self.version, tape.version, tape.rows, weights.len())?;
        let dim = self.dim();
        let blob = self.config.blob_bins;
        let transform = self.config.transform;
        let g_log_det: Vec<f32> = weights.iter().map(|w| -w).collect();
        let mut grads = vec![0.0f32; self.params.len()];
        // ∂L/∂u per chunk; the latent's density is constant, so it starts at zero.
        let mut g_u: Vec<Vec<f32>> = tape
            .chunks
            .iter()
            .map(|c| vec![0.0; c.layers[0].0.len()])
            .collect();
        for (l, coupling) in self.couplings.iter().enumerate().rev() {
            let g_out: Vec<Vec<f32>> = tape
                .chunks
                .par_iter()
                .zip(g_u.par_iter_mut())
                .enumerate()
                .map(|(c, (chunk, g_u))| {
                    let (input, mlp_tape) = &chunk.layers[l];
                    let g_ld = &g_log_det[c * CHUNK_ROWS..c * CHUNK_ROWS + mlp_tape.rows];
                    coupling.spline_backward(transform, mlp_tape, input, dim, g_u, g_ld)
                })
                .collect();
            let tapes: Vec<&MlpTape> = tape.chunks.iter().map(|c| &c.layers[l].1).collect();
            let params = coupling.params(&self.params);
            let range = coupling.offset..coupling.offset + coupling.mlp.param_count();
            // The first layer's input is the fixed x: no gradient needed below it.
            let g_enc = coupling.mlp.backward(
                params,
                &tapes,
                g_out,
                &mut grads[range],
                l > 0 && !coupling.a.is_empty(),
            );
            if let Some(g_enc) = g_enc {
                tape.chunks
                    .par_iter()
                    .zip(g_u.par_iter_mut())
                    .zip(g_enc.par_iter())
                    .for_each(|((chunk, g_u), g_enc)| {
                        let (input, mlp_tape) = &chunk.layers[l];
                        coupling.encoding_backward(blob, mlp_tape, input, dim, g_enc, g_u);
                    });
            }
        }
        Ok(grads)
    }

    /// Checks that `x` holds whole points inside [0, 1]; returns their number.
    pub fn check_points(&self, x: &[f32]) -> Result<usize> {
        check_points(
            x,
            self.dim(),
            "points (length must be a multiple of the dimension)",
        )
    }

    fn check_context(&self, n: usize, ctx: Option<&[f32]>) -> Result<()> {
        let cdim = self.config.context_dim;
        let got = ctx.map_or(0, <[f32]>::len);
        if got != n * cdim || (cdim > 0 && ctx.is_none()) {
            return Err(Error::Dimension {
                what: "context features",
                expected: n * cdim,
                got,
            });
        }
        if let Some(i) = ctx.and_then(|c| c.iter().position(|v| !v.is_finite())) {
            return Err(Error::NonFinite {
                what: "context feature",
                index: i / cdim,
                value: ctx.unwrap()[i] as f64,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests;

/// Checks that `x` holds whole rows of `dim` values inside [0, 1] (`what` names the rows in the
/// error); returns the number of rows.
pub(crate) fn check_points(x: &[f32], dim: usize, what: &'static str) -> Result<usize> {
    if x.len() % dim != 0 {
        return Err(Error::Dimension {
            what,
            expected: dim * (x.len() / dim + 1),
            got: x.len(),
        });
    }
    if let Some(i) = x.iter().position(|v| !(0.0..=1.0).contains(v)) {
        return Err(Error::OutOfDomain {
            index: i / dim,
            coord: i % dim,
            value: x[i] as f64,
        });
    }
    Ok(x.len() / dim)
}

/// A backward pass needs a tape recorded with the current parameters (`version`) and one
/// weight per recorded row.
pub(crate) fn check_tape(
    version: u64,
    tape_version: u64,
    rows: usize,
    weights: usize,
) -> Result<()> {
    if tape_version != version {
        return Err(Error::Config(
            "the tape was recorded before the parameters changed".into(),
        ));
    }
    if weights != rows {
        return Err(Error::Dimension {
            what: "sample weights",
            expected: rows,
            got: weights,
        });
    }
    Ok(())
}
