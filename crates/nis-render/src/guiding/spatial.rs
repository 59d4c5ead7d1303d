//! The spatial half of the classical guides: a binary tree over the scene's bounding cube whose
//! leaves hold a directional distribution each.
//!
//! This is the spatial binary tree of Practical Path Guiding (Müller, Gross & Novák 2017, §5.1):
//! a cell is split at its midpoint, along x, y and z in turn (the axis of a cell at depth `d` is
//! `d mod 3`), so cells stay near-cubic in the cube around the scene and a point finds its leaf by
//! halving its coordinates. Vorba et al. (2014) cache their mixtures in a kd-tree for the same
//! purpose; both [`Ppg`](super::ppg::Ppg) and [`Gmm`](super::gmm::Gmm) use this one tree, and
//! differ only in what a leaf holds and in when it splits (the caller's `split` rule of
//! [`SpatialTree::refine`]).
//!
//! Positions are taken relative to the cube with corner `bounds.min` and side the largest extent
//! of `bounds`, clamped to `[0, 1)³` ([`SpatialTree::unit_position`]).

use glam::Vec3;

use super::ONE_MINUS_EPSILON;
use crate::bvh::Aabb;

#[derive(Clone, Copy, Debug)]
enum Node {
    /// Split at the midpoint of `axis`; children are node indices (lower half first).
    Inner { axis: usize, children: [usize; 2] },
    /// Index into [`SpatialTree::leaves`].
    Leaf(usize),
}

/// A binary tree over the scene cube with a `T` in every leaf (see the module documentation).
#[derive(Clone, Debug)]
pub struct SpatialTree<T> {
    bounds: Aabb,
    nodes: Vec<Node>,
    leaves: Vec<T>,
}

/// Where a point lies in the tree: its leaf, the point in the leaf's cell scaled to `[0, 1)³`,
/// and the cell's size relative to the scene cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Location {
    /// Index of the leaf ([`SpatialTree::leaf`]).
    pub leaf: usize,
    /// The point in the leaf's own unit cube.
    pub local: Vec3,
    /// Side lengths of the leaf's cell, as fractions of the scene cube's side.
    pub size: Vec3,
}

impl<T> SpatialTree<T> {
    /// A tree of one leaf, `root`, over the scene box `bounds`.
    pub fn new(bounds: Aabb, root: T) -> Self {
        Self {
            bounds,
            nodes: vec![Node::Leaf(0)],
            leaves: vec![root],
        }
    }

    /// `p` in coordinates of the scene cube (`bounds.min` and the largest extent), clamped to
    /// `[0, 1)³`.
    pub fn unit_position(&self, p: Vec3) -> Vec3 {
        let extent = (self.bounds.max - self.bounds.min)
            .max_element()
            .max(f32::MIN_POSITIVE);
        ((p - self.bounds.min) / extent).clamp(Vec3::ZERO, Vec3::splat(ONE_MINUS_EPSILON))
    }

    /// The leaf containing the point `x` of the unit cube. Each level doubles the coordinate of
    /// its axis and drops the integer part, which is exact in floating point.
    pub fn locate_unit(&self, mut x: Vec3) -> Location {
        let mut size = Vec3::ONE;
        let mut i = 0;
        loop {
            match self.nodes[i] {
                Node::Leaf(leaf) => {
                    return Location {
                        leaf,
                        local: x,
                        size,
                    }
                }
                Node::Inner { axis, children } => {
                    let upper = x[axis] >= 0.5;
                    x[axis] = 2.0 * x[axis] - f32::from(u8::from(upper));
                    size[axis] *= 0.5;
                    i = children[usize::from(upper)];
                }
            }
        }
    }

    /// Index of the leaf containing the world point `p`.
    pub fn leaf_index(&self, p: Vec3) -> usize {
        self.locate_unit(self.unit_position(p)).leaf
    }

    /// The leaf with index `i`.
    pub fn leaf(&self, i: usize) -> &T {
        &self.leaves[i]
    }

    /// All leaves, by index.
    pub fn leaves(&self) -> &[T] {
        &self.leaves
    }

    /// All leaves, by index, for updating in place.
    pub fn leaves_mut(&mut self) -> &mut [T] {
        &mut self.leaves
    }

    /// Leaves overlapping the box `[lo, hi]` of the unit cube, with the volumes of the
    /// overlaps (as fractions of the cube), written to `out`.
    pub fn overlaps(&self, lo: Vec3, hi: Vec3, out: &mut Vec<(usize, f64)>) {
        out.clear();
        let mut stack = vec![(0usize, Vec3::ZERO, Vec3::ONE)];
        while let Some((i, cell_lo, cell_hi)) = stack.pop() {
            match self.nodes[i] {
                Node::Leaf(l) => {
                    let d = (cell_hi.min(hi) - cell_lo.max(lo))
                        .max(Vec3::ZERO)
                        .as_dvec3();
                    let volume = d.x * d.y * d.z;
                    if volume > 0.0 {
                        out.push((l, volume));
                    }
                }
                Node::Inner { axis, children } => {
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

    /// Split leaves, recursively and depth first: `split(leaf, axis)` decides
    /// whether a leaf splits along `axis`; if so it turns the leaf into the lower half's and
    /// returns the upper half's (which gets a new index, after all existing leaves). A leaf at
    /// `max_depth` is never split.
    pub fn refine(&mut self, max_depth: u32, mut split: impl FnMut(&mut T, usize) -> Option<T>) {
        let mut stack = vec![(0usize, 0u32)]; // (node, depth)
        while let Some((i, depth)) = stack.pop() {
            match self.nodes[i] {
                Node::Inner { children, .. } => {
                    for c in children {
                        stack.push((c, depth + 1));
                    }
                }
                Node::Leaf(l) => {
                    let axis = depth as usize % 3;
                    if depth >= max_depth {
                        continue;
                    }
                    let Some(upper) = split(&mut self.leaves[l], axis) else {
                        continue;
                    };
                    self.leaves.push(upper);
                    let children = [self.nodes.len(), self.nodes.len() + 1];
                    self.nodes.push(Node::Leaf(l));
                    self.nodes.push(Node::Leaf(self.leaves.len() - 1));
                    self.nodes[i] = Node::Inner { axis, children };
                    stack.push((i, depth));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tree() -> SpatialTree<u32> {
        let bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        SpatialTree::new(bounds, 0)
    }

    /// Split every leaf whose value is below `levels`, children one level deeper.
    fn split_to(levels: u32) -> impl FnMut(&mut u32, usize) -> Option<u32> {
        move |v, _| {
            (*v < levels).then(|| {
                *v += 1;
                *v
            })
        }
    }

    #[test]
    fn positions_are_taken_in_the_cube_of_the_largest_extent_and_clamped() {
        let tree = SpatialTree::new(
            Aabb {
                min: Vec3::new(-1.0, 0.0, 0.0),
                max: Vec3::new(3.0, 1.0, 2.0),
            },
            (),
        );
        assert_eq!(
            tree.unit_position(Vec3::new(1.0, 0.5, 1.0)),
            Vec3::new(0.5, 0.125, 0.25)
        );
        let far = tree.unit_position(Vec3::new(9.0, -5.0, 2.0));
        assert_eq!(far, Vec3::new(ONE_MINUS_EPSILON, 0.0, 0.5));
    }

    #[test]
    fn refinement_cycles_the_axes_and_locates_points_in_their_cells() {
        let mut tree = unit_tree();
        // Three levels everywhere: 8 cells of ½ × ½ × ½.
        tree.refine(20, split_to(3));
        assert_eq!(tree.leaves().len(), 8);
        let mut seen = std::collections::HashSet::new();
        for i in 0..8 {
            let corner = Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32);
            let p = 0.5 * corner + Vec3::new(0.1, 0.2, 0.3);
            let at = tree.locate_unit(p);
            assert_eq!(at.size, Vec3::splat(0.5));
            assert!(
                (at.local - Vec3::new(0.2, 0.4, 0.6)).length() < 1e-6,
                "{at:?}"
            );
            assert!(seen.insert(at.leaf), "two cells share leaf {}", at.leaf);
        }
        // Depth 1 splits along x only: two leaves, ½ × 1 × 1.
        let mut tree = unit_tree();
        tree.refine(20, split_to(1));
        assert_eq!(tree.leaves().len(), 2);
        let at = tree.locate_unit(Vec3::new(0.75, 0.3, 0.9));
        assert_eq!((at.leaf, at.size), (1, Vec3::new(0.5, 1.0, 1.0)));
        assert_eq!(tree.leaf_index(Vec3::new(0.25, 0.9, 0.9)), 0);
    }

    #[test]
    fn refinement_stops_at_the_depth_limit_and_keeps_unsplit_leaves() {
        let mut tree = unit_tree();
        tree.refine(2, split_to(10));
        assert_eq!(tree.leaves().len(), 4);
        // Splitting only the upper-x half: the lower half stays one leaf.
        let mut tree = unit_tree();
        tree.refine(20, split_to(1));
        tree.leaves_mut()[0] = 0;
        tree.refine(20, |v, axis| {
            (*v == 1 && axis == 1).then(|| {
                *v = 7;
                8
            })
        });
        assert_eq!(tree.leaves(), &[0, 7, 8]);
        assert_eq!(tree.leaf_index(Vec3::new(0.9, 0.2, 0.5)), 1);
        assert_eq!(tree.leaf_index(Vec3::new(0.9, 0.7, 0.5)), 2);
        assert_eq!(tree.leaf_index(Vec3::new(0.1, 0.7, 0.5)), 0);
    }

    #[test]
    fn overlaps_are_clipped_to_cells_and_sum_to_the_box_volume() {
        let mut tree = unit_tree();
        tree.refine(20, split_to(2)); // 4 cells of ½ × ½ × 1
        let mut out = Vec::new();
        tree.overlaps(
            Vec3::new(0.25, 0.25, 0.0),
            Vec3::new(0.75, 0.5, 1.0),
            &mut out,
        );
        out.sort_by_key(|o| o.0);
        assert_eq!(out.len(), 2, "{out:?}");
        assert!(out.iter().all(|o| (o.1 - 0.0625).abs() < 1e-9), "{out:?}");
        let total: f64 = out.iter().map(|o| o.1).sum();
        assert!((total - 0.5 * 0.25).abs() < 1e-9);
    }
}
