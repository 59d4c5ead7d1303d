//! Practical Path Guiding (Müller, Gross & Novák 2017, "Practical Path Guiding for Efficient
//! Light-Transport Simulation", EGSR): an *SD-tree* that learns the incident radiance.
//!
//! Space is the binary tree of [`spatial`](super::spatial) over the scene's bounding cube, split
//! at the midpoint along x, y, z in turn (§5.1); each spatial leaf holds a *directional
//! quadtree* (`quadtree.rs`) over world-space cylindrical coordinates `((cos θ + 1)/2, φ/2π)`
//! whose nodes store the radiance flux of their four quadrants (§5.2). Sampling descends the quadtree picking children by their
//! flux; the density is the product of `4 · child / parent` along the way, divided by `4π` (the
//! cylindrical map preserves area).
//!
//! Training runs in iterations (§5.3): paths of iteration `k` are guided by the *sampling*
//! tree and deposit `radiance / pdf` (the mean over RGB, a one-sample estimate of the flux)
//! into the *building* tree. At the end of the iteration the building tree becomes the
//! sampling tree, spatial leaves that received more than `c · √(2^k)` samples split (their
//! children copy both trees and half the sample count, recursively), and a fresh building
//! tree is refined from the new sampling tree: a quadrant carrying more than a fraction `ρ` of
//! the total flux gets children (a new child inherits a quarter of its parent's flux, so
//! refinement may go several levels at once), others become leaves (§5.2). `k` counts the
//! [`Guide::update`]s of this guide, not the render loop's pass index.
//!
//! As in the paper, guiding is radiance-driven (the flux is not multiplied by the BSDF) and
//! records are deposited at their own position, unless [`PpgConfig::spatial_filter`] asks
//! for the box filter of the authors' later implementation (no directional filter). Records
//! are buffered and deposited in a sorted order at the end of an iteration, so learning is
//! independent of how threads delivered them. Before the first iteration, and wherever a
//! leaf has learned nothing, the guide is uniform over the sphere with selection probability
//! 0.

use std::f64::consts::PI;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::spatial::SpatialTree;
use super::{
    bits_key, cylindrical_to_dir, dir_to_cylindrical, Guide, GuideRecord, GuideSample, GuideVertex,
    PdfQuery, SampleQuery,
};
use crate::bvh::Aabb;
use quadtree::QuadTree;

mod quadtree;

/// Parameters of [`Ppg`]; the defaults are the paper's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PpgConfig {
    /// `c`: a spatial leaf splits after receiving more than `c · √(2^k)` samples in
    /// iteration `k` (§5.3, c = 12 000 for the paper's 1280 × 720 renders), scaled to the
    /// film by [`PpgConfig::film_pixels`]. The square root is the paper's balance: with
    /// `N_k ∝ 2^k` samples in iteration `k`, both the number of leaves (`N_k / threshold`) and
    /// the samples per leaf grow as `√N_k`. A film of `P` pixels traces `P / P_paper` times
    /// the paper's samples per pass, so keeping that balance at a given `N_k` means the
    /// threshold `c · √(2^k · P / P_paper)`: c = 1 600 at 128², 3 200 at 256². With the
    /// paper's c unscaled, a small render hardly splits and its guide is little better than
    /// none (docs/results/guiding.md, "Settings that set the guide's defaults", PPG's row).
    pub spatial_threshold: f64,
    /// Pixels of the film the guide trains on, if the threshold is to be scaled to it by
    /// `√(film_pixels / PAPER_FILM_PIXELS)`; `None` uses `spatial_threshold` as it is.
    /// [`GuideSpec`](super::factory::GuideSpec) sets it to the rendered film.
    pub film_pixels: Option<u64>,
    /// `ρ`: a quadtree node is subdivided when it carries more than this fraction of its
    /// tree's flux (§5.2, 1 %).
    pub flux_threshold: f64,
    /// Deepest quadtree level (the paper's implementation uses 20).
    pub max_quadtree_depth: u32,
    /// Deepest spatial level (f32 positions resolve about 20 halvings per axis).
    pub max_spatial_depth: u32,
    /// Probability of sampling the BSDF rather than the guide at trained vertices (0.5).
    pub bsdf_fraction: f32,
    /// Spread each record over a box the size of its spatial leaf centred on its position,
    /// shared among the leaves the box overlaps in proportion to the overlap (flux and sample
    /// count alike; the box is clipped to the scene cube). This is the box filter of the
    /// authors' implementation and of Müller 2019 ("Practical Path Guiding" in Production,
    /// §4); the 2017 paper deposits at the position only (`false`, the default).
    pub spatial_filter: bool,
}

impl Default for PpgConfig {
    fn default() -> Self {
        Self {
            spatial_threshold: 12_000.0,
            film_pixels: None,
            flux_threshold: 0.01,
            max_quadtree_depth: 20,
            max_spatial_depth: 60,
            bsdf_fraction: 0.5,
            spatial_filter: false,
        }
    }
}

/// Pixels of the renders the paper's `c = 12 000` was chosen for (1280 × 720).
pub const PAPER_FILM_PIXELS: u64 = 1280 * 720;

impl PpgConfig {
    /// These settings with the spatial threshold scaled to a film of `pixels` pixels.
    pub fn for_film(self, pixels: u64) -> PpgConfig {
        PpgConfig {
            film_pixels: Some(pixels),
            ..self
        }
    }

    /// `c` as applied: [`PpgConfig::spatial_threshold`] scaled to the film, if one is set.
    pub fn effective_spatial_threshold(&self) -> f64 {
        match self.film_pixels {
            Some(p) => self.spatial_threshold * (p as f64 / PAPER_FILM_PIXELS as f64).sqrt(),
            None => self.spatial_threshold,
        }
    }
}

/// A spatial leaf: the two directional trees of §5.3 and the samples the building one got.
#[derive(Clone, Debug, Default)]
struct Leaf {
    sampling: QuadTree,
    sampling_total: f64,
    building: QuadTree,
    /// Samples (fractions of samples with the spatial filter) the building tree received.
    samples: f64,
}

/// One training record reduced to what PPG keeps: position, direction and flux. A training
/// pass's [`Guide::Statistics`] are its deposits, in the order they were made.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Deposit {
    p: Vec3,
    wi: Vec3,
    flux: f32,
}

impl Deposit {
    fn key(&self) -> [u32; 7] {
        bits_key([
            self.p.x, self.p.y, self.p.z, self.wi.x, self.wi.y, self.wi.z, self.flux,
        ])
    }
}

/// The practical-path-guiding SD-tree (see the module documentation).
///
/// ```
/// use nis_render::guiding::{ppg::{Ppg, PpgConfig}, Guide, GuideVertex};
/// let scene = nis_render::scenes::load("cornell-box").unwrap();
/// let guide = Ppg::new(scene.bounds(), PpgConfig::default());
/// let v = GuideVertex { p: glam::Vec3::ZERO, n: glam::Vec3::Z, wo: glam::Vec3::Z, transmissive: false };
/// // Untrained: uniform over the sphere.
/// assert!((guide.pdf(&v, glam::Vec3::X) - 0.25 / std::f32::consts::PI).abs() < 1e-6);
/// ```
#[derive(Debug)]
pub struct Ppg {
    config: PpgConfig,
    tree: SpatialTree<Leaf>,
    iteration: u32,
    learning: bool,
}

impl Ppg {
    /// An untrained guide over the scene box `bounds` (e.g. [`crate::scene::Scene::bounds`]).
    pub fn new(bounds: Aabb, config: PpgConfig) -> Self {
        Self {
            config,
            tree: SpatialTree::new(bounds, Leaf::default()),
            iteration: 0,
            learning: true,
        }
    }

    /// Keep learning from records (the default) or freeze the current distribution.
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

    /// Deposit one record into the building trees, at its leaf or spread by the box filter.
    fn deposit(&mut self, d: &Deposit, overlaps: &mut Vec<(usize, f64)>) {
        let x = self.tree.unit_position(d.p);
        let c = dir_to_cylindrical(d.wi);
        let at = self.tree.locate_unit(x);
        let (l, size) = (at.leaf, at.size);
        if self.config.spatial_filter {
            let (lo, hi) = (
                (x - 0.5 * size).max(Vec3::ZERO),
                (x + 0.5 * size).min(Vec3::ONE),
            );
            self.tree.overlaps(lo, hi, overlaps);
            let total: f64 = overlaps.iter().map(|o| o.1).sum();
            if total > 0.0 {
                let leaves = self.tree.leaves_mut();
                for &(l, v) in overlaps.iter() {
                    let w = v / total;
                    leaves[l].samples += w;
                    leaves[l].building.deposit(c, w * f64::from(d.flux));
                }
                return;
            }
        }
        let leaf = &mut self.tree.leaves_mut()[l];
        leaf.samples += 1.0;
        leaf.building.deposit(c, f64::from(d.flux));
    }

    /// Split leaves that received more than `threshold` samples, recursively (children get
    /// copies of the trees and half the count, Müller et al.'s `SDTree::refine`).
    fn refine_space(&mut self, threshold: f64) {
        self.tree
            .refine(self.config.max_spatial_depth, |leaf, _axis| {
                (leaf.samples > threshold).then(|| {
                    leaf.samples *= 0.5;
                    leaf.clone()
                })
            });
    }
}

impl Guide for Ppg {
    /// The spatial leaf of each vertex.
    type Prepared = Vec<usize>;
    type Statistics = Vec<Deposit>;

    fn prepare(&self, vertices: &[GuideVertex], leaves: &mut Vec<usize>) {
        leaves.clear();
        leaves.extend(vertices.iter().map(|v| self.tree.leaf_index(v.p)));
    }

    fn selection_probabilities(&self, _: &[GuideVertex], leaves: &Vec<usize>, out: &mut [f32]) {
        for (&l, o) in leaves.iter().zip(out) {
            *o = if self.tree.leaf(l).sampling_total <= 0.0 {
                0.0
            } else {
                1.0 - self.config.bsdf_fraction
            };
        }
    }

    fn sample_batch(
        &self,
        _: &[GuideVertex],
        leaves: &Vec<usize>,
        queries: &[SampleQuery],
        out: &mut [Option<GuideSample>],
    ) {
        for (q, o) in queries.iter().zip(out) {
            let tree = &self.tree.leaf(leaves[q.vertex]).sampling;
            let wi = cylindrical_to_dir(tree.sample(q.u));
            // The density of the direction actually returned, so that it equals `pdf(wi)` even
            // where rounding moved it across a cell boundary.
            let pdf = (tree.pdf(dir_to_cylindrical(wi)) / (4.0 * PI)) as f32;
            *o = (pdf > 0.0).then_some(GuideSample { wi, pdf });
        }
    }

    fn pdf_batch(
        &self,
        _: &[GuideVertex],
        leaves: &Vec<usize>,
        queries: &[PdfQuery],
        out: &mut [f32],
    ) {
        for (q, o) in queries.iter().zip(out) {
            let tree = &self.tree.leaf(leaves[q.vertex]).sampling;
            *o = (tree.pdf(dir_to_cylindrical(q.wi)) / (4.0 * PI)) as f32;
        }
    }

    fn wants_records(&self) -> bool {
        self.learning
    }

    fn end_training(&mut self) {
        self.learning = false;
    }

    fn accumulate(&self, records: &[GuideRecord], deposits: &mut Vec<Deposit>) {
        deposits.extend(records.iter().filter_map(|r| {
            let flux = r.radiance.max(Vec3::ZERO).element_sum() / (3.0 * r.pdf);
            (r.pdf > 0.0 && flux.is_finite()).then_some(Deposit {
                p: r.vertex.p,
                wi: r.wi,
                flux,
            })
        }));
    }

    fn update(&mut self, mut deposits: Vec<Deposit>) {
        if !self.learning {
            return;
        }
        deposits.sort_unstable_by_key(Deposit::key);
        let mut overlaps = Vec::new();
        for d in &deposits {
            self.deposit(d, &mut overlaps);
        }
        for leaf in self.tree.leaves_mut() {
            leaf.sampling = std::mem::take(&mut leaf.building);
            leaf.sampling.sum_up();
            leaf.sampling_total = leaf.sampling.total();
        }
        let threshold =
            self.config.effective_spatial_threshold() * 2f64.powf(0.5 * f64::from(self.iteration));
        self.refine_space(threshold);
        let (depth, rho) = (self.config.max_quadtree_depth, self.config.flux_threshold);
        for leaf in self.tree.leaves_mut() {
            leaf.building = leaf.sampling.refined(depth, rho);
            leaf.samples = 0.0;
        }
        self.iteration += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Aabb {
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        }
    }

    fn record(p: Vec3, wi: Vec3, radiance: f32) -> GuideRecord {
        GuideRecord {
            vertex: GuideVertex {
                p,
                n: Vec3::Z,
                wo: Vec3::Z,
                transmissive: false,
            },
            wi,
            pdf: 1.0,
            bsdf_pdf: 0.0,
            bsdf_cos: Vec3::ONE,
            radiance: Vec3::splat(radiance),
            throughput: 1.0,
        }
    }

    fn ppg(spatial_threshold: f64) -> Ppg {
        Ppg::new(
            unit_box(),
            PpgConfig {
                spatial_threshold,
                ..PpgConfig::default()
            },
        )
    }

    /// `n` samples at one point, then one training iteration; the spatial leaf count.
    fn leaves_after(guide: &mut Ppg, n: usize) -> usize {
        let records = vec![record(Vec3::splat(0.3), Vec3::Z, 1.0); n];
        let mut deposits = Vec::new();
        guide.accumulate(&records, &mut deposits);
        guide.update(deposits);
        guide.spatial_leaves()
    }

    #[test]
    fn spatial_leaf_splits_above_c_sqrt_two_to_the_k_samples() {
        // Iteration 0: threshold c = 100. 100 samples stay, 101 split once (50 each).
        assert_eq!(leaves_after(&mut ppg(100.0), 100), 1);
        assert_eq!(leaves_after(&mut ppg(100.0), 101), 2);
        // 400 samples: 200 per child > 100 splits again (100 each), four leaves; 401 samples
        // leave 100.25 per grandchild, which splits once more.
        assert_eq!(leaves_after(&mut ppg(100.0), 400), 4);
        assert_eq!(leaves_after(&mut ppg(100.0), 401), 8);
        // Iteration 1: threshold 100·√2 ≈ 141.4; iteration 2: 200.
        let mut g = ppg(100.0);
        assert_eq!(leaves_after(&mut g, 10), 1);
        assert_eq!(leaves_after(&mut g, 141), 1);
        assert_eq!(leaves_after(&mut g, 200), 1);
        assert_eq!(leaves_after(&mut g, 400), 2); // iteration 3: 200 < 282.8 < 400
        let mut g = ppg(100.0);
        assert_eq!(leaves_after(&mut g, 10), 1);
        assert_eq!(leaves_after(&mut g, 142), 2);
        // Axes cycle x, y, z: after splits along x then y, the point's leaf is a quarter
        // [0, ½) × [0, ½) × [0, 1), so a point at z = 0.9 shares it and x = 0.6 does not.
        let g = {
            let mut g = ppg(100.0);
            leaves_after(&mut g, 400);
            g
        };
        let at = |p: Vec3| g.tree.leaf_index(p);
        assert_eq!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.1, 0.4, 0.9)));
        assert_ne!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.6, 0.3, 0.3)));
        assert_ne!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.3, 0.6, 0.3)));
    }

    #[test]
    fn spatial_threshold_scales_with_the_square_root_of_the_film() {
        // The paper's film: c as given; a quarter of its pixels: c/2.
        let c = PpgConfig::default();
        assert_eq!(c.effective_spatial_threshold(), 12_000.0);
        assert_eq!(
            c.for_film(PAPER_FILM_PIXELS).effective_spatial_threshold(),
            12_000.0
        );
        let quarter = c.for_film(PAPER_FILM_PIXELS / 4);
        assert!((quarter.effective_spatial_threshold() - 6_000.0).abs() < 1e-9);
        let at_128 = c.for_film(128 * 128).effective_spatial_threshold();
        assert!((at_128 - 1_600.0).abs() < 1e-9, "{at_128}");
        // And the tree splits at the scaled threshold: c = 100 on a film of a quarter of the
        // paper's pixels splits above 50 samples.
        let quarter_film = || {
            let c = PpgConfig {
                spatial_threshold: 100.0,
                ..PpgConfig::default()
            };
            Ppg::new(unit_box(), c.for_film(PAPER_FILM_PIXELS / 4))
        };
        assert_eq!(leaves_after(&mut quarter_film(), 51), 2);
        let mut g = quarter_film();
        assert_eq!(leaves_after(&mut g, 50), 1);
    }

    #[test]
    fn box_filter_shares_a_record_among_leaves_by_overlap() {
        let mut g = Ppg::new(
            unit_box(),
            PpgConfig {
                spatial_threshold: 100.0,
                spatial_filter: true,
                ..PpgConfig::default()
            },
        );
        assert_eq!(leaves_after(&mut g, 101), 2); // split at x = ½: cells ½ × 1 × 1
        let mut overlaps = Vec::new();
        let mut shares = |x: f32| {
            let d = Deposit {
                p: Vec3::new(x, 0.5, 0.5),
                wi: Vec3::Z,
                flux: 1.0,
            };
            g.tree.leaves_mut().iter_mut().for_each(|l| l.samples = 0.0);
            g.deposit(&d, &mut overlaps);
            [g.tree.leaf(0).samples, g.tree.leaf(1).samples]
        };
        let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() + (a[1] - b[1]).abs() < 1e-6;
        // The box is as wide as the cell (½ along x) and clipped to the cube.
        assert!(close(shares(0.25), [1.0, 0.0]));
        assert!(close(shares(0.1), [1.0, 0.0]));
        assert!(close(shares(0.5), [0.5, 0.5]));
        assert!(close(shares(0.4), [0.7, 0.3]), "{:?}", shares(0.4));
        assert!(close(shares(0.9), [0.0, 1.0]));
    }
}
