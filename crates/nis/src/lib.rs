//! # nis: neural importance sampling
//!
//! Monte Carlo integration on the unit hypercube whose sampling density is a normalizing flow
//! learned from the integrand itself (Müller, McWilliams, Rousselle, Gross, Novák 2019, "Neural
//! Importance Sampling"; workshop version "Monte Carlo Integration with Normalizing Flows").
//!
//! The pipeline, module by module (ARCHITECTURE.md draws it):
//!
//! - [`transform`]: the 1-D coupling transforms (affine, piecewise-linear, piecewise-quadratic,
//!   rational-quadratic) behind one trait, [`Transform`], chosen by a [`TransformKind`].
//! - [`flow`]: the [`flow::Density`] and [`flow::Bijection`] traits; coupling layers (mask,
//!   one-blob encoding, conditioner, transform) composed into the coupling flow [`Flow`], RealNVP's
//!   multi-scale flow, and the defensive mixture with the uniform density.
//! - [`nn`]: the conditioners (MLP, residual 3×3 convolutions), the one-blob encoding, Adam.
//! - [`kernels`]: the fused CPU kernels (gemm-based dense layers, 3×3 convolutions, SIMD loops).
//! - [`loss`]: sample weights of the KL, χ² and NLL gradients; [`train`]: the training step and
//!   the trainer that learns from Monte Carlo samples.
//! - [`integrate`]: the integrand interface and the integrators (NIS, VEGAS+, plain MC), their
//!   estimates and error bars, unweighted samples.
//! - [`integrands`]: the built-in test suite with exact values.
//! - [`channels`]: channels of multi-channel integration (maps of the unit cube with their
//!   densities, priors, checks) and multi-channel examples with exact values.
//! - [`io`]: model files (config JSON + safetensors) and atomic writes.
//! - [`comm`]: the collective operations of data-parallel runs over MPI ranks (feature `mpi`),
//!   with a single-process implementation that every run uses by default.
//! - [`error`]: the typed errors of all of the above.
//!
//! The paper's experiments (2-D image targets, density estimation on real images, figures,
//! benchmarks) live in the crate `nis-paper`; the path tracer and path guiding in `nis-render`.

pub mod channels;
pub mod comm;
pub mod error;
pub mod flow;
pub mod integrands;
pub mod integrate;
pub mod io;
pub mod kernels;
pub mod loss;
pub mod nn;
pub mod train;
pub mod transform;

pub use error::{Error, Result};
pub use flow::{Bijection, Density, Flow, FlowConfig};
pub use transform::{Transform, TransformKind};

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
struct ReadmeDoctests;

/// The guide's Rust examples (docs/guide/), compiled and run as doctests: one item per page
/// with Rust blocks. Blocks that are not Rust are marked with their language (`sh`, `text`, …).
#[cfg(doctest)]
mod guide {
    #[doc = include_str!("../../../docs/guide/02-integrate.md")]
    struct Integrate;
    #[doc = include_str!("../../../docs/guide/03-results.md")]
    struct Results;
    #[doc = include_str!("../../../docs/guide/04-settings.md")]
    struct Settings;
    #[doc = include_str!("../../../docs/guide/05-save-load-sample.md")]
    struct SaveLoadSample;
    #[doc = include_str!("../../../docs/guide/06-mpi.md")]
    struct Mpi;
    #[doc = include_str!("../../../docs/guide/08-file-formats.md")]
    struct FileFormats;
}
