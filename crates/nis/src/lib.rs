//! # nis: neural importance sampling
//!
//! Monte Carlo integration on the unit hypercube whose sampling density is a normalizing flow
//! learned from the integrand itself (Müller, McWilliams, Rousselle, Gross, Novák 2019, "Neural
//! Importance Sampling"; workshop version "Monte Carlo Integration with Normalizing Flows").
//!
//! - [`spline`]: the 1-D coupling transforms (affine, piecewise-linear, piecewise-quadratic,
//!   rational-quadratic).
//! - [`flow`]: coupling layers, masks, the flow and its config.
//! - [`loss`] and [`train`]: sample weights of the KL, χ² and NLL gradients; Adam steps.
//! - [`io`]: saving and loading flows (config JSON + safetensors, atomic writes).
//! - [`kernels`] and [`nn`]: the fused CPU kernels (dense layers, 3×3 convolutions), the MLP and
//!   Adam.
//! - [`data`] and [`density`]: real image sets (sklearn digits, MNIST) and density estimation in
//!   bits/dim with coupling and multi-scale flows (the paper's Sec. 5.1).

pub mod data;
pub mod density;
pub mod error;
pub mod flow;
pub mod image;
pub mod integrands;
pub mod integrate;
pub mod io;
pub mod kernels;
pub mod loss;
pub mod nn;
pub mod train;
pub mod transform;

pub use error::{Error, Result};
pub use flow::{Flow, FlowConfig};
pub use transform::{Transform, TransformKind};

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
struct ReadmeDoctests;
