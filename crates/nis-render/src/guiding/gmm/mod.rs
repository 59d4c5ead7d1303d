//! Gaussian-mixture guiding after Vorba, Karlík, Šik, Ritschel & Křivánek 2014, "On-line
//! Learning of Parametric Mixture Models for Light Transport Simulation" (SIGGRAPH).
//!
//! The incident radiance on the hemisphere around the shading normal is modelled by a mixture
//! of up to eight 2-D Gaussians on the unit disk (`mixture.rs`: the area-preserving hemisphere–disk
//! map, Gaussians with their exact in-disk mass), fitted by on-line (stepwise) weighted EM
//! with a MAP prior (`em.rs`; §4–5 of the paper, Cappé & Moulines 2009 for stepwise EM), and
//! mixtures are cached in the leaves of the spatial tree shared with practical path guiding
//! ([`spatial`](super::spatial); Vorba et al. use a kd-tree). The hemisphere is the one on the
//! side of `wo` (the shading normal flipped if the surface is seen from the back); directions
//! below it (transmission) get density 0.
//!
//! Departures from Vorba et al.: the mixtures train on the path tracer's own records (the
//! radiance found along sampled directions, weighted by `radiance / pdf`), not on separate
//! photon/importon passes; the uniform "outside the disk" component of the disk map replaces their
//! truncation; the fallback uniform point of a sample that left the disk comes from a hash of
//! the two random numbers (the [`Guide`] interface gives only two); and since a mixture is in
//! local coordinates, every spatial leaf keeps six mixtures, one per dominant axis (±x, ±y,
//! ±z) of the shading normal, each in a frame whose tangent is a fixed world axis projected
//! onto the normal, so nearby normals share coordinates. A leaf splits (children inherit its
//! mixtures) when an iteration brings it more than [`GmmConfig::split_threshold`] records.
//! Each iteration's records are sorted before fitting, so the result does not depend on the
//! order in which render threads delivered them.

use glam::{DVec2, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::spatial::SpatialTree;
use super::{bits_key, Guide, GuideRecord, GuideSample, GuideVertex, PdfQuery, SampleQuery};
use crate::bvh::Aabb;
use crate::sampling::square_to_disk_concentric;
use em::OnlineMixture;
use mixture::{disk_to_hemisphere, hemisphere_to_disk, Mixture};

mod em;
mod mixture;

/// Most Gaussians per mixture.
pub const MAX_COMPONENTS: usize = 8;

/// Parameters of [`Gmm`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GmmConfig {
    /// Gaussians per mixture (1 to [`MAX_COMPONENTS`]).
    pub components: usize,
    /// A spatial leaf splits when one iteration brings it more than this many records.
    pub split_threshold: usize,
    /// Deepest spatial level.
    pub max_depth: u32,
    /// Fewest records with radiance a mixture needs to be fitted in an iteration.
    pub min_samples: usize,
    /// EM steps over each iteration's records.
    pub em_steps: usize,
    /// Stepwise-EM step size `η_t = t^(−exponent)` at the `t`-th fitted iteration (in
    /// (½, 1]; 1 averages iterations equally).
    pub step_exponent: f64,
    /// Weight of the prior relative to one iteration's (normalised) records: Dirichlet
    /// pseudo-count of all weights together, and of the covariance prior.
    pub prior_strength: f64,
    /// Prior covariance `σ₀² I` (in disk units) that MAP estimates shrink towards.
    pub prior_variance: f64,
    /// Probability of sampling the BSDF rather than the guide where a mixture is trained.
    pub bsdf_fraction: f32,
}

impl Default for GmmConfig {
    fn default() -> Self {
        Self {
            components: MAX_COMPONENTS,
            split_threshold: 4000,
            max_depth: 16,
            min_samples: 32,
            em_steps: 4,
            step_exponent: 0.7,
            prior_strength: 0.01,
            prior_variance: 0.01,
            bsdf_fraction: 0.5,
        }
    }
}

/// Normal class (dominant axis and its sign, 0..6) and the frame `(s, t, n)` of that class.
fn class_frame(n: Vec3) -> (usize, [Vec3; 3]) {
    let a = n.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let class = 2 * axis + usize::from(n[axis] < 0.0);
    // A world axis perpendicular to the dominant one is at most 54.7° from the surface plane,
    // so its projection never vanishes.
    let e = Vec3::AXES[(axis + 1) % 3];
    let s = (e - e.dot(n) * n).normalize();
    (class, [s, n.cross(s), n])
}

/// The shading normal turned to the side of `wo`: the mixtures model the light that a
/// surface reflects, arriving on the side it is seen from (two-sided surfaces seen from the
/// back included).
fn reflection_normal(v: &GuideVertex) -> Vec3 {
    if v.n.dot(v.wo) < 0.0 {
        -v.n
    } else {
        v.n
    }
}

fn to_local(frame: &[Vec3; 3], w: Vec3) -> Vec3 {
    Vec3::new(w.dot(frame[0]), w.dot(frame[1]), w.dot(frame[2]))
}

/// One training record reduced to what the mixtures need. A training pass's
/// [`Guide::Statistics`] are its samples, in the order they were made.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Sample {
    p: Vec3,
    n: Vec3,
    wi: Vec3,
    weight: f32,
}

impl Sample {
    fn key(&self) -> [u32; 10] {
        bits_key([
            self.p.x,
            self.p.y,
            self.p.z,
            self.n.x,
            self.n.y,
            self.n.z,
            self.wi.x,
            self.wi.y,
            self.wi.z,
            self.weight,
        ])
    }
}

/// A spatial leaf: the six mixtures (one per normal class), `None` until trained, and while an
/// iteration's records are fitted, those that fell into the leaf with their positions in its
/// unit cube.
#[derive(Clone, Debug, Default)]
struct Leaf {
    mixtures: [Option<OnlineMixture>; 6],
    samples: Vec<(Vec3, Sample)>,
}

impl Leaf {
    /// Split along `axis` when the leaf holds more than `threshold` samples: this leaf keeps
    /// the lower half's samples, the returned one (with copies of the mixtures) the upper's.
    fn split(&mut self, axis: usize, threshold: usize) -> Option<Leaf> {
        if self.samples.len() <= threshold {
            return None;
        }
        let mut lower = Vec::new();
        let mut upper = Vec::new();
        for (mut x, s) in self.samples.drain(..) {
            let above = x[axis] >= 0.5;
            x[axis] = 2.0 * x[axis] - f32::from(u8::from(above));
            if above {
                upper.push((x, s));
            } else {
                lower.push((x, s));
            }
        }
        self.samples = lower;
        Some(Leaf {
            mixtures: self.mixtures.clone(),
            samples: upper,
        })
    }
}

/// A vertex's spatial leaf, normal class and the local frame of that class: the per-vertex
/// work of a batch of queries ([`Guide::Prepared`]).
#[derive(Clone, Copy, Debug)]
pub struct Lookup {
    leaf: usize,
    class: usize,
    frame: [Vec3; 3],
}

/// Vorba-style Gaussian-mixture guide (see the module documentation).
///
/// ```
/// use nis_render::guiding::{gmm::{Gmm, GmmConfig}, Guide, GuideVertex};
/// let scene = nis_render::scenes::load("cornell-box").unwrap();
/// let guide = Gmm::new(scene.bounds(), GmmConfig::default());
/// let v = GuideVertex { p: glam::Vec3::ZERO, n: glam::Vec3::Z, wo: glam::Vec3::Z, transmissive: false };
/// // Untrained: uniform over the hemisphere, nothing below it.
/// let up = glam::Vec3::new(0.6, 0.0, 0.8);
/// assert!((guide.pdf(&v, up) - 0.5 / std::f32::consts::PI).abs() < 1e-6);
/// assert_eq!(guide.pdf(&v, -glam::Vec3::Z), 0.0);
/// ```
#[derive(Debug)]
pub struct Gmm {
    config: GmmConfig,
    tree: SpatialTree<Leaf>,
    iteration: u32,
    learning: bool,
}

impl Gmm {
    /// An untrained guide over the scene box `bounds` (e.g. [`crate::scene::Scene::bounds`]).
    pub fn new(bounds: Aabb, config: GmmConfig) -> Self {
        let config = GmmConfig {
            components: config.components.clamp(1, MAX_COMPONENTS),
            ..config
        };
        Self {
            config,
            tree: SpatialTree::new(bounds, Leaf::default()),
            iteration: 0,
            learning: true,
        }
    }

    /// Keep learning from records (the default) or freeze the current mixtures.
    pub fn set_learning(&mut self, learning: bool) {
        self.learning = learning;
    }

    /// Training iterations completed.
    pub fn iterations(&self) -> u32 {
        self.iteration
    }

    /// Number of spatial leaves.
    pub fn spatial_leaves(&self) -> usize {
        self.tree.leaves().len()
    }

    /// Where the mixture of `vertex` is kept, and the local frame of its normal class.
    fn lookup(&self, vertex: &GuideVertex) -> Lookup {
        let (class, frame) = class_frame(reflection_normal(vertex));
        Lookup {
            leaf: self.tree.leaf_index(vertex.p),
            class,
            frame,
        }
    }

    /// The trained mixture of a looked-up vertex, if any.
    fn mixture(&self, at: &Lookup) -> Option<&Mixture> {
        self.tree.leaf(at.leaf).mixtures[at.class]
            .as_ref()
            .map(|m| &m.mixture)
    }
}

/// Solid-angle density of `wi` under `mixture` (uniform when untrained) on the hemisphere of
/// `frame`.
fn density(mixture: Option<&Mixture>, frame: &[Vec3; 3], wi: Vec3) -> f32 {
    let w = to_local(frame, wi);
    if w.z <= 0.0 {
        return 0.0;
    }
    match mixture {
        Some(m) => (0.5 * m.pdf_disk(hemisphere_to_disk(w))) as f32,
        None => 0.5 / std::f32::consts::PI,
    }
}

/// Fit the six mixtures of a leaf to its samples (those of classes with enough of them).
fn fit_mixtures(mixtures: &mut [Option<OnlineMixture>; 6], samples: &[Sample], config: &GmmConfig) {
    let mut points: [Vec<(DVec2, f64)>; 6] = Default::default();
    for s in samples.iter().filter(|s| s.weight > 0.0) {
        let (class, frame) = class_frame(s.n);
        let w = to_local(&frame, s.wi);
        if w.z > 0.0 {
            points[class].push((hemisphere_to_disk(w), f64::from(s.weight)));
        }
    }
    for (mixture, points) in mixtures.iter_mut().zip(&points) {
        if points.len() >= config.min_samples.max(1) {
            mixture
                .get_or_insert_with(|| OnlineMixture::initial(config.components))
                .fit(points, config);
        }
    }
}

impl Guide for Gmm {
    type Prepared = Vec<Lookup>;
    type Statistics = Vec<Sample>;

    fn prepare(&self, vertices: &[GuideVertex], lookups: &mut Vec<Lookup>) {
        lookups.clear();
        lookups.extend(vertices.iter().map(|v| self.lookup(v)));
    }

    fn selection_probabilities(&self, _: &[GuideVertex], lookups: &Vec<Lookup>, out: &mut [f32]) {
        for (at, o) in lookups.iter().zip(out) {
            *o = if self.mixture(at).is_none() {
                0.0
            } else {
                1.0 - self.config.bsdf_fraction
            };
        }
    }

    fn sample_batch(
        &self,
        _: &[GuideVertex],
        lookups: &Vec<Lookup>,
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        for (q, o) in queries.iter().zip(out) {
            let at = &lookups[q.vertex];
            let mixture = self.mixture(at);
            let d = match mixture {
                Some(m) => m.sample_disk(q.u),
                None => square_to_disk_concentric(q.u).as_dvec2(),
            };
            let w = disk_to_hemisphere(d);
            let f = &at.frame;
            let wi = (w.x * f[0] + w.y * f[1] + w.z * f[2]).normalize();
            // The density of the direction returned (what `pdf(wi)` computes), not of `d`: the
            // two differ by round-off.
            let pdf = density(mixture, f, wi);
            *o = (pdf > 0.0).then_some(GuideSample { wi, pdf });
        }
    }

    fn pdf_batch(
        &self,
        _: &[GuideVertex],
        lookups: &Vec<Lookup>,
        queries: &[PdfQuery],
        out: &mut [f32],
    ) {
        for (q, o) in queries.iter().zip(out) {
            let at = &lookups[q.vertex];
            *o = density(self.mixture(at), &at.frame, q.wi);
        }
    }

    fn wants_records(&self) -> bool {
        self.learning
    }

    fn end_training(&mut self) {
        self.learning = false;
    }

    fn accumulate(&self, records: &[GuideRecord], samples: &mut Vec<Sample>) {
        samples.extend(records.iter().filter_map(|r| {
            let weight = r.radiance.max(Vec3::ZERO).element_sum() / (3.0 * r.pdf);
            (r.pdf > 0.0 && weight.is_finite()).then_some(Sample {
                p: r.vertex.p,
                n: reflection_normal(&r.vertex),
                wi: r.wi,
                weight,
            })
        }));
    }

    fn update(&mut self, mut samples: Vec<Sample>) {
        if !self.learning {
            return;
        }
        samples.sort_unstable_by_key(Sample::key);
        for s in samples {
            let at = self.tree.locate_unit(self.tree.unit_position(s.p));
            self.tree.leaves_mut()[at.leaf].samples.push((at.local, s));
        }
        let threshold = self.config.split_threshold;
        self.tree.refine(self.config.max_depth, |leaf, axis| {
            leaf.split(axis, threshold)
        });
        // Leaves are fitted independently, each from its samples in sorted order: in
        // parallel, and still deterministic.
        let config = self.config;
        self.tree.leaves_mut().par_iter_mut().for_each(|leaf| {
            let samples: Vec<Sample> = leaf.samples.drain(..).map(|(_, s)| s).collect();
            fit_mixtures(&mut leaf.mixtures, &samples, &config);
        });
        self.iteration += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_frames_are_orthonormal_and_continuous_in_the_normal() {
        for n in [
            Vec3::X,
            -Vec3::Y,
            Vec3::new(0.6, 0.0, 0.8),
            Vec3::new(-0.5, 0.5, -0.7),
        ] {
            let n = n.normalize();
            let (_, [s, t, m]) = class_frame(n);
            assert!(s.dot(t).abs() < 1e-6 && s.dot(m).abs() < 1e-6 && t.dot(m).abs() < 1e-6);
            assert!((s.cross(t) - m).length() < 1e-5);
        }
        // Normals on either side of z = 0 within the +x class share (nearly) one frame.
        let (c0, f0) = class_frame(Vec3::new(1.0, 0.0, 1e-3).normalize());
        let (c1, f1) = class_frame(Vec3::new(1.0, 0.0, -1e-3).normalize());
        assert_eq!(c0, c1);
        assert!((f0[0] - f1[0]).length() < 1e-2 && (f0[1] - f1[1]).length() < 1e-2);
    }
}
