//! Flows on [0, 1]^D with a uniform latent, and the traits they share.
//!
//! Data x maps to latent z = h_L ∘ … ∘ h_1(x); the density is exact,
//! q(x) = Π_l |det ∂h_l/∂u| (Müller et al. 2019, Eq. 2), and sampling runs the layers backwards
//! from z ~ U\[0,1\]^D.
//!
//! - [`Density`] and [`Bijection`]: what every flow offers (sample, log-density with a training
//!   tape, parameters, backward; both directions with log-det).
//! - [`composed`]: the one composition loop, [`Composed`], generic over the [`Layer`].
//! - [`coupling`], [`mask`], [`config`]: the coupling layer with its mask, one-blob encoding,
//!   MLP conditioner and transform kind; [`Flow`] is a stack of them built from a [`FlowConfig`].
//! - [`context`]: the per-context cache of a conditioned flow, for many queries at one context.
//! - [`multiscale`]: RealNVP's multi-scale flow with convolutional conditioners, for images.
//! - [`mixture`]: the defensive mixture of a flow with the uniform density.
//!
//! ```
//! use nis::flow::{Density, Flow, FlowConfig};
//! use rand::SeedableRng;
//! let flow = Flow::new(FlowConfig::new(3)).unwrap();
//! let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
//! let s = flow.sample(1000, None, &mut rng).unwrap();
//! // A new flow is the identity: the uniform density, log q = 0.
//! assert!(s.log_q.iter().all(|l| l.abs() < 1e-6));
//! ```

pub mod composed;
pub mod config;
pub mod context;
pub mod coupling;
mod density;
pub mod mask;
pub mod mixture;
pub mod multiscale;

pub use composed::{Composed, Direction, Layer};
pub use config::FlowConfig;
pub use coupling::Coupling;
pub use density::{
    check_context, check_points, next_version, Bijection, Density, Evaluated, Samples, Tape,
};

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use crate::error::Result;
use crate::kernels::dense::Layout;
use crate::nn::encoding::OneBlob;
use crate::nn::mlp::Mlp;
use crate::transform::Transform;

/// `len` latent numbers uniform on [0, 1), drawn one after the other from `rng`: how every
/// [`Composed`] flow starts sampling, so that a copy of the stream taken before a draw gives
/// back the latents of the points drawn (and the stream does not depend on the thread count).
pub fn uniform_latents(len: usize, rng: &mut dyn rand::RngCore) -> Vec<f32> {
    use rand::Rng;
    (0..len).map(|_| rng.random::<f32>()).collect()
}

/// The coupling flow on the unit hypercube: a [`Composed`] stack of [`Coupling`] layers with
/// MLP conditioners.
pub type Flow = Composed<Coupling>;

impl Flow {
    /// Builds a flow from its config, with weights initialised from `config.seed`: hidden layers
    /// at random and output layers at zero, so the new flow is the identity and q is uniform.
    pub fn new(config: FlowConfig) -> Result<Flow> {
        config.validate()?;
        let np = config.transform.param_count();
        let encoding = OneBlob {
            bins: config.blob_bins,
        };
        let mut offset = 0;
        let mut couplings = Vec::new();
        for (a, b) in mask::partitions(config.dim, config.coupling_count(), config.masks) {
            let mut dims = vec![encoding.width(a.len()) + config.context_dim];
            dims.extend(std::iter::repeat_n(
                config.hidden_width,
                config.hidden_layers,
            ));
            dims.push(b.len() * np);
            // Feature-major output: the transforms' kernels read each parameter across rows.
            let mlp = Mlp {
                dims,
                output: Layout::Features,
            };
            let len = mlp.param_count();
            couplings.push(Coupling::new(a, b, encoding, mlp, config.transform, offset));
            offset += len;
        }
        let mut params = vec![0.0; offset];
        let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
        for c in &couplings {
            c.mlp().init(&mut params[c.param_range()], &mut rng);
        }
        let (dim, context_dim) = (config.dim, config.context_dim);
        Ok(Composed::from_parts(
            config,
            couplings,
            params,
            dim,
            context_dim,
        ))
    }
}

#[cfg(test)]
pub(crate) mod tests;
