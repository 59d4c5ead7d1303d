//! The GGX (Trowbridge–Reitz) microfacet distribution and the rough conductor and rough
//! dielectric BSDFs built on it.
//!
//! GGX and the rough dielectric follow Walter, Marschner, Li & Torrance, "Microfacet Models for
//! Refraction through Rough Surfaces" (EGSR 2007); microfacet normals are drawn from the
//! distribution of visible normals with Heitz, "Sampling the GGX Distribution of Visible
//! Normals" (JCGT 7(4), 2018). Shadowing–masking is the separable Smith form
//! `G1(wo) G1(wi)`, which is what Mitsuba 3 uses, so that our images agree with it.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::fresnel::{fresnel_conductor, fresnel_dielectric, refract};
use crate::geometry::{reflect, Rgb};

/// Isotropic GGX with roughness `alpha` (the slope parameter, not squared).
#[derive(Clone, Copy, Debug)]
pub struct Ggx {
    /// Roughness.
    pub alpha: f32,
}

impl Ggx {
    /// Microfacet normal density `D(m)` (per unit projected area).
    pub fn d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let cos2 = m.z * m.z;
        let t = (m.x * m.x + m.y * m.y) / a2 + cos2;
        1.0 / (PI * a2 * t * t)
    }

    /// Smith masking `G1(v, m)`; zero when `v` sees the back of `m`.
    pub fn g1(&self, v: Vec3, m: Vec3) -> f32 {
        if v.dot(m) * v.z <= 0.0 {
            return 0.0;
        }
        let cos2 = v.z * v.z;
        let tan2 = ((1.0 - cos2) / cos2).max(0.0);
        2.0 / (1.0 + (1.0 + self.alpha * self.alpha * tan2).sqrt())
    }

    /// A microfacet normal from the distribution of normals visible from `v` (`v.z > 0`).
    pub fn sample_visible(&self, v: Vec3, u: Vec2) -> Vec3 {
        let a = self.alpha;
        let vh = Vec3::new(a * v.x, a * v.y, v.z).normalize();
        let len2 = vh.x * vh.x + vh.y * vh.y;
        let t1 = if len2 > 0.0 {
            Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
        } else {
            Vec3::X
        };
        let t2 = vh.cross(t1);
        let r = u.x.sqrt();
        let phi = 2.0 * PI * u.y;
        let p1 = r * phi.cos();
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
        let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
        Vec3::new(a * nh.x, a * nh.y, nh.z.max(1e-6)).normalize()
    }

    /// Density of [`Ggx::sample_visible`] for normal `m`: `G1(v, m) |v·m| D(m) / v.z`.
    pub fn pdf_visible(&self, v: Vec3, m: Vec3) -> f32 {
        self.g1(v, m) * v.dot(m).abs() * self.d(m) / v.z.abs()
    }
}

/// Rough conductor: `f = F(wo·h) D(h) G1(wo) G1(wi) / (4 cos θo cos θi)`, one-sided.
pub fn rough_conductor_f(ggx: &Ggx, eta: Rgb, k: Rgb, specular: Rgb, wo: Vec3, wi: Vec3) -> Rgb {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return Rgb::ZERO;
    }
    let h = (wo + wi).normalize();
    let g = ggx.g1(wo, h) * ggx.g1(wi, h);
    let scale = ggx.d(h) * g / (4.0 * wo.z * wi.z);
    specular * fresnel_conductor(wo.dot(h), eta, k) * scale
}

/// Density of sampling `wi` by reflecting `wo` about a visible normal: `G1(wo) D(h) / 4 cos θo`.
pub fn rough_conductor_pdf(ggx: &Ggx, wo: Vec3, wi: Vec3) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        return 0.0;
    }
    let h = (wo + wi).normalize();
    ggx.pdf_visible(wo, h) / (4.0 * wo.dot(h))
}

/// Reflect `wo` about a visible GGX normal.
pub fn rough_conductor_sample(ggx: &Ggx, wo: Vec3, u: Vec2) -> Option<Vec3> {
    if wo.z <= 0.0 {
        return None;
    }
    let wi = reflect(wo, ggx.sample_visible(wo, u));
    (wi.z > 0.0).then_some(wi)
}

/// The half vector of a pair of directions and whether they form a reflection, for a rough
/// dielectric of relative index `eta`: `None` when the pair is degenerate or sees back-facing
/// microfacets.
fn dielectric_half_vector(eta: f32, wo: Vec3, wi: Vec3) -> Option<(Vec3, bool, f32)> {
    if wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let reflection = wo.z * wi.z > 0.0;
    let etap = if wo.z > 0.0 { eta } else { 1.0 / eta };
    let h = if reflection { wo + wi } else { wo + wi * etap };
    if h.length_squared() == 0.0 {
        return None;
    }
    let h = h.normalize();
    let h = if h.z < 0.0 { -h } else { h };
    if wo.dot(h) * wo.z <= 0.0 || wi.dot(h) * wi.z <= 0.0 {
        return None;
    }
    Some((h, reflection, etap))
}

/// Rough dielectric BSDF value (radiance transport: transmission is scaled by `1/η'²`).
pub fn rough_dielectric_f(ggx: &Ggx, eta: f32, r: Rgb, t: Rgb, wo: Vec3, wi: Vec3) -> Rgb {
    let Some((h, reflection, etap)) = dielectric_half_vector(eta, wo, wi) else {
        return Rgb::ZERO;
    };
    let f = fresnel_dielectric(wo.dot(h), eta).0;
    let dg = ggx.d(h) * ggx.g1(wo, h) * ggx.g1(wi, h);
    if reflection {
        r * (f * dg / (4.0 * (wo.z * wi.z).abs()))
    } else {
        let denom = wi.dot(h) * etap + wo.dot(h);
        let v =
            dg * (1.0 - f) * (wi.dot(h) * wo.dot(h)).abs() / ((wi.z * wo.z).abs() * denom * denom);
        t * v
    }
}

/// Density of [`rough_dielectric_sample`].
pub fn rough_dielectric_pdf(ggx: &Ggx, eta: f32, wo: Vec3, wi: Vec3) -> f32 {
    let Some((h, reflection, etap)) = dielectric_half_vector(eta, wo, wi) else {
        return 0.0;
    };
    let wo_up = if wo.z < 0.0 { -wo } else { wo };
    let pdf_m = ggx.pdf_visible(wo_up, h);
    let f = fresnel_dielectric(wo.dot(h), eta).0;
    if reflection {
        pdf_m * f / (4.0 * wo.dot(h).abs())
    } else {
        let denom = wi.dot(h) + wo.dot(h) / etap;
        pdf_m * (1.0 - f) * wi.dot(h).abs() / (denom * denom)
    }
}

/// Draw a visible normal for `wo` (flipped to the upper side), then reflect with probability
/// `F` or refract otherwise.
pub fn rough_dielectric_sample(
    ggx: &Ggx,
    eta: f32,
    wo: Vec3,
    u_lobe: f32,
    u: Vec2,
) -> Option<Vec3> {
    if wo.z == 0.0 {
        return None;
    }
    let wo_up = if wo.z < 0.0 { -wo } else { wo };
    let m = ggx.sample_visible(wo_up, u);
    let cos_i = wo.dot(m);
    let (f, cos_t, etap) = fresnel_dielectric(cos_i, eta);
    let wi = if u_lobe < f {
        let wi = reflect(wo, m);
        if wi.z * wo.z <= 0.0 {
            return None;
        }
        wi
    } else {
        let n = if cos_i > 0.0 { m } else { -m };
        let wi = refract(wo, n, etap, cos_t);
        if wi.z * wo.z >= 0.0 {
            return None;
        }
        wi
    };
    Some(wi)
}
