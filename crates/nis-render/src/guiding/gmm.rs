//! Gaussian-mixture guiding after Vorba, Karlík, Šik, Ritschel & Křivánek 2014, "On-line
//! Learning of Parametric Mixture Models for Light Transport Simulation" (SIGGRAPH).
//!
//! The incident radiance on the hemisphere around the shading normal is modelled by a mixture
//! of up to eight 2-D Gaussians on the unit disk, fitted by on-line (stepwise) weighted EM
//! with a MAP prior (§4–5 of the paper; Cappé & Moulines 2009 for stepwise EM), and mixtures
//! are cached in a spatial kd-tree over the scene.
//!
//! **Hemisphere ↔ disk.** The upper hemisphere maps to the unit disk by the area-preserving
//! (Lambert azimuthal, the Shirley–Chiu uniform-hemisphere) map: a disk point `d` with
//! `r = |d|` is the direction `(d·√(2 − r²), 1 − r²)`, inverse `d = (x, y)/√(1 + z)`. Since
//! `z = 1 − r²` gives `dω = dz dφ = 2r dr dφ = 2 dA`, a density `p_disk` on the disk is the
//! solid-angle density `p_disk / 2`. The hemisphere is the one on the side of `wo` (the
//! shading normal flipped if the surface is seen from the back); directions below it
//! (transmission) get density 0.
//!
//! **Exact density on the disk.** Gaussians live on the plane; the disk density is
//! `p(d) = Σ_k w_k N_k(d) + (Σ_k w_k (1 − P_k)) / π` for `|d| < 1`, with `P_k` the mass
//! of component `k` inside the disk. Sampling picks `k`, draws `d ~ N_k` and replaces a `d`
//! outside the disk by a uniform disk point, which has exactly this density. `P_k` is
//! computed once per fit in the component's whitened coordinates, where the disk's boundary
//! seen from the mean is at distance `ρ(ψ)` in direction `ψ`, so
//! `P_k = (1/2π) ∫ (1 − exp(−ρ(ψ)²/2)) dψ` — a smooth periodic integrand that the trapezoid
//! rule integrates to near machine precision.
//!
//! Departures from Vorba et al.: the mixtures train on the path tracer's own records (the
//! radiance found along sampled directions, weighted by `radiance / pdf`), not on separate
//! photon/importon passes; the uniform "outside the disk" component above replaces their
//! truncation; the fallback uniform point of a sample that left the disk comes from a hash of
//! the two random numbers (the [`Guide`] interface gives only two); and since a mixture is in
//! local coordinates, every spatial leaf keeps six mixtures, one per dominant axis (±x, ±y,
//! ±z) of the shading normal, each in a frame whose tangent is a fixed world axis projected
//! onto the normal, so nearby normals share coordinates. A leaf splits (children inherit its
//! mixtures) when an iteration brings it more than [`GmmConfig::split_threshold`] records.
//! Each iteration's records are sorted before fitting, so the result does not depend on the
//! order in which render threads delivered them.

use std::f64::consts::PI;
use std::sync::{Mutex, OnceLock};

use glam::{DVec2, Vec2, Vec3};
use rayon::prelude::*;

use super::{bits_key, unit_position, Guide, GuideRecord, GuideVertex};
use crate::bsdf::Material;
use crate::bvh::Aabb;
use crate::sampling::square_to_disk_concentric;

/// Most Gaussians per mixture.
pub const MAX_COMPONENTS: usize = 8;
/// Directions of the trapezoid rule for the in-disk mass of a Gaussian.
const DISK_MASS_STEPS: usize = 1024;
/// Farthest a mean may be from the disk centre (keeps the in-disk mass integrand smooth).
const MAX_MEAN_RADIUS: f64 = 0.999;
/// Floor on covariance determinants, against round-off making a covariance singular.
const MIN_DETERMINANT: f64 = 1e-14;

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

/// Direction in the local frame (upper hemisphere) to the unit disk.
fn hemisphere_to_disk(w: Vec3) -> DVec2 {
    let s = 1.0 / (1.0 + f64::from(w.z).max(0.0)).sqrt();
    DVec2::new(f64::from(w.x) * s, f64::from(w.y) * s)
}

/// Unit disk to the local upper hemisphere (inverse of [`hemisphere_to_disk`]).
fn disk_to_hemisphere(d: DVec2) -> Vec3 {
    let r2 = d.length_squared().min(1.0);
    let s = (2.0 - r2).sqrt();
    Vec3::new((d.x * s) as f32, (d.y * s) as f32, (1.0 - r2) as f32)
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

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// Two more uniform numbers derived from `u` (for the uniform disk point that replaces a
/// Gaussian sample outside the disk).
fn rehash(u: Vec2) -> Vec2 {
    let h = splitmix64(u64::from(u.x.to_bits()) | (u64::from(u.y.to_bits()) << 32));
    let to_unit = |b: u64| (b & 0xff_ffff) as f32 / 16_777_216.0;
    Vec2::new(to_unit(h), to_unit(h >> 32))
}

/// The `DISK_MASS_STEPS` unit vectors of the trapezoid rule over the circle.
fn circle() -> &'static [DVec2] {
    static CIRCLE: OnceLock<Vec<DVec2>> = OnceLock::new();
    CIRCLE.get_or_init(|| {
        (0..DISK_MASS_STEPS)
            .map(|j| {
                let psi = 2.0 * PI * (j as f64 + 0.5) / DISK_MASS_STEPS as f64;
                DVec2::new(psi.cos(), psi.sin())
            })
            .collect()
    })
}

/// One Gaussian with the quantities evaluation and sampling need.
#[derive(Clone, Copy, Debug)]
struct Component {
    weight: f64,
    mean: DVec2,
    /// Inverse covariance `(xx, xy, yy)`.
    inv: [f64; 3],
    /// Lower Cholesky factor `(l11, l21, l22)`.
    chol: [f64; 3],
    /// `ln(1 / (2π √det))`.
    log_norm: f64,
    /// Mass inside the unit disk.
    inside: f64,
}

impl Component {
    fn new(weight: f64, mean: DVec2, cov: [f64; 3]) -> Self {
        let mut c = Self::without_mass(weight, mean, cov);
        c.inside = c.disk_mass();
        c
    }

    /// The Gaussian with its in-disk mass still unknown (0), for EM steps that only need
    /// densities.
    fn without_mass(weight: f64, mean: DVec2, cov: [f64; 3]) -> Self {
        let det = (cov[0] * cov[2] - cov[1] * cov[1]).max(MIN_DETERMINANT);
        let l11 = cov[0].sqrt();
        let l21 = cov[1] / l11;
        let l22 = (cov[2] - l21 * l21).max(MIN_DETERMINANT / cov[0]).sqrt();
        Self {
            weight,
            mean,
            inv: [cov[2] / det, -cov[1] / det, cov[0] / det],
            chol: [l11, l21, l22],
            log_norm: -(2.0 * PI * det.sqrt()).ln(),
            inside: 0.0,
        }
    }

    fn log_density(&self, x: DVec2) -> f64 {
        let d = x - self.mean;
        let q = self.inv[0] * d.x * d.x + 2.0 * self.inv[1] * d.x * d.y + self.inv[2] * d.y * d.y;
        self.log_norm - 0.5 * q
    }

    fn whitened_to_plane(&self, z: DVec2) -> DVec2 {
        self.mean + DVec2::new(self.chol[0] * z.x, self.chol[1] * z.x + self.chol[2] * z.y)
    }

    /// `P(|mean + L z| < 1)` for `z ~ N(0, I)`, by the trapezoid rule over directions `ψ` of
    /// `z`: along a ray from the mean the chi distribution gives `exp(−r0²/2) − exp(−r1²/2)`
    /// between the ray's entry and exit distances.
    fn disk_mass(&self) -> f64 {
        let c = self.mean;
        let cc = c.length_squared() - 1.0;
        let mut sum = 0.0;
        for &dir in circle() {
            let v = self.whitened_to_plane(dir) - c;
            // |c + r v|² = 1: a r² + b r + cc = 0, roots in the cancellation-free form.
            let (a, b) = (v.length_squared(), 2.0 * c.dot(v));
            let disc = b * b - 4.0 * a * cc;
            if disc <= 0.0 {
                continue;
            }
            let q = -0.5 * (b + disc.sqrt().copysign(b));
            let (r0, r1) = {
                let (x, y) = (q / a, cc / q);
                (x.min(y), x.max(y))
            };
            if r1 <= 0.0 {
                continue;
            }
            let r0 = r0.max(0.0);
            sum += (-0.5 * r0 * r0).exp() - (-0.5 * r1 * r1).exp();
        }
        (sum / DISK_MASS_STEPS as f64).clamp(0.0, 1.0)
    }
}

/// Normalised weighted sufficient statistics of a mixture: per component `Σ γw`, `Σ γw x`
/// and `Σ γw x xᵀ` over `Σ w = 1`.
#[derive(Clone, Debug, Default)]
struct Statistics {
    s0: Vec<f64>,
    s1: Vec<DVec2>,
    s2: Vec<[f64; 3]>,
}

impl Statistics {
    fn zero(k: usize) -> Self {
        Self {
            s0: vec![0.0; k],
            s1: vec![DVec2::ZERO; k],
            s2: vec![[0.0; 3]; k],
        }
    }

    /// `(1 − η) self + η batch`.
    fn blend(&self, batch: &Statistics, eta: f64) -> Statistics {
        let mix = |a: f64, b: f64| (1.0 - eta) * a + eta * b;
        Statistics {
            s0: (0..self.s0.len())
                .map(|k| mix(self.s0[k], batch.s0[k]))
                .collect(),
            s1: (0..self.s1.len())
                .map(|k| (1.0 - eta) * self.s1[k] + eta * batch.s1[k])
                .collect(),
            s2: (0..self.s2.len())
                .map(|k| std::array::from_fn(|i| mix(self.s2[k][i], batch.s2[k][i])))
                .collect(),
        }
    }
}

/// A Gaussian mixture on the unit disk with its uniform "outside" component.
#[derive(Clone, Debug)]
struct Mixture {
    components: Vec<Component>,
    /// Mass of the Gaussians outside the disk, spread uniformly over it.
    outside: f64,
    /// Cumulative component weights for sampling.
    cdf: Vec<f64>,
    stats: Statistics,
    /// Iterations fitted so far (`t` of stepwise EM).
    steps: u32,
}

impl Mixture {
    /// Broad Gaussians at the centre and on a ring, equal weights.
    fn initial(k: usize) -> Self {
        let components = (0..k)
            .map(|i| {
                let mean = if i == 0 {
                    DVec2::ZERO
                } else {
                    let a = 2.0 * PI * (i - 1) as f64 / (k - 1) as f64;
                    0.5 * DVec2::new(a.cos(), a.sin())
                };
                Component::new(1.0 / k as f64, mean, [0.1, 0.0, 0.1])
            })
            .collect();
        let mut m = Self {
            components,
            outside: 0.0,
            cdf: Vec::new(),
            stats: Statistics::zero(k),
            steps: 0,
        };
        m.finish();
        m
    }

    fn finish(&mut self) {
        self.outside = self
            .components
            .iter()
            .map(|c| c.weight * (1.0 - c.inside))
            .sum();
        let total: f64 = self.components.iter().map(|c| c.weight).sum();
        let mut acc = 0.0;
        self.cdf = self
            .components
            .iter()
            .map(|c| {
                acc += c.weight / total;
                acc
            })
            .collect();
    }

    fn pdf_disk(&self, d: DVec2) -> f64 {
        if d.length_squared() >= 1.0 {
            return 0.0;
        }
        let gaussians: f64 = self
            .components
            .iter()
            .map(|c| c.weight * c.log_density(d).exp())
            .sum();
        gaussians + self.outside / PI
    }

    fn sample_disk(&self, u: Vec2) -> DVec2 {
        let ux = f64::from(u.x);
        let k = self
            .cdf
            .partition_point(|&c| c <= ux)
            .min(self.cdf.len() - 1);
        let lo = if k == 0 { 0.0 } else { self.cdf[k - 1] };
        let v = ((ux - lo) / (self.cdf[k] - lo)).clamp(0.0, 1.0);
        // Box–Muller.
        let r = (-2.0 * (1.0 - v).max(f64::MIN_POSITIVE).ln()).sqrt();
        let a = 2.0 * PI * f64::from(u.y);
        let d = self.components[k].whitened_to_plane(r * DVec2::new(a.cos(), a.sin()));
        if d.length_squared() < 1.0 {
            d
        } else {
            square_to_disk_concentric(rehash(u)).as_dvec2()
        }
    }

    /// Stepwise EM over one iteration's samples `(disk point, weight)` with `Σ weight > 0`.
    fn fit(&mut self, samples: &[(DVec2, f64)], config: &GmmConfig) {
        let k = self.components.len();
        let total: f64 = samples.iter().map(|s| s.1).sum();
        self.steps += 1;
        let eta = f64::from(self.steps).powf(-config.step_exponent);
        let mut blended = self.stats.clone();
        let mut log_g = vec![0.0; k];
        for _ in 0..config.em_steps {
            let mut batch = Statistics::zero(k);
            let log_w: Vec<f64> = self.components.iter().map(|c| c.weight.ln()).collect();
            for &(x, w) in samples {
                for ((g, c), lw) in log_g.iter_mut().zip(&self.components).zip(&log_w) {
                    *g = lw + c.log_density(x);
                }
                let max = log_g.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let sum: f64 = log_g.iter().map(|g| (g - max).exp()).sum();
                for j in 0..k {
                    let gw = (log_g[j] - max).exp() / sum * w / total;
                    batch.s0[j] += gw;
                    batch.s1[j] += gw * x;
                    batch.s2[j][0] += gw * x.x * x.x;
                    batch.s2[j][1] += gw * x.x * x.y;
                    batch.s2[j][2] += gw * x.y * x.y;
                }
            }
            blended = self.stats.blend(&batch, eta);
            self.maximise(&blended, config);
        }
        self.stats = blended;
        for c in &mut self.components {
            c.inside = c.disk_mass();
        }
        self.finish();
    }

    /// MAP M-step: Dirichlet prior on the weights, conjugate (inverse-Wishart-like) prior
    /// `σ₀² I` on the covariances, none on the means (which stay in the disk, being weighted
    /// means of disk points). In-disk masses are left for the end of [`Mixture::fit`].
    fn maximise(&mut self, s: &Statistics, config: &GmmConfig) {
        let k = self.components.len();
        let a = config.prior_strength;
        let pseudo = a / k as f64;
        let s_total: f64 = s.s0.iter().sum();
        for j in 0..k {
            let old = self.components[j];
            let s0 = s.s0[j];
            let weight = (s0 + pseudo) / (s_total + a);
            let mut mean = if s0 > 1e-12 { s.s1[j] / s0 } else { old.mean };
            if mean.length() > MAX_MEAN_RADIUS {
                mean *= MAX_MEAN_RADIUS / mean.length();
            }
            let scatter = [
                (s.s2[j][0] - s0 * mean.x * mean.x).max(0.0),
                s.s2[j][1] - s0 * mean.x * mean.y,
                (s.s2[j][2] - s0 * mean.y * mean.y).max(0.0),
            ];
            let prior = a * config.prior_variance;
            let cov = [
                (scatter[0] + prior) / (s0 + a),
                scatter[1] / (s0 + a),
                (scatter[2] + prior) / (s0 + a),
            ];
            self.components[j] = Component::without_mass(weight, mean, cov);
        }
        self.finish();
    }
}

/// One training sample reduced to what the mixtures need.
#[derive(Clone, Copy, Debug)]
struct Sample {
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

#[derive(Clone, Debug)]
enum SpatialNode {
    /// Split at the midpoint of `axis`; children are node indices (lower half first).
    Inner { axis: usize, children: [usize; 2] },
    /// The six mixtures (one per normal class) of a leaf, `None` until trained.
    Leaf(Box<[Option<Mixture>; 6]>),
}

/// Vorba-style Gaussian-mixture guide (see the module documentation).
///
/// ```
/// use nis_render::guiding::{gmm::{Gmm, GmmConfig}, Guide, GuideVertex};
/// let scene = nis_render::scenes::load("cornell-box").unwrap();
/// let guide = Gmm::new(scene.bounds(), GmmConfig::default());
/// let v = GuideVertex { p: glam::Vec3::ZERO, n: glam::Vec3::Z, wo: glam::Vec3::Z };
/// // Untrained: uniform over the hemisphere, nothing below it.
/// let up = glam::Vec3::new(0.6, 0.0, 0.8);
/// assert!((guide.pdf(&v, up) - 0.5 / std::f32::consts::PI).abs() < 1e-6);
/// assert_eq!(guide.pdf(&v, -glam::Vec3::Z), 0.0);
/// ```
#[derive(Debug)]
pub struct Gmm {
    config: GmmConfig,
    bounds: Aabb,
    nodes: Vec<SpatialNode>,
    pending: Mutex<Vec<Sample>>,
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
            bounds,
            nodes: vec![SpatialNode::Leaf(Box::default())],
            pending: Mutex::new(Vec::new()),
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
        self.nodes
            .iter()
            .filter(|n| matches!(n, SpatialNode::Leaf(_)))
            .count()
    }

    /// The trained mixture for `vertex` (if any) and the local frame of its normal class.
    fn mixture(&self, vertex: &GuideVertex) -> (Option<&Mixture>, [Vec3; 3]) {
        let (class, frame) = class_frame(reflection_normal(vertex));
        let mut x = unit_position(&self.bounds, vertex.p);
        let mut i = 0;
        loop {
            match &self.nodes[i] {
                SpatialNode::Leaf(m) => return (m[class].as_ref(), frame),
                SpatialNode::Inner { axis, children } => {
                    let upper = x[*axis] >= 0.5;
                    x[*axis] = 2.0 * x[*axis] - f32::from(u8::from(upper));
                    i = children[usize::from(upper)];
                }
            }
        }
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
fn fit_mixtures(mixtures: &mut [Option<Mixture>; 6], samples: &[Sample], config: &GmmConfig) {
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
                .get_or_insert_with(|| Mixture::initial(config.components))
                .fit(points, config);
        }
    }
}

impl Guide for Gmm {
    fn selection_probability(&self, vertex: &GuideVertex, material: &Material) -> f32 {
        if material.is_delta() || self.mixture(vertex).0.is_none() {
            0.0
        } else {
            1.0 - self.config.bsdf_fraction
        }
    }

    fn sample(&self, vertex: &GuideVertex, u: Vec2) -> Option<(Vec3, f32)> {
        let (mixture, f) = self.mixture(vertex);
        let d = match mixture {
            Some(m) => m.sample_disk(u),
            None => square_to_disk_concentric(u).as_dvec2(),
        };
        let w = disk_to_hemisphere(d);
        let wi = (w.x * f[0] + w.y * f[1] + w.z * f[2]).normalize();
        // The density of the direction returned (what `pdf(wi)` computes, without a second
        // lookup), not of `d`: the two differ by round-off.
        let pdf = density(mixture, &f, wi);
        (pdf > 0.0).then_some((wi, pdf))
    }

    fn pdf(&self, vertex: &GuideVertex, wi: Vec3) -> f32 {
        let (mixture, frame) = self.mixture(vertex);
        density(mixture, &frame, wi)
    }

    fn wants_records(&self) -> bool {
        self.learning
    }

    fn end_training(&mut self) {
        self.learning = false;
    }

    fn record(&self, records: &[GuideRecord]) {
        let samples = records.iter().filter_map(|r| {
            let weight = r.radiance.max(Vec3::ZERO).element_sum() / (3.0 * r.pdf);
            (r.pdf > 0.0 && weight.is_finite()).then_some(Sample {
                p: r.vertex.p,
                n: reflection_normal(&r.vertex),
                wi: r.wi,
                weight,
            })
        });
        let mut pending = self.pending.lock().unwrap_or_else(|e| e.into_inner());
        pending.extend(samples);
    }

    fn end_iteration(&mut self, _iteration: usize) {
        if !self.learning {
            return;
        }
        let mut samples = std::mem::take(self.pending.get_mut().unwrap_or_else(|e| e.into_inner()));
        samples.sort_unstable_by_key(Sample::key);
        let all: Vec<(Vec3, Sample)> = samples
            .iter()
            .map(|s| (unit_position(&self.bounds, s.p), *s))
            .collect();
        // (node, its split axis if it splits, depth, its samples in the node's unit cube)
        let mut stack = vec![(0usize, 0usize, 0u32, all)];
        let mut work: Vec<(usize, Vec<Sample>)> = Vec::new();
        while let Some((i, axis, depth, mut here)) = stack.pop() {
            if let SpatialNode::Leaf(mixtures) = &self.nodes[i] {
                if here.len() <= self.config.split_threshold || depth >= self.config.max_depth {
                    work.push((i, here.into_iter().map(|h| h.1).collect()));
                    continue;
                }
                let children = [self.nodes.len(), self.nodes.len() + 1];
                let copy = SpatialNode::Leaf(mixtures.clone());
                self.nodes.push(copy.clone());
                self.nodes.push(copy);
                self.nodes[i] = SpatialNode::Inner { axis, children };
            }
            let SpatialNode::Inner { axis, children } = self.nodes[i] else {
                unreachable!("leaves were handled above");
            };
            let mut halves = [Vec::new(), Vec::new()];
            for (mut x, s) in here.drain(..) {
                let upper = x[axis] >= 0.5;
                x[axis] = 2.0 * x[axis] - f32::from(u8::from(upper));
                halves[usize::from(upper)].push((x, s));
            }
            for (c, h) in children.into_iter().zip(halves).rev() {
                stack.push((c, (axis + 1) % 3, depth + 1, h));
            }
        }
        // Leaves are fitted independently, each from its samples in sorted order: in
        // parallel, and still deterministic.
        let mut per_node: Vec<Vec<Sample>> = vec![Vec::new(); self.nodes.len()];
        for (i, samples) in work {
            per_node[i] = samples;
        }
        let config = self.config;
        self.nodes
            .par_iter_mut()
            .zip(per_node.par_iter())
            .for_each(|(node, samples)| {
                if let SpatialNode::Leaf(mixtures) = node {
                    fit_mixtures(mixtures, samples, &config);
                }
            });
        self.iteration += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disk_map_round_trips_and_preserves_area() {
        for i in 0..50 {
            let d = DVec2::new(0.9 * (i as f64 / 50.0), -0.3 + 0.01 * i as f64);
            let w = disk_to_hemisphere(d);
            assert!((w.length() - 1.0).abs() < 1e-6);
            assert!((hemisphere_to_disk(w) - d).length() < 1e-5);
        }
        // Area preservation: a disk ring r ∈ [a, b] (area π(b² − a²)) maps to the zone
        // z ∈ [1 − b², 1 − a²] (solid angle 2π(b² − a²)).
        let (a, b) = (0.3, 0.6);
        let zone =
            disk_to_hemisphere(DVec2::new(a, 0.0)).z - disk_to_hemisphere(DVec2::new(b, 0.0)).z;
        assert!((f64::from(zone) - (b * b - a * a)).abs() < 1e-6);
    }

    #[test]
    fn disk_mass_matches_closed_forms() {
        // Centred isotropic Gaussian: P(|d| < 1) = 1 − exp(−1/(2σ²)).
        for s2 in [0.01, 0.1, 1.0, 10.0] {
            let c = Component::new(1.0, DVec2::ZERO, [s2, 0.0, s2]);
            let exact = 1.0 - (-0.5 / s2).exp();
            assert!(
                (c.inside - exact).abs() < 1e-12,
                "{s2}: {} vs {exact}",
                c.inside
            );
        }
        // Off-centre, anisotropic: against a fine polar midpoint quadrature of the density.
        let c = Component::new(1.0, DVec2::new(0.7, -0.2), [0.09, 0.03, 0.04]);
        let (nr, na) = (2000, 2000);
        let mut q = 0.0;
        for i in 0..nr {
            let r = (i as f64 + 0.5) / nr as f64;
            for j in 0..na {
                let a = 2.0 * PI * (j as f64 + 0.5) / na as f64;
                q += c.log_density(r * DVec2::new(a.cos(), a.sin())).exp() * r;
            }
        }
        q *= 2.0 * PI / (nr * na) as f64;
        assert!((c.inside - q).abs() < 1e-5, "{} vs {q}", c.inside);
    }

    #[test]
    fn weighted_em_recovers_two_gaussians_on_the_disk() {
        // Points on a grid over the disk weighted by a two-Gaussian density: weighted EM
        // (with a negligible prior) recovers the weights, means and covariances.
        let truth = [
            (0.7, DVec2::new(0.3, 0.2), [0.010, 0.004, 0.020]),
            (0.3, DVec2::new(-0.4, -0.3), [0.015, 0.0, 0.005]),
        ];
        let gaussians = truth.map(|(w, m, c)| Component::new(w, m, c));
        let density = |x: DVec2| -> f64 {
            gaussians
                .iter()
                .map(|g| g.weight * g.log_density(x).exp())
                .sum()
        };
        let n = 200;
        let points: Vec<(DVec2, f64)> = (0..n * n)
            .map(|i| {
                let x = DVec2::new(
                    -1.0 + (2 * (i % n) + 1) as f64 / n as f64,
                    -1.0 + (2 * (i / n) + 1) as f64 / n as f64,
                );
                (x, density(x))
            })
            .filter(|(x, _)| x.length_squared() < 1.0)
            .collect();
        let config = GmmConfig {
            components: 2,
            em_steps: 60,
            prior_strength: 1e-6,
            ..GmmConfig::default()
        };
        let mut m = Mixture::initial(2);
        m.fit(&points, &config);
        // Component 0 starts at the centre, component 1 at (0.5, 0): match by the means.
        let mut found: Vec<&Component> = m.components.iter().collect();
        found.sort_by(|a, b| b.mean.x.total_cmp(&a.mean.x));
        for ((w, mean, cov), c) in truth.iter().zip(found) {
            assert!((c.weight - w).abs() < 1e-3, "weight {} vs {w}", c.weight);
            assert!(
                (c.mean - *mean).length() < 1e-3,
                "mean {} vs {mean}",
                c.mean
            );
            let det = cov[0] * cov[2] - cov[1] * cov[1];
            let inv = [cov[2] / det, -cov[1] / det, cov[0] / det];
            for (a, b) in c.inv.iter().zip(inv) {
                assert!(
                    (a - b).abs() < 1e-2 * b.abs().max(1.0),
                    "inverse {:?} vs {inv:?}",
                    c.inv
                );
            }
        }
        // The disk density integrates to one: the uniform part holds what left the disk.
        let cell = (2.0 / n as f64).powi(2);
        let total: f64 = points.iter().map(|&(x, _)| m.pdf_disk(x) * cell).sum();
        assert!((total - 1.0).abs() < 2e-3, "{total}");
    }

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
