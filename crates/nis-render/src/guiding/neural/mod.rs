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
//! coordinates; `ω_o` in the local frame with [`GuideFrame::Local`]). A second, small network
//! predicts the selection probability `c(x, ω_o)` of the one-sample mixture
//! `c·p_flow + (1 − c)·p_bsdf`, kept in `[c_min, 1 − c_min]` so both techniques always have a
//! share.
//!
//! Training is on-line: the flow starts as the uniform density, the first pass renders with
//! BSDF sampling only, and after every training pass (PPG's schedule of doubling sample
//! counts, see [`crate::render::training_schedule`]) both networks take Adam steps on the
//! records gathered so far. A record is a direction `ω` drawn at a vertex with mixture
//! density `p_s(ω)`, and the product `F = L_i(ω)·f_s(ω_o, ω)·|cos θ|` the path found along it
//! (luminance), the quantity the paper learns, here times the luminance of the path's
//! throughput on arrival at the vertex ([`NisGuideConfig::weight_by_throughput`]): the share of
//! the pixel the vertex's choice carries (what a vertex's sampling adds to its pixel's error
//! reaches the pixel scaled by that throughput), so the divergence is weighed over the
//! vertices as the image weighs them. With the current mixture density
//! `q = c·p_flow + (1 − c)·p_bsdf`, the gradients are the paper's off-policy ones:
//!
//! * KL: `−E_{p_s}[(F/p_s)·∇ ln q]`,
//! * χ²: `−E_{p_s}[(F²/(p_s·q))·∇ ln q]`,
//!
//! with `∇_θ ln q = (c·p_flow/q)·∇_θ ln p_flow` for the flow's weights and
//! `∂ ln q/∂c = (p_flow − p_bsdf)/q` for the selection network. The per-sample weights are
//! normalised by their batch mean, which only rescales the step. The selection network takes a
//! share of its step from the χ² gradient whatever the loss
//! ([`NisGuideConfig::selection_chi2_share`]): χ² punishes a high guide share where the flow
//! has a hole far more than KL does, and such holes are where BSDF samples become fireflies. Records of all training
//! passes stay in a bounded replay buffer (each is an unbiased sample of the same gradient,
//! whatever mixture drew it), so early passes with few paths still get enough steps. A step's
//! batch is drawn from the buffer with probabilities ∝ (F/p_s)^α, each record's weight divided
//! by (F/p_s)^α, which keeps the expected gradient ([`NisGuideConfig::pick_by_weight`],
//! `record_draw.rs`).
//! The guide renders with an exponential moving average of the weights over the Adam steps
//! ([`NisGuideConfig::average_span`]), not with the last step's, whose noise would otherwise be
//! part of every image; training goes on from the last step's.
//!
//! The path tracer traces thousands of paths as one wavefront ([`Guide::batch_paths`]), so
//! every query below runs the networks on large batches.
//!
//! **Per-vertex cache.** Every query at a vertex (its selection probability, the guide's sample,
//! the density of the BSDF sample's direction) feeds the same context to the first dense layer
//! of every conditioner and of the selection network. [`Guide::prepare`] encodes each vertex's
//! context once and computes the context's share of all those layers in one matrix product
//! ([`nis::flow::context`], the guide's [`Guide::Prepared`]); every query of the vertex starts
//! from it.
//!
//! The files: [`config`] (the settings), [`records`] (the training records and their wire
//! format), `selection.rs` (the selection network), [`training`] (gradients and Adam steps) and
//! `record_draw.rs` (which records a training batch sees).

use glam::{Vec2, Vec3};
use nis::flow::context::{ContextCache, ContextLayers};
use nis::flow::{Density, Flow};
use nis::nn::encoding::OneBlob;
use nis::nn::{Adam, ParamAverage};
use rayon::prelude::*;

use super::{
    dir_to_cylindrical,
    directions::{DirectionMap, GuideFrame},
    Guide, GuideRecord, GuideSample, GuideVertex, PdfQuery, SampleQuery,
};
use crate::bvh::Aabb;
use crate::geometry::luminance;
use selection::Selection;

pub mod config;
mod record_draw;
pub mod records;
mod selection;
#[cfg(test)]
mod tests;
pub mod training;

pub use config::{GuideLoss, NisGuideConfig};
pub use records::{PassSamples, Sample};
pub use training::TrainingStats;

/// Scalars a vertex is described by: position (3), outgoing direction (2), normal (2).
const CONTEXT_SCALARS: usize = 7;

/// Contexts per parallel work item of their one-blob encoding.
const ENCODE_ROWS: usize = 512;

/// The neural guide: a conditional flow plus a selection network, trained while rendering.
pub struct NisGuide {
    config: NisGuideConfig,
    origin: Vec3,
    inv_extent: Vec3,
    flow: Flow,
    flow_adam: Adam,
    selection: Selection,
    buffer: Vec<Sample>,
    training: bool,
    trained: bool,
    history: Vec<TrainingStats>,
    /// The context's share of the first layer of every conditioner and of the selection
    /// network, which [`Guide::prepare`] evaluates per vertex. Rebuilt after every update.
    context: ContextLayers,
    /// The moving average of both networks' weights, flow first ([`NisGuideConfig::average_span`]),
    /// if any: between training phases the networks hold it, and it holds the Adam iterates.
    average: Option<ParamAverage>,
}

impl NisGuide {
    /// A new (uniform, untrained) guide for a scene inside `bounds`.
    pub fn new(bounds: Aabb, config: NisGuideConfig) -> nis::Result<NisGuide> {
        config.validate()?;
        let context_dim = CONTEXT_SCALARS * config.context_bins;
        let flow = Flow::new(config.flow_config())?;
        let flow_adam = Adam::new(config.adam(), flow.param_count())?;
        let selection = Selection::new(context_dim, &config)?;
        let extent = (bounds.max - bounds.min).max(Vec3::splat(1e-6));
        // A small margin keeps positions on the bounding box's faces inside the encoding.
        let margin = 0.01 * extent;
        let mut guide = NisGuide {
            flow_adam,
            flow,
            selection,
            origin: bounds.min - margin,
            inv_extent: (extent + 2.0 * margin).recip(),
            config,
            buffer: Vec::new(),
            training: true,
            trained: false,
            history: Vec::new(),
            context: ContextLayers::default(),
            average: None,
        };
        if guide.config.average_span > 0.0 {
            // Its decay is set by every training phase.
            guide.average = Some(ParamAverage::new(
                0.0,
                &[guide.flow.params(), &guide.selection.params],
            ));
        }
        guide.refresh_context();
        Ok(guide)
    }

    /// Takes the context's share of every network's first layer ([`NisGuide::context`]) from
    /// the current weights.
    fn refresh_context(&mut self) {
        let selection = (&self.selection.mlp, &self.selection.params[..]);
        self.context = ContextLayers::new(&self.flow, &[selection])
            .expect("the guide's flow is conditioned on the selection network's input");
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
            GuideFrame::World => (dir_to_cylindrical(v.wo), v.n),
            GuideFrame::Local => {
                let wo = map.to_local(v.wo);
                let wo = Vec2::new(wo.z.clamp(0.0, 1.0), dir_to_cylindrical(wo).y);
                (wo, map.normal())
            }
        };
        let n = dir_to_cylindrical(n);
        [p.x, p.y, p.z, wo.x, wo.y, n.x, n.y]
    }

    /// One-blob features of context scalars, `rows × 7·bins`.
    fn encode(&self, scalars: &[[f32; CONTEXT_SCALARS]]) -> Vec<f32> {
        let blob = self.blob();
        let mut out = vec![0.0; scalars.len() * CONTEXT_SCALARS * blob.bins];
        out.par_chunks_mut(ENCODE_ROWS * CONTEXT_SCALARS * blob.bins)
            .zip(scalars.par_chunks(ENCODE_ROWS))
            .for_each(|(out, s)| blob.encode(s.as_flattened(), out));
        out
    }

    /// The one-blob encoding of each context scalar.
    fn blob(&self) -> OneBlob {
        OneBlob {
            bins: self.config.context_bins,
        }
    }
}

impl Guide for NisGuide {
    /// What every query at a vertex shares: the context's share of the first layer of every
    /// conditioner and of the selection network (see the module docs).
    type Prepared = ContextCache;
    type Statistics = PassSamples;

    /// Encodes each vertex's context once and multiplies it with the context's columns of
    /// every network's first layer.
    fn prepare(&self, vertices: &[GuideVertex], cache: &mut ContextCache) {
        let blob = self.blob();
        let encode = |rows: std::ops::Range<usize>, out: &mut [f32]| {
            let scalars: Vec<f32> = vertices[rows]
                .iter()
                .flat_map(|v| self.context_scalars(v, &self.map(v)))
                .collect();
            blob.encode(&scalars, out);
        };
        self.context.cache(vertices.len(), encode, cache);
    }

    /// The selection network from its cached first layer on.
    fn selection_probabilities(&self, _: &[GuideVertex], cache: &ContextCache, out: &mut [f32]) {
        if !self.trained {
            out.fill(0.0);
            return;
        }
        self.selection.cached(cache, out);
    }

    fn sample_batch(
        &self,
        vertices: &[GuideVertex],
        cache: &ContextCache,
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        let vertex: Vec<usize> = queries.iter().map(|q| q.vertex).collect();
        let z: Vec<f32> = queries
            .iter()
            .flat_map(|q| [q.u.x.clamp(0.0, 1.0), q.u.y.clamp(0.0, 1.0)])
            .collect();
        let (x, log_det) = self
            .flow
            .inverse_cached(&z, cache, &vertex)
            .expect("queries refer to the prepared vertices");
        for ((o, q), (x, log_det)) in out
            .iter_mut()
            .zip(queries)
            .zip(x.chunks_exact(2).zip(log_det))
        {
            let map = self.map(&vertices[q.vertex]);
            let pdf = ((-log_det).exp() as f32) * map.jacobian();
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
        cache: &ContextCache,
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
        let x: Vec<f32> = squares
            .iter()
            .flat_map(|(x, _)| x.unwrap_or(Vec2::splat(0.5)).to_array())
            .collect();
        let log_q = self
            .flow
            .log_density_cached(&x, cache, &vertex)
            .expect("queries refer to the prepared vertices");
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

    fn narrowest_lobe(&self) -> f32 {
        self.config.narrowest_lobe_degrees.to_radians()
    }

    fn wants_records(&self) -> bool {
        self.training
    }

    fn accumulate(&self, records: &[GuideRecord], pass: &mut PassSamples) {
        let before = pass.samples.len();
        pass.samples.extend(records.iter().filter_map(|r| {
            let f = luminance(r.radiance * r.bsdf_cos)
                * if self.config.weight_by_throughput {
                    r.throughput
                } else {
                    1.0
                };
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
