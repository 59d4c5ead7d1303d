//! # nis-paper: the experiments of "Neural Importance Sampling"
//!
//! What the paper demonstrates, built on the `nis` library (Müller, McWilliams, Rousselle, Gross,
//! Novák 2019), kept apart from it so that a user of the integrator depends on no plotting or
//! image-decoding crate:
//!
//! - [`image`]: 2-D image targets (Figure 3): built-in patterns and PNG/JPEG images as densities,
//!   fitting a flow to them, the exact grid KL and variance, figures.
//! - [`data`]: real image sets (sklearn digits, MNIST) and their loaders.
//! - [`density`]: density estimation in bits/dim with coupling and multi-scale flows (Sec. 2.3,
//!   Figure 4): training sessions with checkpoints, sample grids and latent interpolation.
//! - [`error`]: the typed errors of these experiments.

pub mod bench;
pub mod data;
pub mod density;
pub mod error;
pub mod image;
pub mod report;

pub use error::{Error, Result};
