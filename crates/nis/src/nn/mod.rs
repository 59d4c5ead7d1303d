//! Neural-network pieces of the conditioner: the MLP (weights in one flat parameter vector) and
//! Adam. The one-blob encoding's kernel lives in [`crate::kernels::elementwise`].

pub mod adam;
pub mod mlp;

pub use adam::{Adam, AdamConfig};
pub use mlp::Mlp;
