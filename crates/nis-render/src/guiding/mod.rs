//! Path guiding: learned distributions of incident light that the integrator samples directions
//! from, mixed with BSDF sampling.
//!
//! Guiding methods (Müller et al. 2017, "Practical Path Guiding"; Vorba et al. 2014, "On-line
//! Learning of Parametric Mixture Models for Light Transport Simulation"; Müller et al. 2019,
//! "Neural Importance Sampling") share one narrow interface, [`Guide`]: at a path vertex, draw
//! a direction with its density and evaluate the density of any direction; after paths finish,
//! learn from what they found ([`GuideRecord`]); and be told when a training iteration starts
//! and ends. The integrator uses the *one-sample* mixture of the guide and the BSDF: with the
//! guide's selection probability `α` it samples the guide, otherwise the BSDF, and always
//! weights by the mixture density `α p_guide + (1 − α) p_bsdf`. [`NoGuide`] (α = 0) is plain
//! unidirectional path tracing.
//!
//! Implementations: [`ppg`] (the SD-tree of practical path guiding), [`gmm`] (Gaussian
//! mixtures on the hemisphere) — both keep their directional distributions in the leaves of one
//! [`spatial`] tree — and [`neural`] (a normalizing flow). Both learn from the records of one
//! training iteration at its end, in a sorted order, so a trained guide depends only on the
//! records, never on the threads that delivered them.

use glam::{Vec2, Vec3};

use crate::bsdf::Material;
use crate::geometry::Rgb;

pub mod gmm;
pub mod neural;
pub mod ppg;
pub mod spatial;
#[cfg(test)]
mod tests;

/// Largest `f32` below 1, where coordinates in `[0, 1)` are clamped.
const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// World direction to world-space cylindrical coordinates `((cos θ + 1)/2, φ/2π)` in
/// `[0, 1)²`, θ measured from +z. The map is area preserving (Archimedes' hat-box theorem),
/// so a density `p` on the square is the solid-angle density `p / 4π` (Müller et al. 2017,
/// §5.2).
pub fn dir_to_cylindrical(w: Vec3) -> Vec2 {
    let cos_theta = w.z.clamp(-1.0, 1.0);
    let mut phi = w.y.atan2(w.x);
    if phi < 0.0 {
        phi += 2.0 * std::f32::consts::PI;
    }
    Vec2::new(
        (0.5 * (cos_theta + 1.0)).min(ONE_MINUS_EPSILON),
        (phi * (0.5 * std::f32::consts::FRAC_1_PI)).min(ONE_MINUS_EPSILON),
    )
}

/// Inverse of [`dir_to_cylindrical`].
pub fn cylindrical_to_dir(c: Vec2) -> Vec3 {
    let cos_theta = 2.0 * c.x - 1.0;
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let (sin_phi, cos_phi) = (2.0 * std::f32::consts::PI * c.y).sin_cos();
    Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)
}

/// Bit patterns of `values`, a total order key for sorting records so that learning does not
/// depend on the order in which render threads delivered them.
fn bits_key<const N: usize>(values: [f32; N]) -> [u32; N] {
    values.map(f32::to_bits)
}

/// What a guide may condition on at a path vertex (world space).
#[derive(Clone, Copy, Debug)]
pub struct GuideVertex {
    /// Position.
    pub p: Vec3,
    /// Shading normal.
    pub n: Vec3,
    /// Unit direction back along the path (towards the camera).
    pub wo: Vec3,
}

/// One training sample from a finished path: at `vertex`, direction `wi` was sampled with
/// mixture density `pdf`, and `radiance` is the (single-sample) estimate of the radiance that
/// arrived from `wi`, i.e. everything the rest of the path collected divided by the path
/// throughput up to and including this vertex's scattering.
#[derive(Clone, Copy, Debug)]
pub struct GuideRecord {
    /// Where the direction was sampled.
    pub vertex: GuideVertex,
    /// Sampled incident direction (world, unit).
    pub wi: Vec3,
    /// Mixture density the direction was drawn with.
    pub pdf: f32,
    /// The BSDF's own sampling density of `wi` (the other component of the mixture).
    pub bsdf_pdf: f32,
    /// BSDF value times `|cos θi|` for `(wo, wi)`, to learn the product if wanted.
    pub bsdf_cos: Rgb,
    /// Incident radiance estimate along `wi`.
    pub radiance: Rgb,
}

/// A directional sampling distribution that may learn from finished paths.
///
/// Implementations are shared between render threads: sampling takes `&self`, learning
/// (`record`) too (use interior mutability, e.g. a `Mutex`'d buffer), while iteration hooks
/// take `&mut self` and are called between render passes.
pub trait Guide: Send + Sync {
    /// Probability `α` of sampling the guide rather than the BSDF at this vertex; 0 disables
    /// guiding here.
    fn selection_probability(&self, vertex: &GuideVertex, material: &Material) -> f32;

    /// Draw a world-space direction and its solid-angle density.
    fn sample(&self, vertex: &GuideVertex, u: Vec2) -> Option<(Vec3, f32)>;

    /// Solid-angle density of [`Guide::sample`] producing `wi`.
    fn pdf(&self, vertex: &GuideVertex, wi: Vec3) -> f32;

    /// [`Guide::selection_probability`] for many vertices at once (`out[i]` for
    /// `vertices[i]` with `materials[i]`); override to batch the work.
    fn selection_probabilities(
        &self,
        vertices: &[GuideVertex],
        materials: &[&Material],
        out: &mut [f32],
    ) {
        for ((v, m), o) in vertices.iter().zip(materials).zip(out) {
            *o = self.selection_probability(v, m);
        }
    }

    /// [`Guide::sample`] for many vertices at once; override to batch the work.
    fn sample_batch(&self, vertices: &[GuideVertex], u: &[Vec2], out: &mut [Option<(Vec3, f32)>]) {
        for ((v, &u), o) in vertices.iter().zip(u).zip(out) {
            *o = self.sample(v, u);
        }
    }

    /// [`Guide::pdf`] for many vertices at once; override to batch the work.
    fn pdf_batch(&self, vertices: &[GuideVertex], wi: &[Vec3], out: &mut [f32]) {
        for ((v, &w), o) in vertices.iter().zip(wi).zip(out) {
            *o = self.pdf(v, w);
        }
    }

    /// How many paths the integrator should trace together as one wavefront. Guides whose
    /// queries are cheap one at a time keep the default (small batches stay in cache); a
    /// neural guide asks for thousands so that its network runs on large matrices.
    fn batch_paths(&self) -> usize {
        64
    }

    /// Whether the integrator should collect [`GuideRecord`]s (costs time; off when not
    /// training).
    fn wants_records(&self) -> bool {
        false
    }

    /// Learn from the records of a batch of finished paths.
    fn record(&self, _records: &[GuideRecord]) {}

    /// Called before render pass `iteration` starts.
    fn begin_iteration(&mut self, _iteration: usize) {}

    /// Called after render pass `iteration` has finished (e.g. to refit or train).
    fn end_iteration(&mut self, _iteration: usize) {}

    /// Called once training is over: the remaining passes only render (a guide should stop
    /// asking for records).
    fn end_training(&mut self) {}
}

/// No guiding: every direction comes from the BSDF.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoGuide;

impl Guide for NoGuide {
    fn selection_probability(&self, _: &GuideVertex, _: &Material) -> f32 {
        0.0
    }

    fn sample(&self, _: &GuideVertex, _: Vec2) -> Option<(Vec3, f32)> {
        None
    }

    fn pdf(&self, _: &GuideVertex, _: Vec3) -> f32 {
        0.0
    }
}
