//! The neural guide's settings: the networks' shapes, the loss, the training schedule, and
//! their bounds. The defaults are the settings the studies of docs/results/guiding.md adopted.

use nis::flow::FlowConfig;
use nis::nn::AdamConfig;
use nis::TransformKind;
use serde::{Deserialize, Serialize};

use super::CONTEXT_SCALARS;
use crate::guiding::directions::GuideFrame;
#[cfg(doc)]
use crate::guiding::Guide;
use crate::guiding::NARROWEST_LOBE_DEGREES;

/// Which divergence the guide minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuideLoss {
    /// Kullback–Leibler divergence (the paper's default).
    Kl,
    /// Pearson χ² divergence, i.e. the variance of the estimator.
    ChiSquare,
}

/// Settings of [`NisGuide`](super::NisGuide) (JSON with any subset of the fields, e.g.
/// `{"hidden_width": 128, "loss": "chisquare"}`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NisGuideConfig {
    /// The divergence to minimise.
    pub loss: GuideLoss,
    /// The frame of the flow's directions: world-space on the sphere, or the vertex's local
    /// frame, on the hemisphere where the material is opaque (docs/results/guiding.md compares them).
    pub frame: GuideFrame,
    /// The coupling transform of the flow.
    pub transform: TransformKind,
    /// Coupling layers of the flow.
    pub couplings: usize,
    /// Hidden layers of each coupling's conditioner.
    pub hidden_layers: usize,
    /// Width of the conditioners' hidden layers.
    pub hidden_width: usize,
    /// One-blob bins of the flow's own inputs.
    pub blob_bins: usize,
    /// One-blob bins of each context scalar (position, outgoing direction, normal).
    pub context_bins: usize,
    /// Hidden width of the selection-probability network (two hidden layers).
    pub selection_width: usize,
    /// Smallest selection probability of either technique.
    pub min_selection: f32,
    /// Share λ of the χ² divergence in the selection network's loss, the rest being `loss`
    /// (each part normalised by its batch's mean weight; the flow learns from `loss` alone):
    /// χ² punishes the mixture's holes, BSDF samples where the guide's share is high and the
    /// flow has little density, far harder than KL.
    pub selection_chi2_share: f32,
    /// Training phases during which only the flow learns and the selection network keeps
    /// its initial ½ (an untrained flow would teach it to avoid the guide).
    pub selection_warmup: usize,
    /// Whether a record weighs in by what its path brings to the image, `F` times the path's
    /// throughput on arrival at the vertex, rather than by `F` alone: the networks then spend
    /// themselves on the vertices the image depends on, not on deep ones near the lights.
    pub weight_by_throughput: bool,
    /// Records per training step.
    pub batch: usize,
    /// Adam steps after a training pass, at least (and about one per `batch` new records).
    pub min_steps: usize,
    /// Adam steps after a training pass, at most.
    pub max_steps: usize,
    /// Records kept for training (the oldest go first).
    pub buffer: usize,
    /// Adam's learning rate (both networks).
    pub learning_rate: f32,
    /// Span of the exponential moving average of both networks' weights over the Adam steps,
    /// which the guide renders with, as a share of each training phase's steps: the phase's
    /// steps enter with the decay `β = 1 − 1/(span·steps)` (bias-corrected, as Adam's moments);
    /// 0 renders with the last step's weights.
    pub average_span: f32,
    /// Exponent α by which training batches favour records that carry light: each record of
    /// the buffer is drawn with probability ∝ (F/p_s)^α and enters its step with its weight
    /// divided by (F/p_s)^α, so every α follows the same expected gradient
    /// (`neural/record_draw.rs`); 0 draws uniformly. A phase whose steps read its buffer more than
    /// once over draws by α/(reads per record) instead (`record_draw::phase_alpha`).
    pub pick_by_weight: f32,
    /// Bounces of a path the guide serves ([`Guide::guided_bounces`]: vertices with a non-delta
    /// BSDF, from the camera ray's hit on); later ones sample the BSDF alone and make no
    /// training records. −1 serves every bounce.
    pub guided_bounces: i32,
    /// The narrowest glossy lobe the guide serves, as the half-angle in degrees of the cone
    /// around the mirror direction that holds 90% of a rough conductor's or dielectric's
    /// scattering ([`Guide::narrowest_lobe`]); narrower lobes are left to BSDF sampling. 0
    /// serves every lobe.
    pub narrowest_lobe_degrees: f32,
    /// Seed of the weights and of the training batches.
    pub seed: u64,
}

impl NisGuideConfig {
    /// Largest batch of records per training step.
    pub const MAX_BATCH: usize = 1 << 20;
    /// Most records the training buffer may keep.
    pub const MAX_BUFFER: usize = 1 << 24;
    /// Most Adam steps per training pass.
    pub const MAX_STEPS: usize = 1 << 20;
    /// Widest selection network.
    pub const MAX_SELECTION_WIDTH: usize = 1 << 12;
    /// Most one-blob bins per context scalar.
    pub const MAX_CONTEXT_BINS: usize = 1024;

    /// Rejects settings that describe no trainable guide, or one far too large to build (the
    /// flow's own bounds are [`FlowConfig::validate`]'s).
    pub fn validate(&self) -> nis::Result<()> {
        let bad = |m: String| Err(nis::Error::Config(m));
        if !(1..=Self::MAX_BATCH).contains(&self.batch)
            || !(self.batch..=Self::MAX_BUFFER).contains(&self.buffer)
        {
            return bad(format!(
                "the guide needs a batch of 1..={} records and a buffer at least as large and at most {}, got {} and {}",
                Self::MAX_BATCH, Self::MAX_BUFFER, self.batch, self.buffer
            ));
        }
        if !(0.0..0.5).contains(&self.min_selection)
            || !(1..=Self::MAX_CONTEXT_BINS).contains(&self.context_bins)
            || !(1..=Self::MAX_SELECTION_WIDTH).contains(&self.selection_width)
        {
            return bad(format!(
                "minimum selection probability must be in [0, 0.5), context bins 1..={} and the selection width 1..={}, got {}, {} and {}",
                Self::MAX_CONTEXT_BINS, Self::MAX_SELECTION_WIDTH, self.min_selection, self.context_bins, self.selection_width
            ));
        }
        if !(0.0..=1.0).contains(&self.pick_by_weight) {
            return bad(format!(
                "records are drawn by their weight to a power in [0, 1], got {}",
                self.pick_by_weight
            ));
        }
        if !(0.0..=1.0).contains(&self.selection_chi2_share) {
            return bad(format!(
                "the χ² share of the selection's loss must be in [0, 1], got {}",
                self.selection_chi2_share
            ));
        }
        if !(0.0..=1.0).contains(&self.average_span) {
            return bad(format!(
                "the weights' average needs a span in [0, 1], got {}",
                self.average_span
            ));
        }
        if self.guided_bounces == 0 || self.guided_bounces < -1 {
            return bad(format!(
                "the guide serves at least one bounce (−1: every bounce), got {}",
                self.guided_bounces
            ));
        }
        if !(0.0..=90.0).contains(&self.narrowest_lobe_degrees) {
            return bad(format!(
                "the narrowest lobe the guide serves is a half-angle in [0, 90] degrees, got {}",
                self.narrowest_lobe_degrees
            ));
        }
        if self.min_steps > self.max_steps || self.max_steps > Self::MAX_STEPS {
            return bad(format!(
                "Adam steps per pass: need min_steps ≤ max_steps ≤ {}, got {} and {}",
                Self::MAX_STEPS,
                self.min_steps,
                self.max_steps
            ));
        }
        self.adam().validate()?;
        self.flow_config().validate()
    }

    /// The flow over cylindrical direction coordinates, conditioned on the one-blob context.
    pub(super) fn flow_config(&self) -> FlowConfig {
        FlowConfig {
            dim: 2,
            transform: self.transform,
            couplings: self.couplings,
            hidden_layers: self.hidden_layers,
            hidden_width: self.hidden_width,
            blob_bins: self.blob_bins,
            context_dim: CONTEXT_SCALARS * self.context_bins,
            seed: self.seed,
            // Two dimensions alternate under either layout.
            ..FlowConfig::default()
        }
    }

    /// The optimiser of both networks.
    pub(super) fn adam(&self) -> AdamConfig {
        AdamConfig {
            learning_rate: self.learning_rate,
            clip_norm: Some(10.0),
            ..AdamConfig::default()
        }
    }
}

impl Default for NisGuideConfig {
    /// The settings chosen by the studies in docs/results/guiding.md ("Settings that set the
    /// guide's defaults": the rows "Network size", "Smaller training batches", "Weight
    /// average", "Records drawn by weight", "Guiding the first bounces" and "Narrow lobes left
    /// to the BSDF" give the numbers).
    fn default() -> Self {
        NisGuideConfig {
            loss: GuideLoss::Kl,
            frame: GuideFrame::World,
            // Small networks: as accurate as twice their size, in about half the time.
            transform: TransformKind::Quadratic { bins: 16 },
            couplings: 2,
            hidden_layers: 2,
            hidden_width: 16,
            blob_bins: 8,
            context_bins: 8,
            selection_width: 16,
            min_selection: 0.05,
            // A fifth χ² in the selection's loss: fewer fireflies from the flow's holes.
            selection_chi2_share: 0.2,
            selection_warmup: 1,
            // Records weighted by the image's share in them: lower MAPE on most scenes.
            weight_by_throughput: true,
            // Small batches: many more steps from the same records, so the guide learns sooner.
            batch: 256,
            min_steps: 40,
            max_steps: 400,
            buffer: 1 << 21,
            learning_rate: 5e-3,
            // Render with the average of the last half phase's weights, not the last step's.
            average_span: 0.5,
            // Batches drawn by √(F/p_s): spent on the records that carry the gradient.
            pick_by_weight: 0.5,
            // The first four bounces: lower error than guiding every bounce, in less time.
            guided_bounces: 4,
            narrowest_lobe_degrees: NARROWEST_LOBE_DEGREES,
            seed: 0,
        }
    }
}
