//! Density estimation of real images with flows on [0, 1]^D (Müller et al. 2019, Sec. 5.1 and
//! Figure 4, after RealNVP, Dinh et al. 2016): `nis density`.
//!
//! An image with D pixels of L integer levels x ∈ {0..L−1}^D is *dequantised* to
//! y = (x + u)/L with u ~ U\[0,1)^D, a point of the unit hypercube, and a flow q on \[0,1\]^D with a
//! uniform latent is trained by maximum likelihood on such points. The discrete model
//! P(x) = ∫_{cell(x)} q(y) dy (a cell has volume L^−D) satisfies, by Jensen,
//! −log₂ P(x) ≤ E_u[−ln q((x + u)/L)]/ln 2 + D·log₂ L, so
//!
//! bits/dim = (E_u[−ln q(y)] + D ln L) / (D ln 2),
//!
//! exact change of variables inside q; the untrained flow (q ≡ 1) scores exactly log₂ L
//! (4.087 for the 17-level digits, 8 for MNIST). Estimates use one u per image.
//!
//! - [`model`]: the models: a coupling flow with MLP conditioners on the flattened image, and
//!   RealNVP's multi-scale flow with convolutional conditioners
//!   ([`nis::flow::multiscale`]).
//! - [`train`]: the training session with validation, checkpoints and resume.
//! - [`figure`]: sample grids and the latent-space interpolation of the paper's Figure 4.

pub mod figure;
pub mod model;
pub mod train;

pub use model::{Arch, ModelConfig};
pub use train::{DensityConfig, EpochStats, Session};

use rand::Rng;

use crate::data::Images;

/// Bits per dimension of a model with mean negative log-density `mean_nll` (nats, of the
/// dequantised points in \[0,1\]^D) on data with `levels` levels per pixel and `dim` pixels.
///
/// ```
/// // q ≡ 1 (the uniform flow) on 8-bit images: exactly 8 bits per pixel.
/// assert!((nis_paper::density::bits_per_dim(0.0, 784, 256) - 8.0).abs() < 1e-12);
/// ```
pub fn bits_per_dim(mean_nll: f64, dim: usize, levels: usize) -> f64 {
    let d = dim as f64;
    (mean_nll + d * (levels as f64).ln()) / (d * std::f64::consts::LN_2)
}

/// The images at `indices`, dequantised to y = (x + u)/L with u ~ U\[0,1) drawn from `rng`
/// (row-major, `indices.len() × D`). In f32, (x + u)/L can round up to 1 at most, which the
/// flows accept.
pub fn dequantize(images: &Images, indices: &[usize], rng: &mut impl Rng) -> Vec<f32> {
    let l = images.levels as f64;
    let mut out = Vec::with_capacity(indices.len() * images.dim());
    for &i in indices {
        for &x in images.image(i) {
            out.push(((x as f64 + rng.random::<f64>()) / l) as f32);
        }
    }
    out
}

/// The images at `indices` at the centres of their cells, y = (x + ½)/L: what the interpolation
/// figure maps to the latent space.
pub fn cell_centres(images: &Images, indices: &[usize]) -> Vec<f32> {
    let l = images.levels as f32;
    indices
        .iter()
        .flat_map(|&i| images.image(i).iter().map(move |&x| (x as f32 + 0.5) / l))
        .collect()
}

#[cfg(test)]
mod tests;
