//! Neural-network pieces of the conditioners: the MLP (weights in one flat parameter vector), the
//! residual convolutional network of the multi-scale flow, the one-blob input encoding, Adam, and
//! a moving average of the weights.

pub mod adam;
pub mod average;
pub mod conv_net;
pub mod encoding;
pub mod mlp;

pub use adam::{Adam, AdamConfig};
pub use average::ParamAverage;
pub use mlp::Mlp;
