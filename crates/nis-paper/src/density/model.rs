//! The models of `nis density`: a [`ModelConfig`] builds one as a `Box<dyn Bijection>`, so the
//! training session, the figures and the checkpoints see every architecture through the flows'
//! one surface ([`Bijection`]: log-density with a tape, the parameter gradient of −Σ w ln q, and
//! both directions of the map).
//!
//! - [`Arch::Mlp`]: the coupling flow of [`nis::flow`] on the flattened image — binary masks on
//!   the pixel index, one-blob encoded MLP conditioners (Müller et al. 2019, Sec. 4).
//! - [`Arch::MultiScale`]: RealNVP's multi-scale architecture with convolutional residual
//!   conditioners ([`nis::flow::multiscale`]).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use nis::flow::multiscale::{MultiScale, MultiScaleConfig};
use nis::flow::{Bijection, Flow, FlowConfig};
use nis::transform::TransformKind;

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
    pub transform: TransformKind,
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

    /// A new model of this shape: the identity map, q ≡ 1.
    pub fn build(&self) -> Result<Box<dyn Bijection>> {
        self.validate()?;
        Ok(match self.arch {
            Arch::Mlp => Box::new(Flow::new(self.flow_config())?),
            Arch::MultiScale => Box::new(MultiScale::new(self.multiscale_config())?),
        })
    }

    /// Rejects shapes that describe no valid model or one too large to allocate (the flows'
    /// own bounds), without building it.
    pub fn validate(&self) -> Result<()> {
        if self.width.checked_mul(self.height).is_none() {
            return Err(Error::Config(format!(
                "images of {}×{} pixels are implausible",
                self.width, self.height
            )));
        }
        match self.arch {
            Arch::Mlp => self.flow_config().validate()?,
            Arch::MultiScale => self.multiscale_config().validate()?,
        }
        Ok(())
    }

    /// The number of parameters of the model this shape builds, without building it (a
    /// checkpoint's claim is checked against its file with it).
    pub fn param_count(&self) -> Result<usize> {
        self.validate()?;
        Ok(match self.arch {
            Arch::Mlp => self
                .flow_config()
                .param_count()
                .expect("a validated flow's parameters are counted"),
            Arch::MultiScale => self.multiscale_config().param_count(),
        })
    }

    fn multiscale_config(&self) -> MultiScaleConfig {
        MultiScaleConfig {
            width: self.width,
            height: self.height,
            transform: self.transform,
            scales: self.scales,
            features: self.features,
            blocks: self.blocks,
            seed: self.seed,
        }
    }

    /// MLP: the number of coupling layers the model has (`couplings`, or by default one pass of
    /// all binary masks and their complements, 2⌈log₂ D⌉).
    pub fn coupling_count(&self) -> usize {
        self.flow_config().coupling_count()
    }

    fn flow_config(&self) -> FlowConfig {
        FlowConfig {
            dim: self.width.saturating_mul(self.height),
            transform: self.transform,
            couplings: self.couplings,
            hidden_layers: self.hidden_layers,
            hidden_width: self.hidden_width,
            blob_bins: self.blob_bins,
            context_dim: 0,
            seed: self.seed,
            masks: nis::flow::mask::Masks::Binary,
        }
    }
}
