//! The disk half of the Gaussian-mixture guide (Vorba et al. 2014, §4): the area-preserving map
//! between the hemisphere and the unit disk, 2-D Gaussians with their exact mass inside the
//! disk, and the mixture density on the disk with its uniform "outside" component.
//!
//! **Hemisphere ↔ disk.** The upper hemisphere maps to the unit disk by the area-preserving
//! (Lambert azimuthal, the Shirley–Chiu uniform-hemisphere) map: a disk point `d` with
//! `r = |d|` is the direction `(d·√(2 − r²), 1 − r²)`, inverse `d = (x, y)/√(1 + z)`. Since
//! `z = 1 − r²` gives `dω = dz dφ = 2r dr dφ = 2 dA`, a density `p_disk` on the disk is the
//! solid-angle density `p_disk / 2`.
//!
//! **Exact density on the disk.** Gaussians live on the plane; the disk density is
//! `p(d) = Σ_k w_k N_k(d) + (Σ_k w_k (1 − P_k)) / π` for `|d| < 1`, with `P_k` the mass
//! of component `k` inside the disk. Sampling picks `k`, draws `d ~ N_k` (Box–Muller) and
//! replaces a `d` outside the disk by a uniform disk point, which has exactly this density.
//! `P_k` is computed once per fit in the component's whitened coordinates, where the disk's
//! boundary seen from the mean is at distance `ρ(ψ)` in direction `ψ`, so
//! `P_k = (1/2π) ∫ (1 − exp(−ρ(ψ)²/2)) dψ` — a smooth periodic integrand that the trapezoid
//! rule integrates to near machine precision.

use std::f64::consts::PI;
use std::sync::OnceLock;

use glam::{DVec2, Vec2, Vec3};

use crate::sampling::{splitmix64, square_to_disk_concentric};

/// Directions of the trapezoid rule for the in-disk mass of a Gaussian.
const DISK_MASS_STEPS: usize = 1024;
/// Floor on covariance determinants, against round-off making a covariance singular.
const MIN_DETERMINANT: f64 = 1e-14;

/// Direction in the local frame (upper hemisphere) to the unit disk.
pub(super) fn hemisphere_to_disk(w: Vec3) -> DVec2 {
    let s = 1.0 / (1.0 + f64::from(w.z).max(0.0)).sqrt();
    DVec2::new(f64::from(w.x) * s, f64::from(w.y) * s)
}

/// Unit disk to the local upper hemisphere (inverse of [`hemisphere_to_disk`]).
pub(super) fn disk_to_hemisphere(d: DVec2) -> Vec3 {
    let r2 = d.length_squared().min(1.0);
    let s = (2.0 - r2).sqrt();
    Vec3::new((d.x * s) as f32, (d.y * s) as f32, (1.0 - r2) as f32)
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
pub(super) struct Component {
    pub(super) weight: f64,
    pub(super) mean: DVec2,
    /// Inverse covariance `(xx, xy, yy)`.
    pub(super) inv: [f64; 3],
    /// Lower Cholesky factor `(l11, l21, l22)`.
    pub(super) chol: [f64; 3],
    /// `ln(1 / (2π √det))`.
    pub(super) log_norm: f64,
    /// Mass inside the unit disk.
    pub(super) inside: f64,
}

impl Component {
    pub(super) fn new(weight: f64, mean: DVec2, cov: [f64; 3]) -> Self {
        let mut c = Self::without_mass(weight, mean, cov);
        c.inside = c.disk_mass();
        c
    }

    /// The Gaussian with its in-disk mass still unknown (0), for EM steps that only need
    /// densities.
    pub(super) fn without_mass(weight: f64, mean: DVec2, cov: [f64; 3]) -> Self {
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

    pub(super) fn log_density(&self, x: DVec2) -> f64 {
        let d = x - self.mean;
        let q = self.inv[0] * d.x * d.x + 2.0 * self.inv[1] * d.x * d.y + self.inv[2] * d.y * d.y;
        self.log_norm - 0.5 * q
    }

    pub(super) fn whitened_to_plane(&self, z: DVec2) -> DVec2 {
        self.mean + DVec2::new(self.chol[0] * z.x, self.chol[1] * z.x + self.chol[2] * z.y)
    }

    /// `P(|mean + L z| < 1)` for `z ~ N(0, I)`, by the trapezoid rule over directions `ψ` of
    /// `z`: along a ray from the mean the chi distribution gives `exp(−r0²/2) − exp(−r1²/2)`
    /// between the ray's entry and exit distances.
    pub(super) fn disk_mass(&self) -> f64 {
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

/// A Gaussian mixture on the unit disk with its uniform "outside" component.
#[derive(Clone, Debug)]
pub(super) struct Mixture {
    pub(super) components: Vec<Component>,
    /// Mass of the Gaussians outside the disk, spread uniformly over it.
    pub(super) outside: f64,
    /// Cumulative component weights for sampling.
    pub(super) cdf: Vec<f64>,
}

impl Mixture {
    /// Broad Gaussians at the centre and on a ring, equal weights.
    pub(super) fn initial(k: usize) -> Self {
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
        };
        m.finish();
        m
    }

    pub(super) fn finish(&mut self) {
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

    pub(super) fn pdf_disk(&self, d: DVec2) -> f64 {
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

    pub(super) fn sample_disk(&self, u: Vec2) -> DVec2 {
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
}
