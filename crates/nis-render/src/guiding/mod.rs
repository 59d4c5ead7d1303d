//! Path guiding: learned distributions of incident light that the path tracer samples directions
//! from, mixed with BSDF sampling.
//!
//! Guiding methods (Müller et al. 2017, "Practical Path Guiding"; Vorba et al. 2014, "On-line
//! Learning of Parametric Mixture Models for Light Transport Simulation"; Müller et al. 2019,
//! "Neural Importance Sampling") share one narrow interface, [`Guide`]: at a batch of path
//! vertices, give the selection probability, draw directions with their densities and evaluate
//! the density of any direction; after paths finish, accumulate what they found
//! ([`GuideRecord`]) into statistics and learn from them. The path tracer uses the *one-sample*
//! mixture of the guide and the BSDF: with the guide's selection probability `α` it samples the
//! guide, otherwise the BSDF, and always weights by the mixture density
//! `α p_guide + (1 − α) p_bsdf`; vertices with a delta BSDF are never guided, nor are those
//! beyond a guide's [`Guide::guided_bounces`]. [`NoGuide`]
//! (α = 0) is plain unidirectional path tracing.
//!
//! Implementations: [`ppg`] (the SD-tree of practical path guiding), [`gmm`] (Gaussian
//! mixtures on the hemisphere) — both keep their directional distributions in the leaves of one
//! [`spatial`] tree — and [`neural`] (a normalizing flow). The classical guides learn from the
//! records of one training pass in a sorted order, so a trained guide depends only on the
//! records, never on the order in which they arrived.

use glam::{Vec2, Vec3};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::geometry::Rgb;

pub mod directions;
pub mod factory;
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
    let mut phi = atan2(w.y, w.x);
    if phi < 0.0 {
        phi += 2.0 * std::f32::consts::PI;
    }
    Vec2::new(
        (0.5 * (cos_theta + 1.0)).min(ONE_MINUS_EPSILON),
        (phi * (0.5 * std::f32::consts::FRAC_1_PI)).min(ONE_MINUS_EPSILON),
    )
}

/// atan2(y, x) in [−π, π] without libm, to within 6.8·10⁻⁷ (its error budget, which a test
/// holds it to over the circle; a correctly rounded f32 result is within 1.2·10⁻⁷): atan of
/// the ratio of the smaller to the larger magnitude, in [0, 1], by an odd polynomial of degree
/// 15 (least-squares fit weighted toward minimax, error 8.9·10⁻⁸ there), then moved to its
/// octant. Every guide maps its queries' directions through it, so libm's atan2 showed in a
/// guided render's profile (docs/results/guiding.md, "Profile of a guided render").
/// atan2(±0, ±0) is 0.
#[inline]
fn atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    const C: [f32; 8] = [
        0.999_999_9,
        -0.333_320_94,
        0.199_713_75,
        -0.140_294_18,
        0.099_427_54,
        -0.059_904_63,
        0.024_557_056,
        -0.004_780_434_5,
    ];
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    if hi == 0.0 {
        return 0.0;
    }
    let a = lo / hi;
    let t = a * a;
    // Horner's scheme from the highest coefficient (0·t + C[7] is exactly C[7]).
    let mut r = a * C.iter().rev().fold(0.0, |p, &c| p * t + c);
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
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
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct GuideVertex {
    /// Position.
    pub p: Vec3,
    /// Shading normal.
    pub n: Vec3,
    /// Unit direction back along the path (towards the camera).
    pub wo: Vec3,
    /// Whether the material may transmit light through the surface; where it does not, all
    /// scattered light leaves on `wo`'s side of the shading normal.
    pub transmissive: bool,
}

/// One training sample from a finished path: at `vertex`, direction `wi` was sampled with
/// mixture density `pdf`, and `radiance` is the (single-sample) estimate of the radiance that
/// arrived from `wi`, i.e. everything the rest of the path collected divided by the path
/// throughput up to and including this vertex's scattering.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
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
    /// Luminance of the path's throughput on arrival at the vertex: how much of what the
    /// vertex scatters reaches the image (1 at the camera ray's hit).
    pub throughput: f32,
}

/// A direction drawn from a guide, with the solid-angle density it was drawn with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuideSample {
    /// World-space unit direction.
    pub wi: Vec3,
    /// Solid-angle density of `wi` under the guide (positive).
    pub pdf: f32,
}

/// A request for a guide sample at vertex `vertex` of a batch, from the random numbers `u`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleQuery {
    /// Index of the vertex in the batch.
    pub vertex: usize,
    /// Two uniform numbers in `[0, 1)`.
    pub u: Vec2,
}

/// A request for the guide's density of direction `wi` at vertex `vertex` of a batch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PdfQuery {
    /// Index of the vertex in the batch.
    pub vertex: usize,
    /// World-space unit direction.
    pub wi: Vec3,
}

/// What a guide accumulates from records until its next update: a plain value (numbers and
/// vectors of them, no locks or handles) with an associative, order-respecting `merge`, so the
/// statistics of several waves, threads or processes can be combined (e.g. gathered or summed
/// over MPI ranks) before one update that every process then applies alike.
///
/// Between processes they travel as bytes of their serde form ([`to_bytes`], [`from_bytes`]).
pub trait GuideStatistics: Default + Send + Serialize + DeserializeOwned {
    /// Add `later`'s statistics after this one's.
    fn merge(&mut self, later: Self);
}

/// Nothing to learn from.
impl GuideStatistics for () {
    fn merge(&mut self, _: Self) {}
}

/// Records (reduced to what a guide keeps), in the order they were made.
impl<T: Send + Serialize + DeserializeOwned> GuideStatistics for Vec<T> {
    fn merge(&mut self, later: Self) {
        self.extend(later);
    }
}

/// Statistics as bytes, to send to other processes: postcard's compact serde form (floats bit
/// for bit, counts as varints).
pub fn to_bytes<S: GuideStatistics>(statistics: &S) -> Vec<u8> {
    postcard::to_allocvec(statistics).expect("guide statistics are plain values")
}

/// The statistics [`to_bytes`] made; `None` for bytes that are not such statistics.
pub fn from_bytes<S: GuideStatistics>(bytes: &[u8]) -> Option<S> {
    postcard::from_bytes(bytes).ok()
}

/// The narrowest glossy lobe a guide serves by default ([`Guide::narrowest_lobe`]): the
/// half-angle, in degrees, of the cone around the mirror direction that holds 90% of a rough
/// conductor's or dielectric's scattering. Narrower lobes (metal and glass of roughness below
/// about 0.066 in GGX or 0.13 in Beckmann) are left to BSDF sampling, which already follows
/// them closely while the light varies little across them: a guide learned from a few samples
/// per region rarely resolves them (the neural guide's 16 spline bins span 22.5° of azimuth
/// each), and its share of the samples there only adds variance (docs/results/guiding.md,
/// "Settings that set the guide's defaults", "Narrow lobes left to the BSDF").
pub const NARROWEST_LOBE_DEGREES: f32 = 22.5;

/// A directional sampling distribution over incident directions at path vertices, mixed with
/// BSDF sampling, that may learn from finished paths.
///
/// **Queries come in batches.** In every bounce of a wavefront the path tracer gathers the
/// guided vertices, calls [`Guide::prepare`] once for all of them, then asks
/// [`Guide::selection_probabilities`] and answers [`SampleQuery`]s and [`PdfQuery`]s that refer
/// to those vertices by index. Per-vertex work that every query shares (a neural guide's
/// encoded context, a classical guide's spatial lookup) goes into [`Guide::Prepared`] and is
/// done once. [`Guide::selection_probability`], [`Guide::sample`] and [`Guide::pdf`] are
/// one-vertex conveniences on top of the batched methods.
///
/// **Learning is accumulate, then update.** While rendering a training pass, the render loop
/// hands each wave's records to [`Guide::accumulate`] (`&self`, so waves may do it in
/// parallel) and [`merge`](GuideStatistics::merge)s the per-wave [`Guide::Statistics`] in wave
/// order; after the pass, [`Guide::update`] (`&mut self`) applies them. No guide needs
/// interior mutability, training depends only on the records and their order, never on the
/// threads, and the statistics are a plain value that several processes' renders could
/// combine before one update (the later MPI driver's reduction goes between the two steps).
///
/// ```
/// use glam::{Vec2, Vec3};
/// use nis_render::guiding::{Guide, GuideSample, GuideVertex, PdfQuery, SampleQuery};
///
/// /// Uniform directions over the sphere, chosen half of the time.
/// struct Uniform;
///
/// impl Guide for Uniform {
///     type Prepared = ();
///     type Statistics = ();
///     fn prepare(&self, _: &[GuideVertex], _: &mut ()) {}
///     fn selection_probabilities(&self, _: &[GuideVertex], _: &(), out: &mut [f32]) {
///         out.fill(0.5);
///     }
///     fn sample_batch(&self, _: &[GuideVertex], _: &(), q: &[SampleQuery], out: &mut [Option<GuideSample>]) {
///         for (q, o) in q.iter().zip(out) {
///             let wi = nis_render::sampling::square_to_uniform_sphere(q.u);
///             *o = Some(GuideSample { wi, pdf: 0.25 / std::f32::consts::PI });
///         }
///     }
///     fn pdf_batch(&self, _: &[GuideVertex], _: &(), _: &[PdfQuery], out: &mut [f32]) {
///         out.fill(0.25 / std::f32::consts::PI);
///     }
/// }
///
/// let v = GuideVertex { p: Vec3::ZERO, n: Vec3::Z, wo: Vec3::Z, transmissive: false };
/// assert_eq!(Uniform.selection_probability(&v), 0.5);
/// assert_eq!(Uniform.sample(&v, Vec2::splat(0.5)).unwrap().pdf, Uniform.pdf(&v, Vec3::X));
/// ```
pub trait Guide: Send + Sync {
    /// Per-vertex work [`Guide::prepare`] does once for a batch of vertices and every query on
    /// that batch reuses. The path tracer keeps one and hands it back, so its buffers are reused.
    type Prepared: Default + Send;

    /// What [`Guide::accumulate`] collects from records for [`Guide::update`].
    type Statistics: GuideStatistics;

    /// Do the per-vertex work for queries at `vertices` (overwriting `prepared`).
    fn prepare(&self, vertices: &[GuideVertex], prepared: &mut Self::Prepared);

    /// Probability `α` of sampling the guide rather than the BSDF at each vertex (`out[i]` for
    /// `vertices[i]`); 0 disables guiding there.
    fn selection_probabilities(
        &self,
        vertices: &[GuideVertex],
        prepared: &Self::Prepared,
        out: &mut [f32],
    );

    /// Draw a direction for each query (`None` where the guide cannot sample).
    fn sample_batch(
        &self,
        vertices: &[GuideVertex],
        prepared: &Self::Prepared,
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    );

    /// Solid-angle density of each query's direction under [`Guide::sample_batch`].
    fn pdf_batch(
        &self,
        vertices: &[GuideVertex],
        prepared: &Self::Prepared,
        queries: &[PdfQuery],
        out: &mut [f32],
    );

    /// [`Guide::selection_probabilities`] at one vertex.
    fn selection_probability(&self, vertex: &GuideVertex) -> f32 {
        let vertices = std::slice::from_ref(vertex);
        let mut prepared = Self::Prepared::default();
        self.prepare(vertices, &mut prepared);
        let mut out = [0.0];
        self.selection_probabilities(vertices, &prepared, &mut out);
        out[0]
    }

    /// [`Guide::sample_batch`] at one vertex.
    fn sample(&self, vertex: &GuideVertex, u: Vec2) -> Option<GuideSample> {
        let vertices = std::slice::from_ref(vertex);
        let mut prepared = Self::Prepared::default();
        self.prepare(vertices, &mut prepared);
        let mut out = [None];
        self.sample_batch(
            vertices,
            &prepared,
            &[SampleQuery { vertex: 0, u }],
            &mut out,
        );
        out[0]
    }

    /// [`Guide::pdf_batch`] at one vertex.
    fn pdf(&self, vertex: &GuideVertex, wi: Vec3) -> f32 {
        let vertices = std::slice::from_ref(vertex);
        let mut prepared = Self::Prepared::default();
        self.prepare(vertices, &mut prepared);
        let mut out = [0.0];
        self.pdf_batch(vertices, &prepared, &[PdfQuery { vertex: 0, wi }], &mut out);
        out[0]
    }

    /// How many paths the path tracer should trace together as one wavefront. Guides whose
    /// queries are cheap one at a time keep the default (small batches stay in cache); a
    /// neural guide asks for thousands so that its network runs on large matrices.
    fn batch_paths(&self) -> usize {
        64
    }

    /// How many bounces of a path the guide serves: the first this many vertices with a
    /// non-delta BSDF, from the camera ray's hit on. At later ones the path tracer samples the
    /// BSDF alone, asks the guide nothing and makes no records, so the guide learns only where
    /// it is used. Every bounce by default.
    fn guided_bounces(&self) -> u32 {
        u32::MAX
    }

    /// The narrowest glossy lobe the guide serves, as the half-angle (radians) of its cone
    /// ([`Bsdf::lobe_half_angle`](crate::bsdf::Bsdf::lobe_half_angle)): at a vertex whose BSDF
    /// is narrower the path tracer samples the BSDF alone, as at a delta one (the vertex still
    /// counts among [`Guide::guided_bounces`]). [`NARROWEST_LOBE_DEGREES`] by default.
    fn narrowest_lobe(&self) -> f32 {
        NARROWEST_LOBE_DEGREES.to_radians()
    }

    /// Whether the path tracer should collect [`GuideRecord`]s for this guide (costs time; off
    /// when not training).
    fn wants_records(&self) -> bool {
        false
    }

    /// Add what `records` (from finished paths, in path order) teach to `statistics`.
    fn accumulate(&self, _records: &[GuideRecord], _statistics: &mut Self::Statistics) {}

    /// Learn from the statistics of a training pass (e.g. refit the distribution, or take
    /// gradient steps).
    fn update(&mut self, _statistics: Self::Statistics) {}

    /// Called once training is over: the remaining passes only render (a guide should stop
    /// asking for records).
    fn end_training(&mut self) {}
}

/// No guiding: every direction comes from the BSDF.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoGuide;

impl Guide for NoGuide {
    type Prepared = ();
    type Statistics = ();

    fn prepare(&self, _: &[GuideVertex], _: &mut ()) {}

    fn selection_probabilities(&self, _: &[GuideVertex], _: &(), out: &mut [f32]) {
        out.fill(0.0);
    }

    fn sample_batch(
        &self,
        _: &[GuideVertex],
        _: &(),
        _: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        out.fill(None);
    }

    fn pdf_batch(&self, _: &[GuideVertex], _: &(), _: &[PdfQuery], out: &mut [f32]) {
        out.fill(0.0);
    }
}
