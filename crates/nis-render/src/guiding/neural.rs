//! Neural path guiding (Müller et al. 2019, "Neural Importance Sampling", §5).
//!
//! At every path vertex a normalizing flow gives the density of incident directions:
//! a 2-D flow on [0, 1]² over world-space cylindrical coordinates
//! `((cos θ + 1)/2, φ/2π)` of the direction ([`super::dir_to_cylindrical`], the map PPG's
//! quadtrees use too; area-preserving, so `p(ω) = q(u, v)/4π`), or, with
//! [`GuideFrame::Local`], over the hemisphere of the vertex's local frame where the material
//! is opaque (`(cos θ, φ/2π)`, `p(ω) = q/2π`, nothing below the surface; see
//! [`super::directions`]), conditioned on the one-blob-encoded vertex position (normalised
//! to the scene box), outgoing direction and shading normal (both in cylindrical
//! coordinates; `ω_o` in the local frame with [`GuideFrame::Local`]). A second, small network predicts the selection probability `c(x, ω_o)` of
//! the one-sample mixture `c·p_flow + (1 − c)·p_bsdf`, kept in `[c_min, 1 − c_min]` so both
//! techniques always have a share.
//!
//! Training is on-line: the flow starts as the uniform density, the first pass renders with
//! BSDF sampling only, and after every training pass (PPG's schedule of doubling sample
//! counts, see [`crate::render::training_schedule`]) both networks take Adam steps on the
//! records gathered so far. A record is a direction `ω` drawn at a vertex with mixture
//! density `p_s(ω)`, and the product `F = L_i(ω)·f_s(ω_o, ω)·|cos θ|` the path found along it
//! (luminance), the quantity the paper learns. With the current mixture density
//! `q = c·p_flow + (1 − c)·p_bsdf`, the gradients are the paper's off-policy ones:
//!
//! * KL: `−E_{p_s}[(F/p_s)·∇ ln q]`,
//! * χ²: `−E_{p_s}[(F²/(p_s·q))·∇ ln q]`,
//!
//! with `∇_θ ln q = (c·p_flow/q)·∇_θ ln p_flow` for the flow's weights and
//! `∂ ln q/∂c = (p_flow − p_bsdf)/q` for the selection network. The per-sample weights are
//! normalised by their batch mean, which only rescales the step. Records of all training
//! passes stay in a bounded replay buffer (each is an unbiased sample of the same gradient,
//! whatever mixture drew it), so early passes with few paths still get enough steps. A step's
//! batch is drawn from the buffer with probabilities ∝ (F/p_s)^α, each record's weight divided
//! by (F/p_s)^α, which keeps the expected gradient ([`NisGuideConfig::pick_by_weight`],
//! `picks.rs`).
//! The guide renders with an exponential moving average of the weights over the Adam steps
//! ([`NisGuideConfig::average_span`]), not with the last step's, whose noise would otherwise be
//! part of every image; training goes on from the last step's.
//!
//! The integrator traces thousands of paths as one wavefront ([`Guide::batch_paths`]), so
//! every query below runs the networks on large batches.
//!
//! **Per-vertex cache.** Every query at a vertex (its selection probability, the guide's sample,
//! the density of the BSDF sample's direction) feeds the same context to the first dense layer
//! of every conditioner and of the selection network. That layer is
//! `W·[enc(x_A); enc(ctx)] + b = W_A·enc(x_A) + (W_ctx·enc(ctx) + b)`, so [`Guide::prepare`]
//! one-blob encodes the context once per vertex and computes the second term of all those
//! layers in one matrix product (the guide's [`Guide::Prepared`]); a query then adds only `W_A·enc(x_A)`, 8
//! inputs instead of 64 at the default sizes. The result is the flow's own density up to f32
//! rounding (tested against [`Flow`]'s uncached evaluation).

use std::collections::VecDeque;

use glam::{Vec2, Vec3};
use nis::flow::{Bijection, Density, Direction, Flow, FlowConfig};
use nis::kernels::dense::{self, Layout, Shape};
use nis::kernels::elementwise::{one_blob, relu};
use nis::kernels::{chunk_rows, CHUNK_ROWS};
use nis::nn::mlp::MlpTape;
use nis::nn::{Adam, AdamConfig, Mlp, ParamAverage};
use nis::TransformKind;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{
    directions::{DirectionMap, GuideFrame},
    picks::{self, RecordPicker},
    Guide, GuideRecord, GuideSample, GuideStatistics, GuideVertex, PdfQuery, SampleQuery,
    COUNT_WORDS,
};
use crate::bvh::Aabb;
use crate::geometry::luminance;

/// Scalars a vertex is described by: position (3), outgoing direction (2), normal (2).
const CONTEXT_SCALARS: usize = 7;

/// Mixed into the seed of the selection network's initial weights, so that they are not drawn
/// from the same stream as the flow's (which [`Flow::new`] seeds with the seed itself).
const SELECTION_SEED_SALT: u64 = 0x005e_1ec7;

/// Bit position of the training phase's index in the seed of its batch stream: each phase
/// draws its batches from a stream of its own, disjoint from the weights' streams above (whose
/// salts use only the low bits).
const PHASE_SEED_SHIFT: u32 = 32;

/// Which divergence the guide minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuideLoss {
    /// Kullback–Leibler divergence (the paper's default).
    Kl,
    /// Pearson χ² divergence, i.e. the variance of the estimator.
    ChiSquare,
}

/// Settings of [`NisGuide`] (JSON with any subset of the fields, e.g.
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
    /// Training phases during which only the flow learns and the selection network keeps
    /// its initial ½ (an untrained flow would teach it to avoid the guide).
    pub selection_warmup: usize,
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
    /// divided by (F/p_s)^α, so every α follows the same expected gradient (`guiding/picks.rs`);
    /// 0 draws uniformly. A phase whose steps read its buffer more than once over draws by
    /// α/(reads per record) instead (`picks::phase_alpha`).
    pub pick_by_weight: f32,
    /// Bounces of a path the guide serves ([`Guide::guided_bounces`]: vertices with a non-delta
    /// BSDF, from the camera ray's hit on); later ones sample the BSDF alone and make no
    /// training records. −1 serves every bounce.
    pub guided_bounces: i32,
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
    fn flow_config(&self) -> FlowConfig {
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
    fn adam(&self) -> AdamConfig {
        AdamConfig {
            learning_rate: self.learning_rate,
            clip_norm: Some(10.0),
            ..AdamConfig::default()
        }
    }
}

impl Default for NisGuideConfig {
    fn default() -> Self {
        NisGuideConfig {
            loss: GuideLoss::Kl,
            frame: GuideFrame::World,
            // Small networks: 16 bins, width 16 and 8 one-blob bins gave the same mean MAPE
            // over 9 seeds as 32 bins, width 32 and 16 one-blob bins, in 55% of the time
            // (docs/results/guiding.md, "Network size"); width 64 was slower and no better.
            transform: TransformKind::Quadratic { bins: 16 },
            couplings: 2,
            hidden_layers: 2,
            hidden_width: 16,
            blob_bins: 8,
            context_bins: 8,
            selection_width: 16,
            min_selection: 0.05,
            selection_warmup: 1,
            // Batches of 256 rather than 4,096 records: a pass takes one step per 256 new
            // records (4.5× the steps on cornell-box at 128², 64 spp, reading 0.28× the
            // records), and the guide learns sooner. Over 9 seeds at 128², 64 spp its mean
            // MAPE is 1.7–7.6% lower on all four scenes, at 256², 256 spp 0.6–3.3% lower, in
            // the same wall time (docs/results/guiding.md, "Smaller training batches").
            batch: 256,
            min_steps: 40,
            max_steps: 400,
            buffer: 1 << 21,
            learning_rate: 5e-3,
            // Rendering with the average of the last half phase's weights rather than the last
            // step's: 2–8% lower mean MAPE over 9 seeds on all four scenes at 128², a third of
            // the spread over seeds on cornell-indirect, and 1–3% lower again at 256², 256 spp
            // than a fixed β = 0.95 (docs/results/guiding.md, "Weight average").
            average_span: 0.5,
            // Batches drawn by √(F/p_s): over 9 seeds at 128², 64 spp, 2.4–4.9% lower mean MAPE
            // on cornell-box, -glossy and -indirect (3.3% at 256², 256 spp on the last),
            // 2.9% higher on two-rooms-door (level at 256²), for 2–3% more wall time
            // (docs/results/guiding.md, "Records drawn by weight").
            pick_by_weight: 0.5,
            // The first four bounces: over 9 seeds at 128², 64 spp, 1.1–3.4% lower mean MAPE
            // on all four scenes than guiding (and learning at) every bounce, in 7–9% less
            // time; three bounces were faster again but 4.6% worse on cornell-indirect over 6
            // seeds (docs/results/guiding.md, "Guiding the first bounces").
            guided_bounces: 4,
            seed: 0,
        }
    }
}

/// What the neural guide keeps of a training record. A training pass's
/// [`Guide::Statistics`] are its samples, in the order they were made.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    context: [f32; CONTEXT_SCALARS],
    /// The direction in cylindrical coordinates.
    x: [f32; 2],
    /// `F`: luminance of incident radiance × BSDF × cosine.
    f: f32,
    /// Mixture density the direction was drawn with.
    pdf: f32,
    /// The BSDF's density of the direction.
    bsdf_pdf: f32,
    /// Solid-angle density per unit density on the square of the vertex's map.
    jacobian: f32,
}

impl Sample {
    /// F/p_s: the record's weight in the KL gradient (in f64, where it cannot overflow).
    fn kl_weight(&self) -> f64 {
        f64::from(self.f) / f64::from(self.pdf)
    }
}

/// The gradients of a training step's loss: the flow's, and the selection network's when it
/// learns.
struct StepGradients {
    flow: Vec<f32>,
    selection: Option<Vec<f32>>,
}

/// What one part of a training step adds up ([`NisGuide::part_gradients`]), before the
/// division by the batch's mean weight.
#[derive(Default)]
struct PartGradients {
    /// Sum of the records' weights.
    weight: f64,
    /// Sum of the records' weighted losses.
    loss: f64,
    /// Sum of the selection probabilities.
    selection_sum: f64,
    flow: Vec<f32>,
    selection: Option<Vec<f32>>,
}

/// The records of a training pass, in the order they were made, of which only the newest `cap`
/// are kept: the replay buffer would keep no more of them (see `NisGuide::train`), so a pass of
/// any number of paths holds at most a buffer's worth of records. `seen` counts them all (it
/// sets the number of steps), so training is the same as with every record kept.
#[derive(Debug, Default)]
pub struct PassSamples {
    samples: VecDeque<Sample>,
    seen: usize,
    /// The replay buffer's size; `None` until the guide has accumulated into these statistics.
    cap: Option<usize>,
}

impl PassSamples {
    fn trim(&mut self) {
        if let Some(cap) = self.cap {
            let excess = self.samples.len().saturating_sub(cap);
            self.samples.drain(..excess);
        }
    }
}

impl super::Record for Sample {
    const WORDS: usize = CONTEXT_SCALARS + 6;
    fn write(&self, out: &mut Vec<f32>) {
        out.extend_from_slice(&self.context);
        out.extend_from_slice(&[
            self.x[0],
            self.x[1],
            self.f,
            self.pdf,
            self.bsdf_pdf,
            self.jacobian,
        ]);
    }
    fn read(w: &[f32]) -> Self {
        let c = CONTEXT_SCALARS;
        let mut context = [0.0; CONTEXT_SCALARS];
        context.copy_from_slice(&w[..c]);
        Sample {
            context,
            x: [w[c], w[c + 1]],
            f: w[c + 2],
            pdf: w[c + 3],
            bsdf_pdf: w[c + 4],
            jacobian: w[c + 5],
        }
    }
}

impl GuideStatistics for PassSamples {
    fn merge(&mut self, later: Self) {
        self.cap = match (self.cap, later.cap) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        self.seen += later.seen;
        self.samples.extend(later.samples);
        self.trim();
    }
    /// The cap plus one (0 for none) and the count of records seen, then the kept records.
    fn to_words(&self) -> Vec<f32> {
        use super::Record;
        let mut out = Vec::with_capacity(2 * COUNT_WORDS + self.samples.len() * Sample::WORDS);
        super::write_count(self.cap.map_or(0, |c| c + 1), &mut out);
        super::write_count(self.seen, &mut out);
        for s in &self.samples {
            s.write(&mut out);
        }
        out
    }
    fn from_words(words: &[f32]) -> Self {
        use super::Record;
        let (head, records) = words.split_at((2 * COUNT_WORDS).min(words.len()));
        if head.len() < 2 * COUNT_WORDS {
            return PassSamples::default();
        }
        let cap = super::read_count(&head[..COUNT_WORDS]);
        PassSamples {
            samples: records
                .chunks_exact(Sample::WORDS)
                .map(Sample::read)
                .collect(),
            seen: super::read_count(&head[COUNT_WORDS..]),
            cap: cap.checked_sub(1),
        }
    }
}

/// What one training phase did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrainingStats {
    /// Records with non-zero `F` that arrived in the pass.
    pub new_records: usize,
    /// Adam steps taken.
    pub steps: usize,
    /// Mean selection probability of the guide over the last batch.
    pub mean_selection: f64,
    /// Mean over the last batch of the normalised loss, `−(w/w̄)·ln q` for KL and `(w/w̄)` for
    /// χ² (`w` the sample weight of the chosen loss), before the step.
    pub loss: f64,
    /// Wall-clock seconds the training phase took.
    pub seconds: f64,
    /// Share of the flow's probability mass below the surface (directions on the other side
    /// of the shading normal than `ω_o`) at the last batch's vertices, from one flow sample per
    /// record drawn after the phase's steps (0 by construction in the local frame, whose
    /// hemisphere map has no point below the surface).
    pub below_surface: f64,
    /// The one selection probability that would minimise the KL divergence of the mixture on
    /// the last batch, with the flow as it is after the phase (the best constant the selection
    /// network could have learned; compare [`TrainingStats::mean_selection`]).
    pub best_constant_selection: f64,
}

/// The neural guide: a conditional flow plus a selection network, trained while rendering.
pub struct NisGuide {
    config: NisGuideConfig,
    origin: Vec3,
    inv_extent: Vec3,
    flow: Flow,
    flow_adam: Adam,
    selection: Mlp,
    selection_params: Vec<f32>,
    selection_adam: Adam,
    buffer: Vec<Sample>,
    training: bool,
    trained: bool,
    history: Vec<TrainingStats>,
    /// The context's columns of the first layer of every conditioner, then of the selection
    /// network, side by side (`context_dim × first_width`), and their biases: what
    /// [`Guide::prepare`] multiplies the encoded context with. Rebuilt after every update.
    context_weights: Vec<f32>,
    context_bias: Vec<f32>,
    /// Where each coupling's first layer starts in a cache row; the selection
    /// network's starts at the last entry.
    first_offsets: Vec<usize>,
    /// Numbers per vertex in a cache row.
    first_width: usize,
    /// The moving average of both networks' weights, flow first ([`NisGuideConfig::average_span`]),
    /// if any: between training phases the networks hold it, and it holds the Adam iterates.
    average: Option<ParamAverage>,
}

fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + (-z).exp())
}

impl NisGuide {
    /// A new (uniform, untrained) guide for a scene inside `bounds`.
    pub fn new(bounds: Aabb, config: NisGuideConfig) -> nis::Result<NisGuide> {
        config.validate()?;
        let context_dim = CONTEXT_SCALARS * config.context_bins;
        let flow = Flow::new(config.flow_config())?;
        let adam = config.adam();
        let selection = Mlp {
            dims: vec![
                context_dim,
                config.selection_width,
                config.selection_width,
                1,
            ],
            output: Layout::Rows,
        };
        let mut selection_params = vec![0.0; selection.param_count()];
        let mut rng = Pcg64Mcg::seed_from_u64(config.seed ^ SELECTION_SEED_SALT);
        selection.init(&mut selection_params, &mut rng);
        let extent = (bounds.max - bounds.min).max(Vec3::splat(1e-6));
        // A small margin keeps positions on the bounding box's faces inside the encoding.
        let margin = 0.01 * extent;
        let mut guide = NisGuide {
            flow_adam: Adam::new(adam, flow.param_count())?,
            selection_adam: Adam::new(adam, selection.param_count())?,
            flow,
            selection,
            selection_params,
            origin: bounds.min - margin,
            inv_extent: (extent + 2.0 * margin).recip(),
            config,
            buffer: Vec::new(),
            training: true,
            trained: false,
            history: Vec::new(),
            context_weights: Vec::new(),
            context_bias: Vec::new(),
            first_offsets: Vec::new(),
            first_width: 0,
            average: None,
        };
        if guide.config.average_span > 0.0 {
            // Its decay is set by every training phase.
            guide.average = Some(ParamAverage::new(
                0.0,
                &[guide.flow.params(), &guide.selection_params],
            ));
        }
        guide.refresh_context_weights();
        Ok(guide)
    }

    /// Gathers the context's part of the first layer of every network (see
    /// [`NisGuide::context_weights`]) from the current parameters.
    fn refresh_context_weights(&mut self) {
        let cdim = self.selection.dims[0];
        let params = self.flow.params();
        let mut parts: Vec<(&[f32], &[f32])> = self
            .flow
            .layers()
            .iter()
            .map(|c| {
                let (w, b) = c.mlp.layer_params(c.params(params), 0);
                // Rows of W are inputs: the encoded x_A first, then the context.
                (&w[(c.mlp.dims[0] - cdim) * b.len()..], b)
            })
            .collect();
        parts.push(self.selection.layer_params(&self.selection_params, 0));
        self.first_offsets.clear();
        let mut width = 0;
        for (_, b) in &parts {
            self.first_offsets.push(width);
            width += b.len();
        }
        self.first_width = width;
        self.context_weights.clear();
        self.context_weights.resize(cdim * width, 0.0);
        self.context_bias.clear();
        for ((w, b), &off) in parts.iter().zip(&self.first_offsets) {
            let o = b.len();
            for (r, row) in w.chunks_exact(o).enumerate() {
                self.context_weights[r * width + off..r * width + off + o].copy_from_slice(row);
            }
            self.context_bias.extend_from_slice(b);
        }
    }

    /// Runs the flow over `u` (two coordinates per row, in place) in `direction`, row `r` at the
    /// cached vertex `vertex[r]`; returns ln q of each row's data-side point. The same layers
    /// as [`Flow`]'s own passes, with each conditioner's first layer started from the cache.
    fn flow_cached(
        &self,
        cache: &[f32],
        vertex: &[usize],
        u: &mut [f32],
        direction: Direction,
    ) -> Vec<f64> {
        let layers = self.flow.layers();
        let params = self.flow.params();
        let (width, dim) = (self.first_width, 2);
        let mut log_q = vec![0.0f64; vertex.len()];
        u.par_chunks_mut(CHUNK_ROWS * dim)
            .zip(log_q.par_chunks_mut(CHUNK_ROWS))
            .zip(vertex.par_chunks(CHUNK_ROWS))
            .for_each(|((u, log_q), vertex)| {
                let n = vertex.len();
                let order: Vec<usize> = match direction {
                    Direction::Forward => (0..layers.len()).collect(),
                    Direction::Inverse => (0..layers.len()).rev().collect(),
                };
                // Buffers shared by the layers: every activation is overwritten before it is
                // read (the first layer's by the cache rows, the others by their dense layer,
                // which sizes them).
                let mut tape = MlpTape {
                    rows: n,
                    acts: Vec::new(),
                };
                let mut enc = Vec::new();
                for l in order {
                    let c = &layers[l];
                    let mlp = &c.mlp;
                    let p = c.params(params);
                    let h = mlp.dims[1];
                    let off = self.first_offsets[l];
                    tape.acts.resize_with(mlp.dims.len(), Vec::new);
                    let first = &mut tape.acts[1];
                    first.resize(n * h, 0.0);
                    for (row, &v) in first.chunks_exact_mut(h).zip(vertex) {
                        row.copy_from_slice(&cache[v * width + off..v * width + off + h]);
                    }
                    let enc_w = c.encoding.width(c.a.len());
                    enc.resize(n * enc_w, 0.0);
                    let mut s = vec![0.0f32; c.a.len()];
                    for (r, e) in enc.chunks_exact_mut(enc_w.max(1)).enumerate().take(n) {
                        for (k, &a) in c.a.iter().enumerate() {
                            s[k] = u[r * dim + a];
                        }
                        c.encoding.encode(&s, e);
                    }
                    let (w, _) = mlp.layer_params(p, 0);
                    dense::accumulate(&enc, &w[..enc_w * h], first, Shape::rows(n, enc_w, h));
                    if mlp.layers() > 1 {
                        relu(first);
                    }
                    mlp.forward_from(p, &mut tape, 1);
                    let out = tape.acts.last().expect("an MLP has an output layer");
                    c.transform_rows(out, u, dim, log_q, direction);
                }
            });
        log_q
    }

    /// The flow (for inspection).
    pub fn flow(&self) -> &Flow {
        &self.flow
    }

    /// What every training phase did, in order.
    pub fn history(&self) -> &[TrainingStats] {
        &self.history
    }

    /// The map of `v`'s directions in the configured frame.
    fn map(&self, v: &GuideVertex) -> DirectionMap {
        DirectionMap::in_frame(v, self.config.frame)
    }

    /// Position in the scene box; in the world frame `ω_o` and the shading normal in world
    /// cylindrical coordinates; in the local frame `ω_o` on the hemisphere map (it always lies
    /// on the normal's side) and the frame's normal. (Whether a local map is the hemisphere's
    /// or the sphere's is not an input: position and normal tell the surfaces apart.)
    fn context_scalars(&self, v: &GuideVertex, map: &DirectionMap) -> [f32; CONTEXT_SCALARS] {
        let p = ((v.p - self.origin) * self.inv_extent).clamp(Vec3::ZERO, Vec3::ONE);
        let (wo, n) = match self.config.frame {
            GuideFrame::World => (super::dir_to_cylindrical(v.wo), v.n),
            GuideFrame::Local => {
                let wo = map.to_local(v.wo);
                let wo = Vec2::new(wo.z.clamp(0.0, 1.0), super::dir_to_cylindrical(wo).y);
                (wo, map.normal())
            }
        };
        let n = super::dir_to_cylindrical(n);
        [p.x, p.y, p.z, wo.x, wo.y, n.x, n.y]
    }

    /// One-blob features of context scalars, `rows × 7·bins`.
    fn encode(&self, scalars: &[[f32; CONTEXT_SCALARS]]) -> Vec<f32> {
        let k = self.config.context_bins;
        let mut out = vec![0.0; scalars.len() * CONTEXT_SCALARS * k];
        out.par_chunks_mut(CHUNK_ROWS * CONTEXT_SCALARS * k)
            .zip(scalars.par_chunks(CHUNK_ROWS))
            .for_each(|(out, s)| one_blob(s.as_flattened(), k, out));
        out
    }

    /// Selection-network forward pass over encoded contexts, chunk by chunk: the tapes (for
    /// training) and the selection probabilities.
    fn select(&self, context: &[f32]) -> (Vec<MlpTape>, Vec<f32>) {
        let cdim = self.selection.dims[0];
        let tapes: Vec<MlpTape> = context
            .par_chunks(CHUNK_ROWS * cdim)
            .map(|c| {
                let mut tape = self.selection.tape(c.len() / cdim);
                tape.acts[0].copy_from_slice(c);
                self.selection.forward(&self.selection_params, &mut tape);
                tape
            })
            .collect();
        let m = self.config.min_selection;
        let c = tapes
            .iter()
            .flat_map(|t| t.acts.last().expect("output layer").iter())
            .map(|&z| m + (1.0 - 2.0 * m) * sigmoid(z))
            .collect();
        (tapes, c)
    }

    /// One Adam step on `batch`, whose records were favoured by the factors `scales`
    /// ([`RecordPicker::scale`]): of the flow, and of the selection network when `selection`.
    fn step(
        &mut self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
    ) -> nis::Result<TrainingStats> {
        // The batch in parts of `chunk_rows(n)` records (a function of `n` alone), each through
        // both networks and back on one thread: a step is one parallel loop over the parts,
        // not dozens of loops over a few hundred records each, which the cores handed over one
        // by one.
        let part = chunk_rows(batch.len());
        let (stats, gradients) = self.gradients(batch, scales, selection, part)?;
        if let Some(g) = gradients {
            self.flow_adam.step(self.flow.params_mut(), &g.flow)?;
            if let Some(g_sel) = g.selection {
                self.selection_adam
                    .step(&mut self.selection_params, &g_sel)?;
            }
        }
        Ok(stats)
    }

    /// The loss of a step on `batch` and its gradients (none when no record of the batch
    /// carries weight), computed `part` records at a time and summed in the parts' order.
    ///
    /// Each part runs both networks forward and back with its records' weights as they are;
    /// the loss and the gradients are linear in the weights, so their sums are divided by the
    /// batch's mean weight once every part is done. The parts are then one parallel loop, not
    /// two with the mean between them: the other core sleeps at the end of every loop, and
    /// waking it again cost more than its share of the work (docs/results/guiding.md).
    fn gradients(
        &self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
        part: usize,
    ) -> nis::Result<(TrainingStats, Option<StepGradients>)> {
        let n = batch.len();
        let parts = batch
            .par_chunks(part)
            .zip(scales.par_chunks(part))
            .map(|(b, scales)| self.part_gradients(b, scales, selection, n))
            .collect::<nis::Result<Vec<_>>>()?;
        let mean = parts.iter().map(|p| p.weight).sum::<f64>() / n as f64;
        let mut stats = TrainingStats {
            mean_selection: parts.iter().map(|p| p.selection_sum).sum::<f64>() / n as f64,
            ..TrainingStats::default()
        };
        if mean <= 0.0 || !mean.is_finite() {
            return Ok((stats, None));
        }
        stats.loss = parts.iter().map(|p| p.loss).sum::<f64>() / mean / n as f64;
        let mut g_flow = vec![0.0f32; self.flow.params().len()];
        let mut g_sel = selection.then(|| vec![0.0f32; self.selection_params.len()]);
        for p in parts {
            g_flow.iter_mut().zip(&p.flow).for_each(|(a, b)| *a += b);
            if let (Some(sum), Some(s)) = (&mut g_sel, p.selection) {
                sum.iter_mut().zip(&s).for_each(|(a, b)| *a += b);
            }
        }
        let inv_mean = (1.0 / mean) as f32;
        for g in g_flow.iter_mut().chain(g_sel.iter_mut().flatten()) {
            *g *= inv_mean;
        }
        Ok((
            stats,
            Some(StepGradients {
                flow: g_flow,
                selection: g_sel,
            }),
        ))
    }

    /// One part of a step of `n` records ([`NisGuide::gradients`]): both networks forward and
    /// back with the records' weights `F/(p_s·scale)` (KL) or `F²/(p_s·q_mix·scale)` (χ²), not
    /// yet divided by the batch's mean weight.
    fn part_gradients(
        &self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
        n: usize,
    ) -> nis::Result<PartGradients> {
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let x: Vec<f32> = batch.iter().flat_map(|s| s.x).collect();
        let evaluated = self.flow.log_density_for_training(&x, Some(&context))?;
        let (tapes, c) = self.select(&context);
        let m = self.config.min_selection;
        let mut out = PartGradients {
            selection_sum: c.iter().map(|&c| f64::from(c)).sum(),
            ..PartGradients::default()
        };
        let mut w_flow = vec![0.0f32; batch.len()];
        let mut g_logit = vec![0.0f32; batch.len()];
        for (i, (s, &log_q)) in batch.iter().zip(&evaluated.log_q).enumerate() {
            let q = (log_q.exp() as f32) * s.jacobian;
            let q_mix = c[i] * q + (1.0 - c[i]) * s.bsdf_pdf;
            let w = match self.config.loss {
                GuideLoss::Kl => s.kl_weight(),
                GuideLoss::ChiSquare => {
                    f64::from(s.f) * f64::from(s.f) / (f64::from(s.pdf) * f64::from(q_mix))
                }
            } / scales[i];
            let w = if w.is_finite() { w } else { 0.0 };
            out.weight += w;
            out.loss += match self.config.loss {
                GuideLoss::Kl => -w * f64::from(q_mix).ln(),
                GuideLoss::ChiSquare => w,
            };
            if q_mix > 0.0 {
                w_flow[i] = (w * f64::from(c[i] * q / q_mix) / n as f64) as f32;
                // The logit's sigmoid, and the mixture's derivative in c.
                let sig = (c[i] - m) / (1.0 - 2.0 * m);
                let d_c = (f64::from(q - s.bsdf_pdf) / f64::from(q_mix)) as f32;
                g_logit[i] =
                    (-w * f64::from(d_c * (1.0 - 2.0 * m) * sig * (1.0 - sig)) / n as f64) as f32;
            }
        }
        out.flow = self.flow.backward(&evaluated.tape, &w_flow)?;
        out.selection = selection.then(|| {
            let g_out = g_logit.chunks(CHUNK_ROWS).map(<[f32]>::to_vec).collect();
            let refs: Vec<&MlpTape> = tapes.iter().collect();
            let mut g = vec![0.0; self.selection_params.len()];
            self.selection
                .backward(&self.selection_params, &refs, g_out, &mut g, false);
            g
        });
        Ok(out)
    }

    /// The constant `c ∈ [c_min, 1 − c_min]` that maximises `Σ (F/p_s)·ln(c·p_flow + (1 − c)·p_bsdf)`
    /// over the records `batch` stands for (favoured by `scales`), a concave function of `c`:
    /// bisection on its derivative.
    fn best_constant_selection(&self, batch: &[Sample], scales: &[f64]) -> f64 {
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let x: Vec<f32> = batch.iter().flat_map(|s| s.x).collect();
        let Ok(log_q) = self.flow.log_density(&x, Some(&context)) else {
            return f64::NAN;
        };
        let terms: Vec<(f64, f64, f64)> = batch
            .iter()
            .zip(&log_q)
            .zip(scales)
            .map(|((s, l), scale)| {
                let q = l.exp() * f64::from(s.jacobian);
                (s.kl_weight() / scale, q, f64::from(s.bsdf_pdf))
            })
            .filter(|(w, q, _)| w.is_finite() && q.is_finite())
            .collect();
        let slope = |c: f64| -> f64 {
            terms
                .iter()
                .map(|&(w, q, b)| w * (q - b) / (c * q + (1.0 - c) * b).max(f64::MIN_POSITIVE))
                .sum()
        };
        let m = f64::from(self.config.min_selection);
        let (mut lo, mut hi) = (m, 1.0 - m);
        if slope(lo) <= 0.0 {
            return lo;
        }
        if slope(hi) >= 0.0 {
            return hi;
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if slope(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Share of the flow's samples at the vertices of the records `batch` stands for (favoured
    /// by `scales`, so each counts 1/s) that fall on the other side of the surface from ω_o
    /// (below it at opaque vertices).
    fn below_surface(&self, batch: &[Sample], scales: &[f64], rng: &mut Pcg64Mcg) -> f64 {
        if self.config.frame == GuideFrame::Local {
            // Nothing of the hemisphere map lies below the surface (and the sphere map is for
            // the transmissive vertices, where the other side is not below the surface).
            return 0.0;
        }
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let z: Vec<f32> = (0..2 * batch.len()).map(|_| rng.random()).collect();
        let Ok((x, _)) = self.flow.inverse(&z, Some(&context)) else {
            return f64::NAN;
        };
        // World frame: the context holds ω_o and the normal in world coordinates (this counts
        // transmission at transmissive vertices too; the built-in scenes have none).
        let (below, all) = batch.iter().zip(x.chunks_exact(2)).zip(scales).fold(
            (0.0, 0.0),
            |(below, all), ((s, x), scale)| {
                let c = &s.context;
                let n = super::cylindrical_to_dir(Vec2::new(c[5], c[6]));
                let wo = super::cylindrical_to_dir(Vec2::new(c[3], c[4]));
                let wi = super::cylindrical_to_dir(Vec2::new(x[0], x[1]));
                let count = 1.0 / scale;
                let under = n.dot(wi) * n.dot(wo) < 0.0;
                (below + if under { count } else { 0.0 }, all + count)
            },
        );
        if all > 0.0 {
            below / all
        } else {
            0.0
        }
    }

    /// Train on the records of the pass that just ended (the `iteration`-th training phase).
    fn train(&mut self, new: PassSamples, iteration: usize) {
        let start = std::time::Instant::now();
        let new_records = new.seen;
        // A pass brings up to millions of 52-byte records: the copy and the first touch of the new
        // pages run on both cores, in the same order (0.044 → 0.021 s over the five phases of a
        // 128², 64-spp cornell-box).
        self.buffer.par_extend(new.samples.par_iter().copied());
        if self.buffer.len() > self.config.buffer {
            let excess = self.buffer.len() - self.config.buffer;
            self.buffer.drain(..excess);
        }
        let mut stats = TrainingStats {
            new_records,
            ..TrainingStats::default()
        };
        if !self.buffer.is_empty() {
            let steps = (new_records / self.config.batch)
                .clamp(self.config.min_steps, self.config.max_steps);
            if let Some(a) = &mut self.average {
                a.resume(&mut [self.flow.params_mut(), &mut self.selection_params]);
                a.set_decay(ParamAverage::span_decay(
                    f64::from(self.config.average_span),
                    steps,
                ));
            }
            let phase = iteration as u64 + 1;
            let mut rng = Pcg64Mcg::seed_from_u64(self.config.seed ^ phase << PHASE_SEED_SHIFT);
            let size = self.config.batch.min(self.buffer.len());
            let alpha = picks::phase_alpha(
                f64::from(self.config.pick_by_weight),
                steps * size,
                self.buffer.len(),
            );
            let picker = RecordPicker::new(self.buffer.par_iter().map(Sample::kl_weight), alpha);
            let mut scales: Vec<f64> = Vec::with_capacity(size);
            let mut batch = Vec::with_capacity(size);
            let mut picks = Vec::with_capacity(size);
            for _ in 0..steps {
                // The indices from the phase's stream in order, and their records: a serial
                // gather, as two parallel loops over 256 records cost more than they shared
                // (picks and gathers of a 128², 64-spp cornell-box's five phases: 0.032–0.037 s
                // serial, 0.043–0.052 s parallel).
                picker.pick(size, &mut rng, &mut picks);
                batch.clear();
                batch.extend(picks.iter().map(|&i| self.buffer[i]));
                scales.clear();
                scales.extend(batch.iter().map(|s| picker.scale(s.kl_weight())));
                let selection = self.history.len() >= self.config.selection_warmup;
                match self.step(&batch, &scales, selection) {
                    Ok(s) => {
                        stats.mean_selection = s.mean_selection;
                        stats.loss = s.loss;
                        stats.steps += 1;
                        if let Some(a) = &mut self.average {
                            a.add(&[self.flow.params(), &self.selection_params]);
                        }
                    }
                    // A non-finite gradient (a rare huge weight) skips the step.
                    Err(_) => continue,
                }
            }
            self.trained = true;
            if let Some(a) = &mut self.average {
                a.use_average(&mut [self.flow.params_mut(), &mut self.selection_params]);
            }
            self.refresh_context_weights();
            stats.below_surface = self.below_surface(&batch, &scales, &mut rng);
            stats.best_constant_selection = self.best_constant_selection(&batch, &scales);
        }
        stats.seconds = start.elapsed().as_secs_f64();
        self.history.push(stats);
    }
}

impl Guide for NisGuide {
    /// What every query at a vertex shares: per vertex, the first layer's pre-activations of
    /// every conditioner and then of the selection network due to the context, bias included
    /// (see the module docs), `rows × first_width`.
    type Prepared = Vec<f32>;
    type Statistics = PassSamples;

    /// Encodes each vertex's context once and multiplies it with the context's columns of
    /// every network's first layer, chunk by chunk.
    fn prepare(&self, vertices: &[GuideVertex], cache: &mut Vec<f32>) {
        let (cdim, width, k) = (
            self.selection.dims[0],
            self.first_width,
            self.config.context_bins,
        );
        cache.clear();
        cache.resize(vertices.len() * width, 0.0);
        cache
            .par_chunks_mut(CHUNK_ROWS * width)
            .zip(vertices.par_chunks(CHUNK_ROWS))
            .for_each(|(out, v)| {
                let scalars: Vec<f32> = v
                    .iter()
                    .flat_map(|v| self.context_scalars(v, &self.map(v)))
                    .collect();
                let mut enc = vec![0.0f32; v.len() * cdim];
                one_blob(&scalars, k, &mut enc);
                dense::forward(
                    &enc,
                    &self.context_weights,
                    &self.context_bias,
                    out,
                    Shape::rows(v.len(), cdim, width),
                );
            });
    }

    /// The selection network from its cached first layer on.
    fn selection_probabilities(&self, _: &[GuideVertex], cache: &Vec<f32>, out: &mut [f32]) {
        if !self.trained {
            out.fill(0.0);
            return;
        }
        let (width, off) = (
            self.first_width,
            *self.first_offsets.last().expect("selection"),
        );
        let h = self.selection.dims[1];
        let m = self.config.min_selection;
        out.par_chunks_mut(CHUNK_ROWS)
            .zip(cache.par_chunks(CHUNK_ROWS * width))
            .for_each(|(out, first)| {
                // The first layer comes from the cache; the dense layers size the others.
                let mut acts = vec![Vec::new(); self.selection.dims.len()];
                acts[1] = vec![0.0; out.len() * h];
                let mut tape = MlpTape {
                    rows: out.len(),
                    acts,
                };
                for (row, f) in tape.acts[1]
                    .chunks_exact_mut(h)
                    .zip(first.chunks_exact(width))
                {
                    row.copy_from_slice(&f[off..off + h]);
                }
                relu(&mut tape.acts[1]);
                self.selection
                    .forward_from(&self.selection_params, &mut tape, 1);
                let z = tape.acts.last().expect("output layer");
                for (o, &z) in out.iter_mut().zip(z) {
                    *o = m + (1.0 - 2.0 * m) * sigmoid(z);
                }
            });
    }

    fn sample_batch(
        &self,
        vertices: &[GuideVertex],
        cache: &Vec<f32>,
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        let vertex: Vec<usize> = queries.iter().map(|q| q.vertex).collect();
        let mut x: Vec<f32> = queries
            .iter()
            .flat_map(|q| [q.u.x.clamp(0.0, 1.0), q.u.y.clamp(0.0, 1.0)])
            .collect();
        let log_q = self.flow_cached(cache, &vertex, &mut x, Direction::Inverse);
        for ((o, q), (x, log_q)) in out
            .iter_mut()
            .zip(queries)
            .zip(x.chunks_exact(2).zip(log_q))
        {
            let map = self.map(&vertices[q.vertex]);
            let pdf = (log_q.exp() as f32) * map.jacobian();
            *o = (pdf.is_finite() && pdf > 0.0).then(|| GuideSample {
                wi: map.to_direction(Vec2::new(x[0], x[1])),
                pdf,
            });
        }
    }

    /// Directions below the surface of an opaque vertex have density zero (the flow is asked
    /// about the square's centre in their place, and its answer discarded).
    fn pdf_batch(
        &self,
        vertices: &[GuideVertex],
        cache: &Vec<f32>,
        queries: &[PdfQuery],
        out: &mut [f32],
    ) {
        let vertex: Vec<usize> = queries.iter().map(|q| q.vertex).collect();
        let squares: Vec<(Option<Vec2>, f32)> = queries
            .iter()
            .map(|q| {
                let map = self.map(&vertices[q.vertex]);
                (map.to_square(q.wi), map.jacobian())
            })
            .collect();
        let mut x: Vec<f32> = squares
            .iter()
            .flat_map(|(x, _)| x.unwrap_or(Vec2::splat(0.5)).to_array())
            .collect();
        let log_q = self.flow_cached(cache, &vertex, &mut x, Direction::Forward);
        for ((o, l), (x, jacobian)) in out.iter_mut().zip(log_q).zip(squares) {
            let pdf = (l.exp() as f32) * jacobian;
            *o = if x.is_some() && pdf.is_finite() {
                pdf
            } else {
                0.0
            };
        }
    }

    fn batch_paths(&self) -> usize {
        8192
    }

    fn guided_bounces(&self) -> u32 {
        u32::try_from(self.config.guided_bounces).unwrap_or(u32::MAX)
    }

    fn wants_records(&self) -> bool {
        self.training
    }

    fn accumulate(&self, records: &[GuideRecord], pass: &mut PassSamples) {
        let before = pass.samples.len();
        pass.samples.extend(records.iter().filter_map(|r| {
            let f = luminance(r.radiance * r.bsdf_cos);
            let map = self.map(&r.vertex);
            // A direction off the map carries no light at an opaque vertex (its F is 0 up to
            // the rounding of the two frames).
            let x = map.to_square(r.wi)?;
            (f > 0.0 && f.is_finite() && r.pdf > 0.0).then(|| Sample {
                context: self.context_scalars(&r.vertex, &map),
                x: x.to_array(),
                f,
                pdf: r.pdf,
                bsdf_pdf: r.bsdf_pdf,
                jacobian: map.jacobian(),
            })
        }));
        pass.seen += pass.samples.len() - before;
        pass.cap = Some(self.config.buffer);
        pass.trim();
    }

    fn update(&mut self, samples: PassSamples) {
        if self.training {
            // Phases are counted by the guide itself: the `k`-th update draws its batches from
            // the `k`-th stream.
            self.train(samples, self.history.len());
        }
    }

    fn end_training(&mut self) {
        self.training = false;
        self.buffer = Vec::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A guide whose networks have random weights everywhere (a new one is uniform), and
    /// vertices, directions and random numbers to query it with.
    fn random_guide(frame: GuideFrame) -> (NisGuide, Vec<GuideVertex>, Vec<Vec3>, Vec<Vec2>) {
        let bounds = Aabb {
            min: Vec3::new(-1.0, 0.0, -2.0),
            max: Vec3::new(1.0, 2.0, 0.5),
        };
        let config = NisGuideConfig {
            frame,
            ..NisGuideConfig::default()
        };
        let mut guide = NisGuide::new(bounds, config).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(11);
        for p in guide.flow.params_mut() {
            *p += 0.3 * (rng.random::<f32>() - 0.5);
        }
        for p in &mut guide.selection_params {
            *p += 0.3 * (rng.random::<f32>() - 0.5);
        }
        guide.refresh_context_weights();
        guide.trained = true;
        let mut unit = || {
            let v = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
            v.normalize_or(Vec3::Z)
        };
        // More than a chunk of vertices, so rows are gathered across chunks.
        let vertices: Vec<GuideVertex> = (0..700)
            .map(|i| GuideVertex {
                p: Vec3::new(
                    -1.0 + 2.0 * (i as f32 * 0.37).fract(),
                    2.0 * (i as f32 * 0.61).fract(),
                    -2.0 + 2.5 * (i as f32 * 0.13).fract(),
                ),
                n: unit(),
                wo: unit(),
                transmissive: i % 3 == 0,
            })
            .collect();
        let dirs = (0..1500).map(|_| unit()).collect();
        let us = (0..1500)
            .map(|_| Vec2::new(rng.random(), rng.random()))
            .collect();
        (guide, vertices, dirs, us)
    }

    /// The flow's own (uncached) context rows of the vertices `rows` refers to.
    fn uncached_context(guide: &NisGuide, v: &[GuideVertex], rows: &[usize]) -> Vec<f32> {
        let s: Vec<_> = rows
            .iter()
            .map(|&r| guide.context_scalars(&v[r], &guide.map(&v[r])))
            .collect();
        guide.encode(&s)
    }

    /// A training batch of `n` records with random contexts, directions and weights.
    fn random_batch(n: usize, seed: u64) -> (Vec<Sample>, Vec<f64>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let batch = (0..n)
            .map(|_| Sample {
                context: std::array::from_fn(|_| rng.random()),
                x: [rng.random(), rng.random()],
                f: if rng.random::<f32>() < 0.2 {
                    0.0
                } else {
                    rng.random::<f32>() * 3.0
                },
                pdf: 0.05 + rng.random::<f32>(),
                bsdf_pdf: 0.05 + rng.random::<f32>(),
                jacobian: 0.25 * std::f32::consts::FRAC_1_PI,
            })
            .collect();
        let scales = (0..n).map(|_| 0.5 + rng.random::<f64>()).collect();
        (batch, scales)
    }

    #[test]
    fn a_step_in_parts_has_the_whole_batch_gradients() {
        let (guide, ..) = random_guide(GuideFrame::World);
        let (batch, scales) = random_batch(256, 5);
        let (s_parts, g_parts) = guide.gradients(&batch, &scales, true, 64).unwrap();
        let (s_whole, g_whole) = guide.gradients(&batch, &scales, true, 256).unwrap();
        let (g_parts, g_whole) = (g_parts.unwrap(), g_whole.unwrap());
        assert!((s_parts.loss - s_whole.loss).abs() <= 1e-12 * s_whole.loss.abs());
        for (a, b) in [
            (&g_parts.flow, &g_whole.flow),
            (
                g_parts.selection.as_ref().unwrap(),
                g_whole.selection.as_ref().unwrap(),
            ),
        ] {
            // Sums of 256 f32 terms in another order: within a few roundings of the largest.
            let scale = b.iter().fold(0.0f32, |m, g| m.max(g.abs()));
            assert!(scale > 0.0);
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-5 * scale, "{x} against {y}");
            }
        }
    }

    /// Parameter `j` of the flow (`network` 0) or of the selection network (1).
    fn param(g: &mut NisGuide, network: usize, j: usize) -> &mut f32 {
        if network == 0 {
            &mut g.flow.params_mut()[j]
        } else {
            &mut g.selection_params[j]
        }
    }

    #[test]
    fn step_gradients_are_those_of_the_kl_loss() {
        let (mut guide, ..) = random_guide(GuideFrame::World);
        let (batch, scales) = random_batch(256, 6);
        let loss = |g: &NisGuide| g.gradients(&batch, &scales, true, 64).unwrap().0.loss;
        let grads = guide
            .gradients(&batch, &scales, true, 64)
            .unwrap()
            .1
            .unwrap();
        let selection = grads.selection.unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        let h = 1e-3f32;
        for (network, grad) in [(0, &grads.flow), (1, &selection)] {
            // The eight steepest parameters, and four at random.
            let mut order: Vec<usize> = (0..grad.len()).collect();
            order.sort_by(|&a, &b| grad[b].abs().total_cmp(&grad[a].abs()));
            order.truncate(8);
            order.extend((0..4).map(|_| rng.random_range(0..grad.len())));
            assert!(grad[order[7]].abs() > 1e-2, "too flat to test");
            for j in order {
                let x = *param(&mut guide, network, j);
                *param(&mut guide, network, j) = x + h;
                let up = loss(&guide);
                *param(&mut guide, network, j) = x - h;
                let down = loss(&guide);
                *param(&mut guide, network, j) = x;
                let fd = (up - down) / (2.0 * f64::from(h));
                // Central differences of an f32 network: truncation O(h²), rounding ≈ 1e-7/h.
                let g = f64::from(grad[j]);
                assert!(
                    (fd - g).abs() <= 2e-3 + 0.02 * g.abs(),
                    "network {network}, parameter {j}: {g} against finite differences {fd}"
                );
            }
        }
    }

    #[test]
    fn the_guide_serves_a_positive_number_of_bounces_or_all() {
        let bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let guide = |guided_bounces| {
            NisGuide::new(
                bounds,
                NisGuideConfig {
                    guided_bounces,
                    ..NisGuideConfig::default()
                },
            )
        };
        assert_eq!(guide(1).unwrap().guided_bounces(), 1);
        assert_eq!(guide(4).unwrap().guided_bounces(), 4);
        assert_eq!(guide(-1).unwrap().guided_bounces(), u32::MAX);
        for bad in [0, -2, i32::MIN] {
            let e = guide(bad).err().expect("rejected");
            assert!(e.to_string().contains("bounce"), "{e}");
        }
    }

    #[test]
    fn cached_queries_match_the_uncached_flow() {
        for frame in [GuideFrame::World, GuideFrame::Local] {
            cached_queries_match_the_uncached_flow_in(frame);
        }
    }

    fn cached_queries_match_the_uncached_flow_in(frame: GuideFrame) {
        // f32 rounding: the first layers' sums run in another order (≈ 1e-6 relative per
        // activation); through two conditioners and the splines' exponentials the density
        // moves by far less than 1e-4 relative, the sampled point by less than 1e-5.
        let (guide, vertices, dirs, us) = random_guide(frame);
        let mut cache = Vec::new();
        guide.prepare(&vertices, &mut cache);
        let rows: Vec<usize> = (0..dirs.len())
            .map(|i| (i * 7919) % vertices.len())
            .collect();
        let context = uncached_context(&guide, &vertices, &rows);

        let queries: Vec<PdfQuery> = rows
            .iter()
            .zip(&dirs)
            .map(|(&vertex, &wi)| PdfQuery { vertex, wi })
            .collect();
        let mut cached = vec![0.0; queries.len()];
        guide.pdf_batch(&vertices, &cache, &queries, &mut cached);
        let maps: Vec<DirectionMap> = rows.iter().map(|&r| guide.map(&vertices[r])).collect();
        let squares: Vec<Option<Vec2>> = maps
            .iter()
            .zip(&dirs)
            .map(|(m, &w)| m.to_square(w))
            .collect();
        let x: Vec<f32> = squares
            .iter()
            .flat_map(|x| x.unwrap_or(Vec2::splat(0.5)).to_array())
            .collect();
        let log_q = guide.flow.log_density(&x, Some(&context)).unwrap();
        let (mut spread, mut below) = (0.0f64, 0);
        for (((c, l), m), x) in cached.iter().zip(&log_q).zip(&maps).zip(&squares) {
            if x.is_none() {
                // Below the surface of an opaque vertex.
                assert_eq!(*c, 0.0);
                below += 1;
                continue;
            }
            let plain = l.exp() * f64::from(m.jacobian());
            spread = spread.max((l.exp() - 1.0).abs());
            assert!((f64::from(*c) / plain - 1.0).abs() < 1e-4, "{c} vs {plain}");
        }
        // In the local frame, a third of the random directions lie below an opaque surface.
        assert_eq!(
            frame == GuideFrame::Local,
            below > 100,
            "{below} below the surface"
        );
        // The random weights must make the density far from uniform, or the test shows little.
        assert!(spread > 0.5, "density hardly varies: {spread}");

        let queries: Vec<SampleQuery> = rows
            .iter()
            .zip(&us)
            .map(|(&vertex, &u)| SampleQuery { vertex, u })
            .collect();
        let mut samples = vec![None; queries.len()];
        guide.sample_batch(&vertices, &cache, &queries, &mut samples);
        let z: Vec<f32> = us.iter().flat_map(|u| u.to_array()).collect();
        let (x, log_det) = guide.flow.inverse(&z, Some(&context)).unwrap();
        for (i, s) in samples.iter().enumerate() {
            let s = s.expect("a sample");
            let plain = maps[i].to_direction(Vec2::new(x[2 * i], x[2 * i + 1]));
            assert!((s.wi - plain).length() < 1e-4, "{:?} vs {plain:?}", s.wi);
            let pdf = (-log_det[i]).exp() * f64::from(maps[i].jacobian());
            assert!(
                (f64::from(s.pdf) / pdf - 1.0).abs() < 1e-4,
                "{} vs {pdf}",
                s.pdf
            );
        }

        let all: Vec<usize> = (0..vertices.len()).collect();
        let (_, plain) = guide.select(&uncached_context(&guide, &vertices, &all));
        let mut cached = vec![0.0; vertices.len()];
        guide.selection_probabilities(&vertices, &cache, &mut cached);
        for (c, p) in cached.iter().zip(&plain) {
            assert!((c - p).abs() < 1e-5, "{c} vs {p}");
        }
    }

    #[test]
    fn averaging_the_weights_leaves_the_training_alone() {
        // Two guides, with and without the average, trained on the same records: the Adam
        // iterates must agree bit for bit after every phase, and the averaged guide must render
        // with other weights than its iterate.
        let sample = |i: usize| Sample {
            context: std::array::from_fn(|j| ((i * 13 + j * 5) % 17) as f32 / 17.0),
            x: [(i as f32 * 0.37).fract(), (i as f32 * 0.71).fract()],
            f: 0.1 + (i % 5) as f32,
            pdf: 1.0 / (4.0 * std::f32::consts::PI),
            bsdf_pdf: 0.1,
            jacobian: 1.0 / (4.0 * std::f32::consts::PI),
        };
        let bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let config = |average_span| NisGuideConfig {
            batch: 64,
            buffer: 1024,
            min_steps: 6,
            max_steps: 6,
            selection_warmup: 0,
            average_span,
            ..NisGuideConfig::default()
        };
        let mut plain = NisGuide::new(bounds, config(0.0)).unwrap();
        let mut averaged = NisGuide::new(bounds, config(0.5)).unwrap();
        for phase in 0..2 {
            for guide in [&mut plain, &mut averaged] {
                guide.update(PassSamples {
                    samples: (phase * 300..phase * 300 + 300).map(sample).collect(),
                    seen: 300,
                    cap: None,
                });
            }
            let a = averaged.average.as_ref().unwrap();
            assert_eq!(a.steps(), 6 * (phase as i32 + 1));
            let iterate = [plain.flow.params(), &plain.selection_params].concat();
            assert_eq!(a.iterate(), &iterate[..]);
            assert_ne!(averaged.flow.params(), plain.flow.params());
            assert_ne!(averaged.selection_params, plain.selection_params);
        }
    }

    #[test]
    fn pass_samples_cross_processes_whole() {
        // What ranks send each other: the cap, the count of records seen (beyond f32's 2^24)
        // and the kept records, bit for bit; no cap stays no cap, and a cap of 0 stays one.
        let sample = |i: usize| Sample {
            context: std::array::from_fn(|j| (i * 31 + j) as f32 * 0.37 - 5.0),
            x: [i as f32 * 0.1, -0.25],
            f: 1.5e-7 * i as f32,
            pdf: 0.3,
            bsdf_pdf: f32::MIN_POSITIVE,
            jacobian: 0.125,
        };
        let bits = |s: &Sample| {
            let mut w = Vec::new();
            super::super::Record::write(s, &mut w);
            w.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        for cap in [None, Some(0), Some(3), Some(1 << 40)] {
            let pass = PassSamples {
                samples: (0..3).map(sample).collect(),
                seen: (1 << 33) + 12_345,
                cap,
            };
            let back = PassSamples::from_words(&pass.to_words());
            assert_eq!((back.seen, back.cap), (pass.seen, pass.cap));
            assert_eq!(back.samples.len(), 3);
            for (a, b) in pass.samples.iter().zip(&back.samples) {
                assert_eq!(bits(a), bits(b));
            }
        }
        let empty = PassSamples::from_words(&PassSamples::default().to_words());
        assert_eq!((empty.seen, empty.cap, empty.samples.len()), (0, None, 0));
    }
}
