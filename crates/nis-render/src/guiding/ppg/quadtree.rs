//! The directional half of Practical Path Guiding (Müller, Gross & Novák 2017, §5.2): a quadtree
//! over the unit square of world-space cylindrical coordinates `((cos θ + 1)/2, φ/2π)` whose
//! nodes store the radiance flux of their four quadrants.
//!
//! Sampling descends the tree picking children by their flux (hierarchical sample warping); the
//! density on the square is the product of `4 · child / parent` along the way. A new tree's
//! structure is refined from the previous one's flux: a quadrant carrying more than a fraction
//! `ρ` of the total gets children, the others become leaves.

use glam::Vec2;

use crate::guiding::ONE_MINUS_EPSILON;

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
pub(super) struct QuadTree {
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
    pub(super) fn total(&self) -> f64 {
        self.nodes[0].flux.iter().sum()
    }

    /// Add `flux` to the leaf quadrant containing `x`.
    pub(super) fn deposit(&mut self, mut x: Vec2, flux: f64) {
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
    pub(super) fn sum_up(&mut self) {
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
    pub(super) fn pdf(&self, mut x: Vec2) -> f64 {
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
    pub(super) fn sample(&self, u: Vec2) -> Vec2 {
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
    pub(super) fn refined(&self, max_depth: u32, rho: f64) -> QuadTree {
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

#[cfg(test)]
mod tests {
    use super::*;

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
