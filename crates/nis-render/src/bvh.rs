//! A bounding volume hierarchy over triangles, built with the binned surface area heuristic.
//!
//! The build follows Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies"
//! (IEEE RT 2007): at each node the triangle centroids are binned along the widest axis and the
//! split minimising `area(L)·n(L) + area(R)·n(R)` is taken, or a leaf is made when no split is
//! cheaper than intersecting every triangle. Nodes are stored depth-first in one array (left
//! child right after its parent) and traversed with a small stack, near child first. Triangles
//! are intersected with the Möller–Trumbore test (JGT 1997).
//!
//! We use our own BVH rather than a crate: the scenes of the experiments are small to medium
//! meshes, the whole structure is ~250 lines, and owning it lets shadow rays stop at the first hit
//! and keeps the triangle layout (`p0`, two edges) next to the nodes that reference it.

use glam::{Vec3, Vec3A};

use crate::geometry::Ray;

/// A triangle stored for intersection: one vertex and the two edges leaving it.
#[derive(Clone, Copy, Debug)]
pub struct Triangle {
    /// First vertex.
    pub p0: Vec3,
    /// `p1 - p0`.
    pub e1: Vec3,
    /// `p2 - p0`.
    pub e2: Vec3,
}

impl Triangle {
    /// The triangle with vertices `a`, `b`, `c`.
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self {
            p0: a,
            e1: b - a,
            e2: c - a,
        }
    }

    fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        b.grow(self.p0);
        b.grow(self.p0 + self.e1);
        b.grow(self.p0 + self.e2);
        b
    }

    /// Möller–Trumbore: distance and barycentrics `(u, v)` of the hit in `(t_min, t_max)`.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
        let p = ray.dir.cross(self.e2);
        let det = self.e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv_det = 1.0 / det;
        let s = ray.origin - self.p0;
        let u = s.dot(p) * inv_det;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = ray.dir.dot(q) * inv_det;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv_det;
        (t > 0.0 && t < t_max).then_some((t, u, v))
    }
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    fn half_area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec3::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// A flattened node: an interior node's left child follows it, `offset` is its right child; a
/// leaf holds `count` triangles starting at `offset`. Bounds are SIMD vectors for the slab test.
#[derive(Clone, Copy, Debug)]
struct Node {
    min: Vec3A,
    max: Vec3A,
    offset: u32,
    count: u16,
    axis: u16,
}

impl Node {
    /// Slab test: the entry distance if the ray meets the box before `t_max`.
    #[inline(always)]
    fn hit(&self, origin: Vec3A, inv_dir: Vec3A, t_max: f32) -> Option<f32> {
        let t0 = (self.min - origin) * inv_dir;
        let t1 = (self.max - origin) * inv_dir;
        let t_near = t0.min(t1).max_element().max(0.0);
        let t_far = t0.max(t1).min_element().min(t_max);
        (t_near <= t_far).then_some(t_near)
    }
}

/// Bins per axis for the SAH sweep.
const SAH_BINS: usize = 16;
/// Largest leaf the builder makes.
const MAX_LEAF: usize = 4;
/// Depth from which nodes are split at the median instead of by SAH, keeping the tree (and
/// the fixed traversal stack of 64 entries) shallow: at most this plus log2(n) levels.
const MAX_SAH_DEPTH: usize = 30;
/// Cost of one traversal step relative to one triangle test.
const TRAVERSAL_COST: f32 = 1.0;

/// A ray–triangle hit: distance, triangle index (in the BVH's order) and barycentrics.
#[derive(Clone, Copy, Debug)]
pub struct TriangleHit {
    /// Distance along the ray.
    pub t: f32,
    /// Index into [`Bvh::triangles`].
    pub prim: u32,
    /// Barycentric of the second vertex.
    pub u: f32,
    /// Barycentric of the third vertex.
    pub v: f32,
}

/// The BVH together with its (reordered) triangles.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    triangles: Vec<Triangle>,
}

impl Bvh {
    /// Build over `triangles`; also returns `order`, where `order[i]` is the input index of the
    /// BVH's `i`-th triangle.
    pub fn build(triangles: &[Triangle]) -> (Bvh, Vec<u32>) {
        let bounds: Vec<Aabb> = triangles.iter().map(Triangle::bounds).collect();
        let centroids: Vec<Vec3> = bounds.iter().map(|b| 0.5 * (b.min + b.max)).collect();
        let mut order: Vec<u32> = (0..triangles.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * triangles.len() / MAX_LEAF + 1);
        if !triangles.is_empty() {
            Builder {
                nodes: &mut nodes,
                bounds: &bounds,
                centroids: &centroids,
            }
            .build_node(&mut order, 0, 0);
        }
        let triangles = order.iter().map(|&i| triangles[i as usize]).collect();
        (Bvh { nodes, triangles }, order)
    }

    /// The triangles in BVH order.
    pub fn triangles(&self) -> &[Triangle] {
        &self.triangles
    }

    /// Closest hit before `t_max`.
    pub fn intersect(&self, ray: &Ray, mut t_max: f32) -> Option<TriangleHit> {
        let origin = Vec3A::from(ray.origin);
        let inv_dir = Vec3A::from(ray.dir).recip();
        let root = self.nodes.first()?;
        root.hit(origin, inv_dir, t_max)?;
        // Stack of (node, entry distance): far children whose boxes were hit.
        let mut stack = [(0u32, 0.0f32); 64];
        let mut sp = 0usize;
        let mut idx = 0usize;
        let mut best: Option<TriangleHit> = None;
        loop {
            let node = &self.nodes[idx];
            if node.count > 0 {
                let first = node.offset as usize;
                for (k, tri) in self.triangles[first..first + node.count as usize]
                    .iter()
                    .enumerate()
                {
                    if let Some((t, u, v)) = tri.intersect(ray, t_max) {
                        t_max = t;
                        best = Some(TriangleHit {
                            t,
                            prim: (first + k) as u32,
                            u,
                            v,
                        });
                    }
                }
            } else {
                let (left, right) = (idx + 1, node.offset as usize);
                let hl = self.nodes[left].hit(origin, inv_dir, t_max);
                let hr = self.nodes[right].hit(origin, inv_dir, t_max);
                match (hl, hr) {
                    (Some(tl), Some(tr)) => {
                        let (near, far, t_far) = if tl <= tr {
                            (left, right, tr)
                        } else {
                            (right, left, tl)
                        };
                        stack[sp] = (far as u32, t_far);
                        sp += 1;
                        idx = near;
                        continue;
                    }
                    (Some(_), None) => {
                        idx = left;
                        continue;
                    }
                    (None, Some(_)) => {
                        idx = right;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next far child that may still hold a closer hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (i, t) = stack[sp];
                if t <= t_max {
                    idx = i as usize;
                    break;
                }
            }
        }
    }

    /// Whether anything is hit before `t_max` (shadow rays: stops at the first hit).
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        let origin = Vec3A::from(ray.origin);
        let inv_dir = Vec3A::from(ray.dir).recip();
        let Some(root) = self.nodes.first() else {
            return false;
        };
        if root.hit(origin, inv_dir, t_max).is_none() {
            return false;
        }
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let mut idx = 0usize;
        loop {
            let node = &self.nodes[idx];
            if node.count > 0 {
                let first = node.offset as usize;
                let leaf = &self.triangles[first..first + node.count as usize];
                if leaf.iter().any(|tri| tri.intersect(ray, t_max).is_some()) {
                    return true;
                }
            } else {
                let (left, right) = (idx + 1, node.offset as usize);
                let hl = self.nodes[left].hit(origin, inv_dir, t_max).is_some();
                let hr = self.nodes[right].hit(origin, inv_dir, t_max).is_some();
                match (hl, hr) {
                    (true, true) => {
                        stack[sp] = right as u32;
                        sp += 1;
                        idx = left;
                        continue;
                    }
                    (true, false) => {
                        idx = left;
                        continue;
                    }
                    (false, true) => {
                        idx = right;
                        continue;
                    }
                    (false, false) => {}
                }
            }
            if sp == 0 {
                return false;
            }
            sp -= 1;
            idx = stack[sp] as usize;
        }
    }

    /// Depth of the tree (for tests and statistics).
    pub fn depth(&self) -> usize {
        fn rec(nodes: &[Node], i: usize) -> usize {
            let n = &nodes[i];
            if n.count > 0 {
                1
            } else {
                1 + rec(nodes, i + 1).max(rec(nodes, n.offset as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            rec(&self.nodes, 0)
        }
    }
}

/// The state of a BVH build: the nodes so far, and every triangle's bounds and centroid.
struct Builder<'a> {
    nodes: &'a mut Vec<Node>,
    bounds: &'a [Aabb],
    centroids: &'a [Vec3],
}

impl Builder<'_> {
    /// Build the subtree over `order[..]` (which starts at `first` in the final triangle
    /// array).
    fn build_node(&mut self, order: &mut [u32], first: usize, depth: usize) -> usize {
        let (bounds, centroids) = (self.bounds, self.centroids);
        let node_bounds = order
            .iter()
            .fold(Aabb::EMPTY, |b, &i| b.union(&bounds[i as usize]));
        let this = self.nodes.len();
        self.nodes.push(Node {
            min: node_bounds.min.into(),
            max: node_bounds.max.into(),
            offset: first as u32,
            count: order.len() as u16,
            axis: 0,
        });
        if order.len() <= MAX_LEAF {
            return this;
        }
        let mut cb = Aabb::EMPTY;
        for &i in order.iter() {
            cb.grow(centroids[i as usize]);
        }
        let extent = cb.max - cb.min;
        let axis = extent.max_position();
        if depth >= MAX_SAH_DEPTH {
            // Deep below here SAH may be peeling off a few triangles at a time; split at the
            // median instead, which bounds the remaining depth by log2(n) and so the
            // traversal stack.
            let mid = order.len() / 2;
            order.select_nth_unstable_by(mid, |&a, &b| {
                centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
            });
            return self.finish_interior(order, first, depth, this, Split { mid, axis });
        }
        let split = if extent[axis] > 0.0 {
            best_split(order, axis, &cb, bounds, centroids, &node_bounds)
        } else {
            None
        };
        let mid = match split {
            Some(pos) => partition(order, |i| centroids[i as usize][axis] < pos),
            // All centroids coincide (or no split pays off) but too many for one leaf: halve.
            None if order.len() > u16::MAX as usize / 2 || order.len() > 4 * MAX_LEAF => {
                order.len() / 2
            }
            None => return this,
        };
        let mid = if mid == 0 || mid == order.len() {
            order.len() / 2
        } else {
            mid
        };
        self.finish_interior(order, first, depth, this, Split { mid, axis })
    }

    /// Build both children of node `this`, split as `split` says, and link them.
    fn finish_interior(
        &mut self,
        order: &mut [u32],
        first: usize,
        depth: usize,
        this: usize,
        split: Split,
    ) -> usize {
        let (left, right) = order.split_at_mut(split.mid);
        self.build_node(left, first, depth + 1);
        let right_child = self.build_node(right, first + split.mid, depth + 1);
        let node = &mut self.nodes[this];
        node.offset = right_child as u32;
        node.count = 0;
        node.axis = split.axis as u16;
        this
    }
}

/// Where an interior node splits its triangles: the first index of the right child's part of
/// the order, and the axis the split was made along.
#[derive(Clone, Copy, Debug)]
struct Split {
    mid: usize,
    axis: usize,
}

/// The SAH-best split position along `axis`, or `None` if a leaf is cheaper.
fn best_split(
    order: &[u32],
    axis: usize,
    cb: &Aabb,
    bounds: &[Aabb],
    centroids: &[Vec3],
    node_bounds: &Aabb,
) -> Option<f32> {
    let mut bin_bounds = [Aabb::EMPTY; SAH_BINS];
    let mut bin_count = [0usize; SAH_BINS];
    let scale = SAH_BINS as f32 / (cb.max[axis] - cb.min[axis]);
    let bin_of = |c: f32| (((c - cb.min[axis]) * scale) as usize).min(SAH_BINS - 1);
    for &i in order {
        let b = bin_of(centroids[i as usize][axis]);
        bin_count[b] += 1;
        bin_bounds[b] = bin_bounds[b].union(&bounds[i as usize]);
    }
    // Sweep from the right to get the cost of every right part, then from the left.
    let mut right_area = [0.0f32; SAH_BINS];
    let mut right_count = [0usize; SAH_BINS];
    let (mut acc, mut n) = (Aabb::EMPTY, 0);
    for b in (1..SAH_BINS).rev() {
        acc = acc.union(&bin_bounds[b]);
        n += bin_count[b];
        right_area[b] = acc.half_area();
        right_count[b] = n;
    }
    let (mut acc, mut n) = (Aabb::EMPTY, 0);
    let mut best = (f32::INFINITY, 0usize);
    for b in 0..SAH_BINS - 1 {
        acc = acc.union(&bin_bounds[b]);
        n += bin_count[b];
        if n == 0 || right_count[b + 1] == 0 {
            continue;
        }
        let cost = acc.half_area() * n as f32 + right_area[b + 1] * right_count[b + 1] as f32;
        if cost < best.0 {
            best = (cost, b);
        }
    }
    let leaf_cost = order.len() as f32;
    let split_cost = TRAVERSAL_COST + best.0 / node_bounds.half_area().max(f32::MIN_POSITIVE);
    let must_split = order.len() > MAX_LEAF * 4;
    if best.0.is_finite() && (split_cost < leaf_cost || must_split) {
        Some(cb.min[axis] + (best.1 + 1) as f32 / scale)
    } else {
        None
    }
}

/// In-place partition; returns the number of elements for which `pred` holds (moved first).
fn partition(v: &mut [u32], pred: impl Fn(u32) -> bool) -> usize {
    let mut i = 0;
    for j in 0..v.len() {
        if pred(v[j]) {
            v.swap(i, j);
            i += 1;
        }
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg32;

    fn brute_force(tris: &[Triangle], ray: &Ray) -> Option<f32> {
        tris.iter()
            .filter_map(|t| t.intersect(ray, f32::INFINITY).map(|h| h.0))
            .min_by(|a, b| a.total_cmp(b))
    }

    #[test]
    fn adversarial_layouts_keep_the_tree_shallow() {
        // Triangles at exponentially growing distances invite SAH to peel one off per level.
        let tris: Vec<Triangle> = (0..300)
            .map(|i| {
                let x = 1.1f32.powi(i);
                Triangle::new(
                    Vec3::new(x, 0.0, 0.0),
                    Vec3::new(x, 1.0, 0.0),
                    Vec3::new(x, 0.0, 1.0),
                )
            })
            .chain((0..100).map(|_| Triangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)))
            .collect();
        let (bvh, _) = Bvh::build(&tris);
        assert!(bvh.depth() <= MAX_SAH_DEPTH + 12, "depth {}", bvh.depth());
        let ray = Ray::new(Vec3::new(-1.0, 0.2, 0.2), Vec3::X);
        assert!(bvh.intersect(&ray, f32::INFINITY).is_some());
    }

    #[test]
    fn bvh_closest_hit_matches_brute_force_on_random_triangles() {
        let mut rng = Pcg32::seed_from_u64(7);
        let mut v = || Vec3::new(rng.random(), rng.random(), rng.random()) * 10.0;
        let tris: Vec<Triangle> = (0..2000)
            .map(|_| {
                let a = v();
                Triangle::new(
                    a,
                    a + 0.3 * (v() - 5.0 * Vec3::ONE) / 5.0,
                    a + (v() - 5.0 * Vec3::ONE) / 10.0,
                )
            })
            .collect();
        let (bvh, order) = Bvh::build(&tris);
        assert_eq!(order.len(), tris.len());
        assert!(bvh.depth() < 40);
        let mut rng = Pcg32::seed_from_u64(8);
        for _ in 0..2000 {
            let o = Vec3::new(rng.random(), rng.random(), rng.random()) * 12.0 - Vec3::ONE;
            let d = (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5).normalize();
            let ray = Ray::new(o, d);
            let expect = brute_force(&tris, &ray);
            let got = bvh.intersect(&ray, f32::INFINITY).map(|h| h.t);
            assert_eq!(expect.is_some(), got.is_some());
            if let (Some(e), Some(g)) = (expect, got) {
                assert!((e - g).abs() < 1e-4, "{e} vs {g}");
            }
            assert_eq!(bvh.occluded(&ray, f32::INFINITY), expect.is_some());
        }
    }
}
