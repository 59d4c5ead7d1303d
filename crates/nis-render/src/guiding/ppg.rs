//! Practical Path Guiding (Müller, Gross & Novák 2017, "Practical Path Guiding for Efficient
//! Light-Transport Simulation", EGSR): an *SD-tree* that learns the incident radiance.
//!
//! Space is a binary tree over the scene's bounding cube, split at the midpoint along x, y, z
//! in turn (§5.1); each spatial leaf holds a *directional quadtree* over world-space
//! cylindrical coordinates `((cos θ + 1)/2, φ/2π)` whose nodes store the radiance flux of
//! their four quadrants (§5.2). Sampling descends the quadtree picking children by their
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
//! `end_iteration` calls of this guide, not the render loop's pass index.
//!
//! As in the paper, guiding is radiance-driven (the flux is not multiplied by the BSDF) and
//! records are deposited at their own position, unless [`PpgConfig::spatial_filter`] asks
//! for the box filter of the authors' later implementation (no directional filter). Records
//! are buffered and deposited in a sorted order at the end of an iteration, so learning is
//! independent of how threads delivered them. Before the first iteration, and wherever a
//! leaf has learned nothing, the guide is uniform over the sphere with selection probability
//! 0.

use std::f64::consts::PI;
use std::sync::Mutex;

use glam::{Vec2, Vec3};

use super::{
    bits_key, cylindrical_to_dir, dir_to_cylindrical, unit_position, Guide, GuideRecord,
    GuideVertex, ONE_MINUS_EPSILON,
};
use crate::bsdf::Material;
use crate::bvh::Aabb;

/// Parameters of [`Ppg`]; the defaults are the paper's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PpgConfig {
    /// `c`: a spatial leaf splits after receiving more than `c · √(2^k)` samples in
    /// iteration `k` (§5.3, c = 12 000). The paper's value is for megapixel renders, where
    /// training yields millions of records; with small training budgets a smaller `c` trades
    /// noisier quadtrees for spatial resolution and can win: on `cornell-indirect` at
    /// 64 × 64, after training passes of 1, 2, …, 64 spp, the mean relative per-pixel variance
    /// at 16 spp was 1.68 unguided, 1.51 with c = 12 000 (8 leaves), 0.97 with c = 2 000 (62).
    pub spatial_threshold: f64,
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
            flux_threshold: 0.01,
            max_quadtree_depth: 20,
            max_spatial_depth: 60,
            bsdf_fraction: 0.5,
            spatial_filter: false,
        }
    }
}

/// A quadtree node: the flux of its four quadrants (quadrant `q` covers `x ≥ ½` if `q & 1`,
/// `y ≥ ½` if `q & 2`) and their children (0: the quadrant is a leaf; the root is never a
/// child, and children always come after their parent in the node list).
#[derive(Clone, Copy, Debug, Default)]
struct QuadNode {
    flux: [f64; 4],
    child: [u32; 4],
}

/// The directional quadtree over the unit square of cylindrical coordinates.
#[derive(Clone, Debug)]
struct QuadTree {
    nodes: Vec<QuadNode>,
}

impl Default for QuadTree {
    fn default() -> Self {
        Self {
            nodes: vec![QuadNode::default()],
        }
    }
}

/// Quadrant of `x` in the unit square and `x` in that quadrant's own unit square (exact in
/// floating point: scaling by 2 and subtracting 1).
fn descend(x: Vec2) -> (usize, Vec2) {
    let hx = x.x >= 0.5;
    let hy = x.y >= 0.5;
    let q = usize::from(hx) + 2 * usize::from(hy);
    let shift = Vec2::new(f32::from(u8::from(hx)), f32::from(u8::from(hy)));
    (q, 2.0 * x - shift)
}

impl QuadTree {
    fn total(&self) -> f64 {
        self.nodes[0].flux.iter().sum()
    }

    /// Add `flux` to the leaf quadrant containing `x`.
    fn deposit(&mut self, mut x: Vec2, flux: f64) {
        let mut i = 0;
        loop {
            let (q, next) = descend(x);
            let c = self.nodes[i].child[q] as usize;
            if c == 0 {
                self.nodes[i].flux[q] += flux;
                return;
            }
            i = c;
            x = next;
        }
    }

    /// Make every inner quadrant's flux the sum of its children's (children follow parents,
    /// so one backward sweep suffices).
    fn sum_up(&mut self) {
        for i in (0..self.nodes.len()).rev() {
            for q in 0..4 {
                let c = self.nodes[i].child[q] as usize;
                if c != 0 {
                    self.nodes[i].flux[q] = self.nodes[c].flux.iter().sum();
                }
            }
        }
    }

    /// Density on the unit square at `x`; uniform where a node has no flux at all.
    fn pdf(&self, mut x: Vec2) -> f64 {
        let mut pdf = 1.0;
        let mut i = 0;
        loop {
            let node = &self.nodes[i];
            let total: f64 = node.flux.iter().sum();
            if total <= 0.0 {
                return pdf;
            }
            let (q, next) = descend(x);
            pdf *= 4.0 * node.flux[q] / total;
            let c = node.child[q] as usize;
            if c == 0 || pdf == 0.0 {
                return pdf;
            }
            i = c;
            x = next;
        }
    }

    /// A point of the unit square with density [`QuadTree::pdf`], by hierarchical warping:
    /// each level picks the x half, then the y half within it, and rescales the random numbers.
    fn sample(&self, u: Vec2) -> Vec2 {
        let mut u = [f64::from(u.x), f64::from(u.y)];
        let mut origin = [0.0f64; 2];
        let mut size = 1.0f64;
        let mut i = 0;
        loop {
            let f = &self.nodes[i].flux;
            let total: f64 = f.iter().sum();
            if total <= 0.0 {
                break;
            }
            let pick = |u: &mut f64, p: f64| {
                if *u < p {
                    *u /= p;
                    0
                } else {
                    *u = (*u - p) / (1.0 - p);
                    1
                }
            };
            let hx = pick(&mut u[0], (f[0] + f[2]) / total);
            let (lo, hi) = if hx == 0 { (f[0], f[2]) } else { (f[1], f[3]) };
            let hy = pick(&mut u[1], lo / (lo + hi));
            size *= 0.5;
            origin[0] += size * hx as f64;
            origin[1] += size * hy as f64;
            let c = self.nodes[i].child[hx + 2 * hy] as usize;
            if c == 0 {
                break;
            }
            i = c;
        }
        let at = |o: f64, u: f64| ((o + size * u.clamp(0.0, 1.0)) as f32).min(ONE_MINUS_EPSILON);
        Vec2::new(at(origin[0], u[0]), at(origin[1], u[1]))
    }

    /// An empty tree (no flux) whose structure is refined from this one's flux (§5.2): a
    /// quadrant with more than `rho` of the total is subdivided, down to `max_depth` levels.
    /// Without any flux the fraction of a level-`d` quadrant is taken as `4^-d`.
    fn refined(&self, max_depth: u32, rho: f64) -> QuadTree {
        let total = self.total();
        let mut out = QuadTree::default();
        // (node in `out`, its flux per quadrant, the node of `self` it mirrors, depth)
        let mut stack = vec![(0usize, self.nodes[0].flux, Some(0usize), 1u32)];
        while let Some((o, flux, source, depth)) = stack.pop() {
            for q in 0..4 {
                let fraction = if total > 0.0 {
                    flux[q] / total
                } else {
                    0.25f64.powi(depth as i32)
                };
                if depth >= max_depth || fraction <= rho {
                    continue;
                }
                let c = out.nodes.len();
                out.nodes.push(QuadNode::default());
                out.nodes[o].child[q] = c as u32;
                let mirrored = source
                    .map(|s| self.nodes[s].child[q] as usize)
                    .filter(|&s| s != 0);
                let child_flux = match mirrored {
                    Some(s) => self.nodes[s].flux,
                    None => [flux[q] / 4.0; 4],
                };
                stack.push((c, child_flux, mirrored, depth + 1));
            }
        }
        out
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

#[derive(Clone, Copy, Debug)]
enum SpatialNode {
    /// Split at the midpoint of `axis`; children are node indices (lower half first).
    Inner { axis: usize, children: [usize; 2] },
    /// Index into [`Ppg::leaves`].
    Leaf(usize),
}

/// One training sample reduced to what PPG keeps: position, direction and flux.
#[derive(Clone, Copy, Debug)]
struct Deposit {
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
/// let v = GuideVertex { p: glam::Vec3::ZERO, n: glam::Vec3::Z, wo: glam::Vec3::Z };
/// // Untrained: uniform over the sphere.
/// assert!((guide.pdf(&v, glam::Vec3::X) - 0.25 / std::f32::consts::PI).abs() < 1e-6);
/// ```
#[derive(Debug)]
pub struct Ppg {
    config: PpgConfig,
    bounds: Aabb,
    nodes: Vec<SpatialNode>,
    leaves: Vec<Leaf>,
    pending: Mutex<Vec<Deposit>>,
    iteration: u32,
    learning: bool,
}

impl Ppg {
    /// An untrained guide over the scene box `bounds` (e.g. [`crate::scene::Scene::bounds`]).
    pub fn new(bounds: Aabb, config: PpgConfig) -> Self {
        Self {
            config,
            bounds,
            nodes: vec![SpatialNode::Leaf(0)],
            leaves: vec![Leaf::default()],
            pending: Mutex::new(Vec::new()),
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
        self.leaves.len()
    }

    fn leaf(&self, p: Vec3) -> &Leaf {
        &self.leaves[self.leaf_index(p)]
    }

    fn leaf_index(&self, p: Vec3) -> usize {
        self.locate(unit_position(&self.bounds, p)).0
    }

    /// The leaf containing `x` (in the unit cube) and the size of its cell.
    fn locate(&self, mut x: Vec3) -> (usize, Vec3) {
        let mut size = Vec3::ONE;
        let mut i = 0;
        loop {
            match self.nodes[i] {
                SpatialNode::Leaf(l) => return (l, size),
                SpatialNode::Inner { axis, children } => {
                    let upper = x[axis] >= 0.5;
                    x[axis] = 2.0 * x[axis] - f32::from(u8::from(upper));
                    size[axis] *= 0.5;
                    i = children[usize::from(upper)];
                }
            }
        }
    }

    /// Leaves overlapping the box `[lo, hi]` of the unit cube, with the overlap volumes.
    fn overlaps(&self, lo: Vec3, hi: Vec3, out: &mut Vec<(usize, f64)>) {
        out.clear();
        let mut stack = vec![(0usize, Vec3::ZERO, Vec3::ONE)];
        while let Some((i, cell_lo, cell_hi)) = stack.pop() {
            match self.nodes[i] {
                SpatialNode::Leaf(l) => {
                    let d = (cell_hi.min(hi) - cell_lo.max(lo))
                        .max(Vec3::ZERO)
                        .as_dvec3();
                    let volume = d.x * d.y * d.z;
                    if volume > 0.0 {
                        out.push((l, volume));
                    }
                }
                SpatialNode::Inner { axis, children } => {
                    let mid = 0.5 * (cell_lo[axis] + cell_hi[axis]);
                    if lo[axis] < mid {
                        let mut h = cell_hi;
                        h[axis] = mid;
                        stack.push((children[0], cell_lo, h));
                    }
                    if hi[axis] > mid {
                        let mut l = cell_lo;
                        l[axis] = mid;
                        stack.push((children[1], l, cell_hi));
                    }
                }
            }
        }
    }

    /// Deposit one record into the building trees, at its leaf or spread by the box filter.
    fn deposit(&mut self, d: &Deposit, overlaps: &mut Vec<(usize, f64)>) {
        let x = unit_position(&self.bounds, d.p);
        let c = dir_to_cylindrical(d.wi);
        let (l, size) = self.locate(x);
        if self.config.spatial_filter {
            let (lo, hi) = (
                (x - 0.5 * size).max(Vec3::ZERO),
                (x + 0.5 * size).min(Vec3::ONE),
            );
            self.overlaps(lo, hi, overlaps);
            let total: f64 = overlaps.iter().map(|o| o.1).sum();
            if total > 0.0 {
                for &(l, v) in overlaps.iter() {
                    let w = v / total;
                    self.leaves[l].samples += w;
                    self.leaves[l].building.deposit(c, w * f64::from(d.flux));
                }
                return;
            }
        }
        self.leaves[l].samples += 1.0;
        self.leaves[l].building.deposit(c, f64::from(d.flux));
    }

    /// Split leaves that received more than `threshold` samples, recursively (children get
    /// copies of the trees and half the count, Müller et al.'s `SDTree::refine`).
    fn refine_space(&mut self, threshold: f64) {
        let mut stack = vec![(0usize, 0usize, 0u32)]; // (node, axis, depth)
        while let Some((i, axis, depth)) = stack.pop() {
            match self.nodes[i] {
                SpatialNode::Inner { axis, children } => {
                    for c in children {
                        stack.push((c, (axis + 1) % 3, depth + 1));
                    }
                }
                SpatialNode::Leaf(l) => {
                    if self.leaves[l].samples <= threshold || depth >= self.config.max_spatial_depth
                    {
                        continue;
                    }
                    self.leaves[l].samples *= 0.5;
                    let copy = self.leaves[l].clone();
                    self.leaves.push(copy);
                    let children = [self.nodes.len(), self.nodes.len() + 1];
                    self.nodes.push(SpatialNode::Leaf(l));
                    self.nodes.push(SpatialNode::Leaf(self.leaves.len() - 1));
                    self.nodes[i] = SpatialNode::Inner { axis, children };
                    stack.push((i, axis, depth));
                }
            }
        }
    }
}

impl Guide for Ppg {
    fn selection_probability(&self, vertex: &GuideVertex, material: &Material) -> f32 {
        if material.is_delta() || self.leaf(vertex.p).sampling_total <= 0.0 {
            0.0
        } else {
            1.0 - self.config.bsdf_fraction
        }
    }

    fn sample(&self, vertex: &GuideVertex, u: Vec2) -> Option<(Vec3, f32)> {
        let leaf = self.leaf(vertex.p);
        let wi = cylindrical_to_dir(leaf.sampling.sample(u));
        // The density of the direction actually returned, so that it equals `pdf(wi)` even
        // where rounding moved it across a cell boundary.
        let pdf = (leaf.sampling.pdf(dir_to_cylindrical(wi)) / (4.0 * PI)) as f32;
        (pdf > 0.0).then_some((wi, pdf))
    }

    fn pdf(&self, vertex: &GuideVertex, wi: Vec3) -> f32 {
        (self.leaf(vertex.p).sampling.pdf(dir_to_cylindrical(wi)) / (4.0 * PI)) as f32
    }

    fn wants_records(&self) -> bool {
        self.learning
    }

    fn end_training(&mut self) {
        self.learning = false;
    }

    fn record(&self, records: &[GuideRecord]) {
        let deposits = records.iter().filter_map(|r| {
            let flux = r.radiance.max(Vec3::ZERO).element_sum() / (3.0 * r.pdf);
            (r.pdf > 0.0 && flux.is_finite()).then_some(Deposit {
                p: r.vertex.p,
                wi: r.wi,
                flux,
            })
        });
        let mut pending = self.pending.lock().unwrap_or_else(|e| e.into_inner());
        pending.extend(deposits);
    }

    fn end_iteration(&mut self, _iteration: usize) {
        if !self.learning {
            return;
        }
        let mut deposits =
            std::mem::take(self.pending.get_mut().unwrap_or_else(|e| e.into_inner()));
        deposits.sort_unstable_by_key(Deposit::key);
        let mut overlaps = Vec::new();
        for d in &deposits {
            self.deposit(d, &mut overlaps);
        }
        for leaf in &mut self.leaves {
            leaf.sampling = std::mem::take(&mut leaf.building);
            leaf.sampling.sum_up();
            leaf.sampling_total = leaf.sampling.total();
        }
        let threshold = self.config.spatial_threshold * 2f64.powf(0.5 * f64::from(self.iteration));
        self.refine_space(threshold);
        let (depth, rho) = (self.config.max_quadtree_depth, self.config.flux_threshold);
        for leaf in &mut self.leaves {
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
            },
            wi,
            pdf: 1.0,
            bsdf_pdf: 0.0,
            bsdf_cos: Vec3::ONE,
            radiance: Vec3::splat(radiance),
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
        guide.record(&records);
        guide.end_iteration(0);
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
        let at = |p: Vec3| g.leaf_index(p);
        assert_eq!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.1, 0.4, 0.9)));
        assert_ne!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.6, 0.3, 0.3)));
        assert_ne!(at(Vec3::new(0.3, 0.3, 0.3)), at(Vec3::new(0.3, 0.6, 0.3)));
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
            g.leaves.iter_mut().for_each(|l| l.samples = 0.0);
            g.deposit(&d, &mut overlaps);
            [g.leaves[0].samples, g.leaves[1].samples]
        };
        let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() + (a[1] - b[1]).abs() < 1e-6;
        // The box is as wide as the cell (½ along x) and clipped to the cube.
        assert!(close(shares(0.25), [1.0, 0.0]));
        assert!(close(shares(0.1), [1.0, 0.0]));
        assert!(close(shares(0.5), [0.5, 0.5]));
        assert!(close(shares(0.4), [0.7, 0.3]), "{:?}", shares(0.4));
        assert!(close(shares(0.9), [0.0, 1.0]));
    }

    #[test]
    fn quadtree_subdivides_quadrants_above_rho_of_the_flux() {
        // Flux fractions of the four top-level quadrants: 0.5 %, 0.5 %, 5 %, 94 %.
        let mut tree = QuadTree::default();
        let fractions = [0.005, 0.005, 0.05, 0.94];
        for (q, f) in fractions.iter().enumerate() {
            let centre = Vec2::new(0.25 + 0.5 * (q & 1) as f32, 0.25 + 0.5 * (q >> 1) as f32);
            tree.deposit(centre, *f);
        }
        tree.sum_up();
        let refined = tree.refined(20, 0.01);
        // 0.5 % stays a leaf; 5 % gets a node whose quadrants (1.25 % each) get nodes whose
        // quadrants (0.31 %) stay leaves: 1 + 4 nodes; 94 % → 23.5 % → 5.9 % → 1.5 % → 0.37 %:
        // 1 + 4 + 16 + 64 nodes. With the root: 91.
        assert_eq!(refined.nodes.len(), 1 + 5 + 85);
        assert_eq!(refined.nodes[0].child[0], 0);
        assert_eq!(refined.nodes[0].child[1], 0);
        assert!(refined.total() == 0.0);
        // The depth limit caps the refinement: with 2 levels only the root's quadrants 2, 3
        // get nodes.
        assert_eq!(tree.refined(2, 0.01).nodes.len(), 3);
        // Without flux, quadrants are refined while 4^-d > ρ: levels 1..3 (1 + 4 + 16 + 64).
        assert_eq!(QuadTree::default().refined(20, 0.01).nodes.len(), 85);
    }

    #[test]
    fn quadtree_density_is_the_product_of_four_times_child_over_parent() {
        let mut tree = QuadTree::default().refined(2, 0.01); // root + 4 children
        tree.deposit(Vec2::new(0.1, 0.1), 3.0); // quadrant 0 of quadrant 0
        tree.deposit(Vec2::new(0.9, 0.9), 1.0); // quadrant 3 of quadrant 3
        tree.sum_up();
        // 4 · 3/4 at the root, 4 · 3/3 below.
        assert!((tree.pdf(Vec2::new(0.1, 0.1)) - 12.0).abs() < 1e-12);
        assert!((tree.pdf(Vec2::new(0.9, 0.9)) - 4.0).abs() < 1e-12);
        assert_eq!(tree.pdf(Vec2::new(0.9, 0.1)), 0.0);
        let s = tree.sample(Vec2::new(0.5, 0.5));
        assert!(s.x < 0.25 && s.y < 0.25, "{s}");
    }
}
