//! Warps from uniform random numbers to directions and points, discrete distributions, the
//! power heuristic for multiple importance sampling, and the one integer hash of the crate.
//!
//! The warps are the standard ones (Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th
//! ed., ch. A.5); the power heuristic with β = 2 is Veach's (thesis, 1997, §9.2.4); the hash is
//! the SplitMix64 finaliser (Steele, Lea & Flood 2014, "Fast Splittable Pseudorandom Number
//! Generators"), which seeds every random stream of a render.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

/// Concentric map from the unit square to the unit disk (Shirley & Chiu 1997).
pub fn square_to_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, std::f32::consts::FRAC_PI_4 * (o.y / o.x))
    } else {
        (
            o.y,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (o.x / o.y),
        )
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Cosine-weighted direction on the +z hemisphere (Malley's method); pdf is `cos θ / π`.
pub fn square_to_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = square_to_disk_concentric(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Uniform direction on the unit sphere; pdf is `1 / 4π`.
pub fn square_to_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Uniform barycentrics `(b1, b2)` on a triangle (the square-root parametrisation).
pub fn square_to_triangle(u: Vec2) -> Vec2 {
    let su = u.x.sqrt();
    Vec2::new(1.0 - su, u.y * su)
}

/// Veach's power heuristic with β = 2 for two strategies with densities `pdf_a` and `pdf_b`.
pub fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    let a = pdf_a * pdf_a;
    let b = pdf_b * pdf_b;
    if a + b > 0.0 && (a + b).is_finite() {
        a / (a + b)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// The SplitMix64 finaliser: a bijective 64-bit mix whose outputs for consecutive inputs look
/// independent, used to derive seeds and extra random numbers from integers.
pub fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// A discrete distribution over `0..n` with probabilities proportional to given weights.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    cdf: Vec<f32>,
    total: f32,
}

impl Distribution1D {
    /// Build from non-negative weights; `None` if they sum to zero.
    pub fn new(weights: &[f32]) -> Option<Self> {
        let mut cdf = Vec::with_capacity(weights.len());
        let mut acc = 0.0f64;
        for &w in weights {
            acc += f64::from(w.max(0.0));
            cdf.push(acc as f32);
        }
        let total = acc as f32;
        if total <= 0.0 {
            return None;
        }
        for c in &mut cdf {
            *c /= total;
        }
        Some(Self { cdf, total })
    }

    /// Index drawn for the uniform number `u`.
    pub fn sample(&self, u: f32) -> usize {
        let i = self.cdf.partition_point(|&c| c <= u);
        i.min(self.cdf.len() - 1)
    }

    /// The cumulative probability up to and including index `i`.
    pub fn cdf_at(&self, i: usize) -> f32 {
        self.cdf[i]
    }

    /// Probability of index `i`.
    pub fn pmf(&self, i: usize) -> f32 {
        let lo = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        self.cdf[i] - lo
    }

    /// Sum of the weights it was built from.
    pub fn total(&self) -> f32 {
        self.total
    }
}

/// A discrete distribution over the cells of a grid with probabilities proportional to given
/// weights: a row by its sum, then a column within it (the marginal and conditional tables of an
/// environment map, Pharr et al., *PBR* 4th ed., §A.5.3). A row of zero weight is never drawn.
#[derive(Clone, Debug)]
pub struct Distribution2D {
    rows: Distribution1D,
    columns: Vec<Option<Distribution1D>>,
}

impl Distribution2D {
    /// Build from the non-negative weights of each row; `None` if they sum to zero.
    pub fn new(rows: &[Vec<f32>]) -> Option<Self> {
        let sums: Vec<f32> = rows
            .iter()
            .map(|r| r.iter().map(|&v| f64::from(v)).sum::<f64>() as f32)
            .collect();
        Some(Self {
            rows: Distribution1D::new(&sums)?,
            columns: rows.iter().map(|r| Distribution1D::new(r)).collect(),
        })
    }

    /// The cell `(row, column)` drawn for the uniform numbers `u` (`u.y` picks the row, `u.x`
    /// the column) and where they fell within it, in `[0, 1)²` (x, y).
    pub fn sample(&self, u: Vec2) -> Option<(usize, usize, Vec2)> {
        let (row, fy) = sample_within(&self.rows, u.y);
        let (column, fx) = sample_within(self.columns[row].as_ref()?, u.x);
        Some((row, column, Vec2::new(fx, fy)))
    }

    /// Probability of the cell `(row, column)`.
    pub fn pmf(&self, row: usize, column: usize) -> f32 {
        self.columns[row]
            .as_ref()
            .map_or(0.0, |c| self.rows.pmf(row) * c.pmf(column))
    }
}

/// A bin of `d` drawn for the uniform number `u`, and where `u` fell within it, in `[0, 1)`
/// (so that one number picks the bin and the position inside it).
pub fn sample_within(d: &Distribution1D, u: f32) -> (usize, f32) {
    let i = d.sample(u);
    let lo = if i == 0 { 0.0 } else { d.cdf_at(i - 1) };
    let p = d.pmf(i);
    let f = if p > 0.0 { (u - lo) / p } else { 0.5 };
    (i, f.clamp(0.0, 1.0 - f32::EPSILON))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distribution_pmf_matches_weights_and_sampling_inverts_cdf() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]).unwrap();
        assert!((d.pmf(0) - 0.25).abs() < 1e-6 && d.pmf(1) == 0.0);
        assert!((d.pmf(2) - 0.75).abs() < 1e-6);
        assert_eq!(d.sample(0.1), 0);
        assert_eq!(d.sample(0.25), 2);
        assert_eq!(d.sample(0.999_999), 2);
        assert!(Distribution1D::new(&[0.0, 0.0]).is_none());
    }

    #[test]
    fn cosine_hemisphere_is_unit_and_upper() {
        for i in 0..100 {
            let u = Vec2::new((i as f32 + 0.5) / 100.0, ((i * 37) % 100) as f32 / 100.0);
            let w = square_to_cosine_hemisphere(u);
            assert!((w.length() - 1.0).abs() < 1e-4 && w.z >= 0.0);
        }
    }

    #[test]
    fn a_grid_draws_cells_by_weight_and_never_a_row_of_none() {
        let d = Distribution2D::new(&[vec![1.0, 3.0], vec![0.0, 0.0], vec![2.0, 2.0]]).unwrap();
        let pmf = [
            d.pmf(0, 0),
            d.pmf(0, 1),
            d.pmf(1, 0),
            d.pmf(2, 0),
            d.pmf(2, 1),
        ];
        for (p, w) in pmf.iter().zip([1.0, 3.0, 0.0, 2.0, 2.0]) {
            assert!((p - w / 8.0).abs() < 1e-6, "{pmf:?}");
        }
        for k in 0..64 {
            let u = Vec2::new((k % 8) as f32 / 8.0 + 0.01, (k / 8) as f32 / 8.0 + 0.01);
            let (row, column, f) = d.sample(u).unwrap();
            assert!(row != 1 && d.pmf(row, column) > 0.0, "{u}");
            assert!((0.0..1.0).contains(&f.x) && (0.0..1.0).contains(&f.y));
        }
        assert!(Distribution2D::new(&[vec![0.0]]).is_none());
    }
}
