//! The description of a flow as data: a `FlowConfig` round-trips through JSON and builds a
//! [`crate::flow::Flow`].

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::flow::mask::{self, Masks};
use crate::transform::TransformKind;

/// Largest dimension a flow accepts (a sanity bound against corrupt configs).
pub const MAX_DIM: usize = 4096;
/// Most parameters a flow may have (256 MiB of f32 weights; Adam keeps two more copies). A
/// config read from a file or the command line is checked against it before anything is
/// allocated, so a corrupt or hostile one is an error, not an attempt at terabytes.
pub const MAX_PARAMS: usize = 1 << 26;

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
    /// How the layers split the dimensions: the paper's binary masks (the default, left out of
    /// the JSON so that model files written before the choice existed read the same) or the
    /// fewer layers of constant-weight codes ([`mask`]).
    #[serde(skip_serializing_if = "Masks::is_binary")]
    pub masks: Masks,
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
            masks: Masks::Binary,
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
            mask::default_layers(self.dim.max(1), self.masks)
        } else {
            self.couplings
        }
    }

    /// The number of parameters of the flow this config builds, computed without building it,
    /// in O(log D) steps whatever the numbers for the binary masks; `None` when it does not fit
    /// in a `usize` (or, for the codes, when D is above [`MAX_DIM`]).
    pub fn param_count(&self) -> Option<usize> {
        use crate::transform::Transform;
        let np = self.transform.param_count();
        let mlp = |inputs: usize, outputs: usize| -> Option<usize> {
            let input = inputs
                .checked_mul(self.blob_bins)?
                .checked_add(self.context_dim)?;
            let hidden = self.hidden_width;
            let output = outputs.checked_mul(np)?;
            if self.hidden_layers == 0 {
                return input.checked_add(1)?.checked_mul(output);
            }
            let first = input.checked_add(1)?.checked_mul(hidden)?;
            let middle = hidden
                .checked_add(1)?
                .checked_mul(hidden)?
                .checked_mul(self.hidden_layers - 1)?;
            let last = hidden.checked_add(1)?.checked_mul(output)?;
            first.checked_add(middle)?.checked_add(last)
        };
        let layers = self.coupling_count();
        let patterns = mask::pattern_sizes(self.dim, self.masks, MAX_DIM)?;
        let mut total = 0usize;
        // Layer l uses pattern l mod the pattern count.
        for (p, &(a, b)) in patterns.iter().enumerate().take(layers) {
            let uses = layers / patterns.len() + usize::from(p < layers % patterns.len());
            total = total.checked_add(mlp(a, b)?.checked_mul(uses)?)?;
        }
        Some(total)
    }

    /// Rejects configurations that describe no valid flow, or one with more than
    /// [`MAX_PARAMS`] parameters.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Config(m));
        if self.dim == 0 || self.dim > MAX_DIM {
            return bad(format!(
                "dimension must be between 1 and {MAX_DIM}, got {}",
                self.dim
            ));
        }
        if self.couplings > 1024 {
            return bad(format!("too many coupling layers: {}", self.couplings));
        }
        if self.hidden_width == 0 || self.hidden_width > 1 << 16 || self.hidden_layers > 64 {
            return bad(format!(
                "conditioner needs between 1 and 65536 hidden units and at most 64 layers, got {} × {}",
                self.hidden_layers, self.hidden_width
            ));
        }
        if self.blob_bins == 0 || self.blob_bins > 1024 {
            return bad(format!(
                "one-blob bins must be between 1 and 1024, got {}",
                self.blob_bins
            ));
        }
        if self.context_dim > 1 << 16 {
            return bad(format!("context dimension too large: {}", self.context_dim));
        }
        self.transform.validate()?;
        match self.param_count() {
            Some(n) if n <= MAX_PARAMS => Ok(()),
            n => bad(format!(
                "the flow would have {} parameters, more than the limit of {MAX_PARAMS}",
                n.map_or("more than 2^64".to_string(), |n| n.to_string())
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::{Density, Flow};

    #[test]
    fn param_count_matches_the_built_flow() {
        for dim in [1, 2, 3, 5, 8, 17, 100] {
            for (couplings, context_dim, transform, hidden_layers, masks) in [
                (0, 0, TransformKind::Quadratic { bins: 4 }, 2, Masks::Binary),
                (0, 0, TransformKind::Quadratic { bins: 4 }, 2, Masks::Codes),
                (3, 0, TransformKind::Affine, 0, Masks::Binary),
                (
                    7,
                    5,
                    TransformKind::RationalQuadratic { bins: 3 },
                    1,
                    Masks::Codes,
                ),
                (23, 0, TransformKind::Linear { bins: 2 }, 3, Masks::Binary),
                (23, 0, TransformKind::Linear { bins: 2 }, 3, Masks::Codes),
            ] {
                let config = FlowConfig {
                    dim,
                    transform,
                    couplings,
                    masks,
                    hidden_layers,
                    hidden_width: 6,
                    blob_bins: 3,
                    context_dim,
                    seed: 0,
                };
                let flow = Flow::new(config.clone()).unwrap();
                assert_eq!(config.param_count(), Some(flow.param_count()), "{config:?}");
            }
        }
    }

    #[test]
    fn the_mask_layout_round_trips_and_the_default_is_left_unwritten() {
        let binary = serde_json::to_string(&FlowConfig::new(8)).unwrap();
        assert!(!binary.contains("masks"), "{binary}");
        let codes = FlowConfig {
            masks: Masks::Codes,
            ..FlowConfig::new(8)
        };
        let json = serde_json::to_string(&codes).unwrap();
        assert!(json.contains(r#""masks":"codes""#), "{json}");
        assert_eq!(serde_json::from_str::<FlowConfig>(&json).unwrap(), codes);
        assert_eq!(Flow::new(codes).unwrap().layers().len(), 5);
        let bad = json.replace("codes", "gray");
        assert!(serde_json::from_str::<FlowConfig>(&bad).is_err());
        assert!("gray".parse::<Masks>().is_err());
        assert_eq!("codes".parse::<Masks>().unwrap(), Masks::Codes);
    }

    #[test]
    fn a_config_too_large_to_allocate_is_rejected_before_building() {
        // Every bound but the total holds: 64 layers of 65536² weights per coupling.
        let config = FlowConfig {
            dim: 4096,
            hidden_layers: 64,
            hidden_width: 1 << 16,
            ..FlowConfig::default()
        };
        let e = Flow::new(config).unwrap_err().to_string();
        assert!(e.contains("parameters"), "{e}");
        // Counting is cheap whatever the numbers (it used to walk every coupling layer).
        let absurd = FlowConfig {
            dim: usize::MAX,
            couplings: usize::MAX,
            ..FlowConfig::default()
        };
        assert_eq!(absurd.param_count(), None);
        let absurd_codes = FlowConfig {
            masks: Masks::Codes,
            ..absurd
        };
        assert_eq!(absurd_codes.param_count(), None);
        assert!(Flow::new(absurd_codes).is_err());
    }
}
