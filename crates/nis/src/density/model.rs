//! The models of `nis density`, behind one small surface ([`Model`]): log-density with a tape,
//! the parameter gradient of −Σ w ln q, and both directions of the map.
//!
//! - [`Arch::Mlp`]: the coupling flow of [`crate::flow`] on the flattened image — binary masks on
//!   the pixel index, one-blob encoded MLP conditioners (Müller et al. 2019, Sec. 4).
//! - [`Arch::MultiScale`]: RealNVP's multi-scale architecture with convolutional residual
//!   conditioners ([`super::multiscale`]).

use serde::{Deserialize, Serialize};

use super::multiscale::{MsTape, MultiScale};
use crate::error::{Error, Result};
use crate::flow::{self, Flow, FlowConfig};
use crate::spline::Transform;

/// Which network shape a model has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Arch {
    /// Coupling flow with MLP conditioners on the flattened image.
    Mlp,
    /// RealNVP's multi-scale flow: checkerboard and channel masks, squeezes, factoring out,
    /// convolutional residual conditioners.
    MultiScale,
}

impl std::str::FromStr for Arch {
    type Err = Error;
    fn from_str(s: &str) -> Result<Arch> {
        match s {
            "mlp" => Ok(Arch::Mlp),
            "multiscale" | "multi_scale" => Ok(Arch::MultiScale),
            _ => Err(Error::Config(format!(
                "unknown architecture {s:?} (mlp, multiscale)"
            ))),
        }
    }
}

/// A model's shape, weights aside; round-trips through JSON (it is stored in checkpoints).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    pub arch: Arch,
    /// Image width and height in pixels (D = width·height).
    pub width: usize,
    pub height: usize,
    /// The coupling transform (the paper: piecewise-quadratic with K = 4; the baseline: affine).
    pub transform: Transform,
    /// MLP: coupling layers (0: one pass of all binary masks, 2⌈log₂ D⌉).
    pub couplings: usize,
    /// MLP: hidden layers and width of every conditioner.
    pub hidden_layers: usize,
    pub hidden_width: usize,
    /// MLP: one-blob bins per conditioner input.
    pub blob_bins: usize,
    /// Multi-scale: number of squeezes (each followed by factoring out half of the channels).
    #[serde(default)]
    pub scales: usize,
    /// Multi-scale: channels and residual blocks of every convolutional conditioner.
    #[serde(default)]
    pub features: usize,
    #[serde(default)]
    pub blocks: usize,
    /// Seed of the weight initialisation.
    pub seed: u64,
}

impl ModelConfig {
    /// Pixels per image, D.
    pub fn dim(&self) -> usize {
        self.width * self.height
    }

    /// A short label for tables, e.g. `mlp pq4`.
    pub fn label(&self) -> String {
        let arch = match self.arch {
            Arch::Mlp => "mlp",
            Arch::MultiScale => "multiscale",
        };
        format!("{arch} {}", self.transform.label())
    }

    fn flow_config(&self) -> FlowConfig {
        FlowConfig {
            dim: self.dim(),
            transform: self.transform,
            couplings: self.couplings,
            hidden_layers: self.hidden_layers,
            hidden_width: self.hidden_width,
            blob_bins: self.blob_bins,
            context_dim: 0,
            seed: self.seed,
        }
    }
}

/// A trainable density on [0, 1]^D.
#[derive(Clone, Debug)]
pub enum Model {
    Mlp(Flow),
    MultiScale(MultiScale),
}

/// What [`Model::log_density_for_training`] recorded for [`Model::backward`].
#[derive(Clone, Debug)]
pub enum ModelTape {
    Mlp(flow::Tape),
    MultiScale(MsTape),
}

impl Model {
    /// A new model: the identity map, q ≡ 1.
    pub fn new(config: &ModelConfig) -> Result<Model> {
        match config.arch {
            Arch::Mlp => Ok(Model::Mlp(Flow::new(config.flow_config())?)),
            Arch::MultiScale => Ok(Model::MultiScale(MultiScale::new(
                config.width,
                config.height,
                config.transform,
                config.scales,
                config.features,
                config.blocks,
                config.seed,
            )?)),
        }
    }

    /// Number of trainable parameters.
    pub fn param_count(&self) -> usize {
        self.params().len()
    }

    /// All parameters, flat.
    pub fn params(&self) -> &[f32] {
        match self {
            Model::Mlp(f) => f.params(),
            Model::MultiScale(f) => f.params(),
        }
    }

    /// Mutable parameters (invalidates tapes).
    pub fn params_mut(&mut self) -> &mut [f32] {
        match self {
            Model::Mlp(f) => f.params_mut(),
            Model::MultiScale(f) => f.params_mut(),
        }
    }

    /// ln q of each row of `x` (`n × D` in [0, 1]).
    pub fn log_density(&self, x: &[f32]) -> Result<Vec<f64>> {
        match self {
            Model::Mlp(f) => f.log_density(x, None),
            Model::MultiScale(f) => f.log_density(x),
        }
    }

    /// ln q with the tape for [`Model::backward`].
    pub fn log_density_for_training(&self, x: &[f32]) -> Result<(Vec<f64>, ModelTape)> {
        match self {
            Model::Mlp(f) => {
                let e = f.log_density_for_training(x, None)?;
                Ok((e.log_q, ModelTape::Mlp(e.tape)))
            }
            Model::MultiScale(f) => {
                let (log_q, tape) = f.log_density_for_training(x)?;
                Ok((log_q, ModelTape::MultiScale(tape)))
            }
        }
    }

    /// ∂/∂θ of −Σ_i w_i ln q(x_i; θ) for the points of `tape`.
    pub fn backward(&self, tape: &ModelTape, weights: &[f32]) -> Result<Vec<f32>> {
        match (self, tape) {
            (Model::Mlp(f), ModelTape::Mlp(t)) => f.backward(t, weights),
            (Model::MultiScale(f), ModelTape::MultiScale(t)) => f.backward(t, weights),
            _ => Err(Error::Config("the tape belongs to another model".into())),
        }
    }

    /// Data to latent: z and ln q(x).
    pub fn forward(&self, x: &[f32]) -> Result<(Vec<f32>, Vec<f64>)> {
        match self {
            Model::Mlp(f) => f.forward(x, None),
            Model::MultiScale(f) => f.forward(x),
        }
    }

    /// Latent to data: x = h⁻¹(z).
    pub fn inverse(&self, z: &[f32]) -> Result<Vec<f32>> {
        match self {
            Model::Mlp(f) => Ok(f.inverse(z, None)?.0),
            Model::MultiScale(f) => f.inverse(z),
        }
    }
}
