//! The description of a flow as data: a `FlowConfig` round-trips through JSON and builds a
//! [`crate::flow::Flow`].

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::flow::mask;
use crate::transform::TransformKind;

/// Largest dimension a flow accepts (a sanity bound against corrupt configs).
pub const MAX_DIM: usize = 4096;

/// Everything needed to build a flow, weights aside.
///
/// ```
/// use nis::flow::FlowConfig;
/// let config = FlowConfig::new(4);
/// let json = serde_json::to_string(&config).unwrap();
/// assert_eq!(serde_json::from_str::<FlowConfig>(&json).unwrap(), config);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FlowConfig {
    /// Dimension D of the unit hypercube.
    pub dim: usize,
    /// The coupling transform and its bins.
    pub transform: TransformKind,
    /// Number of coupling layers (0: the default, one pass of all masks).
    pub couplings: usize,
    /// Hidden layers of each conditioner MLP.
    pub hidden_layers: usize,
    /// Width of each hidden layer.
    pub hidden_width: usize,
    /// One-blob bins per conditioner input.
    pub blob_bins: usize,
    /// Number of context features appended to every conditioner's input (0: unconditional).
    pub context_dim: usize,
    /// Seed of the weight initialisation.
    pub seed: u64,
}

impl Default for FlowConfig {
    fn default() -> Self {
        FlowConfig {
            dim: 2,
            transform: TransformKind::Quadratic { bins: 32 },
            couplings: 0,
            hidden_layers: 3,
            hidden_width: 64,
            blob_bins: 32,
            context_dim: 0,
            seed: 0,
        }
    }
}

impl FlowConfig {
    /// The defaults for dimension `dim`.
    pub fn new(dim: usize) -> FlowConfig {
        FlowConfig {
            dim,
            ..Default::default()
        }
    }

    /// The number of coupling layers this config builds.
    pub fn coupling_count(&self) -> usize {
        if self.couplings == 0 {
            mask::default_layers(self.dim.max(1))
        } else {
            self.couplings
        }
    }

    /// Rejects configurations that describe no valid flow.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Config(m));
        if self.dim == 0 || self.dim > MAX_DIM {
            return bad(format!("dimension must be 1..={MAX_DIM}, got {}", self.dim));
        }
        if self.couplings > 1024 {
            return bad(format!("too many coupling layers: {}", self.couplings));
        }
        if self.hidden_width == 0 || self.hidden_width > 1 << 16 || self.hidden_layers > 64 {
            return bad(format!(
                "conditioner needs 1..=65536 hidden units and at most 64 layers, got {} × {}",
                self.hidden_layers, self.hidden_width
            ));
        }
        if self.blob_bins == 0 || self.blob_bins > 1024 {
            return bad(format!(
                "one-blob bins must be 1..=1024, got {}",
                self.blob_bins
            ));
        }
        if self.context_dim > 1 << 16 {
            return bad(format!("context dimension too large: {}", self.context_dim));
        }
        self.transform.validate()
    }
}
