//! The selection network (Müller et al. 2019, "Neural Importance Sampling", §5.1): a small MLP
//! from the one-blob-encoded vertex context to the probability `c` of sampling the guide rather
//! than the BSDF in the one-sample mixture `c·p_flow + (1 − c)·p_bsdf`. Its output `z` maps to
//! `c = c_min + (1 − 2c_min)·σ(z)`, so both techniques always keep a share.

use nis::flow::context::ContextCache;
use nis::nn::mlp::{BatchForward, Layout};
use nis::nn::{Adam, Mlp};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::NisGuideConfig;

/// Mixed into the seed of the selection network's initial weights, so that they are not drawn
/// from the same stream as the flow's (which [`nis::Flow::new`] seeds with the seed itself).
const SELECTION_SEED_SALT: u64 = 0x005e_1ec7;

/// The selection network, its weights and their optimiser.
pub(super) struct Selection {
    /// Two hidden layers of `selection_width`, one output.
    pub(super) mlp: Mlp,
    pub(super) params: Vec<f32>,
    pub(super) adam: Adam,
    /// The smallest probability of either technique, `c_min`.
    min: f32,
}

fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + (-z).exp())
}

impl Selection {
    /// A new network on contexts of `context_dim` features, with initial weights from the
    /// config's seed.
    pub(super) fn new(context_dim: usize, config: &NisGuideConfig) -> nis::Result<Selection> {
        let width = config.selection_width;
        let mlp = Mlp {
            dims: vec![context_dim, width, width, 1],
            output: Layout::Rows,
        };
        let mut params = vec![0.0; mlp.param_count()];
        let mut rng = Pcg64Mcg::seed_from_u64(config.seed ^ SELECTION_SEED_SALT);
        mlp.init(&mut params, &mut rng);
        Ok(Selection {
            adam: Adam::new(config.adam(), mlp.param_count())?,
            mlp,
            params,
            min: config.min_selection,
        })
    }

    /// The selection probability of the network's output `z`.
    pub(super) fn probability(&self, z: f32) -> f32 {
        let m = self.min;
        m + (1.0 - 2.0 * m) * sigmoid(z)
    }

    /// The forward pass over encoded contexts (for training): the pass and the selection
    /// probabilities.
    pub(super) fn forward(&self, context: &[f32]) -> (BatchForward, Vec<f32>) {
        let forward = self.mlp.forward_batch(&self.params, context);
        let c = forward.outputs().map(|&z| self.probability(z)).collect();
        (forward, c)
    }

    /// The weights' gradient from ∂L/∂z of every row of `forward`.
    pub(super) fn backward(&self, forward: &BatchForward, g_logit: &[f32]) -> Vec<f32> {
        let mut g = vec![0.0; self.params.len()];
        self.mlp
            .backward_batch(&self.params, forward, g_logit, &mut g);
        g
    }

    /// The selection probabilities at the cached contexts, the network's first layer taken
    /// from `cache` (where it is the first network after the flow's couplings).
    pub(super) fn cached(&self, cache: &ContextCache, out: &mut [f32]) {
        let z = cache
            .other_outputs(0, &self.mlp, &self.params)
            .expect("the guide's cache holds its selection network");
        for (o, &z) in out.iter_mut().zip(&z) {
            *o = self.probability(z);
        }
    }
}
