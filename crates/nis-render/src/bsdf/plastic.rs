//! Plastic: a diffuse base under a dielectric coating, smooth or rough (Mitsuba 3's `plastic`
//! and `roughplastic`, after Weidlich & Wilkie, "Arbitrarily Layered Micro-Facet Surfaces",
//! 2007). Light either reflects off the coating — a mirror, or a microfacet lobe
//! `F D G / (4 cos θo cos θi)` — or enters it, scatters diffusely in the base and leaves:
//!
//! `f_d = ρ / (1 − F̄) · T(θo) T(θi) / (π η²)`,
//!
//! where `T` is the coating's transmittance (`1 − F` when smooth, the microfacet interface's
//! directional transmittance when rough), `F̄` its hemispherically averaged internal
//! reflectance (the light that bounces between base and coating), and `ρ F̄` in place of `F̄`
//! with `nonlinear`. Sampling picks the coating or the base with Mitsuba's probabilities:
//! in proportion to `F(θo)·w_s` and `(1 − F(θo))·(1 − w_s)`, `w_s` the specular share of the
//! mean reflectances.

use std::f32::consts::FRAC_1_PI;
use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::fresnel::{fresnel_dielectric, refract};
use super::microfacet::Microfacet;
use super::BsdfSample;
use crate::geometry::{reflect, reflect_z, Rgb};
use crate::sampling::square_to_cosine_hemisphere;

/// Cosines at which a rough coating's transmittance is tabulated (evenly from 0 to 1).
pub const TRANSMITTANCE_RES: usize = 64;
/// Side of the midpoint grid over the visible-normal sample square that integrates a rough
/// interface's transmittance and reflectance.
const QUADRATURE: usize = 48;

/// A plastic BSDF's parameters and what follows from them.
#[derive(Clone, Debug, PartialEq)]
pub struct Plastic {
    /// Interior over exterior index of refraction of the coating.
    pub eta: f32,
    /// Reflectance of the diffuse base.
    pub diffuse_reflectance: Rgb,
    /// Factor on the coating's reflection.
    pub specular_reflectance: Rgb,
    /// Account for the base's colour in the light bouncing under the coating.
    pub nonlinear: bool,
    /// The rough coating's microfacets and its transmittance table; `None` when smooth.
    rough: Option<(Microfacet, Arc<[f32; TRANSMITTANCE_RES]>)>,
    /// Hemispherically averaged internal reflectance of the coating.
    internal_reflectance: f32,
    /// The coating's share in the choice of lobe.
    specular_weight: f32,
}

fn mean(c: Rgb) -> f32 {
    (c.x + c.y + c.z) / 3.0
}

impl Plastic {
    /// A plastic of relative index `eta` (> 0, ≠ 1 when rough), smooth (`rough = None`) or
    /// with a rough coating.
    pub fn new(
        eta: f32,
        diffuse_reflectance: Rgb,
        specular_reflectance: Rgb,
        nonlinear: bool,
        rough: Option<Microfacet>,
    ) -> Self {
        let specular_weight = {
            let s = mean(specular_reflectance);
            let d = mean(diffuse_reflectance);
            if s + d > 0.0 {
                s / (s + d)
            } else {
                0.5
            }
        };
        let (rough, internal_reflectance) = match rough {
            None => (None, smooth_internal_reflectance(eta)),
            Some(dist) => {
                let table = std::array::from_fn(|i| rough_transmittance(&dist, eta, cosine_at(i)));
                // Mitsuba's average: 2 · mean over the grid of R(μ) μ, from the inside.
                let internal = 2.0
                    * (0..TRANSMITTANCE_RES)
                        .map(|i| {
                            let mu = cosine_at(i);
                            rough_reflectance(&dist, 1.0 / eta, mu) * mu
                        })
                        .sum::<f32>()
                    / TRANSMITTANCE_RES as f32;
                (Some((dist, Arc::new(table))), internal)
            }
        };
        Plastic {
            eta,
            diffuse_reflectance,
            specular_reflectance,
            nonlinear,
            rough,
            internal_reflectance,
            specular_weight,
        }
    }

    /// The coating's microfacets when rough.
    pub fn microfacet(&self) -> Option<Microfacet> {
        self.rough.as_ref().map(|(d, _)| *d)
    }

    /// Transmittance of the coating for light leaving or arriving at cosine `mu`.
    fn transmittance(&self, mu: f32) -> f32 {
        match &self.rough {
            None => 1.0 - fresnel_dielectric(mu, self.eta).0,
            Some((_, table)) => {
                let x = mu.clamp(0.0, 1.0) * (TRANSMITTANCE_RES - 1) as f32;
                let i = (x as usize).min(TRANSMITTANCE_RES - 2);
                let t = x - i as f32;
                table[i] * (1.0 - t) + table[i + 1] * t
            }
        }
    }

    /// Probability of sampling the coating's reflection for `wo`.
    fn specular_probability(&self, wo: Vec3) -> f32 {
        let f = 1.0 - self.transmittance(wo.z);
        let s = f * self.specular_weight;
        let d = (1.0 - f) * (1.0 - self.specular_weight);
        if s + d > 0.0 {
            s / (s + d)
        } else {
            0.0
        }
    }

    fn diffuse_f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        let rho = self.diffuse_reflectance;
        let denom = if self.nonlinear {
            Rgb::ONE - rho * self.internal_reflectance
        } else {
            Rgb::splat(1.0 - self.internal_reflectance)
        };
        let t = self.transmittance(wo.z) * self.transmittance(wi.z);
        rho / denom * (t * FRAC_1_PI / (self.eta * self.eta))
    }

    /// `f(wo, wi)` without the smooth coating's delta lobe.
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Rgb {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Rgb::ZERO;
        }
        let mut f = self.diffuse_f(wo, wi);
        if let Some((dist, _)) = &self.rough {
            let h = (wo + wi).normalize();
            let fr = fresnel_dielectric(wo.dot(h), self.eta).0;
            let g = dist.g1(wo, h) * dist.g1(wi, h);
            f += self.specular_reflectance * (fr * dist.d(h) * g / (4.0 * wo.z * wi.z));
        }
        f
    }

    /// Density of [`Plastic::sample`]'s non-delta directions.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let ps = self.specular_probability(wo);
        let mut pdf = (1.0 - ps) * wi.z * FRAC_1_PI;
        if let Some((dist, _)) = &self.rough {
            let h = (wo + wi).normalize();
            pdf += ps * dist.pdf_visible(wo, h) / (4.0 * wo.dot(h));
        }
        pdf
    }

    /// Draw `wi`: the coating's reflection with probability `ps`, else the base's cosine lobe.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let ps = self.specular_probability(wo);
        let wi = if u_lobe < ps {
            match &self.rough {
                None => {
                    let wi = reflect_z(wo);
                    let f = fresnel_dielectric(wo.z, self.eta).0;
                    return Some(BsdfSample {
                        wi,
                        f: self.specular_reflectance * f / wi.z,
                        pdf: ps,
                        delta: true,
                        eta: 1.0,
                    });
                }
                Some((dist, _)) => reflect(wo, dist.sample_visible(wo, u)),
            }
        } else {
            square_to_cosine_hemisphere(u)
        };
        BsdfSample::from_density(wi, self.pdf(wo, wi), || self.f(wo, wi))
    }
}

/// The `i`-th tabulated cosine (Mitsuba's grid, kept off zero).
fn cosine_at(i: usize) -> f32 {
    (i as f32 / (TRANSMITTANCE_RES - 1) as f32).max(1e-6)
}

/// `F̄ = ∫ 2μ F(μ) dμ` of a smooth interface seen from the inside (relative index `1/eta`), by
/// the midpoint rule.
fn smooth_internal_reflectance(eta: f32) -> f32 {
    const N: usize = 4096;
    let sum: f64 = (0..N)
        .map(|i| {
            let mu = (i as f32 + 0.5) / N as f32;
            f64::from(2.0 * mu * fresnel_dielectric(mu, 1.0 / eta).0)
        })
        .sum();
    (sum / N as f64) as f32
}

/// The direction at cosine `mu` in the xz-plane.
fn direction(mu: f32) -> Vec3 {
    Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu)
}

/// Average over the visible normals `m` of `w` (a midpoint grid over their sample square) of
/// `term(m)`.
fn visible_average(dist: &Microfacet, w: Vec3, term: impl Fn(Vec3) -> f32) -> f32 {
    let mut sum = 0.0f64;
    for a in 0..QUADRATURE {
        for b in 0..QUADRATURE {
            let u = Vec2::new(
                (a as f32 + 0.5) / QUADRATURE as f32,
                (b as f32 + 0.5) / QUADRATURE as f32,
            );
            sum += f64::from(term(dist.sample_visible(w, u)));
        }
    }
    (sum / (QUADRATURE * QUADRATURE) as f64) as f32
}

/// Energy a rough interface of relative index `eta` transmits for light at cosine `mu`:
/// `E_m[(1 − F(w·m)) G1(w_t, m)]` over the visible normals.
fn rough_transmittance(dist: &Microfacet, eta: f32, mu: f32) -> f32 {
    let w = direction(mu);
    visible_average(dist, w, |m| {
        let (f, cos_t, etap) = fresnel_dielectric(w.dot(m), eta);
        if f >= 1.0 {
            return 0.0;
        }
        let n = if w.dot(m) > 0.0 { m } else { -m };
        let wt = refract(w, n, etap, cos_t);
        if wt.z * w.z >= 0.0 {
            return 0.0;
        }
        (1.0 - f) * dist.g1(wt, m)
    })
}

/// Energy a rough interface of relative index `eta` reflects for light at cosine `mu`:
/// `E_m[F(w·m) G1(w_r, m)]` over the visible normals.
fn rough_reflectance(dist: &Microfacet, eta: f32, mu: f32) -> f32 {
    let w = direction(mu);
    visible_average(dist, w, |m| {
        let wr = reflect(w, m);
        if wr.z <= 0.0 {
            return 0.0;
        }
        fresnel_dielectric(w.dot(m), eta).0 * dist.g1(wr, m)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::MicrofacetKind;

    /// The smooth coating's internal reflectance against Egan & Hilgeman's fit, which is
    /// within 0.1 % of the integral for η in 1–1.5.
    #[test]
    fn smooth_internal_reflectance_matches_the_published_fit() {
        for eta in [1.2f32, 1.49] {
            let e = 1.0 / eta;
            let fit = 0.0636 / e + e * (e * -1.4399 + 0.7099) + 0.6681;
            let ours = smooth_internal_reflectance(eta);
            assert!((ours - fit).abs() < 2e-3 * fit, "η {eta}: {ours} vs {fit}");
        }
    }

    /// A rough coating tends to the smooth one as it gets smooth, and transmits less at grazing
    /// angles.
    #[test]
    fn rough_transmittance_tends_to_the_smooth_one() {
        for kind in [MicrofacetKind::Ggx, MicrofacetKind::Beckmann] {
            let dist = Microfacet::new(kind, 0.01);
            for mu in [0.3f32, 0.7, 1.0] {
                let rough = rough_transmittance(&dist, 1.5, mu);
                let smooth = 1.0 - fresnel_dielectric(mu, 1.5).0;
                assert!(
                    (rough - smooth).abs() < 5e-3,
                    "{kind:?} μ {mu}: {rough} vs {smooth}"
                );
            }
            let dist = Microfacet::new(kind, 0.3);
            assert!(rough_transmittance(&dist, 1.5, 0.1) < rough_transmittance(&dist, 1.5, 0.9));
        }
    }
}
